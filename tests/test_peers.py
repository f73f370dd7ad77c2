"""A spoofed or confused peer cannot drive the companion (issue 24 §3): the endpoint's
guards, sans-IO, on a simulated clock.

The real autopilot is the mock (:class:`MockAutopilot`, ArduCopter-like); peers are
codecs that write whatever they like under whatever id. Everything the companion sends
is decoded and counted. The same attacks over real loopback UDP beside the mock
autopilot's process are ``tests/test_adversarial_link.py``.
"""

from __future__ import annotations

import heapq
import logging
import math
import random
from collections.abc import Callable
from typing import Any

import pytest

from tcm_companion.core.telemetry import AttitudeSample
from tcm_companion.mavlink import tcm_dialect as d
from tcm_companion.mavlink.codec import SIGNING_EPOCH_US, MavlinkCodec, SigningConfig
from tcm_companion.mavlink.endpoint import (
    REQUEST_BURST,
    AutopilotConflict,
    AutopilotRebooted,
    CompanionEndpoint,
    EndpointConfig,
    ParamChanged,
    TelemetryReceived,
    TelemetryRejected,
)
from tcm_companion.mavlink.peers import SenderGuard, TokenBucket
from tcm_companion.sim.vehicle.mock_autopilot import MockAutopilot, MockAutopilotConfig

from .helpers import decode

START = 5_000_000_000  # µs on the simulated clock
S = 1_000_000


class Link:
    """The companion endpoint and the mock autopilot on one simulated clock (1 ms each
    way), plus peers that inject bytes at times of their choosing. Every message the
    companion sends is decoded into ``sent`` with its time."""

    def __init__(self, endpoint: CompanionEndpoint | None = None, **mock: Any) -> None:
        self.now = START
        self.companion = endpoint or CompanionEndpoint(now_us=START)
        self.mock = MockAutopilot(MockAutopilotConfig(**mock), START)
        self.queue: list[tuple[int, int, str, bytes]] = []
        self.n = 0
        self.events: list[Any] = []
        self.sent: list[tuple[int, Any]] = []
        # (next time, step(now) -> bytes for the companion, period)
        self.peers: list[list[Any]] = []

    def add_peer(self, start_us: int, period_us: int, step: Callable[[int], bytes]) -> None:
        self.peers.append([start_us, period_us, step])

    def _push(self, at: int, to: str, data: bytes) -> None:
        if data:
            heapq.heappush(self.queue, (at, self.n, to, data))
            self.n += 1

    def run(self, seconds: float) -> None:
        end = self.now + int(seconds * S)
        while self.now < end:
            nxt = min(self.companion.next_deadline_us(), self.mock.next_deadline_us(), end)
            if self.queue:
                nxt = min(nxt, self.queue[0][0])
            for p in self.peers:
                nxt = min(nxt, p[0])
            self.now = max(self.now, nxt)
            for p in self.peers:
                if p[0] <= self.now:
                    self._push(self.now, "companion", p[2](self.now))
                    p[0] += p[1]
            while self.queue and self.queue[0][0] <= self.now:
                _, _, to, data = heapq.heappop(self.queue)
                if to == "mock":
                    self.mock.receive_data(data, self.now)
                else:
                    self.events += self.companion.receive_data(data, self.now)
            self.events += self.companion.poll(self.now)
            self.mock.poll(self.now)
            out = self.companion.data_to_send()
            self.sent += [(self.now, m) for m in decode(out)]
            self._push(self.now + 1000, "mock", out)
            self._push(self.now + 1000, "companion", self.mock.data_to_send())

    def sent_of(self, kind: str, since_us: int = 0) -> list[Any]:
        return [m for t, m in self.sent if m.get_type() == kind and t >= since_us]

    def texts(self) -> list[str]:
        return [m.text for m in self.sent_of("STATUSTEXT")]

    def of(self, kind: type) -> list[Any]:
        return [e for e in self.events if isinstance(e, kind)]


