"""What a peer on the link may make the companion do, and how often: sans-IO guards.

On an unsigned link anyone can send anything under any system and component id. Two
things keep a spoofed or confused peer from driving the companion (issue 24 §3):

- :class:`SenderGuard` asks whether the messages that carry the followed autopilot's
  (system, component) id come from **one sender**. Every MAVLink sender numbers its
  messages (``seq``, 0..255, +1 per message on a link); a second sender using the same
  id has its own numbering, so the messages fall into two *sequence lines*. The guard
  assigns each message to the line it continues (a forward step of at most
  ``max_gap``, allowing for lost messages; the smallest step wins, and a message whose
  boot time does not fit a line's clock does not join it; the same number again — a
  sender that does not number its messages, as this project's own codec did before
  issue 24 — fits only when no step forward does; a message that continues the number
  *before* the followed line's last step, when that step skipped numbers, shows that
  step was another sender's that happened to fit, and no clock jump is believed right
  after such a step) and says whether it is the line the
  endpoint follows (``current``), another one (``other``: not used), the followed
  line's last frame again, byte for byte (``duplicate``: a looped or doubled link; not
  used), or a new line that has taken over (``switched``: the followed line fell silent
  — since the new line began, and for ``restart_silence_us`` at least — while the new
  one sent ``confirm`` messages, which is what a reboot looks like: a rebooted autopilot
  is silent for a second or more and numbers from 0 again; a burst from another sender
  between two of the autopilot's 50-Hz messages is not). Messages of another line that arrive *between* messages of the
  followed one (``interleaves``) mean two senders at once: two of them within
  ``conflict_window_us`` are a **conflict**, which lasts until that window has passed
  without any. A single stray message is one interleave: dropped, counted, no conflict.
  During a conflict nothing switches lines.
- :class:`TokenBucket` and :class:`PeerLimits` bound how often the companion acts on
  requests (per requesting peer and for all peers together: a flood that rotates its
  source ids still meets the global bucket) and how often it sends commands to the
  autopilot (stream re-requests).

Time is an argument (µs on the caller's clock) everywhere; nothing here reads a clock.
"""

from __future__ import annotations

from collections import Counter, OrderedDict, deque
from dataclasses import dataclass
from typing import Literal

SEQ_MOD = 256
#: A sender's boot clock may seem to step back or ahead by this much (link jitter, a
#: companion loop that stalled) and still be the same clock (ms).
CLOCK_SLACK_MS = 1000

Verdict = Literal["current", "switched", "other", "duplicate"]


class TokenBucket:
    """At most ``burst`` actions at once, refilled by one every ``interval_us``."""

    def __init__(self, burst: int, interval_us: int, now_us: int) -> None:
        if burst < 1 or interval_us <= 0:
            raise ValueError("a token bucket needs burst >= 1 and interval_us > 0")
        self.burst = burst
        self.interval_us = interval_us
        self._tokens = float(burst)
        self._at_us = now_us

    def _refill(self, now_us: int) -> None:
        if now_us > self._at_us:  # a clock going back refills nothing
            gained = (now_us - self._at_us) / self.interval_us
            self._tokens = min(float(self.burst), self._tokens + gained)
            self._at_us = now_us

    def take(self, now_us: int) -> bool:
        """Use one token if there is one (True), else False."""
        self._refill(now_us)
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        return False

    def ready_us(self, now_us: int) -> int:
        """The earliest time :meth:`take` succeeds (``now_us`` if it would now)."""
        self._refill(now_us)
        if self._tokens >= 1.0:
            return now_us
        return self._at_us + int((1.0 - self._tokens) * self.interval_us) + 1


@dataclass(frozen=True)
class Limit:
    """How often one kind of request is served: per peer, and for all peers together."""

    burst: int
    interval_us: int  # one more per this long, per peer
    total_burst: int
    total_interval_us: int  # one more per this long, all peers together


