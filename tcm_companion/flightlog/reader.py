"""Reading the flight log (MCAP files the :class:`~.writer.FlightLogWriter` wrote).

:func:`read_log` streams a file, or a directory of rotated parts in write order, with
mcap's non-seeking reader and stops at a truncated or damaged tail (a killed writer's file
has no summary or footer; every complete chunk is read). It does not stop silently: give it
a :class:`LogReport` and it says, per part, how much of the file was readable, up to which
time, and why it stopped (:meth:`LogReport.problems`; :func:`check_log` reads a whole log
for that alone). :func:`read_metadata`, :func:`decode_image` and :func:`decode_json` decode
what it yields. Topic names are in :mod:`.topics`.

What a log is, as both sides see it: parts named ``tcm-YYYYmmdd-HHMMSS-NNN.mcap``
(:func:`part_name`), each starting with the :data:`METADATA_NAME` metadata record.
:mod:`.writer` re-exports everything here.
"""

from __future__ import annotations

import errno
import json
import logging
import re
from collections.abc import Container, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from struct import error as struct_error
from typing import Any

import cv2
import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from mcap.records import Channel, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from . import topics

log = logging.getLogger(__name__)

METADATA_NAME = "tcm-companion"
PART_GLOB = "tcm-*.mcap"
_PART_RE = re.compile(r"^tcm-(\d{8}-\d{6})-(\d+)\.mcap$")


def part_name(session: str, counter: int) -> str:
    """The file name of part ``counter`` of the session started at ``session``
    (``YYYYmmdd-HHMMSS``, UTC)."""
    return f"tcm-{session}-{counter:03d}.mcap"


@dataclass(frozen=True)
class LogRecord:
    """One message of the log."""

    topic: str
    log_time_ns: int  # wall clock
    publish_time_ns: int  # companion monotonic clock (= t_us * 1000)
    data: bytes
    schema_name: str  # "" for schema-less (MAVLink)
    message_encoding: str  # "protobuf", "json", "mavlink"


def log_files(path: str | Path) -> list[Path]:
    """A ``.mcap`` file → ``[it]``; a directory → its ``tcm-*.mcap`` parts in order
    (session time stamp, then part counter, numerically)."""
    p = Path(path)
    if p.is_dir():

        def key(f: Path) -> tuple[int, str, int, str]:
            m = _PART_RE.match(f.name)
            return (0, m.group(1), int(m.group(2)), f.name) if m else (1, "", 0, f.name)

        return sorted((f for f in p.glob(PART_GLOB) if f.is_file()), key=key)
    if p.is_file():
        return [p]
    raise FileNotFoundError(errno.ENOENT, "no flight log there", str(p))


