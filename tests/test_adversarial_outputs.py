"""The output-overwrite matrix (issue 24 §1): every command that writes something, with
its output pointed at its own input, inside it, around it, at an unrelated directory, a
device node, a FIFO, a symbolic link to an input or to an unrelated file, a path under a
file, and the same path as another of its outputs. Each case checks that nothing was
lost: every file of the world (inputs, unrelated files, devices, links) is checksummed
before and after, and a refusal is one line (exit 2) naming the paths. Then SIGTERM and
SIGINT in the middle of a write (real subprocesses and signals): the exit is clean (143,
130; one line, no traceback), no hidden ``.NAME.*.tmp`` stays and the previous output is
intact; ``bench --daemon`` removes its working directory.

Found by trying (issue 24): ``export LOGDIR --scenario LOGDIR --force`` deleted the log;
``import SCEN --log SCEN --force`` replaced the scenario with one file; ``replay LOG.mcap
--results LOG.mcap --force`` overwrote the log; ``replay SCEN --results SCEN/frames.csv
--force`` destroyed the scenario; ``export LOG --scenario mydocs --force`` deleted
``mydocs/thesis.tex``; as root, ``--results /dev/full --force`` replaced the device.

Bounded in time: one 1 s virtual-SITL flight log and the 100-frame example scenario,
built once for the module; every refusal happens before any work.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import stat
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from tcm_companion import cli

EXAMPLE = Path(__file__).parent / "data" / "examples" / "EX-T90"

# one worker builds the module's fixtures once (under -n 2 --dist loadgroup)
pytestmark = pytest.mark.xdist_group("adversarial-outputs")


#: A 1.5 s flight of the mock autopilot in virtual time (a second or two of CPU; in the
#: first second the log holds no MAVLink yet, which export needs).
SITL_1S = ["sitl", "--clock", "virtual", "--duration", "1.5", "--status-every", "0",
           "--log-level", "ERROR", "--min-accuracy", "0"]  # fmt: skip


# -- the world: inputs, unrelated files, special files --------------------------------------
@dataclass(frozen=True)
class World:
    root: Path
    log_dir: Path  # a flight log directory (one part)
    log_part: Path  # ... and its part, as a log file
    scen: Path  # a tcm-scenario/1 directory
    config: Path  # a configuration file the commands are given (--config)
    mydocs: Path  # an unrelated directory with a thesis in it
    notes: Path  # an unrelated file
    device: Path  # a character device node (as /dev/null), made here
    fifo: Path  # a FIFO, made here
    run_logs: Path  # run's flight log directory, set in the configuration


def _snapshot(*roots: Path) -> dict[str, tuple[object, ...]]:
    """Every entry under ``roots``: its type and content (SHA-256 of a file, a link's
    target, a device's numbers) and its mode; a FIFO is never opened."""
    out: dict[str, tuple[object, ...]] = {}
    for root in roots:
        for dirpath, dirnames, filenames in os.walk(root):
            for name in dirnames + filenames:
                p = Path(dirpath) / name
                st = p.lstat()
                mode = stat.S_IMODE(st.st_mode)
                if stat.S_ISLNK(st.st_mode):
                    what: tuple[object, ...] = ("link", os.readlink(p))
                elif stat.S_ISREG(st.st_mode):
                    what = ("file", hashlib.sha256(p.read_bytes()).hexdigest(), mode)
                elif stat.S_ISDIR(st.st_mode):
                    what = ("dir", mode)
                elif stat.S_ISCHR(st.st_mode):
                    what = ("chr", st.st_rdev, mode)
                elif stat.S_ISFIFO(st.st_mode):
                    what = ("fifo", mode)
                else:
                    what = ("other", st.st_mode)
                out[str(p)] = what
    return out


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> World:
    if os.geteuid() != 0:
        pytest.skip("the device-node cases need root (os.mknod)")
    root = tmp_path_factory.mktemp("world")
    log_dir = root / "log"
    assert cli.main([*SITL_1S, "--log", str(log_dir)]) == 0
    (log_part,) = sorted(log_dir.glob("tcm-*.mcap"))
    scen = root / "scen"
    shutil.copytree(EXAMPLE, scen)
    state = root / "state"
    state.mkdir()
    run_logs = root / "runlogs"
    cfg_dir = root / "cfg"
    cfg_dir.mkdir()
    config = cfg_dir / "config.toml"
    config.write_text(
        f'[daemon]\nstate_dir = "{state}"\n'
        f'[camera]\nsource = "scenario"\npath = "{scen}"\n'
        f'[logging]\ndirectory = "{run_logs}"\n'
    )
    mydocs = root / "mydocs"
    mydocs.mkdir()
    (mydocs / "thesis.tex").write_text("\\chapter{Six years of work}\n")
    mydocs.chmod(0o755)
    notes = root / "notes.txt"
    notes.write_text("not an output of anything\n")
    device = root / "null"
    os.mknod(device, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    fifo = root / "fifo"
    os.mkfifo(fifo)
    return World(root, log_dir, log_part, scen, config, mydocs, notes, device, fifo, run_logs)


# -- the commands and where each reads ------------------------------------------------------
@dataclass(frozen=True)
class Command:
    name: str
    argv: Callable[[World, str], list[str]]  # the command line writing to this output
    input_dir: Callable[[World], Path | None]  # an input directory (None: it has none)
    input_file: Callable[[World], Path | None]  # an input file
    folder: bool = False  # it adds files to a folder (plots, logs): never replaces it
    writes: str = ""  # a file name it writes into its folder


def _cfg(w: World) -> list[str]:
    return ["--config", str(w.config)]


COMMANDS = [
    Command(
        "replay-scenario",
        lambda w, o: ["replay", str(w.scen), "--results", o, "--force", "-q", *_cfg(w)],
        lambda w: w.scen,
        lambda w: w.scen / "frames.csv",
    ),
    Command(
        "replay-log-file",
        lambda w, o: ["replay", str(w.log_part), "--results", o, "--force", "-q", *_cfg(w)],
        lambda w: None,
        lambda w: w.log_part,
    ),
    Command(
        "replay-log-dir",
        lambda w, o: ["replay", str(w.log_dir), "--results", o, "--force", "-q", *_cfg(w)],
        lambda w: w.log_dir,
        lambda w: w.log_part,  # a log directory contains its parts
    ),
    Command(
        "export",
        lambda w, o: ["export", str(w.log_dir), "--scenario", o, "--force"],
        lambda w: w.log_dir,
        lambda w: w.log_part,
    ),
    Command(
        "export-log-file",
        lambda w, o: ["export", str(w.log_part), "--scenario", o, "--force"],
        lambda w: None,
        lambda w: w.log_part,
    ),
    Command(
        "import",
        lambda w, o: ["import", str(w.scen), "--log", o, "--force", "--results", *_cfg(w)],
        lambda w: w.scen,
        lambda w: w.scen / "telemetry.tlog",
    ),
    Command(
        "sim-export",
        lambda w, o: ["sim", "export", "TS", o, "--force", "--duration", "0.2"],
        lambda w: None,
        lambda w: None,
    ),
    Command(
        "eval",
        lambda w, o: ["eval", str(w.scen), "--out", o, "--no-bsm", "-q", *_cfg(w)],
        lambda w: w.scen,
        lambda w: w.config,
        folder=True,
        writes="report.txt",
    ),
    Command(
        "demo",
        lambda w, o: ["demo", "--out", o, "--duration", "1", "-q", *_cfg(w)],
        lambda w: None,
        lambda w: w.config,
        folder=True,
        writes="roc_native.png",
    ),
    Command(
        "plot-scenario",
        lambda w, o: ["plot", str(w.scen), "--out", o, *_cfg(w)],
        lambda w: w.scen,
        lambda w: w.config,
        folder=True,
        writes="disparity.png",
    ),
    Command(
        "plot-log",
        lambda w, o: ["plot", str(w.log_dir), "--out", o],
        lambda w: w.log_dir,
        lambda w: w.log_part,
        folder=True,
        writes="health.png",
    ),
    Command(
        "run-summary-json",
        lambda w, o: ["run", "--summary-json", o, "--duration", "1", "--no-status", *_cfg(w)],
        lambda w: w.scen,  # camera.source = "scenario"
        lambda w: w.config,
    ),
    Command(
        "sitl-log",
        lambda w, o: [*SITL_1S, "--log", o, *_cfg(w)],
        lambda w: w.scen,
        lambda w: w.config,
        folder=True,
    ),
]

#: Each case: the output path, from the world, the command and a scratch directory;
#: None when the case does not apply to the command.
CASES: dict[str, Callable[[World, Command, Path], Path | None]] = {
    "is-the-input-file": lambda w, c, t: c.input_file(w),
    "is-the-input-dir": lambda w, c, t: c.input_dir(w),
    "inside-the-input": lambda w, c, t: (d / "out") if (d := c.input_dir(w)) else None,
    "contains-the-input": lambda w, c, t: (
        (c.input_dir(w) or c.input_file(w)).parent  # type: ignore[union-attr]
        if (c.input_dir(w) or c.input_file(w))
        else None
    ),
    "an-unrelated-directory": lambda w, c, t: w.mydocs,
    "a-device": lambda w, c, t: w.device,
    "a-fifo": lambda w, c, t: w.fifo,
    "a-link-to-an-input": lambda w, c, t: (
        _link(t / "link", c.input_dir(w) or c.input_file(w))
        if (c.input_dir(w) or c.input_file(w))
        else None
    ),
    "a-link-to-an-unrelated-file": lambda w, c, t: _link(t / "link", w.notes),
    "under-a-file": lambda w, c, t: w.notes / "out",
    "under-the-config-file": lambda w, c, t: w.config / "out",
}


def _link(link: Path, target: Path | None) -> Path:
    assert target is not None
    link.symlink_to(target)
    return link


def _case_ids() -> list[tuple[str, str]]:
    return [(c.name, case) for c in COMMANDS for case in CASES]


@pytest.mark.parametrize(("command", "case"), _case_ids(), ids=[f"{a}:{b}" for a, b in _case_ids()])
def test_an_output_never_destroys_an_input_or_what_is_not_ours(
    world: World,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    command: str,
    case: str,
) -> None:
    cmd = next(c for c in COMMANDS if c.name == command)
    if cmd.folder and case == "an-unrelated-directory":
        if not cmd.writes:
            pytest.skip("adds new files beside the others: tests below")
        # a folder is kept; a file of its name that is not what it writes is not replaced
        out_dir = tmp_path / "mydocs"
        shutil.copytree(world.mydocs, out_dir)
        (out_dir / cmd.writes).write_text("my own file, not a plot or a report\n")
        out: Path | None = out_dir
    else:
        out = CASES[case](world, cmd, tmp_path)
    if out is None:
        pytest.skip(f"{command} has no such input")
    before = _snapshot(world.root, tmp_path)
    capsys.readouterr()
    status = cli.main(cmd.argv(world, str(out)))
    err = capsys.readouterr().err
    assert status == 2, err
    assert _snapshot(world.root, tmp_path) == before  # nothing lost, nothing left behind
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert str(out) in lines[0] or out.name in lines[0], err
    if case.startswith(("is-the-input", "inside-the", "contains-the", "a-link-to-an-input")):
        assert "input" in lines[0], err


def test_the_same_path_for_two_outputs_is_refused(
    world: World, capsys: pytest.CaptureFixture[str]
) -> None:
    """``run --summary-json`` at the flight log's directory ([logging] directory)."""
    before = _snapshot(world.root)
    argv = ["run", "--summary-json", str(world.run_logs), "--duration", "1", *_cfg(world)]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "other output" in err and str(world.run_logs) in err
    assert _snapshot(world.root) == before


def test_a_folder_output_keeps_what_else_it_holds(world: World, tmp_path: Path) -> None:
    """``plot --out mydocs`` (and a virtual-SITL ``--log mydocs``) add their files and
    leave the thesis and the folder's mode as they were; a plot replaces a PNG of its
    own name (written whole: no temporary left)."""
    out = tmp_path / "mydocs"
    shutil.copytree(world.mydocs, out)
    out.chmod(0o755)
    thesis = (out / "thesis.tex").read_bytes()
    (out / "health.png").write_bytes(b"\x89PNG\r\n\x1a\n an earlier plot")
    assert cli.main(["plot", str(world.log_dir), "--out", str(out)]) == 0
    assert len((out / "health.png").read_bytes()) > 1000  # replaced: it was a PNG
    assert (out / "thesis.tex").read_bytes() == thesis
    assert stat.S_IMODE(out.stat().st_mode) == 0o755
    assert not [p for p in out.iterdir() if p.name.startswith(".")]
    pngs = sorted(out.glob("*.png"))
    assert pngs and all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in pngs)
    assert cli.main([*SITL_1S, "--log", str(out)]) == 0
    assert (out / "thesis.tex").read_bytes() == thesis
    assert list(out.glob("tcm-*.mcap"))


def test_force_replaces_only_its_own_kind_with_a_new_files_mode(
    world: World, tmp_path: Path
) -> None:
    """An earlier results CSV, scenario and flight log are replaced with --force, and
    come back with the mode a new file gets under the umask (not mkstemp's 0600 or
    mkdtemp's 0700); a file of another kind is refused even with --force."""
    old = os.umask(0o022)
    try:
        results = tmp_path / "results.csv"
        argv = ["replay", str(world.scen), "--results", str(results), "-q"]
        assert cli.main(argv) == 0
        assert stat.S_IMODE(results.stat().st_mode) == 0o644
        results.chmod(0o600)
        assert cli.main([*argv, "--force"]) == 0
        assert stat.S_IMODE(results.stat().st_mode) == 0o644

        scen = tmp_path / "exported"
        argv = ["export", str(world.log_dir), "--scenario", str(scen)]
        assert cli.main(argv) == 0
        assert cli.main([*argv, "--force"]) == 0
        assert stat.S_IMODE(scen.stat().st_mode) == 0o755
        assert (scen / "scenario.toml").is_file()

        log = tmp_path / "imported.mcap"
        argv = ["import", str(scen), "--log", str(log)]
        assert cli.main(argv) == 0
        assert cli.main([*argv, "--force"]) == 0
        assert stat.S_IMODE(log.stat().st_mode) == 0o644

        # the wrong kind: a scenario where a log goes, a log where results go, ...
        assert cli.main(["import", str(scen), "--log", str(results), "--force"]) == 2
        argv = ["replay", str(world.scen), "--results", str(log), "--force", "-q"]
        assert cli.main(argv) == 2
        assert cli.main(["export", str(world.log_dir), "--scenario", str(log), "--force"]) == 2
        # ... and a scenario holding something of the user's
        (scen / "notes.md").write_text("mine\n")
        argv = ["export", str(world.log_dir), "--scenario", str(scen), "--force"]
        assert cli.main(argv) == 2
        assert (scen / "notes.md").read_text() == "mine\n"
        assert sorted(p.name for p in tmp_path.iterdir()) == [
            "exported",
            "imported.mcap",
            "results.csv",
        ]
    finally:
        os.umask(old)


# -- signals in the middle of a write -------------------------------------------------------
#: Runs the command line with one function held after its ``after``-th call (the write is
#: under way, its temporary output on disk) until a signal ends the process; it touches
#: ``flag`` then. The signal, the clean-up and the files are real.
GATED = r"""
import importlib, sys, time
target, after, flag = sys.argv[1], int(sys.argv[2]), sys.argv[3]
modname, _, qual = target.partition(":")
owner = importlib.import_module(modname)
*path, attr = qual.split(".")
for p in path:
    owner = getattr(owner, p)
orig = getattr(owner, attr)
calls = [0]
def gated(*a, **k):
    r = orig(*a, **k)
    calls[0] += 1
    if calls[0] == after:
        open(flag, "w").close()
        while True:
            time.sleep(0.01)
    return r
setattr(owner, attr, gated)
from tcm_companion.cli import main
sys.exit(main(sys.argv[4:]))
"""


def _run_gated(
    tmp_path: Path, target: str, after: int, argv: list[str], sig: signal.Signals,
    temp_glob: tuple[Path, str] | None, env: dict[str, str] | None = None,
) -> subprocess.CompletedProcess[str]:  # fmt: skip
    """Start the gated command, wait until it is held mid-write (and its temporary is
    there, when ``temp_glob`` says where), send ``sig``, return how it ended."""
    flag = tmp_path / "held"
    proc = subprocess.Popen(
        [sys.executable, "-c", GATED, target, str(after), str(flag), *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        deadline = time.monotonic() + 120  # a bound against hanging, not a timing
        while not flag.exists():
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "never reached the write"
            time.sleep(0.02)
        if temp_glob is not None:
            where, pattern = temp_glob
            assert list(where.glob(pattern)), f"no temporary {pattern} in {where}"
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def _assert_clean_end(done: subprocess.CompletedProcess[str], sig: signal.Signals) -> None:
    assert done.returncode == 128 + int(sig), done.stderr
    assert "Traceback" not in done.stderr, done.stderr
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    word = "terminated" if sig == signal.SIGTERM else "interrupted"
    assert lines and lines[-1] == f"{word} ({sig.name})", done.stderr


@pytest.fixture(scope="module")
def earlier(world: World, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Earlier outputs of replay, export and sim export, to be replaced with --force."""
    d = tmp_path_factory.mktemp("earlier")
    assert cli.main(["replay", str(world.scen), "--results", str(d / "r.csv"), "-q"]) == 0
    assert cli.main(["export", str(world.log_dir), "--scenario", str(d / "exp")]) == 0
    assert cli.main(["sim", "export", "TS", str(d / "sim"), "--duration", "1"]) == 0
    return d


SIGNAL_CASES = [
    # (command, held function, after calls, output name, signal)
    ("replay", "tcm_companion.io.results:ResultsWriter.write", 5, "r.csv", signal.SIGTERM),
    ("replay", "tcm_companion.io.results:ResultsWriter.write", 5, "r.csv", signal.SIGINT),
    ("export", "cv2:imwrite", 3, "exp", signal.SIGTERM),
    ("export", "cv2:imwrite", 3, "exp", signal.SIGINT),
    ("sim-export", "cv2:imwrite", 3, "sim", signal.SIGTERM),
    # no earlier log: nothing appears (its writer thread does not hold the exit either)
    ("import", "tcm_companion.flightlog.writer:FlightLogWriter.log_frame", 3, "l.mcap",
     signal.SIGTERM),
]  # fmt: skip


@pytest.mark.parametrize(
    ("command", "target", "after", "name", "sig"),
    SIGNAL_CASES,
    ids=[f"{c[0]}-{c[4].name}" for c in SIGNAL_CASES],
)
def test_a_signal_mid_write_leaves_no_temporary_and_the_previous_output(
    world: World,
    earlier: Path,
    tmp_path: Path,
    command: str,
    target: str,
    after: int,
    name: str,
    sig: signal.Signals,
) -> None:
    work = tmp_path / "work"
    shutil.copytree(earlier, work)
    out = work / name
    argv = {
        "replay": ["replay", str(world.scen), "--results", str(out), "--force", "-q"],
        "export": ["export", str(world.log_dir), "--scenario", str(out), "--force"],
        "sim-export": ["sim", "export", "TS", str(out), "--duration", "1", "--force"],
        "import": ["import", str(world.scen), "--log", str(out)],
    }[command]
    before = _snapshot(work)
    done = _run_gated(tmp_path, target, after, argv, sig, (work, f".{name}.*.tmp"))
    _assert_clean_end(done, sig)
    assert _snapshot(work) == before  # the previous output whole; no .NAME.*.tmp, no .old


def test_ctrl_c_in_eval_is_one_line(world: World, tmp_path: Path) -> None:
    argv = ["eval", str(world.scen), "--out", str(tmp_path / "ev"), "--no-bsm", "-q"]
    target = "tcm_companion.cli.evaluate:_FrameCounter.__call__"
    done = _run_gated(tmp_path, target, 5, argv, signal.SIGINT, None)
    _assert_clean_end(done, signal.SIGINT)
    assert not (tmp_path / "ev").exists()


def _bench_dirs(tmp: Path) -> list[Path]:
    return list(tmp.glob("tcm-bench-daemon-*"))


def test_bench_daemon_removes_its_working_directory_when_interrupted(tmp_path: Path) -> None:
    """SIGTERM while it renders its frames: no ``tcm-bench-daemon-*`` stays in $TMPDIR."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {**os.environ, "TMPDIR": str(tmp)}
    argv = ["bench", "--daemon", "--duration", "30"]
    done = _run_gated(
        tmp_path, "cv2:imwrite", 2, argv, signal.SIGTERM, (tmp, "tcm-bench-daemon-*"), env
    )
    _assert_clean_end(done, signal.SIGTERM)
    assert _bench_dirs(tmp) == []


def test_bench_daemon_removes_its_working_directory_at_the_end(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A whole (short) run: the daemon, the mock, the summary; then nothing left."""
    import tempfile

    from tcm_companion.bench.daemon import run_daemon_bench

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    result = run_daemon_bench(1.0, frames_s=1.0, out=lambda _line: None)
    assert result["processed"] > 0
    assert _bench_dirs(tmp_path) == []
