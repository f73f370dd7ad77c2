"""What the autopilot would send and the companion would log during a simulated flight.

Two clocks, as on the real vehicle:

- the autopilot's boot clock (``time_boot_ms`` in every message): exact sample times,
  millisecond resolution, the boot having happened a few minutes before the flight;
- the companion's clock (Unix epoch µs): frame capture times (``t_us`` of frames.csv)
  and the receive time of every ``.tlog`` record.

Scenario time ``t_s = 0`` is the nominal capture time of frame 0. A message sampled at
``t_s`` carries ``time_boot_ms = boot(t_s)`` and is logged at
``companion(t_s) + latency``, latency = 3 ms + exponential jitter (mean 2 ms, capped at
10 ms), through a FIFO link (records stay in send order, which is also receive order).

Streams (all from system 1, component 1): HEARTBEAT 1 Hz (quadrotor, ArduPilot),
ATTITUDE 50 Hz (Euler angles with a constant per-axis bias and white noise, body rates
with noise), LOCAL_POSITION_NED 10 Hz (position and velocity with white noise) and
GPS_RAW_INT 5 Hz. The noise amplitudes scale with ``noise``; ``noise = 0`` gives exact
telemetry (latency is physics, not noise, and stays).

:class:`TelemetryNoise` is the noise model, the one the mock autopilot's live telemetry
uses too (:mod:`.mock_vehicle`).
"""

from __future__ import annotations

import io
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from ...core.frames import FloatArray
from ...io.tlog import TlogWriter
from ...mavlink import tcm_dialect
from ...mavlink.outputs import EARTH_RADIUS_M  # the flat-earth conversion ADSB_VEHICLE uses
from ..scene.scenarios import VehicleMotion, euler_zyx_rad


@dataclass(frozen=True)
class TelemetryConfig:
    """Rates, noise and link model of the synthetic telemetry."""

    attitude_hz: float = 50.0
    position_hz: float = 10.0
    heartbeat_hz: float = 1.0
    gps_hz: float = 5.0  # 0 disables GPS_RAW_INT
    attitude_noise_deg: float = 0.3
    attitude_bias_max_deg: float = 0.8
    rate_noise_dps: float = 0.3
    position_noise_m: float = 0.02
    velocity_noise_mps: float = 0.03
    gps_noise_m: float = 0.3
    latency_min_us: int = 3_000
    latency_jitter_mean_us: float = 2_000.0
    latency_jitter_max_us: int = 10_000
    link_us_per_message: int = 60  # serialisation time on the link (keeps FIFO order)
    frame_jitter_us: int = 100
    margin_s: float = 1.0  # telemetry before the first frame and after the last
    origin_lat_deg: float = -27.4975
    origin_lon_deg: float = 153.0137
    origin_alt_m: float = 30.0


@dataclass(frozen=True)
class TelemetryNoise:
    """The telemetry's noise: a constant per-axis attitude bias (uniform within
    ±``attitude_bias_max_deg``, drawn once per flight) plus white Gaussian noise on the
    attitude, the body rates, the local position and velocity and the GPS position, at
    :class:`TelemetryConfig`'s levels times ``noise``.

    The methods take one sample (shape ``(3,)``) or many (``(n, 3)``) and draw from the
    generator they are given, attitude before rates and position before velocity.
    """

    attitude_bias_rad: FloatArray  # (3,) roll, pitch, yaw
    attitude_sigma_rad: float
    rate_sigma_rps: float
    position_sigma_m: float
    velocity_sigma_mps: float
    gps_sigma_m: float

    @staticmethod
    def draw(cfg: TelemetryConfig, noise: float, rng: np.random.Generator) -> TelemetryNoise:
        """The noise of one flight: draws the attitude bias from ``rng``."""
        bias = rng.uniform(-1.0, 1.0, 3) * math.radians(cfg.attitude_bias_max_deg) * noise
        return TelemetryNoise(
            attitude_bias_rad=bias,
            attitude_sigma_rad=math.radians(cfg.attitude_noise_deg) * noise,
            rate_sigma_rps=math.radians(cfg.rate_noise_dps) * noise,
            position_sigma_m=cfg.position_noise_m * noise,
            velocity_sigma_mps=cfg.velocity_noise_mps * noise,
            gps_sigma_m=cfg.gps_noise_m * noise,
        )

    def attitude(
        self, euler_rad: FloatArray, rates_rps: FloatArray, rng: np.random.Generator
    ) -> tuple[FloatArray, FloatArray]:
        """Measured ``(roll, pitch, yaw)`` (yaw wrapped to (-π, π]) and ``(p, q, r)``."""
        eul = np.array(euler_rad, dtype=np.float64)
        eul += self.attitude_bias_rad + rng.normal(0.0, self.attitude_sigma_rad, eul.shape)
        eul[..., 2] = np.angle(np.exp(1j * eul[..., 2]))
        rates = np.array(rates_rps, dtype=np.float64)
        rates += rng.normal(0.0, self.rate_sigma_rps, rates.shape)
        return eul, rates

    def local_position(
        self, pos_ned_m: FloatArray, vel_ned_mps: FloatArray, rng: np.random.Generator
    ) -> tuple[FloatArray, FloatArray]:
        """Measured LOCAL_POSITION_NED position and velocity."""
        pos = np.asarray(pos_ned_m, dtype=np.float64)
        vel = np.asarray(vel_ned_mps, dtype=np.float64)
        pos = pos + rng.normal(0.0, self.position_sigma_m, pos.shape)
        vel = vel + rng.normal(0.0, self.velocity_sigma_mps, vel.shape)
        return pos, vel

    def gps_position(self, pos_ned_m: FloatArray, rng: np.random.Generator) -> FloatArray:
        """Measured GPS position (local NED, before conversion to latitude/longitude)."""
        pos = np.asarray(pos_ned_m, dtype=np.float64)
        return pos + rng.normal(0.0, self.gps_sigma_m, pos.shape)


