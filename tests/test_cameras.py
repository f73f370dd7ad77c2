"""One contract suite over every camera source that runs here, read through CameraReader.

python-can's ``test/back2back_test.py`` idea: the same tests run over a real video file
(MJPG written with ``cv2.VideoWriter``), a directory of PNGs, a vendored example
scenario, the simulator, the dual-fisheye rig (two frame directories and the real
stitcher) and an in-test live source that can be told to fail. Pacing is measured on an
injected fake clock whose ``sleep`` advances it, never on wall time; only ``stop()``'s
promptness and the backoff lower bounds use the real clock.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from tcm_companion.core.camera import Equirectangular, Fisheye, Pinhole
from tcm_companion.io.aio import monotonic_us
from tcm_companion.io.cameras import (
    CameraError,
    CameraGone,
    CameraReader,
    EndOfStream,
    Frame,
    FrameSource,
)
from tcm_companion.io.cameras.base import Pacer
from tcm_companion.io.cameras.dual_fisheye import DualFisheyeSource, Stitcher
from tcm_companion.io.cameras.frames_dir import FramesDirSource
from tcm_companion.io.cameras.opencv import (
    GStreamerSource,
    OpenCVDevice,
    VideoFileSource,
    gstreamer_available,
)
from tcm_companion.io.cameras.scenario_source import ScenarioSource
from tcm_companion.io.cameras.settings import (
    CameraSourceConfig,
    FisheyeCameraConfig,
    open_source,
)
from tcm_companion.sim.scene.truth_camera import SimulatedCamera
from tcm_companion.sim.sources import register_sim_sources

from .helpers import example_path

W, H = 64, 48  # video / frames-directory test images
FPS = 25.0
PERIOD_US = 40_000
SIM_CAMERA = Equirectangular(width=120, height=74)
FISHEYE_PX = 64
PANORAMA = Equirectangular(width=72, height=44)


# --------------------------------------------------------------------------------------
# Test doubles
# --------------------------------------------------------------------------------------
class FakeClock:
    """Monotonic µs clock whose ``sleep`` advances it (never sleeps for real)."""

    def __init__(self, start_us: int = 1_000_000_000) -> None:
        self.now_us = start_us
        self.sleeps: list[float] = []
        self._lock = threading.Lock()

    def clock(self) -> int:
        with self._lock:
            return self.now_us

    def sleep(self, seconds: float) -> None:
        with self._lock:
            self.sleeps.append(seconds)
            self.now_us += round(seconds * 1e6)

    def advance(self, us: int) -> None:
        with self._lock:
            self.now_us += us


def _image(i: int, w: int, h: int) -> np.ndarray:
    """A non-zero BGR test image that differs per frame."""
    img = np.zeros((h, w, 3), np.uint8)
    img[..., 0] = np.linspace(20, 230, w, dtype=np.uint8)[None, :]
    img[..., 1] = np.linspace(20, 230, h, dtype=np.uint8)[:, None]
    img[..., 2] = (40 + 17 * i) % 200 + 20
    return img


class FakeLive(FrameSource):
    """A live camera driven by a script of what each ``open()`` and ``read()`` does.

    read actions: "ok", "none", "empty" (0×0), "zeros", "small" (wrong size), "gray"
    (2-D), "float" (wrong dtype), "gone" (CameraGone), "boom" (RuntimeError), "end",
    "block" (waits until interrupt()), "stuck" (ignores interrupt(); waits for release).
    After the script: "ok" forever. ``times``: "none" lets the reader stamp the time,
    "clock" stamps with the clock, "same" returns one constant time (to be retimed).
    """

    def __init__(
        self,
        reads: list[str] | None = None,
        opens: list[bool] | None = None,
        *,
        clock: FakeClock | None = None,
        times: str = "clock",
        width: int = 32,
        height: int = 24,
    ) -> None:
        super().__init__("fake", width, height)
        self.reads = list(reads or [])
        self.opens = list(opens or [])
        self.fake = clock
        self.times = times
        self.is_open = False
        self.open_calls: list[float] = []  # time.monotonic() of each open()
        self.close_calls = 0
        self.n = 0
        self._interrupted = threading.Event()
        self.release = threading.Event()
        self.blocked = threading.Event()

    def open(self) -> None:
        self.open_calls.append(time.monotonic())
        if self.opens and not self.opens.pop(0):
            raise CameraError("fake: no such camera")
        self.is_open = True

    def read(self) -> tuple[np.ndarray | None, int | None]:
        assert self.is_open, "read() on a closed source"
        action = self.reads.pop(0) if self.reads else "ok"
        if self.fake is not None:
            self.fake.sleep(PERIOD_US / 1e6)
        now = self.fake.clock() if self.fake is not None else monotonic_us()
        t = {"none": None, "clock": now, "same": 5_000_000}[self.times]
        self.n += 1
        if action == "ok":
            return _image(self.n, self.width, self.height), t
        if action == "none":
            return None, t
        if action == "empty":
            return np.zeros((0, 0, 3), np.uint8), t
        if action == "zeros":
            return np.zeros((self.height, self.width, 3), np.uint8), t
        if action == "small":
            return _image(self.n, self.width // 2, self.height), t
        if action == "gray":
            return np.full((self.height, self.width), 7, np.uint8), t
        if action == "float":
            return np.ones((self.height, self.width, 3), np.float32), t
        if action == "gone":
            raise CameraGone("fake: unplugged")
        if action == "boom":
            raise RuntimeError("fake: driver bug")
        if action == "end":
            raise EndOfStream("fake: done")
        if action == "block":
            self.blocked.set()
            self._interrupted.wait(30.0)
            return None, t
        if action == "stuck":
            self.blocked.set()
            self.release.wait(30.0)
            return None, t
        raise AssertionError(action)

    def interrupt(self) -> None:
        self._interrupted.set()

    def close(self) -> None:
        self.is_open = False
        self.close_calls += 1


class StandInStitcher:
    """Used only if ``stitch.FisheyeStitcher`` is not importable: tiles the two images."""

    def __init__(self, front: Fisheye, back: Fisheye, panorama: Equirectangular) -> None:
        self.front, self.back, self.panorama = front, back, panorama

    def stitch(self, front_bgr: np.ndarray, back_bgr: np.ndarray) -> np.ndarray:
        both = np.hstack([front_bgr, back_bgr])
        return cv2.resize(both, (self.panorama.width, self.panorama.height))


def _lenses() -> tuple[Fisheye, Fisheye]:
    f = FISHEYE_PX / np.pi  # equidistant, 180° across the image
    common: dict[str, Any] = dict(width=FISHEYE_PX, height=FISHEYE_PX, fx=f, fy=f, cx=32.0, cy=32.0)
    front = Fisheye(**common, dist=(0.0, 0.0, 0.0, 0.0))
    back = Fisheye(**common, dist=(0.0, 0.0, 0.0, 0.0), mount_rpy_deg=(0.0, 0.0, 180.0))
    return front, back


def _stitcher() -> Stitcher:
    front, back = _lenses()
    try:
        from tcm_companion.io.cameras.stitch import FisheyeStitcher
    except ImportError:
        return StandInStitcher(front, back, PANORAMA)
    return FisheyeStitcher(front, back, PANORAMA)


# --------------------------------------------------------------------------------------
# Real files
# --------------------------------------------------------------------------------------
def write_video(path: Path, n: int, w: int = W, h: int = H, fps: float = FPS) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), fps, (w, h))
    assert writer.isOpened(), "this OpenCV cannot write MJPG/AVI"
    for i in range(n):
        writer.write(_image(i, w, h))
    writer.release()
    return path


def write_frames(directory: Path, n: int, w: int = W, h: int = H) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        assert cv2.imwrite(str(directory / f"{i}.png"), _image(i, w, h))
    return directory


def _fixed_truth(t_us: int) -> tuple[float, np.ndarray, np.ndarray]:
    """The vehicle hovering 2 m up at the origin, level, facing north."""
    return 1.0, np.array([0.0, 0.0, -2.0]), np.eye(3)


# --------------------------------------------------------------------------------------
# The contract cases
# --------------------------------------------------------------------------------------
@dataclass
class Case:
    kind: str
    make: Callable[[FakeClock | None, bool], FrameSource]  # (fake clock or real, realtime)
    n_frames: int | None  # finite sources: frames they hold; live: None
    shape: tuple[int, int, int]
    spacing_us: np.ndarray | None = None  # expected t_capture differences (default 40 ms)


def _clock_kw(fake: FakeClock | None) -> dict[str, Any]:
    return {} if fake is None else {"clock_us": fake.clock, "sleep": fake.sleep}


@pytest.fixture(scope="module")
def media(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("media")
    return {
        "video": write_video(root / "clip.avi", 12),
        "frames": write_frames(root / "frames", 10),
        "front": write_frames(root / "front", 8, FISHEYE_PX, FISHEYE_PX),
        "back": write_frames(root / "back", 8, FISHEYE_PX, FISHEYE_PX),
    }


def _cases(media: dict[str, Path]) -> dict[str, Case]:
    scenario_dir = example_path("EX-PINHOLE")
    scn_times = ScenarioSource(scenario_dir).scenario.frame_times_us

    def video(fake: FakeClock | None, rt: bool) -> FrameSource:
        return VideoFileSource(media["video"], W, H, realtime=rt, **_clock_kw(fake))

    def frames(fake: FakeClock | None, rt: bool) -> FrameSource:
        return FramesDirSource(media["frames"], W, H, realtime=rt, fps=FPS, **_clock_kw(fake))

    def scenario(fake: FakeClock | None, rt: bool) -> FrameSource:
        return ScenarioSource(scenario_dir, realtime=rt, **_clock_kw(fake))

    def sim(fake: FakeClock | None, rt: bool) -> FrameSource:
        return SimulatedCamera(SIM_CAMERA, "T90", _fixed_truth, fps=FPS, **_clock_kw(fake))

    def dual(fake: FakeClock | None, rt: bool) -> FrameSource:
        kw = _clock_kw(fake)
        px = FISHEYE_PX
        front = FramesDirSource(media["front"], px, px, realtime=rt, name="front", **kw)
        back = FramesDirSource(media["back"], px, px, realtime=rt, name="back", **kw)
        return DualFisheyeSource(front, back, _stitcher())

    def fake_live(fake: FakeClock | None, rt: bool) -> FrameSource:
        return FakeLive(clock=fake)

    return {
        "video": Case("video", video, 12, (H, W, 3)),
        "frames": Case("frames", frames, 10, (H, W, 3)),
        "scenario": Case("scenario", scenario, len(scn_times), (480, 640, 3), np.diff(scn_times)),
        "sim": Case("sim", sim, None, (SIM_CAMERA.height, SIM_CAMERA.width, 3)),
        "dual_fisheye": Case("dual_fisheye", dual, 8, (PANORAMA.height, PANORAMA.width, 3)),
        "fake_live": Case("fake_live", fake_live, None, (24, 32, 3)),
    }


KINDS = ("video", "frames", "scenario", "sim", "dual_fisheye", "fake_live")
FINITE = ("video", "frames", "scenario", "dual_fisheye")


@pytest.fixture(params=KINDS)
def case(request: pytest.FixtureRequest, media: dict[str, Path]) -> Case:
    return _cases(media)[request.param]


@dataclass
class Run:
    reader: CameraReader
    frames: list[Frame]
    delivered_at_us: list[int]  # fake clock when on_frame ran
    states: list[str]


def run_reader(
    source: FrameSource,
    *,
    n: int | None = None,
    fake: FakeClock | None = None,
    timeout_s: float = 10.0,
    until: Callable[[CameraReader], bool] | None = None,
    **kwargs: Any,
) -> Run:
    """Run a reader until the source ends, ``n`` frames arrived or ``until`` holds; stop it."""
    frames: list[Frame] = []
    at: list[int] = []
    states: list[str] = []

    def on_frame(frame: Frame) -> None:
        frames.append(frame)
        at.append(fake.clock() if fake is not None else monotonic_us())

    if fake is not None:
        kwargs.setdefault("clock_us", fake.clock)
    reader = CameraReader(
        source,
        7,
        on_frame,
        on_state=lambda name, state: states.append(state),
        **kwargs,
    )
    reader.start()
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and reader.alive:
        if n is not None and len(frames) >= n:
            break
        if until is not None and until(reader):
            break
        time.sleep(0.002)
    assert reader.stop(1.0), "reader thread did not finish"
    return Run(reader, frames, at, states)


def check_counters(reader: CameraReader) -> None:
    s = reader.stats
    assert s.captured == s.delivered + s.rejected_empty + s.rejected_size


# --------------------------------------------------------------------------------------
# The contract
# --------------------------------------------------------------------------------------
def test_contract_frames(case: Case) -> None:
    """Right shape and dtype, consecutive seq, strictly increasing capture times, counters
    adding up; finite sources deliver every frame once and end."""
    fake = FakeClock()
    run = run_reader(case.make(fake, True), n=None if case.n_frames else 6, fake=fake)
    frames = run.frames
    assert frames, "no frame delivered"
    for f in frames:
        assert f.camera_id == 7
        assert f.image.shape == case.shape and f.image.dtype == np.uint8
    assert [f.seq for f in frames] == list(range(len(frames)))
    times = np.array([f.t_capture_us for f in frames])
    assert np.all(np.diff(times) > 0)
    check_counters(run.reader)
    stats = run.reader.stats
    assert stats.rejected_empty == stats.rejected_size == stats.read_errors == 0
    assert stats.retimed == 0
    assert run.states[0] == "open"
    assert run.reader.last_frame_us == frames[-1].t_capture_us
    if case.n_frames is not None:
        assert stats.ended and stats.delivered == case.n_frames == len(frames)
        assert run.states[-1] == "ended" and run.reader.state == "ended"
    else:
        assert not stats.ended
    assert not run.reader.alive


def test_contract_realtime_pacing(case: Case) -> None:
    """Paced at ~fps on the injected clock: capture times on the schedule, and no frame
    handed over before its capture time (the source waited for it)."""
    fake = FakeClock()
    run = run_reader(case.make(fake, True), n=None if case.n_frames else 8, fake=fake)
    times = np.array([f.t_capture_us for f in run.frames])
    expected = case.spacing_us if case.spacing_us is not None else PERIOD_US
    if case.spacing_us is not None:
        expected = case.spacing_us[: len(times) - 1]
    np.testing.assert_allclose(np.diff(times), expected, atol=1)
    delivered = np.array(run.delivered_at_us[: len(times)])
    assert np.all(delivered >= times)
    assert np.all(delivered - times < PERIOD_US)
    assert fake.sleeps, "a realtime source must wait for its frames"
    # The waits add up to the span of the series (no drift, no busy loop); a live source
    # may also have waited before its first frame and for one read discarded at stop().
    span = times[-1] - times[0]
    slept = round(sum(fake.sleeps) * 1e6)
    assert span - len(times) <= slept <= span + 2 * PERIOD_US + len(times)


@pytest.mark.parametrize("kind", FINITE)
def test_contract_fast_mode(kind: str, media: dict[str, Path]) -> None:
    """realtime = False: nothing sleeps, capture times are still the source's series."""
    c = _cases(media)[kind]
    fake = FakeClock()
    run = run_reader(c.make(fake, False), fake=fake)
    assert fake.sleeps == []
    times = np.array([f.t_capture_us for f in run.frames])
    assert len(times) == c.n_frames
    expected = c.spacing_us if c.spacing_us is not None else PERIOD_US
    np.testing.assert_allclose(np.diff(times), expected, atol=1)
    assert times[0] == FakeClock().now_us  # the first frame at open() time
    assert run.reader.stats.ended


