"""What a ``run`` or ``sitl`` reads and writes besides MAVLink: its inputs (which no
output may overwrite), the checks of its outputs before it starts (not after a flight of
hours), and the run's summary as JSON (``run --summary-json``)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .common import config_file

if TYPE_CHECKING:
    from ..config import AppConfig


def run_inputs(args: argparse.Namespace, config: AppConfig) -> list[str | None]:
    """What a run reads from files, which its outputs must not overwrite: the
    configuration file, and each camera's video, frames or scenario."""
    paths = [
        c.source.path
        for c in config.cameras
        if c.source.source in ("file", "frames", "scenario") and c.source.path
    ]
    return [config_file(args), *paths]


def check_outputs(
    inputs: list[str | None], log_dir: str | Path | None, summary_json: str | None, log_what: str
) -> None:
    """The flight log's directory (made now, writable; files are added to it, none
    replaced) and the summary (a summary of an earlier run is replaced, nothing else)
    destroy no input and are not one another: :mod:`tcm_companion.io.outputs`
    (OutputRefused: one ``error:`` line; the log directory's names ``log_what``)."""
    from ..io.outputs import SUMMARY_JSON, OutputRefused, check_folder, check_output

    if summary_json is not None:
        check_output(summary_json, SUMMARY_JSON, force=True, inputs=inputs)
    if log_dir is not None:
        try:
            check_folder(log_dir, inputs=inputs, others=[summary_json], create=True)
        except OutputRefused as exc:
            raise OutputRefused(f"{log_what} {exc}") from None


def camera_summaries(summary: Any) -> list[dict[str, Any]]:
    """Each camera's frames, in camera-id order: its name, and captured, delivered,
    rejected, processed (sent), read errors."""
    names = getattr(summary, "camera_names", []) or list(summary.camera_stats)
    processed = getattr(summary, "processed_per_camera", []) or [None] * len(names)
    return [
        {
            "name": name,
            "captured": s.captured,
            "delivered": s.delivered,
            "rejected": s.rejected_empty + s.rejected_size,
            "processed": n,
            "read_errors": s.read_errors,
        }
        for name, s, n in zip(names, summary.camera_stats.values(), processed, strict=False)
    ]


def write_summary_json(
    path: str,
    summary: Any,
    *,
    inputs: list[str | None] | None = None,
    others: list[Any] | None = None,
) -> None:
    """Latency percentiles, frame accounting and faults of a run, for tools and benches;
    whole or not at all, over an earlier summary only (:data:`~tcm_companion.io.outputs.SUMMARY_JSON`)."""
    import json

    import numpy as np

    doc = {
        "duration_s": summary.duration_s,
        "captured": summary.captured,
        "processed": summary.processed,
        "dropped": summary.dropped,
        "failed": summary.failed,
        "rejected": summary.rejected,
        "frames_balance": summary.frames_balance,
        "latency_p50_ms": summary.latency_percentile_ms(50),
        "latency_p90_ms": summary.latency_percentile_ms(90),
        "latency_p99_ms": summary.latency_percentile_ms(99),
        "latency_max_ms": summary.latency_percentile_ms(100),
        "faults": summary.faults,
        "watchdog_pings": summary.watchdog_pings,
        "watchdog_withheld": summary.watchdog_withheld,
        "frames_waited_for_attitude": summary.stats.frames_waited,
        "objects_sent": summary.stats.objects_sent,
        "box_feed": getattr(summary, "box_feed", {}),
        "cameras": camera_summaries(summary),
        "link": getattr(summary, "link", {}),
        "stages_ms": {
            k: {
                "p50": float(np.percentile(v, 50)) if v else None,
                "p99": float(np.percentile(v, 99)) if v else None,
            }
            for k, v in summary.stage_ms.items()
        },
    }
    from ..io.outputs import SUMMARY_JSON, atomic_text

    with atomic_text(
        path, kind=SUMMARY_JSON, force=True, inputs=inputs or (), others=others or ()
    ) as fh:
        fh.write(json.dumps(doc, indent=2))
