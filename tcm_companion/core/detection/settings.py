"""``[detection]``: which backend finds the objects, and each backend's settings.

One flat table (``config.toml``'s ``[detection]``), chosen by ``backend``:

- ``colour``: colour segmentation. The flat keys ``label``, ``hue_deg``, ``seed_*`` and
  ``grow_*`` describe one colour target, by default the paper's saturated red ball (hue
  ranges are signed degrees from ``hue_deg``); ``targets`` (``[[detection.targets]]``
  tables with the same keys) replaces it with several. A target with ``lab`` (a CIELAB
  colour) and ``seed_max_delta_e`` / ``grow_max_delta_e`` (colour differences from it)
  is a Lab target instead of a hue one: any colour, grey, white and black included.
- ``boxes``: boxes from someone else's detector (a scenario's ``detections.csv`` in
  replay, pushed by a feeder process live), measured through the camera model.
- ``onnx``: a YOLOv8-layout detector exported to ONNX (``onnx_model``), run with OpenCV's
  DNN module.

Shared: ``max_detections``, ``min_angular_radius_rad``; for boxes and onnx ``min_score``,
``classes`` (keep only these labels) and ``box_radius`` (the angular radius of a box).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Literal

Backend = Literal["colour", "boxes", "onnx"]
BACKENDS: tuple[Backend, ...] = ("colour", "boxes", "onnx")
#: How a box's angular radius follows from the angles across it through its centre,
#: horizontally (θw) and vertically (θh): half of ``min`` (short), of the geometric mean
#: ``√(θw·θh)`` (mean), of ``max`` (long), of the diagonal over √2, ``√((θw² + θh²)/2)``
#: (rms). For a sphere all four are its angular radius; docs/decisions.md §9 measured
#: which follows a non-spherical object's range best (rms, the default).
BoxRadius = Literal["short", "mean", "long", "rms"]

# Red, the version-1 target: hue ranges are signed degrees from hue_deg, positive towards
# orange/yellow. Saturation and value are fractions (0..1) of HSV's S and V.
_SEED_HUE_DEG = (-15.0, 12.0)
_GROW_HUE_DEG = (-30.0, 14.0)
# A Lab target's seed and growth tolerances (CIE76 ΔE*ab, Euclidean in L*a*b*).
_SEED_MAX_DELTA_E = 6.0
_GROW_MAX_DELTA_E = 12.0
_LIGHTNESS_FACTOR = 2.0
_HUE_KEYS = (
    "hue_deg",
    "seed_hue_deg",
    "seed_min_saturation",
    "seed_min_value",
    "grow_hue_deg",
    "grow_min_saturation",
    "grow_min_value",
)
_LAB_KEYS = ("lab", "seed_max_delta_e", "grow_max_delta_e", "delta_e_lightness_factor")
_COLOUR_KEYS = ("label", *_HUE_KEYS, *_LAB_KEYS)


@dataclass(frozen=True)
class _ColourKeys:
    """The keys that describe one colour target (see :class:`ColourTarget`): each
    ``[[detection.targets]]`` table, and ``[detection]``'s flat keys."""

    label: str = ""
    hue_deg: float = 0.0
    # Seeds: unmistakably saturated colour (the lit side); what makes a blob an object.
    seed_hue_deg: tuple[float, float] = _SEED_HUE_DEG
    seed_min_saturation: float = 0.70
    seed_min_value: float = 0.15
    # Growth: weaker colour connected to a seed (the shaded side, the rim).
    grow_hue_deg: tuple[float, float] = _GROW_HUE_DEG
    grow_min_saturation: float = 0.60
    grow_min_value: float = 0.07
    # A Lab target instead (any colour, grey, white and black included): the object's
    # colour as the camera sees its lit side, CIELAB (L* 0..100, a* and b* about
    # -128..127; sRGB, D65, as OpenCV converts 8-bit BGR). Empty: a hue target.
    lab: tuple[float, ...] = ()
    # Seeds: pixels within this colour difference of ``lab`` (CIE76 ΔE*ab, the
    # Euclidean distance in L*a*b*; ~2.3 is a just-noticeable difference).
    seed_max_delta_e: float = _SEED_MAX_DELTA_E
    # Growth: within this wider one (the shaded side, the rim); at least the seed's.
    grow_max_delta_e: float = _GROW_MAX_DELTA_E
    # Lightness differences count 1/this in both: ΔE = √((ΔL*/k)² + Δa*² + Δb*²) (CMC's
    # l:c weighting). Shade changes a surface's L* far more than its a*, b*, so k > 1
    # follows an object into its shade without taking in other colours.
    delta_e_lightness_factor: float = _LIGHTNESS_FACTOR


