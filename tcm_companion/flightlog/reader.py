"""Reading the flight log (MCAP files the :class:`~.writer.FlightLogWriter` wrote).

:func:`read_log` streams a file, or a directory of rotated parts in write order, with
mcap's non-seeking reader and stops at a truncated or damaged tail (a killed writer's file
has no summary or footer; every complete chunk is read). It does not stop silently: give it
a :class:`LogReport` and it says, per part, how much of the file was readable, up to which
time, and why it stopped (:meth:`LogReport.problems`; :func:`check_log` reads a whole log
for that alone). :func:`read_metadata`, :func:`decode_image` and :func:`decode_json` decode
what it yields. Topic names are in :mod:`.topics`.

What a log is, as both sides see it: parts named ``tcm-YYYYmmdd-HHMMSS-FLIGHTID-NNN.mcap``
(:func:`part_name`), each starting with the :data:`METADATA_NAME` metadata record, which
holds the flight's id (``flight_id``) and the part's number in the flight (``log_part``).

Flights
-------
A directory may hold many flights (under systemd every flight goes to one). Reading a
directory reads ONE flight (:func:`select_flight`): its parts, joined in their order,
never another flight's. The parts of a flight are those whose metadata names its
``flight_id``, ordered by ``log_part``; a part number missing, a part twice or parts out
of time order are reported as problems of the flight (:attr:`Flight.problems`). Logs
written before flights had ids (no ``flight_id``; ``tcm-YYYYmmdd-HHMMSS-NNN.mcap``) are
grouped as their writer left them: the parts of one name stem (the session) in counter
order, with the same metadata (but ``log_part``), each starting later than the one
before; a part that breaks the run starts another flight (two ``sitl --clock virtual``
runs in one directory were named as parts of one session). A file without a readable
metadata record joins the flight its name names (a part cut before its metadata is a
damaged part of that flight); any other ``tcm-*.mcap`` file is skipped and named
(:attr:`Flight.notes`). With several flights, :func:`select_flight` wants one picked
(``--flight ID``, a unique prefix, or ``latest``) and lists them.
:mod:`.writer` re-exports everything here.
"""

from __future__ import annotations

import errno
import itertools
import json
import logging
import os
import re
import secrets
from collections.abc import Container, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from struct import error as struct_error
from typing import Any

import cv2
import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from mcap.records import Channel, Chunk, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from . import topics

log = logging.getLogger(__name__)

METADATA_NAME = "tcm-companion"
PART_GLOB = "tcm-*.mcap"
#: A flight id: 12 lower-case hex digits (48 random bits; :func:`new_flight_id`).
FLIGHT_ID_RE = re.compile(r"^[0-9a-f]{12}$")
# tcm-SESSION[-FLIGHTID]-NNN.mcap (without the id: written before flights had one)
_MCAP_MAGIC = b"\x89MCAP0\r\n"  # what every MCAP file starts with
_PART_RE = re.compile(r"^tcm-(\d{8}-\d{6})(?:-([0-9a-f]{12}))?-(\d+)\.mcap$")


def new_flight_id() -> str:
    """A fresh random flight id (12 hex digits)."""
    return secrets.token_hex(6)


def part_name(session: str, counter: int, flight_id: str = "") -> str:
    """The file name of part ``counter`` of flight ``flight_id`` started at ``session``
    (``YYYYmmdd-HHMMSS``, UTC); without an id, the name logs had before flights had one."""
    fid = f"-{flight_id}" if flight_id else ""
    return f"tcm-{session}{fid}-{counter:03d}.mcap"


