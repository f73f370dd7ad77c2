"""``tcm-companion bench --mavlink``: the endpoint's encode cost per frame
(:func:`endpoint_encode_cost_us`) and the link latency (:func:`measure_link_latency`),
printed by :func:`run_mavlink_bench`.

Link latency: how long after a status frame is handed to a transport the far end has it.

One TCM_OBJECT_STATUS frame at a time is handed to ``send()`` on one end; the clock
stops when the far end's :class:`MavlinkCodec` has decoded it (``recv()`` + ``feed()``).
Both ends run in this process's event loop, as the daemon and the mock autopilot would
in a test, and the loop idles ``interval_s`` between messages so each one also pays the
wake-up from ``epoll`` that a frame-paced sender pays.

Kinds: ``pty`` (two ptys joined by socat at 921600 baud, through the serial transport),
``udp`` (udpout -> udpin on loopback) and ``memory``. A pty does not pace bytes at the
baud rate, so the result for ``pty`` also reports the wire time the frame would take on
a real UART (10 bits a byte) and the p99 with it added.

Used by ``bench --mavlink`` and ``tools/link_latency.py``.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import numpy as np

from ..io.transports import Transport, memory_pair, open_transport
from ..mavlink import tcm_dialect as dialect
from ..mavlink.codec import MavlinkCodec
from ..service.health import latency_percentile_ms

KINDS = ("pty", "udp", "memory")
PTY_BAUD = 921600


@asynccontextmanager
async def _pair(kind: str) -> AsyncIterator[tuple[Transport, Transport]]:
    if kind == "memory":
        pair: tuple[Transport, Transport] = memory_pair()
        yield pair
        for end in pair:
            await end.close()
    elif kind == "udp":
        async with open_transport("udpin:127.0.0.1:0") as b:
            port = b.local_address[1]  # type: ignore[attr-defined]
            async with open_transport(f"udpout:127.0.0.1:{port}") as a:
                yield a, b
    elif kind == "pty":
        from ..io.transports.socat import SocatPtyPair

        with SocatPtyPair(baud=PTY_BAUD) as socat:
            url_a, url_b = socat.urls()
            async with open_transport(url_a) as a, open_transport(url_b) as b:
                yield a, b
    else:
        raise ValueError(f"unknown link kind {kind!r}; expected one of {KINDS}")


def _status(i: int) -> Any:
    return dialect.MAVLink_tcm_object_status_message(
        time_boot_ms=i,
        track_id=i & 0xFFFF,
        camera_id=0,
        state=1,
        reason=0,
        disparity=0.8,
        threshold=0.5,
        ttc=float("nan"),
        collision_course=0,
        azimuth=0.3,
        elevation=-0.1,
        angular_radius=0.02,
        range=12.5,
        confidence=90,
    )


async def measure_link_latency_async(
    kind: str, n: int = 2000, *, interval_s: float = 0.001, warmup: int = 50
) -> dict[str, Any]:
    """See :func:`measure_link_latency`."""
    tx = MavlinkCodec(src_system=1, src_component=191)
    rx = MavlinkCodec(src_system=1, src_component=1)
    samples = np.empty(n, dtype=np.float64)
    frame_bytes = 0
    async with _pair(kind) as (a, b):
        for i in range(warmup + n):
            frame = tx.encode(_status(i))
            frame_bytes = len(frame)
            wanted = i & 0xFFFF
            t0 = time.perf_counter_ns()
            await a.send(frame)
            arrived = False
            while not arrived:
                for msg in rx.feed(await b.recv(timeout=5.0)):
                    arrived |= msg.get_type() == "TCM_OBJECT_STATUS" and msg.track_id == wanted
            t1 = time.perf_counter_ns()
            if i >= warmup:
                samples[i - warmup] = (t1 - t0) / 1e6
            if interval_s > 0:
                await asyncio.sleep(interval_s)
    ms = samples
    result: dict[str, Any] = {
        "kind": kind,
        "n": n,
        "frame_bytes": frame_bytes,
        "median_ms": latency_percentile_ms(ms, 50),
        "p90_ms": latency_percentile_ms(ms, 90),
        "p99_ms": latency_percentile_ms(ms, 99),
        "max_ms": float(ms.max()),
        "mean_ms": float(ms.mean()),
        "decode_faults": int(rx.stats["bad CRC"] + rx.stats["garbage bytes"]),
    }
    if kind == "pty":
        wire_ms = frame_bytes * 10 / PTY_BAUD * 1e3
        result["baud"] = PTY_BAUD
        result["uart_wire_ms"] = wire_ms
        result["p99_with_wire_ms"] = result["p99_ms"] + wire_ms
    return result


def measure_link_latency(kind: str, n: int = 2000, **options: Any) -> dict[str, Any]:
    """Median/p90/p99/max latency (ms) of ``n`` status frames over a ``kind`` link.

    ``kind`` is one of :data:`KINDS`; ``pty`` needs socat. Runs its own event loop.
    """
    return asyncio.run(measure_link_latency_async(kind, n, **options))


def endpoint_encode_cost_us(n: int = 2000, objects: int = 4) -> dict[str, float]:
    """Time to encode one frame's outputs: a status per object plus a health report."""
    import math

    from ..core.classify import Classification
    from ..core.frames import bearing_from_azel
    from ..core.pipeline import FrameResult, ObjectResult
    from ..mavlink.endpoint import CompanionEndpoint

    ep = CompanionEndpoint(now_us=0)
    objs = []
    for k in range(objects):
        b = bearing_from_azel(np.radians(20.0 * k), np.zeros(()))
        c = Classification("moving", "", disparity=0.3)
        objs.append(
            ObjectResult(
                k,
                True,
                "moving",
                "",
                b,
                b,
                b,
                0.35 * k,
                0.0,
                0.05,
                (0.0, 0.0),
                c,
                math.nan,
                False,
                math.nan,
            )
        )
    result = FrameResult(0, 0, tuple(objs), True, None, {})
    times = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        ep.send_frame(result, i)
        ep.send_health_now(i)
        ep.data_to_send()
        times[i] = time.perf_counter() - t0
    return {
        "median_us": float(np.median(times) * 1e6),
        "p99_us": float(np.percentile(times, 99) * 1e6),
    }


def run_mavlink_bench(n: int = 2000) -> str:
    """Endpoint encode cost and link latency (pty needs socat)."""
    import shutil

    enc = endpoint_encode_cost_us()
    lines = [
        "MAVLink: encode one frame's outputs (4 × TCM_OBJECT_STATUS + TCM_PIPELINE_HEALTH): "
        f"median {enc['median_us']:.0f} µs, p99 {enc['p99_us']:.0f} µs",
        "",
        "link       status frame handed to the transport -> decoded at the far end (ms)",
        "kind       median    p90     p99     max",
    ]
    for kind in ("pty", "udp"):
        if kind == "pty" and shutil.which("socat") is None:
            lines.append("pty        (socat not installed: skipped)")
            continue
        r = measure_link_latency(kind, n)
        lines.append(
            f"{kind:<9} {r['median_ms']:6.3f}  {r['p90_ms']:6.3f}  {r['p99_ms']:6.3f}  {r['max_ms']:6.3f}"
        )
        if kind == "pty":
            lines.append(
                f"           (a pty ignores the baud rate; a real UART at {r['baud']} adds "
                f"{r['uart_wire_ms']:.2f} ms per frame: p99 {r['p99_with_wire_ms']:.2f} ms)"
            )
    return "\n".join(lines)
