"""STATUSTEXT to the ground station, rate-limited and bounded, sans-IO.

:class:`StatustextQueue`: texts wait in a bounded queue and go out at most one per
``min_interval_us`` (a text longer than 50 bytes as MAVLink 2 chunks: one id, increasing
``chunk_seq``). Each *condition* (a key, by default the text itself) is queued at most
once per ``repeat_us``; the table of conditions is bounded (conditions older than
``repeat_us`` are forgotten first, and at most ``max_conditions`` are kept). A full queue
drops the text. Both are counted in ``stats``.

:class:`StatustextAssembler`: the receiving side, whole texts from STATUSTEXTs that may
come in chunks.

:class:`CollisionConditions`: when a track's collision alarm is a new condition, so that
an alarm is announced once, not once per frame or per TTC value.
"""

from __future__ import annotations

from collections import Counter, OrderedDict, deque
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from ..core.pipeline import ObjectResult
from . import tcm_dialect as d

#: Bytes of text in one STATUSTEXT.
TEXT_BYTES = 50


@dataclass(frozen=True)
class _Text:
    severity: int
    text: str


def statustext_messages(severity: int, text: str, now_us: int) -> list[Any]:
    """The STATUSTEXT message(s) of one text: one, or MAVLink 2 chunks (same id,
    increasing ``chunk_seq``, the last one NUL-terminated by the encoder's padding; a text
    of a whole number of full chunks ends with an empty chunk, or no receiver could tell
    that it ended)."""
    data = text.encode("utf-8", "replace")
    if len(data) <= TEXT_BYTES:
        return [d.MAVLink_statustext_message(severity, data, 0, 0)]
    msg_id = (now_us // 1000) & 0xFFFF or 1
    chunks = [data[i : i + TEXT_BYTES] for i in range(0, len(data), TEXT_BYTES)]
    if len(chunks[-1]) == TEXT_BYTES:
        chunks.append(b"")
    return [
        d.MAVLink_statustext_message(severity, chunk, msg_id, seq)
        for seq, chunk in enumerate(chunks)
    ]


class StatustextQueue:
    """A bounded, per-condition rate-limited STATUSTEXT queue (see the module docstring)."""

    def __init__(
        self,
        min_interval_us: int,
        repeat_us: int,
        max_queued: int,
        stats: Counter[str],
        now_us: int,
        max_conditions: int = 256,
        history: int = 256,
    ) -> None:
        self.min_interval_us = min_interval_us
        self.repeat_us = repeat_us
        self.max_queued = max_queued
        self.max_conditions = max_conditions
        self.stats = stats
        self.next_us = now_us  # the earliest time the next text may go out
        self._queue: deque[_Text] = deque()
        # condition -> when it was last queued, oldest first (re-queued ones move to the end)
        self._conditions: dict[str, int] = {}
        self._history: deque[str] = deque(maxlen=history)

    @property
    def pending(self) -> bool:
        """Texts are waiting to go out."""
        return bool(self._queue)

    @property
    def recent(self) -> list[str]:
        """The distinct texts queued lately (the last ``history``; most recent last)."""
        return list(dict.fromkeys(self._history))

    @property
    def conditions(self) -> int:
        """How many conditions the table holds (at most ``max_conditions``)."""
        return len(self._conditions)

    def queue(self, severity: int, text: str, now_us: int, key: str | None = None) -> bool:
        """Queue ``text``; False (counted) when its condition went out within ``repeat_us``
        or the queue is full."""
        cond = text if key is None else key
        last = self._conditions.get(cond)
        if last is not None and now_us - last < self.repeat_us:
            self.stats["statustext suppressed"] += 1
            return False
        if len(self._queue) >= self.max_queued:
            self.stats["statustext dropped"] += 1
            return False
        self._remember(cond, now_us)
        self._history.append(text)
        self._queue.append(_Text(severity, text))
        return True

    def _remember(self, cond: str, now_us: int) -> None:
        conds = self._conditions
        conds.pop(cond, None)
        # Forget conditions past their repeat time (they suppress nothing any more) ...
        horizon = now_us - self.repeat_us
        while conds and next(iter(conds.values())) < horizon:
            del conds[next(iter(conds))]
        # ... and, should a flood of new ones fill the table, the oldest.
        while len(conds) >= self.max_conditions:
            del conds[next(iter(conds))]
        conds[cond] = now_us

    def poll(self, now_us: int) -> list[Any]:
        """The STATUSTEXT message(s) to send now: the next text once ``min_interval_us``
        has passed since the last one went out."""
        if not self._queue or now_us < self.next_us:
            return []
        item = self._queue.popleft()
        self.next_us = now_us + self.min_interval_us
        return statustext_messages(item.severity, item.text, now_us)


class StatustextAssembler:
    """Whole texts from received STATUSTEXT messages, sans-IO.

    A text of at most :data:`TEXT_BYTES` bytes comes in one message with ``id`` 0. A
    longer one comes in chunks sharing one ``id`` (per sender), ``chunk_seq`` 0, 1, ...;
    every chunk but the last is full (:data:`TEXT_BYTES` bytes), so the first shorter one
    ends the text. At most ``max_pending`` texts are held incomplete (the oldest is
    forgotten first, counted in :attr:`dropped`).
    """

    def __init__(self, max_pending: int = 64) -> None:
        self.max_pending = max_pending
        self.dropped = 0  # incomplete texts forgotten to stay within max_pending
        # (sysid, compid, id) -> (the first chunk's time, the chunks so far), oldest first
        self._pending: OrderedDict[tuple[int, int, int], tuple[float, list[str]]] = OrderedDict()

    def add(self, msg: Any, t: float) -> tuple[float, str] | None:
        """Take one STATUSTEXT received at ``t`` (any clock, any unit); return ``(t of its
        first chunk, the whole text)`` when it completes a text, else None."""
        text = str(msg.text)
        chunk_id = int(getattr(msg, "id", 0))
        if chunk_id == 0:
            return t, text
        key = (int(msg.get_srcSystem()), int(msg.get_srcComponent()), chunk_id)
        first_t, parts = self._pending.pop(key, (t, []))
        parts.append(text)
        if len(text.encode("utf-8", "replace")) < TEXT_BYTES:
            return first_t, "".join(parts)
        self._pending[key] = (first_t, parts)
        while len(self._pending) > self.max_pending:
            self._pending.popitem(last=False)
            self.dropped += 1
        return None


class CollisionConditions:
    """Collision alarms as conditions: a track's condition starts with its first alarming
    frame (collision course, ``ttc`` below the alarm time) and lasts until it has not
    alarmed for ``clear_us``."""

    def __init__(self, clear_us: int) -> None:
        self.clear_us = clear_us
        self._last_alarm_us: dict[int, int] = {}  # track id -> its last alarming frame

    def update(
        self, objects: Iterable[ObjectResult], alarm_ttc_s: float, now_us: int
    ) -> list[ObjectResult]:
        """The objects of this frame whose condition starts now (``alarm_ttc_s`` <= 0:
        alarms off, none)."""
        last = self._last_alarm_us
        for tid in [t for t, at in last.items() if now_us - at > self.clear_us]:
            del last[tid]
        if alarm_ttc_s <= 0:
            return []
        new = []
        for obj in objects:
            if not (obj.collision_course and obj.ttc_s < alarm_ttc_s):
                continue
            if obj.track_id not in last:
                new.append(obj)
            last[obj.track_id] = now_us
        return new
