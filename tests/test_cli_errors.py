"""Issue 24 §4: one-line errors, never tracebacks, and no silent success.

Each test here was seen failing on the code before its fix: a setting or an argument
that could be turned against the program (a URL that is not one, a port someone else
holds, a duration of 30 years, a file that is not a video ...) is refused in one line
that names it, and a run that produced nothing does not end as a success.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from tcm_companion import cli
from tcm_companion.config import ConfigError, load_config

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE_T90 = ROOT / "tests" / "data" / "examples" / "EX-T90"
EXAMPLE_T90_FRAMES = ROOT / "tests" / "data" / "examples" / "EX-T90" / "frames"
EXAMPLE_PINHOLE = ROOT / "tests" / "data" / "examples" / "EX-PINHOLE"


def _clean_environ() -> dict[str, str]:
    """The environment without TCM_COMPANION__ overrides."""
    return {k: v for k, v in os.environ.items() if not k.startswith("TCM_COMPANION__")}


# -- 1. link URLs are checked when the configuration is read ------------------------------------
@pytest.mark.parametrize(
    ("url", "names"),
    [
        ("garbage", "unknown transport 'garbage'"),
        ("udpout:127.0.0.1:99999", "port '99999'"),
        ("udpout:127.0.0.1:0", "port '0'"),
        ("udpin:0.0.0.0", "HOST:PORT"),
        ("tcp:999.1.1.1:5760", "'999.1.1.1' is not an IP address"),
        ("tcp:bad_host:5760", "'bad_host' is not an IP address or a host name"),
        ("tcp:-x.example:5760", "not an IP address or a host name"),
        ("serial:/dev/ttyAMA0:9", "baud rate 9"),
        ("serial:ttyAMA0", "absolute path"),
        ("memory:x", "unknown transport 'memory:'"),
    ],
)
@pytest.mark.parametrize("key", ["mavlink.url", "camera.sim_url"])
def test_a_link_url_that_is_not_one_is_a_config_error(key: str, url: str, names: str) -> None:
    """``config check`` accepted ``mavlink.url = "garbage"``; ``run`` then died with a
    TransportURLError traceback. Now the loader refuses it naming the table, the key and
    the flag that set it."""
    table, _, name = key.partition(".")
    with pytest.raises(ConfigError) as err:
        load_config(None, sets=[f"{key}={url}"])
    msg = str(err.value)
    assert msg.startswith(f"config: [{table}] {name} = {url!r} is not a link URL: "), msg
    assert names in msg and msg.endswith(f"(set by --set {key})"), msg
    assert err.value.key == key


@pytest.mark.parametrize(
    "url",
    [
        "udpout:127.0.0.1:14550",
        "udpin:0.0.0.0:14550",
        "udpin:127.0.0.1:0",
        "udpout:[::1]:14550",
        "udpout:companion.local:14550",
        "tcp:localhost:5760",
        "serial:/dev/ttyAMA0",
        "serial:/dev/ttyAMA0:921600",
        "serial:/dev/serial/by-path/platform-3f980000.usb-usb-0:1.3:1.0:921600",
    ],
)
def test_sound_link_urls_are_accepted(url: str) -> None:
    cfg = load_config(None, sets=[f"mavlink.url={url}", f"camera.sim_url={url}"])
    assert cfg.mavlink.url == url and cfg.camera.source.sim_url == url


def test_a_box_feed_host_that_is_not_one_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match=r"\[daemon\]: box_feed .*'999\.0\.0\.1' is not an IP"):
        load_config(None, sets=["detection.backend=boxes", "daemon.box_feed=udp:999.0.0.1:14660"])


@pytest.mark.slow  # a subprocess
def test_run_with_a_bad_url_says_so_in_one_line(tmp_path: Path) -> None:
    """The command as an integrator types it: exit 2, one line, no traceback."""
    proc = subprocess.run(
        [
            *(sys.executable, "-m", "tcm_companion", "run", "--duration", "1", "--no-status"),
            *("--set", "mavlink.url=udpout:127.0.0.1:99999"),
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=_clean_environ(),
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines() == [
        "config error: config: [mavlink] url = 'udpout:127.0.0.1:99999' is not a link URL:"
        " port '99999' is not a number from 1 to 65535 (set by --set mavlink.url)"
    ]


# -- 9. config check reports every error, and takes a byte order mark ---------------------------
def test_config_check_reports_every_error_of_the_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """It stopped at the first one: a file with five mistakes took five runs."""
    path = tmp_path / "c.toml"
    path.write_text(
        "[classifier]\ntcm_threshold = 5\ntreshold = 1\n"
        "[camera]\nwidth = -3\nfps = 0\n"
        '[mavlink]\nurl = "udpout:127.0.0.1:99999"\n'
        '[sim]\nscenario = "T9"\n'
        "[nonsense]\n"
    )
    assert cli.main(["config", "check", str(path), "--set", "logging.jpeg_quality=0"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert all(line.startswith(f"config error: {path}: ") for line in lines), lines
    wanted = [
        "unknown table [nonsense]",
        "[classifier] tcm_threshold = 5 is out of range",
        "[classifier]: unknown key 'treshold'",
        "[camera] width = -3 is out of range",
        "[camera] fps = 0 is out of range",
        "[mavlink] url = 'udpout:127.0.0.1:99999' is not a link URL",
        "[sim]: scenario must be one of",
        "[logging] jpeg_quality = 0 is out of range",
    ]
    for text in wanted:
        assert sum(text in line for line in lines) == 1, (text, lines)
    assert len(lines) == len(wanted), lines
    assert any(line.endswith("(set by --set logging.jpeg_quality)") for line in lines)


def test_a_utf8_byte_order_mark_is_accepted(tmp_path: Path) -> None:
    """Notepad saves one; tomllib called it "Invalid statement (at line 1, column 1)"."""
    path = tmp_path / "c.toml"
    path.write_bytes(b"\xef\xbb\xbf[sim]\nseed = 7\n")
    assert load_config(path).sim.seed == 7


# -- 2. a port someone else holds ------------------------------------------------------------------
def _bounded_memory() -> None:
    """In the child: at most 6 GiB of address space, so that a command that reads
    without end (``config check /dev/zero`` did) fails with a MemoryError, not the
    machine's out-of-memory killer."""
    import resource

    limit = 6 * 1024**3
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))