@dataclass
class PartReport:
    """How much of one part (file) of a log the reader could read, and why it stopped.

    ``complete`` is True only when the reader reached the footer and the closing magic:
    the writer closed the file. Anything else — a killed writer, a power cut, a copy taken
    while the file was written, a file cut short or damaged — is a part whose end is lost.
    """

    path: Path
    size_bytes: int
    read_bytes: int = 0  # up to the end of the last complete record
    messages: int = 0  # messages read, of every topic
    first_time_ns: int | None = None  # publish time (companion monotonic) of the first
    last_time_ns: int | None = None  # ... and of the last message read
    last_log_time_ns: int | None = None  # wall clock of the last message read
    complete: bool = False
    error: str = ""  # what stopped the reader before the footer ("": the file just ended)
    at_eof: bool = True  # the reader had reached the end of the file when it stopped

    @property
    def damaged(self) -> bool:
        """Not read to its end (truncated or corrupt)."""
        return not self.complete

    @property
    def kind(self) -> str:
        """``"complete"``, ``"truncated"`` (the file ends early) or ``"damaged"`` (a
        corrupt record before the end of the file stopped the reader)."""
        if self.complete:
            return "complete"
        return "damaged" if self.error and not self.at_eof and self.size_bytes else "truncated"

    def describe(self, log_start_ns: int | None = None) -> str:
        """One line: what is wrong with the part and what of it is readable.

        Times are in seconds from ``log_start_ns`` (the log's first message; default this
        part's)."""
        if self.complete:
            return f"{self.path}: complete ({self.messages} messages, {self.size_bytes} bytes)"
        size, read = self.size_bytes, self.read_bytes
        pct = f" ({100.0 * read / size:.1f}%)" if size else ""
        unclosed = (
            "; the writer never closed the file (killed, power lost, disk full, or copied"
            " while being written?)"
        )
        if size == 0:
            what = "truncated: the file is empty"
        elif read == size:
            what = (
                "truncated: the file stops after a complete record, without the footer and"
                " closing magic the writer ends it with"
            )
        elif self.error and not self.at_eof:
            what = (
                f"damaged at byte {read} of {size} ({self.error}): the first {read} bytes{pct}"
                f" read, the other {size - read} not"
            )
            unclosed = ""
        else:
            what = (
                f"truncated: {read} of {size} bytes{pct} readable, the file ends inside a"
                f" record that starts at byte {read}"
            )
        return f"{self.path}: {what}; {self._readable(log_start_ns)}{unclosed}"

    def _readable(self, log_start_ns: int | None) -> str:
        if self.last_time_ns is None:
            return "no message readable"
        start = log_start_ns if log_start_ns is not None else self.first_time_ns
        assert start is not None
        last = (self.last_time_ns - start) / 1e9
        wall = ""
        if self.last_log_time_ns is not None and self.last_log_time_ns >= 946_684_800 * 10**9:
            stamp = datetime.fromtimestamp(self.last_log_time_ns / 1e9, UTC)
            wall = f", logged {stamp:%Y-%m-%d %H:%M:%S}.{stamp.microsecond // 1000:03d} UTC"
        return f"{self.messages} messages readable, the last {last:.2f} s into the log{wall}"


@dataclass
class LogReport:
    """What reading a log (a file, or a directory's parts) could read: one
    :class:`PartReport` per part, filled in as :func:`read_log` goes."""

    parts: list[PartReport] = field(default_factory=list)

    @property
    def damaged(self) -> list[PartReport]:
        """The parts whose end was not reached (truncated or damaged)."""
        return [p for p in self.parts if p.damaged]

    @property
    def start_ns(self) -> int | None:
        """Publish time of the log's first message."""
        return next((p.first_time_ns for p in self.parts if p.first_time_ns is not None), None)

    @property
    def last_time_s(self) -> float | None:
        """Seconds from the log's first message to its last readable one."""
        start = self.start_ns
        last = max((p.last_time_ns for p in self.parts if p.last_time_ns is not None), default=None)
        return None if start is None or last is None else (last - start) / 1e9

    def problems(self) -> list[str]:
        """One line per damaged part ([] for a whole log); a log of several parts says
        which part (1-based, of how many)."""
        start = self.start_ns
        out = []
        for k, p in enumerate(self.parts):
            if p.damaged:
                which = f"part {k + 1} of {len(self.parts)}: " if len(self.parts) > 1 else ""
                out.append(which + p.describe(start))
        return out


def read_log(
    path: str | Path,
    topics: Container[str] | None = None,
    report: LogReport | None = None,
) -> Iterator[LogRecord]:
    """Every message of a file or of a directory's parts, in write order, read with the
    non-seeking reader; a truncated or damaged part (crash) yields what is readable, then
    the next part. ``report`` gets one :class:`PartReport` per part as it is read (complete
    once the iterator is exhausted): how much was readable and why reading stopped."""
    for f in log_files(path):
        part = PartReport(f, f.stat().st_size)
        if report is not None:
            report.parts.append(part)
        yield from _read_part(f, topics, part)