class Spoofer:
    """A second sender under the autopilot's id (1, 1) — its own sequence numbers and
    boot clock, the clock going backwards now and then, a NaN attitude every third
    message, a heartbeat every 50 (what issue 24 saw on an unsigned link)."""

    def __init__(self, sysid: int = 1, compid: int = 1, seed: int = 1) -> None:
        self.codec = MavlinkCodec(sysid, compid)
        self.codec.mav.seq = 77  # wherever its own numbering happens to be
        self.rng = random.Random(seed)
        self.boot_ms = 5_000
        self.k = 0

    def __call__(self, now_us: int) -> bytes:
        self.k += 1
        out = b""
        if self.k % 50 == 1:
            out += self.codec.encode(
                d.MAVLink_heartbeat_message(
                    d.MAV_TYPE_QUADROTOR, d.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3
                )
            )
        self.boot_ms += 20 if self.rng.random() > 0.2 else -self.rng.randint(100, 3000)
        roll = math.nan if self.k % 3 == 0 else self.rng.uniform(-3, 3)
        att = d.MAVLink_attitude_message(max(0, self.boot_ms), roll, -3.0, 0.0, 0, 0, 0)
        return out + self.codec.encode(att)


@pytest.mark.slow  # over a second of CPU
def test_a_spoofer_as_the_autopilot_is_one_conflict_not_a_reboot_storm() -> None:
    """Issue 24 §3: a second sender as 1/1 with its own clock (going back) and NaN
    attitude was taken as an autopilot reboot 504 times and drew 60-93 COMMAND_LONG a
    second. Now: no reboot, no request beyond the two the start needs, one conflict
    (one STATUSTEXT, the health flag while it lasts), nothing of the spoofer's used, and
    the conflict ends 10 s after the spoofer stops."""
    link = Link(ekf_origin_delay_us=0)
    link.run(4.0)
    assert len(link.sent_of("COMMAND_LONG")) == 2  # ATTITUDE and LOCAL_POSITION_NED
    t_spoof = link.now
    spoofer = Spoofer()
    link.add_peer(t_spoof, 20_000, spoofer)
    link.run(20.0)
    link.peers.clear()
    t_stop = link.now
    during = [e for e in link.events if isinstance(e, TelemetryReceived)]
    link.run(12.0)
    ep = link.companion
    assert not link.of(AutopilotRebooted), ep.stats
    assert ep.stats["autopilot reboots"] == 0
    # 1000 spoofed messages drew not one more command to the autopilot.
    assert len(link.sent_of("COMMAND_LONG", since_us=t_spoof)) == 0, ep.stats
    assert [(e.active, e.system_id, e.component_id) for e in link.of(AutopilotConflict)] == [
        (True, 1, 1),
        (False, 1, 1),
    ]
    assert ep.stats["autopilot conflicts"] == 1
    texts = link.texts()
    assert texts.count("TCM: two senders as autopilot 1/1, objects unknown") == 1, texts
    assert "TCM: autopilot 1/1 one sender again" in texts
    flagged = [
        m.health & d.TCM_HEALTH_AUTOPILOT_CONFLICT != 0
        for t, m in link.sent
        if m.get_type() == "TCM_PIPELINE_HEALTH" and t_spoof + S < t < t_stop
    ]
    assert flagged and all(flagged)
    assert not ep.link_health_flags(link.now) & d.TCM_HEALTH_AUTOPILOT_CONFLICT
    # Never a mixture: every attitude used is the mock's, on the mock's boot clock (the
    # spoofer's clock is ~5 s, the mock's ~4-40 s), and none of its NaNs was even looked at.
    spoofed = [
        e.sample
        for e in during
        if isinstance(e.sample, AttitudeSample)
        and e.sample.recv_us > t_spoof
        and abs(e.sample.recv_us - START - e.sample.time_boot_us) > 50_000
    ]
    assert spoofed == []
    assert not link.of(TelemetryRejected)
    assert ep.stats["autopilot id: off-sequence message"] >= 900
    assert ep.link_counts()["autopilot conflicts"] == 1
    # The real autopilot's streams went on throughout.
    late = [
        e
        for e in during
        if isinstance(e.sample, AttitudeSample) and e.sample.recv_us > t_stop - 5 * S
    ]
    assert len(late) > 200