def parse_part_name(name: str) -> tuple[str, str, int] | None:
    """``(session, flight id or "", counter)`` of a part's file name; None for another."""
    m = _PART_RE.match(name)
    return (m.group(1), m.group(2) or "", int(m.group(3))) if m else None


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

        def key(f: Path) -> tuple[int, str, str, int, str]:
            m = parse_part_name(f.name)
            return (0, m[0], m[1], m[2], f.name) if m else (1, "", "", 0, f.name)

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
    not_mcap: bool = False  # the file does not start with MCAP's magic bytes

    @property
    def damaged(self) -> bool:
        """Not read to its end (truncated or corrupt)."""
        return not self.complete

    @property
    def kind(self) -> str:
        """``"complete"``, ``"truncated"`` (the file ends early), ``"damaged"`` (a
        corrupt record before the end of the file stopped the reader) or ``"not MCAP"``
        (not a log at all)."""
        if self.complete:
            return "complete"
        if self.not_mcap:
            return "not MCAP"
        return "damaged" if self.error and not self.at_eof and self.size_bytes else "truncated"

    def describe(self, log_start_ns: int | None = None) -> str:
        """One line: what is wrong with the part and what of it is readable.

        Times are in seconds from ``log_start_ns`` (the log's first message; default this
        part's)."""
        if self.complete:
            return f"{self.path}: complete ({self.messages} messages, {self.size_bytes} bytes)"
        size, read = self.size_bytes, self.read_bytes
        if self.not_mcap:
            return (
                f"{self.path}: not an MCAP file (it does not start with MCAP's magic bytes):"
                " not a flight log"
            )
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
    flight: Flight | None = None  # the flight read (set by read_log)

    @property
    def notes(self) -> list[str]:
        """Files of the directory that are not this flight's parts and were skipped, and
        other remarks that do not make the log less whole."""
        return list(self.flight.notes) if self.flight is not None else []

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
        which part (1-based, of how many). The flight's own problems (a part missing, a
        part twice, parts out of order: :attr:`Flight.problems`) come first."""
        start = self.start_ns
        out = list(self.flight.problems) if self.flight is not None else []
        for k, p in enumerate(self.parts):
            if p.damaged:
                which = f"part {k + 1} of {len(self.parts)}: " if len(self.parts) > 1 else ""
                out.append(which + p.describe(start))
        return out


def read_log(
    path: str | Path,
    topics: Container[str] | None = None,
    report: LogReport | None = None,
    flight: str | None = None,
) -> Iterator[LogRecord]:
    """Every message of a file, or of one flight's parts in a directory
    (:func:`select_flight`; ``flight`` picks one when there are several), in write order,
    read with the non-seeking reader; a truncated or damaged part (crash) yields what is
    readable, then the next part. ``report`` gets the flight and one :class:`PartReport`
    per part as it is read (complete once the iterator is exhausted): how much was
    readable and why reading stopped. Raises :class:`FlightSelectionError` when a
    directory holds several flights and ``flight`` picks none (or no one)."""
    chosen = select_flight(path, flight)
    if report is not None:
        report.flight = chosen
    for f in chosen.parts:
        part = PartReport(f, f.stat().st_size)
        if report is not None:
            report.parts.append(part)
        yield from _read_part(f, topics, part)


def check_log(path: str | Path, flight: str | None = None) -> LogReport:
    """Read a whole log (one flight of a directory) and report, per part, what was
    readable (:class:`LogReport`)."""
    report = LogReport()
    for _ in read_log(path, (), report, flight):
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
                if part.read_bytes == 0 and part.size_bytes:
                    fh.seek(0)
                    head = fh.read(len(_MCAP_MAGIC))
                    part.not_mcap = not _MCAP_MAGIC.startswith(head)
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


def read_metadata(path: str | Path, flight: str | None = None) -> dict[str, str]:
    """The first ``"tcm-companion"`` metadata record of the log — of a file, or of one
    flight of a directory (:func:`select_flight`) — ({} if there is none)."""
    for f in select_flight(path, flight).parts:
        meta = _part_metadata(f)
        if meta:
            return meta
    return {}


def _part_metadata(f: Path) -> dict[str, str]:
    """The metadata record of one file ({} when none is readable)."""
    try:
        with open(f, "rb") as fh:
            for rec in StreamReader(fh, emit_chunks=True).records:
                if isinstance(rec, Metadata) and rec.name == METADATA_NAME:
                    return dict(rec.metadata)
                if isinstance(rec, Chunk | Message):
                    break  # the writer puts it before any message
    except Exception as e:
        log.debug("%s: no readable metadata: %r", f, e)
    return {}


def _part_start_ns(f: Path) -> int | None:
    """The wall-clock time (``log_time``) of the first chunk's earliest message of a
    part, read without decompressing anything (None when it has no readable message)."""
    try:
        with open(f, "rb") as fh:
            for rec in StreamReader(fh, emit_chunks=True).records:
                if isinstance(rec, Chunk):
                    return int(rec.message_start_time)
                if isinstance(rec, Message):
                    return int(rec.log_time)
    except Exception as e:
        log.debug("%s: no readable message: %r", f, e)
    return None


# ---------------------------------------------------------------------------------------
# Flights


class FlightSelectionError(ValueError):
    """A log directory holds several flights and none (or no single one) was picked;
    the message lists them."""


@dataclass
class Flight:
    """One flight of a log directory: its parts in order, and what is wrong with them."""

    flight_id: str  # the metadata's flight_id; a flight written before ids: its first part's stem
    parts: list[Path]
    started_utc: str = ""  # the metadata's, e.g. 2024-06-10T06:13:20Z
    legacy: bool = False  # written before flights had ids (grouped by name and time)
    problems: list[str] = field(default_factory=list)  # a part missing, twice, out of order
    notes: list[str] = field(default_factory=list)  # files skipped (not this flight's)
    sort_key: tuple[str, str, int] = ("", "", 0)

    def describe(self) -> str:
        """One line for a listing: id, start, parts."""
        n = len(self.parts)
        started = self.started_utc.replace("T", " ").replace("Z", " UTC") or "start unknown"
        first = self.parts[0].name if self.parts else "no part"
        last = f" ... {self.parts[-1].name}" if n > 1 else ""
        old = " (written before flights had ids)" if self.legacy else ""
        return f"{self.flight_id}  started {started}, {n} part(s): {first}{last}{old}"


@dataclass
class _Part:
    path: Path
    meta: dict[str, str]
    name: tuple[str, str, int] | None  # parse_part_name
    _start: int | None = None
    _start_read: bool = False

    @property
    def flight_id(self) -> str:
        fid = self.meta.get("flight_id", "")
        return fid if fid else (self.name[1] if self.name else "")

    @property
    def index(self) -> int | None:
        try:
            return int(self.meta["log_part"])
        except (KeyError, ValueError):
            return self.name[2] if self.name else None

    @property
    def start_ns(self) -> int | None:
        if not self._start_read:
            self._start, self._start_read = _part_start_ns(self.path), True
        return self._start

    def same_writer(self, other: _Part) -> bool:
        """The same metadata but the part number: what one writer's parts share."""
        strip = lambda m: {k: v for k, v in m.items() if k != "log_part"}  # noqa: E731
        return strip(self.meta) == strip(other.meta)


