"""Read and write MAVProxy ``.tlog`` files.

A ``.tlog`` is a sequence of records: an 8-byte big-endian unsigned timestamp (µs since
the Unix epoch, the receiver's clock) followed by one MAVLink v1 or v2 frame. Frames are
split here by their headers and decoded with pymavlink's generated parser, so a bad CRC
or an unknown message id costs one record, never the rest of the log.

Damage is kept to what it touched. Where no record can be read — a byte that is not a
MAVLink magic, a length that runs past the end of the file, a frame that does not decode
and is not followed by a record — the reader skips ahead to the next plausible record (its
frame decodes with a good CRC and a record or the end of the file follows it) and goes
on from there; junk appended to a log, a record cut short at its end (power loss) and a
corrupt stretch in its middle are all treated so. Each skipped stretch is a
:class:`TlogGap` in :class:`TlogStats` (the byte offset, how many bytes, the record
expected there and why it could not be read). Only a log with nothing usable in it is a
:class:`TlogError`, naming the file, the record and its byte offset.
"""

from __future__ import annotations

import struct
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from pymavlink.dialects.v20 import common as mavlink2

_MAGIC_V1 = 0xFE
_MAGIC_V2 = 0xFD
_SIGNED = 0x01
_TS = struct.Struct(">Q")
_MIN_RECORD = 8 + 8  # time stamp and the shortest frame (MAVLink 1, empty payload)
# A record following another within this much receive time is taken as framed right even
# when its own frame cannot be checked (an unknown message id has no CRC_EXTRA). A time
# stamp of junk lands this close to the log's by chance about once in 10^8.
_NEAR_US = 24 * 3600 * 10**6
_GAPS_SHOWN = 5


class TlogError(ValueError):
    """The file is not a readable .tlog; the message names file, record and offset."""


@dataclass(frozen=True, slots=True)
class TlogRecord:
    """One decoded record: receive time, the message and where it sat in the file."""

    recv_us: int
    msg: Any  # pymavlink MAVLink_message
    index: int
    offset: int


@dataclass(frozen=True, slots=True)
class TlogGap:
    """A stretch of the file in which no record could be read, skipped."""

    offset: int  # first byte skipped
    length: int  # bytes skipped
    record: int  # index of the record expected at ``offset`` (records read before it)
    reason: str  # why no record could be read there
    resumed_at: int | None  # where reading resynchronised; None: skipped to the end
    after_us: int | None  # receive time of the last record read before it

    def describe(self, t0_us: int | None = None) -> str:
        """One phrase; with ``t0_us``, also when (seconds from it) the record before was
        received."""
        where = (
            f"resynchronised at byte {self.resumed_at}"
            if self.resumed_at is not None
            else "to the end of the file"
        )
        when = ""
        if t0_us is not None and self.after_us is not None:
            when = f"; the record before it received at {(self.after_us - t0_us) / 1e6:.2f} s"
        return (
            f"{self.length} bytes skipped at byte {self.offset}, {where}"
            f" (record {self.record}: {self.reason}{when})"
        )


@dataclass
class TlogStats:
    """What reading a log kept and what it skipped, by reason (reported, never silently
    dropped)."""

    records: int = 0  # framed records (decoded or not)
    decoded: int = 0  # records kept
    skipped: Counter[str] = field(default_factory=Counter)
    time_backwards: int = 0
    truncated_tail_bytes: int = 0  # a last record cut short (also one of ``gaps``)
    gaps: list[TlogGap] = field(default_factory=list)
    size_bytes: int = 0
    first_us: int | None = None  # receive time of the first record kept
    last_us: int | None = None  # ... and of the last

    @property
    def bytes_skipped(self) -> int:
        """Bytes of the file in no record (junk, damage, a record cut short)."""
        return sum(g.length for g in self.gaps)

    @property
    def damaged(self) -> bool:
        """Some of the file could not be read as records, or a record did not decode."""
        return bool(self.gaps or self.skipped)

    def summary(self, t0_us: int | None = None) -> str:
        """One line: what was kept, what was not and where; with ``t0_us`` (e.g. the first
        frame's time) also when, in seconds from it."""
        kept = f"{self.decoded} records kept"
        if t0_us is not None and self.first_us is not None and self.last_us is not None:
            kept += (
                f", received {(self.first_us - t0_us) / 1e6:.2f}"
                f"–{(self.last_us - t0_us) / 1e6:.2f} s from the first frame"
            )
        parts = [f"{self.decoded}/{self.records} decoded"]
        parts += [f"{n} {reason}" for reason, n in sorted(self.skipped.items())]
        if self.time_backwards:
            parts.append(f"{self.time_backwards} timestamps going backwards")
        line = f"{kept} ({', '.join(parts)})"
        if not self.gaps:
            return line
        if len(self.gaps) > 1:
            line += f"; {self.bytes_skipped} of {self.size_bytes} bytes skipped in all"
        shown = []
        for g in self.gaps[:_GAPS_SHOWN]:
            if g.length == self.truncated_tail_bytes and g.resumed_at is None:
                shown.append(f"truncated last record: {g.length} bytes at byte {g.offset}")
            else:
                shown.append(g.describe(t0_us))
        if len(self.gaps) > _GAPS_SHOWN:
            shown.append(f"and {len(self.gaps) - _GAPS_SHOWN} more skipped stretches")
        return f"{line}; {'; '.join(shown)}"


