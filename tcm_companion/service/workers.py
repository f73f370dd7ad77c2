"""The daemon's worker processes: one per camera, each running that camera's pipeline.

A Python process runs one thread of Python at a time (the GIL), and one camera's
pipeline takes about a third of a core at 25 Hz: several cameras need several processes.
With ``[daemon] workers`` (:func:`workers_wanted`), the daemon puts the
:class:`~.companion.Companion` in its offloaded mode
(:meth:`~.companion.Companion.offload_steps`) and hands each
:class:`~.outputs.StepRequested` to a :class:`WorkerPool`:

- **What crosses the boundary.** The frame goes through ``multiprocessing.shared_memory``:
  one block per camera, sized for its image, written by the daemon, copied out by the
  worker (one frame per camera is with its worker at a time, so one block is enough).
  Through the camera's pipe go only the frame's metadata — its capture time and the
  telemetry its pipeline reads, computed by the Companion from the one telemetry buffer
  (``R_ned_from_body``, ``pos_ned_m``, ``vel_ned_mps``) — and, when the Companion has
  rebuilt the pipeline (a parameter change, errors), the new
  :class:`~tcm_companion.core.pipeline.PipelineConfig`. Back comes the pickled
  :class:`~tcm_companion.core.pipeline.FrameResult` (or the exception's name). One clock:
  every time is the daemon's; the worker reads none (its stage timings aside).
- **Processes.** Started with the ``spawn`` context (a fresh interpreter: never ``fork``
  a threaded uvloop process), running :func:`.worker_process.worker_main` (a module that
  imports the core only: a worker's memory is the pipeline's), named ``tcm-w-<camera>`` (``/proc/<pid>/comm``) so that
  ``top`` and ``bench --daemon`` can tell them apart. They ignore SIGINT and SIGTERM and
  end when their pipe closes (the daemon stopping, or dying): no orphans.
- **Failures.** A worker that dies (its pipe reads EOF) is reported as a
  :class:`WorkerDied` (the daemon tells the Companion: a counted fault, that camera's
  objects ``unknown``) and started again after a backoff (0.5 s, doubling to 10 s; back to
  0.5 s after a worker ran 30 s). A worker on one frame for :data:`STEP_TIMEOUT_US` is
  killed (:meth:`WorkerPool.kill_stuck`): the same death. An exception in the pipeline
  is not a death: it comes back as a :class:`StepDone` without a result.
- **Shared memory** is unlinked by :meth:`WorkerPool.stop` (the daemon's exit, SIGTERM
  included); if the daemon is killed outright, multiprocessing's resource tracker (a
  process of its own) unlinks it.

The pool does no waiting of its own: the daemon watches each worker's pipe (``fileno``)
with ``loop.add_reader`` through a :class:`PipeWatcher` and calls :meth:`WorkerPool.receive`
when one is readable; the tests wait with :meth:`WorkerPool.wait`. Times are µs on the
daemon's monotonic clock, passed in.
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import multiprocessing
import multiprocessing.connection
import os
import secrets
import signal
import sys
import weakref
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from multiprocessing import shared_memory
from multiprocessing.process import BaseProcess
from typing import Any, Literal, Protocol

import numpy as np

from ..core.camera import CameraModel
from ..core.pipeline import FrameResult, PipelineConfig
from .outputs import StepRequested
from .worker_process import worker_main

log = logging.getLogger(__name__)

#: The shared memory blocks are ``/dev/shm/tcm-<daemon pid>-<camera id>-<random>``.
SHM_PREFIX = "tcm-"
#: The multiprocessing start method: a fresh interpreter per worker.
CONTEXT: Literal["spawn", "forkserver"] = "spawn"
#: A dead worker is started again after this long, doubling up to the maximum ...
BACKOFF_FIRST_US = 500_000
BACKOFF_MAX_US = 10_000_000
#: ... and the backoff starts over once a worker has run this long.
BACKOFF_RESET_US = 30_000_000
#: A worker still on one frame after this long is stuck: it is killed (and so restarted).
STEP_TIMEOUT_US = 5_000_000


def workers_wanted(setting: int | str, n_cameras: int, n_cpus: int | None = None) -> bool:
    """Whether the daemon runs its pipelines in worker processes: ``[daemon] workers``
    ``0`` never, ``1`` always, ``"auto"`` with two cameras or more and two CPUs or more
    in the process's affinity mask (``n_cpus``; default: this process's)."""
    if setting == 0:
        return False
    if setting == 1:
        return True
    if setting != "auto":
        raise ValueError(f'workers must be "auto", 0 or 1, got {setting!r}')
    cpus = len(os.sched_getaffinity(0)) if n_cpus is None else n_cpus
    return n_cameras >= 2 and cpus >= 2


@dataclass(frozen=True)
class StepDone:
    """Camera ``camera_id``'s worker finished its frame: ``result``, or None and the
    exception's name (``error``; ``detail``: its traceback, for the log)."""

    camera_id: int
    result: FrameResult | None
    error: str = ""
    detail: str = ""


