"""A mock ArduCopter that flies a simulated scenario and speaks MAVLink: sans-IO core.

The companion's MAVLink endpoint needs a flight controller to talk to in tests and on the
bench. :class:`MockAutopilot` is one, built like h11/aioquic and like the companion's own
endpoint: bytes and time in (:meth:`~MockAutopilot.receive_data`,
:meth:`~MockAutopilot.poll`, both returning events), bytes out
(:meth:`~MockAutopilot.data_to_send`), the next timer from
:meth:`~MockAutopilot.next_deadline_us`. No sockets, no clock: every entry point takes
``now_us`` (any monotonic µs; the caller's clock). The asyncio runner is
:mod:`.mock_autopilot_run`.

It is three parts, composed here:

- the firmware's MAVLink side (:mod:`.mock_firmware`): heartbeat, streams, commands,
  parameters, TIMESYNC, as ArduCopter does them on one link;
- the vehicle (:mod:`.mock_vehicle`): the scenario's flight, the brake manoeuvre, the
  exact state (:meth:`~MockAutopilot.vehicle_truth`) and the noisy telemetry, with the
  simulator's noise model (:class:`~.telemetry.TelemetryNoise`; ``noise`` scales it, 0
  gives exact telemetry);
- the checks of the companion's messages (:mod:`.mock_checks`).

What it does with the companion's messages: every TCM_OBJECT_STATUS and
TCM_PIPELINE_HEALTH is recorded with its receive time and checked (enums, finite angles
in range, and ``time_boot_ms`` against the mock's own boot clock: "stale" when too old,
"future" when ahead). A valid, fresh status with ``collision_course = 1`` and a finite
``ttc`` below ``brake_ttc_s`` makes the vehicle brake (when ``brake_on_collision``): it
decelerates to a hover at ``brake_decel_mps2`` peak, switches to BRAKE mode in its
HEARTBEAT, says "brake: collision course track N" and emits :class:`BrakeStarted`.
OBSTACLE_DISTANCE, OBSTACLE_DISTANCE_3D (ardupilotmega) and ADSB_VEHICLE are recorded;
:attr:`MockAutopilot.proximity_healthy` follows ArduPilot's AP_Proximity_MAV (healthy
while OBSTACLE_DISTANCE(_3D) keeps arriving, "No Data" 500 ms after the last one).

Faults never raise: garbage, bad CRC, unknown ids, messages for other systems, time going
backwards, a full transmit buffer are all counted in :attr:`MockAutopilot.stats`.
"""

from __future__ import annotations

from collections import Counter, deque
from typing import Any

from ...mavlink import tcm_dialect as mav
from ...mavlink.codec import MavlinkCodec
from ..scene.scenarios import flight_plan
from .mock_checks import STATUS_IDS, check_status, collision_alarm
from .mock_firmware import STREAM_DEFAULT_INTERVAL_US, MockFirmware
from .mock_types import (
    BrakeStarted,
    CommandReceived,
    MockAutopilotConfig,
    MockClock,
    MockEvent,
    ObstacleReceived,
    ParamChanged,
    PeerSeen,
    ReceivedStatus,
    StatusReceived,
)
from .mock_vehicle import BrakingPath, MockVehicle, VehicleTruth

__all__ = [
    "STREAM_DEFAULT_INTERVAL_US",
    "BrakeStarted",
    "BrakingPath",
    "CommandReceived",
    "MockAutopilot",
    "MockAutopilotConfig",
    "MockEvent",
    "ObstacleReceived",
    "ParamChanged",
    "PeerSeen",
    "ReceivedStatus",
    "StatusReceived",
    "VehicleTruth",
]

_OBSTACLE_IDS = frozenset(
    {mav.MAVLINK_MSG_ID_OBSTACLE_DISTANCE, mav.MAVLINK_MSG_ID_OBSTACLE_DISTANCE_3D}
)