def test_contract_stop_is_prompt(case: Case) -> None:
    """On the real clock, stop() returns well within a second and the thread is gone."""
    frames: list[Frame] = []
    src = case.make(None, True)
    reader = CameraReader(src, 1, frames.append)
    reader.start()
    deadline = time.monotonic() + 5.0
    while not frames and time.monotonic() < deadline:
        time.sleep(0.002)
    assert frames
    t0 = time.monotonic()
    assert reader.stop()
    assert time.monotonic() - t0 < 1.0
    assert not reader.alive
    check_counters(reader)


# --------------------------------------------------------------------------------------
# The reader with a failing live source
# --------------------------------------------------------------------------------------
def test_stop_interrupts_a_blocked_read() -> None:
    src = FakeLive(["ok", "block"])
    reader = CameraReader(src, 0, lambda f: None)
    reader.start()
    assert src.blocked.wait(5.0)
    t0 = time.monotonic()
    assert reader.stop(timeout_s=2.0)
    assert time.monotonic() - t0 < 1.0
    assert not src.is_open and src.close_calls >= 1
    assert reader.stats.delivered == 1 and reader.stats.captured == 1  # the woken read is discarded


def test_stop_returns_even_if_read_ignores_interrupt() -> None:
    """A read stuck in a driver: stop() gives up after timeout_s; the thread closes the
    source itself when the read finally returns."""
    src = FakeLive(["stuck"])
    reader = CameraReader(src, 0, lambda f: None)
    reader.start()
    assert src.blocked.wait(5.0)
    t0 = time.monotonic()
    assert reader.stop(timeout_s=0.2) is False
    assert time.monotonic() - t0 < 1.0
    assert reader.alive and src.is_open
    src.release.set()
    deadline = time.monotonic() + 5.0
    while reader.alive and time.monotonic() < deadline:
        time.sleep(0.002)
    assert not reader.alive and not src.is_open
    assert reader.stats.captured == 0


