"""The field flight log: MCAP files written off the hot path, crash-safe, rotated.

Writing
-------
:class:`FlightLogWriter` takes camera frames, their annotations, MAVLink bytes and JSON
documents from the daemon's asyncio thread through non-blocking ``log_*`` calls into one
bounded queue (``[logging] queue_items``). A full queue costs the item (counted), never a
wait. ONE writer thread does everything else: JPEG/PNG encoding, JSON and protobuf
serialisation, MCAP framing, compression and file IO. It is woken by each frame, by a
half-full queue and by its own timers, not by every item: the MAVLink bytes and results
between two frames are written together (a wake-up per item cost the daemon's loop a
futex call and a GIL hand-over each; docs/decisions.md §8.3). Its flush timer still runs,
so the crash-safety bound below holds without frames too.

*Ownership.* ``log_frame`` keeps a reference to the image array, it does not copy it: the
caller must not modify a frame after handing it over (the daemon never does: a captured
frame is immutable). The same holds for the ``circles`` list and the JSON ``doc``. The
queue therefore holds at most ``queue_items`` frames: at 360×220 BGR that is at most
``queue_items × 238 kB`` (61 MB for 256) while the disk stalls.

*Time.* Every ``t_us`` is the companion's monotonic clock in µs. A message's MCAP
``log_time`` is wall-clock ns, ``t_us·1000 + wall_minus_mono_ns`` (the offset is measured
once, at construction, and stored in the metadata record), and its ``publish_time`` is
the monotonic time in ns, ``t_us·1000``: replay runs on exactly the daemon's clock, viewers
(Foxglove) show wall time.

*Crash safety.* Chunks are ``chunk_size_bytes`` (256 KiB), and the writer thread ends the
open chunk and flushes the file to the OS at least every ``flush_interval_s`` (mcap's
``Writer.flush()``). A SIGKILL (or a crash of the interpreter) then loses at most that
much: the non-seeking reader used by :func:`read_log` reads every complete chunk of a
file that has no summary or footer. (mcap's defaults, 1 MiB chunks and no flushing, and
the seeking reader, which needs the footer, recover nothing from a killed file;
``tests/test_flightlog.py`` shows both.) Power loss is a different matter: only the file
close on rotation/stop calls ``fsync``.

*Files.* ``tcm-YYYYmmdd-HHMMSS-FLIGHTID-NNN.mcap`` (UTC wall time of
:meth:`FlightLogWriter.start`, the flight's id, part counter ``NNN``): a new part when the
current one exceeds ``rotate_size_mb`` (MB = 10⁶ bytes) or ``rotate_interval_s``; every
part starts with the ``"tcm-companion"`` metadata record (with ``flight_id`` and the
part's number ``log_part``), and a closed part has the full MCAP summary (index,
statistics), so each part opens on its own in Foxglove or ``mcap info``. The flight id
(12 hex digits) is random unless given (a deterministic run derives its own:
:mod:`tcm_companion.flight_log_setup`): a reader joins the parts of one flight, never two
flights that share a directory (:func:`~.reader.select_flight`).

*Disk.* Below ``min_free_mb`` of free space (checked at most once a second, in the writer
thread) frames and annotations are dropped (counted); MAVLink and JSON continue. A write
error (ENOSPC, EIO, the directory or file removed) never ends the thread: it is counted,
reported once through ``on_event``, the state becomes ``"fault"`` (items are dropped and
counted) and a new part is tried every ``retry_interval_s`` (after a full disk, once
there is room for a part's start and a chunk). The part that failed stays readable up to
its last chunk that reached the OS; what was counted as logged but had not (the open
chunk) is counted again as dropped: ``dropped_disk`` for a full disk (ENOSPC, EDQUOT),
like the items dropped while it stays full, ``dropped_error`` for other errors. A part
that never got a message out, and a part start that failed, leave no file.

*Events.* ``on_event(severity, text)`` is called from the writer thread: it must be
thread-safe and quick (e.g. ``loop.call_soon_threadsafe``); its exceptions are swallowed.

*Counts.* Every call is counted once, in one :class:`~.stats.FlightLogStats` the writer
keeps under its lock; :attr:`FlightLogWriter.stats` is a copy of it.

The writer's parts, one job each: :mod:`.settings` (``[logging]``, :class:`LoggingConfig`),
:mod:`.stats` (the counts and state), :mod:`.encoding` (JPEG/PNG, protobuf and JSON
payloads, off the hot path), :mod:`.part` (one MCAP file: start, channels, flush,
finish) and :mod:`.disk` (the free-space floor, flushing to the OS); this module is the
thread, the queue, and the parts' naming, rotation and faults.

Topics
------
The table of topics is :mod:`.topics`: ``/camera{N}/image`` and ``/camera{N}/annotations``
(protobuf, Foxglove's schemas, frame_id ``camera{N}``), ``/mavlink/in`` and
``/mavlink/out`` (raw bytes, encoding ``"mavlink"``, no schema), and the JSON documents
``/tcm/...`` (schema encoding ``"jsonschema"``, permissive; :meth:`FlightLogWriter.log_json`
takes any topic).

Reading
-------
:mod:`.reader` (:func:`read_log`, :func:`read_metadata`, :func:`decode_image`,
:func:`decode_json`, :func:`log_files`), re-exported here.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import math
import os
import queue
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any, Literal

import numpy as np

from . import topics
from .disk import MB, FreeSpace
from .encoding import encode_item, metadata_value
from .part import LogPart
from .reader import (
    FLIGHT_ID_RE,
    METADATA_NAME,
    LogRecord,
    decode_image,
    decode_json,
    log_files,
    new_flight_id,
    part_name,
    read_log,
    read_metadata,
)
from .settings import LoggingConfig
from .stats import (
    KIND_ANNOTATIONS,
    KIND_FRAME,
    KIND_JSON,
    KIND_MAVLINK,
    KIND_NAMES,
    STATE_CODES,
    FlightLogStats,
    LogState,
    Outcome,
    lost_outcome,
)
from .topics import ANNOTATIONS_SCHEMA, IMAGE_SCHEMA

__all__ = [
    "ANNOTATIONS_SCHEMA",
    "IMAGE_SCHEMA",
    "LOG_FORMAT",
    "MAVLINK_TOPICS",
    "METADATA_NAME",
    "FlightLogWriter",
    "LogRecord",
    "decode_image",
    "decode_json",
    "log_files",
    "read_log",
    "read_metadata",
]

log = logging.getLogger(__name__)

LOG_FORMAT = "tcm-flightlog/1"
MAVLINK_TOPICS = topics.MAVLINK  # log_mavlink's direction -> topic


# ---------------------------------------------------------------------------------------
# Writer

_STOP = object()
_Item = tuple[Any, ...]


class FlightLogWriter:
    """Writes the flight log from one background thread; see the module docstring.

    ``free_check_interval_s`` (how often free space is looked at) and
    ``retry_interval_s`` (how often a new part is tried while in fault) exist for tests.

    ``deterministic`` (a simulation on its own clock, ``sitl --clock virtual``): the
    file's bytes depend only on what was logged. Chunks end, and parts rotate by time, on
    the records' own time stamps instead of the wall clock's (the same crash-safety
    bound, in the log's time); a producer waits for room instead of dropping; parts are
    named after ``session`` (e.g. the simulation's start time) instead of the wall clock.
    ``flight_id`` (12 hex digits; default random) is the flight's id.
    """

    def __init__(
        self,
        config: LoggingConfig,
        directory: str | Path,
        *,
        wall_minus_mono_ns: int | None = None,
        free_bytes: Callable[[Path], int] | None = None,
        on_event: Callable[[str, str], None] | None = None,
        free_check_interval_s: float = 1.0,
        retry_interval_s: float = 3.0,
        deterministic: bool = False,
        session: str | None = None,
        flight_id: str | None = None,
    ) -> None:
        self.config = config
        self.deterministic = deterministic
        self._session_name = session
        if flight_id is not None and not FLIGHT_ID_RE.match(flight_id):
            raise ValueError(f"flight_id must be 12 hex digits, got {flight_id!r}")
        #: This flight's id: in every part's metadata and file name.
        self.flight_id = flight_id if flight_id is not None else new_flight_id()
        self.directory = Path(directory)
        if wall_minus_mono_ns is None:
            wall_minus_mono_ns = time.time_ns() - time.monotonic_ns()
        self.wall_minus_mono_ns = int(wall_minus_mono_ns)
        self._space = FreeSpace(self.directory, config.min_free_mb, free_bytes)
        self._on_event = on_event
        self._free_check_interval_s = max(float(free_check_interval_s), 1e-3)
        self._retry_interval_s = max(float(retry_interval_s), 1e-3)
        self._rotate_bytes = int(config.rotate_size_mb * MB)

        # A SimpleQueue (put and get in C, no Python-level Condition), bounded by the
        # producers themselves: they check the depth and put under ``_lock``, which they
        # take for the counts anyway, so it never holds more than ``queue_items`` items.
        self._q: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._maxsize = int(config.queue_items)
        # Live, the writer thread sleeps until a frame is queued (25 Hz), the queue is
        # half full, its own timers are due or it is stopped: each wake-up is a futex
        # call in the producer and a GIL hand-over, and the link's bytes and the results
        # (~6 items a frame) ride along with the frames. Deterministic: woken per item
        # (a producer waiting for the counts, wait_drained, must not wait for a frame).
        self._wake = threading.Event()
        self._wake_depth = max(1, self._maxsize // 2)
        self._lock = threading.Lock()
        self._accepting = False
        self._started = False
        self._stopped = False
        self._stop_evt = threading.Event()
        self._drain_deadline = math.inf
        self._thread: threading.Thread | None = None

        # The counts (producer and writer side, under the lock); bytes_written is the
        # closed parts' bytes plus the open part's, kept apart while it grows.
        self._counts = FlightLogStats()
        self._bytes_closed = 0
        self._bytes_current = 0

        # writer-thread state (touched by start() before the thread exists)
        self._metadata: dict[str, str] = {}
        self._session = ""
        self._counter = 0
        self._part: LogPart | None = None  # the open part
        self._file_opened_at = 0.0
        self._fault = False
        self._fault_disk_full = False  # the fault is a full disk (ENOSPC, EDQUOT)
        self._fault_reported = False
        self._encode_error_reported = False
        # Counted as logged but not yet pushed to the OS (the open chunk): a failed write
        # loses them, and they are counted again as dropped (see _enter_fault).
        self._pending = [0, 0]  # frames, other messages
        self._written_pos = 0  # the file position last pushed to the OS
        self._part_flushed = False  # a message of the open part has reached the OS
        self._next_free_check = 0.0
        self._next_retry = 0.0
        # deterministic mode: the records' time of the next flush and of the part's start
        self._next_flush_record_us: int | None = None
        self._part_started_record_us: int | None = None

    # -- lifecycle ---------------------------------------------------------------------

    def start(self, metadata: Mapping[str, Any]) -> None:
        """Create the directory, open the first part, write the metadata record and start
        the writer thread. Never raises for IO: a failure puts the log in ``"fault"`` and
        the thread keeps retrying. Non-string metadata values are stored as JSON."""
        if self._started:
            raise RuntimeError("FlightLogWriter.start() called twice")
        self._started = True
        meta = {str(k): metadata_value(v) for k, v in metadata.items()}
        meta.update(
            flight_id=self.flight_id,
            log_format=LOG_FORMAT,
            wall_minus_mono_ns=str(self.wall_minus_mono_ns),
            image_format=self.config.image_format,
            jpeg_quality=str(self.config.jpeg_quality),
        )
        self._metadata = meta
        if not self.config.enabled:
            return
        self._session = self._session_name or datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
        now = time.monotonic()
        try:
            self._open_file()
        except Exception as e:
            self._enter_fault(e, now)
        self._check_free(now)
        self._next_free_check = now + self._free_check_interval_s
        self._accepting = True
        self._thread = threading.Thread(target=self._run, name="flightlog", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Write what is queued (for at most ~80 % of ``timeout_s``; the rest is dropped and
        counted), close the part with its summary and join the thread. Idempotent."""
        if self._stopped:
            return
        self._stopped = True
        self._accepting = False
        t0 = time.monotonic()
        self._drain_deadline = t0 + 0.8 * max(timeout_s, 0.0)
        self._stop_evt.set()
        self._q.put(_STOP)  # (beyond the bound: it carries no data)
        self._wake.set()
        if self._thread is not None:
            self._thread.join(max(0.0, t0 + timeout_s - time.monotonic()))
            if self._thread.is_alive():
                log.warning("flight log writer did not stop within %.1f s", timeout_s)
                return
        self._discard_queue()  # anything a racing producer put after the thread ended

    # -- producers (asyncio thread): never block, never raise ---------------------------

    def log_frame(self, camera_id: int, t_capture_us: int, image: np.ndarray) -> bool:
        """Queue a camera frame (BGR or grey uint8; a reference is kept, not a copy)."""
        return self._put((KIND_FRAME, camera_id, t_capture_us, image))

    def log_annotations(
        self,
        camera_id: int,
        t_capture_us: int,
        circles: list[tuple[float, float, float, str]],
    ) -> bool:
        """Queue the objects of a frame: ``(u px, v px, radius px, label)`` each; the colour
        follows the label's prefix (moving red, stationary green, else grey)."""
        try:
            item = (
                KIND_ANNOTATIONS,
                camera_id,
                t_capture_us,
                tuple(circles),
            )  # a few tuples: cheap
        except Exception:
            item = (KIND_ANNOTATIONS, camera_id, t_capture_us, ())
        return self._put(item)

    def log_mavlink(self, direction: Literal["in", "out"], t_us: int, data: bytes) -> bool:
        """Queue raw MAVLink bytes as received (``"in"``) or sent (``"out"``). ``bytes``
        are kept as they are; a bytearray or memoryview (a reusable buffer) is copied."""
        if type(data) is not bytes:
            try:
                data = bytes(data)
            except Exception:
                data = b""
        return self._put((KIND_MAVLINK, direction, t_us, data))

    def log_json(self, topic: str, t_us: int, doc: Mapping[str, Any]) -> bool:
        """Queue a JSON document on ``topic`` (e.g. ``/tcm/result``)."""
        return self._put((KIND_JSON, topic, t_us, doc))

    def _put(self, item: _Item) -> bool:
        c = self._counts
        q = self._q
        while True:
            with self._lock:  # spelt out: this is the daemon's path (FlightLogStats.count is not)
                ok = wait = False
                try:
                    depth = q.qsize()
                    if self._accepting and depth < self._maxsize:
                        q.put(item)
                        ok = True
                        if item[0] == KIND_FRAME or depth + 1 >= self._wake_depth:
                            self._wake.set()
                    else:
                        # Deterministic: wait for room (a simulation's time does not pass
                        # meanwhile). Live, a full queue costs the item.
                        wait = self.deterministic and self._accepting and self.alive
                except Exception:  # anything: never raise into the daemon
                    ok = wait = False
                if not wait:
                    if item[0] == KIND_FRAME:
                        if ok:
                            c.frames_queued += 1
                        else:
                            c.frames_dropped_queue += 1
                    elif ok:
                        c.messages_queued += 1
                    else:
                        c.messages_dropped_queue += 1
                    return ok
            time.sleep(0.0005)

    # -- state -------------------------------------------------------------------------

    @property
    def state(self) -> LogState:
        if not self._started or not self.config.enabled or self._stopped:
            return "off"
        if self._fault:
            return "fault"
        if self._space.low:
            return "frames paused (disk)"
        return "recording"

    @property
    def log_state_code(self) -> int:
        """The state as MAVLink ``TCM_LOG_STATE`` (OFF=0, RECORDING=1, FAULT=2)."""
        return STATE_CODES[self.state]

    @property
    def alive(self) -> bool:
        """The writer thread is running (for the daemon's watchdog)."""
        return self._thread is not None and self._thread.is_alive()

    def wait_drained(self, timeout_s: float = 60.0) -> bool:
        """Block until the writer has handled every item queued so far (or ``timeout_s``
        passed, or the thread ended); True when drained. For deterministic counters."""
        deadline = time.monotonic() + timeout_s
        while self.alive and time.monotonic() < deadline:
            with self._lock:
                c = self._counts
                frames = c.frames_logged + c.frames_dropped_disk + c.frames_dropped_error
                msgs = c.messages_logged + c.messages_dropped_disk + c.messages_dropped_error
                if frames >= c.frames_queued and msgs >= c.messages_queued:
                    return True
            time.sleep(0.0005)
        return not self.alive

    @property
    def stats(self) -> FlightLogStats:
        """A snapshot of the counts (see :class:`FlightLogStats`)."""
        with self._lock:
            return replace(
                self._counts,
                bytes_written=self._bytes_closed + self._bytes_current,
                files=list(self._counts.files),
                state=self.state,
                queue_depth=self._q.qsize(),
            )

    # -- writer thread -----------------------------------------------------------------

    def _run(self) -> None:
        try:
            self._loop()
        except BaseException:  # pragma: no cover - a bug; keep the daemon alive
            log.exception("flight log writer thread failed")
            self._enter_fault(RuntimeError("writer thread failed"), time.monotonic())
        finally:
            self._counts.writer_cpu_s = time.thread_time()

    def _loop(self) -> None:
        interval = self.config.flush_interval_s
        next_flush = time.monotonic() + interval
        while not self._stop_evt.is_set():
            wake = min(next_flush, self._next_free_check)
            if self._fault:
                wake = min(wake, self._next_retry)
            timeout = max(0.0, wake - time.monotonic())
            if self.deterministic:
                try:
                    item = self._q.get(timeout=timeout)
                except queue.Empty:
                    item = None
                if item is not None and item is not _STOP:
                    self._process(item)
            else:
                # Woken by a frame (or a half-full queue, or stop), not by every item:
                # what came in meanwhile (the link's bytes, results) is written with it.
                self._wake.wait(timeout)
                self._wake.clear()
                while True:
                    try:
                        item = self._q.get_nowait()
                    except queue.Empty:
                        break
                    if item is not _STOP:
                        self._process(item)
            now = time.monotonic()
            self._housekeeping(now)
            if now >= next_flush:
                if not self.deterministic:  # there the records' time flushes
                    self._flush(now)
                next_flush = now + interval  # either way: a past deadline would spin
            self._counts.writer_cpu_s = time.thread_time()
        while time.monotonic() < self._drain_deadline:
            try:
                item = self._q.get_nowait()
            except queue.Empty:
                break
            if item is not _STOP:
                self._process(item)
        self._discard_queue()
        self._close_file()

    def _discard_queue(self) -> None:
        while True:
            try:
                item = self._q.get_nowait()
            except queue.Empty:
                return
            if item is not _STOP:
                self._count(item[0], "dropped_queue")

    def _count(self, kind: int, outcome: Outcome) -> None:
        with self._lock:
            self._counts.count(kind, outcome)

    def _process(self, item: _Item) -> None:
        if self.deterministic:
            self._record_time_housekeeping(int(item[2]))
        kind = item[0]
        if kind in (KIND_FRAME, KIND_ANNOTATIONS) and self._space.low:
            self._count(kind, "dropped_disk")
            return
        if self._part is None:
            self._count(kind, "dropped_disk" if self._fault_disk_full else "dropped_error")
            return
        try:
            topic, channel_kind, t_us, payload = encode_item(
                item, self.config, self.wall_minus_mono_ns
            )
            publish_ns = int(t_us) * 1000
            log_ns = publish_ns + self.wall_minus_mono_ns
            if not (0 <= publish_ns < 1 << 64 and 0 <= log_ns < 1 << 64):
                raise ValueError(f"time stamp out of range: t_us={t_us}")
        except Exception as e:
            with self._lock:
                self._counts.count(kind, "dropped_error")
                self._counts.encode_errors += 1
            if not self._encode_error_reported:
                self._encode_error_reported = True
                self._event("warning", f"log: cannot encode {KIND_NAMES[kind]}: {e}")
            return
        counted = False
        try:
            self._part.write(topic, channel_kind, log_ns, publish_ns, payload)
            with self._lock:
                self._counts.count(kind, "logged")
            self._pending[kind != KIND_FRAME] += 1
            counted = True  # from here on a failure counts it again, as pending
            pos = self._part.fh.tell()
            if pos != self._written_pos:  # mcap ended a chunk: push it to the OS now, so
                self._part.fh.flush()  # that what is counted as logged is what the file holds
                self._written(pos)
        except Exception as e:
            if not counted:  # the write itself failed
                self._count(kind, lost_outcome(e))
            self._enter_fault(e, time.monotonic())
            return
        if pos >= self._rotate_bytes:
            self._rotate(time.monotonic())

    def _written(self, pos: int) -> None:
        """Everything up to file position ``pos`` reached the OS: the pending items are
        in the file."""
        self._written_pos = pos
        if self._pending != [0, 0]:
            self._part_flushed = True
        self._pending = [0, 0]

    def _record_time_housekeeping(self, t_us: int) -> None:
        """Deterministic mode: flush and rotate by the records' time (every item's
        ``t_us``), before writing the first record past the interval."""
        step_us = round(self.config.flush_interval_s * 1e6)
        if self._next_flush_record_us is None:
            self._next_flush_record_us = t_us + step_us
        elif t_us >= self._next_flush_record_us:
            self._flush(time.monotonic())
            self._next_flush_record_us = t_us + step_us
        if self._part_started_record_us is None:
            self._part_started_record_us = t_us
        elif t_us - self._part_started_record_us >= self.config.rotate_interval_s * 1e6:
            self._part_started_record_us = t_us
            self._rotate(time.monotonic())

    def _housekeeping(self, now: float) -> None:
        if now >= self._next_free_check:
            self._next_free_check = now + self._free_check_interval_s
            self._check_free(now)
            self._check_file_linked(now)
        if (
            self._part is not None
            and not self.deterministic
            and now - self._file_opened_at >= self.config.rotate_interval_s
        ):
            self._rotate(now)
        if self._fault and now >= self._next_retry:
            self._retry(now)

    def _check_free(self, now: float) -> None:
        if not self._space.checked():
            return
        low = self._space.low
        floor = f"{self.config.min_free_mb:g} MB"
        if low:
            self._event("warning", f"log: disk below {floor}, frames not logged")
        else:
            self._event("info", f"log: disk above {floor}, frames logged again")

    def _check_file_linked(self, now: float) -> None:
        if self._part is None:
            return
        try:
            if os.fstat(self._part.fh.fileno()).st_nlink == 0:
                raise FileNotFoundError(errno.ENOENT, "the log file was deleted")
        except Exception as e:
            self._enter_fault(e, now)

    def _flush(self, now: float) -> None:
        if self._part is None or not self._part.dirty:
            return
        try:
            self._bytes_current = self._part.flush()
            self._written(self._bytes_current)
        except Exception as e:
            self._enter_fault(e, now)

    def _rotate(self, now: float) -> None:
        self._close_file()
        if self._fault:
            return
        try:
            self._open_file()
        except Exception as e:
            self._enter_fault(e, now)

    def _retry(self, now: float) -> None:
        if self._fault_disk_full and not self._space.room_for_a_part(self.config.chunk_size_bytes):
            self._next_retry = now + self._retry_interval_s
            return
        try:
            self._open_file()
        except Exception as e:
            with self._lock:
                self._counts.write_errors += 1
            log.debug("flight log retry failed: %s", e)
            self._next_retry = now + self._retry_interval_s
            return
        self._fault = False
        self._fault_disk_full = False
        self._fault_reported = False
        self._event("info", f"log: recording again ({self._counts.files[-1].name})")

    def _open_file(self) -> None:
        """Open the next part: header, metadata record, flushed; raises on failure."""
        self.directory.mkdir(parents=True, exist_ok=True)
        for _ in range(100_000):
            path = self.directory / part_name(self._session, self._counter, self.flight_id)
            try:
                fh = self._open_stream(path)
                break
            except FileExistsError:
                self._counter += 1
                continue
        else:  # pragma: no cover
            raise FileExistsError(errno.EEXIST, "no free log file name", str(self.directory))
        try:
            part = LogPart(fh, self.config.chunk_size_bytes)
            part.start({**self._metadata, "log_part": str(len(self._counts.files))})
        except BaseException:
            with contextlib.suppress(Exception):
                fh.close()
            with contextlib.suppress(OSError):
                path.unlink()  # ours (created here): no empty or partial part is left
            raise
        self._counter += 1
        self._part = part
        self._pending = [0, 0]
        self._written_pos = fh.tell()
        self._part_flushed = False
        self._file_opened_at = time.monotonic()
        with self._lock:
            self._counts.files.append(path)
            self._bytes_current = fh.tell()

    def _open_stream(self, path: Path) -> IO[bytes]:
        """A new file for writing (never an existing one); a seam for tests."""
        return open(path, "xb")

    def _close_file(self) -> None:
        """Finish the part (summary, footer), fsync and close it."""
        if self._part is None:
            return
        try:
            size = self._part.finish()
        except Exception as e:
            self._enter_fault(e, time.monotonic())
            return
        self._pending = [0, 0]
        self._part = None
        with self._lock:
            self._bytes_closed += size
            self._bytes_current = 0

    def _enter_fault(self, exc: BaseException, now: float) -> None:
        # What was counted as logged but had not reached the OS is lost with the part's
        # tail: counted again, as dropped (disk on a full disk, else error).
        lost = lost_outcome(exc)
        frames, messages = self._pending
        self._pending = [0, 0]
        fh = self._part.fh if self._part is not None else None
        # A part that never got a message out holds only its start: remove it (a full
        # disk would otherwise leave one such part per retry).
        useless = fh is not None and not self._part_flushed
        with self._lock:
            c = self._counts
            c.write_errors += 1
            c.frames_logged -= frames
            c.messages_logged -= messages
            setattr(c, f"frames_{lost}", getattr(c, f"frames_{lost}") + frames)
            setattr(c, f"messages_{lost}", getattr(c, f"messages_{lost}") + messages)
            if useless and c.files:
                self._counter -= 1
                gone = c.files.pop()
            else:
                self._bytes_closed += self._bytes_current
                gone = None
            self._bytes_current = 0
        if fh is not None:
            with contextlib.suppress(Exception):
                fh.close()
        if gone is not None:
            with contextlib.suppress(OSError):
                gone.unlink()
        self._part = None
        self._fault = True
        self._fault_disk_full = lost == "dropped_disk"
        self._next_retry = now + self._retry_interval_s
        log.warning("flight log write failed: %s", exc)
        if not self._fault_reported:
            self._fault_reported = True
            why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            self._event("error", f"log: write failed ({why}), retrying")

    def _event(self, severity: str, text: str) -> None:
        if self._on_event is None:
            return
        try:
            self._on_event(severity, text)
        except Exception:
            log.exception("flight log on_event callback failed")
