"""``config.toml`` → frozen dataclasses, with errors that name the file, table and key.

Each TOML table maps onto one dataclass of the core by field name (``[classifier]`` →
:class:`~tcm_companion.core.classify.ClassifierConfig`, …). Unknown keys are errors (a
typo must not silently fall back to a default), values are type-checked against the
field's annotation, an angle field ``x_rad`` may be given in degrees as ``x_deg``, and
every numeric value is checked against its valid range in :data:`RANGES` before the
dataclass is built, whatever set it (file, environment, ``--set``).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import re
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .core.camera import (
    _KEYS,
    LENS_RANGES,
    CameraModel,
    CameraModelError,
    Equirectangular,
    camera_from_dict,
    lens_range_text,
)
from .core.pipeline import PipelineConfig
from .flightlog.settings import LoggingConfig
from .io.cameras.settings import CameraSourceConfig
from .service.daemon_config import RANGES as DAEMON_RANGES
from .service.daemon_config import DaemonConfig
from .service.endpoint_setup import MavlinkConfig

log = logging.getLogger(__name__)


class ConfigError(ValueError):
    """A configuration value is missing, unknown, of the wrong type or out of range.

    ``key``: the dotted key at fault as it was written (``"classifier.tcm_threshold"``)
    when the error is about one value, so that the override that set it can be named.
    """

    def __init__(self, message: str, key: str = "") -> None:
        super().__init__(message)
        self.key = key

    @property
    def errors(self) -> list[ConfigError]:
        """Each error on its own (one here; several in :class:`ConfigErrors`)."""
        return [self]


class ConfigErrors(ConfigError):
    """Several errors of one configuration, all found in one reading (``config check``
    reports every one); ``str()`` is one line per error."""

    def __init__(self, errors: typing.Sequence[ConfigError]) -> None:
        flat = [e for err in errors for e in err.errors]
        super().__init__("\n".join(str(e) for e in flat))
        self._errors = flat

    @property
    def errors(self) -> list[ConfigError]:
        return list(self._errors)


def _combined(errors: typing.Sequence[ConfigError]) -> ConfigError:
    """The errors found as one exception: one as itself, several as :class:`ConfigErrors`."""
    flat = [e for err in errors for e in err.errors]
    return flat[0] if len(flat) == 1 else ConfigErrors(flat)


def _raise_all(errors: typing.Sequence[ConfigError]) -> None:
    """Raise the errors found, if any (:func:`_combined`)."""
    if errors:
        raise _combined(errors)


@dataclass(frozen=True)
class SimConfig:
    """``[sim]``: the simulated vehicle flown by the mock autopilot when the camera source
    is ``"sim"`` (``tcm-companion run`` with the repository's config, and ``sitl``)."""

    scenario: str = "T90"  # TS, T45, T90, RAISED, INPLANE, COLLISION, HEADON, TWO
    seed: int = 0  # turbulence of the flight, telemetry noise, sensor noise
    telemetry_noise: float = 1.0  # scale of the mock's attitude/position noise (0: exact)
    ekf_origin_delay_us: int = 3_000_000  # LOCAL_POSITION_NED starts this long after boot
    brake_on_collision: bool = True  # the mock brakes on a collision-course alarm

    def __post_init__(self) -> None:
        from .sim.scene.names import SCENARIO_NAMES

        if self.scenario.upper() not in SCENARIO_NAMES:
            raise ValueError(
                f"scenario must be one of {', '.join(SCENARIO_NAMES)}, got {self.scenario!r}"
            )
        for name in ("telemetry_noise", "ekf_origin_delay_us"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")


def _default_camera_model() -> CameraModel:
    return Equirectangular(360, 220)


@dataclass(frozen=True)
class CameraConfig:
    """``[camera]``: the lens model the pipeline uses (the keys of a scenario's ``[camera]``:
    ``model``, ``width``, ``height``, ``mount_rpy_deg`` and the model's intrinsics) and
    where its frames come from (:class:`~tcm_companion.io.cameras.settings.CameraSourceConfig`:
    ``source``, ``device``, ``path`` …), in one table."""

    model: CameraModel = field(default_factory=_default_camera_model)
    source: CameraSourceConfig = field(default_factory=CameraSourceConfig)
    name: str = "camera0"


_MODEL_KEYS = {"model", "width", "height", "mount_rpy_deg"} | {
    k for ks in _KEYS.values() for k in ks
}
#: The keys of ``[camera]`` that describe the lens (the rest say where frames come from).
LENS_KEYS = frozenset(_MODEL_KEYS)


def camera_config_from_table(table: Any, where: str) -> CameraConfig:
    """Split ``[camera]`` into the lens model and the source settings; check both."""
    if not isinstance(table, dict):
        raise ConfigError(f"{where} must be a table")
    model_keys = {k: v for k, v in table.items() if k in _MODEL_KEYS}
    source_keys = {k: v for k, v in table.items() if k not in _MODEL_KEYS and k != "name"}
    errors: list[ConfigError] = []
    name = table.get("name", "camera0")
    if not isinstance(name, str) or not name:
        errors.append(
            ConfigError(f"{_key_at(where, 'name')} must be a non-empty string, got {name!r}")
        )
    model: CameraModel | None = _default_camera_model()
    if model_keys:
        merged = {"model": "equirectangular", "width": 360, "height": 220, **model_keys}
        # Ranges first (numbers only: camera_from_dict reports a wrong type).
        given = {k: (k, v, v) for k, v in model_keys.items()}
        try:
            _check_ranges("camera", where, given, merged.get, list(merged))
            model = camera_from_dict(merged, where=where)
        except ConfigError as exc:
            errors.append(exc)
            model = None
        except CameraModelError as exc:
            # camera_from_dict writes "<where>.key"; the other messages "<where> key".
            msg = str(exc).replace(f"{where}.", _key_at(where, ""), 1)
            errors.append(ConfigError(msg))
            model = None
    source: CameraSourceConfig | None = None
    try:
        source = build_dataclass(CameraSourceConfig, source_keys, where)
    except ConfigError as exc:
        # CameraSourceConfig names its fields "camera.x" (and "camera.front.x"); say where
        # they were written, once.
        def at(m: re.Match[str]) -> str:
            return _key_at(_table_at(where, m[1]) if m[1] else where, "")

        for e in exc.errors:
            msg = re.sub(rf"{re.escape(where)}: camera\.(?:(front|back)\.)?", at, str(e), count=1)
            errors.append(ConfigError(msg, e.key))
    sim_url = source_keys.get("sim_url", CameraSourceConfig.sim_url)
    if isinstance(sim_url, str) and sim_url:  # "" with sim_autopilot: CameraSourceConfig says
        errors += _url_errors(sim_url, where, "sim_url", "camera.sim_url")
    _raise_all(errors)
    assert model is not None and source is not None and isinstance(name, str)
    if source.source == "dual_fisheye" and model.model_name != "equirectangular":
        raise ConfigError(
            f'{_key_at(where, "model")} must be "equirectangular" for source = "dual_fisheye" '
            "(the two fisheyes are stitched into a panorama)",
            "camera.model",
        )
    return CameraConfig(model=model, source=source, name=name)


#: The most cameras a rig may have (``[[cameras]]`` tables).
MAX_CAMERAS = 16


def _one_camera() -> tuple[CameraConfig, ...]:
    return (CameraConfig(),)


@dataclass(frozen=True)
class AppConfig:
    """The whole configuration. ``cameras``: the rig, camera id = index (``[[cameras]]``;
    a lone ``[camera]`` is a rig of one); :attr:`camera` is ``cameras[0]``."""

    pipeline: PipelineConfig = field(default_factory=PipelineConfig)
    mavlink: MavlinkConfig = field(default_factory=MavlinkConfig)
    daemon: DaemonConfig = field(default_factory=DaemonConfig)
    sim: SimConfig = field(default_factory=SimConfig)
    cameras: tuple[CameraConfig, ...] = field(default_factory=_one_camera)
    logging: LoggingConfig = field(default_factory=LoggingConfig)

    def __post_init__(self) -> None:
        if not 1 <= len(self.cameras) <= MAX_CAMERAS:
            raise ValueError(f"cameras: 1 to {MAX_CAMERAS} cameras, got {len(self.cameras)}")
        names = [c.name for c in self.cameras]
        for i, name in enumerate(names):
            if name in names[:i]:
                raise ValueError(
                    f"cameras: name {name!r} given twice (cameras {names.index(name)} and {i})"
                )

    @property
    def camera(self) -> CameraConfig:
        """The first camera (id 0): the one camera of a ``[camera]`` configuration."""
        return self.cameras[0]

    def with_camera(self, camera: CameraConfig, camera_id: int = 0) -> AppConfig:
        """This configuration with camera ``camera_id`` replaced by ``camera``."""
        cams = list(self.cameras)
        cams[camera_id] = camera
        return dataclasses.replace(self, cameras=tuple(cams))


# --------------------------------------------------------------------------------------
# Valid ranges
#
# Every numeric setting of every table has one entry in RANGES, keyed "table.key" as the
# user writes it (pipeline stages under their own table names, nested tables dotted:
# "mavlink.endpoint.attitude_rate_hz", "camera.front.fx"; angles under their _rad name).
# tests/test_config_ranges.py checks that every numeric field reachable from AppConfig
# has one, and config.toml states the same range in each setting's comment.


_INF = ("inf", "∞")


@dataclass(frozen=True)
class Range:
    """The valid values of one numeric setting: ``lo``..``hi`` (``None``: unbounded),
    each bound inclusive unless ``*_open``, in ``unit`` ("" = dimensionless); ``also``:
    values valid outside it (``exposure = -1``: auto); ``hi_key``: the upper bound is
    another key of the same table (``cx`` within ``[0, width]``). For a list, the range of
    every item. Written as text, :func:`Range.parse` of e.g. ``"(0, 10] s"``."""

    lo: float | None
    hi: float | None
    unit: str = ""
    lo_open: bool = False
    hi_open: bool = False
    also: tuple[float, ...] = ()
    hi_key: str = ""

    @classmethod
    def parse(cls, spec: str) -> Range:
        """``"[0, 2]"``, ``"(0, 10] s"``, ``"[0, pi/2) rad"``, ``"[0, inf) m"``,
        ``"[0, width] px"``, ``"-1 or (0, 100000] × 100 µs"``."""
        m = re.fullmatch(
            r"(?:(?P<also>[-+0-9.e_]+) or )?(?P<lb>[\[(])(?P<lo>[^,]+), *(?P<hi>[^\])]+)"
            r"(?P<rb>[\])]) *(?P<unit>.*)",
            spec,
        )
        if m is None:
            raise ValueError(f"bad range {spec!r}")
        hi_key = (
            m["hi"] if re.fullmatch(r"[a-z_]+", m["hi"]) and m["hi"] not in ("inf", "pi") else ""
        )
        return cls(
            lo=_bound(m["lo"]),
            hi=None if hi_key else _bound(m["hi"]),
            unit=m["unit"],
            lo_open=m["lb"] == "(",
            hi_open=m["rb"] == ")",
            also=(float(m["also"]),) if m["also"] else (),
            hi_key=hi_key,
        )

    def admits(self, x: float, hi: float | None = None, *, eps: float = 0.0) -> bool:
        """Whether ``x`` is valid; ``hi``: the value of ``hi_key``. ``eps``: how far a
        value converted from degrees may round past a closed bound (or must stay inside
        an open one)."""
        if x in self.also:
            return True
        top = hi if self.hi_key else self.hi
        if self.lo is not None:
            e = eps * max(1.0, abs(self.lo))
            if not (x > self.lo + e if self.lo_open else x >= self.lo - e):
                return False
        if top is not None:
            e = eps * max(1.0, abs(top))
            if not (x < top - e if self.hi_open else x <= top + e):
                return False
        return True

    def text(self, *, deg: bool = False, hi: float | None = None) -> str:
        """``"(0, 10] s"``; ``deg``: an angle range in radians shown in degrees; ``hi``:
        the value of ``hi_key``, shown as ``width = 640``."""
        unit = "deg" if deg else self.unit

        def show(b: float | None, sign: str) -> str:
            if b is None:
                return f"{sign}∞"
            if deg:
                return _num(math.degrees(b))
            return _rad(b) if self.unit == "rad" else _num(b)

        if self.hi_key:
            top = self.hi_key if hi is None else f"{self.hi_key} = {_num(hi)}"
        else:
            top = show(self.hi, "")
        interval = (
            f"{'(' if self.lo_open or self.lo is None else '['}{show(self.lo, '-')}, "
            f"{top}{')' if self.hi_open or (self.hi is None and not self.hi_key) else ']'}"
        )
        also = "".join(f"{_num(a)} or " for a in self.also)
        return f"{also}{interval}{' ' + unit if unit else ''}"

    def must(self, *, deg: bool = False, hi: float | None = None) -> str:
        """The end of an error message: ``"in [0, 2] (dimensionless)"``."""
        text = self.text(deg=deg, hi=hi)
        if self.also:
            head, _, rest = text.partition(" or ")
            text = f"{head} or in {rest}"
        else:
            text = f"in {text}"
        return text if deg or self.unit else f"{text} (dimensionless)"


@dataclass(frozen=True)
class PerItem:
    """The ranges of the items of a fixed-length list, by position (``sim_static_balls``:
    each ball's ``[n_m, e_m, d_m, radius_m]``)."""

    items: tuple[tuple[str, Range], ...]

    def text(self) -> str:
        return ", ".join(f"{name} {r.text()}" for name, r in self.items)


RangeSpec = Range | PerItem


def _bound(tok: str) -> float | None:
    tok = tok.strip()
    if tok.lstrip("+-") in _INF:
        return None
    m = re.fullmatch(r"(-?)(\d*)(?:pi|π)(?:/(\d+))?", tok)
    if m:
        k = float(m[2] or 1) / float(m[3] or 1)
        return -k * math.pi if m[1] else k * math.pi
    return float(tok)


def _num(x: float) -> str:
    """A number as a person would write it: ``2``, ``0.09``, ``1e-09``, ``10000000``."""
    if float(x).is_integer() and abs(x) < 1e16:
        return str(int(x))
    return f"{x:.6g}"


def _rad(x: float) -> str:
    """A bound in radians, as a fraction of π when it is one (``π/2``)."""
    for n in (1, 2, 4):
        k = x * n / math.pi
        if k and abs(k - round(k)) < 1e-12:
            k_int = round(k)
            head = "-" if k_int < 0 else ""
            head += "π" if abs(k_int) == 1 else f"{abs(k_int)}π"
            return head if n == 1 else f"{head}/{n}"
    return _num(x)


def _ranges(table: str, specs: dict[str, str]) -> dict[str, RangeSpec]:
    return {f"{table}.{key}": Range.parse(spec) for key, spec in specs.items()}


def _colour_target(table: str) -> dict[str, RangeSpec]:
    """The colour keys of ``[detection]`` and of each ``[[detection.targets]]``."""
    return _ranges(
        table,
        {
            # The target's HSV hue (0 red, 120 green, 240 blue); negative: the other way
            # round the colour wheel (-20 = 340).
            "hue_deg": "[-360, 360] deg",
            # Signed degrees from hue_deg; beyond ±90° it is another colour altogether.
            "seed_hue_deg": "[-90, 90] deg",
            "seed_min_saturation": "[0, 1]",  # fractions of HSV's S and V
            "seed_min_value": "[0, 1]",
            "grow_hue_deg": "[-90, 90] deg",
            "grow_min_saturation": "[0, 1]",  # and at most the seed's
            "grow_min_value": "[0, 1]",
            # A Lab target's tolerances: CIE76 ΔE*ab from its lab colour (seed ≤ grow).
            "seed_max_delta_e": "(0, 200]",
            "grow_max_delta_e": "(0, 200]",
            "delta_e_lightness_factor": "[0.1, 10]",  # ΔL* counts 1/this
        },
    ) | {
        # A Lab target's colour: CIELAB, L* 0..100, a* and b* about -128..127.
        f"{table}.lab": PerItem(
            (
                ("L", Range.parse("[0, 100]")),
                ("a", Range.parse("[-128, 127]")),
                ("b", Range.parse("[-128, 127]")),
            )
        )
    }


def _camera_lens(table: str) -> dict[str, RangeSpec]:
    """The lens keys of ``[camera]`` (pinhole and fisheye) and of ``[camera.front]``/
    ``[camera.back]``."""
    return _ranges(
        table,
        # The ranges and why: core/camera.py LENS_RANGES (scenario.toml is checked
        # against the same).
        {key: lens_range_text(key) for key in LENS_RANGES},
    )


#: The valid range of every numeric setting, keyed ``"table.key"`` (see the comment above).
RANGES: dict[str, RangeSpec] = {
    **_colour_target("detection"),
    **_colour_target("detection.targets"),
    **_ranges(
        "detection",
        {
            "min_seed_px": "[1, inf) px",
            "min_area_px": "[0, inf) px",
            "min_angular_radius_rad": "[0, pi/2] rad",  # a sphere's angular radius ≤ 90°
            "max_detections": "[1, 1000]",
            "rim_width_px": "[1, 100] px",
            "rim_width_out_px": "[1, 100] px",
            "colour_sigma_px": "(0, 100] px",
            "refine_passes": "[0, 100]",
            "refine_min_shift_px": "[0, inf) px",
            # Colour distance in 0..255 units: at most 255·√3 ≈ 442 (black to white).
            "min_unmix_contrast": "[0, 442]",
            "coarse_cell_px": "[2, 256] px",
            "black_level": "[0, 255]",  # 8-bit grey level
            "min_score": "[0, 1]",  # a detector's confidence
            # Pushed boxes belong to the frame captured within this of theirs; a second
            # is several frames at any rate.
            "boxes_time_tolerance_s": "[0, 1] s",
            # Width, height: at least one 32-px stride of the YOLO network.
            "onnx_input_size": "[32, 8192] px",
            "onnx_nms_iou": "(0, 1]",  # 0 would suppress every overlap
        },
    ),
    # Memberships are clipped to [low, high]: the clip must hold the whole of [0, 1].
    "detection.membership_clip": PerItem(
        (("low", Range.parse("[-1, 0]")), ("high", Range.parse("[1, 2]")))
    ),
    **_ranges(
        "tracking",
        {
            "gate_rad": "[0, pi] rad",
            "gate_radius_factor": "[0, inf) radii",
            "max_log_size_change": "(0, inf)",  # |ln(α_new/α_old)|; 0 refuses any change
            "max_misses": "[0, 1000] frames",
            # Histories are sized for 60 fps (timebase.MAX_FRAME_RATE_HZ): 3600 per track.
            "history_s": "(0, 60] s",
        },
    ),
    **_ranges(
        "flow",
        {
            "n_points": "[1, 10000] points",
            "win_size_px": "[3, 99] px",
            "max_level": "[0, 8] levels",  # 2^8: a 256-px move per frame
            "max_level_predicted": "[0, 8] levels",
            "max_iterations": "[1, 1000]",
            "epsilon_px": "[0, 10] px",  # 0: always max_iterations
            "fb_threshold_px": "(0, 100] px",
            "max_patch_error": "(0, 255] grey levels",  # mean |difference| of 8-bit levels
            "fb_every": "[1, 100] frames",
            "min_eigen": "[0, inf) (grey levels/px)²",
            "sky_elevation_rad": "[-pi/2, pi/2] rad",
            "max_history": "[2, 10000] frames",
            "exclude_margin_px": "[0, 1000] px",
            "reseed_fraction": "(0, 1]",
            "reseed_interval": "[1, 1000] frames",
            "cull_cell_fraction": "[0, 1]",  # 0: never
            "downscale": "[0, 16]",  # 0: automatic
        },
    ),
    **_ranges(
        "egomotion",
        {
            "n_hypotheses": "[1, 10000]",
            # Bearing errors: beyond 90° every point is an inlier of any direction.
            "ransac_threshold_rad": "(0, pi/2] rad",
            "inlier_threshold_rad": "(0, pi/2] rad",
            "bearing_sigma_rad": "(0, pi/2] rad",
            "systematic_rad": "[0, pi/2] rad",
            "min_parallax_rad": "[0, pi] rad",
            "restart_ratio": "[0, inf)",
            "min_inliers": "[2, 10000] points",  # a direction needs two bearing pairs
            "min_inlier_ratio": "[0, 1]",
            "rotation_prior_rad": "[0, pi] rad",  # 0: no rotation estimated
            "refine_iterations": "[1, 100]",
            "max_refine_iterations": "[1, 100]",
            "step_tolerance_rad": "[0, pi] rad",
            "max_sigma_rad": "(0, pi] rad",
            "position_sigma_m": "[0, 100] m",
            "fuse_gate": "(0, inf) σ",
        },
    ),
    **_ranges(
        "classifier",
        {
            # Histories hold the longest interval at 60 fps: 10 s keeps them at 600 frames
            # (the paper: 1 s; the GCS parameter TCM_INTERVAL_S has this range too).
            "interval_s": "(0, 10] s",
            "extra_intervals_s": "(0, 10] s",
            "hold_s": "[0, 10] s",
            "min_interval_s": "(0, 10] s",
            "interval_tolerance_s": "[0, 10] s",
            # δ = |R_img - R_geo|, of ratios near 1: as TCM_THRESH, 0..2 (above 2 nothing
            # would ever be moving).
            "tcm_threshold": "[0, 2]",
            "ecm_threshold_rad": "[0, pi/2] rad",  # Ω is at most 90°
            "bsm_threshold": "[0, inf) px",
            # θ from the translation axis; head-on is θ < min_theta or > π - min_theta,
            # so at 90° everything would be head-on.
            "min_theta_rad": "[0, pi/2) rad",
            "head_on_extent_fraction": "[0, 1]",  # of the angular radius; 0: off
            "min_baseline_m": "[0, inf) m",  # 0: off
            "min_flow_parallax_rad": "[0, pi] rad",  # 0: off
            "hover_max_baseline_m": "[0, inf) m",
            "max_disparity_sigma": "(0, inf)",  # 0 would refuse every pair
            "min_range_parallax_rad": "[0, pi] rad",
            # Fit window of a pair's ends; unset: per backend (0 colour, 0.48 s boxes/onnx).
            "fit_window_s": "[0, 2] s",
        },
    ),
    **_ranges(
        "ttc",
        {
            "window_s": "(0, 10] s",
            "min_span_s": "[0, 10] s",  # and below window_s
            "min_samples": "[3, 1000] samples",  # a slope and its spread need three
            "max_ttc_s": "(0, 3600] s",
            "min_significance": "[0, inf)",
            "collision_miss_radii": "[0, inf) radii",
            "collision_max_ttc_s": "[0, 3600] s",
        },
    ),
    **_ranges(
        "bsm",
        {
            "pixel_threshold": "[0, 255] grey levels",
            "window_radius_factor": "[0, inf) radii",
            "ground_d_m": "[-10000, 10000] m",  # NED down: from below sea to above Everest
            "min_window_px": "[0, 1000] px",
        },
    ),
    **_ranges("mavlink", {"signing_link_id": "[0, 255]"}),  # a uint8 of the signature
    **_ranges(
        "mavlink.endpoint",
        {
            "component_id": "[1, 255]",  # 0 is the broadcast id
            "default_system_id": "[1, 255]",
            "heartbeat_interval_us": "[10000, 10000000] µs",
            "autopilot_timeout_us": "[100000, 60000000] µs",
            # Autopilots stream at most at their main loop's rate (ArduCopter 400 Hz).
            "attitude_rate_hz": "(0, 500] Hz",
            "position_rate_hz": "(0, 500] Hz",
            # Periods: 10 ms (100 Hz) to a minute.
            "request_retry_us": "[10000, 60000000] µs",
            "rate_check_us": "[10000, 60000000] µs",
            "timesync_interval_us": "[10000, 60000000] µs",
            "timesync_fast_interval_us": "[10000, 60000000] µs",
            "health_interval_us": "[10000, 60000000] µs",
            "obstacle_interval_us": "[10000, 60000000] µs",
            "fresh_frame_us": "[1000, 60000000] µs",
            "statustext_min_interval_us": "[10000, 60000000] µs",  # paces the radio link
            "statustext_repeat_us": "[0, 3600000000] µs",
            "collision_clear_us": "[0, 60000000] µs",
            "statustext_queue": "[1, 1000] texts",
        },
    ),
    **_ranges("daemon", DAEMON_RANGES),  # the service keeps them (service/daemon_config.py)
    **_ranges(
        "sim",
        {
            "seed": "[0, 4294967295]",  # NumPy's legacy seeds are 32-bit
            "telemetry_noise": "[0, 100]",
            "ekf_origin_delay_us": "[0, 600000000] µs",
        },
    ),
    **_ranges(
        "camera",
        {
            "azimuth_min_deg": "[-360, 360] deg",  # and less than azimuth_max_deg
            "azimuth_max_deg": "[-360, 360] deg",  # within 360° of azimuth_min_deg
            "elevation_max_deg": "[-90, 90] deg",
            "elevation_min_deg": "[-90, 90] deg",
            "fps": "(0, 1000] fps",
            "exposure": "-1 or (0, 100000] × 100 µs",  # V4L2 exposure_absolute; -1: auto
            "sim_noise_dn": "[0, 255] DN",
            "sim_seed": "[0, 4294967295]",
            "sim_contact_s": "[1, 120] s",
            "sim_ball_speed_mps": "[0, 50] m/s",
            "sim_side_deg": "[-180, 180] deg",
            "sim_heading_deg": "[-360, 360] deg",
            "sim_ball_radius_m": "(0, 10] m",
        },
    ),
    "camera.sim_static_balls": PerItem(
        (
            ("n_m", Range.parse("[-10000, 10000] m")),
            ("e_m", Range.parse("[-10000, 10000] m")),
            ("d_m", Range.parse("[-10000, 10000] m")),
            ("radius_m", Range.parse("(0, 10] m")),
        )
    ),
    **_camera_lens("camera"),
    **_camera_lens("camera.front"),
    **_camera_lens("camera.back"),
    **_ranges(
        "logging",
        {
            "jpeg_quality": "[1, 100]",
            "queue_items": "[1, 1000000] items",
            "chunk_size_bytes": "[1024, 1073741824] bytes",
            "flush_interval_s": "(0, 60] s",
            "rotate_size_mb": "(0, 1000000] MB",
            "rotate_interval_s": "(0, 604800] s",  # a week
            "min_free_mb": "[0, 1000000] MB",
        },
    ),
}


def _stage_tables() -> dict[type, str]:
    hints = typing.get_type_hints(PipelineConfig)
    return {
        hints[f.name]: f.name
        for f in dataclasses.fields(PipelineConfig)
        if dataclasses.is_dataclass(hints[f.name])
    }


#: The :data:`RANGES` table each dataclass is read from (nested ones by their parent).
_RANGE_TABLES: dict[type, str] = {
    PipelineConfig: "",  # its stages are tables of their own: "classifier", ...
    **_stage_tables(),
    MavlinkConfig: "mavlink",
    typing.get_type_hints(MavlinkConfig)["endpoint"]: "mavlink.endpoint",
    DaemonConfig: "daemon",
    SimConfig: "sim",
    CameraSourceConfig: "camera",
    LoggingConfig: "logging",
}


def _describe(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _coerce(value: Any, tp: Any, where: str) -> Any:
    """Check ``value`` against annotation ``tp``; convert lists to tuples, ints to floats."""
    origin = typing.get_origin(tp)
    if origin is typing.Literal:
        allowed = typing.get_args(tp)
        if value not in allowed:
            raise ConfigError(f"{where} must be one of {list(allowed)}, got {value!r}")
        return value
    if origin in (typing.Union, types.UnionType):
        errors = []
        for arm in typing.get_args(tp):
            if arm is type(None):
                continue
            try:
                return _coerce(value, arm, where)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if errors else f"{where}: bad value {value!r}")
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where} must be a list, got {value!r}")
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
        if len(args) != len(value):
            raise ConfigError(f"{where} must have {len(args)} items, got {len(value)}")
        return tuple(_coerce(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where} must be true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where} must be an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where} must be a number, got {value!r}")
        if not math.isfinite(float(value)):
            raise ConfigError(f"{where} must be finite, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where} must be a string, got {value!r}")
        return value
    return value