def test_lost_camera_is_reopened_with_backoff() -> None:
    """Gone after 3 frames, two failed reopens, then back: counted, states reported,
    backoff doubling between attempts (lower bounds only: Event.wait never returns early)."""
    src = FakeLive(["ok", "ok", "ok", "gone"], opens=[True, False, False, True])
    run = run_reader(
        src,
        until=lambda r: r.stats.delivered >= 6,
        initial_backoff_s=0.02,
        max_backoff_s=0.5,
    )
    s = run.reader.stats
    assert s.read_errors == 1 and s.open_failures == 2 and s.reconnects == 1
    assert not s.ended
    assert run.states[:4] == ["open", "lost", "failed", "reconnected"]
    gaps = np.diff(src.open_calls[:4])
    assert gaps[0] >= 0.02 * 0.99  # lost -> first retry
    assert gaps[1] >= 0.04 * 0.99  # doubled
    assert gaps[2] >= 0.08 * 0.99
    assert [f.seq for f in run.frames] == list(range(len(run.frames)))
    assert np.all(np.diff([f.t_capture_us for f in run.frames]) > 0)
    check_counters(run.reader)


def test_any_exception_is_a_loss_not_a_crash() -> None:
    src = FakeLive(["ok", "boom", "ok"])
    run = run_reader(src, until=lambda r: r.stats.delivered >= 3, initial_backoff_s=0.01)
    s = run.reader.stats
    assert s.read_errors == 1 and s.reconnects == 1 and s.delivered >= 3
    assert "lost" in run.states and "reconnected" in run.states


