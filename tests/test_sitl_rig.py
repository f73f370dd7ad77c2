"""SITL with a camera rig (issue 26): ``sitl --rig``, the rig scenarios (PASS, OVERLAP,
CAMLOSS), scoring per camera and the handover figure, a dying camera, the flight log of
every camera; the panorama default unchanged.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tcm_companion.cli import build_parser
from tcm_companion.config import AppConfig
from tcm_companion.core.frames import normalize
from tcm_companion.io.cameras.base import CameraError, CameraGone, FrameSource
from tcm_companion.sim.scene.cameras import RIGS, rig_cameras
from tcm_companion.sim.scene.names import CAMERA_LOSS, RIG_SCENARIO_NAMES, SCENARIO_NAMES
from tcm_companion.sim.scene.scenarios import flight_plan
from tcm_companion.sim.scene.truth_camera import DyingCamera
from tcm_companion.sim.vehicle.mock_autopilot import MockAutopilot
from tcm_companion.sitl.mock_flight import SitlReport, _mock_config, run_sitl_virtual
from tcm_companion.sitl.virtual import VIRTUAL_START_MONO_US, VIRTUAL_UNIX_US_AT_START

from .numerics import numeric_kind


def _seen_by(name: str, rig: str, t_s: float) -> list[str]:
    """Per object of scenario ``name`` at ``t_s``: the rig cameras whose image holds its
    centre, joined with "+" ("-": none)."""
    plan = flight_plan(name)
    pos = plan.vehicle.position_ned_m(t_s)
    R = plan.vehicle.R_ned_from_body(t_s)
    out = []
    for obj in plan.objects:
        b = normalize(obj.centre_ned_m(t_s) - pos)
        seen = []
        for cam_name, cam in rig_cameras(rig):
            px = cam.pixel_from_bearing_cam((R @ cam.R_body_from_cam).T @ b)
            if np.all(np.isfinite(px)) and bool(cam.in_image(px)):
                seen.append(cam_name)
        out.append("+".join(seen) or "-")
    return out


# -- the scenarios, from the truth alone (no rendering) ------------------------------------
def test_pass_crosses_from_the_front_view_into_the_right_and_the_rear() -> None:
    assert set(RIG_SCENARIO_NAMES) <= set(SCENARIO_NAMES)
    views = [_seen_by("PASS", "quad", t)[0] for t in np.arange(0.0, 10.0, 0.1)]
    # In order, each for a while: front, the front/right overlap, right, right/rear, rear.
    runs = [v for i, v in enumerate(views) if i == 0 or v != views[i - 1]]
    assert runs == ["front", "front+right", "right", "right+rear", "rear"], runs
    assert views.count("front+right") >= 3 and views.count("right") >= 20


def test_overlap_holds_its_ball_in_two_cameras_throughout() -> None:
    for t in np.arange(0.0, flight_plan("OVERLAP").duration_s, 0.25):
        assert _seen_by("OVERLAP", "quad", t) == ["front+right"], t
        assert _seen_by("OVERLAP", "front-right", t) == ["front+right"], t


def test_camloss_has_one_object_per_camera_and_loses_the_front_one() -> None:
    assert CAMERA_LOSS["CAMLOSS"][0] == "front"
    for rig in ("quad", "front-back"):
        for t in np.arange(0.0, 16.0, 0.5):
            assert _seen_by("CAMLOSS", rig, t) == ["front", "rear"], (rig, t)


def test_an_object_is_scored_in_the_camera_nearest_its_axis() -> None:
    from tcm_companion.io.scoring import Handover, view_camera

    cams = [c for _, c in rig_cameras("quad")]
    level = np.eye(3)

    def at(az_deg: float) -> np.ndarray:
        a = math.radians(az_deg)
        return 5.0 * np.array([math.cos(a), math.sin(a), 0.0])

    assert [view_camera(cams, level, at(a)) for a in (0, 44, 46, 90, 180, -90)] == [
        0,
        0,
        1,
        1,
        2,
        3,
    ]
    assert view_camera(cams[:1], level, at(120)) == -1  # outside the one camera
    yawed = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # nose east
    assert view_camera(cams, yawed, at(90)) == 0
    h = Handover()
    for cam, tid in ((0, 7), (0, 7), (1, 7)):
        h.add("ball", cam, tid)
    h.add("box", 1, 3)
    h.add("box", 2, None)  # in view, unmatched
    h.add("box", 2, 4)
    h.add("tree", 0, 1)
    assert h.figure() == {"ball": 1, "box": 2}


def test_the_sitl_command_takes_a_rig() -> None:
    parser = build_parser()
    assert parser.parse_args(["sitl", "--rig", "quad"]).rig == "quad"
    assert parser.parse_args(["sitl"]).rig is None  # the configuration's cameras
    assert set(RIGS) >= {"panorama", "quad", "front-back", "front-right"}
    with pytest.raises(SystemExit):
        parser.parse_args(["sitl", "--rig", "hexa"])


# -- a camera that dies -----------------------------------------------------------------
class _Ticker(FrameSource):
    def __init__(self, clock: list[int]) -> None:
        super().__init__("ticker", 4, 3)
        self.clock = clock

    def open(self) -> None:
        pass

    def read(self) -> tuple[np.ndarray | None, int | None]:
        self.clock[0] += 40_000
        return np.zeros((3, 4, 3), np.uint8), self.clock[0]

    def close(self) -> None:
        pass


def test_a_dying_camera_stops_at_its_instant_and_never_opens_again() -> None:
    clock = [0]
    cam = DyingCamera(_Ticker(clock), 100_000, lambda: clock[0])
    cam.open()
    assert cam.read()[1] == 40_000 and cam.read()[1] == 80_000
    with pytest.raises(CameraGone):
        cam.read()  # the frame at 120 ms is past the instant: not delivered
    with pytest.raises(CameraError):
        cam.open()


# -- virtual-time flights -----------------------------------------------------------------
def _config(scenario: str, brake: bool = True) -> AppConfig:
    cfg = AppConfig()
    return dataclasses.replace(
        cfg, sim=dataclasses.replace(cfg.sim, scenario=scenario, brake_on_collision=brake)
    )


def _fly(
    tmp_path: Path, scenario: str, rig: str, duration_s: float, brake: bool = True, **kw: Any
) -> tuple[SitlReport, MockAutopilot]:
    cfg = _config(scenario, brake)
    mock = MockAutopilot(_mock_config(cfg, VIRTUAL_UNIX_US_AT_START), VIRTUAL_START_MONO_US)
    report = run_sitl_virtual(
        cfg,
        duration_s=duration_s,
        rig=rig,
        mock=mock,
        state_dir=str(tmp_path / "state"),
        min_accuracy=None,
        **kw,
    )
    return report, mock


def _statuses(mock: MockAutopilot, since_s: float = 0.0) -> list[Any]:
    """The TCM_OBJECT_STATUS messages the mock received ``since_s`` into the run."""
    t0 = VIRTUAL_START_MONO_US + round(since_s * 1e6)
    return [
        r.msg
        for r in mock.received_status
        if r.name == "TCM_OBJECT_STATUS" and r.recv_us >= t0 and r.ok
    ]


#: The results digest of a 6-s virtual T90 flight of the default panorama, recorded on
#: main before rigs came in (f5cc45e), per machine kind (tests/numerics.py).
PANORAMA_T90_6S_SHA256 = {"Haswell X86_V3": "e6b747c7288cdd83"}


@pytest.mark.slow  # a 6-s virtual flight
def test_the_panorama_default_is_unchanged(tmp_path: Path) -> None:
    kind = numeric_kind()
    if kind not in PANORAMA_T90_6S_SHA256:
        pytest.skip(f"digest recorded on {sorted(PANORAMA_T90_6S_SHA256)}, this is {kind}")
    report = run_sitl_virtual(AppConfig(), duration_s=6.0, state_dir=str(tmp_path))
    assert report.results_sha256.startswith(PANORAMA_T90_6S_SHA256[kind]), report.lines()
    assert report.camera_names == ("camera0",) and not report.camera_scores
    assert not [x for x in report.lines() if "camera " in x or "handover" in x]


@pytest.fixture(scope="module")
def pass_flight(tmp_path_factory: pytest.TempPathFactory) -> tuple[SitlReport, MockAutopilot]:
    """PASS on the quad rig for 5 s (the ball crosses from the front camera to the right
    one at 2.7-3.3 s), without the mock's brake (the vehicle flies on past the ball)."""
    return _fly(tmp_path_factory.mktemp("pass"), "PASS", "quad", 5.0, brake=False)


