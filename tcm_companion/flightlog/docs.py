"""What the daemon writes to the flight log about each frame: plain JSON documents.

``/tcm/result`` holds, per processed frame, what was sent (states after the input-health
override) and what process replay needs to recompute it exactly: the capture and
processing times, the override reason, and the autopilot-to-companion clock offset the
pipeline used. Pure functions; the writer thread serialises them.
"""

from __future__ import annotations

import math
from typing import Any

from ..core.camera import CameraModel
from ..core.pipeline import FrameResult, ObjectResult
from ..mavlink.outputs import body_azel_rad, object_range_m


def _num(x: float) -> float | None:
    """JSON has no NaN: unknown values are null."""
    return float(x) if x is not None and math.isfinite(x) else None


def object_doc(o: ObjectResult, object_radius_m: float) -> dict[str, Any]:
    az_b, el_b = body_azel_rad(o.bearing_body)
    return {
        "track_id": o.track_id,
        "detected": o.detected,
        "state": o.state,
        "reason": o.reason,
        "disparity": _num(o.classification.disparity),
        "ttc_s": _num(o.ttc_s),
        "collision_course": bool(o.collision_course),
        "miss_radii": _num(o.miss_radii),
        "azimuth_body_deg": math.degrees(az_b),
        "elevation_body_deg": math.degrees(el_b),
        # NaN (null) in a frame without attitude
        "azimuth_ned_deg": _num(math.degrees(o.azimuth_ned_rad)),
        "elevation_ned_deg": _num(math.degrees(o.elevation_ned_rad)),
        "angular_radius_deg": math.degrees(o.angular_radius_rad),
        "range_m": _num(object_range_m(o, object_radius_m)),
        "centroid_px": [float(o.centroid_px[0]), float(o.centroid_px[1])],
    }


def result_doc(
    camera_id: int,
    result: FrameResult,
    *,
    threshold: float,
    t_process_us: int,
    override: str,
    clock_offset_us: float,
    latency_ms: float | None,
    object_radius_m: float = 0.0,
) -> dict[str, Any]:
    tr = result.translation
    return {
        "camera_id": camera_id,
        "frame_index": result.frame_index,
        "t_capture_us": result.t_us,
        "t_process_us": t_process_us,
        "threshold": threshold,
        "attitude_ok": result.attitude_ok,
        "override": override,
        "clock_offset_us": _num(clock_offset_us),
        "objects": [object_doc(o, object_radius_m) for o in result.objects],
        "egomotion": None
        if tr is None
        else {
            "source": tr.source,
            "valid": bool(tr.valid),
            "sigma_rad": _num(tr.sigma_rad),
            "inlier_ratio": _num(tr.inlier_ratio),
            "parallax_rad": _num(tr.parallax_rad),
            "magnitude_m": _num(tr.magnitude_m),
        },
        "timings_ms": {k: round(v, 4) for k, v in result.timings_ms.items()},
        # Capture -> outputs queued on the endpoint (the link write, ~0.4 ms, comes after
        # the record is logged; the health message has the full figure).
        "latency_ms": latency_ms,
    }


def annotation_circles(
    result: FrameResult, camera: CameraModel
) -> list[tuple[float, float, float, str]]:
    """``(u, v, radius px, label)`` per object, for the log's image annotations."""
    size = camera.pixel_size_map_rad
    out = []
    for o in result.objects:
        u, v = o.centroid_px
        if not (math.isfinite(u) and math.isfinite(v)):
            continue
        # np.clip's value for a finite scalar, on Python floats (np.clip on a scalar is
        # ~3 µs of wrapper per call; tests/test_fast_paths.py holds the two equal).
        iu = int(min(max(u, 0), camera.width - 1))
        iv = int(min(max(v, 0), camera.height - 1))
        px = float(size[iv, iu])
        r_px = o.angular_radius_rad / px if px > 0 and math.isfinite(px) else 5.0
        label = f"{o.state} {o.track_id}"
        if math.isfinite(o.ttc_s):
            label += f" ttc {o.ttc_s:.1f}s"
        out.append((float(u), float(v), float(r_px), label))
    return out