def test_open_failures_are_retried_and_counted() -> None:
    src = FakeLive(opens=[False, False, False, True])
    run = run_reader(
        src, until=lambda r: r.stats.delivered >= 2, initial_backoff_s=0.01, max_backoff_s=0.02
    )
    s = run.reader.stats
    assert s.open_failures == 3 and s.reconnects == 0 and s.delivered >= 2
    assert run.states[:2] == ["failed", "open"]  # first success after failures is "open"


def test_bad_images_are_rejected_and_counted() -> None:
    reads = ["ok", "none", "empty", "zeros", "small", "gray", "float", "ok", "end"]
    src = FakeLive(reads, times="none")
    run = run_reader(src)
    s = run.reader.stats
    assert (s.delivered, s.rejected_empty, s.rejected_size) == (2, 3, 3)
    assert s.captured == 8 and s.ended
    assert [f.seq for f in run.frames] == [0, 1]
    # times stamped by the reader (the source gave None): strictly increasing
    assert run.frames[1].t_capture_us > run.frames[0].t_capture_us


def test_non_increasing_source_times_are_retimed() -> None:
    src = FakeLive(["ok", "ok", "ok", "end"], times="same")
    run = run_reader(src)
    times = [f.t_capture_us for f in run.frames]
    assert times == [5_000_000, 5_000_001, 5_000_002]
    assert run.reader.stats.retimed == 2


