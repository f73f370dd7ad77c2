"""The ArduCopter SITL binary as a process: finding it, claiming an instance, starting and stopping it.

ArduPilot's real ArduCopter SITL (a flight controller nobody here wrote; the build:
``../shared/ardupilot-sitl/README.md``) is driven by :class:`~.ardupilot_vehicle.ArduPilotSitl`;
this module is the part that owns the process. What :meth:`ArduPilotProcess.spawn` does:

1. Picks a free instance N (``-I N``: tcp 5760+10N SERIAL0, 5762+10N SERIAL1, 5763+10N
   SERIAL2): holds ``/tmp/tcm-ardupilot-sitl-N.lock`` (``flock``, exclusive, for the
   instance's lifetime, so two processes or pytest-xdist workers never share one) and checks
   that the ports of N can be bound. Scanning starts at ``first_instance`` (default 20, or
   ``$TCM_ARDUPILOT_FIRST_INSTANCE``) and goes up.
2. Makes a working directory (its state: ``eeprom.bin``, ``scripts/``, ``logs/``), copies the
   Lua scripts into ``scripts/``, writes ``extra.parm`` with the caller's parameters and
   starts the binary by absolute path (a MAVLink reboot ``execv()``\\ s ``argv[0]``) with
   ``--model + --speedup 10 --defaults copter.parm,extra.parm -I N --home ... -w``. A
   comma-separated ``--defaults`` list works in this build (the console says ``Loaded
   defaults from copter.parm,extra.parm``; the later file wins). Console output goes to
   ``arducopter.log`` in the working directory.

The binary then waits for a client on SERIAL0 before it boots (the ground station of
:class:`~.ardupilot_vehicle.ArduPilotSitl`).

Hygiene: :meth:`ArduPilotProcess.stop` (SIGTERM, wait, SIGKILL) runs on ``__exit__``, at
interpreter exit (``atexit``) and on a failed start; when started from the main thread the
child also gets SIGTERM from the kernel if this process dies (``PR_SET_PDEATHSIG``, which
survives the firmware's reboot ``execv``).
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import errno
import fcntl
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from .errors import SitlError

__all__ = [
    "DEFAULT_HOME",
    "ENV_BINARY",
    "ENV_DEFAULTS",
    "ENV_FIRST_INSTANCE",
    "ArduPilotProcess",
    "find_binary",
    "find_defaults",
    "serial_port",
    "skip_reason",
]

ENV_BINARY = "TCM_ARDUPILOT_SITL"
ENV_DEFAULTS = "TCM_ARDUPILOT_DEFAULTS"
ENV_FIRST_INSTANCE = "TCM_ARDUPILOT_FIRST_INSTANCE"

#: tcm_companion/sitl/ardupilot_process.py -> the repository root
REPO_ROOT = Path(__file__).resolve().parents[2]
_SHARED_SITL = REPO_ROOT.parent / "shared" / "ardupilot-sitl"

#: ArduPilot's SITL test site (CMAC, Canberra): lat_deg, lon_deg, alt_m AMSL, heading_deg
DEFAULT_HOME: tuple[float, float, float, float] = (-35.363261, 149.165230, 584.0, 353.0)

#: SERIALn -> tcp port offset for instance 0 (``-I N`` adds 10 N)
_SERIAL_PORT_BASE = {0: 5760, 1: 5762, 2: 5763}
_DEFAULT_FIRST_INSTANCE = 20
_LOCK_DIR = Path("/tmp")


# ---------------------------------------------------------------------------------------------
# Finding the binary


def find_binary() -> Path | None:
    """The ArduCopter SITL binary: ``$TCM_ARDUPILOT_SITL``, else ``../shared/ardupilot-sitl/bin/
    arducopter`` next to this repository; None if that file does not exist."""
    env = os.environ.get(ENV_BINARY)
    path = Path(env) if env else _SHARED_SITL / "bin" / "arducopter"
    path = path.expanduser().resolve()
    return path if path.is_file() and os.access(path, os.X_OK) else None


def find_defaults(binary: Path | None = None) -> Path | None:
    """The SITL defaults file: ``$TCM_ARDUPILOT_DEFAULTS``, else ``params/copter.parm`` next to the
    binary's ``bin/``; None if absent."""
    env = os.environ.get(ENV_DEFAULTS)
    if env:
        path = Path(env).expanduser().resolve()
    else:
        binary = binary or find_binary()
        if binary is None:
            return None
        path = binary.parent.parent / "params" / "copter.parm"
    return path if path.is_file() else None


