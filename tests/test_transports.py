"""One contract test suite over every transport kind, as python-can's back2back_test.

The ``link`` fixture makes connected pairs of each kind: an in-memory pair, UDP on
loopback (udpin <-> udpout), a real pty pair made by socat at 921600 baud, and TCP on
loopback against a small asyncio server. Every contract test runs over all of them;
a kind that by nature cannot show a behaviour (UDP never pushes back, so it cannot time
out a write) is skipped with the reason. Timeouts are generous: the tests assert what
happens, not how fast, except where "promptly rather than hanging" is the contract.
"""

from __future__ import annotations

import asyncio
import os
import random
import re
import sys
import time
from collections.abc import AsyncIterator, Callable, Coroutine
from contextlib import asynccontextmanager
from typing import Any

import pytest

from tcm_companion.io.transports import (
    LinkDown,
    ReconnectingTransport,
    Transport,
    TransportClosed,
    TransportError,
    TransportOpenError,
    TransportTimeout,
    TransportURLError,
    memory_pair,
    open_transport,
)
from tcm_companion.io.transports.socat import SocatPtyPair, socat_available
from tcm_companion.mavlink import tcm_dialect as dialect
from tcm_companion.mavlink.codec import MavlinkCodec

KINDS = ("memory", "udp", "pty", "tcp")
# Reconnect tests need to see the backoff work, not wait for it.
FAST_BACKOFF = {"initial_backoff_s": 0.05, "max_backoff_s": 0.4}


def run(coro: Coroutine[Any, Any, Any], timeout: float = 30.0) -> Any:
    """Run one test body; a hang fails the test instead of stalling CI."""

    async def bounded() -> Any:
        async with asyncio.timeout(timeout):
            return await coro

    return asyncio.run(bounded())


# -- the far end of a TCP link: a small asyncio server --------------------------------------
class ServerSide(Transport):
    """The server's end of one accepted connection, as a Transport (over asyncio streams).

    Also shows how little a backend needs: ``_open``, ``_write``, ``_release``.
    """

    kind = "tcp-server-side"

    def __init__(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, **options: Any
    ) -> None:
        super().__init__("tcp-server-side", **options)
        self._reader, self._writer = reader, writer
        self._pump: asyncio.Task[None] | None = None

    async def _open(self) -> None:
        self._pump = asyncio.create_task(self._pump_loop())

    async def _pump_loop(self) -> None:
        try:
            while data := await self._reader.read(65536):
                self._data_received(data)
            self._lost(None)
        except OSError as exc:
            self._lost(exc)

    async def _write(self, data: memoryview) -> None:
        self._writer.write(bytes(data))
        self.stats["bytes_out"] += len(data)
        await self._writer.drain()

    def _release(self) -> None:
        if self._pump is not None and self._pump is not asyncio.current_task():
            self._pump.cancel()
        self._writer.close()


