"""SITL in virtual time: the mock autopilot, the simulated camera and the companion on ONE
simulated clock, as fast as the CPU allows, with the same results every run.

A discrete-event simulation over the sans-IO pieces — no threads (but the flight log's
writer, made deterministic by :mod:`tcm_companion.flight_log_setup`), no sockets, no asyncio:

- the :class:`~tcm_companion.sim.vehicle.mock_autopilot.MockAutopilot` (``receive_data``,
  ``poll``, ``data_to_send``, ``next_deadline_us``) is polled at its deadlines and takes
  bytes as they arrive;
- each camera's :class:`~tcm_companion.io.cameras.reader.ReaderCore` — the reader
  thread's own state machine: open, read, reject, reconnect with backoff — steps its
  source on the simulated clock. The simulated camera (its ``clock_us`` this clock, its
  sleeps none) renders each frame when the previous one is handed over, from the mock's
  true pose at the new frame's instant, and the frame is handed over at that instant;
- the links are in memory, each way a constant latency (``link_latency_us``), in order,
  and can be cut (``link_up``);
- the :class:`~tcm_companion.service.companion.Companion`, through the same
  :class:`~tcm_companion.service.host.CompanionHost` as the asyncio daemon, is one
  single-threaded "loop": a frame's pipeline takes ``process_us`` of simulated time
  (not the machine's), during which frames and bytes queue up as they would behind a
  busy event loop, and the frame's bytes go out when it is done.

Events at the same instant run in the order they were scheduled, so a run is a function
of the configuration, the seed and this model alone: on a loaded or an idle machine, the
same frames, results, MAVLink bytes and flight-log bytes. The clocks are named: the
companion monotonic clock (``_mono_us``) starts at ``start_mono_us``, the autopilot's boot
clock (``_boot_us``) is the mock's, and Unix time (``_unix_us``, SYSTEM_TIME and the
flight log's wall time) is ``unix_us_at_start`` at the start.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from ..core.pipeline import FrameResult
from ..io.cameras.reader import ReaderCore
from ..service.companion import Companion
from ..service.host import CameraInput, CompanionHost, DaemonSummary
from ..service.outputs import FrameProcessed

log = logging.getLogger(__name__)

#: The simulated companion monotonic clock at the start of a virtual run (µs): as if the
#: companion had been up 1000 s. Any fixed value gives reproducible runs; this one keeps
#: time stamps well clear of 0.
VIRTUAL_START_MONO_US = 1_000_000_000
#: Unix time at the start of a virtual run (µs): 2024-06-10T06:13:20Z, the mock's default.
VIRTUAL_UNIX_US_AT_START = 1_718_000_000_000_000


@dataclass(frozen=True)
class VirtualTimeModel:
    """What virtual time assumes about the things that take real time."""

    start_mono_us: int = VIRTUAL_START_MONO_US
    unix_us_at_start: int = VIRTUAL_UNIX_US_AT_START
    # One way, each direction (loopback UDP is ~0.05 ms; a 921600-baud UART ~1 ms).
    link_latency_us: int = 1_000
    # A frame's pipeline (the daemon's own p50 is 5.5-7 ms at 25 Hz, docs/daemon.md).
    process_us: int = 5_000
    # The companion (its endpoint, cameras and loop) starts this long after the autopilot
    # boots, as the daemon starts after the mock in real-time SITL and after the flight
    # controller on a drone.
    companion_start_us: int = 20_000

    def __post_init__(self) -> None:
        if min(self.link_latency_us, self.process_us, self.companion_start_us) < 0:
            raise ValueError("link_latency_us, process_us and companion_start_us must be >= 0")


class AutopilotLike(Protocol):
    """The sans-IO autopilot: :class:`MockAutopilot` or a wrapper such as the Lua applet."""

    def receive_data(self, data: bytes, now_us: int) -> Any: ...
    def poll(self, now_us: int) -> Any: ...
    def data_to_send(self) -> bytes: ...
    def next_deadline_us(self) -> int: ...


# Event kinds, in the order they run when simultaneous and scheduled together.
_MOCK_WAKE, _TO_MOCK, _TO_COMPANION, _CAMERA, _FRAME, _COMPANION, _CALL = range(7)


class VirtualSitl:
    """One virtual-time run; see the module docstring. ``run`` returns the summary."""

    def __init__(
        self,
        autopilot: AutopilotLike,
        companion: Companion,
        host: CompanionHost,
        cameras: Sequence[CameraInput],
        model: VirtualTimeModel,
        *,
        start_mono_us: int,
        schedule: Sequence[tuple[float, Callable[[int], None]]] = (),
        link_up: Callable[[float], bool] | None = None,
    ) -> None:
        """``schedule``: ``(run time s, fn(now_mono_us))`` calls (tests: reboot the mock);
        ``link_up(run time s)``: False while the radio is out (bytes vanish)."""
        self.autopilot = autopilot
        self.companion = companion
        self.host = host
        self.cameras = list(cameras)
        self.model = model
        self.start_mono_us = int(start_mono_us)
        self.now_mono_us = self.start_mono_us
        self.link_up = link_up
        self.readers = [
            ReaderCore(c.source, cid, on_state=_log_camera_state) for cid, c in enumerate(cameras)
        ]
        self._heap: list[tuple[int, int, int, Any]] = []
        self._seq = itertools.count()
        self._busy_until_mono_us = self.start_mono_us  # the companion's loop is working
        self._companion_wake_mono_us: int | None = None
        self._mock_wake_mono_us: int | None = None
        self.bytes_lost = 0  # while the link was down
        self.stopped_early = False  # should_stop() ended the run before its duration
        self.stalled_turns = 0  # companion turns due again at once with nothing done
        for at_s, fn in schedule:
            self._push(self.start_mono_us + round(at_s * 1e6), _CALL, fn)

    # -- the clock the simulated camera and the readers read --------------------------------
    def now_us(self) -> int:
        return self.now_mono_us

    # -- scheduling -----------------------------------------------------------------------
    def _push(self, t_mono_us: int, kind: int, payload: Any = None) -> None:
        heapq.heappush(self._heap, (int(t_mono_us), next(self._seq), kind, payload))

    def _wake_companion(self, t_mono_us: int) -> None:
        t = max(int(t_mono_us), self._busy_until_mono_us)
        if self._companion_wake_mono_us is None or t < self._companion_wake_mono_us:
            self._companion_wake_mono_us = t
            self._push(t, _COMPANION, t)

    def _wake_mock(self) -> None:
        t = max(int(self.autopilot.next_deadline_us()), self.now_mono_us)
        if self._mock_wake_mono_us is None or t < self._mock_wake_mono_us:
            self._mock_wake_mono_us = t
            self._push(t, _MOCK_WAKE, t)

    def _carry(self, data: bytes, sent_mono_us: int, kind: int) -> None:
        """Bytes onto the link at ``sent_mono_us``; they arrive one latency later."""
        if not data:
            return
        if self.link_up is not None and not self.link_up((sent_mono_us - self.start_mono_us) / 1e6):
            self.bytes_lost += len(data)
            return
        self._push(sent_mono_us + self.model.link_latency_us, kind, data)

    # -- the actors -----------------------------------------------------------------------------
    def _mock_flush(self, now: int) -> None:
        self._carry(self.autopilot.data_to_send(), now, _TO_COMPANION)
        self._wake_mock()

    def _camera_step(self, cid: int, now: int) -> None:
        step = self.readers[cid].step(self.now_us, lambda: False)
        if step.finished:
            return
        if step.wait_s > 0:
            self._push(now + round(step.wait_s * 1e6), _CAMERA, cid)
            return
        at = now
        if step.frame is not None:
            # Handed over at its instant (rendered before it: the truth is known ahead).
            at = max(now, step.frame.t_capture_us)
            self._push(at, _FRAME, step.frame)
        elif step.t_image_us is not None:
            at = max(now, step.t_image_us)  # a rejected image: the next read starts then
        self._push(at, _CAMERA, cid)

    def _companion_turn(self, now: int) -> None:
        host = self.host
        outputs = host.process_due(now)
        worked = any(isinstance(o, FrameProcessed) for o in outputs)
        done = now + (self.model.process_us if worked else 0)
        data = host.take_bytes()  # written, then logged and handled, as in the daemon
        self._carry(data, done, _TO_MOCK)
        host.written(outputs, data, done, done)
        self._busy_until_mono_us = done
        nxt = self.companion.next_deadline_us()
        if nxt <= now and not worked:
            # Due again at once without having done anything: a timer that does not
            # advance. The asyncio daemon would spin; here, move on a microsecond.
            self.stalled_turns += 1
            nxt = now + 1
        self._wake_companion(nxt)

    # -- the run --------------------------------------------------------------------------------
    def run(
        self, duration_s: float | None, should_stop: Callable[[], bool] = lambda: False
    ) -> DaemonSummary:
        """Simulate until ``duration_s`` of simulated time (None: until ``should_stop()``,
        which is also looked at between events); the summary of the run."""
        end = None if duration_s is None else self.start_mono_us + round(duration_s * 1e6)
        start = self.start_mono_us
        self.autopilot.poll(start)
        self._mock_flush(start)
        up = start + self.model.companion_start_us
        self._busy_until_mono_us = up
        for cid in range(len(self.readers)):
            self._push(up, _CAMERA, cid)
        self._wake_companion(up)
        self.host.notifier.ready(f"running: {len(self.cameras)} camera(s), virtual time")
        ran_out = True  # of simulated time (not stopped)
        while self._heap:
            if should_stop():
                ran_out = False
                break
            t, _, kind, payload = self._heap[0]
            if end is not None and t >= end:
                break
            heapq.heappop(self._heap)
            self.now_mono_us = t
            if kind == _MOCK_WAKE:
                if payload != self._mock_wake_mono_us:
                    continue  # superseded by an earlier wake
                self._mock_wake_mono_us = None
                self.autopilot.poll(t)
                self._mock_flush(t)
            elif kind == _TO_MOCK:
                self.autopilot.receive_data(payload, t)
                self._mock_flush(t)  # answers (ACKs, TIMESYNC) go out at once
            elif kind == _CAMERA:
                self._camera_step(payload, t)
            elif kind in (_TO_COMPANION, _FRAME):
                if t < self._busy_until_mono_us:  # behind the busy loop, in order
                    self._push(self._busy_until_mono_us, kind, payload)
                    continue
                if kind == _FRAME:
                    self.host.frame_arrived(payload, t)
                else:
                    self.host.bytes_received(payload, t)
                self._wake_companion(t)
            elif kind == _COMPANION:
                if payload != self._companion_wake_mono_us:
                    continue
                self._companion_wake_mono_us = None
                self._companion_turn(t)
            elif kind == _CALL:
                payload(t)
                self._wake_mock()
        self.stopped_early = not ran_out
        return self._stop(end if ran_out else None)

    def _stop(self, end: int | None) -> DaemonSummary:
        now = max(self.now_mono_us, self._busy_until_mono_us)
        if end is not None:
            now = max(now, end)
        self.now_mono_us = now
        # The cameras stop; frames they handed over land in their slots, and what still
        # waits there is dropped (counted), as in the daemon. What the Companion queued
        # goes out, and the autopilot takes in everything still on the link.
        pending = sorted(self._heap)
        for _, _, kind, payload in pending:
            if kind == _FRAME:
                self.host.frame_arrived(payload, now)
        self.companion.discard_pending(now)
        self._heap = [e for e in pending if e[2] == _TO_MOCK]
        self._carry(self.host.bytes_to_send(now), now, _TO_MOCK)
        for t, _, _, payload in sorted(self._heap):
            self.now_mono_us = max(self.now_mono_us, t)
            self.autopilot.receive_data(payload, t)
        self._heap.clear()
        self.host.notifier.stopping()
        for reader in self.readers:
            reader.close()
        return self.host.summary(
            (now - self.start_mono_us - self.model.companion_start_us) / 1e6,
            {r.source.name: r.stats for r in self.readers},
        )


def _log_camera_state(name: str, state: str) -> None:
    log.debug("camera %s: %s", name, state)


class RunTimer:
    """Wall and CPU time of a run (for the speed-up a virtual run reports)."""

    def __init__(self) -> None:
        self.wall0 = time.perf_counter()
        self.cpu0 = time.process_time()

    def elapsed(self) -> tuple[float, float]:
        return time.perf_counter() - self.wall0, time.process_time() - self.cpu0


def frame_result_key(camera_id: int, result: FrameResult) -> bytes:
    """A frame's result as bytes, every float exact: what the results digest hashes."""
    parts = [f"{camera_id} {result.frame_index} {result.t_us} {int(result.attitude_ok)}"]
    for o in result.objects:
        parts.append(
            " ".join(
                [
                    str(o.track_id),
                    o.state,
                    o.reason,
                    float(o.classification.disparity).hex(),
                    float(o.ttc_s).hex(),
                    str(int(o.collision_course)),
                    *(float(x).hex() for x in o.bearing_ned),
                ]
            )
        )
    return ("\n".join(parts) + "\n").encode()


__all__ = [
    "VIRTUAL_START_MONO_US",
    "VIRTUAL_UNIX_US_AT_START",
    "AutopilotLike",
    "RunTimer",
    "VirtualSitl",
    "VirtualTimeModel",
    "frame_result_key",
]