def _key_at(where: str, key: str) -> str:
    """Where ``key`` of the table at ``where`` is: ``"c.toml: [daemon] state_dir"`` (a
    table given as ``[name]``) or ``"camera.fps"`` (a bare name, for other callers)."""
    return f"{where} {key}" if where.endswith("]") else f"{where}.{key}"


def _table_at(where: str, key: str) -> str:
    """Where the nested table ``key`` is: ``"c.toml: [mavlink.endpoint]"``."""
    return f"{where[:-1]}.{key}]" if where.endswith("]") else f"{where}.{key}"


def _join(prefix: str, key: str) -> str:
    return f"{prefix}.{key}" if prefix else key


def build_dataclass(cls: type, table: Any, where: str, ranges_key: str | None = None) -> Any:
    """Instantiate dataclass ``cls`` from a TOML table, defaults for absent keys.

    Every value is type-checked, then range-checked against :data:`RANGES` under
    ``ranges_key`` (default: the table ``cls`` is read from, e.g. ``"classifier"``; no
    check for a class of no table), and only then is the dataclass built (whose own
    checks are left with the relations between fields).
    """
    if not isinstance(table, dict):
        raise ConfigError(f"{where} must be a table")
    prefix = _RANGE_TABLES.get(cls) if ranges_key is None else ranges_key
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    kwargs: dict[str, Any] = {}
    given: dict[str, tuple[str, Any, Any]] = {}  # field -> (key, value) as written, value
    errors: list[ConfigError] = []  # every key's, reported together
    for key, value in table.items():
        try:
            _build_field(key, value, where, prefix, fields, hints, kwargs, given)
        except ConfigError as exc:
            errors.append(exc)
    if prefix is not None:

        def lookup(name: str) -> Any:
            if name in kwargs:
                return kwargs[name]
            f = fields.get(name)
            return None if f is None or f.default is dataclasses.MISSING else f.default

        try:
            _check_ranges(prefix, where, given, lookup, list(fields))
        except ConfigError as exc:
            errors.append(exc)
    _raise_all(errors)  # the relations between fields are checked on sound values only
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{where}: {exc}") from None