def test_on_frame_errors_do_not_kill_the_thread() -> None:
    calls = []

    def on_frame(frame: Frame) -> None:
        calls.append(frame.seq)
        raise RuntimeError("event loop closed")

    reader = CameraReader(FakeLive(["ok", "ok", "ok", "end"]), 0, on_frame)
    reader.start()
    deadline = time.monotonic() + 5.0
    while reader.alive and time.monotonic() < deadline:
        time.sleep(0.002)
    assert calls == [0, 1, 2] and reader.stats.ended


def test_finite_source_error_ends_instead_of_replaying() -> None:
    src = FakeLive(["ok", "gone"])
    src.live = False
    run = run_reader(src)
    s = run.reader.stats
    assert s.read_errors == 1 and s.ended and s.reconnects == 0
    assert len(src.open_calls) == 1 and run.states[-1] == "ended"


# --------------------------------------------------------------------------------------
# Source specifics
# --------------------------------------------------------------------------------------
def test_pacer_does_not_drift_and_reanchors_when_late() -> None:
    fake = FakeClock()

    def oversleep(s: float) -> None:
        fake.sleep(s + 0.005)  # every sleep overshoots by 5 ms

    pacer = Pacer(fake.clock, oversleep, realtime=True, max_lag_us=PERIOD_US)
    pacer.start()
    t0 = fake.clock()
    got = [pacer.wait(i * PERIOD_US) for i in range(10)]
    assert got == [t0 + i * PERIOD_US for i in range(10)]  # absolute deadlines
    fake.advance(200_000)  # a stall of 5 frames
    late = pacer.wait(10 * PERIOD_US)
    assert late == fake.clock() and pacer.late == 1
    assert pacer.wait(11 * PERIOD_US) == late + PERIOD_US  # spacing kept from the new anchor


def test_opencv_device_missing_raises_naming_it() -> None:
    with pytest.raises(CameraError, match="/dev/video99"):
        OpenCVDevice("/dev/video99", 640, 480).open()


def test_opencv_device_missing_through_reader_is_retried() -> None:
    src = OpenCVDevice("/dev/video99", 640, 480)
    run = run_reader(
        src,
        until=lambda r: r.stats.open_failures >= 3,
        initial_backoff_s=0.01,
        max_backoff_s=0.02,
        timeout_s=5.0,
    )
    s = run.reader.stats
    assert s.open_failures >= 3 and s.delivered == 0 and not s.ended
    assert run.states == ["failed"]


