"""Score a camera rig against truth: per camera, overall, and the handover.

A rig is replayed as ``replay`` does (:class:`~tcm_companion.replay.rig.RigReplay`: one
pipeline per camera, the rig tracker over them), and each camera's reported objects are
matched to that camera's truth rows the way ``eval`` matches one camera's
(:func:`~.evaluate.match_frame`, by bearing). Which object-frames count:

- a truth object counts for a camera's frame when its centre is in that camera's image
  (projected through the lens at the attitude the shared telemetry gives at the frame's
  capture time); frames without attitude are not scored (``eval`` warns about them);
- an object in view of a camera but reported by another camera in the same frame cycle
  (the better-placed view in an overlap: the rig leaves the other view out) is not a
  miss of this camera: its unmatched record is dropped when another camera matched that
  object within half a frame period of it.

Per camera: that camera's records; overall: every camera's records together (an object
in two views is scored once, by the camera that reported it). Handover: for each truth
object that two cameras or more measured (matched), the distinct rig track ids its
matched records carry (target: 1 — the object kept one id across cameras).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..config import AppConfig
from ..core.pipeline import FrameResult
from ..replay.rig import RigFrame, RigReplay
from ..replay.scenario import with_method
from .evaluate import ObjectFrame, ScenarioEval, match_frame, scenario_detections

__all__ = ["HandoverRow", "RigEval", "evaluate_rig", "handover_text"]


@dataclass(frozen=True)
class HandoverRow:
    """One truth object that two cameras or more measured: which cameras (in camera-id
    order) and the distinct rig track ids it got (sorted)."""

    object_id: int
    cameras: tuple[str, ...]
    track_ids: tuple[int, ...]

    @property
    def n_tracks(self) -> int:
        return len(self.track_ids)


@dataclass
class RigEval:
    """A rig's scores: ``cameras[i]`` camera id ``i``'s (named ``"<rig>/<camera>"``),
    ``overall`` all of them (``"<rig>/all"``), ``handover`` per object seen by ≥ 2
    cameras, ``stats`` the rig tracker's, ``no_attitude`` frames per camera not scored."""

    name: str
    camera_names: list[str]
    cameras: list[ScenarioEval]
    overall: ScenarioEval
    handover: list[HandoverRow] = field(default_factory=list)
    stats: dict[str, int] = field(default_factory=dict)
    no_attitude: list[int] = field(default_factory=list)


def _in_view(camera: Any, R_ned_from_body: np.ndarray, rel_ned_m: np.ndarray) -> bool:
    """Whether a point ``rel_ned_m`` from the vehicle projects into ``camera``'s image."""
    R_ned_from_cam = R_ned_from_body @ camera.R_body_from_cam
    b_cam = R_ned_from_cam.T @ rel_ned_m
    if b_cam[0] <= 0 and camera.model_name == "pinhole":
        return False  # behind a pinhole (its projection would mirror it into the image)
    px = camera.pixel_from_bearing_cam(b_cam)
    return bool(np.all(np.isfinite(px)) and camera.in_image(px))