@dataclass(frozen=True)
class Clocks:
    """Both clocks at scenario time 0 (integers, µs)."""

    epoch_us_at_t0: int  # companion clock, µs since the Unix epoch
    boot_us_at_t0: int  # autopilot clock, µs since boot

    def companion_us(self, t_s: float | np.ndarray) -> np.ndarray:
        return np.asarray(self.epoch_us_at_t0 + np.round(np.asarray(t_s) * 1e6), dtype=np.int64)

    def t_s_from_boot_us(self, boot_us: np.ndarray) -> np.ndarray:
        return (np.asarray(boot_us, dtype=np.int64) - self.boot_us_at_t0) / 1e6


def make_clocks(rng: np.random.Generator) -> Clocks:
    """Companion clock on 2024-06-10 plus up to a day; autopilot booted 2–10 min before."""
    epoch = 1_718_000_000_000_000 + int(rng.integers(0, 86_400_000_000))
    boot = int(rng.integers(120_000_000, 600_000_000))
    return Clocks(epoch, boot)


def frame_times(
    n_frames: int, fps: float, clocks: Clocks, cfg: TelemetryConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Capture times of the frames: (companion ``t_us`` int64, scenario ``t_s`` float64).

    Nominal ``k / fps`` with a ±``frame_jitter_us`` capture jitter; strictly increasing.
    """
    nominal_us = np.round(np.arange(n_frames) * (1e6 / fps)).astype(np.int64)
    jitter = np.clip(
        np.round(rng.normal(0.0, cfg.frame_jitter_us / 2.5, n_frames)),
        -cfg.frame_jitter_us,
        cfg.frame_jitter_us,
    )
    rel_us = nominal_us + jitter.astype(np.int64)
    t_us = clocks.epoch_us_at_t0 + rel_us
    if n_frames > 1 and not np.all(np.diff(t_us) > 0):
        raise ValueError("frame jitter too large for the frame rate")
    return t_us, rel_us / 1e6


def _sample_times_ms(
    hz: float, boot_start_us: int, boot_end_us: int, rng: np.random.Generator, jitter: bool
) -> np.ndarray:
    """Sample times on the boot clock (integer ms): a fixed period, random phase, ±1 ms jitter."""
    period_ms = max(1, round(1000.0 / hz))
    phase = int(rng.integers(0, period_ms))
    first = -(-(boot_start_us // 1000 - phase) // period_ms)
    last = (boot_end_us // 1000 - phase) // period_ms
    ms = np.arange(first, last + 1, dtype=np.int64) * period_ms + phase
    if jitter and period_ms >= 4:
        ms = ms + rng.choice(np.array([-1, 0, 0, 0, 1]), ms.size)
    return ms


def synthesize_tlog(
    vehicle: VehicleMotion,
    t_start_s: float,
    t_end_s: float,
    clocks: Clocks,
    rng: np.random.Generator,
    cfg: TelemetryConfig | None = None,
    noise: float = 1.0,
) -> list[tuple[int, bytes]]:
    """``(recv_us, packed MAVLink v2 frame)`` records in receive order over [t_start, t_end]."""
    cfg = cfg or TelemetryConfig()
    b0 = clocks.boot_us_at_t0 + round(t_start_s * 1e6)
    b1 = clocks.boot_us_at_t0 + round(t_end_s * 1e6)
    streams: list[tuple[str, np.ndarray]] = [
        ("HEARTBEAT", _sample_times_ms(cfg.heartbeat_hz, b0, b1, rng, jitter=False)),
        ("ATTITUDE", _sample_times_ms(cfg.attitude_hz, b0, b1, rng, jitter=True)),
        ("LOCAL_POSITION_NED", _sample_times_ms(cfg.position_hz, b0, b1, rng, jitter=True)),
    ]
    if cfg.gps_hz > 0:
        streams.append(("GPS_RAW_INT", _sample_times_ms(cfg.gps_hz, b0, b1, rng, jitter=True)))

    # Per stream, each message's values in its encoder's argument order (after time_boot_ms).
    payloads: dict[str, list[tuple[float, ...]]] = {}
    model = TelemetryNoise.draw(cfg, noise, rng)
    for kind, ms in streams:
        t = clocks.t_s_from_boot_us(ms * 1000)
        if kind == "ATTITUDE":
            eul, rates = model.attitude(
                euler_zyx_rad(vehicle.R_ned_from_body(t)), vehicle.body_rates_rps(t), rng
            )
            payloads[kind] = [_floats(e, r) for e, r in zip(eul, rates)]
        elif kind == "LOCAL_POSITION_NED":
            pos, vel = model.local_position(
                vehicle.position_ned_m(t), vehicle.velocity_ned_mps(t), rng
            )
            payloads[kind] = [_floats(p, v) for p, v in zip(pos, vel)]
        elif kind == "GPS_RAW_INT":
            pos = model.gps_position(vehicle.position_ned_m(t), rng)
            vel = vehicle.velocity_ned_mps(t)
            lat0 = math.radians(cfg.origin_lat_deg)
            lat = cfg.origin_lat_deg + np.degrees(pos[:, 0] / EARTH_RADIUS_M)
            lon = cfg.origin_lon_deg + np.degrees(pos[:, 1] / (EARTH_RADIUS_M * math.cos(lat0)))
            alt = cfg.origin_alt_m - pos[:, 2]
            speed = np.hypot(vel[:, 0], vel[:, 1])
            cog = np.degrees(np.arctan2(vel[:, 1], vel[:, 0])) % 360.0
            payloads[kind] = [_floats(row) for row in zip(lat, lon, alt, speed, cog)]
        else:
            payloads[kind] = [() for _ in ms]

    # Send order: by sample time; at equal times heartbeat, attitude, position, GPS.
    order = {"HEARTBEAT": 0, "ATTITUDE": 1, "LOCAL_POSITION_NED": 2, "GPS_RAW_INT": 3}
    events = [(int(m), order[kind], kind, i) for kind, ms in streams for i, m in enumerate(ms)]
    events.sort()

    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    records: list[tuple[int, bytes]] = []
    last_recv = -1
    for boot_ms, _, kind, i in events:
        values = payloads[kind][i]
        msg = _encode(mav, kind, boot_ms, values)
        t_s = (boot_ms * 1000 - clocks.boot_us_at_t0) / 1e6
        send_us = int(clocks.companion_us(t_s))
        jitter = min(rng.exponential(cfg.latency_jitter_mean_us), cfg.latency_jitter_max_us)
        recv = send_us + cfg.latency_min_us + round(jitter)
        recv = max(recv, last_recv + cfg.link_us_per_message)
        last_recv = recv
        records.append((recv, bytes(msg.pack(mav))))
    return records


def _floats(*parts: Iterable[float]) -> tuple[float, ...]:
    return tuple(float(x) for part in parts for x in part)


def copter_heartbeat(mav: Any, custom_mode: int) -> Any:
    """ArduCopter's HEARTBEAT (armed quadrotor, ``custom_mode`` its flight mode) encoded
    with ``mav`` (a pymavlink ``MAVLink`` of any dialect)."""
    return mav.heartbeat_encode(
        mavlink2.MAV_TYPE_QUADROTOR,
        mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA,
        mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
        | mavlink2.MAV_MODE_FLAG_GUIDED_ENABLED
        | mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED
        | mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
        custom_mode,
        mavlink2.MAV_STATE_ACTIVE,
    )


def _encode(
    mav: mavlink2.MAVLink, kind: str, boot_ms: int, v: tuple[float, ...]
) -> mavlink2.MAVLink_message:
    if kind == "HEARTBEAT":
        return copter_heartbeat(mav, tcm_dialect.COPTER_MODE_GUIDED)
    if kind == "ATTITUDE":
        return mav.attitude_encode(boot_ms, *v)  # roll, pitch, yaw, p, q, r
    if kind == "LOCAL_POSITION_NED":
        return mav.local_position_ned_encode(boot_ms, *v)  # x, y, z, vx, vy, vz
    lat, lon, alt, vel, cog = v
    return mav.gps_raw_int_encode(
        boot_ms * 1000,
        3,  # 3D fix
        round(lat * 1e7),
        round(lon * 1e7),
        round(alt * 1000.0),
        80,
        120,
        round(vel * 100.0),
        round(cog * 100.0) % 36000,
        14,
    )


def tlog_bytes(records: list[tuple[int, bytes]]) -> bytes:
    """The records as a ``.tlog`` file's bytes (written with :class:`TlogWriter`)."""
    buf = io.BytesIO()
    w = TlogWriter(buf)
    for recv_us, frame in records:
        w.write(recv_us, frame)
    return buf.getvalue()