def test_one_stray_message_is_no_reboot_but_a_real_reboot_still_is() -> None:
    link = Link(ekf_origin_delay_us=0)
    link.run(4.0)
    ep = link.companion
    stray = MavlinkCodec(1, 1)
    assert ep.guard.current is not None
    stray.mav.seq = (ep.guard.current.last_seq + 128) % 256
    # One message under the autopilot's id, its own numbering, the clock 1 s after boot
    # (the mock's is at 4 s).
    att = d.MAVLink_attitude_message(1_000, 0.1, 0.0, 0.0, 0, 0, 0)
    ev = ep.receive_data(stray.encode(att), link.now)
    assert ev == [] and ep.stats["autopilot id: off-sequence message"] == 1
    link.run(3.0)
    assert not link.of(AutopilotRebooted) and not link.of(AutopilotConflict)
    # The mock reboots: its numbering starts again from 0 and its clock from 0: a
    # sequence that takes over while the old one is silent, with the clock back.
    t_reboot = link.now
    link.mock.reboot(t_reboot)
    link.run(6.0)
    assert len(link.of(AutopilotRebooted)) == 1, ep.stats
    assert ep.stats["autopilot sequence restarts"] == 1
    after = [
        e.sample
        for e in link.events
        if isinstance(e, TelemetryReceived)
        and isinstance(e.sample, AttitudeSample)
        and e.sample.recv_us > t_reboot + 4 * S
    ]
    assert len(after) > 50  # the streams were asked for again and flow
    assert abs(ep.timesync.offset_us - (link.now - link.mock.boot_us(link.now))) < 3000


def test_requests_to_the_autopilot_are_rate_limited_whatever_the_link_says() -> None:
    """An autopilot that seems to reboot every 0.8 s (silent for 0.6 s, then a new
    sequence with the clock back: what a real reboot looks like) gets at most
    ``REQUEST_BURST`` commands and then one a second, not two per reboot."""
    ep = CompanionEndpoint(now_us=START)
    now = START
    commands = 0
    reboots = 0
    end = START + 20 * S
    while now < end:
        ap = MavlinkCodec(1, 1)
        msgs = [
            d.MAVLink_heartbeat_message(
                d.MAV_TYPE_QUADROTOR, d.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3
            )
        ] + [d.MAVLink_attitude_message(t, 0, 0, 0, 0, 0, 0) for t in (1000, 1020, 1040, 5000)]
        for k, m in enumerate(msgs):
            now += 600_000 if k == 0 else 40_000
            for t in range(now - 30_000, now, 10_000):  # the companion's timers meanwhile
                ep.poll(t)
            reboots += sum(
                isinstance(e, AutopilotRebooted) for e in ep.receive_data(ap.encode(m), now)
            )
            ep.poll(now)
            for cmd in decode(ep.data_to_send()):
                if cmd.get_type() == "COMMAND_LONG":  # ACCEPTED at once, as ArduPilot does
                    commands += 1
                    ack = d.MAVLink_command_ack_message(cmd.command, 0, 0, 0, 1, 191)
                    ep.receive_data(ap.encode(ack), now + 1000)
    assert reboots >= 20, (reboots, commands, ep.stats)  # each looked like a real reboot ...
    assert commands <= REQUEST_BURST + 20 + 1  # ... but the budget held (2 per reboot wanted)
    assert ep.stats["requests rate-limited"] > 0


def test_the_guard_alone() -> None:
    g = SenderGuard()
    assert g.observe(10, 0).verdict == "current"
    assert g.observe(11, 1).verdict == "current"
    assert g.observe(13, 2, frame=b"x").verdict == "current"  # one lost: the same sender
    assert g.observe(13, 3, frame=b"x").verdict == "duplicate"  # the same frame again
    assert g.observe(200, 4).verdict == "other"  # a stray: no conflict yet
    assert g.observe(14, 5).verdict == "current" and not g.conflict
    assert g.observe(201, 6).verdict == "other"
    assert g.observe(15, 7).verdict == "current" and g.conflict  # two interleaves
    g.poll(7 + 9_000_000)
    assert g.conflict
    g.poll(6 + 10_000_000)
    assert not g.conflict and g.conflicts == 1
    # A time jump on the followed line needs the next number exactly.
    assert g.observe(17, 11_000_000, anomalous=True).verdict == "other"
    # A restart: the old line silent while a new one counts 3.
    h = SenderGuard()
    h.observe(100, 0)
    h.observe(101, 1)
    # ... a burst of three right after the followed line's last message is not one ...
    assert [h.observe(s, 2 + s).verdict for s in (0, 1, 2)] == ["other"] * 3
    # ... the followed line silent for half a second is.
    assert h.observe(3, 500_001).verdict == "switched"
    assert h.observe(102, 500_010).verdict == "other"  # the old one back: not followed
    # A sender that does not number its messages (seq always 0: this project's mock and
    # companion before issue 24, in older flight logs) is still one sender, and its
    # reboot (the clock back) is still a restart.
    u = SenderGuard()
    assert {u.observe(0, t, frame=bytes([t])).verdict for t in range(10)} == {"current"}
    restart = [
        u.observe(0, 600_000 + t, anomalous=True, frame=b"r%d" % t).verdict for t in range(3)
    ]
    assert restart == ["other", "other", "switched"]