def _frame_length(buf: bytes | memoryview, pos: int) -> int:
    """Length of the MAVLink frame starting at ``pos`` (header, payload, CRC, signature)."""
    magic = buf[pos]
    if magic == _MAGIC_V1:
        return 6 + buf[pos + 1] + 2
    if magic == _MAGIC_V2:
        incompat = buf[pos + 2]
        if incompat & ~_SIGNED:
            raise ValueError(f"MAVLink 2 incompatibility flags 0x{incompat:02x} are not defined")
        signed = incompat & _SIGNED
        return 10 + buf[pos + 1] + 2 + (13 if signed else 0)
    raise ValueError(f"byte 0x{magic:02x} is not a MAVLink magic byte (0xFD or 0xFE)")


def _decode(parser: Any, frame: bytes) -> tuple[Any, str]:
    """``(message, "")`` or ``(None, why it was not decoded)``."""
    try:
        msg = parser.decode(bytearray(frame))
    except mavlink2.MAVError as exc:
        return None, ("bad CRC" if "CRC" in str(exc) else "undecodable frame")
    except Exception:  # junk can upset the generated unpackers in other ways
        return None, "undecodable frame"
    if isinstance(msg, mavlink2.MAVLink_unknown):
        return None, f"unknown message id {_msg_id(frame)}"
    return msg, ""


def _msg_id(frame: bytes) -> int:
    """The message id in a MAVLink 1 or 2 header."""
    return frame[5] if frame[0] == _MAGIC_V1 else int.from_bytes(frame[7:10], "little")


class _Framer:
    """Where records are in a .tlog held in memory, and how sure we are of it."""

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.n = len(data)
        self._probe = mavlink2.MAVLink(None)  # decoding has no state we rely on

    def header(self, pos: int) -> tuple[int, int]:
        """``(receive time, frame length)`` of the record at ``pos``; ValueError if its
        header is not a record's (the frame may still run past the end of the file)."""
        if self.n - pos < _MIN_RECORD:
            if self.cut_short(pos):
                raise ValueError(f"the file ends inside it ({self.n - pos} bytes)")
            magic = self.data[pos + 8]
            raise ValueError(f"byte 0x{magic:02x} is not a MAVLink magic byte (0xFD or 0xFE)")
        (recv_us,) = _TS.unpack_from(self.data, pos)
        return int(recv_us), _frame_length(self.data, pos + 8)

    def cut_short(self, pos: int) -> bool:
        """Fewer bytes left at ``pos`` than the shortest record, as a record cut short
        would leave them (a time stamp, or one followed by a magic byte)."""
        left = self.n - pos
        return left < _MIN_RECORD and (left <= 8 or self.data[pos + 8] in (_MAGIC_V1, _MAGIC_V2))

    def good(self, pos: int) -> bool:
        """A record at ``pos`` whose frame is whole and decodes (known id, good CRC)."""
        try:
            _, flen = self.header(pos)
        except ValueError:
            return False
        if pos + 8 + flen > self.n:
            return False
        # cheap first: a message id of the dialect, a payload no longer than its own
        f = pos + 8
        cls = mavlink2.mavlink_map.get(_msg_id(self.data[f : f + 10]))
        if cls is None or self.data[f + 1] > cls.unpacker.size:
            return False
        msg, _ = _decode(self._probe, self.data[f : f + flen])
        return msg is not None

    def plausible(self, pos: int, near_us: int) -> bool:
        """A record can start at ``pos``: the end of the file, a record header received
        within a day of ``near_us``, or a record that decodes."""
        if pos >= self.n:
            return True
        try:
            recv_us, _ = self.header(pos)
        except ValueError:
            return self.cut_short(pos)
        return abs(recv_us - near_us) <= _NEAR_US or self.good(pos)

    def resync(self, start: int) -> int | None:
        """The first position from ``start`` where a good record starts, followed by a
        plausible one (or the end of the file); None if there is none."""
        data, n = self.data, self.n
        q = start
        # the next of each magic byte at or after q + 8 (-1: none left), found once each
        nxt = {b"\xfe": data.find(b"\xfe", q + 8), b"\xfd": data.find(b"\xfd", q + 8)}
        while q + _MIN_RECORD <= n:
            for magic, at in nxt.items():
                if 0 <= at < q + 8:
                    nxt[magic] = data.find(magic, q + 8)
            hits = [h for h in nxt.values() if h >= 0]
            if not hits:
                return None
            q = min(hits) - 8
            if self.good(q):
                recv_us, flen = self.header(q)
                if self.plausible(q + 8 + flen, recv_us):
                    return q
            q += 1
        return None


