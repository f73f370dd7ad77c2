"""The systemd unit (verify, security exposure) and the sd_notify client.

The unit is checked with the real ``systemd-analyze`` (no running systemd needed): it
must verify with no message at all, and ``security --offline`` must rate it 3.0 or
better. The notifier is checked against sockets bound here, the way systemd's manager
socket receives: exact datagrams, the abstract namespace, failures counted and never
raised, and a separate process sending as the daemon would (with its own PID in the
kernel-attached credentials, which is what ``NotifyAccess=main`` checks).
"""

from __future__ import annotations

import errno
import os
import re
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from tcm_companion.io.sdnotify import MAX_MESSAGE_BYTES, Notifier, watchdog_interval_us

ROOT = Path(__file__).resolve().parent.parent
UNIT = ROOT / "systemd" / "tcm-companion.service"
INSTALL_DOC = ROOT / "docs" / "install.md"
EXEC_START = "/opt/tcm-companion/venv/bin/tcm-companion run --config /etc/tcm-companion/config.toml"
MAX_EXPOSURE = 3.0

needs_analyze = pytest.mark.skipif(
    shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed"
)


def unit_settings(text: str) -> dict[str, list[str]]:
    """``Key`` -> every value assigned to it in the unit (sections merged)."""
    out: dict[str, list[str]] = {}
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith(("#", ";", "[")):
            continue
        key, _, value = line.partition("=")
        out.setdefault(key.strip(), []).append(value.strip())
    return out


# -- the unit file ---------------------------------------------------------------------


def test_unit_declares_what_the_daemon_and_docs_rely_on() -> None:
    s = unit_settings(UNIT.read_text())
    assert s["Type"] == ["notify"]
    assert s["NotifyAccess"] == ["main"]
    assert s["WatchdogSec"] == ["5"]
    assert s["ExecStart"] == [EXEC_START]
    assert set(s["SupplementaryGroups"][0].split()) >= {"video", "dialout"}
    assert s["DevicePolicy"] == ["closed"]
    assert "char-video4linux rw" in s["DeviceAllow"]
    assert "AF_NETLINK" not in " ".join(s["RestrictAddressFamilies"])
    # numpy's bundled OpenBLAS calls mbind() (in @resources) at import: with the filter's
    # default action (kill) the daemon would die on start; EPERM is ignored by OpenBLAS.
    if any("@resources" in v and v.startswith("~") for v in s["SystemCallFilter"]):
        assert s.get("SystemCallErrorNumber") == ["EPERM"]
    # the install guide documents the paths the unit uses
    assert EXEC_START.split()[0] in INSTALL_DOC.read_text()


def _runnable_copy(tmp_path: Path) -> Path:
    """The unit with ExecStart's binary (not installed here) replaced by this Python."""
    text = UNIT.read_text()
    exe = sys.executable if " " not in sys.executable else f'"{sys.executable}"'
    new, n = re.subn(
        r"(?m)^ExecStart=\S+",
        lambda _m: f"ExecStart={exe} -m tcm_companion",
        text,
    )
    assert n == 1
    copy = tmp_path / UNIT.name  # same name: verify checks the unit name too
    copy.write_text(new)
    return copy