@pytest.mark.skipif(gstreamer_available(), reason="this OpenCV has GStreamer")
def test_gstreamer_without_support_says_so() -> None:
    src = GStreamerSource("videotestsrc ! videoconvert ! appsink", 320, 240)
    with pytest.raises(CameraError, match="no GStreamer support"):
        src.open()


def test_video_file_missing_names_the_path(tmp_path: Path) -> None:
    path = tmp_path / "nope.avi"
    with pytest.raises(CameraError, match=r"nope\.avi"):
        VideoFileSource(path, W, H).open()


def test_video_file_reports_fps_and_loops(tmp_path: Path) -> None:
    path = write_video(tmp_path / "ten.avi", 5, fps=10.0)
    fake = FakeClock()
    src = VideoFileSource(path, W, H, realtime=True, loop=True, **_clock_kw(fake))
    assert src.live
    run = run_reader(src, n=12, fake=fake)
    assert src.fps == pytest.approx(10.0)
    assert np.all(np.diff([f.t_capture_us for f in run.frames]) == 100_000)
    assert not run.reader.stats.ended and run.reader.stats.delivered >= 12


def test_frames_dir_unreadable_image_is_rejected(tmp_path: Path) -> None:
    d = write_frames(tmp_path / "f", 3)
    (d / "1.png").write_bytes(b"not a png")
    (d / "notes.txt").write_text("ignored")
    fake = FakeClock()
    run = run_reader(FramesDirSource(d, W, H, realtime=False, **_clock_kw(fake)), fake=fake)
    s = run.reader.stats
    assert (s.delivered, s.rejected_empty, s.ended) == (2, 1, True)
    # the bad frame kept its slot: frame 2 is two periods after frame 0
    assert run.frames[1].t_capture_us - run.frames[0].t_capture_us == 2 * PERIOD_US


def test_frames_dir_natural_order_and_errors(tmp_path: Path) -> None:
    d = tmp_path / "n"
    d.mkdir()
    for i in (10, 2, 1):
        cv2.imwrite(str(d / f"{i}.png"), _image(i, W, H))
    src = FramesDirSource(d, W, H, realtime=False)
    src.open()
    assert [p.name for p in src.files] == ["1.png", "2.png", "10.png"]
    with pytest.raises(CameraError, match="no such directory"):
        FramesDirSource(tmp_path / "missing", W, H).open()
    (tmp_path / "empty").mkdir()
    with pytest.raises(CameraError, match="no images"):
        FramesDirSource(tmp_path / "empty", W, H).open()


def test_scenario_source_rebases_times_and_matches_files() -> None:
    path = example_path("EX-FISHEYE")
    fake = FakeClock()
    src = ScenarioSource(path, realtime=False, **_clock_kw(fake))
    assert (src.width, src.height) == (640, 640)
    src.open()
    img, t = src.read()
    assert t == fake.now_us
    assert src.last_scenario_t_us == int(src.scenario.frame_times_us[0])
    expected = cv2.imread(str(path / "frames" / "000000.png"), cv2.IMREAD_COLOR)
    assert img is not None and expected is not None and np.array_equal(img, expected)
    src.close()
    with pytest.raises(CameraError, match=r"scenario\.toml"):
        ScenarioSource(path / "frames")


def test_sim_skips_ticks_when_rendering_falls_behind() -> None:
    fake = FakeClock()

    def slow_truth(t_us: int) -> tuple[float, np.ndarray, np.ndarray]:
        fake.advance(90_000)  # rendering takes 90 ms of simulated time
        return _fixed_truth(t_us)

    src = SimulatedCamera(SIM_CAMERA, "T90", slow_truth, render_ahead=False, **_clock_kw(fake))
    src.open()
    times = [src.read()[1] for _ in range(4)]
    t0 = times[0]
    assert t0 is not None
    assert all((t - t0) % PERIOD_US == 0 for t in times if t is not None)  # on the 25 Hz grid
    assert times == [t0, t0 + 3 * PERIOD_US, t0 + 6 * PERIOD_US, t0 + 9 * PERIOD_US]
    assert src.skipped_ticks == 6


