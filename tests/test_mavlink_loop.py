"""The companion endpoint and the mock autopilot together: in memory with a jittery
simulated link (deterministic, simulated time), and over real transports."""

from __future__ import annotations

import asyncio
import heapq
import random

import numpy as np
import pytest

from tcm_companion.core.classify import Classification
from tcm_companion.core.frames import bearing_from_azel
from tcm_companion.core.pipeline import FrameResult, ObjectResult
from tcm_companion.mavlink.endpoint import (
    AutopilotFound,
    AutopilotRebooted,
    CompanionEndpoint,
    TelemetryReceived,
)
from tcm_companion.sim.vehicle.mock_autopilot import (
    BrakeStarted,
    MockAutopilot,
    MockAutopilotConfig,
)

from .mavlink_link import CompanionLink

START = 5_000_000_000  # µs on the shared simulated clock


class SimulatedLink:
    """Both endpoints on one simulated clock; bytes delayed by a jittery latency."""

    def __init__(self, latency_us: tuple[int, int] = (0, 2000), seed: int = 0, **mock) -> None:  # type: ignore[no-untyped-def]
        self.rng = random.Random(seed)
        self.latency = latency_us
        self.now = START
        self.companion = CompanionEndpoint(now_us=START)
        self.mock = MockAutopilot(MockAutopilotConfig(**mock), START)
        self.queue: list[tuple[int, int, str, bytes]] = []  # (deliver_at, seq, to, data)
        self.seq = 0
        self.events: list = []
        self.mock_events: list = []
        self.last_delivery = {"mock": START, "companion": START}

    def _send(self, to: str, data: bytes) -> None:
        if data:
            at = self.now + self.rng.randint(*self.latency)
            at = max(at, self.last_delivery[to])  # a link keeps byte order
            self.last_delivery[to] = at
            heapq.heappush(self.queue, (at, self.seq, to, data))
            self.seq += 1

    def run(self, seconds: float, on_step=None) -> None:  # type: ignore[no-untyped-def]
        end = self.now + int(seconds * 1e6)
        while self.now < end:
            nxt = min(self.companion.next_deadline_us(), self.mock.next_deadline_us(), end)
            if self.queue:
                nxt = min(nxt, self.queue[0][0])
            self.now = max(self.now, nxt)
            while self.queue and self.queue[0][0] <= self.now:
                _, _, to, data = heapq.heappop(self.queue)
                if to == "mock":
                    self.mock_events += self.mock.receive_data(data, self.now)
                else:
                    self.events += self.companion.receive_data(data, self.now)
            self.events += self.companion.poll(self.now)
            self.mock.poll(self.now)
            if on_step is not None:
                on_step(self)
            self._send("mock", self.companion.data_to_send())
            self._send("companion", self.mock.data_to_send())
            if self.now == end:
                break

    def telemetry(self, kind: type) -> list:
        return [
            e.sample
            for e in self.events
            if isinstance(e, TelemetryReceived) and isinstance(e.sample, kind)
        ]


def test_companion_finds_the_mock_and_gets_its_streams() -> None:
    from tcm_companion.core.telemetry import AttitudeSample, PositionSample

    link = SimulatedLink(ekf_origin_delay_us=0)
    link.run(6.0)
    assert any(isinstance(e, AutopilotFound) for e in link.events)
    assert link.companion.system_id == 1
    att = [s for s in link.telemetry(AttitudeSample) if s.recv_us > START + 3_000_000]
    pos = [s for s in link.telemetry(PositionSample) if s.recv_us > START + 3_000_000]
    # 3 s of steady streams at the requested 50 Hz and 10 Hz (±10 %).
    assert 135 <= len(att) <= 165 and 27 <= len(pos) <= 33


