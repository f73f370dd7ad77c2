"""``[camera]`` of config.toml, and the registry that builds the configured source.

:class:`CameraSourceConfig` is a frozen dataclass of plain fields (str, int, float, bool,
Literal, tuples, nested frozen dataclasses) so the config loader can map the TOML table
onto it and type-check it; ranges are checked in ``__post_init__`` with errors that name
the field. :func:`open_source` is the registry (python-can's ``can/interfaces``): one
builder per ``source`` kind, each importing its backend lazily, each error naming the
setting at fault. The devices and files are built here; the simulator's two kinds
(``"sim"``, ``"sim_autopilot"``) are registered with :func:`register_source` by the
simulator itself (:mod:`tcm_companion.sim.sources`), so that this layer does not import
the layer above it: the application registers them before it opens a camera.

Note for config files: a nested table (``[camera.back]``) is built from
:class:`FisheyeCameraConfig`'s own defaults, not from ``CameraSourceConfig.back``'s
default (device "1", yaw 180°), so give every key of ``[camera.front]`` and
``[camera.back]`` when you write them.
"""

from __future__ import annotations

import math
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from .base import CameraError, FrameSource

if TYPE_CHECKING:
    import numpy as np

    from ...core.camera import CameraModel, Fisheye

SourceKind = Literal[
    "sim", "sim_autopilot", "device", "gstreamer", "file", "frames", "scenario", "dual_fisheye"
]
SOURCE_KINDS: tuple[str, ...] = typing.get_args(SourceKind)
#: What ``source = "sim_autopilot"`` puts in the field
#: (:mod:`tcm_companion.sim.scene.autopilot_camera`).
SimSceneKind = Literal["crossing", "headon", "static"]
SIM_SCENE_KINDS: tuple[str, ...] = typing.get_args(SimSceneKind)
#: One ball of ``sim_scene = "static"``: ``(n_m, e_m, d_m, radius_m)`` in the autopilot's local NED.
StaticBall = tuple[float, float, float, float]


