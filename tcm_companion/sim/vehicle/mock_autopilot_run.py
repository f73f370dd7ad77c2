"""Run the mock autopilot on a real link: the thin asyncio adapter around :class:`MockAutopilot`.

Like aioquic's asyncio protocol, this only moves bytes and time: received bytes go to
:meth:`MockAutopilot.receive_data`, the timer sleeps until
:meth:`MockAutopilot.next_deadline_us`, and :meth:`MockAutopilot.data_to_send` goes to
``transport.send``. All behaviour lives in the sans-IO core (:mod:`.mock_autopilot`).

The transport is anything with ``async recv() -> bytes`` and ``async send(bytes)``
(:mod:`tcm_companion.io.transports`); :func:`run_mock_autopilot` does not open or close
it. :func:`serve_mock_autopilot` opens a transport URL (``udpout:127.0.0.1:14550``,
``serial:/dev/pts/3:921600``, ...) and runs until stopped; :func:`run_from_args` is what
``tcm-companion mock-autopilot`` calls (its options are defined in
:func:`tcm_companion.cli.sim.add_mock_autopilot_arguments`, which does not import this
module, so that ``tcm-companion --help`` stays light).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any, Protocol

from ...io.transports import (
    LinkDown,
    TransportClosed,
    TransportError,
    TransportTimeout,
    open_transport,
)
from .mock_autopilot import (
    BrakeStarted,
    CommandReceived,
    MockAutopilot,
    MockAutopilotConfig,
    MockEvent,
    ParamChanged,
    PeerSeen,
)

__all__ = [
    "LinkDown",
    "Transport",
    "TransportClosed",
    "TransportError",
    "TransportTimeout",
    "config_from_args",
    "run_from_args",
    "run_mock_autopilot",
    "serve_mock_autopilot",
]

log = logging.getLogger(__name__)


class Transport(Protocol):
    """What the runner needs of a transport (see tcm_companion.io.transports)."""

    async def recv(self) -> bytes: ...

    async def send(self, data: bytes) -> None: ...


def _log_event(ev: MockEvent) -> None:
    if isinstance(ev, BrakeStarted):
        log.warning(
            "brake: collision course track %d (ttc %.2f s) at %.2f m/s; hover at %s",
            ev.track_id,
            ev.ttc_s,
            ev.speed_mps,
            tuple(round(x, 2) for x in ev.hover_ned_m),
        )
    elif isinstance(ev, PeerSeen):
        log.info("peer %d/%d (MAV_TYPE %d) on the link", ev.system, ev.component, ev.mav_type)
    elif isinstance(ev, ParamChanged):
        log.info("param %s = %g", ev.name, ev.value)
    elif isinstance(ev, CommandReceived):
        log.debug(
            "command %d from %d/%d: result %d",
            ev.command,
            ev.src_system,
            ev.src_component,
            ev.result,
        )


async def _flush(transport: Transport, ap: MockAutopilot) -> bool:
    """Send what the mock has queued; False when the link is gone."""
    data = ap.data_to_send()
    if not data:
        return True
    try:
        await transport.send(data)
    except TransportTimeout:
        # The peer stopped reading (a pty nobody drains): drop, as a UART would.
        ap.stats["tx timeout"] += 1
    except TransportClosed:
        return False
    return True


async def run_mock_autopilot(
    transport: Transport,
    config: MockAutopilotConfig,
    stop: asyncio.Event | None = None,
    clock: Callable[[], int] = time.monotonic_ns,
    *,
    autopilot: MockAutopilot | None = None,
    on_event: Callable[[MockEvent], None] | None = None,
) -> MockAutopilot:
    """Serve ``transport`` as the mock autopilot until ``stop`` is set or the link closes.

    ``clock`` gives ns (monotonic); the mock starts flying at its first reading. Pass
    ``autopilot`` to run a mock you keep a reference to (``config`` is then unused; a
    :class:`~.lua_applet.LuaAppletAutopilot` works too), and ``on_event`` to see the
    events of :meth:`MockAutopilot.receive_data` and :meth:`MockAutopilot.poll`. Returns
    the mock, for its records and stats.
    """

    def now_us() -> int:
        return clock() // 1000

    if autopilot is None:
        if config.unix_us_at_start is None:
            config = replace(config, unix_us_at_start=time.time_ns() // 1000)
        autopilot = MockAutopilot(config, now_us())
    ap = autopilot

    def dispatch(events: list[MockEvent]) -> None:
        for ev in events:
            _log_event(ev)
            if on_event is not None:
                on_event(ev)

    stop = stop if stop is not None else asyncio.Event()
    stop_task: asyncio.Task[Any] = asyncio.create_task(stop.wait())
    recv_task: asyncio.Task[Any] | None = None
    try:
        while not stop.is_set():
            dispatch(ap.poll(now_us()))
            if not await _flush(transport, ap):
                log.info("link closed")
                break
            if recv_task is None:
                recv_task = asyncio.create_task(transport.recv())
            timeout_s = max(0.0, (ap.next_deadline_us() - now_us()) / 1e6)
            done, _ = await asyncio.wait(
                {recv_task, stop_task}, timeout=timeout_s, return_when=asyncio.FIRST_COMPLETED
            )
            if recv_task not in done:
                continue
            finished, recv_task = recv_task, None
            try:
                data = finished.result()
            except LinkDown:
                # A reconnecting link: wait for it rather than give up, but not past a
                # stop (SIGINT, SIGTERM): waiting on regardless, a link that never came up
                # (no such device) left only SIGKILL to end the command.
                wait_connected = getattr(transport, "wait_connected", None)
                if wait_connected is None:
                    break
                connected = asyncio.ensure_future(wait_connected())
                await asyncio.wait({connected, stop_task}, return_when=asyncio.FIRST_COMPLETED)
                if not connected.done():
                    connected.cancel()
                    with contextlib.suppress(asyncio.CancelledError):
                        await connected
                continue
            except TransportClosed:
                log.info("link closed")
                break
            except TransportTimeout:
                continue
            dispatch(ap.receive_data(data, now_us()))
            # Answers (ACKs, TIMESYNC) go out at once, not at the next timer.
            if not await _flush(transport, ap):
                log.info("link closed")
                break
    finally:
        for leftover in (recv_task, stop_task):
            if leftover is not None and not leftover.done():
                leftover.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await leftover
    return ap


async def serve_mock_autopilot(
    url: str, config: MockAutopilotConfig, stop: asyncio.Event | None = None
) -> MockAutopilot:
    """Open the transport ``url``, serve it until ``stop`` or the link ends, close it."""
    # Serial and TCP links reopen after a hang-up (the runner waits out LinkDown).
    transport = open_transport(url, reconnect=True)
    try:
        await transport.open()
        log.info(
            "mock autopilot %d/%d flying %s on %s",
            config.system_id,
            config.component_id,
            config.scenario,
            url,
        )
        return await run_mock_autopilot(transport, config, stop)
    finally:
        await transport.close()


# -- command line ------------------------------------------------------------------------
def config_from_args(args: argparse.Namespace) -> MockAutopilotConfig:
    """The mock's configuration from ``tcm-companion mock-autopilot``'s options."""
    return MockAutopilotConfig(
        system_id=args.sysid,
        scenario=args.scenario,
        seed=args.seed,
        noise=args.noise,
        ekf_origin_delay_us=round(args.ekf_origin_delay * 1e6),
        brake_on_collision=not args.no_brake,
        brake_ttc_s=args.brake_ttc,
    )


async def _serve_until_signal(url: str, config: MockAutopilotConfig) -> MockAutopilot:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
    return await serve_mock_autopilot(url, config, stop)


def run_from_args(args: argparse.Namespace) -> int:
    """Run the mock until SIGINT/SIGTERM or the link closes; print what it received."""
    try:
        config = config_from_args(args)
        ap = asyncio.run(_serve_until_signal(args.connect, config))
    except (TransportError, ValueError, OSError) as exc:  # a bad URL, a port in use
        print(f"mock-autopilot: error: {exc}", file=sys.stderr)
        return 2
    received = len(ap.received_status)
    problems = sum(1 for r in ap.received_status if not r.ok)
    print(
        f"mock autopilot: {received} status messages received ({problems} with problems), "
        f"{len(ap.received_obstacles)} obstacle messages, braked: {ap.braking is not None}"
    )
    for key, n in sorted(ap.stats.items()):
        print(f"  {key}: {n}")
    return 0