def _build_field(
    key: str,
    value: Any,
    where: str,
    prefix: str | None,
    fields: dict[str, dataclasses.Field[Any]],
    hints: dict[str, Any],
    kwargs: dict[str, Any],
    given: dict[str, tuple[str, Any, Any]],
) -> None:
    """One key of :func:`build_dataclass`'s table: its checked value into ``kwargs`` (and
    ``given``, for the range checks), or a :class:`ConfigError` naming it."""
    name, val = key, value
    if key not in fields and key.endswith("_deg") and f"{key[:-4]}_rad" in fields:
        name = f"{key[:-4]}_rad"
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{_key_at(where, key)} must be a number of degrees, got {value!r}")
        val = math.radians(value)
    if name not in fields:
        known = ", ".join(sorted(fields))
        raise ConfigError(f"{where}: unknown key {key!r} (known keys: {known})")
    if name in kwargs:
        raise ConfigError(f"{where}: {name} given twice (as _rad and _deg)")
    tp = hints[name]
    if dataclasses.is_dataclass(tp):
        nested = None if prefix is None else _join(prefix, key)
        kwargs[name] = build_dataclass(tp, val, _table_at(where, key), nested)  # type: ignore[arg-type]
        return
    kwargs[name] = _coerce(val, tp, _key_at(where, key))
    given[name] = (key, kwargs[name], value)
    if prefix is not None and _is_table_list(tp) and isinstance(val, list):
        # [[table.key]]: each table's values against RANGES["table.key.x"]
        # (built by the dataclass itself, which checks their types).
        errors: list[ConfigError] = []
        for i, item in enumerate(val):
            if isinstance(item, dict):
                items = {k: (k, v, v) for k, v in item.items()}
                at = _table_at(where, f"{key}[{i}]")
                try:
                    _check_ranges(_join(prefix, key), at, items, item.get, list(item))
                except ConfigError as exc:
                    errors.append(exc)
        _raise_all(errors)