def skip_reason() -> str:
    """A one-line reason to skip tests that need the binary ('' when it is present)."""
    binary = find_binary()
    if binary is None:
        if os.environ.get(ENV_BINARY):
            return f"ArduCopter SITL not found: ${ENV_BINARY}={os.environ[ENV_BINARY]} is no binary"
        return (
            f"ArduCopter SITL not found: set ${ENV_BINARY} to an arducopter SITL binary "
            f"(looked for {_SHARED_SITL / 'bin' / 'arducopter'})"
        )
    if find_defaults(binary) is None:
        return f"ArduCopter SITL defaults not found: set ${ENV_DEFAULTS} (copter.parm)"
    return ""


def serial_port(instance: int, serial: int) -> int:
    """The tcp port of SERIAL0/1/2 of SITL instance ``instance`` (``-I``)."""
    return _SERIAL_PORT_BASE[serial] + 10 * instance


# ---------------------------------------------------------------------------------------------
# Instance allocation


def _ports_free(instance: int) -> bool:
    """Whether the SITL's tcp ports (SERIAL0-2) and udp ports (RC in 5501+10N, irlock
    9005+10N) of ``instance`` can be bound (SO_REUSEADDR like the SITL's own listeners)."""
    tcp = [serial_port(instance, s) for s in (0, 1, 2)]
    udp = [5501 + 10 * instance, 9005 + 10 * instance]
    for kind, ports in ((socket.SOCK_STREAM, tcp), (socket.SOCK_DGRAM, udp)):
        for port in ports:
            with socket.socket(socket.AF_INET, kind) as sock:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                try:
                    sock.bind(("0.0.0.0", port))
                except OSError:
                    return False
    return True


def _claim_instance(first: int, count: int) -> tuple[int, int]:
    """(instance, lock fd): the first instance >= ``first`` whose lock file we can hold and
    whose ports are free."""
    for instance in range(first, first + count):
        path = _LOCK_DIR / f"tcm-ardupilot-sitl-{instance}.lock"
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                continue
            raise
        if _ports_free(instance):
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
            return instance, fd
        os.close(fd)  # releases the lock
    raise SitlError(f"no free ArduPilot SITL instance in {first}..{first + count - 1}")


def _pdeathsig_preexec() -> Callable[[], None] | None:
    """A preexec_fn that asks the kernel to SIGTERM the child when its parent thread dies."""
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    pr_set_pdeathsig = 1

    def preexec() -> None:
        prctl(pr_set_pdeathsig, signal.SIGTERM)

    return preexec


# ---------------------------------------------------------------------------------------------
# The process