def _run_cli(args: list[str], cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tcm_companion", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=_clean_environ(),
        timeout=timeout,
        preexec_fn=_bounded_memory,
    )


def _daemon_args(tmp_path: Path) -> list[str]:
    """``run`` on a frames directory (EX-T90's), its state and no log under ``tmp_path``."""
    frames = EXAMPLE_T90_FRAMES
    return [
        *("run", "--duration", "2", "--no-status"),
        *("--set", f"daemon.state_dir={tmp_path / 'state'}", "--set", "logging.enabled=false"),
        *("--set", "camera.source=frames", "--set", f"camera.path={frames}"),
    ]


@pytest.mark.slow  # a subprocess
@pytest.mark.parametrize("what", ["mavlink", "box_feed", "mock-autopilot"])
def test_a_udp_port_in_use_is_one_line_naming_it_and_its_holder(what: str, tmp_path: Path) -> None:
    """It was a TransportOpenError traceback ("could not bind to local_addr"), and for the
    box feed "error: [Errno None] ... cannot listen: None"."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as held:
        held.bind(("127.0.0.1", 0))
        port = held.getsockname()[1]
        if what == "mavlink":
            args = [*_daemon_args(tmp_path), "--set", f"mavlink.url=udpin:127.0.0.1:{port}"]
        elif what == "box_feed":
            args = [
                *_daemon_args(tmp_path),
                *("--set", "detection.backend=boxes"),
                *("--set", f"daemon.box_feed=udp:127.0.0.1:{port}"),
            ]
        else:
            args = ["mock-autopilot", "--connect", f"udpin:127.0.0.1:{port}"]
        proc = _run_cli(args, tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    (line,) = [ln for ln in proc.stderr.splitlines() if "error" in ln]
    assert f"cannot listen on 127.0.0.1:{port}: UDP port {port} is already in use" in line
    assert f"by pid {os.getpid()} (" in line, line  # this test holds it


# -- 3. every size argument is bounded, and says its bound -----------------------------------------
@pytest.mark.parametrize(
    ("argv", "option", "limit"),
    [
        (["sim", "export", "TS", "D", "--duration", "1e9"], "--duration", "up to 3600"),
        (["sim", "export", "TS", "D", "--resolution", "100000x100000"], "--resolution", "16384"),
        (["sim", "export", "TS", "D", "--resolution", "16384x16384"], "--resolution", "4096x4096"),
        (["sim", "export", "TS", "D", "--seed", "99999999999999"], "--seed", "0..4294967295"),
        (["eval", "--sim", "TS", "--duration", "1e9"], "--duration", "up to 3600"),
        (["eval", "--sim", "TS", "--resolutions", "1x1000000"], "--resolutions", "16384"),
        (["eval", "--sim", "TS", "--seed", "4294967296"], "--seed", "0..4294967295"),
        (["demo", "--duration", "1e300"], "--duration", "up to 3600"),
        (["demo", "--seed", "5000000000"], "--seed", "0..4294967295"),
        (["bench", "--frames", "10000000"], "--frames", "1..100000"),
        (["bench", "--resolutions", "65536x65536"], "--resolutions", "16384"),
        (["bench", "--daemon", "--duration", "1e9"], "--duration", "up to 3600"),
        (["run", "--duration", "1e300"], "--duration", "up to 604800"),
        (["sitl", "--duration", "1e9"], "--duration", "up to 604800"),
        (
            ["mock-autopilot", "--connect", "udpin:0.0.0.0:0", "--ekf-origin-delay", "1e300"],
            "--ekf-origin-delay",
            "[0, 600]",
        ),
        (
            ["mock-autopilot", "--connect", "udpin:0.0.0.0:0", "--noise", "1e300"],
            "--noise",
            "[0, 100]",
        ),
        (
            ["mock-autopilot", "--connect", "udpin:0.0.0.0:0", "--brake-ttc", "1e300"],
            "--brake-ttc",
            "(0, 3600]",
        ),
        (
            ["mock-autopilot", "--connect", "udpin:0.0.0.0:0", "--seed", "4294967296"],
            "--seed",
            "0..4294967295",
        ),
    ],
    ids=lambda v: " ".join(v) if isinstance(v, list) else v,
)
def test_a_size_beyond_its_bound_is_a_usage_error_that_says_the_bound(
    argv: list[str], option: str, limit: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """``sim export TS DIR --duration 1e9`` was a numpy ArrayMemoryError for 186 GiB.
    (Parsed only: before the fix these ran, and a 16384x16384 render fills any memory.)"""
    with pytest.raises(SystemExit) as exc:
        cli.build_parser().parse_args(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"error: argument {option}: " in err and limit in err, err


def test_the_library_bounds_a_flight_too() -> None:
    from tcm_companion.sim.scene.scenarios import flight_plan

    with pytest.raises(ValueError, match="at most 3600 s"):
        flight_plan("TS", duration_s=1e9)


def test_running_out_of_memory_is_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """What a bound leaves over (a machine smaller than the bound assumed)."""
    from tcm_companion.cli import sim

    def hungry(_args: object) -> int:
        raise MemoryError("Unable to allocate 74.5 GiB")

    monkeypatch.setattr(sim, "cmd_sim_list", hungry)
    assert cli.main(["sim", "list"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: out of memory (Unable to allocate 74.5 GiB): ask for less")
    assert err.count("\n") == 1


# -- 4. a camera that never produced a frame is not a success ---------------------------------------
@pytest.mark.slow  # a subprocess
def test_a_file_that_is_not_a_video_is_refused_at_start_like_a_missing_one(tmp_path: Path) -> None:
    """It was retried for ever (exit 0, 0 frames) while a missing file was refused."""
    from tcm_companion.core.camera import Equirectangular
    from tcm_companion.io.cameras.base import CameraError
    from tcm_companion.io.cameras.settings import CameraSourceConfig, open_source

    junk = tmp_path / "flight.mp4"
    junk.write_text("not a video\n")
    empty = tmp_path / "frames"
    empty.mkdir()
    cam = Equirectangular(360, 220)
    with pytest.raises(CameraError, match=r"^camera\.path: .*flight\.mp4: OpenCV cannot open"):
        open_source(CameraSourceConfig(source="file", path=str(junk)), cam)
    with pytest.raises(CameraError, match=r"^camera\.path: .*frames: no images"):
        open_source(CameraSourceConfig(source="frames", path=str(empty)), cam)

    proc = _run_cli(
        [*_daemon_args(tmp_path), "--set", "camera.source=file", "--set", f"camera.path={junk}"],
        tmp_path,
    )
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and "retrying" not in proc.stderr
    assert f"error: camera.path: {junk}: OpenCV cannot open this video" in proc.stderr


@pytest.mark.slow  # a subprocess
def test_run_whose_camera_never_produced_a_frame_fails_at_the_end(tmp_path: Path) -> None:
    """``run --duration 8`` with no camera at all exited 0."""
    device = tmp_path / "video7"  # no such device
    proc = _run_cli(
        [
            *_daemon_args(tmp_path),
            *("--set", "camera.source=device", "--set", f"camera.device={device}"),
        ],
        tmp_path,
    )
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith(f"error: camera {device} never produced a frame: it could not be opened")
    assert "no such device" in last
    assert proc.stdout.startswith("stopped after 2.0 s: captured 0, processed 0")


def test_a_camera_whose_every_image_was_rejected_never_produced_a_frame() -> None:
    from tcm_companion.cli.run import cameras_without_frames
    from tcm_companion.io.cameras.base import CameraStats

    stats = {
        "ok": CameraStats(captured=5, delivered=5),
        "junk": CameraStats(captured=2, rejected_empty=1, rejected_size=1),
        "gone": CameraStats(read_errors=1, last_error="unplugged"),
    }
    assert cameras_without_frames(stats) == [
        "camera junk never produced a frame: all 2 images it returned were rejected (1 empty,"
        " 1 of the wrong size)",
        "camera gone never produced a frame: reading failed (unplugged)",
    ]


# -- 5. a setting the simulated run does not use is named, not dropped in silence -------------------
@pytest.mark.slow  # a subprocess
@pytest.mark.parametrize("command", ["run", "sitl"])
@pytest.mark.parametrize("url", ["udpout:10.0.0.5:14550", ""])
def test_mavlink_url_with_the_simulator_is_said_to_be_ignored(
    command: str, url: str, tmp_path: Path
) -> None:
    """With ``source = "sim"`` the daemon talks to the in-process mock autopilot over its
    own loopback pair: a ``--set mavlink.url=...`` was dropped without a word."""
    args = [command, "--duration", "1"]
    if command == "run":
        args += ["--no-status", "--set", "camera.source=sim"]
        args += ["--set", f"daemon.state_dir={tmp_path / 'state'}"]
    else:
        args += ["--clock", "virtual", "--min-accuracy", "0", "--status-every", "0"]
    args += ["--set", "logging.enabled=false"]
    if url:
        args += ["--set", f"mavlink.url={url}"]
    proc = _run_cli(args, tmp_path)
    assert proc.returncode in (0, 1), proc.stderr  # a 1 s flight may decide nothing
    assert "Traceback" not in proc.stderr
    warned = [ln for ln in proc.stderr.splitlines() if "[mavlink] url" in ln]
    if url:
        (line,) = warned
        assert f"WARNING tcm_companion: [mavlink] url = '{url}' is ignored" in line
        assert 'source = "sim_autopilot"' in line
    else:
        assert warned == []  # the default is not worth a word


# -- 6. source = "scenario" takes the camera the scenario declares -----------------------------------


@pytest.mark.slow  # a subprocess
def test_run_on_a_scenario_takes_its_camera_model_and_says_so(tmp_path: Path) -> None:
    """It refused: "scenario ... has 640x480 frames but the camera model is 360x220",
    although the scenario declares its camera (scenario.toml [camera])."""
    args = _daemon_args(tmp_path)
    args[args.index("camera.source=frames")] = "camera.source=scenario"
    args[args.index(f"camera.path={EXAMPLE_T90_FRAMES}")] = f"camera.path={EXAMPLE_PINHOLE}"
    proc = _run_cli(args, tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert (
        f"INFO tcm_companion: camera model: scenario {EXAMPLE_PINHOLE} declares a pinhole"
        " 640x480 camera" in proc.stderr
    )
    assert "processed 0" not in proc.stdout, proc.stdout

    # A lens key this run sets that the scenario contradicts: a conflict, named.
    proc = _run_cli([*args, "--set", "camera.width=500"], tmp_path)
    assert proc.returncode == 2, proc.stderr
    (line,) = proc.stderr.strip().splitlines()
    assert line.startswith("error: camera.source = 'scenario': scenario ")
    assert "declares a pinhole 640x480 camera" in line
    assert "camera.width = 500 (--set camera.width; the scenario's: 640)" in line


def test_the_scenario_camera_replaces_the_configured_one(caplog: pytest.LogCaptureFixture) -> None:
    from tcm_companion.cli.scenario_camera import camera_from_scenario
    from tcm_companion.io.scenario import load_scenario

    declared = load_scenario(EXAMPLE_PINHOLE, check_frames=False).camera
    base = load_config(None, sets=["camera.source=scenario", f"camera.path={EXAMPLE_PINHOLE}"])
    assert camera_from_scenario(base, {}).camera.model == declared
    # a camera someone described (not the built-in default) is replaced with a warning
    fisheye = load_config(
        None,
        sets=[
            "camera.source=scenario",
            f"camera.path={EXAMPLE_PINHOLE}",
            "camera.model=fisheye",
            *("camera.width=640", "camera.height=640", "camera.fx=200.0", "camera.fy=200.0"),
            *("camera.cx=320.0", "camera.cy=320.0", "camera.dist=[0.0, 0.0, 0.0, 0.0]"),
        ],
    )
    with caplog.at_level("INFO"):
        assert camera_from_scenario(fisheye, {}).camera.model == declared
    (record,) = [r for r in caplog.records if "camera model" in r.getMessage()]
    assert record.levelname == "WARNING" and "model, height" in record.getMessage()
    with pytest.raises(ValueError, match=r"camera\.model = 'fisheye' \(environment X"):
        camera_from_scenario(fisheye, {"model": "environment X"})


# -- 7. latency is never negative ------------------------------------------------------------------


@pytest.mark.slow  # a subprocess
def test_frames_read_as_fast_as_possible_have_no_negative_latency(tmp_path: Path) -> None:
    """``realtime = false`` gave "latency p99 -79.09 ms" (p50 -7940 ms): the files'
    series of capture times (anchor + i / fps) ran ahead of the monotonic clock the
    output is stamped on, a mixed time base. The daemon's readers now take a time after
    the read as the read's."""
    import json

    summary = tmp_path / "summary.json"
    proc = _run_cli(
        [
            *("run", "--duration", "3", "--no-status", "--summary-json", str(summary)),
            *("--set", f"daemon.state_dir={tmp_path / 'state'}", "--set", "logging.enabled=false"),
            *("--set", "camera.source=frames", "--set", f"camera.path={EXAMPLE_T90_FRAMES}"),
            *("--set", "camera.realtime=false", "--set", "camera.loop=true"),
        ],
        tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(summary.read_text())
    assert doc["processed"] > 0
    for p in ("p50", "p90", "p99", "max"):
        assert doc[f"latency_{p}_ms"] >= 0.0, doc
    assert "latency p99 -" not in proc.stdout


def test_a_reader_that_may_not_see_the_future_stamps_on_the_read() -> None:
    """The rule itself, on an injected clock: a source's time after the read is the read's;
    times stay strictly increasing; the source's own times are kept otherwise."""
    import numpy as np

    from tcm_companion.io.cameras.base import FrameSource
    from tcm_companion.io.cameras.reader import ReaderCore

    clock = [1_000_000]
    image = np.full((4, 6, 3), 9, np.uint8)

    class Ahead(FrameSource):
        """Times 40 ms apart from 1 s, whatever the clock (a file read fast)."""

        def __init__(self) -> None:
            super().__init__("ahead", 6, 4)
            self.k = 0

        def open(self) -> None:
            pass

        def read(self) -> tuple[np.ndarray, int]:
            self.k += 1
            return image, 1_000_000 + 40_000 * (self.k - 1)

        def close(self) -> None:
            pass

    def times(no_future: bool) -> list[int]:
        core = ReaderCore(Ahead(), 0, no_future=no_future)
        core.step(lambda: clock[0], lambda: False)  # open
        out = []
        for _ in range(4):
            clock[0] += 10_000  # the read comes 10 ms after the last: 4x the file's rate
            step = core.step(lambda: clock[0], lambda: False)
            assert step.frame is not None
            out.append(step.frame.t_capture_us)
        assert core.stats.restamped == (3 if no_future else 0)
        return out

    clock[0] = 1_000_000
    assert times(False) == [1_000_000, 1_040_000, 1_080_000, 1_120_000]  # the source's
    clock[0] = 1_000_000
    assert times(True) == [1_000_000, 1_020_000, 1_030_000, 1_040_000]  # never ahead


# -- 8. the drone's install: no matplotlib, no tqdm --------------------------------------------------
#: What the ``tools`` extra brings (and what only it needs).
TOOLS_ONLY = ("matplotlib", "mpl_toolkits", "tqdm")


@pytest.fixture(scope="module")
def site_without_tools(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """This environment's site-packages without the ``tools`` extra: a directory of
    symbolic links to every entry but matplotlib's and tqdm's (a few hundred links, no
    copy), for an interpreter started with ``-S`` (no site-packages of its own)."""
    import site

    (packages,) = [p for p in site.getsitepackages() if (Path(p) / "numpy").is_dir()]
    out = tmp_path_factory.mktemp("site-without-tools")
    for entry in Path(packages).iterdir():
        if not entry.name.lower().startswith(TOOLS_ONLY):
            (out / entry.name).symlink_to(entry)
    return out


def _run_without_tools(
    site_dir: Path, args: list[str], cwd: Path
) -> subprocess.CompletedProcess[str]:
    """``tcm-companion ARGS`` as installed without the ``tools`` extra."""
    script = (
        "import site, sys\n"
        f"site.addsitedir({str(site_dir)!r})\n"  # its .pth files too (the editable install)
        "for name in ('matplotlib', 'tqdm'):\n"
        "    try:\n"
        "        __import__(name)\n"
        "    except ImportError:\n"
        "        pass\n"
        "    else:\n"
        "        raise SystemExit(f'{name} is importable: the test would prove nothing')\n"
        "from tcm_companion.cli import main\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    return subprocess.run(
        [sys.executable, "-S", "-c", script, *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=_clean_environ(),
        timeout=300,
    )


#: Each command that draws nothing, as the drone would run it, and what it prints.
WITHOUT_TOOLS = {
    "config check": (["config", "check", str(ROOT / "config.toml")], "OK."),
    "sim list": (["sim", "list"], "T90"),
    "sim export": (
        ["sim", "export", "T90", "OUT/scn", "--duration", "0.2", "--resolution", "90x55"],
        "wrote T90: 5 frames",
    ),
    "import": (["import", str(EXAMPLE_T90), "--log", "OUT/t90.mcap"], "-> OUT/t90.mcap"),
    "import --results": (
        ["import", str(EXAMPLE_T90), "--log", "OUT/r.mcap", "--results"],
        "-> OUT/r.mcap",
    ),
    "export": (["export", "OUT/r.mcap", "--scenario", "OUT/back"], "100 frames"),
    "replay": (["replay", str(EXAMPLE_T90), "--results", "OUT/r.csv"], "EX-T90: 100 frames"),
    "replay LOG": (["replay", "OUT/r.mcap", "--results", "OUT/log.csv"], "frames replayed"),
    "eval": (
        ["eval", str(EXAMPLE_T90), "--no-bsm", "--out", "OUT/ev"],
        "no plots in OUT/ev/: matplotlib is not installed: pip install 'tcm-companion[tools]'",
    ),
    "bench": (["bench", "--frames", "3", "--resolutions", "90x55"], "90x55"),
    "run": (
        [
            *("run", "--duration", "1", "--no-status", "--set", "daemon.state_dir=OUT/state"),
            *("--set", "camera.source=frames", "--set", f"camera.path={EXAMPLE_T90 / 'frames'}"),
        ],
        "stopped after 1.0 s",
    ),
    "sitl": (
        [
            *("sitl", "--clock", "virtual", "--duration", "1", "--min-accuracy", "0"),
            *("--set", "logging.enabled=false", "--status-every", "0"),
        ],
        "SITL T90",
    ),
}


@pytest.mark.slow  # a subprocess
@pytest.mark.parametrize("name", list(WITHOUT_TOOLS))
def test_every_command_that_draws_nothing_works_without_the_tools_extra(
    name: str, site_without_tools: Path, tmp_path: Path
) -> None:
    """``export`` was a ModuleNotFoundError traceback for matplotlib on the drone's
    install: ``logtools/__init__.py`` imported the plotting module eagerly."""
    args, says = WITHOUT_TOOLS[name]
    out = tmp_path / "OUT"
    out.mkdir()
    if name in ("export", "replay LOG"):  # a log of the scenario to start from
        prep = _run_without_tools(
            site_without_tools, ["import", str(EXAMPLE_T90), "--log", "OUT/r.mcap"], tmp_path
        )
        assert prep.returncode == 0, prep.stderr
    proc = _run_without_tools(site_without_tools, args, tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert says in proc.stdout + proc.stderr


@pytest.mark.slow  # a subprocess
def test_plot_without_the_tools_extra_names_the_extra(
    site_without_tools: Path, tmp_path: Path
) -> None:
    proc = _run_without_tools(site_without_tools, ["plot", str(EXAMPLE_T90)], tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip() == (
        "error: plot: matplotlib is not installed: pip install 'tcm-companion[tools]'"
        " (make installs it)"
    )


# -- 10. what the docs say about damaged frames is what the commands do -----------------------------
@pytest.fixture(scope="module")
def damaged_scenarios(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """EX-T90 with frame 5's file removed, and with it replaced by junk."""
    import shutil

    root = tmp_path_factory.mktemp("damaged")
    out = {}
    for kind in ("missing", "corrupt"):
        path = root / kind
        shutil.copytree(EXAMPLE_T90, path)
        frame = path / "frames" / "000005.png"
        if kind == "missing":
            frame.unlink()
        else:
            frame.write_bytes(b"not a png")
        out[kind] = path
    return out


@pytest.mark.slow  # over a second of CPU
@pytest.mark.parametrize("command", ["replay", "eval", "plot"])
def test_a_missing_frame_is_refused_and_an_unreadable_one_skipped_by_every_command(
    command: str,
    damaged_scenarios: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The format's rule, "readers must reject a malformed scenario with an error that
    names the file, the line and the problem": a frame frames.csv lists without its file
    is malformed. A frame that is there but unreadable is damage, read around."""

    def argv(scenario: Path) -> list[str]:
        return {
            "replay": ["replay", str(scenario), "--results", str(tmp_path / "r.csv"), "-q"],
            "eval": ["eval", str(scenario), "--no-bsm", "-q", "--out", str(tmp_path / "ev")],
            "plot": ["plot", str(scenario), "--out", str(tmp_path / "plots")],
        }[command]

    missing = damaged_scenarios["missing"]
    assert cli.main(argv(missing)) == 2
    err = capsys.readouterr().err
    assert (
        err
        == f"error: {missing}/frames.csv: line 7: frame 5 has no file {missing}/frames/000005.png\n"
    )
    assert not (tmp_path / "r.csv").exists() and not (tmp_path / "ev").exists()

    if command == "plot":
        pytest.importorskip("matplotlib")
    assert cli.main(argv(damaged_scenarios["corrupt"]) + ["--force"] * (command == "replay")) == 0
    err = capsys.readouterr().err
    assert "000005.png: cannot be read as an image" in err, err


def test_the_docs_say_what_the_commands_do_with_damaged_frames() -> None:
    """README said eval "stops at it ... (exit 2)" (it skips it, exit 0); the scenario
    format page listed a missing frame as skipped (every command refuses it)."""
    import re

    readme = " ".join((ROOT / "README.md").read_text().split())
    assert "`eval` stops at it" not in readme
    assert re.search(r"`replay`, `eval` and `plot` skip an unreadable frame", readme)
    assert "whose file is missing makes the scenario malformed" in readme
    fmt = " ".join((ROOT / "docs" / "scenario-format.md").read_text().split())
    unreadable = fmt[fmt.index("**An unreadable frame**") :]
    assert "(missing," not in unreadable[:200]
    assert "skipped and reported by `replay`, `eval` and `plot` alike" in unreadable
    assert "a frame `frames.csv` lists whose image file does not exist" in fmt


# -- 11. the options each command should have, and its own usage for one it does not --------------
@pytest.mark.slow  # a subprocess
def test_sitl_has_no_status_as_run_does(tmp_path: Path) -> None:
    base = [
        *("sitl", "--clock", "virtual", "--duration", "2", "--min-accuracy", "0"),
        *("--status-every", "1", "--set", "logging.enabled=false"),
    ]
    shown = _run_cli(base, tmp_path)
    assert shown.returncode == 0, shown.stderr
    assert "objects " in shown.stderr  # the status line, once a second
    quiet = _run_cli([*base, "--no-status"], tmp_path)
    assert quiet.returncode == 0, quiet.stderr
    assert "objects " not in quiet.stderr and "fps |" not in quiet.stderr


@pytest.mark.slow  # a subprocess
def test_sim_export_has_quiet(tmp_path: Path) -> None:
    base = ["sim", "export", "TS", "OUT", "--duration", "2.4", "--resolution", "64x40"]
    loud = _run_cli(base, tmp_path)
    assert loud.returncode == 0 and "rendering TS" in loud.stderr, loud.stderr
    quiet = _run_cli([*base, "--force", "-q"], tmp_path)
    assert quiet.returncode == 0, quiet.stderr
    assert quiet.stderr == ""


#: A valid command line of every command (what it needs, nothing else).
MINIMAL_ARGV = {
    "run": ["run"],
    "sitl": ["sitl"],
    "config check": ["config", "check", "c.toml"],
    "replay": ["replay", "SCN", "--results", "r.csv"],
    "eval": ["eval", "SCN"],
    "demo": ["demo"],
    "bench": ["bench"],
    "export": ["export", "LOG", "--scenario", "DIR"],
    "import": ["import", "SCN", "--log", "x.mcap"],
    "plot": ["plot", "SCN"],
    "sim export": ["sim", "export", "TS", "DIR"],
    "sim list": ["sim", "list"],
    "mock-autopilot": ["mock-autopilot", "--connect", "udpin:0.0.0.0:0"],
}


def test_minimal_argv_covers_every_command() -> None:
    def leaves(parser: Any, path: tuple[str, ...] = ()) -> list[str]:
        subs = [a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction"]
        if not subs:
            return [" ".join(path)]
        return [leaf for a in subs for n, p in a.choices.items() for leaf in leaves(p, (*path, n))]

    assert sorted(leaves(cli.build_parser())) == sorted(MINIMAL_ARGV)


@pytest.mark.parametrize("command", list(MINIMAL_ARGV))
def test_an_unknown_option_is_reported_with_the_command_s_own_usage(
    command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """``sim export TS DIR -q`` printed the top level's usage ("usage: tcm-companion [-h]
    [--version] COMMAND ..."), which says nothing about the command's options."""
    with pytest.raises(SystemExit) as exc:
        cli.build_parser().parse_args([*MINIMAL_ARGV[command], "--no-such-option"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"usage: tcm-companion {command} "), err
    assert err.endswith(
        f"tcm-companion {command}: error: unrecognized arguments: --no-such-option\n"
    )


# -- 12. start-up states read as such, not as faults -------------------------------------------------
def test_position_before_the_ekf_origin_is_waiting_not_a_fault() -> None:
    """``make run`` passed and printed ``faults: {'position missing': 1}``: the mock's
    EKF origin comes 3 s after boot (ArduPilot's tens of seconds), as designed."""
    from tcm_companion.core.camera import Equirectangular
    from tcm_companion.core.pipeline import PipelineConfig
    from tcm_companion.mavlink.endpoint import CompanionEndpoint
    from tcm_companion.service.companion import Companion
    from tcm_companion.service.inputs import Inputs, InputSpec

    t0 = 1_000_000_000
    inputs = Inputs([InputSpec("position", 10.0, 1_000_000, starts_late=True)], t0)
    st = inputs.status(t0 + 1_000_000)["position"]
    assert (st.condition, st.problem, st.fault) == ("waiting", "waiting for position", False)
    assert inputs.changes(t0 + 1_000_000) == [("position", "waiting for position")]
    for k in range(10):  # it comes at 3 s ...
        inputs.update("position", t0 + 3_000_000 + k * 100_000)
    assert inputs.changes(t0 + 4_000_000) == [("position", "")]
    st = inputs.status(t0 + 6_000_000)["position"]  # ... and goes: that is a fault
    assert (st.problem, st.fault) == ("position stale", True)

    comp = Companion([Equirectangular(360, 220)], PipelineConfig(), CompanionEndpoint(now_us=0), 0)
    comp.check_inputs(1_000_000)
    assert not [f for f in comp.stats.faults if "position" in f], comp.stats.faults
    assert "TCM: waiting for position" in comp.endpoint.statustexts_queued
    line = comp.status_line(1_000_000)
    assert "waiting for position" in line and "position missing" not in line


def test_the_first_status_line_says_starting_not_zero_fps() -> None:
    from tcm_companion.core.camera import Equirectangular
    from tcm_companion.core.pipeline import PipelineConfig
    from tcm_companion.mavlink.endpoint import CompanionEndpoint
    from tcm_companion.service.companion import Companion

    comp = Companion([Equirectangular(360, 220)], PipelineConfig(), CompanionEndpoint(now_us=0), 0)
    assert "| starting |" in comp.status_line(1_000_000)
    assert " 0.0 fps" not in comp.status_line(1_000_000)
    # No frame two seconds in is no longer starting: the rate is measured, and it is 0.
    assert "|  0.0 fps |" in comp.status_line(2_500_000)


@pytest.mark.slow  # a subprocess
def test_a_sitl_run_like_make_run_reports_no_start_up_fault(tmp_path: Path) -> None:
    proc = _run_cli(
        [
            *("sitl", "--clock", "virtual", "--duration", "4", "--status-every", "1"),
            *("--set", "logging.enabled=false"),
        ],
        tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    assert "  faults: none;" in proc.stdout, proc.stdout
    status = [ln for ln in proc.stderr.splitlines() if ln.startswith("objects ")]
    assert "| starting |" in status[0] and "waiting for position" in status[0]
    assert "0.0 fps" not in proc.stderr and "position missing" not in proc.stderr
    assert "1 moving" in status[-1]  # the T90 ball moves: what `make run` shows


# -- beyond the list: every command against hostile arguments ---------------------------------------
@pytest.fixture(scope="module")
def hostile(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Files that are not what a command expects: empty, a directory, junk, not UTF-8."""
    root = tmp_path_factory.mktemp("hostile")
    (root / "empty").write_bytes(b"")
    (root / "adir").mkdir()
    (root / "emptydir").mkdir()
    (root / "file.txt").write_text("x\n")
    (root / "junk.mcap").write_bytes(b"garbage\n")
    (root / "latin.toml").write_bytes(b"\xff\xfe[sim]\nseed = 1\n")
    return root


EX = str(EXAMPLE_T90)
DAEMON = ["--no-status", "--set", "daemon.state_dir=st", "--set", "camera.source=frames"]
DAEMON += ["--set", f"camera.path={EXAMPLE_T90 / 'frames'}"]

#: (arguments, what the one error line says); every one exits 2 without a traceback.
HOSTILE = [
    (["config", "check", "latin.toml"], "not UTF-8"),
    (["config", "check", "adir"], "is a directory"),
    (["config", "check", "/dev/zero"], "larger than 1024 KiB: not a configuration file"),
    (["config", "check", "empty", "--set", "classifier.tcm_threshold=nan"], "must be finite"),
    (["config", "check", "empty", "--set", "sim.seed=1e400"], "must be an integer"),
    (["config", "check", "empty", "--set", "camera.mount_rpy_deg=[nan, 0, 0]"], "three numbers"),
    (["config", "check", "empty", "--set", "camera"], "expected TABLE.KEY=VALUE"),
    (["replay", EX, "--results", "r.csv", "--config", "latin.toml"], "not UTF-8"),
    (["replay", "empty", "--results", "r.csv"], "not a directory"),
    (["replay", "emptydir", "--results", "r.csv"], "scenario.toml: missing"),
    (["replay", "junk.mcap", "--results", "r.csv"], "no tcm-companion metadata record"),
    (
        [
            *("replay", EX, "--results", "r.csv", "-q", "--set", "detection.backend=onnx"),
            *("--set", "detection.onnx_model=junk.mcap"),
        ],
        "cannot read it as an ONNX model",
    ),
    (["replay", EX, "--results", "/proc/nowhere/r.csv"], "error: /proc/nowhere: No such file"),
    (["eval", "emptydir", "-q"], "scenario.toml: missing"),
    (["export", "junk.mcap", "--scenario", "out"], "error: junk.mcap: "),
    (["export", "emptydir", "--scenario", "out"], "holds no flight log"),
    (["import", "file.txt", "--log", "o.mcap"], "not a directory"),
    (["plot", "junk.mcap", "--out", "pl"], "junk.mcap: not an MCAP file"),
    (["plot", "emptydir", "--out", "pl"], "scenario.toml: missing"),
    (["sim", "export", "TS", "/proc/nowhere", "--duration", "0.2"], "No such file or directory"),
    (["bench", "--resolutions", "0x0"], "resolution must be positive"),
    (
        ["bench", "--daemon", "--duration", "1", "--set", "camera.width=abc"],
        "[camera] width must be a positive integer",
    ),
    (["run", "--duration", "1", "--summary-json", "adir", *DAEMON], "adir: is a directory"),
    (
        ["run", "--duration", "1", "--set", "logging.directory=file.txt", *DAEMON],
        "[logging] directory file.txt: is not a directory",
    ),
    (["sitl", "--clock", "virtual", "--duration", "1", "--log", "file.txt"], "not a directory"),
    (["mock-autopilot", "--connect", "garbage"], "unknown transport 'garbage'"),
]


@pytest.mark.slow  # a subprocess
@pytest.mark.parametrize(
    ("args", "says"), HOSTILE, ids=lambda v: " ".join(v)[:60] if isinstance(v, list) else None
)
def test_hostile_arguments_are_one_line_and_exit_2(
    args: list[str],
    says: str,
    hostile: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A directory where a file is expected, an empty or junk file, text that is not
    UTF-8, NaN and infinities, paths that cannot be: exit 2, one ``error`` line that
    names the input, no traceback. (Before: an OnnxModelError traceback for a file that
    is not a model; "plot" of a junk file exited 0 having drawn nothing; a flight log
    directory that is a file, or --summary-json a directory, found out only after the
    run; "[Errno 2] No such file ..."; mock-autopilot exited 1.)

    In this process (``main`` as the console script calls it: an exception that escapes
    it fails the test, a traceback logged is a record with ``exc_info``), except a case
    that may read without end, which runs in a child with bounded memory."""
    import shutil

    for entry in hostile.iterdir():  # each case in a directory of its own
        dest = tmp_path / entry.name
        if entry.is_dir():
            shutil.copytree(entry, dest)
        else:
            shutil.copy(entry, dest)
    if "/dev/zero" in args:
        proc = _run_cli(args, tmp_path)
        rc, err = proc.returncode, proc.stderr
    else:
        monkeypatch.chdir(tmp_path)
        for name in list(os.environ):
            if name.startswith("TCM_COMPANION__"):
                monkeypatch.delenv(name)
        try:
            rc = cli.main(args)
        except SystemExit as exc:  # argparse's usage errors, as the console script ends
            rc = int(exc.code or 0)
        err = capsys.readouterr().err
        logged = [r for r in caplog.records if r.exc_info]
        assert not logged, [r.getMessage() for r in logged]
    assert rc == 2, (rc, err[-2000:])
    assert "Traceback" not in err
    errors = [ln for ln in err.splitlines() if "error" in ln]
    assert len(errors) == 1 and says in errors[0], err[-2000:]


@pytest.mark.slow  # a subprocess
def test_mock_autopilot_stops_on_sigterm_while_its_link_is_down(tmp_path: Path) -> None:
    """``mock-autopilot --connect serial:/dev/nonexistent`` waited for the link to come
    up whatever signal came: only SIGKILL ended it."""
    import signal
    import time

    proc = subprocess.Popen(
        [
            *(sys.executable, "-m", "tcm_companion", "mock-autopilot"),
            *("--connect", f"serial:{tmp_path / 'ttyNONE'}:57600"),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
        env=_clean_environ(),
    )
    try:
        deadline = time.monotonic() + 60
        assert proc.stderr is not None
        for line in proc.stderr:  # the link's first failure: it is waiting for it now
            if "retrying with backoff" in line or time.monotonic() > deadline:
                break
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0
    assert out.startswith("mock autopilot: 0 status messages received")


def test_plot_of_a_flight_log_that_holds_nothing_to_plot_is_an_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A flight log with its metadata and nothing else (a run stopped at once): every plot
    is skipped, and that is exit 2 with one line, not a success with no picture."""
    from tcm_companion.flightlog.settings import LoggingConfig
    from tcm_companion.flightlog.writer import FlightLogWriter

    writer = FlightLogWriter(LoggingConfig(), tmp_path / "log")
    writer.start({"config": "{}"})
    writer.stop()
    rc = cli.main(["plot", str(tmp_path / "log"), "--out", str(tmp_path / "pl")])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert [ln for ln in err.splitlines() if ln.startswith("error:")] == [
        f"error: {tmp_path / 'log'}: nothing to plot (every plot skipped, above)"
    ]
    assert not list((tmp_path / "pl").glob("*.png"))