@dataclass(frozen=True)
class WorkerReady:
    """Camera ``camera_id``'s worker has built its pipeline and takes frames."""

    camera_id: int
    pid: int


@dataclass(frozen=True)
class WorkerDied:
    """Camera ``camera_id``'s worker is gone (``why``: its exit code or signal)."""

    camera_id: int
    why: str


WorkerEvent = StepDone | WorkerReady | WorkerDied


class PipeWatcher(Protocol):
    """Who waits on the workers' pipes (the daemon: ``loop.add_reader``)."""

    def watch(self, fd: int, camera_id: int) -> None: ...
    def unwatch(self, fd: int) -> None: ...


def _stop_at_exit(ref: weakref.ref[WorkerPool]) -> None:
    pool = ref()
    if pool is not None:
        pool.stop()


@contextlib.contextmanager
def _main_not_rerun() -> Iterator[None]:
    """While a worker is spawned: a ``__main__`` run from a file (the ``tcm-companion``
    script, pytest) is not run again in it. ``spawn`` runs the parent's main script in
    the child (as ``__mp_main__``) unless it was started as a module (``python -m``);
    the script imports the whole CLI, doubling the worker's memory, and the worker needs
    none of it."""
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if main is None or path is None or getattr(main, "__spec__", None) is not None:
        yield
        return
    del main.__file__
    try:
        yield
    finally:
        main.__file__ = path


@dataclass
class _Worker:
    """The daemon's side of one worker."""

    camera_id: int
    name: str
    model: CameraModel
    shm: shared_memory.SharedMemory
    shape: tuple[int, ...]
    config: PipelineConfig
    generation: int = 0  # of the config the worker has (or is started with)
    process: BaseProcess | None = None
    conn: multiprocessing.connection.Connection | None = None
    up: bool = False  # ready and not dead
    busy: bool = False
    busy_since_us: int = 0  # when it was given the frame it is on
    started_mono_us: int = 0
    backoff_us: int = BACKOFF_FIRST_US
    restart_at_us: int | None = None


@dataclass
class WorkerStats:
    """What the pool did: workers started (restarts included), deaths, frames passed
    through the pipe instead of shared memory (a frame not of the camera's size)."""

    started: int = 0
    restarts: int = 0
    deaths: dict[str, int] = field(default_factory=dict)  # camera -> count
    frames_by_pipe: int = 0


