"""The rig form of the scenario format (issue 26): reader, writer, sim export --rig, replay
and eval of a rig, and the one-camera form unchanged."""

from __future__ import annotations

import csv
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from tcm_companion import cli
from tcm_companion.core.camera import Pinhole
from tcm_companion.io.results import RESULTS_HEADER, RIG_RESULTS_HEADER, ResultsWriter
from tcm_companion.io.scenario import (
    RigScenario,
    Scenario,
    ScenarioError,
    load_any,
    load_rig,
    load_scenario,
)
from tcm_companion.sim.scene.export import make_scenario
from tcm_companion.sim.scene.rig_scenario import SimulatedRig, export_rig, make_rig

from .helpers import EXAMPLE_NAMES, example_path

SMALL = (64, 48)


@pytest.fixture(scope="module")
def tiny_rig(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """T90 seen by the front-back rig, 0.4 s at 64x48 (10 frames a camera)."""
    out = tmp_path_factory.mktemp("rig") / "tiny"
    export_rig(make_rig("T90", "front-back", duration_s=0.4, resolution=SMALL), out)
    return out


@pytest.fixture()
def broken(tiny_rig: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "r"
    shutil.copytree(tiny_rig, dst)
    return dst


def edit(path: Path, old: str, new: str, count: int = 1) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, count))


def line_of(path: Path, pattern: str, k: int = 0) -> int:
    lines = [i + 1 for i, s in enumerate(path.read_text().splitlines()) if re.match(pattern, s)]
    return lines[k]


# -- reader and writer -------------------------------------------------------------------
def test_round_trip(tiny_rig: Path) -> None:
    sim = make_rig("T90", "front-back", duration_s=0.4, resolution=SMALL)
    rig = load_rig(tiny_rig)
    assert isinstance(rig, RigScenario)
    assert rig.camera_names == ["front", "rear"] and rig.name == "T90"
    assert [c.root for c in rig.cameras] == [tiny_rig / "cameras/front", tiny_rig / "cameras/rear"]
    assert [c.name for c in rig.cameras] == ["T90/front", "T90/rear"]
    for got, want in zip(rig.cameras, sim.cameras):
        assert got.camera == want.camera
        assert np.array_equal(got.frame_times_us, want.frame_times_us)
        assert got.truth is not None
        np.testing.assert_allclose(got.truth.obj_ned_m, want.truth.obj_ned_m, atol=1e-6)
        assert got.telemetry is rig.telemetry  # one telemetry for the rig
        _, t_us, img = next(got.iter_frames())
        assert img.shape == (SMALL[1], SMALL[0], 3) and t_us == got.frame_times_us[0]
    assert len(rig.telemetry) == len(sim.telemetry)
    assert rig.cameras[1].camera.mount_rpy_deg == (0.0, 0.0, 180.0)
    assert rig.has_truth and rig.n_frames == 20
    assert isinstance(load_any(tiny_rig), RigScenario)


def test_load_scenario_points_a_rig_to_load_rig(tiny_rig: Path) -> None:
    with pytest.raises(ScenarioError, match=r"scenario\.toml: this scenario is a camera rig \("):
        load_scenario(tiny_rig)


@pytest.mark.parametrize("name", EXAMPLE_NAMES)
def test_independent_examples_read_as_before(name: str) -> None:
    path = example_path(name)
    one, any_ = load_scenario(path), load_any(path)
    assert isinstance(any_, Scenario)
    assert any_.camera == one.camera and any_.name == one.name
    assert np.array_equal(any_.frame_times_us, one.frame_times_us)
    assert any_.warnings == one.warnings == []
    assert one.truth is not None and any_.truth is not None
    assert np.array_equal(any_.truth.obj_ned_m, one.truth.obj_ned_m)
    with pytest.raises(ScenarioError, match="no \\[\\[cameras\\]\\] tables"):
        load_rig(path)


def test_one_camera_results_header_unchanged() -> None:
    import io

    fh = io.StringIO()
    ResultsWriter(fh)
    assert fh.getvalue() == ",".join(RESULTS_HEADER) + "\n"
    fh = io.StringIO()
    w = ResultsWriter(fh, ["front", "rear"])
    assert fh.getvalue() == (
        "frame,t_us,camera,track_id,azimuth_deg,elevation_deg,angular_radius_deg,state,"
        "disparity,ttc_s\n"
    )
    assert RIG_RESULTS_HEADER[2] == "camera"
    from tcm_companion.core.pipeline import FrameResult

    with pytest.raises(ValueError, match="camera_id"):
        w.write(FrameResult(0, 0, (), True, None, {}))