def find_flights(directory: str | Path) -> tuple[list[Flight], list[Path]]:
    """The flights of a log directory, oldest first, and the ``tcm-*.mcap`` files that
    belong to none (no readable metadata, and a name that names no flight there)."""
    parts = [_Part(f, _part_metadata(f), parse_part_name(f.name)) for f in log_files(directory)]
    with_meta = [p for p in parts if p.meta]
    by_id: dict[str, list[_Part]] = {}
    for p in with_meta:
        if p.meta.get("flight_id"):
            by_id.setdefault(p.meta["flight_id"], []).append(p)
    groups: list[tuple[str, list[_Part], bool]] = [(fid, g, False) for fid, g in by_id.items()]
    # Before flights had ids: one writer's parts, in name order, each starting later.
    legacy: list[list[_Part]] = []
    for p in (p for p in with_meta if not p.meta.get("flight_id")):
        prev = legacy[-1][-1] if legacy else None
        if (
            prev is not None
            and p.name is not None
            and prev.name is not None
            and p.name[0] == prev.name[0]
            and p.same_writer(prev)
            and _later(p.start_ns, prev.start_ns)
        ):
            legacy[-1].append(p)
        else:
            legacy.append([p])
    groups += [(g[0].path.stem, g, True) for g in legacy]
    # Files without metadata join the flight their name names.
    orphans: list[Path] = []
    for p in (p for p in parts if not p.meta):
        home = None
        if p.name is not None and p.name[1]:
            home = next((g for fid, g, _ in groups if fid == p.name[1]), None)
        elif p.name is not None:
            same = [
                g
                for _, g, old in groups
                if old
                and g[0].name is not None
                and g[0].name[0] == p.name[0]
                and g[0].name[2] <= p.name[2]
            ]
            home = max(same, key=lambda g: g[0].name[2] if g[0].name else 0, default=None)
        if home is None:
            orphans.append(p.path)
        else:
            home.append(p)
    flights = [_flight(fid, g, old) for fid, g, old in groups]
    flights.sort(key=lambda f: f.sort_key)
    return flights, orphans


def _same_bytes(a: Path, b: Path) -> bool:
    """The two files hold the same bytes."""
    try:
        if a.stat().st_size != b.stat().st_size:
            return False
        with open(a, "rb") as fa, open(b, "rb") as fb:
            while True:
                x, y = fa.read(1 << 20), fb.read(1 << 20)
                if x != y:
                    return False
                if not x:
                    return True
    except OSError:
        return False


def _later(a: int | None, b: int | None) -> bool:
    return a is None or b is None or a > b


