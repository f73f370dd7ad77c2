"""Boot and fly ArduPilot's real ArduCopter SITL (a flight controller nobody here wrote).

The mock autopilot (:mod:`tcm_companion.sim.vehicle.mock_autopilot`) behaves like ArduCopter
as far as we have observed it; this runs the real thing, so that tests and ``tcm-companion
sitl --autopilot ardupilot`` check the daemon and the Lua applet against the firmware
itself. See ``../shared/ardupilot-sitl/README.md`` (the build) and
``../shared/docs/autopilots.md``. Three jobs, three modules: the process and its instance
(:mod:`.ardupilot_process`), the ground-station link (:mod:`.gcs`), and here the vehicle
flown through that link.

::

    with ArduPilotSitl(params={"PRX1_TYPE": 2}) as sitl:   # boots, GPS, back to real time
        companion = sitl.connect(1, source_system=1, source_component=191)   # SERIAL1
        sitl.takeoff(5.0)
        sitl.fly_velocity(2.0, 0.0, 0.0)                   # north at 2 m/s, re-sent at 5 Hz
        sitl.set_mode("BRAKE")
        sitl.gcs.wait_statustext("...", 5.0)               # what the autopilot said

What :meth:`ArduPilotSitl.start` does, and how long each step took here (wall time, 2-core
x86-64, ``--speedup 10``; :attr:`ArduPilotSitl.boot_timings_s` has the numbers of each run):

1-2. Claims an instance and spawns the binary (:meth:`.ArduPilotProcess.spawn`).
3. Connects a ground-station link (system 255, component 190, MAVLink 2) to SERIAL0, which
   the binary waits for before it boots: accepted 0.05-0.4 s after the spawn; HEARTBEAT
   0.05-0.25 s after connecting.
4. Asks for LOCAL_POSITION_NED, GLOBAL_POSITION_INT, SYS_STATUS and EKF_STATUS_REPORT with
   MAV_CMD_SET_MESSAGE_INTERVAL (applies to this link only; ~0.01 s for the four) and waits
   until the EKF uses GPS (STATUSTEXT ``EKF3 IMU0 is using GPS``, or EKF_STATUS_REPORT with an
   absolute horizontal position) and LOCAL_POSITION_NED flows: 4.0 s of wall time.
5. Sets ``SIM_SPEEDUP`` = 1 (confirmed by PARAM_VALUE, ~0.005 s), so that the rest runs in
   real time: afterwards ``time_boot_ms`` advances 1.000 s per wall second. The whole
   ``start()`` takes 4.2-4.5 s. :meth:`ArduPilotSitl.reboot` takes the same ~4.2 s (the
   binary re-executes itself without wiping: parameters set before survive).

Observed with this runner (ArduCopter V4.8.0-dev 1b34668c; ``tests/test_ardupilot_sitl.py``):
SERIAL1/SERIAL2 accept clients connecting any time after boot; heartbeats of other
components (a companion (1, 191) on SERIAL1) are routed to SERIAL0 and back; SIM_STATE (108)
and SIMSTATE (164) are sent when asked for, without any timestamp field (SIM_STATE's float
``lat``/``lon`` carry degE7, use ``lat_int``/``lon_int``); proximity health is SYS_STATUS bit
MAV_SYS_STATUS_SENSOR_PROXIMITY (:meth:`ArduPilotSitl.proximity_healthy`); ADSB_VEHICLE from
a companion is consumed by AP_ADSB/AP_Avoidance (COLLISION messages, AVOID_ADSB mode) but not
routed to other links.

The ground-station link (:attr:`ArduPilotSitl.gcs`, a :class:`~.gcs.GcsClient`) records
every message with its receive time (``time.monotonic()``): the autopilot's heartbeats
(mode = ``custom_mode``, armed flag), every STATUSTEXT, the latest message of each type, the
history of mode changes; what was heard, the waits, parameters and commands are asked of
it directly. Its periodic senders (our own HEARTBEAT at 1 Hz, the GUIDED velocity set-point
at 5 Hz) run on its I/O thread, and it reconnects by itself when the TCP connection drops
(a reboot).
"""

from __future__ import annotations

import re
import time
from collections.abc import Mapping
from typing import Any

from ..mavlink import tcm_dialect as dialect
from ..mavlink.copter_modes import mode_name, mode_number
from ..mavlink.gcs import Message
from .ardupilot_process import ArduPilotProcess
from .errors import SitlError, SitlTimeout
from .gcs import GcsClient

__all__ = ["ArduPilotSitl"]