@dataclass(frozen=True)
class FisheyeCameraConfig:
    """One camera of the dual-fisheye rig: device, image size, OpenCV fisheye intrinsics.

    Pixel coordinates follow ``tcm-scenario/1`` (``cx = width / 2`` is the exact centre,
    not OpenCV's ``width / 2 - 0.5``); ``dist = (k1, k2, k3, k4)`` of ``cv2.fisheye``;
    ``mount_rpy_deg`` the camera's roll, pitch, yaw in the body frame (FRD), degrees.
    The defaults describe an uncalibrated 180° lens on a 640×640 sensor: calibrate.
    """

    device: str = "0"  # V4L2 index ("0") or path ("/dev/video0")
    width: int = 640  # px
    height: int = 640  # px
    fx: float = 203.7  # px; 640 px ≈ 180° for an equidistant lens: 320 / (π / 2)
    fy: float = 203.7  # px
    cx: float = 320.0  # px, scenario convention
    cy: float = 320.0  # px
    dist: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)  # deg, body FRD

    def __post_init__(self) -> None:
        if not self.device.strip():
            raise ValueError("device must not be empty")
        for name in ("width", "height"):
            if not getattr(self, name) > 0:
                raise ValueError(
                    f"{name} must be a positive number of pixels, got {getattr(self, name)!r}"
                )
        for name in ("fx", "fy"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive focal length in pixels, got {value!r}")
        if not 0.0 <= self.cx <= self.width:
            raise ValueError(f"cx must lie within [0, width = {self.width}] px, got {self.cx!r}")
        if not 0.0 <= self.cy <= self.height:
            raise ValueError(f"cy must lie within [0, height = {self.height}] px, got {self.cy!r}")
        if len(self.dist) != 4 or not all(math.isfinite(k) for k in self.dist):
            raise ValueError(f"dist must be 4 finite numbers [k1, k2, k3, k4], got {self.dist!r}")
        if len(self.mount_rpy_deg) != 3 or not all(math.isfinite(a) for a in self.mount_rpy_deg):
            raise ValueError(f"mount_rpy_deg must be 3 finite angles, got {self.mount_rpy_deg!r}")

    def camera_model(self) -> Fisheye:
        """The :class:`~tcm_companion.core.camera.Fisheye` model of this camera."""
        from ...core.camera import Fisheye

        return Fisheye(
            width=self.width,
            height=self.height,
            mount_rpy_deg=self.mount_rpy_deg,
            fx=self.fx,
            fy=self.fy,
            cx=self.cx,
            cy=self.cy,
            dist=self.dist,
        )


def _back_default() -> FisheyeCameraConfig:
    return FisheyeCameraConfig(device="1", mount_rpy_deg=(0.0, 0.0, 180.0))


@dataclass(frozen=True)
class CameraSourceConfig:
    """Where the frames come from (``source``) and how to open it.

    The image size is the pipeline's camera model's (``[camera]`` of the scenario or
    the companion's camera description), passed to :func:`open_source`.
    """

    source: SourceKind = "sim"
    device: str = "0"  # source = "device": V4L2 index ("0") or path ("/dev/video0")
    fps: float = 25.0  # frames per second (device, frames directory, simulator)
    fourcc: str = ""  # device pixel format, e.g. "MJPG" or "YUYV"; "" = the driver's default
    exposure: float = -1.0  # -1 = auto; else V4L2 exposure_absolute (units of 100 µs)
    pipeline: str = ""  # source = "gstreamer": a pipeline ending in appsink (BGR)
    path: str = ""  # source = "file" (video), "frames" (image directory), "scenario" (directory)
    realtime: bool = (
        True  # file/frames/scenario: pace at the frame rate (false: as fast as possible)
    )
    loop: bool = False  # file/frames: start again at the end
    sim_noise_dn: float = 2.5  # simulator sensor noise σ, digital numbers (0..255 scale)
    sim_seed: int = 0  # simulator noise and flight-plan variant
    # source = "sim_autopilot": the field rendered from any autopilot's pose over MAVLink.
    sim_url: str = "tcp:127.0.0.1:5763"  # its own link to the autopilot (SITL SERIAL2)
    sim_scene: SimSceneKind = "crossing"  # "crossing", "headon" or "static"
    sim_contact_s: float = 7.0  # s from launch to the predicted contact (crossing, headon)
    sim_ball_speed_mps: float = 1.5  # crossing: the ball's ground speed, m/s
    sim_side_deg: float = 90.0  # crossing: side it comes from, deg clockwise from the track
    sim_heading_deg: float = 0.0  # the field's track direction, deg clockwise from north
    sim_ball_radius_m: float = 0.375  # crossing / headon ball radius, m
    sim_static_balls: tuple[StaticBall, ...] = ()  # static: [[n_m, e_m, d_m, radius_m], ...]
    front: FisheyeCameraConfig = field(default_factory=FisheyeCameraConfig)  # dual_fisheye
    back: FisheyeCameraConfig = field(default_factory=_back_default)  # dual_fisheye

    def __post_init__(self) -> None:
        if self.source not in SOURCE_KINDS:
            raise ValueError(
                f"camera.source must be one of {list(SOURCE_KINDS)}, got {self.source!r}"
            )
        if not (math.isfinite(self.fps) and 0.0 < self.fps <= 1000.0):
            raise ValueError(f"camera.fps must be in (0, 1000] frames per second, got {self.fps!r}")
        if self.fourcc and len(self.fourcc) != 4:
            raise ValueError(
                f"camera.fourcc must be 4 characters (e.g. 'MJPG') or empty, got {self.fourcc!r}"
            )
        if not (self.exposure == -1.0 or (math.isfinite(self.exposure) and self.exposure > 0)):
            raise ValueError(
                f"camera.exposure must be -1 (auto) or positive, got {self.exposure!r}"
            )
        if not (math.isfinite(self.sim_noise_dn) and self.sim_noise_dn >= 0):
            raise ValueError(f"camera.sim_noise_dn must be >= 0, got {self.sim_noise_dn!r}")
        if self.sim_seed < 0:
            raise ValueError(f"camera.sim_seed must be >= 0, got {self.sim_seed!r}")
        self._check_sim_autopilot()
        if self.source == "device" and not self.device.strip():
            raise ValueError("camera.device must not be empty when camera.source = 'device'")
        if self.source == "gstreamer" and not self.pipeline.strip():
            raise ValueError("camera.pipeline must be given when camera.source = 'gstreamer'")
        if self.source in ("file", "frames", "scenario") and not self.path.strip():
            raise ValueError(f"camera.path must be given when camera.source = {self.source!r}")
        if self.source == "dual_fisheye" and self.front.device.strip() == self.back.device.strip():
            raise ValueError(
                f"camera.back.device must differ from camera.front.device (both {self.front.device!r})"
            )

    def _check_sim_autopilot(self) -> None:
        if self.sim_scene not in SIM_SCENE_KINDS:
            raise ValueError(
                f"camera.sim_scene must be one of {list(SIM_SCENE_KINDS)}, got {self.sim_scene!r}"
            )
        if self.source == "sim_autopilot" and ":" not in self.sim_url.strip():
            raise ValueError(
                "camera.sim_url must be a link URL such as 'tcp:127.0.0.1:5763' or "
                f"'udpin:0.0.0.0:14560' when camera.source = 'sim_autopilot', got {self.sim_url!r}"
            )
        ranges = (
            ("sim_contact_s", 1.0, 120.0, "s"),
            ("sim_ball_speed_mps", 0.0, 50.0, "m/s"),
            ("sim_side_deg", -180.0, 180.0, "degrees"),
            ("sim_heading_deg", -360.0, 360.0, "degrees"),
        )
        for name, lo, hi, unit in ranges:
            value = getattr(self, name)
            if not (math.isfinite(value) and lo <= value <= hi):
                raise ValueError(f"camera.{name} must be in [{lo:g}, {hi:g}] {unit}, got {value!r}")
        if not (math.isfinite(self.sim_ball_radius_m) and 0.0 < self.sim_ball_radius_m <= 10.0):
            raise ValueError(
                f"camera.sim_ball_radius_m must be in (0, 10] m, got {self.sim_ball_radius_m!r}"
            )
        for i, ball in enumerate(self.sim_static_balls):
            if (
                len(ball) != 4
                or not all(math.isfinite(x) for x in ball)
                or not 0.0 < ball[3] <= 10.0
            ):
                raise ValueError(
                    f"camera.sim_static_balls[{i}] must be [n_m, e_m, d_m, radius_m] with "
                    f"finite numbers and 0 < radius_m <= 10, got {ball!r}"
                )

    @property
    def exposure_or_auto(self) -> float | None:
        """``exposure``, or None for auto."""
        return None if self.exposure < 0 else self.exposure


# --------------------------------------------------------------------------------------
# The registry
# --------------------------------------------------------------------------------------
#: ``truth_us(t_mono_us) -> (scenario_t_s, pos_ned_m (3,), R_ned_from_body (3, 3))`` or
#: None while there is no vehicle yet; ``t_mono_us`` on the camera's clock (the companion
#: monotonic clock, or the simulated one). Only the simulator's ``"sim"`` source takes it.
TruthFn = Callable[[int], "tuple[float, np.ndarray, np.ndarray] | None"]

#: Builds the source of one kind: ``(settings, camera_model, truth_us, scenario) -> source``.
SourceBuilder = Callable[["CameraSourceConfig", "CameraModel", "TruthFn | None", str], FrameSource]

#: The module that registers each kind not built here (named in the error when it was not).
REGISTERED_BY = {"sim": "tcm_companion.sim.sources", "sim_autopilot": "tcm_companion.sim.sources"}


def _device(
    s: CameraSourceConfig, cam: CameraModel, truth_us: TruthFn | None, scenario: str
) -> FrameSource:
    from .opencv import OpenCVDevice

    return OpenCVDevice(s.device, cam.width, cam.height, s.fps, s.fourcc, s.exposure_or_auto)


def _gstreamer(
    s: CameraSourceConfig, cam: CameraModel, truth_us: TruthFn | None, scenario: str
) -> FrameSource:
    from .opencv import GStreamerSource

    return GStreamerSource(s.pipeline, cam.width, cam.height)


def _file(
    s: CameraSourceConfig, cam: CameraModel, truth_us: TruthFn | None, scenario: str
) -> FrameSource:
    if not Path(s.path).is_file():
        raise CameraError(f"camera.path: no such file {s.path!r} (camera.source = 'file')")
    from .opencv import VideoFileSource

    return _probed(
        VideoFileSource(s.path, cam.width, cam.height, realtime=s.realtime, loop=s.loop), s
    )


def _frames(
    s: CameraSourceConfig, cam: CameraModel, truth_us: TruthFn | None, scenario: str
) -> FrameSource:
    if not Path(s.path).is_dir():
        raise CameraError(f"camera.path: no such directory {s.path!r} (camera.source = 'frames')")
    from .frames_dir import FramesDirSource

    return _probed(
        FramesDirSource(s.path, cam.width, cam.height, realtime=s.realtime, fps=s.fps, loop=s.loop),
        s,
    )


def _probed(src: FrameSource, s: CameraSourceConfig) -> FrameSource:
    """``src`` (a file or a directory: nothing to wait for) once it has been opened and
    closed again, which reads its first frame: a file OpenCV cannot decode, or a directory
    without images, is refused now like a missing one, rather than retried for ever."""
    try:
        src.open()
    except CameraError as exc:
        raise CameraError(f"camera.path: {exc} (camera.source = {s.source!r})") from None
    finally:
        src.close()
    return src


def _scenario(
    s: CameraSourceConfig, cam: CameraModel, truth_us: TruthFn | None, scenario: str
) -> FrameSource:
    if not Path(s.path).is_dir():
        raise CameraError(f"camera.path: no such directory {s.path!r} (camera.source = 'scenario')")
    from .scenario_source import ScenarioSource

    try:
        src = ScenarioSource(s.path, realtime=s.realtime)
    except CameraError as exc:
        raise CameraError(f"camera.path: {exc}") from None
    if (src.width, src.height) != (cam.width, cam.height):
        raise CameraError(
            f"camera.path: scenario {s.path!r} has {src.width}x{src.height} frames but the "
            f"camera model is {cam.width}x{cam.height}"
        )
    return src


def _dual_fisheye(
    s: CameraSourceConfig, cam: CameraModel, truth_us: TruthFn | None, scenario: str
) -> FrameSource:
    from ...core.camera import Equirectangular

    if not isinstance(cam, Equirectangular):
        raise CameraError(
            "camera.source = 'dual_fisheye' stitches an equirectangular panorama; the "
            f"camera model is {cam.model_name}"
        )
    try:
        from .stitch import FisheyeStitcher
    except ImportError as exc:
        raise CameraError(
            f"camera.source = 'dual_fisheye': the stitcher is not available ({exc})"
        ) from None
    from .dual_fisheye import DualFisheyeSource
    from .opencv import OpenCVDevice

    def device(which: str, f: FisheyeCameraConfig) -> FrameSource:
        return OpenCVDevice(
            f.device,
            f.width,
            f.height,
            s.fps,
            s.fourcc,
            s.exposure_or_auto,
            name=f"{which}:{f.device}",
        )

    stitcher = FisheyeStitcher(s.front.camera_model(), s.back.camera_model(), cam)
    return DualFisheyeSource(device("front", s.front), device("back", s.back), stitcher)


#: The builder of each ``source`` kind; the simulator's are added by :func:`register_source`.
BUILDERS: dict[str, SourceBuilder] = {
    "device": _device,
    "gstreamer": _gstreamer,
    "file": _file,
    "frames": _frames,
    "scenario": _scenario,
    "dual_fisheye": _dual_fisheye,
}


def register_source(kind: str, builder: SourceBuilder) -> None:
    """Make :func:`open_source` build ``source = kind`` with ``builder`` (registering a
    kind again replaces its builder). ``kind`` must be one of :data:`SourceKind`."""
    if kind not in SOURCE_KINDS:
        raise ValueError(f"camera source kind must be one of {list(SOURCE_KINDS)}, got {kind!r}")
    BUILDERS[kind] = builder


def open_source(
    settings: CameraSourceConfig,
    camera_model: CameraModel,
    *,
    truth_us: TruthFn | None = None,
    scenario: str = "T90",
) -> FrameSource:
    """Build (not open) the source ``settings.source`` for images of ``camera_model``'s size.

    ``truth_us`` (``t_us -> (scenario_t_s, pos_ned_m, R_ned_from_body)``) and
    ``scenario`` are for the simulator (``"sim"``) only; ``"sim_autopilot"`` takes its
    pose from the autopilot at ``sim_url`` instead (both registered by
    :func:`tcm_companion.sim.sources.register_sim_sources`). Raises :class:`CameraError`
    naming the setting at fault; the device itself is opened later, by the reader thread.
    """
    try:
        builder = BUILDERS[settings.source]
    except KeyError:
        where = REGISTERED_BY.get(settings.source)
        if where is not None:
            raise CameraError(
                f"camera.source = {settings.source!r}: no builder registered; {where} "
                "registers the simulator's sources (register_sim_sources())"
            ) from None
        raise CameraError(
            f"camera.source: unknown source {settings.source!r} (known: {', '.join(BUILDERS)})"
        ) from None
    return builder(settings, camera_model, truth_us, scenario)