def test_sim_renders_ahead_and_hands_frames_over_at_their_instant() -> None:
    fake = FakeClock()
    cost = {"us": 9_000}

    def truth(t_us: int) -> tuple[float, np.ndarray, np.ndarray]:
        fake.advance(cost["us"])  # rendering time
        return _fixed_truth(t_us)

    src = SimulatedCamera(SIM_CAMERA, "T90", truth, **_clock_kw(fake))
    src.open()
    for _ in range(3):
        _, t = src.read()
        assert t == fake.now_us  # delivered exactly at its capture instant
    assert src.late_frames == 0 and src.skipped_ticks == 0
    cost["us"] = 90_000  # slower than the frame period: late frames, counted, grid kept
    times = [src.read()[1] for _ in range(3)]
    assert src.late_frames >= 2 and src.skipped_ticks >= 2
    assert all(t is not None and (t - times[0]) % PERIOD_US == 0 for t in times)


def test_sim_without_vehicle_counts_empty_frames() -> None:
    fake = FakeClock()
    src = SimulatedCamera(SIM_CAMERA, "T90", lambda t: None, **_clock_kw(fake))
    run = run_reader(src, fake=fake, until=lambda r: r.stats.captured >= 3)
    s = run.reader.stats
    assert s.delivered == 0 and s.rejected_empty >= 3
    check_counters(run.reader)


def test_sim_for_mock_autopilot_renders_its_truth() -> None:
    from tcm_companion.sim.vehicle.mock_autopilot import MockAutopilot, MockAutopilotConfig

    fake = FakeClock()
    ap = MockAutopilot(MockAutopilotConfig(scenario="T90", seed=3), fake.clock())
    src = SimulatedCamera.for_mock(SIM_CAMERA, ap, **_clock_kw(fake))
    assert src.plan is ap.plan and src.seed == 3
    src.open()
    img, t = src.read()
    assert img is not None and img.shape == (SIM_CAMERA.height, SIM_CAMERA.width, 3) and img.any()
    assert t == fake.now_us


def test_dual_fisheye_pairs_and_fails_together() -> None:
    front, back = FakeLive(["ok", "ok", "small"]), FakeLive(["ok", "gone"])
    front.width = back.width = front.height = back.height = FISHEYE_PX
    src = DualFisheyeSource(front, back, _stitcher())
    src.open()
    assert front.is_open and back.is_open
    pano, t = src.read()
    assert pano is not None and pano.shape == (PANORAMA.height, PANORAMA.width, 3)
    assert t is not None and src.last_skew_us >= 0
    with pytest.raises(CameraGone):
        src.read()
    src.close()
    assert not front.is_open and not back.is_open
    # a wrong-sized fisheye image makes the pair rejected_size through the reader
    front, back = FakeLive(["small", "end"]), FakeLive()
    front.width = back.width = front.height = back.height = FISHEYE_PX
    run = run_reader(DualFisheyeSource(front, back, _stitcher()))
    assert run.reader.stats.rejected_size == 1 and run.reader.stats.ended


def test_dual_fisheye_open_failure_closes_the_other() -> None:
    front, back = FakeLive(), FakeLive(opens=[False])
    src = DualFisheyeSource(front, back, StandInStitcher(*_lenses(), PANORAMA))
    with pytest.raises(CameraError):
        src.open()
    assert not front.is_open and front.close_calls == 1


# --------------------------------------------------------------------------------------
# Settings and the registry
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"fps": 0.0}, "camera.fps"),
        ({"exposure": -2.0}, "camera.exposure"),
        ({"fourcc": "MJP"}, "camera.fourcc"),
        ({"sim_noise_dn": -1.0}, "camera.sim_noise_dn"),
        ({"sim_seed": -1}, "camera.sim_seed"),
        ({"source": "file"}, "camera.path"),
        ({"source": "frames", "path": " "}, "camera.path"),
        ({"source": "gstreamer"}, "camera.pipeline"),
        ({"source": "device", "device": ""}, "camera.device"),
        ({"source": "webcam"}, "camera.source"),
        (
            {"source": "dual_fisheye", "back": FisheyeCameraConfig(device="0")},
            "camera.back.device",
        ),
    ],
)
def test_settings_errors_name_the_field(kwargs: dict[str, object], field: str) -> None:
    with pytest.raises(ValueError, match=field.replace(".", r"\.")):
        CameraSourceConfig(**kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"fx": 0.0}, "fx"),
        ({"width": 0}, "width"),
        ({"cx": 700.0}, "cx"),
        ({"dist": (0.0, 0.0, 0.0)}, "dist"),
        ({"device": ""}, "device"),
    ],
)
def test_fisheye_settings_errors_name_the_field(kwargs: dict[str, object], field: str) -> None:
    with pytest.raises(ValueError, match=field):
        FisheyeCameraConfig(**kwargs)  # type: ignore[arg-type]


