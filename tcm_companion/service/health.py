"""The service's health figures: its counters, the latency percentiles every report uses,
and objects made unknown when an input they depend on is unhealthy."""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from ..core.classify import unknown
from ..core.pipeline import FrameResult


def latency_percentile_ms(latencies_ms: Iterable[float], q: float) -> float:
    """The ``q``-th percentile (0..100) of capture-to-MAVLink latencies (ms), NumPy's
    linear interpolation between the closest ranks; NaN when there are none.

    The one definition of every latency figure: the status line and
    ``TCM_PIPELINE_HEALTH`` (:class:`Companion`), a run's :class:`~.plumbing.DaemonSummary`
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
