"""The flight daemon: camera threads and the MAVLink link around one :class:`Companion`.

Everything here is plumbing; the decisions are in :mod:`.companion` (the frame slots,
the attitude wait, input health, rebuilds, the order outputs go out in) and what is done
with its outputs in :mod:`.host` (shared with the virtual-time SITL).

- One reader thread per camera (:class:`~tcm_companion.io.cameras.reader.CameraReader`)
  blocks in the camera's ``read()``, stamps the capture time on the companion monotonic
  clock and hands the frame to the event loop with ``call_soon_threadsafe``; there it
  takes its camera's slot in the Companion (a frame still waiting is dropped, counted).
- A link task reads the transport and feeds the bytes to the Companion.
- With ``[daemon] box_feed``, a UDP socket takes the live box feed's datagrams
  (:mod:`.box_feed`, docs/box-feed.md) to the Companion as they arrive.
- The main task runs :meth:`Companion.process_due` whenever
  :meth:`Companion.next_deadline_us` has come or an input arrived, writes what the
  Companion has to send at once (a frame's outputs go out the same turn), and waits —
  on the clock it stamps with (:class:`~tcm_companion.io.aio.MonotonicClock`) — for the
  next deadline or input. The once-a-second health check is one of those deadlines; the
  systemd watchdog is pinged from it only while every task and camera thread is alive,
  so a stuck loop sends no ping.
- Shutdown (SIGTERM/SIGINT, or ``stop``): the tasks of a ``TaskGroup`` end, then an
  ``AsyncExitStack`` undoes the start-up in reverse — notify STOPPING, stop the camera
  threads, close the box feed. What was there before the daemon (the endpoint, the link,
  the flight log) is :mod:`.runner`'s, which persists the parameters and the signing
  timestamp, closes the link and stops the log after the daemon's run.

Frame accounting always closes: ``captured = processed + failed + dropped + rejected``
(rejected: empty or wrong-sized frames refused by the reader; dropped: superseded, or
still waiting at shutdown).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import cv2

from ..core.pipeline import FrameResult, PipelineConfig
from ..io.aio import MONOTONIC, LoopClock
from ..io.cameras.base import Frame
from ..io.detector_model import read_detector_model
from ..io.transports import Transport, TransportError
from ..mavlink.endpoint import CompanionEndpoint
from .box_feed import open_box_feed
from .companion import Companion
from .daemon_config import DaemonConfig
from .endpoint_setup import MavlinkConfig
from .host import CameraInput, CompanionHost, DaemonSummary, NotifierLike

if TYPE_CHECKING:
    from ..flightlog.handle import FlightLog

__all__ = ["CameraInput", "Daemon", "DaemonSummary", "NotifierLike", "ServiceConfig"]

log = logging.getLogger(__name__)

_LINK_RETRY_US = 100_000  # a closed or failing transport is read again after this


class ServiceConfig(Protocol):
    """The tables of the configuration the daemon reads (``tcm_companion.config.AppConfig``
    is one; the daemon does not import the application's configuration)."""

    @property
    def daemon(self) -> DaemonConfig: ...

    @property
    def pipeline(self) -> PipelineConfig: ...

    @property
    def mavlink(self) -> MavlinkConfig: ...


def name_os_threads() -> None:
    """Give every Python thread but the main one its ``threading`` name as its OS name
    (``/proc/self/task/<tid>/comm``, at most 15 bytes), so ``top -H``, ``ps -L`` and
    ``bench --daemon`` can tell the camera threads and the flight-log writer apart
    (Python 3.11 leaves them all named after the process). Silent where there is no
    such file (not Linux)."""
    for thread in threading.enumerate():
        tid = thread.native_id
        if tid is None or thread is threading.main_thread():
            continue
        name = thread.name.encode("utf-8")[:15].decode("utf-8", errors="ignore")
        with contextlib.suppress(OSError):
            Path(f"/proc/self/task/{tid}/comm").write_text(name)


class Daemon:
    """``tcm-companion run``: cameras + pipeline + MAVLink until stopped.

    Put together by :func:`~.runner.open_service`, which makes the ``endpoint`` from the
    configuration and its state files and opens the ``transport`` (or takes the caller's).
    ``on_result`` sees every processed frame (SITL scores them), ``on_status`` the status
    line once a second. ``clock`` is what the daemon stamps every time with and waits on
    (the companion monotonic clock). ``persist``: write the parameters and the signing
    timestamp back, called when parameters change (None: not written as they change).
    """

    def __init__(
        self,
        config: ServiceConfig,
        cameras: Sequence[CameraInput],
        *,
        transport: Transport,
        endpoint: CompanionEndpoint,
        notifier: NotifierLike | None = None,
        watchdog_interval_us: int | None = None,
        clock: LoopClock = MONOTONIC,
        on_result: Callable[[int, FrameResult], None] | None = None,
        on_status: Callable[[str], None] | None = None,
        flight_log: FlightLog | None = None,
        persist: Callable[[], None] | None = None,
    ) -> None:
        if not cameras:
            raise ValueError("the daemon needs at least one camera")
        self.config = config
        self.camera_inputs = list(cameras)
        self._transport = transport
        self._endpoint = endpoint
        self.notifier = notifier
        self.clock = clock
        self.on_result = on_result
        self.on_status = on_status
        self.flight_log = flight_log
        self._persist = persist
        interval = config.daemon.health_interval_us
        if watchdog_interval_us is not None:
            interval = min(interval, watchdog_interval_us)
        self.health_interval_us = interval
        self.companion: Companion | None = None
        self.host: CompanionHost | None = None
        self.readers: list[Any] = []
        self.send_errors = 0
        self._wake = asyncio.Event()
        self._handoff_failures = 0
        self._box_error_logged_us: int | None = None
        self._tasks: list[asyncio.Task[Any]] = []

    # -- frames from the camera threads -------------------------------------------------
    def _make_on_frame(self, loop: asyncio.AbstractEventLoop) -> Callable[[Frame], None]:
        def on_frame(frame: Frame) -> None:  # runs on a camera thread
            try:
                loop.call_soon_threadsafe(self._on_frame, frame)
            except RuntimeError:  # the loop is closing: the frame is lost, but counted
                self._handoff_failures += 1

        return on_frame

    def _on_frame(self, frame: Frame) -> None:
        assert self.host is not None
        self.host.frame_arrived(frame, self.clock.now_us())
        self._wake.set()

    def _on_box_datagram(self, data: bytes) -> None:  # on the loop's thread
        assert self.host is not None
        now = self.clock.now_us()
        try:
            self.host.box_datagram(data, now)
        except Exception:  # a bug must not close the socket (uvloop would) or stop the loop
            counts = self.host.companion.stats.box_feed
            counts["handler error"] += 1
            # A bug's traceback once per 10 s, not once per (hostile) datagram.
            last = self._box_error_logged_us
            if last is None or now - last >= 10_000_000:
                self._box_error_logged_us = now
                log.exception("box feed: a datagram raised (%d so far)", counts["handler error"])
        self._wake.set()  # a frame waiting for these boxes may go now

    # -- tasks -------------------------------------------------------------------------------
    async def _link_reader(self, transport: Transport) -> None:
        host = self.host
        assert host is not None
        while True:
            try:
                data = await transport.recv()
            except TransportError:  # closed (a reconnecting transport comes back) or failing
                await self.clock.wait_until(None, self.clock.now_us() + _LINK_RETRY_US)
                continue
            host.bytes_received(data, self.clock.now_us())
            self._wake.set()

    async def _write(self, transport: Transport, data: bytes) -> None:
        if not data:
            return
        try:
            await transport.send(data)
        except TransportError:
            # The link is down or the peer stopped reading: drop rather than block the
            # pipeline; the endpoint's timers resend what matters (heartbeats, requests).
            self.send_errors += 1

    async def _turn(self, transport: Transport) -> None:
        """One turn: whatever is due, its outputs handled, its bytes written."""
        host, clock = self.host, self.clock
        assert host is not None
        now = clock.now_us()
        outputs = host.process_due(now)
        done = clock.now_us()
        data = host.take_bytes()
        await self._write(transport, data)
        host.written(outputs, data, done, clock.now_us())

    async def _main(self, transport: Transport) -> None:
        comp = self.companion
        assert comp is not None
        while True:
            self._wake.clear()
            await self._turn(transport)
            deadline = comp.next_deadline_us()
            if deadline <= self.clock.now_us():
                await asyncio.sleep(0)  # let the camera threads' frames and the link in
                continue
            await self.clock.wait_until(self._wake, deadline)

    def _loop_healthy(self) -> tuple[bool, str]:
        for task in self._tasks:
            if task.done():
                return False, f"task {task.get_name()} ended"
        for reader in self.readers:
            if not reader.alive and not reader.stats.ended:
                return False, f"camera thread {reader.source.name} died"
        return True, ""

    # -- the whole run -------------------------------------------------------------------------
    async def run(self, stop: asyncio.Event | None = None) -> DaemonSummary:
        """Run until ``stop`` is set (or a fatal error); returns the run's summary."""
        from ..io.cameras.reader import CameraReader

        stop = stop if stop is not None else asyncio.Event()
        loop = asyncio.get_running_loop()
        clock = self.clock
        t0 = clock.now_us()
        if self.config.daemon.opencv_threads:
            cv2.setNumThreads(self.config.daemon.opencv_threads)
        # A camera thread that wakes with a frame needs the GIL; by default it may wait
        # 5 ms for the loop thread to let go. A shorter switch interval bounds that wait
        # (handoff p50 2.3 ms -> see docs/daemon.md for the measurement).
        sys.setswitchinterval(self.config.daemon.gil_switch_interval_us / 1e6)
        async with contextlib.AsyncExitStack() as stack:
            endpoint, transport = self._endpoint, self._transport
            daemon_cfg = dataclasses.replace(
                self.config.daemon, health_interval_us=self.health_interval_us
            )
            self.companion = Companion(
                [c.model for c in self.camera_inputs],
                self.config.pipeline,
                endpoint,
                t0,
                daemon_cfg,
                [c.name for c in self.camera_inputs],
                camera_rates_hz=[c.fps for c in self.camera_inputs],
                detector_model=read_detector_model(self.config.pipeline.detection),
            )
            self.host = CompanionHost(
                self.companion,
                self.camera_inputs,
                flight_log=self.flight_log,
                notifier=self.notifier,
                on_result=self.on_result,
                on_status=self.on_status,
                persist=self._persist,
                loop_healthy=self._loop_healthy,
            )
            notifier = self.host.notifier

            # The live box feed: a UDP socket on the loop, closed on the way out.
            feed_url = self.config.daemon.box_feed
            if feed_url:
                feed, _ = await open_box_feed(feed_url, self._on_box_datagram)
                stack.callback(feed.close)
                log.info("box feed: listening on %s", feed_url)
            elif (
                self.config.pipeline.detection.backend == "boxes"
                and not self.config.daemon.box_tracking
            ):
                log.warning(
                    'detection backend "boxes" without [daemon] box_feed or box_tracking: no'
                    " boxes will arrive, nothing will be detected"
                )

            # Cameras: one reader thread each; stopped (joined) on the way out.
            on_frame = self._make_on_frame(loop)
            for cid, cam in enumerate(self.camera_inputs):
                # no_future: capture times on this clock, never after the read (a file
                # read with realtime = false runs its own series ahead of the clock, and
                # the latency came out negative).
                reader = CameraReader(
                    cam.source, cid, on_frame, clock_us=clock.now_us, no_future=True
                )
                self.readers.append(reader)
                reader.start()
                stack.callback(reader.stop)
            name_os_threads()
            stack.callback(notifier.stopping)
            notifier.ready(f"running: {len(self.camera_inputs)} camera(s), link {transport.url}")
            log.info("running: %d camera(s), link %s", len(self.camera_inputs), transport.url)

            try:
                async with asyncio.TaskGroup() as tg:
                    self._tasks = [
                        tg.create_task(self._link_reader(transport), name="link"),
                        tg.create_task(self._main(transport), name="process"),
                    ]
                    await stop.wait()
                    for task in self._tasks:
                        task.cancel()
            finally:
                # Stop the cameras first, then let the frames they handed over in the
                # meantime land in their slots, so every delivered frame is accounted for;
                # what still waits is dropped, and what the Companion queued goes out.
                for reader in self.readers:
                    reader.stop()
                for _ in range(3):
                    await asyncio.sleep(0)
                now = clock.now_us()
                self.companion.discard_pending(now)
                await self._write(transport, self.host.bytes_to_send(now))
        # One camera's stats under its source's name ("/dev/video0"); a rig's under each
        # camera's name (unique; two sources may share a name, "frames").
        rig = len(self.readers) > 1
        return self.host.summary(
            (clock.now_us() - t0) / 1e6,
            {
                self.camera_inputs[r.camera_id].name if rig else r.source.name: r.stats
                for r in self.readers
            },
            self._handoff_failures,
        )