# -- what the reader refuses, with file and line ---------------------------------------------
def test_both_camera_and_cameras(broken: Path) -> None:
    toml = broken / "scenario.toml"
    edit(toml, 'description = "', '[camera]\nmodel = "pinhole"\n\n[x]\ndescription = "')
    # [camera] must come after the top-level keys: put it at the end instead
    toml.write_text(
        toml.read_text().replace('[camera]\nmodel = "pinhole"\n\n[x]\n', "")
        + '\n[camera]\nmodel = "pinhole"\n'
    )
    line = line_of(toml, r"\[camera\]")
    for load in (load_rig, load_scenario, load_any):
        with pytest.raises(ScenarioError, match=rf"scenario\.toml: line {line}: both \[camera\]"):
            load(broken)


@pytest.mark.parametrize(
    ("old", "new", "k", "problem"),
    [
        ('name = "rear"\n', "", 1, r"name must be letters, digits, '_' or '-', got None"),
        ('name = "rear"', 'name = "rear cam"', 1, r"name must be letters.*got 'rear cam'"),
        ('name = "rear"', 'name = "front"', 1, r"\(front\): name 'front' is already camera 1's"),
        ('dir = "cameras/rear"\n', "", 1, r"\(rear\): dir must be a relative path, got None"),
        ('dir = "cameras/rear"', 'dir = "/tmp"', 1, r"\(rear\): dir '/tmp' is not inside"),
        ('dir = "cameras/rear"', 'dir = "../.."', 1, r"\(rear\): dir '\.\./\.\.' is not inside"),
        ('dir = "cameras/rear"', 'dir = "."', 1, r"\(rear\): dir '\.' is the scenario's top"),
        ('dir = "cameras/rear"', 'dir = "cameras/side"', 1, r"\(rear\): dir .* not a directory"),
        ('dir = "cameras/rear"', 'dir = "cameras/front"', 1, r"is already camera 1's"),
        ('dir = "cameras/rear"', 'dir = "cameras/rear"\nfxx = 3.0', 1, r"unknown key 'fxx'"),
        (
            'dir = "cameras/rear"',
            'dir = "cameras/rear"\nframes_dir = "frames"\nvideo = "v.mkv"',
            1,
            r"give at most one of frames_dir or video",
        ),
        (
            'dir = "cameras/rear"',
            'dir = "cameras/rear"\nframes_dir = "../../../x"',
            1,
            r"frames_dir '(\.\./){3}x' is not a path inside",
        ),
        ("width = 64", "width = 4", 0, r"\(front\): camera\.width = 4 is out of range"),
        ('model = "pinhole"', 'model = "orthographic"', 0, r"\(front\): camera\.model must be"),
    ],
)
def test_cameras_table_rejections(broken: Path, old: str, new: str, k: int, problem: str) -> None:
    toml = broken / "scenario.toml"
    line = line_of(toml, r"\[\[cameras\]\]", k)
    text = toml.read_text()
    at = [m.start() for m in re.finditer(r"\[\[cameras\]\]", text)][k]
    assert old in text[at:]
    toml.write_text(text[:at] + text[at:].replace(old, new, 1))
    with pytest.raises(
        ScenarioError, match=rf"scenario\.toml: line {line}: \[\[cameras\]\] {k + 1}.*{problem}"
    ):
        load_rig(broken)


def test_top_level_frames_keys_and_files(broken: Path) -> None:
    toml = broken / "scenario.toml"
    edit(toml, 'description = "', 'frames_dir = "frames"\ndescription = "')
    with pytest.raises(
        ScenarioError, match=r"scenario\.toml: line 3: frames_dir is a \[\[cameras\]\] key"
    ):
        load_rig(broken)
    edit(toml, 'frames_dir = "frames"\n', "")
    shutil.copy(broken / "cameras/front/frames.csv", broken / "frames.csv")
    with pytest.raises(ScenarioError, match=r"/frames\.csv: a rig keeps frames\.csv in each"):
        load_rig(broken)


def test_no_cameras_and_not_tables(broken: Path) -> None:
    toml = broken / "scenario.toml"
    head = toml.read_text().split("[[cameras]]")[0]
    toml.write_text(head + "cameras = []\n")
    with pytest.raises(ScenarioError, match=r"a rig needs at least one camera"):
        load_rig(broken)
    toml.write_text(head + "cameras = [1, 2]\n")
    with pytest.raises(ScenarioError, match=r"cameras must be an array of tables"):
        load_rig(broken)