@dataclass(frozen=True)
class ColourTarget(_ColourKeys):
    """One colour to segment: seeds of strong colour, grown through a weaker one.

    A *hue* target (``lab`` empty, the default): ``hue_deg`` is the target's HSV hue (0
    red, 60 yellow, 120 green, 180 cyan, 240 blue, 300 magenta); ``seed_hue_deg`` and
    ``grow_hue_deg`` are (low, high) signed degrees from it. The defaults are the paper's
    red ball against grass, sky, dirt and buildings in daylight (they reject brown/orange
    dirt, skin, shadows and grey). Grey, white and black have no hue.

    A *Lab* target (``lab = (L*, a*, b*)``): seeds are the pixels within
    ``seed_max_delta_e`` of that colour (CIE76 ΔE*ab), growth the pixels within
    ``grow_max_delta_e``; the hue keys are then not used (and may not be set). This finds
    any colour, grey, white and black included, and also whatever else in view has that
    colour (a grey building, a white cloud): pick the object's colour as the camera sees
    its lit side, and check what else matches in your scenes.
    """

    @property
    def is_lab(self) -> bool:
        """A Lab target (``lab`` given), not a hue one."""
        return bool(self.lab)

    def to_dict(self) -> dict[str, Any]:
        """The target's own keys, as a ``[[detection.targets]]`` table: its label and
        either the hue keys or the Lab ones (the other kind's are not used, and a Lab
        target may not set the hue keys), so ``config check`` prints what is in force."""
        names = ("label", *(_LAB_KEYS if self.is_lab else _HUE_KEYS))
        return {name: getattr(self, name) for name in names}

    def __post_init__(self) -> None:
        check_colour(self, "ColourTarget")