def evaluate_rig(
    rig: Any,
    config: AppConfig,
    with_bsm: bool = True,
    on_frame: Callable[[int, FrameResult], None] | None = None,
) -> RigEval:
    """Replay rig ``rig`` (a :class:`~tcm_companion.io.scenario.RigScenario` or a
    simulated rig, every camera with truth) and score it (module docstring).
    ``on_frame(camera_id, fused result)`` is called after each frame."""
    cams = list(rig.cameras)
    for c in cams:
        if getattr(c, "truth", None) is None:
            raise ValueError(f"{c.name}: no truth.csv, cannot evaluate")
    cfg = with_method(config, "tcm", bsm=with_bsm)
    detections = None
    if cfg.pipeline.detection.backend == "boxes":
        detections = [scenario_detections(c) for c in cams]
        for c, rows in zip(cams, detections):
            if rows is None:
                raise ValueError(
                    f'{c.name}: [detection] backend "boxes" needs each camera\'s '
                    "detections.csv (sim export NAME DIR --rig R --detections writes them)"
                )
    replay = RigReplay(cams, rig.telemetry, cfg, detections, name=rig.name)
    names = list(rig.camera_names)
    t0_us = min(int(c.frame_times_us[0]) for c in cams)
    ttc_cfg = cfg.pipeline.ttc
    true_ttc = [c.truth.ttc_s(c.frame_times_us) for c in cams]
    true_coll = [
        c.truth.collision_course(
            c.frame_times_us, ttc_cfg.collision_miss_radii, ttc_cfg.collision_max_ttc_s
        )
        for c in cams
    ]
    period_us = [
        float(np.median(np.diff(c.frame_times_us))) if c.n_frames > 1 else math.inf for c in cams
    ]
    per_cam: list[list[ObjectFrame]] = [[] for _ in cams]
    evs = [ScenarioEval(c.name, (c.camera.width, c.camera.height)) for c in cams]
    no_attitude = [0] * len(cams)
    frame: RigFrame
    for frame in replay.frames():
        k, result = frame.camera_id, frame.fused
        cam = cams[k]
        R_body = replay.buffer.attitude_at(result.t_us)
        if R_body is None:
            no_attitude[k] += 1
        else:
            recs, false = match_frame(
                result, cam.truth, result.frame_index, true_ttc[k], true_coll[k], t0_us=t0_us
            )
            truth = cam.truth
            rows = truth.rows_for_frame(result.frame_index)
            seen = {
                int(truth.object_id[r])
                for r in rows
                if _in_view(cam.camera, R_body, truth.obj_ned_m[r] - truth.veh_ned_m[r])
            }
            per_cam[k].extend(r for r in recs if r.matched or r.object_id in seen)
            evs[k].false_tracks += false
        evs[k].frame_ms.append(result.timings_ms.get("total", math.nan))
        if on_frame is not None:
            on_frame(k, result)

    # An unmatched record is no miss when another camera matched the object in the same
    # frame cycle (within half this camera's frame period).
    matched_at: dict[int, list[tuple[int, int]]] = {}  # object -> (camera, t_us) matched
    for k, recs in enumerate(per_cam):
        for r in recs:
            if r.matched:
                matched_at.setdefault(r.object_id, []).append((k, r.t_us))
    for k, recs in enumerate(per_cam):
        half = 0.5 * period_us[k]
        evs[k].records = [
            r
            for r in recs
            if r.matched
            or not any(
                j != k and abs(t - r.t_us) <= half for j, t in matched_at.get(r.object_id, ())
            )
        ]
    overall = ScenarioEval(f"{rig.name}/all", evs[0].resolution)
    for ev in evs:
        overall.records.extend(ev.records)
        overall.false_tracks += ev.false_tracks
        overall.frame_ms.extend(ev.frame_ms)
    overall.records.sort(key=lambda r: (r.t_us, r.object_id))

    handover = []
    for oid in sorted({r.object_id for r in overall.records}):
        cams_seen = sorted(
            {k for k, ev in enumerate(evs) for r in ev.records if r.matched and r.object_id == oid}
        )
        if len(cams_seen) < 2:
            continue
        tracks = sorted({r.track_id for r in overall.records if r.matched and r.object_id == oid})
        handover.append(HandoverRow(oid, tuple(names[k] for k in cams_seen), tuple(tracks)))
    stats = dict(replay.tracker.stats) if replay.tracker is not None else {}
    return RigEval(rig.name, names, evs, overall, handover, stats, no_attitude)


def handover_text(evals: Sequence[RigEval]) -> list[str]:
    """The report's handover section: per rig, each object measured by ≥ 2 cameras and
    how many track ids it got (target 1), and the rig tracker's counts."""
    lines = []
    for ev in evals:
        stats = ", ".join(f"{v} {k}" for k, v in ev.stats.items())
        if not ev.handover:
            lines.append(
                f"  {ev.name}: no object was measured by two cameras or more"
                + (f" (rig tracker: {stats})" if stats else "")
            )
            continue
        ones = sum(h.n_tracks == 1 for h in ev.handover)
        mean = sum(h.n_tracks for h in ev.handover) / len(ev.handover)
        lines.append(
            f"  {ev.name}: {len(ev.handover)} object(s) measured by >= 2 cameras, {ones} with one"
            f" track id; mean {mean:.2f} track ids per object (target 1)"
            + (f"; rig tracker: {stats}" if stats else "")
        )
        for h in ev.handover:
            lines.append(
                f"    object {h.object_id}: cameras {', '.join(h.cameras)}: {h.n_tracks} track"
                f" id(s) ({', '.join(str(t) for t in h.track_ids)})"
            )
    return lines