def test_a_spoofers_message_that_happens_to_fit_takes_nothing_over() -> None:
    """Seen against real ArduCopter: the spoofer's first message (a heartbeat, no clock)
    fell 15 numbers after the autopilot's last and joined its line; its next message
    continued that exactly with its clock 40 s back: a "reboot", and the spoofer followed
    from then on. Now the skip is provisional: no clock jump is believed after it, and the
    autopilot's next number shows it was another sender's."""
    g = SenderGuard()
    for seq in (60, 61, 62):
        assert g.observe(seq, seq * 20_000, boot_ms=46_000 + seq * 20).verdict == "current"
    assert g.observe(77, 1_250_000).verdict == "current"  # fits: 14 lost, as far as it shows
    jump = g.observe(78, 1_251_000, anomalous=True, boot_ms=5_020)
    assert jump.verdict == "other"  # not the autopilot's reboot
    assert g.observe(63, 1_260_000, boot_ms=46_660).verdict == "current"  # back on its own
    assert g.current is not None and g.current.last_seq == 63
    for k in range(4):  # the spoofer goes on, the autopilot too: a conflict, not a takeover
        t = 1_270_000 + k * 20_000
        assert g.observe(79 + k, t, boot_ms=5_040 + 20 * k).verdict == "other"
        assert g.observe(64 + k, t + 10_000, boot_ms=46_680 + 20 * k).verdict == "current"
    assert g.conflict and g.switches == 0


def test_token_bucket() -> None:
    b = TokenBucket(3, 1000, 0)
    assert [b.take(0) for _ in range(4)] == [True, True, True, False]
    assert b.ready_us(0) == 1001 and not b.take(999) and b.take(1001)
    assert not b.take(500)  # a clock going back refills nothing


# -- beyond the list: other ways a peer could drive the companion --------------------------
def connected() -> tuple[CompanionEndpoint, MavlinkCodec]:
    ep = CompanionEndpoint(now_us=START)
    ap = MavlinkCodec(1, 1)
    ep.receive_data(
        ap.encode(
            d.MAVLink_heartbeat_message(
                d.MAV_TYPE_QUADROTOR, d.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3
            )
        ),
        START,
    )
    ep.receive_data(ap.encode(d.MAVLink_attitude_message(60_000, 0, 0, 0, 0, 0, 0)), START)
    ep.data_to_send()
    return ep, ap


def _flood(ep: CompanionEndpoint, peer: MavlinkCodec, msg: Any, n: int, seconds: float) -> list:
    """``n`` copies of ``msg`` from ``peer`` spread over ``seconds``; what came back."""
    got: list[Any] = []
    events: list[Any] = []
    for i in range(n):
        now = START + 1000 + int(i * seconds * S / n)
        events += ep.receive_data(peer.encode(msg), now)
        ep.poll(now)
        got += decode(ep.data_to_send())
    return got + [("event", e) for e in events]


def test_a_parameter_set_storm_is_bounded() -> None:
    """1000 PARAM_SET a second from one ground station: each accepted change rebuilds the
    pipeline and is saved to disk, so they are served at most 20 at once and 5 a second
    per peer (10 in all)."""
    ep, _ = connected()
    gcs = MavlinkCodec(255, 190)
    got: list[Any] = []
    for i in range(1000):
        now = START + 1000 + i * 1000
        value = 0.05 + 0.01 * (i % 2)
        got += ep.receive_data(
            gcs.encode(d.MAVLink_param_set_message(1, 191, b"TCM_THRESH", value, 9)), now
        )
        got += decode(ep.data_to_send())
    changes = [e for e in got if isinstance(e, ParamChanged)]
    values = [m for m in got if getattr(m, "get_type", lambda: "")() == "PARAM_VALUE"]
    assert 20 <= len(changes) <= 26 and len(values) <= 26
    assert ep.stats["parameter set rate-limited"] >= 970


