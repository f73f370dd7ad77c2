"""The companion's MAVLink endpoint: a sans-IO state machine (bytes and time in, events and
bytes out), in the manner of h11 and aioquic.

What it does, as a well-behaved companion component (mavlink.io microservices):

- HEARTBEAT at 1 Hz as MAV_TYPE_ONBOARD_CONTROLLER / MAV_AUTOPILOT_INVALID, component id
  191 by default, system id learned from the autopilot; the autopilot is *lost* after
  ~5 missed heartbeats and *rebooted* when its boot clock goes backwards — as one sender:
  messages under the autopilot's id that do not continue its MAVLink sequence are not
  used, a clock jump is believed from a message that continues the sequence exactly or
  from a new sequence that took over while the old one fell silent, and two interleaved
  senders are a *conflict* (:class:`~.peers.SenderGuard`, :class:`AutopilotConflict`).
- Requests the telemetry it needs with MAV_CMD_SET_MESSAGE_INTERVAL, one command at a
  time, retried, with a fallback and rate checks (:mod:`.streams`); at most
  :data:`REQUEST_BURST` such commands at once and one per :data:`REQUEST_INTERVAL_US`
  after that, whatever happens on the link.
- Telemetry messages become samples by the one rule replay uses too
  (:func:`tcm_companion.mavlink.samples.parse_telemetry`); unusable ones are
  :class:`TelemetryRejected`.
- TIMESYNC requests; replies matched by ``ts1`` (the message has no target fields) and
  filtered (:mod:`.timesync`, which also says when an offset is fresh); the autopilot's
  own requests answered.
- The parameter protocol for our tunables (:mod:`.params`), COMMAND_LONG/COMMAND_INT to
  us answered with COMMAND_ACK (UNSUPPORTED when we do not support it), each kind of
  request served at a bounded rate per peer and in all (:data:`REQUEST_LIMITS`), optional
  MAVLink 2 signing (:mod:`.codec`; rejected frames counted, logged at most once a
  second).
- STATUSTEXT through a bounded queue, each condition rate-limited (:mod:`.statustext`);
  a collision alarm is one condition per track.
- Outputs: TCM_OBJECT_STATUS for every object of every frame, TCM_PIPELINE_HEALTH at
  2 Hz, and when enabled OBSTACLE_DISTANCE (10 Hz, only while frames are fresh),
  OBSTACLE_DISTANCE_3D and ADSB_VEHICLE (:mod:`.outputs`).

The events it returns are in :mod:`.events` (re-exported here). It never raises into its
caller: malformed input is counted in :attr:`stats` and dropped. Time is always an
argument (``now_us``, the companion's clock, the same clock as the frame times);
:meth:`next_deadline_us` says when :meth:`poll` has work next.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from ..core.pipeline import FrameResult, ObjectResult
from ..core.telemetry import ClockSync, PositionSample
from . import outputs
from . import tcm_dialect as d
from .codec import MavlinkCodec, SigningConfig
from .events import (
    AutopilotConflict,
    AutopilotFound,
    AutopilotLost,
    AutopilotRebooted,
    CommandReceived,
    Event,
    GlobalOrigin,
    HealthReport,
    ParamChanged,
    TelemetryReceived,
    TelemetryRejected,
    TrackingImageStatus,
)
from .params import PARAMS, ParamTable
from .peers import Limit, PeerLimits, SenderGuard, TokenBucket
from .samples import TELEMETRY_TYPES, Rejected, parse_telemetry
from .statustext import CollisionConditions, StatustextQueue
from .streams import StreamRequests
from .timesync import TimesyncFilter

__all__ = [
    "AutopilotConflict",
    "AutopilotFound",
    "AutopilotLost",
    "AutopilotRebooted",
    "CommandReceived",
    "CompanionEndpoint",
    "EndpointConfig",
    "Event",
    "GlobalOrigin",
    "HealthReport",
    "ParamChanged",
    "TelemetryReceived",
    "TelemetryRejected",
    "TrackingImageStatus",
]

log = logging.getLogger(__name__)

MAV_COMP_ID_ALL = 0
_FTP_NAK = 129  # MAVLink FTP opcode
_FTP_ERR_UNKNOWN_COMMAND = 7

#: How often each kind of request addressed to us is served, per peer (system,
#: component) and for all peers together; beyond, it is dropped unanswered and counted
#: (``"<kind> rate-limited"``). Generous for a ground station (a parameter file of ~20
#: values at once; a list every few seconds), bounded for a flood: a PARAM_SET rebuilds
#: the pipeline and is saved to disk, a PARAM_REQUEST_LIST costs ~15 PARAM_VALUE.
REQUEST_LIMITS: dict[str, Limit] = {
    "command": Limit(10, 200_000, 20, 100_000),
    "parameter list": Limit(2, 2_000_000, 4, 1_000_000),
    "parameter read": Limit(40, 50_000, 80, 25_000),
    "parameter set": Limit(20, 200_000, 40, 100_000),
    "timesync request": Limit(10, 100_000, 20, 50_000),
    "ftp": Limit(10, 200_000, 20, 100_000),
}
#: Commands to the autopilot (stream requests and re-requests): at most this many at
#: once, then one per :data:`REQUEST_INTERVAL_US`, whatever the link does (a spoofer's
#: fake reboots once drew 60-93 a second). Not a setting: a bound.
REQUEST_BURST = 8
REQUEST_INTERVAL_US = 1_000_000
#: MAV_CMD_SET_MESSAGE_INTERVAL for TCM_PIPELINE_HEALTH: intervals outside are refused
#: (1 µs made the daemon's loop spin, sending health messages as fast as it could).
HEALTH_INTERVAL_MIN_US = 50_000
HEALTH_INTERVAL_MAX_US = 60_000_000
#: A rejected frame (bad or missing signature) sets TCM_HEALTH_SIGNATURE_REJECTED this long.
SIGNATURE_FLAG_US = 10_000_000
#: Signature rejections are logged at most once per this long (with the count per reason).
SIGNATURE_LOG_US = 1_000_000
#: Messages kept from a sequence line that is not (yet) followed: if it takes over (a
#: reboot), they are handled then, in order.
_HELD_PER_LINE = 4


@dataclass(frozen=True)
class EndpointConfig:
    component_id: int = 191
    default_system_id: int = 1  # until the autopilot's heartbeat tells us its system id
    heartbeat_interval_us: int = 1_000_000
    autopilot_timeout_us: int = 5_000_000  # ~5 missed heartbeats
    attitude_message: Literal["ATTITUDE", "ATTITUDE_QUATERNION"] = "ATTITUDE"
    attitude_rate_hz: float = 50.0
    position_rate_hz: float = 10.0
    request_retry_us: int = 1_000_000  # no COMMAND_ACK within this: send again
    rate_check_us: int = 3_000_000  # after an ACK, the rate must show within this
    timesync_interval_us: int = 1_000_000
    timesync_fast_interval_us: int = 200_000  # until the filter has a few samples
    health_interval_us: int = 500_000
    obstacle_interval_us: int = 100_000
    fresh_frame_us: int = 500_000  # obstacle outputs stop when frames are older
    statustext_min_interval_us: int = 250_000
    statustext_repeat_us: int = 10_000_000  # the same condition is not repeated within this
    collision_clear_us: int = 2_000_000  # a track's collision ends this long after its last alarm
    statustext_queue: int = 16


@dataclass
class _Autopilot:
    system_id: int
    component_id: int
    last_heartbeat_us: int
    lost: bool = False
    last_boot_ms: int = -1
    last_boot_at_us: int = 0  # when last_boot_ms last advanced


class CompanionEndpoint:
    """Sans-IO MAVLink endpoint of the companion (one per link)."""

    def __init__(
        self,
        config: EndpointConfig = EndpointConfig(),
        params: Mapping[str, float] | None = None,
        signing: SigningConfig | None = None,
        now_us: int = 0,
        threshold: float | None = None,
        param_defaults: Mapping[str, float] | None = None,
    ) -> None:
        self.config = config
        self.codec = MavlinkCodec(config.default_system_id, config.component_id, signing)
        self.params = ParamTable(params, param_defaults)
        #: Judges a whole candidate table after a PARAM_SET passed its own range check:
        #: "" if it can be applied, else why not (values that only fail together, e.g. a
        #: seed hue range that leaves the grow range). The value is then refused as an
        #: out-of-range one is. Set by the application (the Companion); None: no check.
        self.param_check: Callable[[Mapping[str, float]], str] | None = None
        self.stats: Counter[str] = Counter()
        self.timesync = TimesyncFilter()
        self.telemetry_clock = ClockSync()  # fallback mapping when TIMESYNC is silent
        self.autopilot: _Autopilot | None = None
        self.origin: GlobalOrigin | None = None
        self.vehicle_pos_ned_m: np.ndarray | None = None
        self._out = bytearray()
        self._events: list[Event] = []
        self._next_heartbeat = now_us
        self._next_timesync = now_us
        self._next_health = now_us
        self._next_obstacle = now_us
        self._timesync_sent: deque[int] = deque(maxlen=16)  # ts1 values (ns) awaiting replies
        attitude_id = (
            d.MAVLINK_MSG_ID_ATTITUDE_QUATERNION
            if config.attitude_message == "ATTITUDE_QUATERNION"
            else d.MAVLINK_MSG_ID_ATTITUDE
        )
        self.streams = StreamRequests(
            [
                (attitude_id, config.attitude_rate_hz),
                (d.MAVLINK_MSG_ID_LOCAL_POSITION_NED, config.position_rate_hz),
            ],
            config.request_retry_us,
            config.rate_check_us,
            self.stats,
            now_us,
        )
        self.statustexts = StatustextQueue(
            config.statustext_min_interval_us,
            config.statustext_repeat_us,
            config.statustext_queue,
            self.stats,
            now_us,
        )
        self._collisions = CollisionConditions(config.collision_clear_us)
        # Who speaks as the autopilot (one sender?), how often peers are served, how
        # often we command the autopilot.
        self.guard = SenderGuard()
        self._held: dict[int, deque[tuple[Any, int]]] = {}
        self._conflict = False
        self.limits = PeerLimits(REQUEST_LIMITS, self.stats)
        self._request_buckets: dict[tuple[int, int], TokenBucket] = {}
        self._request_deferred = False
        self._now_us = now_us  # the latest time seen
        # Signature rejections: when the last one was seen, and what was last logged.
        self._signature_seen_us: int | None = None
        self._signature_logged_us: int | None = None
        self._signature_logged: Counter[str] = Counter()
        self._other_autopilots: set[tuple[int, int]] = set()
        self._health = HealthReport()
        # Each camera's last objects and when they were sent: OBSTACLE_DISTANCE covers
        # every camera whose frames are fresh (one message, the rig's every sector).
        self._last_objects: dict[int, tuple[int, tuple[ObjectResult, ...]]] = {}
        self._last_frame_us: int | None = None
        self._threshold = threshold

    # -- identity --------------------------------------------------------------------------
    @property
    def system_id(self) -> int:
        return self.codec.src_system

    @property
    def component_id(self) -> int:
        return self.codec.src_component

    @property
    def autopilot_connected(self) -> bool:
        return self.autopilot is not None and not self.autopilot.lost

    # -- receiving ---------------------------------------------------------------------------
    def receive_data(self, data: bytes, now_us: int) -> list[Event]:
        """Bytes from the link; returns what they meant. Never raises."""
        self._now_us = max(self._now_us, now_us)
        for msg in self.codec.feed(data):
            try:
                self._handle(msg, now_us)
            except Exception as exc:  # a hostile but well-framed message: count, go on
                self.stats[f"handler error {type(exc).__name__}"] += 1
        self._report_signatures(now_us)
        return self._take_events()

    def _report_signatures(self, now_us: int) -> None:
        """Frames the codec rejected for their signature: the health flag, and a log
        line (the count per reason since the last one) at most once per
        :data:`SIGNATURE_LOG_US` — never a line per frame."""
        stats = self.codec.stats
        total = stats["signature rejected"]
        if total == self._signature_logged["signature rejected"]:
            return
        self._signature_seen_us = now_us
        last = self._signature_logged_us
        if last is not None and now_us - last < SIGNATURE_LOG_US:
            return
        reasons = {
            k: stats[k] - self._signature_logged[k]
            for k in stats
            if k.startswith("signature rejected:") and stats[k] > self._signature_logged[k]
        }
        n = total - self._signature_logged["signature rejected"]
        log.warning(
            "MAVLink signing: %d frame(s) rejected (%s); %d so far",
            n,
            ", ".join(f"{v} {k.split(': ', 1)[1]}" for k, v in sorted(reasons.items())),
            total,
        )
        self.statustext(
            d.MAV_SEVERITY_WARNING,
            "TCM: frames with a bad or no signature rejected",
            now_us,
            key="signature rejected",
        )
        self._signature_logged_us = now_us
        self._signature_logged = Counter({k: v for k, v in stats.items() if "signature" in k})

    def _take_events(self) -> list[Event]:
        events, self._events = self._events, []
        return events

    def _handle(self, msg: Any, now_us: int) -> None:
        ap = self.autopilot
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if ap is None or src != (ap.system_id, ap.component_id):
            self._dispatch(msg, now_us, from_autopilot=False)
            return
        # The autopilot's id: is it the sender we follow? (SenderGuard)
        seen = self.guard.observe(
            msg.get_seq(),
            now_us,
            self._contradicts_clock(msg, now_us),
            self._boot_ms_of(msg),
            bytes(msg.get_msgbuf()),
        )
        if seen.verdict == "duplicate":
            self.stats["autopilot id: duplicate frame"] += 1
        elif seen.verdict == "other":
            # Another sender, or the autopilot restarting: kept a little, in case this
            # sequence takes over (then handled in order), else dropped.
            self.stats["autopilot id: off-sequence message"] += 1
            held = self._held.setdefault(seen.line, deque(maxlen=_HELD_PER_LINE))
            held.append((msg, now_us))
            live = self.guard.live_lines()
            for line in [k for k in self._held if k not in live]:
                del self._held[line]
        elif seen.verdict == "switched":
            # The sequence we followed fell silent while a new one counted on: a restart
            # (a reboot numbers from 0). Its messages are the autopilot's now; a clock
            # jump among them is its reboot.
            self.stats["autopilot sequence restarts"] += 1
            for held_msg, held_us in self._held.pop(seen.line, ()):
                self._dispatch(held_msg, held_us, from_autopilot=True)
            self._dispatch(msg, now_us, from_autopilot=True)
        else:
            # A clock jump reaches here only in a message that continues the sequence
            # exactly, with no other sender between the autopilot's messages lately
            # (SenderGuard.observe): then it is the autopilot's reboot.
            self._dispatch(msg, now_us, from_autopilot=True)
        self._check_conflict(now_us)

    def _boot_ms_of(self, msg: Any) -> int | None:
        """The sender's boot time (ms) a message states: telemetry's ``time_boot_ms``, a
        TIMESYNC reply's ``tc1``; None for the rest."""
        kind = msg.get_type()
        if kind in TELEMETRY_TYPES:
            return int(msg.time_boot_ms)
        if kind == "TIMESYNC" and msg.tc1 > 0 and msg.ts1 in self._timesync_sent:
            return int(msg.tc1) // 1_000_000
        return None

    def _contradicts_clock(self, msg: Any, now_us: int) -> bool:
        """Whether a message of the autopilot's id says its clock jumped: telemetry more
        than 1 s behind the last, or a TIMESYNC reply that would restart the filter."""
        ap = self.autopilot
        assert ap is not None
        kind = msg.get_type()
        if kind in TELEMETRY_TYPES:
            boot_ms = int(msg.time_boot_ms)
            if ap.last_boot_ms < 0:
                return False
            # More than 1 s back (a reboot, or another sender), or ahead of where its
            # clock can be by now (another sender).
            ahead_ms = ap.last_boot_ms + (now_us - ap.last_boot_at_us) // 1000
            return not ap.last_boot_ms - 1000 <= boot_ms <= ahead_ms + 1000
        if kind == "TIMESYNC" and msg.tc1 != 0 and msg.ts1 in self._timesync_sent:
            return self.timesync.would_restart(msg.ts1 // 1000, msg.tc1, now_us)
        return False

    def _check_conflict(self, now_us: int) -> None:
        """Report the guard's conflict when it starts or ends."""
        if self.guard.conflict == self._conflict or self.autopilot is None:
            return
        self._conflict = self.guard.conflict
        ap = self.autopilot
        self._events.append(AutopilotConflict(ap.system_id, ap.component_id, self._conflict))
        who = f"autopilot {ap.system_id}/{ap.component_id}"
        if self._conflict:
            self.stats["autopilot conflicts"] += 1
            log.warning("two senders use the id of %s (MAVLink sequences interleave)", who)
            self.statustext(
                d.MAV_SEVERITY_WARNING,
                f"TCM: two senders as {who}, objects unknown",
                now_us,
                key="autopilot conflict",
            )
        else:
            log.info("%s: one sender again", who)
            self.statustext(
                d.MAV_SEVERITY_INFO,
                f"TCM: {who} one sender again",
                now_us,
                key="autopilot conflict over",
            )

    @property
    def conflict(self) -> bool:
        """Two senders use the followed autopilot's id now (:class:`AutopilotConflict`)."""
        return self._conflict

    def link_health_flags(self, now_us: int) -> int:
        """The health flags the link itself raises: TCM_HEALTH_AUTOPILOT_CONFLICT while
        two senders use the autopilot's id, TCM_HEALTH_SIGNATURE_REJECTED while a frame
        was rejected for its signature within :data:`SIGNATURE_FLAG_US`."""
        flags = d.TCM_HEALTH_AUTOPILOT_CONFLICT if self._conflict else 0
        seen = self._signature_seen_us
        if seen is not None and now_us - seen < SIGNATURE_FLAG_US:
            flags |= d.TCM_HEALTH_SIGNATURE_REJECTED
        return flags

    def link_counts(self) -> dict[str, int]:
        """What peers did to the link that the companion refused or bounded: frames
        rejected for their signature, conflicts and off-sequence messages under the
        autopilot's id, requests and commands rate-limited (zeros left out)."""
        out = {
            k: v
            for k, v in self.codec.stats.items()
            if (k.startswith("signature rejected") or k == "unsigned rejected") and v
        }
        for k, v in self.stats.items():
            if v and (
                k.startswith("autopilot id:")
                or k.endswith("rate-limited")
                or k
                in (
                    "autopilot conflicts",
                    "autopilot sequence restarts",
                    "another autopilot",
                    "timesync reply from another component",
                )
            ):
                out[k] = v
        return out

    def _dispatch(self, msg: Any, now_us: int, *, from_autopilot: bool) -> None:
        """One message, once the guard let it through (``from_autopilot``: the sender we
        follow, whose clock jump is believed)."""
        kind = msg.get_type()
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if kind == "HEARTBEAT":
            self._on_heartbeat(msg, src, now_us)
            return
        if kind in TELEMETRY_TYPES:
            if from_autopilot:
                self._on_telemetry(msg, now_us)
            else:
                self.stats["telemetry from another system"] += 1
        elif kind == "TIMESYNC":
            self._on_timesync(msg, src, now_us, from_autopilot)
        elif kind == "COMMAND_ACK":
            if (
                from_autopilot
                and msg.target_system in (0, self.system_id)
                and msg.command == d.MAV_CMD_SET_MESSAGE_INTERVAL
            ):
                self.streams.on_ack(msg.result, now_us)
        elif kind in ("COMMAND_LONG", "COMMAND_INT"):
            if self._addressed_to_us(
                msg.target_system, msg.target_component, broadcast=False
            ) and self.limits.allow("command", src, now_us):
                self._on_command(msg, src, now_us)
        elif kind in ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"):
            if self._addressed_to_us(
                msg.target_system, msg.target_component, broadcast=True
            ) and self.limits.allow(_PARAM_KIND[kind], src, now_us):
                self._on_param(msg, kind, now_us)
        elif kind == "FILE_TRANSFER_PROTOCOL":
            if self._addressed_to_us(
                msg.target_system, msg.target_component, broadcast=False
            ) and self.limits.allow("ftp", src, now_us):
                self._on_ftp(msg, src, now_us)
        elif kind in ("GPS_GLOBAL_ORIGIN", "HOME_POSITION"):
            if from_autopilot and kind == "GPS_GLOBAL_ORIGIN":
                self.origin = GlobalOrigin(
                    msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3
                )
                self._events.append(self.origin)
        elif kind == "CAMERA_TRACKING_IMAGE_STATUS":
            # A tracking camera's target (the Companion may take it as a box).
            self._events.append(
                TrackingImageStatus(
                    src,
                    int(msg.tracking_status),
                    int(msg.tracking_mode),
                    int(msg.target_data),
                    float(msg.rec_top_x),
                    float(msg.rec_top_y),
                    float(msg.rec_bottom_x),
                    float(msg.rec_bottom_y),
                    int(msg.camera_device_id),
                    now_us,
                )
            )
        else:
            self.stats[f"ignored {kind}"] += 1

    def _addressed_to_us(self, target_system: int, target_component: int, broadcast: bool) -> bool:
        if target_system not in (0, self.system_id):
            return False
        if target_component == self.component_id:
            return True
        return broadcast and target_component == MAV_COMP_ID_ALL

    def _on_heartbeat(self, msg: Any, src: tuple[int, int], now_us: int) -> None:
        is_autopilot = (
            msg.autopilot != d.MAV_AUTOPILOT_INVALID
            and msg.type not in (d.MAV_TYPE_GCS, d.MAV_TYPE_ONBOARD_CONTROLLER)
            and src[1] == d.MAV_COMP_ID_AUTOPILOT1
        )
        ap = self.autopilot
        if ap is not None and src == (ap.system_id, ap.component_id):
            if ap.lost:
                ap.lost = False
                self.streams.restart(now_us)
                self._events.append(AutopilotFound(src[0], src[1], msg.autopilot, msg.type))
            ap.last_heartbeat_us = now_us
            return
        if ap is None and is_autopilot:
            self.autopilot = _Autopilot(src[0], src[1], now_us)
            self.codec.src_system = src[0]  # we belong to the autopilot's system
            self.guard.reset()
            # Its sequence is the one we follow.
            self.guard.observe(msg.get_seq(), now_us, frame=bytes(msg.get_msgbuf()))
            self.streams.restart(now_us)
            self._events.append(AutopilotFound(src[0], src[1], msg.autopilot, msg.type))
            self.statustext(d.MAV_SEVERITY_INFO, "TCM companion online", now_us)
        elif is_autopilot:
            # A second autopilot on the link (another vehicle, or someone posing as one
            # under another id): we keep following the first; said once per id.
            assert ap is not None
            self.stats["another autopilot"] += 1
            if src not in self._other_autopilots and len(self._other_autopilots) < 16:
                self._other_autopilots.add(src)
                self.statustext(
                    d.MAV_SEVERITY_WARNING,
                    f"TCM: another autopilot {src[0]}/{src[1]} on link, following"
                    f" {ap.system_id}/{ap.component_id}",
                    now_us,
                    key="another autopilot",
                )
        else:
            self.stats["heartbeat of another component"] += 1

    def _on_telemetry(self, msg: Any, now_us: int) -> None:
        assert self.autopilot is not None
        boot_ms = int(msg.time_boot_ms)
        ap = self.autopilot
        if ap.last_boot_ms >= 0 and boot_ms < ap.last_boot_ms - 1000:
            # The autopilot's boot clock went back: it rebooted and forgot our requests.
            # (Its sender guard let this through: the message continues the sequence
            # exactly with no other sender about, or its new sequence took over.)
            self._on_reboot(now_us)
            ap.last_boot_ms, ap.last_boot_at_us = boot_ms, now_us
        else:
            if boot_ms > ap.last_boot_ms:
                ap.last_boot_ms, ap.last_boot_at_us = boot_ms, now_us
        self.streams.received(msg.get_msgId())
        sample = parse_telemetry(msg, now_us)
        if isinstance(sample, Rejected):
            self.stats[f"bad {sample.kind}"] += 1
            self._events.append(TelemetryRejected(sample.kind, sample.reason))
            return
        if sample is None:
            return
        self.telemetry_clock.observe(sample.time_boot_us, now_us)
        if isinstance(sample, PositionSample):
            self.vehicle_pos_ned_m = sample.pos_ned_m
        self._events.append(TelemetryReceived(sample))

    def _on_reboot(self, now_us: int, keep_timesync: bool = False) -> None:
        self.stats["autopilot reboots"] += 1
        self._events.append(AutopilotRebooted())
        self.statustext(d.MAV_SEVERITY_NOTICE, "TCM: autopilot reboot seen, re-requesting", now_us)
        if not keep_timesync:
            self.timesync = TimesyncFilter()
        self.telemetry_clock = ClockSync()
        if self.autopilot is not None:
            self.autopilot.last_boot_ms = -1
        self.streams.restart(now_us)

    # -- TIMESYNC -------------------------------------------------------------------------------
    def _on_timesync(
        self, msg: Any, src: tuple[int, int], now_us: int, from_autopilot: bool
    ) -> None:
        if msg.tc1 == 0:
            # A request (ArduPilot sends one every 10 s): answer with our clock.
            if self.limits.allow("timesync request", src, now_us):
                self._send(d.MAVLink_timesync_message(now_us * 1000, msg.ts1), now_us)
            return
        if msg.ts1 not in self._timesync_sent:
            self.stats["timesync reply not ours"] += 1
            return
        if not from_autopilot:
            # ArduPilot forwards our request to its other links, where a ground station
            # may answer with its own clock: only the autopilot's answer is its time.
            self.stats["timesync reply from another component"] += 1
            return
        self._timesync_sent.remove(msg.ts1)
        before = self.timesync.resets
        if self.timesync.add_reply(msg.ts1 // 1000, msg.tc1, now_us) is None:
            self.stats["timesync rejected"] += 1
        elif self.timesync.resets != before:
            # The autopilot's clock jumped: a reboot (it has forgotten our streams). This
            # is usually the first sign of one, a second before the telemetry shows it.
            self.stats["timesync resets"] += 1
            self._on_reboot(now_us, keep_timesync=True)

    def _service_timesync(self, now_us: int) -> None:
        if now_us < self._next_timesync or not self.autopilot_connected:
            return
        ts1 = now_us * 1000
        self._timesync_sent.append(ts1)
        self._send(d.MAVLink_timesync_message(0, ts1), now_us)
        fast = self.timesync.n_samples < 4
        self._next_timesync = now_us + (
            self.config.timesync_fast_interval_us if fast else self.config.timesync_interval_us
        )

    def has_time_base(self, now_us: int) -> bool:
        """Whether :meth:`boot_ms` maps companion times (TIMESYNC or the telemetry fit)."""
        return self.timesync.fresh(now_us) or self.telemetry_clock.ready

    def boot_ms(self, companion_us: int, now_us: int) -> int:
        """Autopilot boot time (ms) of a companion-clock instant: TIMESYNC if fresh
        (:meth:`TimesyncFilter.fresh`), else the telemetry clock fit, else 0."""
        if self.timesync.fresh(now_us):
            return max(0, int(self.timesync.to_autopilot_us(companion_us) // 1000))
        if self.telemetry_clock.ready:
            return max(0, int((companion_us - self.telemetry_clock.offset_us) // 1000))
        return 0

    # -- commands and parameters -----------------------------------------------------------------
    def _on_command(self, msg: Any, src: tuple[int, int], now_us: int) -> None:
        cmd = int(msg.command)
        params = tuple(float(getattr(msg, f"param{i}", math.nan)) for i in range(1, 8))
        result = d.MAV_RESULT_UNSUPPORTED
        if cmd == d.MAV_CMD_REQUEST_MESSAGE:
            wanted = int(params[0]) if math.isfinite(params[0]) else -1
            if wanted == d.MAVLINK_MSG_ID_HEARTBEAT:
                result = d.MAV_RESULT_ACCEPTED
                self._next_heartbeat = now_us
            elif wanted == d.MAVLINK_MSG_ID_TCM_PIPELINE_HEALTH:
                result = d.MAV_RESULT_ACCEPTED
                self.send_health_now(now_us)  # asked for: sent whatever the time base
            else:
                result = d.MAV_RESULT_DENIED
        elif (
            cmd == d.MAV_CMD_SET_MESSAGE_INTERVAL
            and int(params[0]) == d.MAVLINK_MSG_ID_TCM_PIPELINE_HEALTH
        ):
            interval = params[1]
            if HEALTH_INTERVAL_MIN_US <= interval <= HEALTH_INTERVAL_MAX_US:
                self.config = dataclasses.replace(self.config, health_interval_us=int(interval))
                result = d.MAV_RESULT_ACCEPTED
            else:
                result = d.MAV_RESULT_DENIED
        self.stats[f"command {cmd}"] += 1
        self._send(
            d.MAVLink_command_ack_message(cmd, result, 0, 0, src[0], src[1]),
            now_us,
        )
        self._events.append(CommandReceived(cmd, params, src, result))

    def _on_ftp(self, msg: Any, src: tuple[int, int], now_us: int) -> None:
        """We serve no files: NAK every MAVLink FTP request at once, so a ground station
        that tries FTP first (MAVProxy's parameter download) falls back without waiting
        out its time-out."""
        req = bytes(msg.payload)
        if len(req) < 12:
            self.stats["malformed ftp"] += 1
            return
        seq = (req[0] | (req[1] << 8)) + 1
        payload = bytearray(251)
        payload[0], payload[1] = seq & 0xFF, (seq >> 8) & 0xFF
        payload[2] = req[2]  # session
        payload[3] = _FTP_NAK
        payload[4] = 1  # data size: the error code
        payload[5] = req[3]  # the request's opcode
        payload[12] = _FTP_ERR_UNKNOWN_COMMAND
        self.stats["ftp refused"] += 1
        self._send(
            d.MAVLink_file_transfer_protocol_message(0, src[0], src[1], list(payload)), now_us
        )

    def _param_value(self, index: int) -> Any:
        spec = PARAMS[index]
        return d.MAVLink_param_value_message(
            spec.name.encode(),
            self.params.values[spec.name],
            d.MAV_PARAM_TYPE_REAL32,
            len(PARAMS),
            index,
        )

    def _on_param(self, msg: Any, kind: str, now_us: int) -> None:
        if kind == "PARAM_REQUEST_LIST":
            for i in range(len(PARAMS)):
                self._send(self._param_value(i), now_us)
            return
        name = _param_name(msg.param_id)
        if kind == "PARAM_REQUEST_READ":
            index = msg.param_index if msg.param_index >= 0 else self._index_of(name)
            if index is None or not 0 <= index < len(PARAMS):
                self.stats["unknown parameter"] += 1
                return
            self._send(self._param_value(index), now_us)
            return
        index = self._index_of(name)
        if index is None:
            self.stats["unknown parameter"] += 1
            return
        old = self.params.values[name]
        stored = self.params.set(name, float(msg.param_value))
        problem = "value out of range" if stored is None else ""
        if stored is not None and stored != old and self.param_check is not None:
            problem = self.param_check(self.params.values)
            if problem:
                self.params.values[name] = old  # refused: the table stays as it was
        if problem:
            self.stats["parameter refused"] += 1
            self.statustext(d.MAV_SEVERITY_WARNING, f"{name}: {problem}", now_us)
        elif stored is not None and stored != old:
            self._events.append(ParamChanged(name, stored))
        self._send(self._param_value(index), now_us)  # the current value, as the protocol asks

    def _index_of(self, name: str) -> int | None:
        try:
            return self.params.index(name)
        except ValueError:
            return None

    # -- sending -------------------------------------------------------------------------------
    def _send(self, msg: Any, now_us: int) -> None:
        self._out += self.codec.encode(msg, now_us)

    def data_to_send(self) -> bytes:
        """Everything queued for the link since the last call."""
        out, self._out = bytes(self._out), bytearray()
        return out

    @property
    def statustexts_queued(self) -> list[str]:
        """The distinct STATUSTEXTs this endpoint queued lately (the last 256; most recent
        last)."""
        return self.statustexts.recent

    def statustext(self, severity: int, text: str, now_us: int, key: str | None = None) -> bool:
        """Queue a STATUSTEXT; dropped (False) if the same condition went out recently or
        the queue is full (:class:`~.statustext.StatustextQueue`).

        A condition is ``key`` (default: the text itself). Texts that carry a changing
        number (a TTC, a rate) must pass a key naming the condition, or each new number
        would count as a new text and flood the ground station.
        """
        return self.statustexts.queue(severity, text, now_us, key)

    def set_health(self, report: HealthReport) -> None:
        self._health = report

    def send_frame(self, result: FrameResult, now_us: int, camera_id: int = 0) -> None:
        """Queue the outputs of one processed frame (TCM_OBJECT_STATUS per object, and
        OBSTACLE_DISTANCE_3D / ADSB_VEHICLE when enabled)."""
        self._last_objects[camera_id] = (now_us, result.objects)
        self._last_frame_us = now_us
        v = self.params.values
        threshold = self._threshold if self._threshold is not None else v["TCM_THRESH"]
        radius = v["TCM_OBJ_RADIUS"]
        boot_ms = self.boot_ms(result.t_us, now_us)
        if v["TCM_OUT_STATUS"]:
            for msg in outputs.object_statuses(result, boot_ms, threshold, camera_id, radius):
                self._send(msg, now_us)
        if v["TCM_OUT_OBST3D"]:
            for obstacle in outputs.obstacle_distance_3d(result.objects, boot_ms, radius):
                self._send(obstacle, now_us)
        if v["TCM_OUT_ADSB"] and self.origin is not None and self.vehicle_pos_ned_m is not None:
            o = self.origin
            for traffic in outputs.adsb_vehicles(
                result.objects, self.vehicle_pos_ned_m, o.lat_deg, o.lon_deg, o.alt_m, radius, {}
            ):
                self._send(traffic, now_us)
        self._announce_collisions(result, now_us)

    def fresh_objects(self, now_us: int) -> tuple[ObjectResult, ...]:
        """The last objects sent of every camera whose last frame went out less than
        ``fresh_frame_us`` before ``now_us`` (camera id order): what OBSTACLE_DISTANCE
        merges."""
        fresh_us = self.config.fresh_frame_us
        return tuple(
            obj
            for cam in sorted(self._last_objects)
            for sent_us, objects in (self._last_objects[cam],)
            if now_us - sent_us < fresh_us
            for obj in objects
        )

    def _announce_collisions(self, result: FrameResult, now_us: int) -> None:
        """One STATUSTEXT per collision condition (:class:`~.statustext.CollisionConditions`),
        not per frame or per TTC value; a new condition of the same track is announced at
        most once per ``statustext_repeat_us``."""
        alarm = self.params.values["TCM_TTC_ALARM"]
        for obj in self._collisions.update(result.objects, alarm, now_us):
            self.statustext(
                d.MAV_SEVERITY_WARNING,
                f"TCM: collision course track {obj.track_id}, TTC {obj.ttc_s:.1f}s",
                now_us,
                key=f"collision course track {obj.track_id}",
            )

    # -- timers --------------------------------------------------------------------------------
    def poll(self, now_us: int) -> list[Event]:
        """Run whatever is due at ``now_us``; returns events (e.g. the autopilot lost)."""
        cfg = self.config
        self._now_us = max(self._now_us, now_us)
        if now_us >= self._next_heartbeat:
            self._send(
                d.MAVLink_heartbeat_message(
                    d.MAV_TYPE_ONBOARD_CONTROLLER,
                    d.MAV_AUTOPILOT_INVALID,
                    0,
                    0,
                    d.MAV_STATE_ACTIVE,
                    3,
                ),
                now_us,
            )
            self._next_heartbeat = now_us + cfg.heartbeat_interval_us
        ap = self.autopilot
        if (
            ap is not None
            and not ap.lost
            and now_us - ap.last_heartbeat_us > cfg.autopilot_timeout_us
        ):
            ap.lost = True
            self._events.append(AutopilotLost(now_us - ap.last_heartbeat_us))
        if ap is not None and ap.lost:
            self.guard.reset()  # whatever speaks as it next starts anew
            self._held.clear()
        self.guard.poll(now_us)
        self._check_conflict(now_us)
        if self.autopilot_connected:
            assert ap is not None
            self._service_requests((ap.system_id, ap.component_id), now_us)
        self._service_timesync(now_us)
        for text in self.statustexts.poll(now_us):
            self._send(text, now_us)
        if now_us >= self._next_health:
            # With an autopilot, not before its clock is known: time_boot_ms = 0 reads as
            # ancient there (the mock, like the applet, calls such a report stale). With no
            # autopilot at all (a GCS alone) it goes out as it is.
            waiting = self.autopilot_connected and not self.has_time_base(now_us)
            if self.params.values["TCM_OUT_HEALTH"] and not waiting:
                self._send(self._health_message(now_us), now_us)
            self._next_health = now_us + cfg.health_interval_us
        if now_us >= self._next_obstacle:
            fresh = (
                self._last_frame_us is not None
                and now_us - self._last_frame_us < cfg.fresh_frame_us
            )
            if self.params.values["TCM_OUT_OBST"] and fresh:
                # Stale frames (camera lost) send nothing: the autopilot then flags its
                # proximity sensor unhealthy, which is the truth.
                self._send(
                    outputs.obstacle_distance(
                        self.fresh_objects(now_us), now_us, self.params.values["TCM_OBJ_RADIUS"]
                    ),
                    now_us,
                )
            self._next_obstacle = now_us + cfg.obstacle_interval_us
        return self._take_events()

    def _request_bucket(self, target: tuple[int, int]) -> TokenBucket:
        bucket = self._request_buckets.get(target)
        if bucket is None:
            bucket = TokenBucket(REQUEST_BURST, REQUEST_INTERVAL_US, self._now_us)
            self._request_buckets = {target: bucket}  # one autopilot at a time
        return bucket

    def _service_requests(self, target: tuple[int, int], now_us: int) -> None:
        """The stream requests due, within the command budget of ``target``."""
        if now_us < self.streams.next_us:
            return
        bucket = self._request_bucket(target)
        if bucket.ready_us(now_us) > now_us:
            if not self._request_deferred:
                self._request_deferred = True
                self.stats["requests rate-limited"] += 1
            return
        request = self.streams.poll(now_us, target)
        if request is not None:
            bucket.take(now_us)
            self._request_deferred = False
            self._send(request, now_us)

    def send_health_now(self, now_us: int) -> None:
        """Queue a TCM_PIPELINE_HEALTH at once (as MAV_CMD_REQUEST_MESSAGE does)."""
        self._send(self._health_message(now_us), now_us)

    def _health_message(self, now_us: int) -> Any:
        h = self._health
        flags = h.health_flags | self.link_health_flags(now_us)
        if not self.timesync.fresh(now_us):
            flags |= d.TCM_HEALTH_TIMESYNC_LOST
        offset = self.timesync.offset_us
        rtt = self.timesync.last_rtt_us
        return d.MAVLink_tcm_pipeline_health_message(
            time_boot_ms=self.boot_ms(now_us, now_us) & 0xFFFFFFFF,
            frame_rate=h.frame_rate_hz,
            latency=h.latency_ms,
            frames_dropped=h.frames_dropped & 0xFFFFFFFF,
            egomotion_source=h.egomotion_source,
            egomotion_quality=max(0, min(100, h.egomotion_quality_pct)),
            health=flags,
            objects=max(0, min(255, h.objects)),
            log_state=h.log_state,
            timesync_offset_us=int(offset) if math.isfinite(offset) else 0,
            timesync_rtt_us=min(rtt, 0xFFFF) if rtt is not None else 0xFFFF,
            protocol=outputs.PROTOCOL,
        )

    def next_deadline_us(self) -> int:
        """When :meth:`poll` next has something to do."""
        deadlines = [self._next_heartbeat, self._next_health]
        if self.autopilot_connected:
            ap = self.autopilot
            assert ap is not None
            requests = self.streams.next_us
            bucket = self._request_buckets.get((ap.system_id, ap.component_id))
            if bucket is not None and requests <= self._now_us:
                requests = max(requests, bucket.ready_us(self._now_us))
            deadlines += [requests, self._next_timesync]
            deadlines.append(ap.last_heartbeat_us + self.config.autopilot_timeout_us + 1)
        ends = self.guard.conflict_ends_us()
        if ends is not None:
            deadlines.append(ends)
        if self.statustexts.pending:
            deadlines.append(self.statustexts.next_us)
        if self.params.values["TCM_OUT_OBST"]:
            deadlines.append(self._next_obstacle)
        return min(deadlines)


_PARAM_KIND = {
    "PARAM_REQUEST_LIST": "parameter list",
    "PARAM_REQUEST_READ": "parameter read",
    "PARAM_SET": "parameter set",
}


def _param_name(raw: Any) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return str(raw).split("\x00", 1)[0]
