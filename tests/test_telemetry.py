"""Telemetry on the frame clock: clock alignment, slerp, refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tcm_companion.core.frames import euler_zyx_from_rot
from tcm_companion.core.telemetry import (
    AttitudeSample,
    ClockSync,
    PositionSample,
    TelemetryBuffer,
)

OFFSET_US = 1_700_000_000_000_000


def attitude_stream(
    rate_hz: float = 50.0, seconds: float = 4.0, yaw_rate: float = 0.5, seed: int = 0
):
    rng = np.random.default_rng(seed)
    out = []
    for k in range(int(seconds * rate_hz)):
        boot_us = 100_000_000 + int(k * 1e6 / rate_hz) // 1000 * 1000  # ms resolution
        latency = 3_000 + rng.exponential(4_000)
        out.append(
            AttitudeSample.from_euler(
                boot_us,
                int(OFFSET_US + boot_us + latency),
                0.0,
                0.0,
                yaw_rate * (boot_us - 100_000_000) * 1e-6,
            )
        )
    return out


def test_clock_sync_follows_the_lower_envelope() -> None:
    cs = ClockSync()
    for s in attitude_stream():
        cs.observe(s.time_boot_us, s.recv_us)
    # Minimum latency is 3 ms; the estimate sits just above it, far below the mean (7 ms).
    assert 3_000 <= cs.offset_us - OFFSET_US < 4_000


def test_clock_sync_resets_on_reboot() -> None:
    cs = ClockSync()
    cs.observe(50_000_000, OFFSET_US + 50_000_000)
    cs.observe(1_000, OFFSET_US + 60_000_000)
    assert cs.resets == 1
    assert cs.offset_us == pytest.approx(OFFSET_US + 60_000_000 - 1_000)


def test_attitude_interpolated_at_frame_time() -> None:
    buf = TelemetryBuffer()
    buf.extend(attitude_stream())
    # A frame 1.01 s after boot 100 s on the companion clock: yaw = 0.5 rad/s × 1.01 s.
    t_frame = OFFSET_US + 101_010_000
    R = buf.attitude_at(t_frame)
    assert R is not None
    yaw = euler_zyx_from_rot(R)[2]
    # The clock estimate carries the ~3 ms minimum latency: 0.5 rad/s × 3.x ms.
    assert yaw == pytest.approx(0.5 * 1.01, abs=0.5 * 0.0045)


def test_attitude_not_covered_is_none() -> None:
    buf = TelemetryBuffer()
    assert buf.attitude_at(OFFSET_US) is None
    buf.extend(attitude_stream(seconds=1.0))
    assert buf.attitude_at(OFFSET_US + 100_000_000 + 5_000_000) is None  # far in the future


def test_bad_samples_are_refused_and_counted() -> None:
    buf = TelemetryBuffer()
    good = attitude_stream(seconds=0.2)
    buf.extend(good)
    nan = AttitudeSample.from_euler(200_000_000, OFFSET_US + 200_000_000, math.nan, 0.0, 0.0)
    assert not buf.add(nan)
    assert not buf.add(good[2])  # time not increasing
    bad_pos = PositionSample(1, 2, np.array([np.nan, 0, 0]), np.zeros(3))
    assert not buf.add(bad_pos)
    rej = buf.health.rejected
    assert rej["attitude not finite or not a rotation"] == 1
    assert rej["attitude time not increasing"] == 1
    assert rej["position not finite"] == 1


def test_position_interpolation_and_extrapolation() -> None:
    buf = TelemetryBuffer()
    for k in range(10):
        boot = 100_000_000 + k * 100_000
        buf.add(
            PositionSample(
                boot, OFFSET_US + boot, np.array([k * 0.1, 0.0, -2.0]), np.array([1.0, 0.0, 0.0])
            )
        )
    pos, _vel = buf.position_at(OFFSET_US + 100_450_000)
    assert pos[0] == pytest.approx(0.45)
    pos, _ = buf.position_at(OFFSET_US + 100_950_000)
    assert pos[0] == pytest.approx(0.95)
    assert buf.position_at(OFFSET_US + 102_000_000) is None


def test_queries_as_of_a_receive_time_see_only_the_samples_received_by_then() -> None:
    """``received_by_us`` (process replay of a frame stepped in a worker): the attitude a
    frame got when its step began, although the buffer has been given later samples."""
    stream = attitude_stream(seconds=1.0, yaw_rate=2.0)
    early = TelemetryBuffer()
    early.extend(stream[:20])
    full = TelemetryBuffer()
    full.extend(stream)
    # A frame captured just after the 20th sample: extrapolated from the first 20 then,
    # interpolated with the later ones now.
    t_frame = int(early.clock.to_companion_us(stream[19].time_boot_us + 10_000))
    then = early.attitude_at(t_frame)
    assert then is not None
    now = full.attitude_at(t_frame)
    assert now is not None and not np.allclose(now, then, atol=1e-12)
    full.received_by_us = stream[19].recv_us
    # The two buffers' clock fits differ by a few µs: ask both at the same boot time.
    tb = t_frame - early.clock.offset_us
    as_of = full.attitude_at(int(tb + full.clock.offset_us))
    assert as_of is not None and np.allclose(as_of, then, atol=1e-9)
    full.received_by_us = None
    again = full.attitude_at(t_frame)
    assert again is not None and np.allclose(again, now, atol=1e-12)