def test_request_floods_are_bounded() -> None:
    ep, _ = connected()
    gcs = MavlinkCodec(255, 190)
    req_list = d.MAVLink_param_request_list_message(1, 191)
    out = _flood(ep, gcs, req_list, 200, 1.0)
    values = [m for m in out if not isinstance(m, tuple) and m.get_type() == "PARAM_VALUE"]
    assert len(values) <= 3 * 15  # two lists at once, one more in the second
    health = d.MAVLink_command_long_message(
        1, 191, d.MAV_CMD_REQUEST_MESSAGE, 0, d.MAVLINK_MSG_ID_TCM_PIPELINE_HEALTH, 0, 0, 0, 0, 0, 0
    )
    ep2, _ = connected()
    out = _flood(ep2, gcs, health, 1000, 1.0)
    acks = [m for m in out if not isinstance(m, tuple) and m.get_type() == "COMMAND_ACK"]
    assert len(acks) <= 16 and ep2.stats["command rate-limited"] >= 980
    # TIMESYNC requests (a peer may ask for our clock) are answered 10 at once, 10 a second.
    ep3, _ = connected()
    out = _flood(ep3, gcs, d.MAVLink_timesync_message(0, 123), 1000, 1.0)
    answers = [m for m in out if not isinstance(m, tuple) and m.get_type() == "TIMESYNC"]
    answers = [m for m in answers if m.ts1 == 123]
    assert 10 <= len(answers) <= 21
    # A peer rotating its source id still meets the limit of all peers together.
    ep4, _ = connected()
    n_acks = 0
    for i in range(1000):
        now = START + 1000 + i * 1000
        peer = MavlinkCodec(200 + i % 50, 190)
        ep4.receive_data(peer.encode(health), now)
        n_acks += sum(m.get_type() == "COMMAND_ACK" for m in decode(ep4.data_to_send()))
    assert n_acks <= 20 + 10 + 1


def test_the_health_interval_cannot_be_set_to_spin_the_loop() -> None:
    ep, _ = connected()
    gcs = MavlinkCodec(255, 190)
    for interval in (1.0, -5.0, math.inf, math.nan, 1e12):
        cmd = d.MAVLink_command_long_message(
            1, 191, d.MAV_CMD_SET_MESSAGE_INTERVAL, 0, d.MAVLINK_MSG_ID_TCM_PIPELINE_HEALTH,
            interval, 0, 0, 0, 0, 0,
        )  # fmt: skip
        ep.receive_data(gcs.encode(cmd), START + 10)
        (ack,) = [m for m in decode(ep.data_to_send()) if m.get_type() == "COMMAND_ACK"]
        assert ack.result == d.MAV_RESULT_DENIED, interval
    assert ep.config.health_interval_us == EndpointConfig().health_interval_us
    # A sane one is applied.
    cmd = d.MAVLink_command_long_message(
        1, 191, d.MAV_CMD_SET_MESSAGE_INTERVAL, 0, d.MAVLINK_MSG_ID_TCM_PIPELINE_HEALTH,
        200_000, 0, 0, 0, 0, 0,
    )  # fmt: skip
    ep.receive_data(gcs.encode(cmd), START + 20)
    assert ep.config.health_interval_us == 200_000


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_timesync_is_the_autopilots_alone() -> None:
    """ArduPilot forwards our TIMESYNC request to its other links, where a ground
    station may answer with its own clock; a spoofer under the autopilot's id may answer
    too. Neither moves our offset."""
    link = Link(ekf_origin_delay_us=0)
    link.run(4.0)
    ep = link.companion
    offset = ep.timesync.offset_us
    resets = ep.timesync.resets
    gcs, spoof = MavlinkCodec(255, 190), MavlinkCodec(1, 1)
    spoof.mav.seq = 150

    def answer(now_us: int) -> bytes:
        out = b""
        for ts1 in list(ep._timesync_sent):
            fake = d.MAVLink_timesync_message(999_000_000_000, ts1)  # ~1000 s after boot
            out += gcs.encode(fake) + spoof.encode(fake)
        return out

    link.add_peer(link.now, 1000, answer)
    link.run(10.0)
    assert ep.timesync.resets == resets and abs(ep.timesync.offset_us - offset) < 2000
    assert ep.stats["timesync reply from another component"] >= 9
    assert not link.of(AutopilotRebooted)