class TcpServer:
    """Listens on loopback; hands out accepted connections in order."""

    def __init__(self, port: int = 0) -> None:
        self.port = port
        self._server: asyncio.Server | None = None
        self._accepted: asyncio.Queue[tuple[asyncio.StreamReader, asyncio.StreamWriter]] = (
            asyncio.Queue()
        )
        self._writers: list[asyncio.StreamWriter] = []

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._on_connect, "127.0.0.1", self.port)
        self.port = self._server.sockets[0].getsockname()[1]

    def _on_connect(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._writers.append(writer)
        self._accepted.put_nowait((reader, writer))

    async def accept_raw(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        async with asyncio.timeout(10):
            return await self._accepted.get()

    async def accept(self, **options: Any) -> ServerSide:
        reader, writer = await self.accept_raw()
        side = ServerSide(reader, writer, **options)
        await side.open()
        return side

    async def stop(self) -> None:
        """Stop listening and drop every connection: the peer goes away."""
        for writer in self._writers:
            writer.transport.abort()
        self._writers.clear()
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
            self._server = None


# -- one way per kind to make connected pairs ----------------------------------------------
class Link:
    """How one transport kind makes connected pairs; the contract's parametrised fixture."""

    name = "?"
    pushes_back = False  # a peer that stops reading makes send() time out
    reports_peer_close = False  # closing one end ends the other's recv()
    reconnectable = False

    @asynccontextmanager
    async def pair(self, **options: Any) -> AsyncIterator[tuple[Transport, Transport]]:
        raise NotImplementedError
        yield  # pragma: no cover

    @asynccontextmanager
    async def stalled(self, **options: Any) -> AsyncIterator[Transport]:
        """An open transport whose peer is connected but never reads."""
        raise NotImplementedError
        yield  # pragma: no cover


class MemoryLink(Link):
    name = "memory"
    reports_peer_close = True

    @asynccontextmanager
    async def pair(self, **options: Any) -> AsyncIterator[tuple[Transport, Transport]]:
        a, b = memory_pair(**options)
        async with a, b:  # already open: entering only closes them at the end
            yield a, b


class UdpLink(Link):
    name = "udp"

    @asynccontextmanager
    async def pair(self, **options: Any) -> AsyncIterator[tuple[Transport, Transport]]:
        async with open_transport("udpin:127.0.0.1:0", **options) as a:
            port = a.local_address[1]  # type: ignore[attr-defined]
            async with open_transport(f"udpout:127.0.0.1:{port}", **options) as b:
                # udpin answers whoever spoke last: say hello so that a knows b.
                await b.send(b"\0")
                assert await a.recv(timeout=5) == b"\0"
                yield a, b


class PtyLink(Link):
    name = "pty"
    pushes_back = True
    reconnectable = True

    def __init__(self, socat: SocatPtyPair) -> None:
        self.socat = socat

    @asynccontextmanager
    async def pair(self, **options: Any) -> AsyncIterator[tuple[Transport, Transport]]:
        url_a, url_b = self.socat.urls()
        async with open_transport(url_a, **options) as a, open_transport(url_b, **options) as b:
            yield a, b

    @asynccontextmanager
    async def stalled(self, **options: Any) -> AsyncIterator[Transport]:
        # The far end is open (so the pty carries data) but nobody reads it.
        fd = os.open(self.socat.links[1], os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            async with open_transport(self.socat.urls()[0], **options) as a:
                yield a
        finally:
            os.close(fd)

    # reconnect harness: the "device" goes away when socat exits and comes back
    async def far_end(self) -> Transport:
        far = open_transport(self.socat.urls()[1])
        await far.open()
        return far

    def url(self) -> str:
        return self.socat.urls()[0]

    async def take_down(self) -> None:
        self.socat.stop()

    async def bring_up(self) -> None:
        self.socat.start()


class TcpLink(Link):
    name = "tcp"
    pushes_back = True
    reports_peer_close = True
    reconnectable = True

    def __init__(self) -> None:
        self.server = TcpServer()

    @asynccontextmanager
    async def pair(self, **options: Any) -> AsyncIterator[tuple[Transport, Transport]]:
        await self.server.start()
        try:
            async with open_transport(f"tcp:127.0.0.1:{self.server.port}", **options) as a:
                b = await self.server.accept(**options)
                try:
                    yield a, b
                finally:
                    await b.close()
        finally:
            await self.server.stop()

    @asynccontextmanager
    async def stalled(self, **options: Any) -> AsyncIterator[Transport]:
        await self.server.start()
        try:
            async with open_transport(f"tcp:127.0.0.1:{self.server.port}", **options) as a:
                await self.server.accept_raw()  # accepted, never read
                yield a
        finally:
            await self.server.stop()

    async def far_end(self) -> Transport:
        return await self.server.accept()

    def url(self) -> str:
        return f"tcp:127.0.0.1:{self.server.port}"

    async def take_down(self) -> None:
        await self.server.stop()

    async def bring_up(self) -> None:
        await self.server.start()  # same port: asyncio sets SO_REUSEADDR


@pytest.fixture(
    # the pty pair is made by socat, a subprocess: slow (tests/conftest.py)
    params=[pytest.param(k, marks=pytest.mark.slow) if k == "pty" else k for k in KINDS]
)
def link(request: pytest.FixtureRequest) -> Any:
    kind = request.param
    if kind == "memory":
        yield MemoryLink()
    elif kind == "udp":
        yield UdpLink()
    elif kind == "tcp":
        yield TcpLink()
    else:
        if not socat_available():
            pytest.skip("socat not installed: the pty cases need it (apt-get install socat)")
        with SocatPtyPair(baud=921600) as socat:
            yield PtyLink(socat)


# -- helpers ------------------------------------------------------------------------------
_FRAMES: dict[int, list[bytes]] = {}


def mavlink_frames(seed: int, n: int = 3000) -> list[bytes]:
    """Real MAVLink 2 frames of mixed sizes (~300 KiB for n=3000), all different."""
    if seed in _FRAMES:
        return _FRAMES[seed]
    codec = MavlinkCodec(src_system=1 + seed, src_component=191)
    rng = random.Random(seed)
    frames = []
    for i in range(n):
        kind = i % 4
        if kind == 0:
            msg: Any = dialect.MAVLink_tcm_object_status_message(
                i, i & 0xFFFF, 0, rng.randrange(3), 0, rng.random(), 0.5, float("nan"), 0,
                rng.uniform(-3, 3), rng.uniform(-1, 1), 0.01, rng.uniform(1, 50), 90,
            )  # fmt: skip
        elif kind == 1:
            msg = dialect.MAVLink_attitude_message(i, *(rng.uniform(-1, 1) for _ in range(6)))
        elif kind == 2:
            distances = [rng.randrange(20, 4000) for _ in range(72)]
            msg = dialect.MAVLink_obstacle_distance_message(i, 4, distances, 5, 20, 4000)
        else:
            msg = dialect.MAVLink_statustext_message(6, f"frame {i} {rng.random()}".encode())
        frames.append(codec.encode(msg))
    _FRAMES[seed] = frames
    return frames


async def send_frames(t: Transport, frames: list[bytes], seed: int) -> None:
    """Send in batches of 1..40 frames, as a busy endpoint would."""
    rng = random.Random(seed)
    i = 0
    while i < len(frames):
        k = rng.randint(1, 40)
        await t.send(b"".join(frames[i : i + k]))
        i += k
        await asyncio.sleep(0)  # a real producer yields between batches


async def receive_frames(t: Transport, n: int) -> tuple[list[bytes], MavlinkCodec]:
    codec = MavlinkCodec(src_system=250, src_component=0)
    got: list[bytes] = []
    while len(got) < n:
        for msg in codec.feed(await t.recv(timeout=10)):
            got.append(bytes(msg.get_msgbuf()))
    return got, codec


async def receive_bytes(t: Transport, n: int) -> bytes:
    buf = bytearray()
    while len(buf) < n:
        buf += await t.recv(timeout=10)
    return bytes(buf)


async def eventually(check: Callable[[], bool], timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not check():
        assert time.monotonic() < deadline, "condition not reached in time"
        await asyncio.sleep(0.01)


async def roundtrip(a: Transport, b: Transport, tag: bytes) -> None:
    await a.send(b"ping " + tag)
    assert await receive_bytes(b, 5 + len(tag)) == b"ping " + tag
    await b.send(b"pong " + tag)
    assert await receive_bytes(a, 5 + len(tag)) == b"pong " + tag


# -- the contract -------------------------------------------------------------------------
def test_mavlink_frames_arrive_in_order_and_intact_both_ways(link: Link) -> None:
    async def body() -> None:
        fwd, back = mavlink_frames(1), mavlink_frames(2)
        async with link.pair(write_timeout_s=10) as (a, b):
            results = await asyncio.gather(
                send_frames(a, fwd, seed=3),
                send_frames(b, back, seed=4),
                receive_frames(b, len(fwd)),
                receive_frames(a, len(back)),
            )
        (got_fwd, codec_b), (got_back, codec_a) = results[2], results[3]
        assert got_fwd == fwd
        assert got_back == back
        for codec in (codec_a, codec_b):
            assert codec.stats["bad CRC"] == 0 and codec.stats["garbage bytes"] == 0

    assert sum(map(len, mavlink_frames(1))) > 200_000  # "a few hundred KiB"
    run(body())


def test_large_single_writes(link: Link) -> None:
    async def body() -> None:
        fwd, back = os.urandom(512 * 1024), os.urandom(300 * 1024)
        async with link.pair(write_timeout_s=10) as (a, b):
            _, _, got_fwd, got_back = await asyncio.gather(
                a.send(fwd), b.send(back), receive_bytes(b, len(fwd)), receive_bytes(a, len(back))
            )
        assert got_fwd == fwd  # all 256 byte values: the pty is 8-bit clean (raw mode)
        assert got_back == back

    run(body())


def test_concurrent_senders_do_not_interleave(link: Link) -> None:
    async def body() -> None:
        frames_1, frames_2 = mavlink_frames(1)[:600], mavlink_frames(2)[:600]
        async with link.pair(write_timeout_s=10) as (a, b):
            _, _, (got, codec) = await asyncio.gather(
                send_frames(a, frames_1, seed=5),
                send_frames(a, frames_2, seed=6),
                receive_frames(b, 1200),
            )
        assert codec.stats["bad CRC"] == 0
        assert [f for f in got if f in set(frames_1)] == frames_1
        assert [f for f in got if f in set(frames_2)] == frames_2

    run(body())


def test_close_makes_recv_and_send_raise_closed(link: Link) -> None:
    async def body() -> None:
        async with link.pair() as (a, _b):
            waiting = asyncio.create_task(a.recv())
            await asyncio.sleep(0.05)
            await a.close()
            with pytest.raises(TransportClosed):
                async with asyncio.timeout(2):
                    await waiting  # a task already waiting wakes up
            with pytest.raises(TransportClosed):
                await a.recv()
            with pytest.raises(TransportClosed):
                await a.send(b"x")
            await a.close()  # idempotent
            assert not a.is_open

    run(body())


def test_peer_closing_ends_recv_after_pending_data(link: Link) -> None:
    if not link.reports_peer_close:
        pytest.skip(
            f"{link.name}: the far end closing is not visible (UDP is connectionless; a pty "
            "stays up while socat runs — the hang-up path is test_reconnect_after_peer_goes_away)"
        )

    async def body() -> None:
        async with link.pair() as (a, b):
            await b.send(b"last words")
            await b.close()
            assert await receive_bytes(a, 10) == b"last words"
            with pytest.raises(TransportClosed):
                await a.recv(timeout=5)
            assert a.stats["links_lost"] == 1

    run(body())


def test_send_to_peer_that_stopped_reading_times_out(link: Link) -> None:
    if not link.pushes_back:
        pytest.skip(f"{link.name}: never blocks a writer (drops instead; see the overflow test)")

    async def body() -> None:
        async with link.stalled(write_timeout_s=0.3) as a:
            chunk = bytes(64 * 1024)
            deadline = time.monotonic() + 20
            with pytest.raises(TransportTimeout):
                while time.monotonic() < deadline:
                    t0 = time.monotonic()
                    await a.send(chunk)
            assert time.monotonic() - t0 < 3.0  # bounded by write_timeout_s, not forever
            assert a.stats["write_timeouts"] == 1
            t0 = time.monotonic()
            await a.close()  # closing with a stuck backlog does not hang either
            assert time.monotonic() - t0 < 3.0

    run(body())


def test_rx_overflow_drops_oldest_and_counts(link: Link) -> None:
    async def body() -> None:
        payload = os.urandom(64 * 1024)
        async with link.pair(max_rx_bytes=4096, write_timeout_s=10) as (a, b):
            start = b.stats["bytes_in"]
            for i in range(0, len(payload), 4096):  # b is not reading meanwhile
                await a.send(payload[i : i + 4096])
            await eventually(lambda: b.stats["bytes_in"] - start >= len(payload))
            assert await b.recv(timeout=5) == payload[-4096:]
            assert b.stats["dropped_bytes"] == len(payload) - 4096

    run(body())


def test_stats_count_bytes(link: Link) -> None:
    async def body() -> None:
        async with link.pair() as (a, b):
            out0, in0 = a.stats["bytes_out"], b.stats["bytes_in"]
            await a.send(b"x" * 1000)
            await a.send(b"y" * 234)
            await receive_bytes(b, 1234)
            assert a.stats["bytes_out"] - out0 == 1234
            assert b.stats["bytes_in"] - in0 == 1234
            assert b.stats["dropped_bytes"] == 0

    run(body())


def test_reconnect_after_peer_goes_away(link: Link) -> None:
    if not link.reconnectable:
        pytest.skip(f"{link.name}: cannot be lost, so there is nothing to reconnect")
    assert isinstance(link, PtyLink | TcpLink)

    async def body() -> None:
        if isinstance(link, TcpLink):
            await link.server.start()
        a = open_transport(link.url(), reconnect=True, **FAST_BACKOFF)
        assert isinstance(a, ReconnectingTransport)
        async with a:
            assert a.connected
            far = await link.far_end()
            await roundtrip(a, far, b"1")

            await far.send(b"before the loss")
            await receive_bytes(a, 15)
            await link.take_down()
            with pytest.raises(LinkDown):
                await a.recv(timeout=5)  # the loss is noticed, not waited out
            # During the outage nothing hangs: both raise at once.
            t0 = time.monotonic()
            with pytest.raises(LinkDown):
                await a.recv()
            with pytest.raises(TransportTimeout):
                await a.send(b"into the void")
            assert time.monotonic() - t0 < 0.5
            with pytest.raises(TransportTimeout):
                await a.wait_connected(timeout=0.2)
            await far.close()

            await link.bring_up()
            await a.wait_connected(timeout=10)
            far = await link.far_end()
            await roundtrip(a, far, b"2")
            await far.close()
            assert a.stats["reconnects"] == 1
            assert a.stats["links_lost"] == 1
        if isinstance(link, TcpLink):
            await link.server.stop()

    run(body())


# -- the registry, URLs and transport-specific behaviour -----------------------------------
@pytest.mark.parametrize(
    ("url", "names"),
    [
        ("ser:/dev/ttyAMA0", "'ser:'"),
        ("/dev/ttyAMA0", "unknown transport"),
        ("udpin:0.0.0.0", "HOST:PORT"),
        ("udpout:127.0.0.1:0", "port '0'"),
        ("tcp:localhost:http", "port 'http'"),
        ("tcp::5760", "host"),
        ("serial::921600", "device path is empty"),
        ("serial:/dev/ttyAMA0:9", "baud rate 9"),
        ("memory:", "channel name"),
    ],
)
def test_bad_urls_name_the_bad_part(url: str, names: str) -> None:
    with pytest.raises(TransportURLError, match=names) as info:
        open_transport(url)
    assert repr(url) in str(info.value)
    assert isinstance(info.value, ValueError)


def test_missing_pyserial_is_a_readable_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "serial", None)  # import serial -> ImportError
    monkeypatch.delitem(sys.modules, "tcm_companion.io.transports.serial_port", raising=False)
    with pytest.raises(TransportError, match=re.escape("pip install 'pyserial>=3.5'")):
        open_transport("serial:/dev/ttyAMA0:921600")
    # the other backends do not need it
    assert open_transport("udpout:127.0.0.1:14550").kind == "udpout"


def test_serial_device_missing_names_the_path() -> None:
    async def body() -> None:
        with pytest.raises(TransportOpenError, match="/dev/tcm-no-such-tty"):
            await open_transport("serial:/dev/tcm-no-such-tty:921600").open()

    run(body())


def test_serial_url_forms() -> None:
    t: Any = open_transport("serial:/dev/ttyAMA0:921600")
    assert (t.path, t.baudrate) == ("/dev/ttyAMA0", 921600)
    t = open_transport("serial:/dev/ttyUSB0")
    assert (t.path, t.baudrate) == ("/dev/ttyUSB0", 115200)
    by_path = "/dev/serial/by-path/platform-fd500000.pcie-pci-0000:01:00.0-usb-0:1.3:1.0-port0"
    t = open_transport(f"serial:{by_path}:57600")
    assert (t.path, t.baudrate) == (by_path, 57600)
    t = open_transport(f"serial:{by_path}")
    assert (t.path, t.baudrate) == (by_path, 115200)


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_reconnecting_link_that_never_comes_up_backs_off_and_does_not_hang() -> None:
    async def body() -> None:
        server = TcpServer()
        await server.start()
        port = server.port
        await server.stop()  # a port nobody listens on
        a = open_transport(f"tcp:127.0.0.1:{port}", reconnect=True, initial_backoff_s=0.1)
        async with a:  # open() does not fail: the link is retried in the background
            assert not a.connected  # type: ignore[attr-defined]
            t0 = time.monotonic()
            with pytest.raises(LinkDown, match="reconnecting"):
                await a.recv()
            with pytest.raises(TransportTimeout):
                await a.send(b"x")
            assert time.monotonic() - t0 < 0.5
            await asyncio.sleep(1.0)
            # 0.1 + 0.2 + 0.4 s of backoff fit in a second: a handful of attempts, not a spin
            assert 2 <= a.stats["open_failures"] <= 6

    run(body())


def test_reconnecting_tcp_follows_a_server_that_drops_the_connection() -> None:
    async def body() -> None:
        server = TcpServer()
        await server.start()
        a = open_transport(f"tcp:127.0.0.1:{server.port}", reconnect=True, **FAST_BACKOFF)
        async with a:
            for i in range(3):
                far = await server.accept()
                await a.wait_connected(timeout=5)  # type: ignore[attr-defined]
                await roundtrip(a, far, str(i).encode())
                await far.close()  # the server hangs up; the listener stays
            assert a.stats["reconnects"] == 2
        await server.stop()

    run(body())


def test_memory_channels_pair_by_name() -> None:
    async def body() -> None:
        async with open_transport("memory:chan-x") as a:
            await a.send(b"nobody yet")  # dropped and counted, as on UDP
            assert a.stats["no_peer_drops"] == 1
            async with open_transport("memory:chan-x") as b:
                await roundtrip(a, b, b"x")
            with pytest.raises(TransportClosed):
                await a.recv(timeout=1)

    run(body())


def test_udpin_replies_to_the_last_peer() -> None:
    async def body() -> None:
        async with open_transport("udpin:127.0.0.1:0") as hub:
            port = hub.local_address[1]  # type: ignore[attr-defined]
            await hub.send(b"before anyone")  # no peer yet: dropped, counted
            assert hub.stats["no_peer_drops"] == 1
            url = f"udpout:127.0.0.1:{port}"
            async with open_transport(url) as gcs1, open_transport(url) as gcs2:
                await roundtrip(gcs1, hub, b"1")
                await roundtrip(gcs2, hub, b"2")
                await hub.send(b"to the latest")
                assert await gcs2.recv(timeout=5) == b"to the latest"
                with pytest.raises(TransportTimeout):
                    await gcs1.recv(timeout=0.2)
            assert hub.stats["peer_changes"] == 1

    run(body())


def test_recv_timeout_and_chunk_bound() -> None:
    async def body() -> None:
        a, b = memory_pair()
        with pytest.raises(TransportTimeout):
            await b.recv(timeout=0.05)
        await a.send(bytes(200_000))
        sizes = [len(await b.recv()) for _ in range(4)]
        assert sizes == [65536, 65536, 65536, 200_000 - 3 * 65536]

    run(body())


def test_send_lock_and_timeouts_leave_no_background_tasks() -> None:
    async def body() -> None:
        a, b = memory_pair()
        await asyncio.gather(*(a.send(bytes([i]) * 10) for i in range(20)))
        data = await receive_bytes(b, 200)
        assert all(len(set(data[i : i + 10])) == 1 for i in range(0, 200, 10))
        await a.close()
        await b.close()
        assert asyncio.all_tasks() == {asyncio.current_task()}

    run(body())
