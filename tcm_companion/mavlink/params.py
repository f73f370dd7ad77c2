"""Our tunables as MAVLink parameters: the table, range checks, and the config mapping.

Every parameter travels as ``MAV_PARAM_TYPE_REAL32`` (integers are whole-valued
floats), so no ground station has to guess between the bytewise and C-cast encodings.
Names are at most 16 characters, prefixed ``TCM_``. Values are range-checked; a
``PARAM_SET`` out of range is refused (the current value is sent back, as the protocol
asks) and counted. Persistence is the edge's job: the endpoint reports changes, and
:func:`config_with_params` turns the values into the pipeline's configuration.

Durations are in seconds and their names say so (``TCM_INTERVAL_S``, ``TCM_HOLD_S``); they
replace ``TCM_INTERVAL`` and ``TCM_HOLD``, which counted frames (a frame is 40 ms only at
25 Hz). New names rather than new units under the old ones, so that a frame count stored
on the companion or saved in a GCS parameter file is refused as unknown (and reported)
instead of being read as seconds: an old ``TCM_HOLD`` of 3 frames would have become 3 s.

A parameter that stands for a configuration key (:data:`CONFIG_KEYS`) has that key's
range (``config.py`` states it; a test holds the two together), so every value
``config.toml`` admits is one the parameter admits too: a configured 3-s interval is
used, not replaced by the parameter's default. Values that fit their own ranges but not
each other (a seed hue range leaving the grow range, a zero interval) are refused by the
Companion's check of the whole table.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass

from ..core.pipeline import PipelineConfig

_SOURCES = ("vision", "autopilot", "fused")


@dataclass(frozen=True)
class ParamSpec:
    name: str
    default: float
    minimum: float
    maximum: float
    integer: bool
    description: str


PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("TCM_THRESH", 0.09, 0.0, 2.0, False, "TCM disparity threshold (moving above)"),
    ParamSpec("TCM_INTERVAL_S", 1.0, 0.0, 10.0, False, "time between compared observations, s"),
    ParamSpec("TCM_HOLD_S", 0.48, 0.0, 10.0, False, "time a disparity keeps counting, s"),
    ParamSpec("TCM_HUE_MIN", -15.0, -90.0, 90.0, False, "detector seed hue lower bound, deg"),
    ParamSpec("TCM_HUE_MAX", 12.0, -90.0, 90.0, False, "detector seed hue upper bound, deg"),
    ParamSpec("TCM_SAT_MIN", 0.70, 0.0, 1.0, False, "detector seed minimum saturation"),
    ParamSpec("TCM_EGO_SRC", 2, 0, 2, True, "egomotion source: 0 vision, 1 autopilot, 2 fused"),
    ParamSpec("TCM_TTC_ALARM", 3.0, 0.0, 60.0, False, "time to contact alarm, s (0: off)"),
    ParamSpec("TCM_OUT_STATUS", 1, 0, 1, True, "send TCM_OBJECT_STATUS"),
    ParamSpec("TCM_OUT_HEALTH", 1, 0, 1, True, "send TCM_PIPELINE_HEALTH"),
    ParamSpec("TCM_OUT_OBST", 0, 0, 1, True, "send OBSTACLE_DISTANCE (proximity)"),
    ParamSpec("TCM_OUT_OBST3D", 0, 0, 1, True, "send OBSTACLE_DISTANCE_3D (ArduPilot)"),
    ParamSpec("TCM_OUT_ADSB", 0, 0, 1, True, "send ADSB_VEHICLE for moving objects"),
    ParamSpec("TCM_OBJ_RADIUS", 0.375, 0.0, 50.0, False, "object radius, m (ranges of movers)"),
)
BY_NAME: dict[str, ParamSpec] = {p.name: p for p in PARAMS}
assert all(len(p.name) <= 16 for p in PARAMS)


class ParamTable:
    """Current values in table order; ``set`` range-checks and reports refusals."""

    def __init__(
        self,
        initial: Mapping[str, float] | None = None,
        defaults: Mapping[str, float] | None = None,
    ) -> None:
        """``defaults``: the values the configuration gives (:func:`params_from_config`),
        else each parameter's own default; ``initial``: values set over MAVLink before
        (the persisted ones), which take precedence."""
        self.values: dict[str, float] = {p.name: float(p.default) for p in PARAMS}
        self.ignored_defaults = [n for n, v in (defaults or {}).items() if self.set(n, v) is None]
        self.defaults = dict(self.values)
        self.ignored_initial: list[str] = []
        for name, value in (initial or {}).items():
            if self.set(name, value) is None:
                self.ignored_initial.append(name)

    def overrides(self) -> dict[str, float]:
        """The values that differ from the defaults: what was set over MAVLink, and what
        to persist (a value equal to the configuration's follows the configuration)."""
        return {k: v for k, v in self.values.items() if v != self.defaults[k]}

    def __len__(self) -> int:
        return len(PARAMS)

    def index(self, name: str) -> int:
        return [p.name for p in PARAMS].index(name)

    def by_index(self, i: int) -> ParamSpec | None:
        return PARAMS[i] if 0 <= i < len(PARAMS) else None

    def set(self, name: str, value: float) -> float | None:
        """Store ``value`` if valid; returns the stored value, or None if refused."""
        spec = BY_NAME.get(name)
        if spec is None or not isinstance(value, int | float) or not math.isfinite(value):
            return None
        if not spec.minimum <= value <= spec.maximum:
            return None
        # Values arrive as 32-bit floats: keep the 7 significant digits they really have,
        # so 0.12 is stored as 0.12 and not 0.11999999731779099.
        stored = float(round(value)) if spec.integer else float(f"{value:.7g}")
        self.values[name] = stored
        return stored


def config_with_params(config: PipelineConfig, values: Mapping[str, float]) -> PipelineConfig:
    """The pipeline configuration with the parameter values applied."""
    v = {**{p.name: p.default for p in PARAMS}, **values}
    cls = dataclasses.replace(
        config.classifier,
        tcm_threshold=float(v["TCM_THRESH"]),
        interval_s=float(v["TCM_INTERVAL_S"]),
        hold_s=float(v["TCM_HOLD_S"]),
    )
    det = dataclasses.replace(
        config.detection,
        seed_hue_deg=(float(v["TCM_HUE_MIN"]), float(v["TCM_HUE_MAX"])),
        seed_min_saturation=float(v["TCM_SAT_MIN"]),
    )
    return dataclasses.replace(
        config,
        classifier=cls,
        detection=det,
        egomotion_source=_SOURCES[int(v["TCM_EGO_SRC"])],  # type: ignore[arg-type]
    )


def params_problem(config: PipelineConfig, values: Mapping[str, float]) -> str:
    """Why the parameter ``values`` cannot be applied to ``config`` together (a seed hue
    range leaving the grow range: each value passes its own range, the pair does not),
    for a STATUSTEXT ("" if they can)."""
    try:
        config_with_params(config, values)
    except ValueError as exc:
        # Without the class prefix: "DetectionConfig.seed_hue_deg ..." -> "seed_hue_deg ...".
        text = str(exc)
        head, dot, rest = text.partition(".")
        return rest if dot and head.endswith("Config") and " " not in head else text
    return ""


#: The configuration key each parameter stands for (:func:`params_from_config`).
CONFIG_KEYS: dict[str, str] = {
    "TCM_THRESH": "[classifier] tcm_threshold",
    "TCM_INTERVAL_S": "[classifier] interval_s",
    "TCM_HOLD_S": "[classifier] hold_s",
    "TCM_HUE_MIN": "[detection] seed_hue_deg[0]",
    "TCM_HUE_MAX": "[detection] seed_hue_deg[1]",
    "TCM_SAT_MIN": "[detection] seed_min_saturation",
    "TCM_EGO_SRC": "[pipeline] egomotion_source",
}


def params_from_config(config: PipelineConfig) -> dict[str, float]:
    """Parameter values that describe ``config`` (used as defaults at start-up)."""
    return {
        "TCM_THRESH": config.classifier.tcm_threshold,
        "TCM_INTERVAL_S": config.classifier.interval_s,
        "TCM_HOLD_S": config.classifier.hold_s,
        "TCM_HUE_MIN": config.detection.seed_hue_deg[0],
        "TCM_HUE_MAX": config.detection.seed_hue_deg[1],
        "TCM_SAT_MIN": config.detection.seed_min_saturation,
        "TCM_EGO_SRC": float(_SOURCES.index(config.egomotion_source)),
    }