def test_truth_all_or_none(broken: Path) -> None:
    (broken / "cameras/rear/truth.csv").unlink()
    with pytest.raises(
        ScenarioError, match=r"cameras/rear/truth\.csv: missing \(cameras rear have no truth"
    ):
        load_rig(broken)


def test_per_camera_files_named_with_their_camera(broken: Path) -> None:
    frames = broken / "cameras/rear/frames.csv"
    lines = frames.read_text().splitlines()
    lines[3] = lines[3].split(",")[0] + "," + lines[2].split(",")[1]
    frames.write_text("\n".join(lines) + "\n")
    with pytest.raises(
        ScenarioError, match=r"cameras/rear/frames\.csv: line 4: t_us .* does not increase"
    ):
        load_rig(broken)


def test_per_camera_missing_frame_file(broken: Path) -> None:
    (broken / "cameras/front/frames/000005.png").unlink()
    with pytest.raises(
        ScenarioError,
        match=r"cameras/front/frames\.csv: line 7: frame 5 has no file .*cameras/front/frames/000005\.png",
    ):
        load_rig(broken)


def test_per_camera_truth_frame_out_of_range(broken: Path) -> None:
    truth = broken / "cameras/front/truth.csv"
    edit(truth, "\n9,", "\n10,")
    line = next(i + 1 for i, s in enumerate(truth.read_text().splitlines()) if s.startswith("10,"))
    with pytest.raises(
        ScenarioError, match=rf"cameras/front/truth\.csv: line {line}: frame 10 is not in"
    ):
        load_rig(broken)