def _is_number(x: object) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _is_table_list(tp: Any) -> bool:
    """``tuple[SomeDataclass, ...]``: a TOML array of tables."""
    args = typing.get_args(tp)
    return (
        typing.get_origin(tp) is tuple
        and len(args) == 2
        and args[1] is Ellipsis
        and dataclasses.is_dataclass(args[0])
    )


def _leaves(value: Any, index: str = "") -> typing.Iterator[tuple[str, float]]:
    """The numbers of a value and their indices (``"[0][3]"``); other items are skipped
    (their type is someone else's error)."""
    if _is_number(value):
        yield index, float(value)
    elif isinstance(value, list | tuple):
        for i, v in enumerate(value):
            yield from _leaves(v, f"{index}[{i}]")


def _first_bad(
    spec: RangeSpec, value: Any, hi: float | None, deg: bool
) -> tuple[str, float, Range, str] | None:
    """The first number of ``value`` outside ``spec``: (index, number, its range, label)."""
    if isinstance(spec, PerItem):
        if not isinstance(value, list | tuple):
            return None
        # One list of positions (membership_clip), or a list of them (sim_static_balls).
        nested = any(isinstance(v, list | tuple) for v in value)
        items = [(f"[{i}]", v) for i, v in enumerate(value)] if nested else [("", value)]
        for index, item in items:
            for j, (label, r) in enumerate(spec.items):
                if isinstance(item, list | tuple) and j < len(item) and _is_number(item[j]):
                    if not r.admits(float(item[j])):
                        return f"{index}[{j}]", float(item[j]), r, f" ({label})"
        return None
    eps = 1e-12 if deg else 0.0  # a bound written in degrees may round in radians
    for index, x in _leaves(value):
        if not spec.admits(x, hi, eps=eps):
            return index, x, spec, ""
    return None