@pytest.mark.slow  # a 5-s virtual flight of four cameras
def test_a_quad_rig_runs_one_camera_per_rig_camera(
    pass_flight: tuple[SitlReport, MockAutopilot],
) -> None:
    report, mock = pass_flight
    s = report.summary
    assert report.camera_names == ("front", "right", "rear", "left")
    assert sorted(s.camera_stats) == ["sim-front", "sim-left", "sim-rear", "sim-right"]
    for stats in s.camera_stats.values():  # every camera at 25 Hz
        assert stats.delivered >= 5.0 * 25 - 3
    assert s.frames_balance and report.ok, report.lines()
    front, right, rear, left = report.camera_scores
    assert front.matched > 40 and right.matched > 20, report.lines()
    assert rear.truth_frames == left.truth_frames == 0
    assert report.score.truth_frames == sum(c.truth_frames for c in report.camera_scores)
    # The statuses on the wire name the camera the ball was measured in: both of them.
    cams = Counter(int(m.camera_id) for m in _statuses(mock))
    assert cams[0] > 20 and cams[1] > 10, cams
    text = "\n".join(report.lines())
    assert "camera front:" in text and "handover:" in text


@pytest.mark.slow
def test_the_crossing_ball_keeps_one_track_id(
    pass_flight: tuple[SitlReport, MockAutopilot],
) -> None:
    report, mock = pass_flight
    assert report.handover == {0: 1}, report.lines()
    # On the wire: the right camera's first status carries the id the front one used, and
    # is decided (the history came along: a cross-camera pair, no warm-up again).
    statuses = _statuses(mock)
    first_right = next(m for m in statuses if m.camera_id == 1)
    front_ids = {int(m.track_id) for m in statuses if m.camera_id == 0}
    assert int(first_right.track_id) in front_ids, (first_right, front_ids)
    assert first_right.state != 0, first_right


