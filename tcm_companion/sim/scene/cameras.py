"""Camera presets for simulated flights: the paper's panorama and two side-looking lenses.

The vehicle passes to the ball's left, so the pinhole faces right (yaw +90°) and slightly
down, keeping the ball in view over the whole back-and-forth track; for the head-on and
collision flights it faces the way the threat comes from. The 180° fisheye faces
right-forward (yaw +45°), which covers both the side and straight ahead.
"""

from __future__ import annotations

from ...core.camera import CameraModel, Equirectangular, Fisheye, Pinhole
from .names import RIGS as _RIGS

PRESETS = ("panorama", "pinhole", "fisheye")

#: Pinhole yaw (degrees right of the nose) per scenario; others look right (90°). The
#: variants with other objects (``COLLISION-DISC``, ``HEADON-BOX``, ...) look like theirs.
_PINHOLE_YAW_DEG = {"HEADON": 0.0, "COLLISION": 35.0}


def preset_camera(
    name: str, resolution: tuple[int, int] | None = None, scenario: str = ""
) -> CameraModel:
    """``panorama`` (360×220, 360°×150°), ``pinhole`` (640×480, ~90° wide) or ``fisheye``
    (640×640, 180°); ``resolution`` rescales the lens to another image size."""
    cam: CameraModel
    if name == "panorama":
        cam = Equirectangular(360, 220)
    elif name == "pinhole":
        cam = Pinhole(
            640,
            480,
            (0.0, -10.0, _PINHOLE_YAW_DEG.get(scenario.upper().split("-")[0], 90.0)),
            fx=320.0,
            fy=320.0,
            cx=320.0,
            cy=240.0,
            dist=(-0.05, 0.01, 0.0, 0.0, 0.0),
        )
    elif name == "fisheye":
        cam = Fisheye(
            640,
            640,
            (0.0, -10.0, 45.0),
            fx=200.0,
            fy=200.0,
            cx=320.0,
            cy=320.0,
            dist=(0.02, -0.005, 0.001, 0.0),
        )
    else:
        raise ValueError(f"unknown camera preset {name!r} (known: {', '.join(PRESETS)})")
    return cam if resolution is None else cam.scaled(*resolution)


#: The simulator's camera rigs (``--rig``): several cameras on one vehicle, each a
#: ``(name, lens)``. ``panorama`` is the paper's single 360° camera (the default).
RIGS = _RIGS

#: A rig pinhole: 320×240 over 100° horizontally (fx = 160 / tan 50°), level, no
#: distortion; ``quad`` puts four at 0/90/180/270° (10° overlap between neighbours),
#: ``front-back`` two at 0 and 180° (the sides 50°..130° unseen at the horizon),
#: ``front-right`` the quad's first two (a two-camera rig with an overlap, 40°..50°).
_RIG_HFOV_DEG = 100.0
_RIG_SIZE = (320, 240)
_RIG_YAWS_DEG = {
    "quad": (("front", 0.0), ("right", 90.0), ("rear", 180.0), ("left", -90.0)),
    "front-back": (("front", 0.0), ("rear", 180.0)),
    "front-right": (("front", 0.0), ("right", 90.0)),
}


def rig_cameras(
    name: str, resolution: tuple[int, int] | None = None
) -> list[tuple[str, CameraModel]]:
    """The cameras of rig ``name`` (:data:`RIGS`) as ``(camera name, lens)``, in camera-id
    order; ``resolution`` rescales each lens to another image size."""
    import math

    if name == "panorama":
        cams: list[tuple[str, CameraModel]] = [("camera0", Equirectangular(360, 220))]
    elif name in _RIG_YAWS_DEG:
        w, h = _RIG_SIZE
        f = (w / 2) / math.tan(math.radians(_RIG_HFOV_DEG / 2))
        cams = [
            (cam_name, Pinhole(w, h, (0.0, 0.0, yaw), fx=f, fy=f, cx=w / 2, cy=h / 2))
            for cam_name, yaw in _RIG_YAWS_DEG[name]
        ]
    else:
        raise ValueError(f"unknown camera rig {name!r} (known: {', '.join(RIGS)})")
    if resolution is None:
        return cams
    return [(n, c.scaled(*resolution)) for n, c in cams]
