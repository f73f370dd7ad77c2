"""Adversarial link (issue 24, "Done when"): what a hostile peer did on the first day, on
real loopback UDP, against the running daemon.

- A spoofing peer beside the mock autopilot: the daemon, the mock autopilot and a
  second sender posing as system 1 / component 1 (its own sequence numbers and boot
  clock, the clock going back, NaN attitude) all talk through a small UDP router that
  forwards every datagram to every other peer, as mavlink-router or a shared radio
  would. Before issue 24 that peer was taken for an autopilot reboot hundreds of times
  and drew 60-93 COMMAND_LONG a second. The router sees everything the daemon sends.
- A bounded burst of hostile box-feed datagrams at the daemon's live box feed socket
  (numbers of thousands of digits, NaN, wrong types, deep nesting, non-UTF-8, oversize),
  then good ones.

The logic behind both is tested sans-IO in virtual time (``tests/test_peers.py``,
``tests/test_box_feed.py``); this file is the end-to-end part, in real time (about 30 s).
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import logging
import math
import random
import socket
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from tcm_companion.config import AppConfig
from tcm_companion.core.detection import DetectionConfig
from tcm_companion.io.aio import monotonic_us
from tcm_companion.io.transports import open_transport
from tcm_companion.mavlink import tcm_dialect as d
from tcm_companion.mavlink.codec import MavlinkCodec
from tcm_companion.mavlink.endpoint import REQUEST_BURST
from tcm_companion.service.box_feed import MAX_DATAGRAM_BYTES, encode_box_message
from tcm_companion.sitl.mock_flight import SitlReport, run_sitl

pytestmark = pytest.mark.xdist_group("sitl")  # real-time SITL: one at a time

CONFLICT_TEXT = "TCM: two senders as autopilot 1/1, objects unknown"


class Router(asyncio.DatagramProtocol):
    """Forwards every datagram to every other address it has heard from, and decodes
    what the daemon (component 191) sends: ``(monotonic s, message)``."""

    def __init__(self) -> None:
        self.peers: list[Any] = []
        self.transport: asyncio.DatagramTransport | None = None
        self.parsers: dict[Any, Any] = {}
        self.daemon_out: list[tuple[float, Any]] = []

    def connection_made(self, transport: Any) -> None:
        self.transport = transport

    def datagram_received(self, data: bytes, addr: Any) -> None:
        if addr not in self.peers:
            self.peers.append(addr)
        assert self.transport is not None
        for peer in self.peers:
            if peer != addr:
                self.transport.sendto(data, peer)
        mav = self.parsers.get(addr)
        if mav is None:
            mav = self.parsers[addr] = d.MAVLink(None)
            mav.robust_parsing = True
        now = time.monotonic()
        for m in mav.parse_buffer(data) or []:
            if m.get_type() != "BAD_DATA" and m.get_srcComponent() == 191:
                self.daemon_out.append((now, m))

    def of(self, kind: str, start: float = 0.0, end: float = math.inf) -> list[Any]:
        return [m for t, m in self.daemon_out if m.get_type() == kind and start <= t < end]


class Spoofer(threading.Thread):
    """Sends as 1/1 between monotonic times ``start`` and ``end`` from its own socket and
    thread: ATTITUDE at 50 Hz on its own clock (back by up to 3 s one time in five, NaN
    one time in three), a HEARTBEAT a second. ``sent``: the messages sent."""

    def __init__(self, port: int, start: float, end: float) -> None:
        super().__init__(name="spoofer", daemon=True)
        self.port, self.start_at, self.end_at = port, start, end
        self.sent = 0

    def run(self) -> None:
        codec = MavlinkCodec(1, 1)
        codec.mav.seq = 77
        rng = random.Random(24)
        boot_ms, k = 5_000, 0
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.connect(("127.0.0.1", self.port))
            time.sleep(max(0.0, self.start_at - time.monotonic()))
            while (now := time.monotonic()) < self.end_at:
                while k < (now - self.start_at) * 50:  # catching up after a late wake-up
                    k += 1
                    if k % 50 == 1:
                        hb = d.MAVLink_heartbeat_message(
                            d.MAV_TYPE_QUADROTOR, d.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3
                        )
                        sock.send(codec.encode(hb))
                        self.sent += 1
                    boot_ms += 20 if rng.random() > 0.2 else -rng.randint(100, 3000)
                    roll = math.nan if k % 3 == 0 else rng.uniform(-3.0, 3.0)
                    att = d.MAVLink_attitude_message(max(0, boot_ms), roll, -3.0, 0.0, 0, 0, 0)
                    sock.send(codec.encode(att))
                    self.sent += 1
                time.sleep(0.02)


def test_a_spoofing_peer_beside_the_mock_autopilot(tmp_path: Path) -> None:
    router = Router()

    async def go() -> tuple[SitlReport, int, dict[str, float]]:
        loop = asyncio.get_running_loop()
        hub, _ = await loop.create_datagram_endpoint(lambda: router, local_addr=("127.0.0.1", 0))
        port = hub.get_extra_info("sockname")[1]
        mock_link = open_transport(f"udpout:127.0.0.1:{port}")
        daemon_link = open_transport(f"udpout:127.0.0.1:{port}")
        await mock_link.open()
        await daemon_link.open()
        t0 = time.monotonic()
        times = {"start": t0 + 4.0, "end": t0 + 8.0}
        spoofer = Spoofer(port, times["start"], times["end"])
        spoofer.start()
        try:
            report = await run_sitl(
                AppConfig(),
                # The conflict ends ~18-19.5 s in (10 s after the spoofer stops); the run
                # goes on long enough to see decisions 2.5 s after that on a busy machine
                # (at 22 s the window was 0.5-1.5 s, and a starved mock's "attitude slow"
                # fault there left only unknowns: it failed once in a full suite run).
                duration_s=26.0,
                state_dir=str(tmp_path),
                links=(mock_link, daemon_link),
                min_accuracy=None,
            )
        finally:
            hub.close()
            spoofer.join()
        return report, spoofer.sent, times

    report, spoofed, times = asyncio.run(go())
    s = report.summary
    start, end = times["start"], times["end"]
    assert spoofed >= 190  # 4 s at 50 a second, and 4 heartbeats
    # The daemon kept running the whole time: frames throughout, the watchdog fed.
    assert s.frames_balance and s.processed > 20 and s.watchdog_withheld == 0, report.lines()
    # No reboot storm, and the requests to the autopilot bounded (866 before issue 24).
    assert s.faults.get("autopilot reboot", 0) == 0, s.faults
    commands = router.of("COMMAND_LONG")
    assert len(commands) <= REQUEST_BURST + 22, len(commands)
    in_window = [
        (round(t - start, 2), m.param1, m.param2)
        for t, m in router.daemon_out
        if m.get_type() == "COMMAND_LONG" and start <= t < end + 1.0
    ]
    # 4 s of spoofing drew no storm: at most the stream re-requests a loaded machine's
    # stalled loop may cause (each stream checked every 3 s; 240+ before the fix).
    assert len(in_window) <= 4, json.dumps([in_window, s.endpoint_stats, report.lines()])
    # One fault, reported once (STATUSTEXT, the health flag, the summary's counts).
    assert s.faults.get("autopilot conflict") == 1, s.faults
    assert s.link.get("autopilot conflicts") == 1 and s.link["autopilot id: off-sequence message"]
    texts = [(t, m.text) for t, m in router.daemon_out if m.get_type() == "STATUSTEXT"]
    conflict_at = [t for t, text in texts if text == CONFLICT_TEXT]
    assert len(conflict_at) == 1, texts
    assert start < conflict_at[0] < start + 1.5
    health = router.of("TCM_PIPELINE_HEALTH", conflict_at[0] + 0.6, end)
    assert health and all(h.health & d.TCM_HEALTH_AUTOPILOT_CONFLICT for h in health)
    # While the senders conflict every status is unknown; once the conflict is over
    # (10 s after the spoofer's last message) the objects are decided again.
    during = router.of("TCM_OBJECT_STATUS", conflict_at[0] + 0.2, end)
    assert during and {m.state for m in during} == {d.TCM_OBJECT_STATE_UNKNOWN}
    over = [t for t, text in texts if text == "TCM: autopilot 1/1 one sender again"]
    assert over and end + 9.0 < over[0] < end + 11.5, (over, end)
    after = router.of("TCM_OBJECT_STATUS", over[0] + 2.5)
    assert {m.state for m in after} - {d.TCM_OBJECT_STATE_UNKNOWN}, "never decided again"
    assert report.mock_status_received > 0


def _hostile_datagrams() -> list[bytes]:
    good = json.loads(encode_box_message(0, 1, []))
    huge = "9" * 4000
    cases: list[bytes] = [
        json.dumps({**good, "capture_mono_us": 0}).replace('"capture_mono_us": 0', f'"capture_mono_us": {huge}').encode(),
        json.dumps({**good, "boxes": [{"x_min": 1, "y_min": 2, "x_max": 3, "y_max": 4}]}).replace('"x_min": 1', f'"x_min": {huge[:400]}').encode(),
        json.dumps({**good, "capture_mono_us": 2**64}).encode(),
        json.dumps({**good, "capture_mono_us": -5}).encode(),
        json.dumps({**good, "boxes": [{"x_min": math.nan, "y_min": 0, "x_max": 1, "y_max": 1}]}).encode(),
        json.dumps({**good, "boxes": [{"x_min": math.inf, "y_min": 0, "x_max": 1, "y_max": 1}]}).encode(),
        json.dumps({**good, "camera": [0]}).encode(),
        json.dumps({**good, "camera": 10**300}).encode(),
        json.dumps({**good, "boxes": "all of them"}).encode(),
        json.dumps({**good, "boxes": [[[[[]]]]]}).encode(),
        json.dumps({**good, "v": True}).encode(),
        b"[" * 5000 + b"]" * 5000,
        b"\xff\xfe\x00garbage",
        b"{" * 20,
        b" " * (MAX_DATAGRAM_BYTES + 10),
        b"",
    ]  # fmt: skip
    return cases * 20  # 320 datagrams


def test_a_burst_of_hostile_box_datagrams(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Every hostile datagram counted, the feed alive, no traceback logged, and good
    datagrams after the burst still used."""
    with socketpair_port() as port:
        feed = f"udp:127.0.0.1:{port}"
    config = AppConfig()
    config = dataclasses.replace(
        config,
        pipeline=dataclasses.replace(config.pipeline, detection=DetectionConfig(backend="boxes")),
        daemon=dataclasses.replace(config.daemon, box_feed=feed),
    )
    hostile = _hostile_datagrams()
    good_sent: list[int] = []

    async def feeder() -> None:
        loop = asyncio.get_running_loop()
        transport, _ = await loop.create_datagram_endpoint(
            asyncio.DatagramProtocol, remote_addr=("127.0.0.1", port)
        )
        try:
            await asyncio.sleep(2.0)
            for data in hostile:
                transport.sendto(data)
                await asyncio.sleep(0)
            await asyncio.sleep(0.3)
            for _ in range(25):  # then a good feeder, a second's worth
                t = monotonic_us() + 10_000
                transport.sendto(encode_box_message(0, t, []))
                good_sent.append(t)
                await asyncio.sleep(0.04)
        finally:
            transport.close()

    async def go() -> SitlReport:
        task = asyncio.create_task(feeder())
        report = await run_sitl(config, duration_s=5.0, state_dir=str(tmp_path), min_accuracy=None)
        await task
        return report

    caplog.set_level(logging.INFO)
    report = asyncio.run(go())
    counts = report.summary.box_feed
    refused = sum(counts.get(k, 0) for k in ("malformed", "unknown camera", "future", "late"))
    empty = hostile.count(b"")  # an empty datagram may not be delivered as one
    assert counts["datagrams"] >= len(hostile) - empty + len(good_sent)
    assert refused >= len(hostile) - empty, counts
    assert counts.get("handler error", 0) == 0, counts
    assert counts.get("accepted", 0) >= len(good_sent) - 2, counts  # used after the burst
    assert not [r for r in caplog.records if r.exc_info], "a traceback was logged"
    assert report.summary.frames_balance and report.summary.processed >= 10


class socketpair_port:
    """A free UDP port on loopback (bound, then released for the daemon to take)."""

    def __enter__(self) -> int:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        return int(self.sock.getsockname()[1])

    def __exit__(self, *exc: object) -> None:
        self.sock.close()