def _check_ranges(
    prefix: str,
    where: str,
    given: dict[str, tuple[str, Any, Any]],
    lookup: typing.Callable[[str], Any],
    names: list[str],
) -> None:
    """Refuse every value of ``given`` (name -> (key as written, value, value as
    written)) outside its range in :data:`RANGES` under ``prefix``, naming each key
    (the first item of a list that is out of range).

    ``lookup(name)`` is the value a field will have (given or default), for ranges bound
    by another key (``cx`` by ``width``): those are checked after the others, and also
    when only the other key was given (a default ``cx = 320`` with ``width = 100``).
    """

    def bound_by(name: str) -> str:
        spec = RANGES.get(_join(prefix, name))
        return spec.hi_key if isinstance(spec, Range) else ""

    order = [n for n in given if not bound_by(n)] + [n for n in names if bound_by(n)]
    errors: list[ConfigError] = []
    for name in order:
        spec = RANGES.get(_join(prefix, name))
        if spec is None:
            continue
        hi_key = bound_by(name)
        if name in given:
            key, value, shown = given[name]
            default = ""
        elif hi_key in given:
            key, value, shown, default = name, lookup(name), lookup(name), " (default)"
        else:
            continue
        hi = None
        if hi_key:
            hi = lookup(hi_key)
            if not _is_number(hi):
                continue  # the other key's type error is reported instead
            hi = float(hi)
        deg = key != name  # x_deg written for field x_rad
        bad = _first_bad(spec, value, hi, deg)
        if bad is None:
            continue
        index, x, r, label = bad
        if not index and _is_number(shown):
            x = shown  # as written (in degrees for x_deg)
        errors.append(
            ConfigError(
                f"{_key_at(where, key)}{index}{label} = {_num(x)}{default} is out of range: "
                f"must be {r.must(deg=deg, hi=hi)}",
                _join(prefix, key),
            )
        )
    _raise_all(errors)


