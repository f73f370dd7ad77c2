"""Autopilot telemetry on the frame clock: samples, clock alignment, interpolation.

The autopilot stamps every sample with its own ``time_boot_ms`` (exact; its boot clock,
``_boot_us``), while the companion only knows when a message arrived (late by a jittery
link latency). Frames are stamped on the companion clock: the clock the caller stamps
frames and receptions with, in µs — in the daemon its monotonic clock (``_mono_us``); in
a recorded scenario the ``.tlog``'s reception times (µs since the Unix epoch,
``_unix_us``). :class:`ClockSync` maps autopilot boot time to the companion clock by a
robust lower-envelope fit of ``recv_us - boot_us`` — the same quantity TIMESYNC measures
live — and :class:`TelemetryBuffer` places samples on that clock and interpolates them
to frame times (slerp for attitude, linear for position).

Nothing here reads a clock: every time is an argument.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np

from .frames import (
    FloatArray,
    quat_wxyz_from_rot,
    rot_from_euler_zyx,
    rot_from_quat_wxyz,
    slerp_quat,
)


@dataclass(frozen=True, slots=True)
class AttitudeSample:
    """Body attitude relative to NED at autopilot time ``time_boot_us``.

    ``recv_us`` is when the companion received it (companion clock, µs: in the daemon
    its monotonic clock, ``_mono_us``; see the module docstring).
    ``R_ned_from_body`` is 3×3.
    """

    time_boot_us: int
    recv_us: int
    R_ned_from_body: FloatArray

    @staticmethod
    def from_euler(
        time_boot_us: int, recv_us: int, roll_rad: float, pitch_rad: float, yaw_rad: float
    ) -> AttitudeSample:
        return AttitudeSample(
            time_boot_us, recv_us, rot_from_euler_zyx(roll_rad, pitch_rad, yaw_rad)
        )

    @staticmethod
    def from_quaternion(time_boot_us: int, recv_us: int, q_wxyz: FloatArray) -> AttitudeSample:
        return AttitudeSample(time_boot_us, recv_us, rot_from_quat_wxyz(q_wxyz))


@dataclass(frozen=True, slots=True)
class PositionSample:
    """Vehicle position and velocity in local NED (m, m/s) at autopilot time ``time_boot_us``."""

    time_boot_us: int
    recv_us: int
    pos_ned_m: FloatArray
    vel_ned_mps: FloatArray


TelemetrySample = AttitudeSample | PositionSample


class ClockSync:
    """Map autopilot boot time (µs, ``_boot_us``) to the companion clock (µs; the
    daemon's monotonic clock, ``_mono_us``, or a recording's reception clock).

    The offset ``recv_us - boot_us`` of every sample is the true clock offset plus a
    non-negative link latency, so the offset is estimated from the lower envelope: a low
    percentile over a sliding window of recent samples (a percentile, not the minimum,
    so that one mis-stamped record cannot drag it). An autopilot reboot (boot time
    jumping back by more than ``reboot_jump_us``) restarts the estimate.
    """

    def __init__(
        self,
        window_us: int = 10_000_000,
        percentile: float = 5.0,
        reboot_jump_us: int = 1_000_000,
        capacity: int = 2048,
    ) -> None:
        self.window_us = window_us
        self.percentile = percentile
        self.reboot_jump_us = reboot_jump_us
        # Ring buffers of (boot_us, recv_us - boot_us); the newest ``capacity`` samples.
        self._boot = np.zeros(capacity, dtype=np.float64)
        self._offset = np.zeros(capacity, dtype=np.float64)
        self._n = 0  # samples written since the last reset
        self._newest_boot = -math.inf
        self._cached: float | None = None
        self.resets = 0

    def observe(self, boot_us: int, recv_us: int) -> None:
        """Add one (autopilot time, receive time) pair."""
        if self._n and boot_us < self._newest_boot - self.reboot_jump_us:
            self._n = 0
            self._newest_boot = -math.inf
            self.resets += 1
        i = self._n % len(self._boot)
        self._boot[i] = boot_us
        self._offset[i] = recv_us - boot_us
        self._n += 1
        self._newest_boot = max(self._newest_boot, float(boot_us))
        self._cached = None

    @property
    def ready(self) -> bool:
        return self._n > 0

    @property
    def offset_us(self) -> float:
        """Current estimate of ``companion_us - boot_us`` (NaN before any sample)."""
        if self._cached is None:
            if not self._n:
                return math.nan
            m = min(self._n, len(self._boot))
            recent = self._offset[:m][self._boot[:m] >= self._newest_boot - self.window_us]
            k = int(self.percentile / 100.0 * (len(recent) - 1))
            self._cached = float(np.partition(recent, k)[k])
        return self._cached

    def to_companion_us(self, boot_us: float) -> float:
        return boot_us + self.offset_us


@dataclass
class TelemetryHealth:
    """Counters of telemetry the buffer refused, by reason."""

    rejected: Counter[str] = field(default_factory=Counter)
    attitude_samples: int = 0
    position_samples: int = 0


class _Series:
    """Time-sorted samples (boot time) of one kind, bounded in length."""

    def __init__(self, maxlen: int) -> None:
        self.t_boot: deque[int] = deque(maxlen=maxlen)
        self.values: deque[object] = deque(maxlen=maxlen)
        self.recv: deque[int] = deque(maxlen=maxlen)  # companion receive times

    def add(self, t_boot: int, value: object, recv_us: int) -> bool:
        """Append in time order; refuse a sample not newer than the last one."""
        if self.t_boot and t_boot <= self.t_boot[-1]:
            return False
        self.t_boot.append(t_boot)
        self.values.append(value)
        self.recv.append(recv_us)
        return True

    def clear(self) -> None:
        self.t_boot.clear()
        self.values.clear()
        self.recv.clear()

    def received_by(self, cutoff_us: int | None) -> int:
        """How many of the oldest samples had been received by ``cutoff_us`` (all: None)."""
        n = len(self.t_boot)
        if cutoff_us is None:
            return n
        while n and self.recv[n - 1] > cutoff_us:
            n -= 1
        return n

    def bracket(self, t_boot: float, n: int) -> tuple[int, int] | None:
        """Indices ``(i, j)`` of the samples around ``t_boot`` (j = i + 1), or the last
        two, among the oldest ``n``."""
        if n == 0:
            return None
        if n == 1:
            return (0, 0)
        arr = self.t_boot
        # Frames ask for recent times: search from the end.
        j = n - 1
        while j > 0 and arr[j - 1] >= t_boot:
            j -= 1
        j = max(j, 1)
        return (j - 1, j)


class TelemetryBuffer:
    """Recent attitude and position samples, queried on the companion clock.

    ``max_gap_us`` bounds how far apart two samples may be to interpolate between them,
    ``max_extrapolation_us`` how far past the newest (or before the oldest) sample a query
    may reach; beyond either, queries return ``None`` and the caller reports ``unknown``.
    """

    def __init__(
        self,
        clock: ClockSync | None = None,
        maxlen: int = 512,
        max_gap_us: int = 250_000,
        max_extrapolation_us: int = 60_000,
        position_max_gap_us: int = 500_000,
        position_max_extrapolation_us: int = 200_000,
    ) -> None:
        self.clock = clock or ClockSync()
        self._att = _Series(maxlen)
        self._pos = _Series(maxlen)
        self.max_gap_us = max_gap_us
        self.max_extrapolation_us = max_extrapolation_us
        self.position_max_gap_us = position_max_gap_us
        self.position_max_extrapolation_us = position_max_extrapolation_us
        self.health = TelemetryHealth()
        #: Queries see only the samples received by this companion time (None: all). Process
        #: replay sets it to a frame's processing time: a frame stepped in a worker process
        #: is logged when it comes back, after frames of other cameras requested later,
        #: whose replay has already handed the buffer the samples received meanwhile.
        self.received_by_us: int | None = None

    # -- input ------------------------------------------------------------------------
    def add(self, sample: TelemetrySample) -> bool:
        """Take one sample; returns False (and counts why) if it was refused."""
        if isinstance(sample, AttitudeSample):
            R = sample.R_ned_from_body
            if not np.isfinite(R).all() or abs(np.linalg.det(R) - 1.0) > 1e-3:
                self.health.rejected["attitude not finite or not a rotation"] += 1
                return False
            series, kind = self._att, "attitude"
        elif isinstance(sample, PositionSample):
            if not (np.isfinite(sample.pos_ned_m).all() and np.isfinite(sample.vel_ned_mps).all()):
                self.health.rejected["position not finite"] += 1
                return False
            series, kind = self._pos, "position"
        else:
            self.health.rejected["unknown sample type"] += 1
            return False
        resets = self.clock.resets
        self.clock.observe(sample.time_boot_us, sample.recv_us)
        if self.clock.resets != resets:  # autopilot rebooted: old samples are on another clock
            self._att.clear()
            self._pos.clear()
        # Attitude is kept as quaternions: slerp needs them, and they are cheap to store.
        value = (
            quat_wxyz_from_rot(sample.R_ned_from_body)
            if isinstance(sample, AttitudeSample)
            else sample
        )
        if not series.add(sample.time_boot_us, value, sample.recv_us):
            self.health.rejected[f"{kind} time not increasing"] += 1
            return False
        if kind == "attitude":
            self.health.attitude_samples += 1
        else:
            self.health.position_samples += 1
        return True

    def extend(self, samples: list[TelemetrySample] | tuple[TelemetrySample, ...]) -> None:
        for s in samples:
            self.add(s)

    # -- queries ----------------------------------------------------------------------
    def _boot_time(self, t_us: int) -> float:
        return t_us - self.clock.offset_us

    def latest_attitude_time_us(self) -> float | None:
        """Companion-clock time of the newest attitude sample."""
        if not self._att.t_boot:
            return None
        return self.clock.to_companion_us(self._att.t_boot[-1])

    def attitude_at(self, t_us: int) -> FloatArray | None:
        """``R_ned_from_body`` at companion time ``t_us`` by slerp, or None if not covered."""
        if not self.clock.ready:
            return None
        tb = self._boot_time(t_us)
        br = self._att.bracket(tb, self._att.received_by(self.received_by_us))
        if br is None:
            return None
        i, j = br
        t0, t1 = self._att.t_boot[i], self._att.t_boot[j]
        q0 = self._att.values[i]
        q1 = self._att.values[j]
        assert isinstance(q0, np.ndarray) and isinstance(q1, np.ndarray)
        if i == j:
            return rot_from_quat_wxyz(q0) if abs(tb - t0) <= self.max_extrapolation_us else None
        if t1 - t0 > self.max_gap_us:
            return None
        if tb < t0 - self.max_extrapolation_us or tb > t1 + self.max_extrapolation_us:
            return None
        s = (tb - t0) / (t1 - t0)
        return rot_from_quat_wxyz(slerp_quat(q0, q1, s))

    def position_at(self, t_us: int) -> tuple[FloatArray, FloatArray] | None:
        """``(pos_ned_m, vel_ned_mps)`` at companion time ``t_us``, linear, or None."""
        if not self.clock.ready:
            return None
        tb = self._boot_time(t_us)
        br = self._pos.bracket(tb, self._pos.received_by(self.received_by_us))
        if br is None:
            return None
        i, j = br
        a = self._pos.values[i]
        b = self._pos.values[j]
        assert isinstance(a, PositionSample) and isinstance(b, PositionSample)
        if i == j:
            if abs(tb - a.time_boot_us) > self.position_max_extrapolation_us:
                return None
            dt = (tb - a.time_boot_us) * 1e-6
            return a.pos_ned_m + a.vel_ned_mps * dt, a.vel_ned_mps
        t0, t1 = a.time_boot_us, b.time_boot_us
        if t1 - t0 > self.position_max_gap_us:
            return None
        if (
            tb < t0 - self.position_max_extrapolation_us
            or tb > t1 + self.position_max_extrapolation_us
        ):
            return None
        s = (tb - t0) / (t1 - t0)
        if s > 1.0:  # past the newest sample: extrapolate with its velocity
            dt = (tb - t1) * 1e-6
            return b.pos_ned_m + b.vel_ned_mps * dt, b.vel_ned_mps
        pos = (1.0 - s) * a.pos_ned_m + s * b.pos_ned_m
        vel = (1.0 - s) * a.vel_ned_mps + s * b.vel_ned_mps
        return pos, vel
