"""Telemetry stream requests (MAV_CMD_SET_MESSAGE_INTERVAL to the autopilot), sans-IO.

The companion asks for each stream it needs with one COMMAND_LONG at a time (a
COMMAND_ACK does not say which message it is for):

- no ACK within ``retry_us``: the same request again (counted, ``request retries``);
  MAV_RESULT_IN_PROGRESS: the same request again at the retry time, uncounted;
- refused: ATTITUDE_QUATERNION falls back to ATTITUDE (the same attitude as Euler
  angles); any other refusal is counted (``requests refused``) and the request stays
  open, so it is asked again at once;
- all acknowledged: every ``retry_us`` each stream's measured rate is checked, and one
  that stopped or ran below half its requested rate for ``rate_check_us`` is asked for
  again (``streams re-requested``; an autopilot that rebooted has forgotten).

:meth:`StreamRequests.restart` starts over (an autopilot found, found again, rebooted).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from . import tcm_dialect as d

#: A refused stream -> the stream that carries the same data.
FALLBACK: dict[int, int] = {d.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: d.MAVLINK_MSG_ID_ATTITUDE}


@dataclass
class StreamRequest:
    """One SET_MESSAGE_INTERVAL we want honoured."""

    msg_id: int
    rate_hz: float
    acked_at_us: int | None = None  # None: still to be asked for


class StreamRequests:
    """The SET_MESSAGE_INTERVAL requests of one link; counts land in ``stats``."""

    def __init__(
        self,
        wanted: Sequence[tuple[int, float]],
        retry_us: int,
        rate_check_us: int,
        stats: Counter[str],
        now_us: int,
    ) -> None:
        self.requests = [StreamRequest(msg_id, rate_hz) for msg_id, rate_hz in wanted]
        self.retry_us = retry_us
        self.rate_check_us = rate_check_us
        self.stats = stats
        self.next_us = now_us  # when :meth:`poll` next has something to do
        self._pending: StreamRequest | None = None
        self._rx_count: Counter[int] = Counter()
        self._rx_since_us: dict[int, int] = {}

    def restart(self, now_us: int) -> None:
        """Every request open again, from now; the rate measurements forgotten."""
        for r in self.requests:
            r.acked_at_us = None
        self._pending = None
        self.next_us = now_us
        self._rx_count.clear()
        self._rx_since_us.clear()

    def received(self, msg_id: int) -> None:
        """A message of a stream arrived (for the rate check)."""
        self._rx_count[msg_id] += 1

    def poll(self, now_us: int, target: tuple[int, int]) -> Any | None:
        """The COMMAND_LONG to send to ``target`` (system, component) now, if any. Call it
        only while the autopilot is connected."""
        if now_us < self.next_us:
            return None
        if self._pending is not None and self._pending.acked_at_us is None:
            self.stats["request retries"] += 1  # no ACK in time: send it again
        self.next_us = now_us + self.retry_us
        todo = next((r for r in self.requests if r.acked_at_us is None), None)
        if todo is None:
            self._check_rates(now_us)
            return None
        self._pending = todo
        return d.MAVLink_command_long_message(
            target[0],
            target[1],
            d.MAV_CMD_SET_MESSAGE_INTERVAL,
            0,
            float(todo.msg_id),
            1e6 / todo.rate_hz,
            0,
            0,
            0,
            0,
            0,
        )

    def on_ack(self, result: int, now_us: int) -> None:
        """The autopilot's COMMAND_ACK of SET_MESSAGE_INTERVAL (for the pending request)."""
        if self._pending is None:
            return
        req, self._pending = self._pending, None
        if result == d.MAV_RESULT_ACCEPTED:
            req.acked_at_us = now_us
            self._rx_count[req.msg_id] = 0
            self._rx_since_us[req.msg_id] = now_us
        elif result == d.MAV_RESULT_IN_PROGRESS:
            return  # the final answer follows; asked again at the retry time if not
        elif req.msg_id in FALLBACK:
            req.msg_id = FALLBACK[req.msg_id]
        else:
            self.stats["requests refused"] += 1
        self.next_us = now_us  # on to the next request at once

    def _check_rates(self, now_us: int) -> None:
        """Re-request a stream that stopped or runs well below the rate we asked for."""
        for r in self.requests:
            since = self._rx_since_us.get(r.msg_id)
            if r.acked_at_us is None or since is None:
                continue
            elapsed = now_us - since
            if elapsed < self.rate_check_us:
                continue
            rate = self._rx_count[r.msg_id] * 1e6 / elapsed
            if rate < 0.5 * r.rate_hz:
                self.stats["streams re-requested"] += 1
                r.acked_at_us = None
            self._rx_count[r.msg_id] = 0
            self._rx_since_us[r.msg_id] = now_us
