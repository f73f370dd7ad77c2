"""A real pty pair made by socat, for tests and benchmarks of the serial path.

``socat -d -d pty,raw,echo=0,b921600,link=A pty,raw,echo=0,b921600,link=B`` joins two
pseudo-terminals back to back; socat reports their ``/dev/pts/N`` paths on stderr. The
``link=`` symlinks keep stable names across :meth:`SocatPtyPair.restart`, so a
reconnecting serial transport can find the "device" again after it went away.

Note that a pty ignores the baud rate: bytes cross at memory speed. On a real UART at
921600 baud (8N1, 10 bits a byte) each byte adds ~10.9 µs of wire time.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from types import TracebackType
from typing import Self

_PTY_LINE = re.compile(r"PTY is (\S+)")
_READY_LINE = "starting data transfer loop"


class SocatError(RuntimeError):
    pass


def socat_available() -> bool:
    return shutil.which("socat") is not None


class SocatPtyPair:
    """Two connected ptys; use as a context manager. ``links`` are the stable names."""

    def __init__(self, baud: int = 921600, start_timeout_s: float = 5.0) -> None:
        self.baud = baud
        self.start_timeout_s = start_timeout_s
        self._dir = Path(tempfile.mkdtemp(prefix="tcm-pty-"))
        self.links = (str(self._dir / "a"), str(self._dir / "b"))
        self.paths: tuple[str, str] = ("", "")
        self._proc: subprocess.Popen[bytes] | None = None
        self._log = self._dir / "socat.log"

    def urls(self, baud: int | None = None) -> tuple[str, str]:
        """``serial:`` URLs of the two ends (by their stable links)."""
        b = baud or self.baud
        return f"serial:{self.links[0]}:{b}", f"serial:{self.links[1]}:{b}"

    def start(self) -> None:
        exe = shutil.which("socat")
        if exe is None:
            raise SocatError("socat is not installed (apt-get install socat)")
        if self._proc is not None:
            raise SocatError("already running")
        for link in self.links:  # left behind if an earlier socat was killed hard
            Path(link).unlink(missing_ok=True)
        opts = f"pty,raw,echo=0,b{self.baud}"
        # stderr goes to a file: a pipe nobody drains could block socat.
        with open(self._log, "wb") as log:
            self._proc = subprocess.Popen(
                [exe, "-d", "-d", f"{opts},link={self.links[0]}", f"{opts},link={self.links[1]}"],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=log,
            )
        deadline = time.monotonic() + self.start_timeout_s
        while True:
            text = self._log.read_text(errors="replace")
            paths = _PTY_LINE.findall(text)
            if len(paths) >= 2 and _READY_LINE in text:
                self.paths = (paths[0], paths[1])
                break
            if self._proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise SocatError(f"socat did not start a pty pair:\n{text}")
            time.sleep(0.005)
        for link, path in zip(self.links, self.paths, strict=True):
            if os.path.realpath(link) != os.path.realpath(path):
                self.stop()
                raise SocatError(f"socat link {link} does not point at {path}")

    def stop(self) -> None:
        """End socat: both ptys hang up (their readers see the device go away)."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        proc.terminate()
        try:
            proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()

    def restart(self) -> None:
        self.stop()
        self.start()

    def close(self) -> None:
        self.stop()
        shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
