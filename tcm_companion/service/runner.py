"""Put the service together in one place: state files, endpoint, flight log, daemon.

Every way the daemon runs — ``tcm-companion run``, SITL against the mock autopilot (real
and virtual time) and against ArduPilot's SITL — does the same steps around its
:class:`~.companion.Companion`, here once:

1. the ``[mavlink]`` state files (signing timestamp, parameters) resolved under the
   run's state directory (:func:`~.endpoint_setup.resolve_state_paths`);
2. the endpoint made from them (:func:`~.endpoint_setup.make_endpoint`), its warnings
   logged (a :class:`~tcm_companion.io.persist.SigningKeyError` goes to the caller);
3. the flight log started with the parameters in force at start (replay needs them), by
   the caller's ``start_log`` (the service does not know the application's
   configuration: ``tcm_companion.flight_log_setup.start_flight_log`` does);
4. in real time, the transport (``[mavlink] url`` unless the caller brings its own) and
   the :class:`~.daemon.Daemon`.

On the way out the steps are undone in reverse, one at a time (like aiohttp's
``AppRunner`` on an ``AsyncExitStack``): the transport closed, the parameters and the
signing timestamp persisted, the flight log stopped (drained; in real time off the event
loop, so what is still in flight is not held up). Signals are the caller's: the command
line installs its handlers once around the run and sets the ``stop`` event it passes to
:meth:`Service.run`.

:func:`open_service` is the real-time (asyncio) runner; :func:`open_service_state` is its
first three steps alone, for the virtual-time SITL, which drives the Companion on its own
simulated clock without an event loop.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator, Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..io.aio import monotonic_us
from ..io.transports import Transport, open_transport
from ..mavlink.endpoint import CompanionEndpoint
from .daemon import Daemon, ServiceConfig
from .endpoint_setup import MavlinkConfig, make_endpoint, persist, resolve_state_paths
from .host import CameraInput, DaemonSummary

if TYPE_CHECKING:
    from ..flightlog.handle import FlightLog

__all__ = ["Service", "ServiceState", "StartLog", "open_service", "open_service_state"]

log = logging.getLogger(__name__)

#: ``start_log(params)``: start the run's flight log; ``params`` are the endpoint's
#: parameter values at start (persisted ones included), which the log records for replay.
StartLog = Callable[[Mapping[str, float]], "FlightLog"]


@dataclass
class ServiceState:
    """What the service keeps besides the daemon: its MAVLink settings with the state
    files resolved (absolute, under the state directory), the endpoint made from them,
    and the flight log (None: not logging)."""

    settings: MavlinkConfig
    endpoint: CompanionEndpoint
    flight_log: FlightLog | None

    def persist(self) -> None:
        """Write the parameters set over MAVLink and the signing timestamp back."""
        persist(self.settings, self.endpoint)

    def persist_at_exit(self) -> None:
        """:meth:`persist`, a failing disk logged rather than raised (on the way out)."""
        try:
            self.persist()
        except OSError as exc:
            log.warning("cannot persist parameters: %s", exc)


def _start(
    config: ServiceConfig,
    state_dir: str | Path,
    now_us: int,
    start_log: StartLog | None,
) -> ServiceState:
    settings = resolve_state_paths(config.mavlink, state_dir)
    endpoint, warnings = make_endpoint(settings, now_us, config.pipeline)
    for w in warnings:
        log.warning("%s", w)
    flight_log = None
    if start_log is not None:
        flight_log = start_log(dict(endpoint.params.values))
    return ServiceState(settings, endpoint, flight_log)


@contextlib.contextmanager
def open_service_state(
    config: ServiceConfig,
    state_dir: str | Path,
    now_us: int,
    *,
    start_log: StartLog | None = None,
) -> Iterator[ServiceState]:
    """Steps 1-3 (module docstring) with the endpoint started at ``now_us`` (µs, the
    companion monotonic clock the run stamps with); on exit the state is persisted and
    the flight log stopped (here, on this thread: virtual time has no loop to spare)."""
    state = _start(config, state_dir, now_us, start_log)
    with contextlib.ExitStack() as stack:
        if state.flight_log is not None:
            stack.callback(state.flight_log.stop)
        stack.callback(state.persist_at_exit)
        yield state


@dataclass
class Service:
    """A service put together by :func:`open_service`: its :class:`ServiceState` and its
    :class:`~.daemon.Daemon` (run it with :meth:`run`)."""

    state: ServiceState
    daemon: Daemon

    @property
    def endpoint(self) -> CompanionEndpoint:
        return self.state.endpoint

    @property
    def flight_log(self) -> FlightLog | None:
        return self.state.flight_log

    async def run(self, stop: asyncio.Event) -> DaemonSummary:
        """Run the daemon until ``stop`` is set (or a fatal error); the run's summary."""
        return await self.daemon.run(stop)


@contextlib.asynccontextmanager
async def open_service(
    config: ServiceConfig,
    cameras: Sequence[CameraInput],
    *,
    state_dir: str | Path,
    transport: Transport | None = None,
    now_us: int | None = None,
    start_log: StartLog | None = None,
    persist_changes: bool = False,
    **daemon_kwargs: Any,
) -> AsyncIterator[Service]:
    """The service on the running event loop (module docstring), torn down on exit.

    ``state_dir``: where the ``[mavlink]`` state files with relative names go.
    ``transport``: the link, opened, which the caller keeps and closes (default: ``[mavlink]
    url``, opened here with reconnection and closed on exit). ``now_us``: the endpoint's
    start on the companion monotonic clock (µs; default: now). ``start_log``: see
    :data:`StartLog` (None: no flight log). ``persist_changes``: write parameter changes
    to the state files as they happen (the service on a drone), not only on exit.
    ``daemon_kwargs`` go to :class:`~.daemon.Daemon` (notifier, watchdog interval, clock,
    ``on_result``, ``on_status``).
    """
    state = _start(config, state_dir, monotonic_us() if now_us is None else now_us, start_log)
    async with contextlib.AsyncExitStack() as stack:
        if state.flight_log is not None:
            stack.push_async_callback(asyncio.to_thread, state.flight_log.stop)
        stack.callback(state.persist_at_exit)
        if transport is None:
            transport = open_transport(state.settings.url, reconnect=True)
            await transport.open()
            stack.push_async_callback(transport.close)
        daemon = Daemon(
            config,
            cameras,
            transport=transport,
            endpoint=state.endpoint,
            flight_log=state.flight_log,
            persist=state.persist if persist_changes else None,
            **daemon_kwargs,
        )
        yield Service(state, daemon)