@pytest.mark.slow  # 0.5 s: the CLI's imports
def test_cli_refuses_a_malformed_rig(
    broken: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    edit(broken / "scenario.toml", 'name = "rear"', 'name = "front"')
    rc = cli.main(["replay", str(broken), "--results", str(tmp_path / "r.csv"), "-q"])
    assert rc == 2
    assert "is already camera 1's" in capsys.readouterr().err
    assert not (tmp_path / "r.csv").exists()


# -- sim export --rig, replay and eval of a rig -----------------------------------------------
@pytest.mark.slow  # renders and replays a few hundred frames
def test_sim_export_rig_cli_and_force(tmp_path: Path) -> None:
    out = tmp_path / "q"
    argv = ["sim", "export", "T90", str(out), "--rig", "quad", "--duration", "0.3"]
    argv += ["--resolution", "64x48", "-q"]
    assert cli.main([*argv, "--camera", "pinhole"]) == 2  # a rig or a camera, not both
    assert not out.exists()
    assert cli.main(argv) == 0
    rig = load_rig(out)
    assert rig.camera_names == ["front", "right", "rear", "left"]
    assert [c.camera.mount_rpy_deg[2] for c in rig.cameras] == [0.0, 90.0, 180.0, -90.0]
    assert cli.main([*argv, "--force"]) == 0  # a rig this program wrote is replaced
    (out / "cameras" / "notes.txt").write_text("mine")
    assert cli.main([*argv, "--force"]) == 2  # ... but not with something else in it
    assert (out / "cameras" / "notes.txt").exists()


def crossing_rig(duration_s: float) -> SimulatedRig:
    """T90 through two 100° pinholes at yaw 45° ("fwd") and 135° ("aft"): the ball, at
    58°-118° right of the nose, starts in their 10° overlap (89°) and crosses it again at
    about 5.3 s."""
    w, h = 160, 120
    f = (w / 2) / math.tan(math.radians(50.0))
    cams = [
        (n, Pinhole(w, h, (0.0, 0.0, yaw), fx=f, fy=f, cx=w / 2, cy=h / 2))
        for n, yaw in (("fwd", 45.0), ("aft", 135.0))
    ]
    return SimulatedRig(make_scenario("T90", cams[0][1], duration_s=duration_s), cams)


@pytest.fixture(scope="module")
def crossing(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cross") / "T90-cross"
    export_rig(crossing_rig(7.0), out, progress=False)
    return out


@pytest.mark.slow  # replays 350 frames
def test_replay_of_a_rig(crossing: Path, tmp_path: Path) -> None:
    res = tmp_path / "r.csv"
    assert cli.main(["replay", str(crossing), "--results", str(res), "-q", "--check"]) == 0
    rows = list(csv.DictReader(res.open()))
    assert list(rows[0]) == RIG_RESULTS_HEADER
    assert {r["camera"] for r in rows} == {"fwd", "aft"}
    rig = load_rig(crossing)
    times = {n: c.frame_times_us for n, c in zip(rig.camera_names, rig.cameras)}
    for r in rows:  # frame and t_us are the measuring camera's
        assert times[r["camera"]][int(r["frame"])] == int(r["t_us"])
    t = [int(r["t_us"]) for r in rows]
    assert t == sorted(t)  # capture-time order across cameras
    # the ball is reported by both cameras over the flight (before and after the crossing)
    aft = [int(r["t_us"]) for r in rows if r["camera"] == "aft" and r["state"] != "unknown"]
    fwd = [int(r["t_us"]) for r in rows if r["camera"] == "fwd" and r["state"] != "unknown"]
    assert aft and fwd and min(aft) < min(fwd)


@pytest.mark.slow  # replays 350 frames
def test_eval_of_a_rig_per_camera_overall_and_handover(crossing: Path, tmp_path: Path) -> None:
    from tcm_companion.config import AppConfig
    from tcm_companion.eval.evaluate import summarize
    from tcm_companion.eval.rig import evaluate_rig, handover_text

    cfg = AppConfig()
    ev = evaluate_rig(load_rig(crossing), cfg, with_bsm=False)
    assert [e.name for e in ev.cameras] == ["T90/fwd", "T90/aft"]
    assert ev.overall.name == "T90/all"
    n_all = len(ev.overall.records)
    assert n_all == sum(len(e.records) for e in ev.cameras)
    tcm = {
        e.name: next(s for s in summarize(e.records, cfg.pipeline.classifier) if s.method == "tcm")
        for e in [*ev.cameras, ev.overall]
    }
    assert all(s.accuracy > 0.9 for s in tcm.values())  # T90: the ball moves
    # "aft" measures the ball from the start, "fwd" after the crossing (5.3 s of 7): its
    # young track is decided at once by a cross-camera pair (97% of its object-frames;
    # 31% with per-camera decisions only, RigTracker passing results through)
    assert all(s.coverage > 0.9 for s in tcm.values())
    # the ball (object 1) was measured by both cameras: one handover row, whose track ids
    # are exactly those of its matched records
    (row,) = ev.handover
    assert row.object_id == 1 and row.cameras == ("fwd", "aft")
    assert set(row.track_ids) == {r.track_id for r in ev.overall.records if r.matched}
    text = "\n".join(handover_text([ev]))
    assert f"object 1: cameras fwd, aft: {row.n_tracks} track id(s)" in text
    # object-frames: only those in a camera's view (never the ball behind "fwd")
    assert all(r.matched or r.object_id == 1 for r in ev.overall.records)


@pytest.mark.slow  # replays 350 frames
def test_the_crossing_ball_keeps_one_track_id(crossing: Path) -> None:
    """Issue 26's handover target: the ball that crosses from "aft" to "fwd" keeps one
    rig track id (RigTracker.fuse; with per-camera ids it got 4)."""
    from tcm_companion.config import AppConfig
    from tcm_companion.eval.rig import evaluate_rig

    ev = evaluate_rig(load_rig(crossing), AppConfig(), with_bsm=False)
    assert [h.n_tracks for h in ev.handover] == [1]


@pytest.mark.slow  # renders and replays a 2-second quad flight
def test_replay_of_the_quad_rig_t90(tmp_path: Path) -> None:
    """What the T90 ball gets on the quad rig: one track id, from the right camera alone
    (the ball stays 58°-118° right of the nose, inside that camera's 40°-140°)."""
    out, res = tmp_path / "q", tmp_path / "r.csv"
    argv = ["sim", "export", "T90", str(out), "--rig", "quad", "--duration", "2"]
    assert cli.main([*argv, "--resolution", "160x120", "-q"]) == 0
    assert cli.main(["replay", str(out), "--results", str(res), "-q"]) == 0
    rows = list(csv.DictReader(res.open()))
    assert len(rows) == 50  # the ball in each of the 50 frames of the right camera
    assert {(r["camera"], r["track_id"]) for r in rows} == {("right", "1")}


@pytest.mark.slow  # renders and evaluates a 2-second quad flight
def test_eval_sim_rig_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "ev"
    assert cli.main(["eval", "--rig", "quad", "--out", str(out)]) == 2  # --rig needs --sim
    assert "argument --rig: it needs --sim" in capsys.readouterr().err
    argv = ["eval", "--sim", "T90", "--rig", "quad", "--duration", "2", "--no-bsm", "-q"]
    assert cli.main([*argv, "--camera", "pinhole", "--out", str(out)]) == 2
    assert cli.main([*argv, "--resolutions", "160x120", "--out", str(out)]) == 0
    report = (out / "report.txt").read_text()
    for name in ("T90/front", "T90/right", "T90/rear", "T90/left", "T90/all"):
        assert f"\n{name} " in report
    # on the quad rig T90's ball stays 58°-118° right of the nose: the right camera alone
    assert "Camera rigs: handover" in report
    assert "T90: no object was measured by two cameras or more" in report


def test_unsynchronised_cameras_replay_in_capture_time_order(tiny_rig: Path) -> None:
    """Cameras with their own frame times (rear 13 ms after front, at another rate) are
    processed in capture-time order across the rig, each frame with its own index."""
    from tcm_companion.config import AppConfig
    from tcm_companion.replay.rig import RigReplay

    rig = load_rig(tiny_rig)
    rear = rig.cameras[1]
    rear.frame_times_us = rear.frame_times_us[::2] + 13_000  # a camera at half the rate
    rear.truth = None
    rear.iter_frames = lambda: (  # type: ignore[method-assign]
        (i, int(t), rear.read_frame(2 * i)) for i, t in enumerate(rear.frame_times_us)
    )
    replay = RigReplay(rig.cameras, rig.telemetry, AppConfig())
    got = [(f.camera_id, f.raw.frame_index, f.raw.t_us) for f in replay.frames()]
    assert len(got) == 10 + 5
    assert [t for _, _, t in got] == sorted(t for _, _, t in got)
    assert [i for k, i, _ in got if k == 1] == list(range(5))
    assert [t for k, _, t in got if k == 1] == [int(t) for t in rear.frame_times_us]
    assert replay.tracker is not None  # two cameras: the rig tracker


def test_a_camera_as_a_video(broken: Path) -> None:
    import cv2

    rear = broken / "cameras/rear"
    writer = cv2.VideoWriter(str(rear / "rear.avi"), cv2.VideoWriter.fourcc(*"MJPG"), 25, SMALL)
    for p in sorted((rear / "frames").iterdir()):
        img = cv2.imread(str(p))
        assert img is not None
        writer.write(img)
    writer.release()
    shutil.rmtree(rear / "frames")
    edit(
        broken / "scenario.toml", 'dir = "cameras/rear"', 'dir = "cameras/rear"\nvideo = "rear.avi"'
    )
    rig = load_rig(broken)
    cam = rig.cameras[1]
    assert cam.video == rear / "rear.avi" and cam.frames_dir is None
    frames = list(cam.iter_frames())
    assert len(frames) == 10 and frames[0][2].shape == (SMALL[1], SMALL[0], 3)


def test_a_rig_through_a_flight_log_and_back(tiny_rig: Path, tmp_path: Path) -> None:
    """import writes every camera of a rig to the log (camera{k}, its names in the
    metadata), export of a log of two cameras writes the rig back: the same cameras,
    times and (PNG) frames; --camera-id N exports that camera alone."""
    from tcm_companion.logtools.convert import (
        LogConversionError,
        log_to_scenario,
        scenario_to_log,
    )

    log = tmp_path / "rig.mcap"
    summary = scenario_to_log(tiny_rig, log)
    assert summary.frames == 20
    back = log_to_scenario(log, tmp_path / "back", camera_id=None)
    assert back.cameras == ["front", "rear"] and back.frames == 20
    want, got = load_rig(tiny_rig), load_rig(tmp_path / "back")
    assert got.camera_names == want.camera_names
    assert len(got.telemetry) == len(want.telemetry)
    for a, b in zip(want.cameras, got.cameras):
        assert a.camera == b.camera
        assert np.array_equal(a.frame_times_us, b.frame_times_us)
        for (_, _, ia), (_, _, ib) in zip(a.iter_frames(), b.iter_frames()):
            assert np.array_equal(ia, ib)
    one = log_to_scenario(log, tmp_path / "one", camera_id=1)
    assert one.cameras == [] and one.frames == 10
    rear = load_scenario(tmp_path / "one")
    assert np.array_equal(rear.frame_times_us, want.cameras[1].frame_times_us)
    with pytest.raises(LogConversionError, match="a camera rig is imported without --results"):
        scenario_to_log(tiny_rig, tmp_path / "r.mcap", results=True)