class PeerLimits:
    """Token buckets per (kind, peer) and per kind; the table of peers is bounded (the
    least recently seen is forgotten first). Refusals are counted in ``stats`` as
    ``"<kind> rate-limited"``."""

    def __init__(self, limits: dict[str, Limit], stats: Counter[str], max_peers: int = 64) -> None:
        self.limits = limits
        self.stats = stats
        self.max_peers = max_peers
        self._peers: OrderedDict[tuple[str, tuple[int, int]], TokenBucket] = OrderedDict()
        self._totals: dict[str, TokenBucket] = {}

    def allow(self, kind: str, peer: tuple[int, int], now_us: int) -> bool:
        """Whether a request of ``kind`` from ``peer`` (system, component) is served now."""
        lim = self.limits[kind]
        total = self._totals.get(kind)
        if total is None:
            total = self._totals[kind] = TokenBucket(lim.total_burst, lim.total_interval_us, now_us)
        key = (kind, peer)
        bucket = self._peers.get(key)
        if bucket is None:
            while len(self._peers) >= self.max_peers:
                self._peers.popitem(last=False)
            bucket = self._peers[key] = TokenBucket(lim.burst, lim.interval_us, now_us)
        else:
            self._peers.move_to_end(key)
        if bucket.take(now_us) and total.take(now_us):
            return True
        self.stats[f"{kind} rate-limited"] += 1
        return False


@dataclass
class _Line:
    """One sequence line: messages that continue each other's ``seq``."""

    ident: int
    last_seq: int
    first_n: int  # order of its first and last message among all observed
    last_n: int
    last_us: int
    count: int = 1
    last_frame: bytes = b""
    boot_ms: int | None = None  # its sender's boot clock, as its last timed message said
    boot_at_us: int = 0  # when that message arrived
    # The number before the last step when that step skipped numbers (lost messages, or
    # another sender that happened to fit): a message continuing *it* shows that the
    # step was another sender's. None after an exact step.
    before_skip: int | None = None

    def clock_agrees(self, boot_ms: int | None, now_us: int) -> bool:
        """Whether a message stamped ``boot_ms`` fits this line's clock: not more than
        1 s behind its last time, not more than 1 s ahead of where that clock is now."""
        if boot_ms is None or self.boot_ms is None:
            return True
        ahead_ms = self.boot_ms + (now_us - self.boot_at_us) // 1000
        return self.boot_ms - CLOCK_SLACK_MS <= boot_ms <= ahead_ms + CLOCK_SLACK_MS

    def take(
        self, seq: int, gap: int, n: int, now_us: int, boot_ms: int | None, frame: bytes
    ) -> None:
        if gap > 1:
            self.before_skip = self.last_seq
        elif gap == 1:
            self.before_skip = None
        self.last_seq, self.last_n, self.last_us, self.last_frame = seq, n, now_us, frame
        self.count += 1
        if boot_ms is not None:
            self.boot_ms, self.boot_at_us = boot_ms, now_us


@dataclass(frozen=True)
class Seen:
    """What :meth:`SenderGuard.observe` made of one message."""

    verdict: Verdict
    line: int  # the line's identity (held messages are kept by it)
    gap: int  # seq step from the line's previous message (0: it started the line)