def _pipeline_table(doc: dict[str, Any], where: str) -> dict[str, Any]:
    """The flat TOML layout ([pipeline] plus one table per stage) as one nested table."""
    table = dict(doc.get("pipeline", {}))
    stage_names = [
        f.name for f in dataclasses.fields(PipelineConfig) if f.name != "egomotion_source"
    ]
    for name in stage_names:
        if name in doc:
            if name in table:
                raise ConfigError(f"{where}: [{name}] given both as a table and inside [pipeline]")
            table[name] = doc[name]
    return table


#: Environment variables ``TCM_COMPANION__TABLE__KEY=value`` override the file
#: (e.g. ``TCM_COMPANION__MAVLINK__URL=serial:/dev/ttyAMA0:921600``); CLI ``--set
#: table.key=value`` overrides both. Values are read as TOML (``0.1``, ``true``,
#: ``[1, 2]``, ``"text"``), and as plain text when they are not valid TOML. A camera of
#: a rig (``[[cameras]]``) is ``cameras.NAME.key`` (``TCM_COMPANION__CAMERAS__NAME__KEY``,
#: the name matched without regard to case); ``camera.key`` of a rig is refused.
ENV_PREFIX = "TCM_COMPANION__"


def _toml_value(text: str) -> Any:
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def _rig_override(doc: dict[str, Any], path: list[str], origin: str) -> list[str]:
    """``path`` of an override for the rig's ``[[cameras]]``: ``cameras.NAME.KEY`` ->
    ``["cameras", "<i>", "KEY"]`` (the index of the camera named NAME, case-insensitive
    for the environment's upper-case names); ``camera.KEY`` of a rig is refused."""
    cams = doc.get("cameras")
    names = [t.get("name") for t in cams if isinstance(t, dict)] if isinstance(cams, list) else []
    shown = ", ".join(str(n) for n in names)
    if path[0] == "camera":
        if not isinstance(cams, list):
            return path
        raise ConfigError(
            f"{origin}: this configuration is a rig of [[cameras]] ({shown}): set one"
            f" camera's key as cameras.NAME.{'.'.join(path[1:])}"
        )
    if not isinstance(cams, list):
        raise ConfigError(
            f"{origin}: cameras.NAME.KEY sets a camera of [[cameras]], and this configuration"
            " has none (one camera: set camera.KEY)"
        )
    if len(path) < 3:
        raise ConfigError(f"{origin}: expected cameras.NAME.KEY (cameras: {shown})")
    matches = [i for i, n in enumerate(names) if n == path[1]] or [
        i for i, n in enumerate(names) if isinstance(n, str) and n.lower() == path[1].lower()
    ]
    if len(matches) != 1:
        raise ConfigError(f"{origin}: no camera named {path[1]!r} in [[cameras]] ({shown})")
    return ["cameras", str(matches[0]), *path[2:]]