@pytest.mark.slow  # a subprocess
@needs_analyze
def test_unit_verifies_without_any_message(tmp_path: Path) -> None:
    copy = _runnable_copy(tmp_path)
    proc = subprocess.run(
        ["systemd-analyze", "verify", str(copy)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    output = (proc.stdout + proc.stderr).strip()
    # unknown keys, bad values etc. are only warnings (exit 0): any message fails
    assert proc.returncode == 0 and output == "", output


@pytest.mark.slow  # a subprocess
@needs_analyze
def test_verify_would_catch_a_bad_setting(tmp_path: Path) -> None:
    """The check above is meaningful: a misspelt key in the same unit is reported."""
    copy = _runnable_copy(tmp_path)
    copy.write_text(copy.read_text().replace("ProtectClock=yes", "ProtectClok=yes"))
    proc = subprocess.run(
        ["systemd-analyze", "verify", str(copy)], capture_output=True, text=True, timeout=120
    )
    assert "ProtectClok" in proc.stdout + proc.stderr


@pytest.mark.slow  # a subprocess
@needs_analyze
def test_security_exposure_is_ok_or_better() -> None:
    proc = subprocess.run(
        ["systemd-analyze", "security", "--offline=yes", "--no-pager", str(UNIT)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    m = re.search(r"Overall exposure level for \S+: (\d+(?:\.\d+)?) (\S+)", proc.stdout)
    assert m, proc.stdout + proc.stderr
    score = float(m.group(1))
    print(f"systemd-analyze security --offline=yes {UNIT.name}: {score} {m.group(2)}")
    assert score <= MAX_EXPOSURE, proc.stdout


# -- the notifier against a socket bound here ------------------------------------------


class Receiver:
    """A manager-side notification socket: AF_UNIX datagrams, credentials passed."""

    def __init__(self, address: str) -> None:
        self.address = address  # as it goes into NOTIFY_SOCKET
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_PASSCRED, 1)
        bind_to = "\0" + address[1:] if address.startswith("@") else address
        self.sock.bind(bind_to)
        self.sock.settimeout(10)

    def recv(self) -> bytes:
        return self.sock.recv(65536)

    def recv_with_pid(self) -> tuple[bytes, int]:
        data, anc, _flags, _addr = self.sock.recvmsg(65536, socket.CMSG_SPACE(12))
        for level, kind, payload in anc:
            if level == socket.SOL_SOCKET and kind == socket.SCM_CREDENTIALS:
                pid, _uid, _gid = struct.unpack("3i", payload[:12])
                return data, pid
        raise AssertionError("no credentials attached")

    def pending(self) -> bytes | None:
        """The next datagram if one is queued, else None (without waiting)."""
        self.sock.setblocking(False)
        try:
            return self.sock.recv(65536)
        except BlockingIOError:
            return None
        finally:
            self.sock.settimeout(10)

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def sock_dir(tmp_path: Path) -> Iterator[Path]:
    # sun_path holds 108 bytes; a deep tmp_path may not fit
    if len(str(tmp_path / "notify")) < 100:
        yield tmp_path
    else:
        d = Path(tempfile.mkdtemp(prefix="sdn"))
        yield d
        shutil.rmtree(d, ignore_errors=True)


@pytest.fixture
def receiver(sock_dir: Path) -> Iterator[Receiver]:
    r = Receiver(str(sock_dir / "notify"))
    yield r
    r.close()


def test_messages_arrive_as_exact_datagrams(receiver: Receiver) -> None:
    n = Notifier.from_env({"NOTIFY_SOCKET": receiver.address})
    assert n.enabled
    assert n.ready()
    assert receiver.recv() == b"READY=1"
    assert n.ready("tracking 2 objects")
    assert receiver.recv() == b"READY=1\nSTATUS=tracking 2 objects"
    assert n.status("camera 0: 25.0 fps, link up")
    assert receiver.recv() == b"STATUS=camera 0: 25.0 fps, link up"
    assert n.watchdog()
    assert receiver.recv() == b"WATCHDOG=1"
    assert n.stopping()
    assert receiver.recv() == b"STOPPING=1"
    assert n.stopping("closing link")
    assert receiver.recv() == b"STOPPING=1\nSTATUS=closing link"
    assert n.extend_timeout(3_000_000)
    assert receiver.recv() == b"EXTEND_TIMEOUT_USEC=3000000"
    assert n.notify(STATUS="two\nlines", ERRNO=5)
    assert receiver.recv() == b"STATUS=two lines\nERRNO=5"
    assert n.send("READY=1\nSTATUS=raw")
    assert receiver.recv() == b"READY=1\nSTATUS=raw"
    assert (n.sent, n.errors) == (9, 0)
    n.close()


def test_one_socket_is_created_and_reused(receiver: Receiver) -> None:
    n = Notifier(receiver.address)
    assert n._sock is None  # nothing opened before the first send
    n.watchdog()
    first = n._sock
    assert first is not None and not first.getblocking()
    for _ in range(5):
        n.watchdog()
    assert n._sock is first
    n.close()


def test_abstract_namespace_address() -> None:
    r = Receiver(f"@tcm-companion-test-{uuid.uuid4().hex}")
    try:
        n = Notifier.from_env({"NOTIFY_SOCKET": r.address})
        assert n.enabled
        assert n.ready("up") and n.watchdog()
        assert r.recv() == b"READY=1\nSTATUS=up"
        assert r.recv() == b"WATCHDOG=1"
        assert n.errors == 0
        n.close()
    finally:
        r.close()


@pytest.mark.parametrize(
    "environ", [{}, {"NOTIFY_SOCKET": ""}, {"NOTIFY_SOCKET": "@"}, {"NOTIFY_SOCKET": "vsock:2:9"}]
)
def test_without_a_usable_socket_everything_is_a_no_op(environ: dict[str, str]) -> None:
    n = Notifier.from_env(environ)
    assert not n.enabled
    assert not n.ready("x")
    assert not n.status("x")
    assert not n.watchdog()
    assert not n.stopping()
    assert not n.notify(READY=1)
    assert (n.sent, n.errors, n._sock) == (0, 0, None)


def test_a_vanished_socket_is_counted_not_raised(receiver: Receiver, sock_dir: Path) -> None:
    n = Notifier(receiver.address)
    assert n.ready()
    assert receiver.recv() == b"READY=1"
    # the manager's socket closes but its file stays: ECONNREFUSED
    receiver.close()
    assert not n.watchdog()
    assert n.errors == 1 and isinstance(n.last_error, ConnectionRefusedError)
    # and then the file goes too: ENOENT
    os.unlink(receiver.address)
    assert not n.status("still running")
    assert n.errors == 2 and isinstance(n.last_error, FileNotFoundError)
    # a manager that comes back (daemon-reexec) is reached again on the same socket
    again = Receiver(receiver.address)
    try:
        assert n.watchdog()
        assert again.recv() == b"WATCHDOG=1"
        assert (n.sent, n.errors) == (2, 2)
    finally:
        again.close()
        n.close()


def test_a_full_queue_does_not_block(receiver: Receiver) -> None:
    n = Notifier(receiver.address)
    results = [n.watchdog() for _ in range(5000)]  # nobody reads: the queue fills
    assert not all(results)
    assert n.errors == results.count(False) and n.sent == results.count(True)
    assert isinstance(n.last_error, OSError) and n.last_error.errno in (
        errno.EAGAIN,
        errno.EWOULDBLOCK,
    )
    # draining the queue makes room again
    while receiver.pending() is not None:
        pass
    assert n.watchdog()
    n.close()


def test_bad_input_never_raises(receiver: Receiver, sock_dir: Path) -> None:
    n = Notifier(receiver.address)
    assert not n.notify(ready=1)  # not an upper-case field name
    assert n.errors == 1 and isinstance(n.last_error, ValueError)
    assert receiver.pending() is None
    long_path = Notifier("/" + "x" * 200)  # longer than sun_path
    assert long_path.enabled and not long_path.watchdog() and long_path.errors == 1
    # a message longer than systemd reads is cut to its buffer, on a character boundary
    assert n.status("é" * MAX_MESSAGE_BYTES)
    got = receiver.recv()
    assert len(got) <= MAX_MESSAGE_BYTES and got.startswith(b"STATUS=")
    got.decode("utf-8")
    n.close()


def test_watchdog_interval() -> None:
    me = os.getpid()
    assert watchdog_interval_us({}) is None
    assert watchdog_interval_us({"WATCHDOG_USEC": "5000000"}) == 2_500_000
    assert watchdog_interval_us({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": str(me)}) == 2_500_000
    # the variables were meant for another process (inherited from a parent)
    assert watchdog_interval_us({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": str(me + 1)}) is None
    assert watchdog_interval_us({"WATCHDOG_USEC": "4000", "WATCHDOG_PID": "77"}, pid=77) == 2000
    for bad in ("", "0", "-5", "5s", "1e6"):
        assert watchdog_interval_us({"WATCHDOG_USEC": bad}) is None
    assert watchdog_interval_us({"WATCHDOG_USEC": "100", "WATCHDOG_PID": "abc"}) is None
    assert watchdog_interval_us({"WATCHDOG_USEC": "1"}) == 1


# -- across processes, as under systemd ------------------------------------------------

CHILD = """
from tcm_companion.io.sdnotify import Notifier, watchdog_interval_us
n = Notifier.from_env()
interval = watchdog_interval_us()
ok = [n.ready(f"watchdog every {interval} us"), n.watchdog(), n.watchdog()]
n.close()
raise SystemExit(0 if all(ok) and n.errors == 0 else 1)
"""


@pytest.mark.slow  # a subprocess
@pytest.mark.parametrize("abstract", [False, True], ids=["path", "abstract"])
def test_a_separate_process_notifies(sock_dir: Path, abstract: bool) -> None:
    address = f"@tcm-companion-test-{uuid.uuid4().hex}" if abstract else str(sock_dir / "nfy")
    r = Receiver(address)
    try:
        env = dict(os.environ, NOTIFY_SOCKET=address, WATCHDOG_USEC="5000000")
        env.pop("WATCHDOG_PID", None)
        proc = subprocess.Popen([sys.executable, "-c", CHILD], env=env, cwd=ROOT)
        got = [r.recv_with_pid() for _ in range(3)]
        assert proc.wait(timeout=60) == 0
        assert [data for data, _ in got] == [
            b"READY=1\nSTATUS=watchdog every 2500000 us",
            b"WATCHDOG=1",
            b"WATCHDOG=1",
        ]
        # the kernel stamps the sender's PID: the main PID NotifyAccess=main accepts
        assert {pid for _, pid in got} == {proc.pid}
    finally:
        r.close()