def check_colour(c: Any, where: str) -> None:
    """Validate the colour keys of a :class:`ColourTarget` or :class:`DetectionConfig`."""
    if not isinstance(c.label, str):
        raise ValueError(f"{where}.label must be a string")
    if len(c.lab) not in (0, 3):
        raise ValueError(
            f"{where}.lab must be three numbers [L*, a*, b*] (or empty), got {c.lab!r}"
        )
    if c.lab:
        _check_lab(c, where)
        return
    for name in _LAB_KEYS[1:]:
        if getattr(c, name) != getattr(_ColourKeys, name):
            raise ValueError(f"{where}.{name} is a Lab target's key: it needs lab = [L*, a*, b*]")
    for name in ("seed_hue_deg", "grow_hue_deg"):
        lo, hi = getattr(c, name)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(f"{where}.{name} must be (low, high) with low < high")
    if not (c.grow_hue_deg[0] <= c.seed_hue_deg[0] and c.seed_hue_deg[1] <= c.grow_hue_deg[1]):
        raise ValueError(f"{where}.seed_hue_deg must lie inside grow_hue_deg")
    if not (-90.0 <= c.grow_hue_deg[0] and c.grow_hue_deg[1] <= 90.0):
        raise ValueError(f"{where}.grow_hue_deg must lie within ±90°")
    if not math.isfinite(c.hue_deg):
        raise ValueError(f"{where}.hue_deg must be finite")
    for name in ("seed_min_saturation", "seed_min_value", "grow_min_saturation", "grow_min_value"):
        if not 0.0 <= getattr(c, name) <= 1.0:
            raise ValueError(f"{where}.{name} must lie in [0, 1]")
    if c.grow_min_saturation > c.seed_min_saturation:
        raise ValueError(f"{where}.grow_min_saturation must not exceed the seed's")
    if c.grow_min_value > c.seed_min_value:
        raise ValueError(f"{where}.grow_min_value must not exceed the seed's")
    try:
        hue_plan(c.hue_deg, c.seed_hue_deg, c.grow_hue_deg)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def _check_lab(c: Any, where: str) -> None:
    """A Lab target's keys: its colour, its tolerances, and no hue keys."""
    L, a, b = c.lab
    if not all(isinstance(v, int | float) and math.isfinite(v) for v in (L, a, b)):
        raise ValueError(f"{where}.lab must be three finite numbers [L*, a*, b*], got {c.lab!r}")
    if not 0.0 <= L <= 100.0:
        raise ValueError(f"{where}.lab[0] (L*) must lie in [0, 100], got {L:g}")
    for i, v in ((1, a), (2, b)):
        if not -128.0 <= v <= 127.0:
            raise ValueError(f"{where}.lab[{i}] must lie in [-128, 127], got {v:g}")
    for name in _LAB_KEYS[1:3]:
        v = getattr(c, name)
        if not (math.isfinite(v) and 0.0 < v <= 200.0):
            raise ValueError(f"{where}.{name} must lie in (0, 200], got {v!r}")
    k = c.delta_e_lightness_factor
    if not (math.isfinite(k) and 0.1 <= k <= 10.0):
        raise ValueError(f"{where}.delta_e_lightness_factor must lie in [0.1, 10], got {k!r}")
    if c.grow_max_delta_e < c.seed_max_delta_e:
        raise ValueError(f"{where}.grow_max_delta_e must be at least seed_max_delta_e")
    for name in _HUE_KEYS:
        if getattr(c, name) != getattr(_ColourKeys, name):
            raise ValueError(
                f"{where}.{name} is a hue target's key: a Lab target (lab given) does not use it"
            )


@dataclass(frozen=True)
class HuePlan:
    """How a target's hue ranges are tested on OpenCV's 8-bit HSV (hue in half-degrees,
    0..179, wrapping at 180). ``swapped``: convert the BGR image with COLOR_RGB2HSV, so a
    true hue θ reads as (240° - θ) — red then sits at 120, far from the wrap; otherwise
    COLOR_BGR2HSV (θ reads as θ). ``seed`` and ``grow``: inclusive bounds."""

    swapped: bool
    seed: tuple[int, int]
    grow: tuple[int, int]


def _wrap_distance_deg(hue_deg: float, wrap_deg: float) -> float:
    return abs(((hue_deg - wrap_deg + 180.0) % 360.0) - 180.0)


def _bounds(hue_deg: float, rel_deg: tuple[float, float], swapped: bool) -> tuple[int, int]:
    if swapped:  # reads (240° - θ)/2: the range flips
        lo_v, hi_v = (240.0 - hue_deg - rel_deg[1]) / 2.0, (240.0 - hue_deg - rel_deg[0]) / 2.0
    else:
        lo_v, hi_v = (hue_deg + rel_deg[0]) / 2.0, (hue_deg + rel_deg[1]) / 2.0
    shift = math.floor(lo_v / 180.0) * 180.0
    lo_v, hi_v = lo_v - shift, hi_v - shift
    if hi_v >= 180.0:
        raise ValueError(
            f"hue range {hue_deg + rel_deg[0]:g}..{hue_deg + rel_deg[1]:g}° crosses OpenCV's"
            " hue wrap; narrow it"
        )
    lo = math.ceil(lo_v - 1e-9)
    hi = math.floor(hi_v + 1e-9)
    return max(lo, 0), min(hi, 179)


