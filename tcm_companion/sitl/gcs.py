"""A ground-station client for the SITL drivers: a sans-IO ground station on a transport.

:class:`GcsClient` is a :class:`~tcm_companion.mavlink.gcs.GroundStation` (framing,
records, periodic senders; time is ``time.monotonic()`` s) run on a transport of
:mod:`tcm_companion.io.transports` (``tcp:HOST:PORT`` to a SITL's SERIALn, or any other
URL), reopened with backoff when the connection drops (an autopilot reboot), by a
:class:`~tcm_companion.io.link_thread.LinkThread` (the autopilot camera's link runs on one
too). The caller's side is blocking: :meth:`send` from any thread, the ``wait_*``
methods (woken after each received batch), and the ground station's commands to the
autopilot (COMMAND_LONG with its COMMAND_ACK, parameters read and set through
PARAM_VALUE, message intervals).
"""

from __future__ import annotations

import math
import re
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

from ..io.link_thread import LinkThread
from ..io.transports import TransportError
from ..mavlink import tcm_dialect as dialect
from ..mavlink.gcs import GroundStation, Message, Received, StatusText, message_id
from .errors import SitlError, SitlTimeout

__all__ = ["GcsClient"]

T = TypeVar("T")


class GcsClient(GroundStation):
    """A MAVLink 2 client at ``url`` as system ``source_system``/``source_component``.

    ``station``: :class:`GroundStation`'s keyword arguments (``source_system`` 255,
    ``source_component`` 190, ``heartbeat_type`` ``MAV_TYPE_GCS``, ``target_system``/
    ``target_component`` (1, 1), ``history`` ...). One I/O thread reads the transport,
    records every message and runs the periodic senders (its own HEARTBEAT at 1 Hz unless
    ``heartbeat_type`` is None; a new one goes out within 50 ms). :meth:`send`
    may be called from any thread. When the connection drops it reconnects by itself;
    sends in between are dropped and counted in :attr:`dropped_sends`. The constructor
    waits up to ``connect_timeout_s`` for the connection (:class:`SitlError` without
    one; None: it does not wait, see :attr:`connected`).
    """

    def __init__(
        self,
        url: str,
        *,
        connect_timeout_s: float | None = 10.0,
        name: str = "",
        **station: Any,
    ) -> None:
        self.url = url
        self.name = name or url
        self._send_lock = threading.Lock()  # frames leave in the order they were numbered
        self._link = LinkThread(  # started below, once the ground station is there
            url,
            on_data=lambda data: self.receive_data(data, time.monotonic()),
            on_tick=self._tick,
            initial_backoff_s=0.05,
            max_backoff_s=0.5,
            name=f"mavlink {self.name}",
        )
        super().__init__(now_s=time.monotonic(), **station)
        try:
            self._link.start()
        except TransportError as exc:
            raise SitlError(f"cannot open {self.name}: {exc}") from exc
        if connect_timeout_s is not None:
            try:
                self.wait_for(lambda: self.connected, connect_timeout_s, "the connection")
            except SitlTimeout as exc:
                self.close()
                raise SitlError(f"cannot connect to {self.name}: {exc}") from exc

    # -- the link ----------------------------------------------------------------------------

    @property
    def connected(self) -> bool:
        return self._link.connected

    @property
    def disconnects(self) -> int:
        """How many times the connection was lost (e.g. by a reboot)."""
        return self._link.links_lost

    @property
    def dropped_sends(self) -> int:
        """Frames not sent: the link was down, or the write failed."""
        return self._link.send_errors

    def _tick(self) -> tuple[list[bytes], float]:
        now = time.monotonic()
        return self.poll(now), self.next_deadline_s(now) - now

    # -- sending -----------------------------------------------------------------------------

    def send(self, msg: Message) -> bool:
        """Send a message built with ``client.mav.<name>_encode(...)``; False if not connected."""
        with self._send_lock:
            return self._link.send(self.encode(msg))

    def send_bytes(self, data: bytes) -> bool:
        """Send frames encoded elsewhere (e.g. by another system's codec); False if not
        connected."""
        with self._send_lock:
            return self._link.send(data)

    # -- waiting -----------------------------------------------------------------------------

    def wait_for(self, predicate: Callable[[], T | None], timeout_s: float, what: str = "") -> T:
        """Wait until ``predicate()`` (evaluated after each received batch, and at least every
        0.1 s) is truthy and return it; :class:`SitlTimeout` after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        with self.changed:
            while True:
                value = predicate()
                if value:
                    return value
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise SitlTimeout(
                        f"{self.name}: timed out after {timeout_s:.1f} s waiting for "
                        f"{what or getattr(predicate, '__name__', 'a condition')}"
                    )
                self.changed.wait(min(remaining, 0.1))

    def wait_message(
        self,
        msg_type: str,
        timeout_s: float,
        predicate: Callable[[Message], bool] | None = None,
        since_s: float | None = None,
        src: tuple[int, int] | None = None,
    ) -> Received:
        """The first message of a type received at/after ``since_s`` (default: now) from
        ``src`` that satisfies ``predicate``."""
        since = time.monotonic() if since_s is None else since_s
        return self.wait_for(
            lambda: self.first_message(msg_type, since, predicate, src), timeout_s, msg_type
        )

    def wait_statustext(
        self, pattern: str, timeout_s: float, since_s: float | None = None
    ) -> StatusText:
        """The first STATUSTEXT at/after ``since_s`` (default: now) matching regex ``pattern``."""
        since = time.monotonic() if since_s is None else since_s
        regex = re.compile(pattern)

        def find() -> StatusText | None:
            for st in self.statustexts(since):
                if regex.search(st.text):
                    return st
            return None

        return self.wait_for(find, timeout_s, what=f"STATUSTEXT /{pattern}/")

    # -- commands to the autopilot -----------------------------------------------------------

    def command_long(
        self,
        command: int,
        *params: float,
        timeout_s: float = 3.0,
        target_component: int = 1,
    ) -> int:
        """Send COMMAND_LONG (up to 7 params) to the target system and return the final
        COMMAND_ACK result (MAV_RESULT); :class:`SitlTimeout` without one."""
        p = [float(v) for v in params] + [0.0] * (7 - len(params))
        since = time.monotonic()
        self.send(
            self.mav.command_long_encode(self.target_system, target_component, command, 0, *p[:7])
        )
        rec = self.wait_message(
            "COMMAND_ACK",
            timeout_s,
            lambda m: m.command == command and m.result != dialect.MAV_RESULT_IN_PROGRESS,
            since_s=since,
        )
        return int(rec.msg.result)

    def set_message_interval(self, msg_type: str | int, rate_hz: float) -> int:
        """MAV_CMD_SET_MESSAGE_INTERVAL on this link (0 Hz: off); the result."""
        interval_us = -1.0 if rate_hz <= 0 else 1e6 / rate_hz
        return self.command_long(
            dialect.MAV_CMD_SET_MESSAGE_INTERVAL, message_id(msg_type), interval_us
        )

    def _param_values(
        self, name: str, target_component: int, timeout_s: float, request: Callable[[], Any]
    ) -> Iterator[Received]:
        """Sends ``request()`` (a PARAM_SET or PARAM_REQUEST_READ message) and yields the
        PARAM_VALUE of ``name`` from ``target_component`` that answers it; re-sends after
        a second without one, until ``timeout_s``. The caller stops when it is satisfied."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            since = time.monotonic()
            self.send(request())
            try:
                rec = self.wait_message(
                    "PARAM_VALUE",
                    min(1.0, max(0.05, deadline - time.monotonic())),
                    lambda m: m.param_id == name,
                    since_s=since,
                    src=(self.target_system, target_component),
                )
            except SitlTimeout:
                continue
            yield rec

    def set_param(
        self, name: str, value: float, timeout_s: float = 5.0, target_component: int = 1
    ) -> float:
        """PARAM_SET to ``target_component`` of the target system (the autopilot, or e.g.
        the companion at 191 through the autopilot's routing), re-sent every second until a
        PARAM_VALUE with the new value comes back; returns it. :class:`SitlError` if it keeps
        another value."""
        last: Received | None = None
        for last in self._param_values(
            name,
            target_component,
            timeout_s,
            lambda: self.mav.param_set_encode(
                self.target_system,
                target_component,
                name.encode(),
                float(value),
                dialect.MAV_PARAM_TYPE_REAL32,
            ),
        ):
            if math.isclose(last.msg.param_value, value, rel_tol=1e-6, abs_tol=1e-6):
                return float(last.msg.param_value)
        if last is not None:
            raise SitlError(f"{name} set to {value} but reads {last.msg.param_value}")
        raise SitlTimeout(f"no PARAM_VALUE for {name} (unknown parameter?)")

    def get_param(self, name: str, target_component: int = 1, timeout_s: float = 3.0) -> float:
        """PARAM_REQUEST_READ by name; the value of the PARAM_VALUE reply."""
        for rec in self._param_values(
            name,
            target_component,
            timeout_s,
            lambda: self.mav.param_request_read_encode(
                self.target_system, target_component, name.encode(), -1
            ),
        ):
            return float(rec.msg.param_value)
        raise SitlTimeout(f"no PARAM_VALUE for {name} from component {target_component}")

    # -- the end -----------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the I/O thread and close the transport (idempotent)."""
        self._link.stop()

    def __enter__(self) -> GcsClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