def _flight(flight_id: str, group: list[_Part], legacy: bool) -> Flight:
    """A flight of its parts: ordered, and what is wrong with them said."""
    problems: list[str] = []
    notes: list[str] = []
    if legacy:
        ordered = sorted(group, key=lambda p: (p.name[2] if p.name else 0, p.path.name))
    else:
        ordered = sorted(group, key=lambda p: (p.index if p.index is not None else -1, p.path.name))
        seen: dict[int, _Part] = {}
        kept: list[_Part] = []
        for p in ordered:
            k = p.index
            if k is not None and k in seen:
                other = seen[k].path
                if _same_bytes(p.path, other):  # a copy: nothing lost, nothing to add
                    notes.append(f"{p.path}: a copy of {other.name} (part {k}): skipped")
                else:
                    problems.append(
                        f"{p.path}: another part {k} of flight {flight_id} (besides"
                        f" {other.name}), with other contents: skipped"
                    )
                continue
            if k is not None:
                seen[k] = p
            kept.append(p)
        ordered = kept
        numbers = sorted(seen)
        missing = sorted(set(range(numbers[-1] + 1)) - set(numbers)) if numbers else []
        if missing:
            which = ", ".join(str(k) for k in missing[:10]) + (" ..." if len(missing) > 10 else "")
            problems.append(
                f"flight {flight_id}: part(s) {which} of {numbers[-1] + 1} missing"
                " (deleted, or never written?): what they held is not replayed"
            )
        for a, b in itertools.pairwise(ordered):
            if a.meta and b.meta and not _later(b.start_ns, a.start_ns):
                problems.append(
                    f"{b.path}: part {b.index} of flight {flight_id} does not start after"
                    f" part {a.index} ({a.path.name}): parts out of time order"
                )
    first = next((p for p in ordered if p.meta), ordered[0])
    started = first.meta.get("started_utc", "")
    session = first.name[0] if first.name else ""
    try:
        mtime = os.stat(first.path).st_mtime_ns
    except OSError:
        mtime = 0
    return Flight(
        flight_id=flight_id,
        parts=[p.path for p in ordered],
        started_utc=started,
        legacy=legacy,
        problems=problems,
        notes=notes,
        sort_key=(started or session, session, mtime),
    )


def select_flight(path: str | Path, flight: str | None = None) -> Flight:
    """The flight to read at ``path``: a file is one on its own (``flight``, when
    given, must be its id); a directory's only flight, or the one ``flight`` picks (its
    id, a unique prefix of it, or ``latest``). A directory of several flights without
    ``flight`` raises :class:`FlightSelectionError`, listing them."""
    p = Path(path)
    if p.is_file():
        meta = _part_metadata(p)
        fid = meta.get("flight_id", "")
        if flight is not None and flight != "latest" and not (fid and fid.startswith(flight)):
            raise FlightSelectionError(
                f"{p}: the file is of flight {fid or '(no id: written before flights had ids)'},"
                f" not {flight} (--flight picks a flight in a log directory)"
            )
        notes = []
        if meta.get("log_part", "0") not in ("0", ""):
            notes.append(
                f"{p}: part {meta['log_part']} of flight {fid or p.stem}: read on its own,"
                " from the middle of its flight (give the directory to read the whole flight)"
            )
        return Flight(fid or p.stem, [p], meta.get("started_utc", ""), not fid, notes=notes)
    files = log_files(p)  # raises FileNotFoundError when there is nothing at all
    flights, orphans = find_flights(p)
    if not flights:  # nothing with a readable metadata record: read them, and say so
        return Flight("", files, problems=[])
    chosen = _choose(p, flights, flight)
    chosen.notes += [
        f"{o}: skipped: not a part of flight {chosen.flight_id} (no tcm-companion metadata"
        " record, and its name names no flight here)"
        for o in orphans
    ]
    if len(flights) > 1:
        chosen.notes.append(
            f"{p}: flight {chosen.flight_id} of the {len(flights)} flights in the directory"
        )
    return chosen


def _choose(directory: Path, flights: list[Flight], flight: str | None) -> Flight:
    if flight is None:
        if len(flights) == 1:
            return flights[0]
        raise FlightSelectionError(
            f"{directory} holds {len(flights)} flights: pick one with --flight ID (or"
            " --flight latest), or give one of its files; oldest first:\n"
            + "\n".join(f"  {f.describe()}" for f in flights)
        )
    if flight == "latest":
        return flights[-1]
    exact = [f for f in flights if f.flight_id == flight]
    found = exact or [f for f in flights if f.flight_id.startswith(flight)]
    if len(found) == 1:
        return found[0]
    what = "no flight" if not found else f"{len(found)} flights"
    raise FlightSelectionError(
        f"{directory}: {what} with id {flight!r}; its flights, oldest first:\n"
        + "\n".join(f"  {f.describe()}" for f in flights)
    )


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