def hue_plan(
    hue_deg: float, seed_hue_deg: tuple[float, float], grow_hue_deg: tuple[float, float]
) -> HuePlan:
    """The HSV conversion (of the two) whose hue wrap lies farther from the target's
    growth range, and the 8-bit bounds of its seed and growth ranges in it."""
    centre = hue_deg + 0.5 * (grow_hue_deg[0] + grow_hue_deg[1])
    swapped = _wrap_distance_deg(centre, 240.0) >= _wrap_distance_deg(centre, 0.0)
    return HuePlan(
        swapped, _bounds(hue_deg, seed_hue_deg, swapped), _bounds(hue_deg, grow_hue_deg, swapped)
    )


def _target_from_table(table: Any, where: str) -> ColourTarget:
    """A ``[[detection.targets]]`` table (as TOML gives it) as a :class:`ColourTarget`."""
    if isinstance(table, ColourTarget):
        return table
    if not isinstance(table, dict):
        raise ValueError(f"{where} must be a table of colour-target keys, got {table!r}")
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        if key not in _COLOUR_KEYS:
            raise ValueError(
                f"{where}: unknown key {key!r} (known keys: {', '.join(sorted(_COLOUR_KEYS))})"
            )
        if key == "label":
            if not isinstance(value, str):
                raise ValueError(f"{where}.label must be a string, got {value!r}")
            kwargs[key] = value
        elif key.endswith("_hue_deg"):
            if (
                not isinstance(value, list | tuple)
                or len(value) != 2
                or not all(_is_number(v) for v in value)
            ):
                raise ValueError(f"{where}.{key} must be two numbers [low, high], got {value!r}")
            kwargs[key] = (float(value[0]), float(value[1]))
        elif key == "lab":
            if (
                not isinstance(value, list | tuple)
                or len(value) != 3
                or not all(_is_number(v) for v in value)
            ):
                raise ValueError(f"{where}.lab must be three numbers [L*, a*, b*], got {value!r}")
            kwargs[key] = tuple(float(v) for v in value)
        else:
            if not _is_number(value):
                raise ValueError(f"{where}.{key} must be a number, got {value!r}")
            kwargs[key] = float(value)
    try:
        return ColourTarget(**kwargs)
    except ValueError as exc:
        raise ValueError(str(exc).replace("ColourTarget", where)) from None


def _is_number(x: object) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(float(x))