def test_timesync_offset_within_1ms_with_2ms_jitter() -> None:
    link = SimulatedLink(latency_us=(0, 2000), seed=3)
    link.run(10.0)
    ts = link.companion.timesync
    assert ts.synced
    # True offset: companion clock minus the mock's boot clock.
    true_offset = link.now - link.mock.boot_us(link.now)
    assert abs(ts.offset_us - true_offset) < 1000


def test_reboot_is_survived() -> None:
    from tcm_companion.core.telemetry import AttitudeSample

    link = SimulatedLink(ekf_origin_delay_us=0)
    link.run(4.0)
    link.mock.reboot(link.now)
    t_reboot = link.now
    link.run(6.0)
    assert any(isinstance(e, AutopilotRebooted) for e in link.events)
    late = [s for s in link.telemetry(AttitudeSample) if s.recv_us > t_reboot + 3_000_000]
    assert len(late) > 100  # streams requested again after the reboot
    true_offset = link.now - link.mock.boot_us(link.now)
    assert abs(link.companion.timesync.offset_us - true_offset) < 1000


def _alarm(t_us: int) -> FrameResult:
    b = bearing_from_azel(np.radians(5.0), 0.0)
    c = Classification("moving", "", disparity=0.4)
    o = ObjectResult(1, True, "moving", "", b, b, b, 0.087, 0.0, 0.1, (0.0, 0.0), c, 1.5, True, 1.0)
    return FrameResult(0, t_us, (o,), True, None, {})


def test_closed_loop_brake_on_collision_alarm() -> None:
    link = SimulatedLink(ekf_origin_delay_us=0, scenario="COLLISION")
    link.run(3.0)  # connected and time-synchronised
    sent = []

    def alarm(lk: SimulatedLink) -> None:
        if not sent:
            lk.companion.send_frame(_alarm(lk.now - 40_000), lk.now)
            sent.append(lk.now)

    link.run(0.5, on_step=alarm)
    brakes = [e for e in link.mock_events if isinstance(e, BrakeStarted)]
    assert brakes and brakes[0].track_id == 1
    # Once time-synchronised, every status the mock received passed its checks (time
    # within its tolerance of the mock's own boot clock, valid fields).
    statuses = [s for s in link.mock.received_status if s.recv_us > START + 2_000_000]
    assert statuses and all(s.ok for s in statuses), [s.problems for s in statuses]
    link.run(3.0)
    speed = float(np.linalg.norm(link.mock.vehicle_truth(link.now).velocity_ned_mps))
    assert speed < 0.05


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_link_over_udp_with_the_mock_runner() -> None:
    from tcm_companion.io.transports import open_transport
    from tcm_companion.sim.vehicle.mock_autopilot_run import run_mock_autopilot

    async def main() -> tuple[CompanionEndpoint, MockAutopilot]:
        import socket

        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        companion_side = open_transport(f"udpin:127.0.0.1:{port}")
        mock_side = open_transport(f"udpout:127.0.0.1:{port}")
        await companion_side.open()
        await mock_side.open()
        stop = asyncio.Event()
        endpoint = CompanionEndpoint(now_us=0)
        link = CompanionLink(companion_side, endpoint)
        mock_task = asyncio.create_task(
            run_mock_autopilot(mock_side, MockAutopilotConfig(ekf_origin_delay_us=0), stop)
        )
        link_task = asyncio.create_task(link.run())
        for _ in range(60):
            await asyncio.sleep(0.1)
            if endpoint.timesync.synced and endpoint.autopilot_connected:
                break
        link.send_frame(_alarm(link.now_us()))
        await asyncio.sleep(0.3)
        link.stop()
        stop.set()
        await link_task
        mock = await mock_task
        await companion_side.close()
        await mock_side.close()
        return endpoint, mock

    endpoint, mock = asyncio.run(main())
    assert endpoint.autopilot_connected and endpoint.timesync.synced
    assert any(s.msg.get_type() == "TCM_OBJECT_STATUS" for s in mock.received_status)
    assert mock.braking