def check_log(path: str | Path) -> LogReport:
    """Read a whole log and report, per part, what was readable (:class:`LogReport`)."""
    report = LogReport()
    for _ in read_log(path, (), report):
        pass
    return report


def _read_part(path: Path, wanted: Container[str] | None, part: PartReport) -> Iterator[LogRecord]:
    with open(path, "rb") as fh:
        records = StreamReader(fh, validate_crcs=True).records
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        footer = False
        while True:
            try:
                rec = next(records)
            except StopIteration:  # the footer and the closing magic were read
                part.complete = footer
                part.read_bytes = fh.tell()
                return
            except Exception as e:  # truncated or corrupt tail: stop, and say where
                part.error = _reason(e)
                part.at_eof = fh.tell() >= part.size_bytes
                log.debug("%s: stopped reading at a damaged record: %r", path, e)
                return
            # a chunk's records come out once the whole chunk is read: the file position
            # is then at the end of the last complete top-level record
            part.read_bytes = fh.tell()
            if isinstance(rec, Message):
                part.messages += 1
                if part.first_time_ns is None:
                    part.first_time_ns = rec.publish_time
                part.last_time_ns = rec.publish_time
                part.last_log_time_ns = rec.log_time
                ch = channels.get(rec.channel_id)
                if ch is None or (wanted is not None and ch.topic not in wanted):
                    continue
                schema = schemas.get(ch.schema_id)
                yield LogRecord(
                    topic=ch.topic,
                    log_time_ns=rec.log_time,
                    publish_time_ns=rec.publish_time,
                    data=rec.data,
                    schema_name=schema.name if schema is not None else "",
                    message_encoding=ch.message_encoding,
                )
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Footer):
                footer = True  # complete once the closing magic after it is read too


def _reason(exc: Exception) -> str:
    """A short text for what stopped the stream reader."""
    name = type(exc).__name__
    text = str(exc).strip()
    if name == "EndOfFile" or isinstance(exc, struct_error):
        return "end of file inside a record"
    return f"{name}: {text}" if text else name


def read_metadata(path: str | Path) -> dict[str, str]:
    """The first ``"tcm-companion"`` metadata record of the log ({} if there is none)."""
    for f in log_files(path):
        with open(f, "rb") as fh:
            try:
                for rec in StreamReader(fh, emit_chunks=True).records:
                    if isinstance(rec, Metadata) and rec.name == METADATA_NAME:
                        return dict(rec.metadata)
            except Exception as e:
                log.debug("%s: no readable metadata: %r", f, e)
    return {}


def decode_image(rec: LogRecord) -> tuple[int, int, np.ndarray]:
    """``(camera_id, t_capture_us, BGR uint8 image)`` of a ``/camera{N}/image`` record."""
    if rec.schema_name != topics.IMAGE_SCHEMA:
        raise ValueError(f"{rec.topic}: not a {topics.IMAGE_SCHEMA} record ({rec.schema_name!r})")
    msg = CompressedImage.FromString(rec.data)
    camera_id = topics.camera_of(rec.topic)
    if camera_id is None:
        camera_id = topics.camera_of(msg.frame_id, topics.CAMERA_FRAME_ID)
    if camera_id is None:
        raise ValueError(f"{rec.topic}: no camera id in topic or frame_id {msg.frame_id!r}")
    image = cv2.imdecode(np.frombuffer(msg.data, np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"{rec.topic}: undecodable {msg.format} image")
    return camera_id, rec.publish_time_ns // 1000, image


def decode_json(rec: LogRecord) -> dict[str, Any]:
    """The document of a JSON record."""
    if rec.message_encoding != "json":
        raise ValueError(f"{rec.topic}: not a JSON record ({rec.message_encoding!r})")
    doc = json.loads(rec.data)
    if not isinstance(doc, dict):
        raise ValueError(f"{rec.topic}: JSON record is not an object")
    return doc
