"""The run's statistics (latencies and where the time goes, per frame) take fixed memory.

The daemon keeps every frame's capture-to-MAVLink latency and its four stage times for
the run's summary. Kept as Python floats in deques they grew by ~32 bytes a sample, five
samples a frame: the daemon's RSS crept by ~2.4 MB every 10 minutes at 25 Hz (issue 15,
"RSS flat over 10 minutes"). They are now rings of float64 allocated once.
"""

from __future__ import annotations

import tracemalloc
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from tcm_companion.service.host import CompanionHost, SampleRing
from tcm_companion.service.outputs import FrameProcessed


def test_a_ring_keeps_the_newest_samples_oldest_first() -> None:
    ring = SampleRing(5)
    assert len(ring) == 0 and ring.values().size == 0
    for v in range(3):
        ring.append(float(v))
    assert ring.tolist() == [0.0, 1.0, 2.0]
    for v in range(3, 12):
        ring.append(float(v))
    assert len(ring) == 5
    assert ring.tolist() == [7.0, 8.0, 9.0, 10.0, 11.0]
    ring.append(12.0)  # wraps again mid-buffer
    np.testing.assert_array_equal(ring.values(), [8.0, 9.0, 10.0, 11.0, 12.0])
    ring.clear()
    assert len(ring) == 0 and ring.tolist() == []
    with pytest.raises(ValueError, match="capacity"):
        SampleRing(0)


@dataclass
class _Companion:
    """What :meth:`CompanionHost.sent` asks of the Companion: the frame's latency."""

    def frame_sent(self, out: FrameProcessed, sent_mono_us: int) -> float:
        return (sent_mono_us - out.capture_mono_us) / 1000.0


def _frame(k: int) -> FrameProcessed:
    t = 1_000_000 + 40_000 * k
    return FrameProcessed(
        camera_id=0,
        result=object(),  # type: ignore[arg-type]
        capture_mono_us=t,
        arrival_mono_us=t + 1_500,
        process_mono_us=t + 1_700,
        waited=False,
        clock_offset_us=0.0,
        override="",
        threshold=0.1,
        object_radius_m=0.5,
    )


def test_the_run_statistics_take_no_memory_per_frame() -> None:
    host = CompanionHost(_Companion(), [])  # type: ignore[arg-type]
    frames: list[Any] = [_frame(k) for k in range(20_000)]

    def send(batch: list[Any]) -> None:
        for k, out in enumerate(batch):
            done = out.process_mono_us + 3_000 + k % 7
            host.sent([out], done, done + 80)

    send(frames[:100])
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        send(frames[100:])  # 19,900 frames: ~13 minutes at 25 Hz
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    # Five Python floats a frame would be ~3 MB; a fixed ring, nothing.
    assert grown < 64 * 1024, f"the statistics grew by {grown} bytes over 19,900 frames"
    summary_latency = host.latencies_ms.values()
    assert summary_latency.size == 20_000
    assert summary_latency[-1] == pytest.approx(
        (frames[-1].process_mono_us + 3_000 + 19_899 % 7 + 80 - frames[-1].capture_mono_us) / 1000.0
    )
    assert np.allclose(host.stage_ms["handoff"].values(), 1.5)