class SenderGuard:
    """Is the followed autopilot's (system, component) id one sender? (module docstring)"""

    def __init__(
        self,
        *,
        max_gap: int = 32,
        confirm: int = 3,
        line_window_us: int = 2_000_000,
        restart_silence_us: int = 500_000,
        conflict_window_us: int = 10_000_000,
        max_lines: int = 4,
    ) -> None:
        self.max_gap = max_gap
        self.confirm = confirm
        self.line_window_us = line_window_us
        self.restart_silence_us = restart_silence_us
        self.conflict_window_us = conflict_window_us
        self.max_lines = max_lines
        self.current: _Line | None = None
        self._others: list[_Line] = []
        self._n = 0
        self._next_ident = 0
        self._other_since_current = False  # another line spoke since the current one did
        self._interleaves: deque[int] = deque(maxlen=64)  # when they happened (µs)
        self.conflict = False
        self.conflicts = 0  # conflicts begun so far
        self.switches = 0

    def reset(self) -> None:
        """Forget every line (the autopilot was lost: whatever comes next starts anew)."""
        self.current = None
        self._others.clear()
        self._other_since_current = False

    def live_lines(self) -> set[int]:
        """The identities of the lines the guard still keeps."""
        lines = {o.ident for o in self._others}
        if self.current is not None:
            lines.add(self.current.ident)
        return lines

    def interleaved_recently(self, now_us: int) -> bool:
        """Another sender spoke between the followed one's messages within
        ``conflict_window_us``: single-message evidence (a clock jump) is not trusted."""
        return bool(self._interleaves) and now_us - self._interleaves[-1] < self.conflict_window_us

    def _new_line(self, seq: int, now_us: int, boot_ms: int | None, frame: bytes) -> _Line:
        self._next_ident += 1
        return _Line(self._next_ident, seq, self._n, self._n, now_us, 1, frame, boot_ms, now_us)

    def observe(
        self,
        seq: int,
        now_us: int,
        anomalous: bool = False,
        boot_ms: int | None = None,
        frame: bytes = b"",
    ) -> Seen:
        """Take one message's ``seq`` (and its sender's boot time ``boot_ms``, if it
        carries one). ``anomalous``: its content contradicts the followed sender's clock
        (time back, a TIMESYNC jump); it then joins the followed line only if it
        continues it exactly (``gap`` 1) and no other sender spoke lately, else it joins
        another line whose clock it fits, or starts one — a stray message cannot pass for
        the autopilot's reboot, nor a sender that numbers in step with it for it.
        ``frame``: the message's bytes (a repeat of the followed line's last frame is a
        ``duplicate``)."""
        self._n += 1
        seq %= SEQ_MOD
        cur = self.current
        if cur is None:
            self.current = self._new_line(seq, now_us, boot_ms, frame)
            return Seen("current", self.current.ident, 0)
        self._expire(now_us)
        if frame and frame == cur.last_frame:
            return Seen("duplicate", cur.ident, 0)
        if cur.before_skip is not None and (seq - cur.before_skip) % SEQ_MOD == 1:
            # The followed sender continues from before its last step: that step (which
            # skipped numbers) was another sender's message. Back on its own numbers.
            cur.take(seq, 1, self._n, now_us, boot_ms, frame)
            self._interleaves.append(now_us)
            self._other_since_current = False
            self._update_conflict(now_us)
            return Seen("current", cur.ident, 1)
        best: _Line | None = None
        best_gap, best_rank = 0, SEQ_MOD
        trust = not self.interleaved_recently(now_us)
        for line in (cur, *self._others):
            gap = (seq - line.last_seq) % SEQ_MOD
            if gap > self.max_gap:
                continue
            if line is cur:
                # A clock jump only from the next number of a line whose last step was
                # exact, with no other sender about lately.
                if anomalous and not (gap == 1 and trust and cur.before_skip is None):
                    continue
            elif not line.clock_agrees(boot_ms, now_us):
                continue
            rank = gap if gap else self.max_gap + 1  # the same number: the last resort
            if rank < best_rank:
                best, best_gap, best_rank = line, gap, rank
        if best is None:
            if len(self._others) >= self.max_lines - 1:
                self._others.remove(min(self._others, key=lambda o: o.last_n))
            best, best_gap = self._new_line(seq, now_us, boot_ms, frame), 0
            self._others.append(best)
        else:
            best.take(seq, best_gap, self._n, now_us, boot_ms, frame)
        if best is cur:
            if self._other_since_current:
                self._interleaves.append(now_us)
                self._other_since_current = False
            self._update_conflict(now_us)
            return Seen("current", cur.ident, best_gap)
        self._other_since_current = True
        self._update_conflict(now_us)
        silent_us = now_us - cur.last_us
        if (
            not self.conflict
            and best.count >= self.confirm
            and silent_us >= self.restart_silence_us
            and (best.first_n > cur.last_n or silent_us > self.line_window_us)
        ):
            # The followed line fell silent while this one kept counting: a restart.
            self._others.remove(best)
            self._others.append(cur)
            self.current = best
            self._other_since_current = False
            self.switches += 1
            return Seen("switched", best.ident, best_gap)
        return Seen("other", best.ident, best_gap)

    def poll(self, now_us: int) -> None:
        """Let time pass: lines expire, a conflict ends when its window has passed
        without interleaves (read :attr:`conflict` after)."""
        self._expire(now_us)
        self._update_conflict(now_us)

    def conflict_ends_us(self) -> int | None:
        """When the conflict in force ends if no sender interleaves again (None: none)."""
        if not self.conflict or len(self._interleaves) < 2:
            return None
        return self._interleaves[-2] + self.conflict_window_us

    def _expire(self, now_us: int) -> None:
        self._others = [o for o in self._others if now_us - o.last_us <= self.line_window_us]

    def _update_conflict(self, now_us: int) -> None:
        recent = [t for t in self._interleaves if now_us - t < self.conflict_window_us]
        conflict = len(recent) >= 2
        if conflict and not self.conflict:
            self.conflicts += 1
        self.conflict = conflict