class ArduPilotProcess:
    """One ArduCopter SITL process on an instance of its own (see the module docstring).

    ``params`` go into an extra defaults file (applied at every boot, after ``copter.parm``;
    ``-w`` wipes ``eeprom.bin`` at start). ``scripts`` (paths) and ``script_texts`` (file name
    -> Lua source) go into ``scripts/``. ``workdir``: use (and keep) this directory instead of
    a temporary one (removed at :meth:`stop` unless ``keep_workdir``). ``speedup``: the
    simulation's speed-up at boot. ``home``: lat_deg, lon_deg, alt_m AMSL, heading_deg.
    ``die_with_parent``: PR_SET_PDEATHSIG (default: when started from the main thread; the
    kernel signals when the *thread* that started it ends).
    """

    def __init__(
        self,
        *,
        params: Mapping[str, float] | None = None,
        scripts: Iterable[str | Path] = (),
        script_texts: Mapping[str, str] | None = None,
        binary: str | Path | None = None,
        defaults: str | Path | None = None,
        first_instance: int | None = None,
        instance_count: int = 80,
        speedup: float = 10.0,
        home: Sequence[float] = DEFAULT_HOME,
        model: str = "+",
        workdir: str | Path | None = None,
        keep_workdir: bool = False,
        die_with_parent: bool | None = None,
    ) -> None:
        found = Path(binary) if binary is not None else find_binary()
        if found is None:
            raise SitlError(skip_reason())
        self.binary = found.expanduser().resolve()
        found_defaults = Path(defaults) if defaults is not None else find_defaults(self.binary)
        if found_defaults is None:
            raise SitlError(skip_reason() or "no defaults file")
        self.defaults = found_defaults.expanduser().resolve()
        self.params = dict(params or {})
        self.scripts = [Path(s) for s in scripts]
        self.script_texts = dict(script_texts or {})
        if first_instance is None:
            first_instance = int(os.environ.get(ENV_FIRST_INSTANCE, _DEFAULT_FIRST_INSTANCE))
        self.first_instance = first_instance
        self.instance_count = instance_count
        self.speedup = speedup
        self.home = tuple(home)
        self.model = model
        self._workdir_arg = Path(workdir) if workdir is not None else None
        self.keep_workdir = keep_workdir or workdir is not None
        self.die_with_parent = die_with_parent
        self.instance: int | None = None
        self.workdir: Path | None = None
        self.process: subprocess.Popen[bytes] | None = None
        self._lock_fd: int | None = None
        self._log_file: Any = None

    def spawn(self) -> None:
        """Claim an instance, make the working directory and start the binary (steps 1-2
        of the module docstring); :meth:`stop` undoes it."""
        if self.process is not None:
            raise SitlError("already started")
        atexit.register(self.stop)
        self.instance, self._lock_fd = _claim_instance(self.first_instance, self.instance_count)
        prefix = f"tcm-ardupilot-sitl-{self.instance}-"
        # working directories of this instance left by a killed process (we hold its lock now)
        for stale in Path(tempfile.gettempdir()).glob(prefix + "*"):
            if stale.is_dir() and not (stale / ".keep").exists():
                shutil.rmtree(stale, ignore_errors=True)
        if self._workdir_arg is not None:
            self.workdir = self._workdir_arg.resolve()
            self.workdir.mkdir(parents=True, exist_ok=True)
        else:
            self.workdir = Path(tempfile.mkdtemp(prefix=prefix))
            if self.keep_workdir:
                (self.workdir / ".keep").touch()
        scripts_dir = self.workdir / "scripts"
        scripts_dir.mkdir(exist_ok=True)
        for script in self.scripts:
            shutil.copy(script, scripts_dir / script.name)
        for name, text in self.script_texts.items():
            (scripts_dir / name).write_text(text)
        extra = self.workdir / "extra.parm"
        extra.write_text("".join(f"{k} {v:.9g}\n" for k, v in self.params.items()))
        argv = [
            str(self.binary),
            "--model",
            self.model,
            "--speedup",
            f"{self.speedup:g}",
            "--defaults",
            f"{self.defaults},{extra}",
            "-I",
            str(self.instance),
            "--home",
            ",".join(f"{v:.9g}" for v in self.home),
            "-w",
        ]
        die = self.die_with_parent
        if die is None:
            die = threading.current_thread() is threading.main_thread()
        self._log_file = open(self.console_log_path, "wb")
        self.process = subprocess.Popen(
            argv,
            cwd=self.workdir,
            stdin=subprocess.DEVNULL,
            stdout=self._log_file,
            stderr=subprocess.STDOUT,
            preexec_fn=_pdeathsig_preexec() if die else None,
        )

    def check_alive(self) -> bool:
        """Raise if the process has exited; False otherwise (so it can sit in an ``or``)."""
        if self.process is not None and self.process.poll() is not None:
            raise SitlError(f"arducopter exited with status {self.process.returncode}")
        return False

    def stop(self) -> None:
        """SIGTERM the process (SIGKILL after 5 s), release the instance, remove the working
        directory (unless kept). Idempotent; also runs at interpreter exit."""
        atexit.unregister(self.stop)
        proc, self.process = self.process, None
        if proc is not None and proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    proc.kill()
                proc.wait(timeout=5.0)
        if self._log_file is not None:
            self._log_file.close()
            self._log_file = None
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None
        if self.workdir is not None and not self.keep_workdir:
            shutil.rmtree(self.workdir, ignore_errors=True)

    # -- where things are --------------------------------------------------------------------

    @property
    def pid(self) -> int | None:
        return self.process.pid if self.process is not None else None

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    @property
    def console_log_path(self) -> Path:
        """The binary's stdout+stderr."""
        if self.workdir is None:
            raise SitlError("not started")
        return self.workdir / "arducopter.log"

    def console_tail(self, lines: int = 40) -> str:
        try:
            text = self.console_log_path.read_text(errors="replace")
        except (OSError, SitlError):
            return ""
        return "\n".join(text.splitlines()[-lines:])

    def serial_port(self, serial: int) -> int:
        """The tcp port of SERIAL0/1/2 of this instance."""
        if self.instance is None:
            raise SitlError("not started")
        return serial_port(self.instance, serial)

    def serial_url(self, serial: int) -> str:
        """``tcp:127.0.0.1:PORT`` of SERIAL0/1/2 (our daemon: SERIAL1; a camera: SERIAL2)."""
        return f"tcp:127.0.0.1:{self.serial_port(serial)}"

    @property
    def serial1_url(self) -> str:
        return self.serial_url(1)

    @property
    def serial2_url(self) -> str:
        return self.serial_url(2)
