"""The service's health figures: its counters, the latency percentiles every report uses,
the egomotion's source and quality as the health message states them, the status line's
text, and objects made unknown when an input they depend on is unhealthy."""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..core.classify import unknown
from ..core.egomotion import TranslationEstimate
from ..core.pipeline import FrameResult, ObjectResult
from ..mavlink import tcm_dialect as d

_EGO_SOURCE = {
    "vision": d.TCM_EGOMOTION_SOURCE_VISION,
    "autopilot": d.TCM_EGOMOTION_SOURCE_AUTOPILOT,
    "fused": d.TCM_EGOMOTION_SOURCE_FUSED,
}


def latency_percentile_ms(latencies_ms: Iterable[float], q: float) -> float:
    """The ``q``-th percentile (0..100) of capture-to-MAVLink latencies (ms), NumPy's
    linear interpolation between the closest ranks; NaN when there are none.

    The one definition of every latency figure: the status line and
    ``TCM_PIPELINE_HEALTH`` (:class:`Companion`), a run's :class:`~.host.DaemonSummary`
    (the SITL report, ``bench --daemon``) and the flight-log plots.
    """
    values = np.fromiter(latencies_ms, dtype=np.float64)
    if not values.size:
        return math.nan
    return float(np.percentile(values, q))


@dataclass
class CompanionStats:
    frames_processed: int = 0
    frames_dropped: int = 0  # superseded by a newer frame before processing, or at stop
    frames_failed: int = 0  # the pipeline raised
    frames_waited: int = 0  # processed after waiting for the attitude after them
    frames_without_time_base: int = 0  # processed before the autopilot's clock was known
    pipeline_rebuilds: int = 0
    objects_sent: int = 0
    objects_unknown_by_input: int = 0
    faults: Counter[str] = field(default_factory=Counter)
    # The live box feed (docs/box-feed.md): datagrams, accepted messages and their boxes,
    # what was refused or not used (BOX_FEED_BAD), and frames with / without / waiting
    # for boxes.
    box_feed: Counter[str] = field(default_factory=Counter)


def mark_unknown(result: FrameResult, reason: str) -> FrameResult:
    """``result`` with every object's state ``unknown`` for ``reason``."""
    objs = tuple(
        dataclasses.replace(
            o,
            state="unknown",
            reason=reason,
            classification=unknown(
                reason, o.classification.interval_frames, o.classification.interval_s
            ),
        )
        for o in result.objects
    )
    return dataclasses.replace(result, objects=objs)


def egomotion_source_code(translation: TranslationEstimate | None) -> int:
    """The ``TCM_EGOMOTION_SOURCE`` of the last translation estimate (NONE without one)."""
    source = translation.source if translation is not None else ""
    return _EGO_SOURCE.get(source, d.TCM_EGOMOTION_SOURCE_NONE)


def egomotion_quality_pct(translation: TranslationEstimate | None) -> int:
    """The health message's egomotion quality (%): 100 for a direction σ of 0, falling
    linearly to 0 at σ = 0.2 rad; 0 without a valid estimate."""
    tr = translation
    if tr is not None and tr.valid and math.isfinite(tr.sigma_rad):
        return round(100 * max(0.0, 1.0 - tr.sigma_rad / 0.2))
    return 0


def status_line_text(
    objects: Sequence[ObjectResult],
    frame_rate_hz: float | None,
    latencies_ms: Sequence[float],
    drops: str,
    problems: Sequence[str],
) -> str:
    """One line: objects and states, nearest TTC, fps (None: "starting", no two frames yet
    to measure a rate on), capture-to-MAVLink latency (ms), ``drops`` as shown, problems."""
    states: dict[str, int] = {}
    for o in objects:
        states[o.state] = states.get(o.state, 0) + 1
    ttcs = [o.ttc_s for o in objects if o.ttc_s == o.ttc_s]
    st = ", ".join(f"{n} {s}" for s, n in sorted(states.items())) or "none"
    if latencies_ms:
        p50, p99 = (latency_percentile_ms(latencies_ms, q) for q in (50, 99))
        latency = f"latency p50 {p50:.1f} p99 {p99:.1f} ms"
    else:
        latency = "latency n/a"  # no frame's output written yet
    head = f"objects {len(objects)} ({st}) | "
    if ttcs:
        head += f"TTC {min(ttcs):.1f}s | "
    rate = "starting" if frame_rate_hz is None else f"{frame_rate_hz:4.1f} fps"
    return head + (
        f"{rate} | {latency} | drops {drops} | "
        + ("; ".join(problems) if problems else "inputs OK")
    )