def test_settings_load_through_the_config_loader() -> None:
    from tcm_companion.config import ConfigError, build_dataclass

    table = {
        "source": "dual_fisheye",
        "fps": 30,
        "front": {"device": "/dev/video0", "dist": [0.01, 0.0, 0.0, 0.0]},
        "back": {"device": "/dev/video2", "mount_rpy_deg": [0, 0, 180]},
    }
    s = build_dataclass(CameraSourceConfig, table, "camera")
    assert s.fps == 30.0 and s.front.dist == (0.01, 0.0, 0.0, 0.0)
    assert s.back.mount_rpy_deg == (0.0, 0.0, 180.0)
    with pytest.raises(ConfigError, match=r"camera\.source"):
        build_dataclass(CameraSourceConfig, {"source": "webcam"}, "camera")
    with pytest.raises(ConfigError, match=r"camera\.fps"):
        build_dataclass(CameraSourceConfig, {"fps": -1}, "camera")


def test_the_simulators_sources_are_registered_by_the_simulator(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """io does not import the simulator: until tcm_companion.sim.sources registers "sim"
    and "sim_autopilot", open_source refuses them and says which module registers them."""
    from tcm_companion.io.cameras import settings
    from tcm_companion.sim.scene.autopilot_camera import AutopilotSimCamera

    for kind in ("sim", "sim_autopilot"):
        monkeypatch.delitem(settings.BUILDERS, kind, raising=False)
    cam = Equirectangular(width=W, height=H)
    for kind in ("sim", "sim_autopilot"):
        with pytest.raises(CameraError, match=rf"'{kind}'.*tcm_companion\.sim\.sources"):
            open_source(CameraSourceConfig(source=kind), cam)
    with pytest.raises(ValueError, match="webcam"):
        settings.register_source("webcam", lambda *_: FakeLive())
    register_sim_sources()
    assert isinstance(
        open_source(CameraSourceConfig(source="sim_autopilot"), cam), AutopilotSimCamera
    )
    register_sim_sources()  # again: idempotent
    assert {"sim", "sim_autopilot"} <= set(settings.BUILDERS)


def test_open_source_registry(media: dict[str, Path], tmp_path: Path) -> None:
    register_sim_sources()
    cam = Equirectangular(width=W, height=H)
    with pytest.raises(CameraError, match="mock autopilot"):
        open_source(CameraSourceConfig(source="sim"), cam)
    sim = open_source(
        CameraSourceConfig(source="sim", sim_seed=2), SIM_CAMERA, truth_us=_fixed_truth
    )
    assert isinstance(sim, SimulatedCamera) and (sim.width, sim.height) == (120, 74)
    dev = open_source(CameraSourceConfig(source="device", device="/dev/video3", exposure=50.0), cam)
    assert isinstance(dev, OpenCVDevice) and dev.exposure == 50.0
    assert isinstance(
        open_source(CameraSourceConfig(source="gstreamer", pipeline="x ! appsink"), cam),
        GStreamerSource,
    )
    missing = str(tmp_path / "missing.avi")
    with pytest.raises(CameraError, match=r"camera\.path: no such file"):
        open_source(CameraSourceConfig(source="file", path=missing), cam)
    video = open_source(
        CameraSourceConfig(source="file", path=str(media["video"]), realtime=False), cam
    )
    assert isinstance(video, VideoFileSource) and not video.realtime
    frames = open_source(
        CameraSourceConfig(source="frames", path=str(media["frames"]), fps=10.0), cam
    )
    assert isinstance(frames, FramesDirSource) and frames.fps == 10.0
    with pytest.raises(CameraError, match=r"camera\.path: no such directory"):
        open_source(CameraSourceConfig(source="frames", path=missing), cam)
    pinhole_dir = str(example_path("EX-PINHOLE"))
    with pytest.raises(CameraError, match="640x480"):
        open_source(CameraSourceConfig(source="scenario", path=pinhole_dir), cam)
    pin = Pinhole(width=640, height=480, fx=320.0, fy=320.0, cx=320.0, cy=240.0)
    assert isinstance(
        open_source(CameraSourceConfig(source="scenario", path=pinhole_dir), pin), ScenarioSource
    )
    dual = CameraSourceConfig(source="dual_fisheye")
    with pytest.raises(CameraError, match="equirectangular"):
        open_source(dual, pin)
    rig = open_source(dual, Equirectangular(width=180, height=110))
    assert isinstance(rig, DualFisheyeSource) and (rig.width, rig.height) == (180, 110)
    assert isinstance(rig.front, OpenCVDevice) and rig.front.device == "0"
    assert isinstance(rig.back, OpenCVDevice) and rig.back.device == "1"