def iter_tlog(
    data: bytes, path: str = "<tlog>", stats: TlogStats | None = None
) -> Iterator[TlogRecord]:
    """Decode the records of a whole .tlog held in memory.

    CRC failures and unknown message ids cost one record each (``stats.skipped``). A
    stretch in which no record can be read (junk, a corrupt record, a last record cut
    short) is skipped to the next plausible record and recorded in ``stats.gaps`` (a cut
    last record also in ``stats.truncated_tail_bytes``). Raises :class:`TlogError` only
    when nothing in a non-empty file decodes, naming the file, the first damaged record
    and its byte offset.
    """
    stats = stats if stats is not None else TlogStats()
    stats.size_bytes = len(data)
    parser = mavlink2.MAVLink(None)
    framer = _Framer(data)
    pos, index, last_ts = 0, 0, -1
    n = len(data)
    while pos < n:
        start = pos
        problem = ""
        ends_inside = False
        try:
            recv_us, flen = framer.header(pos)
        except ValueError as exc:
            problem = str(exc)
            ends_inside = framer.cut_short(pos)
        else:
            if pos + 8 + flen > n:
                problem = f"the file ends inside it ({n - pos} of {8 + flen} bytes)"
                ends_inside = True
            else:
                frame = data[pos + 8 : pos + 8 + flen]
                msg, why = _decode(parser, frame)
                near = last_ts if last_ts >= 0 else recv_us
                if msg is None and not framer.plausible(pos + 8 + flen, near):
                    problem = f"{why}, and no record follows it"
                else:
                    pos += 8 + flen
                    stats.records += 1
                    if recv_us < last_ts:
                        stats.time_backwards += 1
                    last_ts = recv_us
                    if msg is None:
                        stats.skipped[why] += 1
                    else:
                        stats.decoded += 1
                        if stats.first_us is None:
                            stats.first_us = recv_us
                        stats.last_us = recv_us
                        yield TlogRecord(recv_us=recv_us, msg=msg, index=index, offset=start)
                    index += 1
                    continue
        resume = framer.resync(start + 1)
        if resume is None and ends_inside:
            stats.truncated_tail_bytes = n - start
        stats.gaps.append(
            TlogGap(
                offset=start,
                length=(resume if resume is not None else n) - start,
                record=index,
                reason=problem,
                resumed_at=resume,
                after_us=last_ts if last_ts >= 0 else None,
            )
        )
        if resume is None:
            break
        pos = resume
    if n and not stats.decoded:
        first = stats.gaps[0] if stats.gaps else None
        where = (
            f"record {first.record} at byte {first.offset}: {first.reason}"
            if first is not None
            else stats.summary()
        )
        raise TlogError(f"{path}: no usable MAVLink record in {n} bytes ({where})")


def read_tlog(path: str | Path) -> tuple[list[TlogRecord], TlogStats]:
    """Read a whole .tlog file; see :func:`iter_tlog` for what is skipped or raised."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise TlogError(f"{p}: cannot read: {exc.strerror}") from None
    stats = TlogStats()
    records = list(iter_tlog(data, str(p), stats))
    return records, stats


class TlogWriter:
    """Append records to a .tlog (timestamp + already-packed MAVLink frame)."""

    def __init__(self, fh: BinaryIO) -> None:
        self._fh = fh

    def write(self, recv_us: int, frame: bytes) -> None:
        self._fh.write(_TS.pack(int(recv_us)))
        self._fh.write(frame)


def write_tlog(path: str | Path, records: Iterable[tuple[int, bytes]]) -> None:
    """Write ``(recv_us, packed MAVLink frame)`` pairs to ``path``."""
    with open(path, "wb") as fh:
        w = TlogWriter(fh)
        for recv_us, frame in records:
            w.write(recv_us, frame)