@dataclass(frozen=True)
class DetectionConfig(_ColourKeys):
    """Everything ``[detection]`` sets (see the module docstring for the layout).

    The colour keys and their defaults are those of the version-1 red-ball detector:
    with ``backend = "colour"`` and nothing else set, detections are bit-identical.
    """

    # (The colour keys of the one target the flat keys describe, unless ``targets`` is
    # given, come first: :class:`_ColourKeys`.)
    backend: Backend = "colour"

    # Several targets at once ([[detection.targets]] tables, the keys above); replaces
    # the flat one.
    targets: tuple[ColourTarget, ...] = ()
    # Acceptance.
    min_seed_px: int = 3
    min_area_px: float = 6.0
    min_angular_radius_rad: float = 0.0
    max_detections: int = 8
    # Sub-pixel edge: pixels within rim_width_px inside / rim_width_out_px outside the
    # grown blob's boundary get a fractional membership; the local object and background
    # colours are Gaussian-weighted means (this sigma) over pixels farther in / out.
    rim_width_px: int = 2
    rim_width_out_px: int = 2
    colour_sigma_px: float = 1.5
    # Re-centre the band on the measured edge (membership ½) when the grown edge is on
    # average more than refine_min_shift_px away from it (at most refine_passes times).
    refine_passes: int = 1
    refine_min_shift_px: float = 0.5
    # Fractional memberships are clipped to this range: a little beyond [0, 1] keeps
    # the sum unbiased under noise, while a grass fleck or a highlight cannot count as
    # several pixels of the object.
    membership_clip: tuple[float, float] = (-0.25, 1.25)
    # Below this colour contrast (0..255 units) between object and background the
    # unmixing is noise, and the hard mask is used instead.
    min_unmix_contrast: float = 12.0
    # Coarse grid cell for grouping seeds into regions of interest.
    coarse_cell_px: int = 8
    # Pixels no brighter than this in every channel (0..255) next to an object count as
    # the lens's black surround for ``touches_border``: the scenario format gives a
    # fisheye no field of view, so the camera model alone cannot say where it ends.
    black_level: int = 8

    # -- boxes and onnx
    min_score: float = 0.25  # boxes scoring lower are ignored
    classes: tuple[str, ...] = ()  # keep only boxes with these labels (empty: all)
    box_radius: BoxRadius = "rms"
    # boxes: pushed boxes belong to the frame whose capture time is within this of theirs
    boxes_time_tolerance_s: float = 0.01

    # -- onnx (YOLOv8 layout: one output (1, 4 + classes, N), cx cy w h in input pixels)
    onnx_model: str = ""  # path of the .onnx file
    onnx_input_size: tuple[int, int] = (640, 640)  # the model's input width, height
    onnx_class_names: tuple[str, ...] = ()  # class index -> label (empty: COCO for 80)
    onnx_nms_iou: float = 0.45  # per-class non-maximum suppression overlap

    def __post_init__(self) -> None:
        check_colour(self, "DetectionConfig")
        if self.backend not in BACKENDS:
            raise ValueError(f"DetectionConfig.backend must be one of {list(BACKENDS)}")
        targets = tuple(
            _target_from_table(t, f"DetectionConfig.targets[{i}]")
            for i, t in enumerate(self.targets)
        )
        object.__setattr__(self, "targets", targets)
        lo, hi = self.membership_clip
        if not lo < hi:
            raise ValueError("DetectionConfig.membership_clip must be (low, high) with low < high")
        if (
            min(self.rim_width_px, self.rim_width_out_px) < 1
            or self.coarse_cell_px < 2
            or self.min_seed_px < 1
        ):
            raise ValueError(
                "DetectionConfig: rim_width_px ≥ 1, coarse_cell_px ≥ 2, min_seed_px ≥ 1"
            )
        if self.max_detections < 1 or self.colour_sigma_px <= 0:
            raise ValueError("DetectionConfig: max_detections ≥ 1 and colour_sigma_px > 0")
        if not 0.0 <= self.min_score <= 1.0:
            raise ValueError("DetectionConfig.min_score must lie in [0, 1]")
        if self.box_radius not in ("short", "mean", "long", "rms"):
            raise ValueError("DetectionConfig.box_radius must be one of short, mean, long, rms")
        if not (math.isfinite(self.boxes_time_tolerance_s) and self.boxes_time_tolerance_s >= 0):
            raise ValueError("DetectionConfig.boxes_time_tolerance_s must be >= 0")
        w, h = self.onnx_input_size
        if not (w > 0 and h > 0):
            raise ValueError("DetectionConfig.onnx_input_size must be two positive integers")
        if not 0.0 < self.onnx_nms_iou <= 1.0:
            raise ValueError("DetectionConfig.onnx_nms_iou must lie in (0, 1]")
        if self.backend == "onnx" and not self.onnx_model:
            raise ValueError(
                'DetectionConfig: backend "onnx" needs onnx_model (the path of a YOLOv8-layout'
                " .onnx file)"
            )

    @property
    def colour_targets(self) -> tuple[ColourTarget, ...]:
        """The colour backend's targets: ``targets``, or the one the flat keys describe."""
        if self.targets:
            return self.targets
        return (ColourTarget(**{k: getattr(self, k) for k in _COLOUR_KEYS}),)


__all__ = [
    "BACKENDS",
    "Backend",
    "BoxRadius",
    "ColourTarget",
    "DetectionConfig",
    "HuePlan",
    "hue_plan",
]

# Every colour key of a target is a flat key of the config (one source of truth).
assert set(_COLOUR_KEYS) <= {f.name for f in fields(DetectionConfig)}