@pytest.mark.slow
def test_the_crossing_ball_raises_no_collision_alarm(
    pass_flight: tuple[SitlReport, MockAutopilot],
) -> None:
    from tcm_companion.sim.vehicle.mock_checks import collision_alarm

    _, mock = pass_flight
    alarms = [m for m in _statuses(mock) if collision_alarm(m, mock.config.brake_ttc_s)]
    assert not alarms, [(m.camera_id, m.track_id, m.ttc) for m in alarms[:5]]


@pytest.fixture(scope="module")
def overlap_flight(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[SitlReport, MockAutopilot]:
    """OVERLAP on the front-right rig for 3 s, without the brake (the ball stays at 45°)."""
    return _fly(tmp_path_factory.mktemp("overlap"), "OVERLAP", "front-right", 3.0, brake=False)


@pytest.mark.slow  # a 3-s virtual flight of two cameras
def test_the_overlap_ball_is_scored_once_per_cycle(
    overlap_flight: tuple[SitlReport, MockAutopilot],
) -> None:
    report, _ = overlap_flight
    assert report.ok, report.lines()
    # One object-frame per cycle (not one per camera), in the camera nearer its axis.
    assert 2.9 * 25 <= report.score.truth_frames <= 3.0 * 25 + 1
    sc = report.score
    assert sc.scored >= 0.9 * sc.truth_after_warmup > 0, report.lines()  # matched, after 1 s


@pytest.mark.slow
def test_the_overlap_ball_gets_one_status_per_cycle(
    overlap_flight: tuple[SitlReport, MockAutopilot],
) -> None:
    _, mock = overlap_flight
    per_cycle = Counter(int(m.time_boot_ms) for m in _statuses(mock) if m.state != 0)
    assert per_cycle and max(per_cycle.values()) == 1, per_cycle.most_common(3)


@pytest.mark.slow  # a 7-s virtual flight of two cameras
def test_a_dying_camera_makes_only_its_objects_unknown(tmp_path: Path) -> None:
    """CAMLOSS on the front-back rig, the front camera dying 4 s in: its ball (ahead) is
    sent unknown once the input is stale and then no more; the rear camera's ball goes on
    being decided."""
    dies_s = 4.0
    report, mock = _fly(tmp_path, "CAMLOSS", "front-back", 7.5, camera_loss=("front", dies_s))
    s = report.summary
    assert s.faults.get("front stale") == 1, s.faults
    assert "rear stale" not in s.faults and "rear slow" not in s.faults, s.faults
    assert s.camera_stats["sim-front"].read_errors >= 1
    before = _statuses(mock)
    front_before = [m for m in before if m.camera_id == 0]
    assert any(m.state != 0 for m in front_before), "the front ball was never decided"
    # After the loss (and the stale input's timeout): from the front camera nothing but
    # "unknown"; from the rear one decisions, as before.
    after = _statuses(mock, since_s=dies_s + 0.5)
    front_after = [m for m in after if m.camera_id == 0]
    rear_after = [m for m in after if m.camera_id == 1]
    assert front_after, "the front ball was never sent unknown"
    assert all(m.state == 0 for m in front_after), Counter(m.state for m in front_after)
    assert sum(m.state != 0 for m in rear_after) >= 25, Counter(m.state for m in rear_after)
    rear = report.camera_scores[1]
    assert rear.decided > 0 and rear.accuracy >= 0.9, report.lines()
    assert not math.isnan(report.score.accuracy)


@pytest.mark.slow  # a 1.5-s virtual flight of four cameras with the flight log
def test_a_quad_flight_log_holds_every_camera(tmp_path: Path) -> None:
    from tcm_companion.flightlog.reader import read_log, read_metadata

    report = run_sitl_virtual(
        AppConfig(),
        duration_s=1.5,
        rig="quad",
        state_dir=str(tmp_path / "state"),
        log_dir=str(tmp_path / "log"),
        min_accuracy=None,
    )
    assert report.log is not None and report.log.frames_logged > 4 * 30, report.lines()
    topics = Counter(r.topic for r in read_log(tmp_path / "log"))
    for cid in range(4):
        assert topics[f"/camera{cid}/image"] >= 30, topics
    meta = read_metadata(tmp_path / "log")
    assert meta["cameras"] == '["front", "right", "rear", "left"]'


_TWO_CAMERAS = """
[[cameras]]
name = "fwd"
model = "pinhole"
width = 320
height = 240
fx = 134.3
fy = 134.3
cx = 160.0
cy = 120.0
dist = [0.0, 0.0, 0.0, 0.0, 0.0]
fps = 10

[[cameras]]
name = "starboard"
model = "pinhole"
width = 320
height = 240
fx = 134.3
fy = 134.3
cx = 160.0
cy = 120.0
dist = [0.0, 0.0, 0.0, 0.0, 0.0]
mount_rpy_deg = [0.0, 0.0, 90.0]
fps = 10
"""


@pytest.mark.slow  # the CLI in a subprocess, a 2-s flight of two cameras
def test_sitl_flies_the_configured_cameras_without_rig(tmp_path: Path) -> None:
    """No ``--rig``: a configuration of two ``[[cameras]]`` is flown as its rig (names,
    lenses and frame rates from the file)."""
    import os
    import subprocess
    import sys

    cfg = tmp_path / "rig.toml"
    cfg.write_text(_TWO_CAMERAS)
    env = {**os.environ, "XDG_STATE_HOME": str(tmp_path / "state")}
    env.pop("STATE_DIRECTORY", None)
    args = ["--config", str(cfg), "--duration", "2", "--min-accuracy", "0"]
    run = subprocess.run(
        [sys.executable, "-m", "tcm_companion", "sitl", "--clock", "virtual", *args],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
        env=env,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "  camera fwd: " in run.stdout and "  camera starboard: " in run.stdout, run.stdout
    # 10 fps each, two cameras: about 40 frames in 2 s (not 2 x 50).
    frames = next(x for x in run.stdout.splitlines() if x.startswith("  frames:"))
    captured = int(frames.split("captured ")[1].split()[0])
    assert 36 <= captured <= 42, frames


@pytest.mark.slow  # a 3-s virtual flight of two cameras, logged losslessly, and its replay
def test_a_rig_flight_log_replays_to_exactly_the_logged_results(tmp_path: Path) -> None:
    """``replay LOG`` of a rig's SITL flight: every camera's frames through one Companion
    (its RigTracker), the same results as logged, bit for bit."""
    from tcm_companion.replay.log import compare, replay_log

    cfg = _config("PASS", brake=False)
    cfg = dataclasses.replace(cfg, logging=dataclasses.replace(cfg.logging, image_format="png"))
    report = run_sitl_virtual(
        cfg,
        duration_s=3.0,
        rig="front-right",
        state_dir=str(tmp_path / "state"),
        log_dir=str(tmp_path / "log"),
        min_accuracy=None,
    )
    assert report.ok and report.log is not None, report.lines()
    frames = list(replay_log(tmp_path / "log"))
    assert len(frames) == report.summary.processed
    assert {f.camera_id for f in frames} == {0, 1}
    assert [d for f in frames for d in compare(f)] == []
    assert any(o.state != "unknown" for f in frames for o in f.result.objects)


def test_the_scenarios_camera_loss_needs_that_camera(caplog: pytest.LogCaptureFixture) -> None:
    from tcm_companion.sitl.mock_flight import _camera_loss

    cfg = _config("CAMLOSS")
    assert _camera_loss(cfg, "quad", "scenario") == ("front", 8.0)
    assert _camera_loss(cfg, "panorama", "scenario") is None
    assert _camera_loss(cfg, "quad", None) is None
    assert _camera_loss(cfg, "quad", ("rear", 2.0)) == ("rear", 2.0)
    assert _camera_loss(_config("PASS"), "quad", "scenario") is None
    with caplog.at_level("WARNING"):
        assert _camera_loss(cfg, "config", "scenario") is None  # one camera, "camera0"
    assert "no camera dies" in caplog.text