#: SET_POSITION_TARGET_LOCAL_NED type_mask: use vx, vy, vz (and yaw unless ignored) only
_TYPEMASK_VELOCITY = (
    dialect.POSITION_TARGET_TYPEMASK_X_IGNORE
    | dialect.POSITION_TARGET_TYPEMASK_Y_IGNORE
    | dialect.POSITION_TARGET_TYPEMASK_Z_IGNORE
    | dialect.POSITION_TARGET_TYPEMASK_AX_IGNORE
    | dialect.POSITION_TARGET_TYPEMASK_AY_IGNORE
    | dialect.POSITION_TARGET_TYPEMASK_AZ_IGNORE
    | dialect.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
)

_EKF_USING_GPS = re.compile(r"EKF\d IMU\d is using GPS")


class ArduPilotSitl(ArduPilotProcess):
    """A running ArduCopter SITL and a ground-station link to it. Use as a context manager.

    ``process``: :class:`.ArduPilotProcess`'s keyword arguments (``params``, ``scripts``,
    ``binary``, ``speedup``, ``workdir`` ...). ``streams_hz``: message name ->
    rate asked for on the ground-station link at boot. ``real_time``: set SIM_SPEEDUP to 1
    once the EKF uses GPS. ``boot_timeout_s``: how long the EKF may take to use GPS.
    """

    DEFAULT_STREAMS_HZ: Mapping[str, float] = {
        "LOCAL_POSITION_NED": 10.0,
        "GLOBAL_POSITION_INT": 5.0,
        "SYS_STATUS": 5.0,
        "EKF_STATUS_REPORT": 2.0,
    }

    def __init__(
        self,
        *,
        real_time: bool = True,
        streams_hz: Mapping[str, float] | None = None,
        boot_timeout_s: float = 60.0,
        **process: Any,
    ) -> None:
        super().__init__(**process)
        self.real_time = real_time
        self.streams_hz = dict(self.DEFAULT_STREAMS_HZ if streams_hz is None else streams_hz)
        self.boot_timeout_s = boot_timeout_s
        #: wall-clock durations (s) of the start-up steps of the last (re)boot
        self.boot_timings_s: dict[str, float] = {}
        self._gcs: GcsClient | None = None
        self._clients: list[GcsClient] = []
        self._velocity_key = "velocity"

    # -- life cycle --------------------------------------------------------------------------

    def __enter__(self) -> ArduPilotSitl:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> None:
        """Claim an instance, spawn the binary, connect, wait for GPS, go real time."""
        if self.process is not None:
            raise SitlError("already started")
        try:
            self._start()
        except BaseException as exc:
            report = self.failure_report()
            self.stop()
            if isinstance(exc, SitlError):
                raise SitlError(f"{exc}\n{report}") from exc
            raise

    def _start(self) -> None:
        t_start = time.monotonic()
        self.spawn()
        timings = {"claim_and_spawn": time.monotonic() - t_start}
        t = time.monotonic()
        self._gcs = gcs = GcsClient(
            self.serial_url(0), connect_timeout_s=None, name=f"SITL{self.instance} GCS"
        )
        gcs.wait_for(lambda: self.check_alive() or gcs.connected, 15.0, "SERIAL0 to accept")
        timings["serial0_accept"] = time.monotonic() - t
        t = time.monotonic()
        gcs.wait_for(
            lambda: self.check_alive() or gcs.heartbeats(), 15.0, "the autopilot's HEARTBEAT"
        )
        timings["heartbeat"] = time.monotonic() - t
        self._streams_gps_real_time(timings, t_start, t_start, "")

    def _streams_gps_real_time(
        self, timings: dict[str, float], t_start: float, gps_since: float, after: str
    ) -> None:
        """The end of a boot: ask for the streams, wait until the EKF uses GPS (texts since
        ``gps_since``), then back to real time; step times into ``timings``."""
        gcs = self.gcs
        t = time.monotonic()
        for name, rate_hz in self.streams_hz.items():
            gcs.set_message_interval(name, rate_hz)
        timings["message_intervals"] = time.monotonic() - t
        t = time.monotonic()
        since = gps_since if gps_since else t
        gcs.wait_for(
            lambda: self.check_alive() or self.ekf_uses_gps(since_s=since),
            self.boot_timeout_s,
            f"the EKF to use GPS and LOCAL_POSITION_NED to flow{after}",
        )
        timings["ekf_uses_gps"] = time.monotonic() - t
        if self.real_time:
            t = time.monotonic()
            gcs.set_param("SIM_SPEEDUP", 1.0)
            timings["sim_speedup_1"] = time.monotonic() - t
        timings["total"] = time.monotonic() - t_start
        self.boot_timings_s = timings

    def ekf_uses_gps(self, since_s: float | None = None) -> bool:
        """Whether the EKF has said it uses GPS (STATUSTEXT, or EKF_STATUS_REPORT with an
        absolute horizontal position) and LOCAL_POSITION_NED arrived (after ``since_s``)."""
        gcs = self.gcs
        lpn = gcs.latest("LOCAL_POSITION_NED")
        if lpn is None or (since_s is not None and lpn.t_s < since_s):
            return False
        if any(_EKF_USING_GPS.search(s.text) for s in gcs.statustexts(since_s)):
            return True
        ekf = gcs.latest("EKF_STATUS_REPORT")
        flags = ekf.msg.flags if ekf is not None else 0
        return bool(flags & dialect.EKF_POS_HORIZ_ABS) and not (flags & dialect.EKF_CONST_POS_MODE)

    def stop(self) -> None:
        """Close every link, then stop the process (:meth:`.ArduPilotProcess.stop`).
        Idempotent; also runs at interpreter exit."""
        for client in [*self._clients, *([self._gcs] if self._gcs else [])]:
            client.close()
        self._clients.clear()
        super().stop()

    # -- the links ---------------------------------------------------------------------------

    @property
    def gcs(self) -> GcsClient:
        """The ground-station link on SERIAL0 (system 255, component 190)."""
        if self._gcs is None:
            raise SitlError("not started")
        return self._gcs

    def connect(
        self,
        serial: int = 1,
        *,
        source_system: int = 1,
        source_component: int = dialect.MAV_COMP_ID_ONBOARD_COMPUTER,
        heartbeat_type: int | None = dialect.MAV_TYPE_ONBOARD_CONTROLLER,
        name: str = "",
    ) -> GcsClient:
        """Another MAVLink client on SERIALn (default: a companion, (1, 191), on SERIAL1);
        closed by :meth:`stop`."""
        client = GcsClient(
            self.serial_url(serial),
            source_system=source_system,
            source_component=source_component,
            heartbeat_type=heartbeat_type,
            name=name or f"SITL{self.instance} SERIAL{serial} ({source_system},{source_component})",
        )
        self._clients.append(client)
        return client

    def failure_report(self, lines: int = 30) -> str:
        """The console's tail and the last STATUSTEXTs, for assertion messages."""
        texts = self._gcs.statustexts()[-lines:] if self._gcs is not None else []
        where = f"SITL instance {self.instance}, working directory {self.workdir}"
        return (
            f"{where}\n--- console ---\n{self.console_tail(lines)}\n--- STATUSTEXT ---\n"
            + "\n".join(f"{s.t_s:.2f} [{s.severity}] {s.text}" for s in texts)
        )

    # -- the vehicle's state -----------------------------------------------------------------

    def local_position_ned(self) -> Message | None:
        """The last LOCAL_POSITION_NED (x, y, z m; vx, vy, vz m/s; time_boot_ms)."""
        rec = self.gcs.latest("LOCAL_POSITION_NED")
        return rec.msg if rec is not None else None

    def proximity_healthy(self) -> bool | None:
        """From the last SYS_STATUS: None if no proximity sensor is present (or no SYS_STATUS
        yet), else its bit MAV_SYS_STATUS_SENSOR_PROXIMITY in ``onboard_control_sensors_health``."""
        rec = self.gcs.latest("SYS_STATUS", (1, 1))
        if rec is None:
            return None
        bit = dialect.MAV_SYS_STATUS_SENSOR_PROXIMITY
        if not rec.msg.onboard_control_sensors_present & bit:
            return None
        return bool(rec.msg.onboard_control_sensors_health & bit)

    # -- flying ------------------------------------------------------------------------------

    def set_mode(self, mode: str | int, timeout_s: float = 5.0) -> None:
        """MAV_CMD_DO_SET_MODE (custom mode) and wait for a heartbeat in that mode."""
        gcs = self.gcs
        number = mode_number(mode)
        result = gcs.command_long(
            dialect.MAV_CMD_DO_SET_MODE,
            dialect.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
            number,
            timeout_s=timeout_s,
        )
        if result != dialect.MAV_RESULT_ACCEPTED:
            raise SitlError(f"mode {mode_name(number)} refused (MAV_RESULT {result})")
        gcs.wait_for(lambda: gcs.mode == number, timeout_s, f"mode {mode_name(number)}")

    def arm(self, timeout_s: float = 20.0, force: bool = False) -> None:
        """Arm, retrying every second while pre-arm checks fail; SitlError with the last
        pre-arm texts on timeout."""
        gcs = self.gcs
        since = time.monotonic()
        deadline = since + timeout_s
        while time.monotonic() < deadline:
            try:
                gcs.command_long(dialect.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196 if force else 0)
            except SitlTimeout:
                pass
            try:
                gcs.wait_for(lambda: gcs.armed, 1.0, "armed")
                return
            except SitlTimeout:
                continue
        texts = [s.text for s in gcs.statustexts(since) if "arm" in s.text.lower()][-5:]
        raise SitlError(f"could not arm in {timeout_s:.0f} s: {texts}")

    def disarm(self, force: bool = False, timeout_s: float = 5.0) -> None:
        gcs = self.gcs
        gcs.command_long(dialect.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196 if force else 0)
        gcs.wait_for(lambda: gcs.armed is False, timeout_s, "disarmed")

    def takeoff(self, alt_m: float, timeout_s: float = 30.0, tolerance_m: float = 0.5) -> None:
        """GUIDED, arm, MAV_CMD_NAV_TAKEOFF to ``alt_m`` above home; wait until within
        ``tolerance_m`` of it (LOCAL_POSITION_NED z, the EKF origin being home)."""
        self.set_mode("GUIDED")
        self.arm()
        result = self.gcs.command_long(dialect.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt_m)
        if result != dialect.MAV_RESULT_ACCEPTED:
            raise SitlError(f"takeoff refused (MAV_RESULT {result})")

        def up() -> bool:
            lpn = self.local_position_ned()
            return lpn is not None and -lpn.z >= alt_m - tolerance_m

        self.gcs.wait_for(up, timeout_s, f"altitude {alt_m} m")

    def fly_velocity(
        self,
        vn_m_s: float,
        ve_m_s: float,
        vd_m_s: float,
        yaw_rad: float | None = None,
        rate_hz: float = 5.0,
    ) -> None:
        """Fly at this NED velocity in GUIDED (SET_POSITION_TARGET_LOCAL_NED, MAV_FRAME_LOCAL_NED,
        velocity only; heading ``yaw_rad`` if given). ArduCopter drops a velocity target after
        ~3 s, so it is re-sent at ``rate_hz`` until :meth:`stop_velocity` or another call."""
        gcs = self.gcs
        mask = _TYPEMASK_VELOCITY | (
            dialect.POSITION_TARGET_TYPEMASK_YAW_IGNORE if yaw_rad is None else 0
        )

        def target() -> Message:
            return gcs.mav.set_position_target_local_ned_encode(
                gcs.time_boot_ms(time.monotonic()),
                1,
                1,
                dialect.MAV_FRAME_LOCAL_NED,
                mask,
                0.0,
                0.0,
                0.0,
                vn_m_s,
                ve_m_s,
                vd_m_s,
                0.0,
                0.0,
                0.0,
                0.0 if yaw_rad is None else yaw_rad,
                0.0,
            )

        gcs.set_periodic(self._velocity_key, rate_hz, target)

    def stop_velocity(self) -> None:
        """Stop re-sending the velocity set-point (GUIDED then holds after its ~3 s time-out)."""
        self.gcs.clear_periodic(self._velocity_key)

    def reboot(self, timeout_s: float | None = None) -> None:
        """MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN (disarmed): the binary ``execv``\\ s itself with the
        same arguments; reconnect, wait for GPS again and return to real time."""
        gcs = self.gcs
        if self.real_time:
            gcs.set_param("SIM_SPEEDUP", self.speedup)
        disconnects = gcs.disconnects
        t_start = time.monotonic()
        result = gcs.command_long(dialect.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1)
        if result != dialect.MAV_RESULT_ACCEPTED:
            raise SitlError(f"reboot refused (MAV_RESULT {result})")
        gcs.wait_for(
            lambda: self.check_alive() or gcs.disconnects > disconnects, 10.0, "the reboot"
        )
        t = time.monotonic()
        gcs.wait_for(lambda: self.check_alive() or gcs.connected, 10.0, "reconnection")
        timings = {"disconnect": t - t_start, "reconnect": time.monotonic() - t}
        t = time.monotonic()
        gcs.wait_message("HEARTBEAT", 15.0, since_s=t_start, src=(1, 1))
        timings["heartbeat"] = time.monotonic() - t
        if timeout_s is not None:
            self.boot_timeout_s = timeout_s
        self._streams_gps_real_time(timings, t_start, 0.0, " after the reboot")