class MockAutopilot:
    """An ArduCopter-like MAVLink vehicle flying a simulated scenario (sans-IO)."""

    def __init__(self, config: MockAutopilotConfig, start_us: int) -> None:
        self.config = config
        self.plan = flight_plan(config.scenario, seed=config.seed)
        self.stats: Counter[str] = Counter()
        self.clock = MockClock(start_us, self.stats)
        self.vehicle = MockVehicle(self.plan, config, self.clock)
        self.firmware = MockFirmware(config, self.vehicle, self.clock, self.stats)
        self.received_status: deque[ReceivedStatus] = deque(maxlen=config.max_records)
        self.received_obstacles: deque[ObstacleReceived] = deque(maxlen=config.max_records)
        self.received_adsb: deque[ObstacleReceived] = deque(maxlen=config.max_records)
        self._last_obstacle_us: int | None = None
        self._brake: BrakeStarted | None = None

    # -- the caller's interface ----------------------------------------------------------
    def receive_data(self, data: bytes, now_us: int) -> list[MockEvent]:
        """Take bytes from the link; return what happened. Never raises."""
        events: list[MockEvent] = []
        try:
            now = self.clock.advance(now_us)
            if not isinstance(data, bytes | bytearray | memoryview):
                self.stats["bad input"] += 1
                return events
            msgs = self.codec.feed(bytes(data))
        except Exception:
            self.stats["internal error"] += 1
            return events
        for msg in msgs:
            try:
                self._handle(msg, now, events)
            except Exception:  # a hostile value we did not foresee: count, carry on
                self.stats["handler error"] += 1
        return events

    def poll(self, now_us: int) -> list[MockEvent]:
        """Advance to ``now_us`` and queue every message that has come due; returns the
        events of the time that passed (none today: everything the mock reports follows
        a message it received). Never raises."""
        try:
            self.firmware.poll(self.clock.advance(now_us))
        except Exception:
            self.stats["internal error"] += 1
        return []

    def data_to_send(self) -> bytes:
        """Drain the bytes queued for the link."""
        return self.firmware.data_to_send()

    def next_deadline_us(self) -> int:
        """When :meth:`poll` next has something to do (caller's clock, µs); never before
        the latest time seen, so something overdue reads as "now"."""
        return self.firmware.next_deadline_us()

    def reboot(self, now_us: int) -> None:
        """Reboot the firmware: boot clock back to 0, stream rates forgotten, no EKF
        origin, sequence numbers from 0; SYSID_THISMAV changes take effect. The vehicle
        keeps flying (and braking) as before: only the autopilot's software restarts."""
        try:
            self.clock.advance(now_us)
            self.vehicle.redraw()
            self.firmware.reboot()
            self.stats["reboots"] += 1
        except Exception:
            self.stats["internal error"] += 1

    def statustext(self, severity: int, text: str) -> None:
        """Send a STATUSTEXT now (cut to 50 characters, as ArduPilot does)."""
        self.firmware.statustext(severity, text)

    def start_brake(
        self, now_us: int, track_id: int, ttc_s: float, text: str | None = None
    ) -> BrakeStarted | None:
        """Start the brake manoeuvre now (the built-in rule, or an outside decider such
        as the Lua applet, :mod:`.lua_applet`); None when already braking. ``text``
        replaces the STATUSTEXT (empty: none)."""
        if self._brake is not None:
            return None
        now = self.clock.advance(now_us)
        brake = self.vehicle.start_brake(now, self.config.brake_decel_mps2)
        self.firmware.mode = mav.COPTER_MODE_BRAKE
        self._brake = BrakeStarted(
            now, int(track_id), float(ttc_s), brake.speed_mps, brake.hover_at_us, brake.hover_ned_m
        )
        self.stats["brakes"] += 1
        if text is None:
            text = f"brake: collision course track {track_id}"
        if text:
            self.statustext(mav.MAV_SEVERITY_WARNING, text)
        return self._brake

    # -- state -----------------------------------------------------------------------------
    @property
    def now_us(self) -> int:
        """The latest caller time seen (µs)."""
        return self.clock.now_us

    @property
    def codec(self) -> MavlinkCodec:
        """The link's codec (a new one after each reboot)."""
        return self.firmware.codec

    @property
    def system_id(self) -> int:
        return self.firmware.system_id

    def boot_us(self, now_us: int | None = None) -> int:
        """The autopilot's time since boot (µs) at ``now_us`` (default: the latest time seen)."""
        return self.firmware.boot_us(now_us)

    def scenario_t_s(self, now_us: int | None = None) -> float:
        """Scenario time (s) of the flight at ``now_us`` (default: the latest time seen)."""
        return self.vehicle.t_s(now_us)

    def vehicle_truth(self, now_us: int | None = None) -> VehicleTruth:
        """The vehicle's exact state at ``now_us`` (default: the latest time seen)."""
        return self.vehicle.truth(now_us)

    @property
    def ekf_has_origin(self) -> bool:
        return self.firmware.ekf_has_origin()

    @property
    def proximity_healthy(self) -> bool:
        """ArduPilot's proximity status at the latest time seen: PRX1_TYPE = 2 and an
        OBSTACLE_DISTANCE(_3D) within ``proximity_timeout_us``."""
        if int(self.firmware.params["PRX1_TYPE"].value) != 2 or self._last_obstacle_us is None:
            return False
        return self.clock.now_us - self._last_obstacle_us <= self.config.proximity_timeout_us

    @property
    def braking(self) -> BrakeStarted | None:
        """The brake in force (latched until the mock is discarded), or None."""
        return self._brake

    @property
    def params(self) -> dict[str, float]:
        return {name: p.value for name, p in self.firmware.params.items()}

    @property
    def stream_intervals_us(self) -> dict[int, int]:
        """Message id -> interval (µs) on this link; 0 = not streamed."""
        return dict(self.firmware.interval_us)

    @property
    def peers(self) -> dict[tuple[int, int], int]:
        """(system, component) -> caller time of its last HEARTBEAT."""
        return self.firmware.peers

    @property
    def timesync_rtt_us(self) -> int | None:
        """Round trip of the mock's own last TIMESYNC request that was answered."""
        return self.firmware.timesync_rtt_us

    # -- what it received ------------------------------------------------------------------
    def _handle(self, msg: Any, now: int, events: list[MockEvent]) -> None:
        src = (int(msg.get_srcSystem()), int(msg.get_srcComponent()))
        if src == (self.system_id, self.config.component_id):
            self.stats["own echo ignored"] += 1  # a looped-back link
            return
        mid = int(msg.get_msgId())
        if self.firmware.handle(msg, mid, src, now, events):
            return
        if mid in STATUS_IDS:
            self._handle_status(msg, src, now, events)
        elif mid in _OBSTACLE_IDS:
            if src[0] != self.system_id:  # proximity data comes from our own companion
                self.stats["other system ignored"] += 1
                return
            self._last_obstacle_us = now
            rec = ObstacleReceived(now, src[0], src[1], msg)
            self.received_obstacles.append(rec)
            events.append(rec)
        elif mid == mav.MAVLINK_MSG_ID_ADSB_VEHICLE:
            # AP_ADSB takes traffic from any system (a GCS may relay it).
            rec = ObstacleReceived(now, src[0], src[1], msg)
            self.received_adsb.append(rec)
            events.append(rec)
        else:
            self.stats["ignored " + str(msg.get_type())] += 1

    def _handle_status(
        self, msg: Any, src: tuple[int, int], now: int, events: list[MockEvent]
    ) -> None:
        if src[0] != self.system_id:
            # Another vehicle's companion: not about our airspace.
            self.stats["other system ignored"] += 1
            return
        cfg = self.config
        boot_ms = self.boot_us(now) // 1000
        problems = check_status(msg, boot_ms, cfg.status_max_age_ms, cfg.status_max_lead_ms)
        is_object = msg.get_msgId() == mav.MAVLINK_MSG_ID_TCM_OBJECT_STATUS
        self.stats["object status" if is_object else "pipeline health"] += 1
        for problem in problems:
            self.stats["status " + problem.split()[0]] += 1
        rec = ReceivedStatus(now, boot_ms, src[0], src[1], msg, problems)
        self.received_status.append(rec)
        events.append(StatusReceived(rec))
        if is_object:
            self._maybe_brake(rec, now, events)

    def _maybe_brake(self, rec: ReceivedStatus, now: int, events: list[MockEvent]) -> None:
        """The built-in rule: brake on a trusted collision alarm."""
        if not collision_alarm(rec.msg, self.config.brake_ttc_s):
            return
        if not self.config.brake_on_collision:
            self.stats["collision alarm (brake disabled)"] += 1
            return
        if not rec.ok:
            # An alarm we cannot trust (stale time or bad fields) is not acted on.
            self.stats["collision alarm ignored (bad status)"] += 1
            return
        brake = self.start_brake(now, int(rec.msg.track_id), float(rec.msg.ttc))
        if brake is not None:
            events.append(brake)