def _set_dotted(doc: dict[str, Any], path: list[str], value: Any, origin: str) -> str:
    """Set ``path`` of ``doc`` to ``value``; the dotted key set, as errors name it
    (``cameras.NAME.KEY`` with the camera's name as the file writes it)."""
    if path[0] in ("camera", "cameras"):
        path = _rig_override(doc, path, origin)
    dotted = ".".join(path)
    node = doc
    if path[0] == "cameras":  # ["cameras", index, key...]: that camera's table
        node = doc["cameras"][int(path[1])]
        path = path[2:]
        dotted = ".".join(["cameras", str(node["name"]), *path])
    for part in path[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise ConfigError(f"{origin}: {'.'.join(path)}: {part} is not a table")
        node = child
    key = path[-1]
    # An override of x_rad replaces the file's x_deg (and the other way round).
    for unit, other in (("_rad", "_deg"), ("_deg", "_rad")):
        if key.endswith(unit):
            node.pop(f"{key[: -len(unit)]}{other}", None)
    node[key] = value
    return dotted


def apply_overrides(
    doc: dict[str, Any],
    environ: typing.Mapping[str, str] | None = None,
    sets: typing.Sequence[str] = (),
) -> dict[str, str]:
    """Apply environment then ``--set`` overrides to ``doc`` in place.

    Returns ``{dotted key: where it was set}`` so that errors can name the variable or
    flag that set a bad value.
    """
    origins: dict[str, str] = {}
    for name, raw in sorted((environ or {}).items()):
        if not name.startswith(ENV_PREFIX):
            continue
        path = [p.lower() for p in name[len(ENV_PREFIX) :].split("__") if p]
        if len(path) < 2:
            raise ConfigError(f"environment {name}: expected {ENV_PREFIX}TABLE__KEY")
        dotted = _set_dotted(doc, path, _toml_value(raw), f"environment {name}")
        origins[dotted] = f"environment {name}"
    for item in sets:
        key, eq, raw = item.partition("=")
        path = [p for p in key.strip().split(".") if p]
        if not eq or len(path) < 2:
            raise ConfigError(f"--set {item!r}: expected TABLE.KEY=VALUE")
        dotted = _set_dotted(doc, path, _toml_value(raw.strip()), f"--set {item}")
        origins[dotted] = f"--set {key.strip()}"
    return origins


#: The largest configuration file read (the repository's is ~20 KiB).
MAX_CONFIG_BYTES = 1024 * 1024


def load_config(
    path: str | Path | None,
    *,
    environ: typing.Mapping[str, str] | None = None,
    sets: typing.Sequence[str] = (),
) -> AppConfig:
    """Read ``config.toml`` (``None``: built-in defaults), then apply overrides.

    Precedence: ``sets`` (CLI) > ``environ`` (``TCM_COMPANION__…``) > file > defaults.
    """
    doc: dict[str, Any] = {}
    where = "config"
    if path is not None:
        p = Path(path)
        where = str(p)
        try:
            with open(p, "rb") as fh:
                raw = fh.read(MAX_CONFIG_BYTES + 1)  # /dev/zero would never end
            if len(raw) > MAX_CONFIG_BYTES:
                raise ConfigError(
                    f"{p}: larger than {MAX_CONFIG_BYTES // 1024} KiB: not a configuration file"
                )
            # A UTF-8 byte order mark (Windows editors write one) is not TOML: skip it.
            doc = tomllib.loads(raw.removeprefix(b"\xef\xbb\xbf").decode("utf-8"))
        except FileNotFoundError:
            raise ConfigError(f"{p}: no such file") from None
        except IsADirectoryError:
            raise ConfigError(f"{p}: is a directory, not a TOML file") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{p}: {exc}") from None
        except UnicodeDecodeError:
            from .io.scenario import not_utf8

            raise ConfigError(f"{p}: {not_utf8(p)}") from None
        except OSError as exc:  # permission denied, an I/O error
            raise ConfigError(f"{p}: cannot read: {exc.strerror or exc}") from None
    origins = apply_overrides(doc, environ, sets)
    try:
        return config_from_dict(doc, where)
    except ConfigError as exc:
        raise _combined([_name_origin(e, origins) for e in exc.errors]) from None


def _name_origin(exc: ConfigError, origins: dict[str, str]) -> ConfigError:
    """``exc`` naming the environment variable or ``--set`` that set the bad value, if
    one did (``origins``: dotted key -> what set it)."""
    msg = str(exc)
    if exc.key:  # one value at fault: name what set it, if not the file
        origin = origins.get(exc.key) or origins.get(f"pipeline.{exc.key}")
        if origin:
            msg += f" (set by {origin})"
    else:
        for key, origin in origins.items():
            table, _, name = key.rpartition(".")
            tables = {f"[{table}]", f"[{table.removeprefix('pipeline.')}]"}
            if any(t in msg for t in tables) and re.search(rf"\b{re.escape(name)}\b", msg):
                msg += f" (set by {origin})"
    return ConfigError(msg, exc.key)


_TABLES = ("pipeline", "mavlink", "daemon", "sim", "camera", "cameras", "logging")

#: Keys that are no longer settings, and what replaced them. Still accepted, so that an
#: older config.toml (or a flight log's recorded configuration) loads, but ignored: each
#: is named in a warning when given (:func:`drop_deprecated`). A table that held nothing
#: else (``[replay]``) may stay in the file, empty.
DEPRECATED_KEYS: dict[tuple[str, str], str] = {
    # Replay gave each frame the telemetry received up to this long after its capture,
    # apart from the daemon's own wait; both now read the daemon's.
    ("replay", "telemetry_wait_us"): (
        "[daemon] attitude_wait_max_us (replay gives each frame the telemetry the daemon"
        " would have had, waiting as long as the daemon does)"
    ),
}


def drop_deprecated(doc: dict[str, Any], where: str = "config") -> tuple[dict[str, Any], list[str]]:
    """``doc`` without the :data:`DEPRECATED_KEYS` (and without a table they leave empty),
    and one warning for each that was given, naming it and its replacement."""
    out = dict(doc)
    warnings: list[str] = []
    for (table, key), replacement in DEPRECATED_KEYS.items():
        section = out.get(table)
        if not isinstance(section, dict):
            continue
        if key in section:
            section = {k: v for k, v in section.items() if k != key}
            out[table] = section
            warnings.append(
                f"{_key_at(f'{where}: [{table}]', key)} is deprecated and ignored; its"
                f" replacement is {replacement}: remove it"
            )
        if not section and table not in _TABLES:
            del out[table]  # a table of deprecated keys only, now empty
    return out, warnings


def config_from_dict(doc: dict[str, Any], where: str = "config") -> AppConfig:
    """The configuration of a parsed TOML document; a deprecated key is dropped with a
    warning logged (:func:`drop_deprecated`)."""
    doc, warnings = drop_deprecated(doc, where)
    for w in warnings:
        log.warning("%s", w)
    known = set(_TABLES) | {f.name for f in dataclasses.fields(PipelineConfig)}
    errors: list[ConfigError] = []  # every table's, reported together
    for key in doc:
        if key not in known:
            errors.append(
                ConfigError(f"{where}: unknown table [{key}] (known: {', '.join(sorted(known))})")
            )

    def table(build: typing.Callable[..., Any], *args: Any) -> Any:
        try:
            return build(*args)
        except ConfigError as exc:
            errors.append(exc)
            return None

    def pipeline_config() -> PipelineConfig:
        stages = _pipeline_table(doc, where)  # may refuse a stage given twice
        return build_dataclass(PipelineConfig, stages, f"{where}: [pipeline]")

    pipeline = table(pipeline_config)
    tables = {
        name: table(build_dataclass, cls, doc.get(name, {}), f"{where}: [{name}]")
        for name, cls in (
            ("mavlink", MavlinkConfig),
            ("daemon", DaemonConfig),
            ("sim", SimConfig),
            ("logging", LoggingConfig),
        )
    }
    cameras = _cameras_from_doc(doc, where, errors)
    if tables["mavlink"] is not None:
        errors += _url_errors(tables["mavlink"].url, f"{where}: [mavlink]", "url", "mavlink.url")
    try:
        _raise_all(errors)  # the checks across tables need every table sound
        problem = tables["daemon"].feed_problem(pipeline.detection.backend, len(cameras))
        if problem is not None:
            key, why = problem
            raise ConfigError(f"{where}: [daemon] {why}", f"daemon.{key}")
    except ConfigError as exc:
        renamed = []
        for e in exc.errors:
            msg = str(e)
            # Report stage keys under their own table name, as the user wrote them.
            for name in (f.name for f in dataclasses.fields(PipelineConfig)):
                msg = msg.replace(f"[pipeline.{name}]", f"[{name}]")
                msg = msg.replace(f"[pipeline.{name}.", f"[{name}.")
            renamed.append(ConfigError(msg, e.key))
        _raise_all(renamed)
    return AppConfig(pipeline=pipeline, cameras=cameras, **tables)


def _rig_table_at(where: str, index: int, table: Any) -> str:
    """Where camera ``index`` of ``[[cameras]]`` is, for its errors: ``"c.toml:
    [cameras.front]"`` by its name (as ``--set cameras.front.fx=…`` names it), or
    ``"c.toml: [cameras[2]]"`` by position when it has no usable name."""
    name = table.get("name") if isinstance(table, dict) else None
    if isinstance(name, str) and name:
        shown = name if re.fullmatch(r"[A-Za-z0-9_-]+", name) else f'"{name}"'
        return f"{where}: [cameras.{shown}]"
    return f"{where}: [cameras[{index}]]"


def _cameras_from_doc(
    doc: dict[str, Any], where: str, errors: list[ConfigError]
) -> tuple[CameraConfig, ...]:
    """The rig: ``[[cameras]]`` (each table the keys of ``[camera]``, ``name`` required
    and unique, at most :data:`MAX_CAMERAS`) or a lone ``[camera]`` (a rig of one).
    Errors are appended to ``errors`` (the result is then meaningless)."""
    if "cameras" not in doc:
        try:
            return (camera_config_from_table(doc.get("camera", {}), f"{where}: [camera]"),)
        except ConfigError as exc:
            errors.append(exc)
            return _one_camera()
    if "camera" in doc:
        errors.append(
            ConfigError(
                f"{where}: both [camera] and [[cameras]] given: a rig is [[cameras]] tables"
                " only (one camera: [camera] alone)"
            )
        )
        return _one_camera()
    tables = doc["cameras"]
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        errors.append(
            ConfigError(
                f"{where}: cameras must be an array of tables ([[cameras]], one per camera)"
            )
        )
        return _one_camera()
    if not 1 <= len(tables) <= MAX_CAMERAS:
        errors.append(
            ConfigError(f"{where}: [[cameras]]: 1 to {MAX_CAMERAS} cameras, got {len(tables)}")
        )
        return _one_camera()
    cams: list[CameraConfig] = []
    seen: dict[str, int] = {}
    for i, t in enumerate(tables):
        at = _rig_table_at(where, i, t)
        name = t.get("name")
        if "name" not in t:
            errors.append(
                ConfigError(
                    f"{at} name is required (camera {i} of [[cameras]]: each camera is named)"
                )
            )
        elif isinstance(name, str) and name in seen:
            j = seen[name]
            errors.append(
                ConfigError(
                    f"{where}: [[cameras]] name = {name!r} given twice (cameras {j} and {i}):"
                    " camera names must be unique"
                )
            )
        elif isinstance(name, str):
            seen[name] = i
        try:
            cams.append(camera_config_from_table(t, at))
        except ConfigError as exc:
            prefix = f"cameras.{name}." if isinstance(name, str) and name else f"cameras.{i}."
            errors.extend(
                ConfigError(str(e), prefix + e.key.removeprefix("camera.") if e.key else "")
                for e in exc.errors
            )
    return tuple(cams) if len(cams) == len(tables) else _one_camera()


#: Camera sources that make one camera of the whole run, and why they cannot be one
#: camera of a rig of several (yet).
ONE_CAMERA_SOURCES: dict[str, str] = {
    "sim": "renders the one camera of the simulated flight; fly a simulated rig with"
    " `tcm-companion sitl --rig NAME`",
    "scenario": "plays a one-camera scenario's frames and telemetry; replay a scenario"
    " with `tcm-companion replay`",
    "dual_fisheye": "stitches two fisheyes into the one panorama of a one-camera"
    " configuration; give each camera of a rig its own source",
}


def rig_source_problems(config: AppConfig, where: str = "config") -> list[ConfigError]:
    """Why ``tcm-companion run`` cannot run this rig's sources, one error per camera at
    fault (empty for one camera): a source that makes the run's one camera
    (:data:`ONE_CAMERA_SOURCES`), or two cameras opening one device or one
    ``sim_url``. Not refused by the loader: a simulated rig (``sitl``) and the replay of
    its flight log read such a configuration."""
    if len(config.cameras) < 2:
        return []
    errors: list[ConfigError] = []
    opened: dict[tuple[str, str], str] = {}
    for cam in config.cameras:
        src = cam.source
        at = f"{where}: [cameras.{cam.name}]"
        if src.source in ONE_CAMERA_SOURCES:
            why = ONE_CAMERA_SOURCES[src.source]
            errors.append(
                ConfigError(
                    f'{at} source = "{src.source}" {why} (one camera: [camera])',
                    f"cameras.{cam.name}.source",
                )
            )
            continue
        key = {"device": ("device", src.device.strip()), "sim_autopilot": ("sim_url", src.sim_url)}
        if src.source in key:
            which, value = key[src.source]
            other = opened.setdefault((which, value), cam.name)
            if other != cam.name:
                errors.append(
                    ConfigError(
                        f"{at} {which} = {value!r} is camera {other}'s too: each camera"
                        " opens its own",
                        f"cameras.{cam.name}.{which}",
                    )
                )
    return errors


def _url_errors(url: str, where: str, key: str, dotted: str) -> list[ConfigError]:
    """The error of a link URL setting (``[mavlink] url``, ``[camera] sim_url``) that is
    not one (:func:`~tcm_companion.io.transports.check_url`: scheme, host, port, baud
    rate, device path), as a list: empty when it is sound."""
    from .io.transports.urls import check_url

    try:
        check_url(url)
    except ValueError as exc:
        why = str(exc).removeprefix(f"{url!r}: ")
        return [ConfigError(f"{_key_at(where, key)} = {url!r} is not a link URL: {why}", dotted)]
    return []


def _plain(value: Any) -> Any:
    """Dataclasses, tuples and camera models as TOML-writable values."""
    if hasattr(value, "to_dict") and callable(value.to_dict):
        return _plain(value.to_dict())
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        # A field left None means "unset" (e.g. a per-backend default): TOML has no null,
        # so it is left out, and reading the text back leaves it unset again.
        return {
            f.name: _plain(getattr(value, f.name))
            for f in dataclasses.fields(value)
            if f.init and getattr(value, f.name) is not None
        }
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    return value


def config_to_toml(config: AppConfig) -> str:
    """The configuration in force, as TOML (the camera's model and source in one table)."""
    import tomli_w

    doc = _plain(config)
    cams = [{"name": c["name"], **c["model"], **c["source"]} for c in doc.pop("cameras")]
    # One camera: [camera] (as before rigs); several: [[cameras]].
    rig = {"cameras": cams} if len(cams) > 1 else {"camera": cams[0]}
    doc |= rig
    return tomli_w.dumps(doc)