class WorkerPool:
    """One worker process per camera (module docstring). ``cameras``: each camera's
    model; ``names``: their names (the processes are named after them)."""

    def __init__(
        self,
        cameras: Sequence[CameraModel],
        names: Sequence[str],
        pipeline_config: PipelineConfig,
        *,
        detector_model: bytes | None = None,
        opencv_threads: int = 1,
        watcher: PipeWatcher | None = None,
        context: Literal["spawn", "forkserver"] = CONTEXT,
    ) -> None:
        if len(names) != len(cameras):
            raise ValueError(f"{len(cameras)} camera(s) but {len(names)} name(s)")
        self._ctx: Any = multiprocessing.get_context(context)
        self._detector_model = detector_model
        self._opencv_threads = opencv_threads
        self.watcher = watcher
        self.stats = WorkerStats()
        self._workers: list[_Worker] = []
        self._stopped = False
        # A process that exits without stop() (an exception in a tool) would otherwise
        # hang in multiprocessing's own exit handler, joining workers that ignore SIGTERM
        # and wait for their pipes to close; registered after it, this runs first.
        atexit.register(_stop_at_exit, weakref.ref(self))
        try:
            for cid, (model, name) in enumerate(zip(cameras, names, strict=True)):
                shape = (model.height, model.width, 3)
                shm = shared_memory.SharedMemory(
                    name=f"{SHM_PREFIX}{os.getpid()}-{cid}-{secrets.token_hex(4)}",
                    create=True,
                    size=int(np.prod(shape)),
                )
                self._workers.append(_Worker(cid, name, model, shm, shape, pipeline_config))
        except BaseException:
            self._unlink()
            raise

    @property
    def shm_names(self) -> list[str]:
        """The shared memory blocks' names (``/dev/shm/<name>`` on Linux)."""
        return [w.shm.name for w in self._workers]

    def pids(self) -> dict[str, int]:
        """Each running worker's process id, by camera name."""
        return {
            w.name: w.process.pid
            for w in self._workers
            if w.process is not None and w.process.pid is not None and w.process.is_alive()
        }

    def fileno(self, camera_id: int) -> int:
        conn = self._workers[camera_id].conn
        if conn is None:
            raise ValueError(f"camera {camera_id}'s worker is not running")
        return conn.fileno()

    # -- life ----------------------------------------------------------------------------------
    def start(self, now_mono_us: int) -> None:
        """Start every worker (each reports :class:`WorkerReady` when it takes frames)."""
        for w in self._workers:
            self._start(w, now_mono_us)

    def _start(self, w: _Worker, now_mono_us: int) -> None:
        ours, theirs = self._ctx.Pipe(duplex=True)
        proc = self._ctx.Process(
            target=worker_main,
            name=f"tcm-worker-{w.name}",
            args=(
                w.camera_id,
                f"tcm-w-{w.name}",
                w.model,
                w.config,
                self._detector_model,
                w.shm.name,
                w.shape,
                theirs,
                self._opencv_threads,
            ),
            daemon=True,
        )
        with _main_not_rerun():
            proc.start()
        theirs.close()  # the worker's end: only the worker holds it (EOF when it dies)
        w.process, w.conn = proc, ours
        w.up = w.busy = False
        w.started_mono_us = now_mono_us
        w.restart_at_us = None
        self.stats.started += 1
        if self.watcher is not None:
            self.watcher.watch(ours.fileno(), w.camera_id)

    def _close_conn(self, w: _Worker) -> None:
        if w.conn is None:
            return
        if self.watcher is not None:
            self.watcher.unwatch(w.conn.fileno())
        w.conn.close()
        w.conn = None

    def next_restart_us(self) -> int | None:
        """When :meth:`restart_due` has a dead worker to start again (None: none)."""
        times = [w.restart_at_us for w in self._workers if w.restart_at_us is not None]
        return min(times) if times else None

    def restart_due(self, now_mono_us: int) -> list[int]:
        """Start again every dead worker whose backoff is over; their camera ids."""
        if self._stopped:
            return []
        restarted = []
        for w in self._workers:
            if w.restart_at_us is not None and w.restart_at_us <= now_mono_us:
                self._start(w, now_mono_us)
                self.stats.restarts += 1
                restarted.append(w.camera_id)
        return restarted

    def stop(self, timeout_s: float = 3.0) -> None:
        """Stop every worker (``stop``, then the pipe closed; killed if it lingers) and
        unlink the shared memory. Idempotent."""
        if self._stopped:
            return
        self._stopped = True
        for w in self._workers:
            if w.conn is not None:
                with contextlib.suppress(OSError, ValueError):
                    w.conn.send(("stop",))
            self._close_conn(w)
        for w in self._workers:
            if w.process is None:
                continue
            w.process.join(timeout_s)
            if w.process.is_alive():
                w.process.kill()
                w.process.join(timeout_s)
            w.process.close()
            w.process = None
            w.up = False
        self._unlink()

    def _unlink(self) -> None:
        for w in self._workers:
            with contextlib.suppress(FileNotFoundError):
                w.shm.close()
                w.shm.unlink()

    # -- frames --------------------------------------------------------------------------------
    def idle(self, camera_id: int) -> bool:
        """Whether camera ``camera_id``'s worker takes a frame now."""
        w = self._workers[camera_id]
        return w.up and not w.busy

    def kill_stuck(self, now_mono_us: int, timeout_us: int = STEP_TIMEOUT_US) -> list[int]:
        """Kill every worker that has been on one frame for ``timeout_us`` or more (a
        pipeline that hangs would otherwise hold its camera forever): its death comes
        through :meth:`receive` as any other, and it is restarted. Their camera ids."""
        killed = []
        for w in self._workers:
            if w.busy and w.process is not None and now_mono_us - w.busy_since_us >= timeout_us:
                log.error("worker %s: stuck on a frame for %.1f s, killed", w.name,
                          (now_mono_us - w.busy_since_us) / 1e6)  # fmt: skip
                w.process.kill()
                w.busy = False  # killed once; its EOF follows
                killed.append(w.camera_id)
        return killed

    def submit(self, req: StepRequested) -> bool:
        """Hand ``req``'s frame to its camera's worker; False if it cannot take it (not
        ready, busy, or its pipe broke: its death is reported by :meth:`receive`)."""
        w = self._workers[req.camera_id]
        if not w.up or w.busy or w.conn is None:
            return False
        image: np.ndarray | None = req.image
        try:
            if req.generation != w.generation:
                w.conn.send(("config", req.pipeline_config))
                w.config, w.generation = req.pipeline_config, req.generation
            if req.image.shape == w.shape and req.image.dtype == np.uint8:
                np.copyto(np.ndarray(w.shape, dtype=np.uint8, buffer=w.shm.buf), req.image)
                image = None
            else:  # a frame not of the camera's size: the pipeline counts it (bad frame)
                self.stats.frames_by_pipe += 1
            w.conn.send(
                ("step", req.capture_mono_us, req.R_ned_from_body, req.pos_ned_m,
                 req.vel_ned_mps, image)
            )  # fmt: skip
        except (OSError, ValueError):
            return False
        w.busy = True
        w.busy_since_us = req.requested_mono_us
        return True

    def receive(self, camera_id: int, now_mono_us: int) -> list[WorkerEvent]:
        """What camera ``camera_id``'s worker has said (call when its pipe is readable)."""
        w = self._workers[camera_id]
        events: list[WorkerEvent] = []
        while w.conn is not None:
            try:
                if not w.conn.poll(0):
                    break
                msg: Any = w.conn.recv()
            except (EOFError, OSError):
                events.append(self._died(w, now_mono_us))
                break
            if msg[0] == "ready":
                w.up = True
                events.append(WorkerReady(camera_id, int(msg[1])))
            elif msg[0] == "done":
                w.busy = False
                events.append(StepDone(camera_id, msg[1], msg[2], msg[3]))
        return events

    def wait(self, camera_id: int, timeout_s: float, now_mono_us: int) -> list[WorkerEvent]:
        """Wait up to ``timeout_s`` for camera ``camera_id``'s worker to say something
        (tests and tools; the daemon uses ``loop.add_reader``)."""
        conn = self._workers[camera_id].conn
        if conn is None:
            return []
        multiprocessing.connection.wait([conn], timeout_s)
        return self.receive(camera_id, now_mono_us)

    def _died(self, w: _Worker, now_mono_us: int) -> WorkerDied:
        self._close_conn(w)
        why = "ended"
        if w.process is not None:
            w.process.join(1.0)
            code = w.process.exitcode
            if code is not None and code < 0:
                why = f"killed by {signal.Signals(-code).name}"
            elif code is not None:
                why = f"exit {code}"
            w.process.close()
            w.process = None
        w.up = w.busy = False
        self.stats.deaths[w.name] = self.stats.deaths.get(w.name, 0) + 1
        if now_mono_us - w.started_mono_us >= BACKOFF_RESET_US:
            w.backoff_us = BACKOFF_FIRST_US
        if not self._stopped:
            w.restart_at_us = now_mono_us + w.backoff_us
            log.warning("worker %s: %s; restarting in %.1f s", w.name, why, w.backoff_us / 1e6)
            w.backoff_us = min(2 * w.backoff_us, BACKOFF_MAX_US)
        return WorkerDied(w.camera_id, why)