def test_a_statustext_flood_and_another_autopilot_change_nothing() -> None:
    ep, _ = connected()
    gcs = MavlinkCodec(255, 190)
    other = MavlinkCodec(2, 1)
    events: list[Any] = []
    sent: list[Any] = []
    for i in range(2000):
        now = START + 1000 + i * 1000
        events += ep.receive_data(
            gcs.encode(d.MAVLink_statustext_message(4, b"flood %d" % i, 0, 0)), now
        )
        if i % 100 == 0:
            events += ep.receive_data(
                other.encode(
                    d.MAVLink_heartbeat_message(
                        d.MAV_TYPE_QUADROTOR, d.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3
                    )
                ),
                now,
            )
        events += ep.receive_data(
            other.encode(d.MAVLink_attitude_message(1000 + i, 3.0, -3.0, 0, 0, 0, 0)), now
        )
        ep.poll(now)
        sent += decode(ep.data_to_send())
    assert events == []  # nothing of theirs is telemetry, a parameter or a command
    assert ep.stats["ignored STATUSTEXT"] == 2000
    assert ep.stats["telemetry from another system"] == 2000
    texts = [m.text for m in sent if m.get_type() == "STATUSTEXT"]
    assert texts.count("TCM: another autopilot 2/1 on link, following 1/1") == 1
    assert ep.autopilot is not None and ep.autopilot.system_id == 1


# -- signing (issue 24 §3: two INFO lines per wrongly signed frame) --------------------------
def test_wrongly_signed_frames_are_counted_by_reason_and_logged_once_a_second(
    caplog: pytest.LogCaptureFixture,
) -> None:
    key = bytes(range(32))
    now = SIGNING_EPOCH_US + 10**15
    ep = CompanionEndpoint(now_us=now, signing=SigningConfig(key))
    good = MavlinkCodec(1, 1, SigningConfig(key))
    forger = MavlinkCodec(1, 1, SigningConfig(bytes(32)))
    plain = MavlinkCodec(1, 1)
    hb = d.MAVLink_heartbeat_message(
        d.MAV_TYPE_QUADROTOR, d.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3
    )
    caplog.set_level(logging.INFO)
    ep.receive_data(good.encode(hb, now), now)
    replay = good.encode(hb, now + 1)
    ep.receive_data(replay, now + 2)
    for i in range(700):  # 14 s at 50 a second
        t = now + 1000 + i * 20_000
        ep.receive_data(forger.encode(hb, t), t)
        if i % 10 == 0:
            ep.receive_data(plain.encode(hb), t)
            ep.receive_data(replay, t)  # the same signed frame again
        ep.poll(t)
    stats = ep.codec.stats
    assert stats["signature rejected: wrong key"] == 700
    assert stats["signature rejected: unsigned"] == 70
    assert stats["signature rejected: replayed timestamp"] == 70
    assert stats["signature rejected"] == 840
    dialect = [r for r in caplog.records if r.name == d.__name__]
    assert dialect == []  # was 2 INFO lines per frame
    ours = [r for r in caplog.records if "MAVLink signing" in r.getMessage()]
    assert 10 <= len(ours) <= 15, [r.getMessage() for r in ours]  # at most once a second
    assert "wrong key" in ours[-1].getMessage()
    t_end = now + 1000 + 699 * 20_000
    assert ep.link_health_flags(t_end) & d.TCM_HEALTH_SIGNATURE_REJECTED
    assert not ep.link_health_flags(t_end + 11 * S) & d.TCM_HEALTH_SIGNATURE_REJECTED
    assert ep.link_counts()["signature rejected"] == 840
    texts = [m.text for m in decode(ep.data_to_send()) if m.get_type() == "STATUSTEXT"]
    assert texts.count("TCM: frames with a bad or no signature rejected") <= 2
    assert ep.autopilot is not None  # the good heartbeat went through


def test_the_companion_makes_objects_unknown_while_senders_conflict() -> None:
    """The Companion's side of a conflict: one fault, the reason on every object and the
    status line, the health flag; the pipelines start over when it ends."""
    from tcm_companion.core.camera import Equirectangular
    from tcm_companion.core.pipeline import PipelineConfig
    from tcm_companion.service.companion import Companion

    ep, _ = connected()
    comp = Companion([Equirectangular(360, 220)], PipelineConfig(), ep, START)
    before = comp.pipeline(0)
    comp.on_events([AutopilotConflict(1, 1, True)], START + 10)
    assert comp.stats.faults["autopilot conflict"] == 1
    assert comp._blocking_input(START + 20) == "two senders as autopilot 1/1"
    assert "two senders as autopilot 1/1" in comp.status_line(START + 20)
    comp.on_events([AutopilotConflict(1, 1, False)], START + 30)
    assert comp._blocking_input(START + 40) != "two senders as autopilot 1/1"
    assert comp.pipeline(0) is not before  # tracks start over
    assert comp.stats.faults["autopilot conflict"] == 1
