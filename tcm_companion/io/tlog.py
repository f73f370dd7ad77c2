"""Read and write MAVProxy ``.tlog`` files.

A ``.tlog`` is a sequence of records: an 8-byte big-endian unsigned timestamp (µs since
the Unix epoch, the receiver's clock) followed by one MAVLink v1 or v2 frame. Frames are
split here by their headers and decoded with pymavlink's generated parser, so a bad CRC
or an unknown message id costs one record, never the rest of the log; a record whose
frame does not start with a MAVLink magic byte is a framing error that names the record
and its byte offset.
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


class TlogError(ValueError):
    """The file is not a readable .tlog; the message names file, record and offset."""


@dataclass(frozen=True, slots=True)
class TlogRecord:
    """One decoded record: receive time, the message and where it sat in the file."""

    recv_us: int
    msg: Any  # pymavlink MAVLink_message
    index: int
    offset: int


@dataclass
class TlogStats:
    """What reading a log skipped, by reason (reported, never silently dropped)."""

    records: int = 0
    decoded: int = 0
    skipped: Counter[str] = field(default_factory=Counter)
    time_backwards: int = 0
    truncated_tail_bytes: int = 0

    def summary(self) -> str:
        parts = [f"{self.decoded}/{self.records} records decoded"]
        parts += [f"{n} {reason}" for reason, n in sorted(self.skipped.items())]
        if self.time_backwards:
            parts.append(f"{self.time_backwards} timestamps going backwards")
        if self.truncated_tail_bytes:
            parts.append(f"truncated last record ({self.truncated_tail_bytes} bytes)")
        return ", ".join(parts)


def _frame_length(buf: bytes | memoryview, pos: int) -> int:
    """Length of the MAVLink frame starting at ``pos`` (header, payload, CRC, signature)."""
    magic = buf[pos]
    if magic == _MAGIC_V1:
        return 6 + buf[pos + 1] + 2
    if magic == _MAGIC_V2:
        signed = buf[pos + 2] & _SIGNED
        return 10 + buf[pos + 1] + 2 + (13 if signed else 0)
    raise ValueError(f"byte 0x{magic:02x} is not a MAVLink magic byte (0xFD or 0xFE)")


def iter_tlog(
    data: bytes, path: str = "<tlog>", stats: TlogStats | None = None
) -> Iterator[TlogRecord]:
    """Decode the records of a whole .tlog held in memory.

    Raises :class:`TlogError` on a framing error. CRC failures and unknown message ids
    are counted in ``stats.skipped`` and skipped; a record cut short at the end of the
    file (a log interrupted by power loss) is counted in ``stats.truncated_tail_bytes``.
    """
    stats = stats if stats is not None else TlogStats()
    parser = mavlink2.MAVLink(None)
    pos, index, last_ts = 0, 0, -1
    n = len(data)
    while pos < n:
        start = pos
        if n - pos < 8 + 3:
            stats.truncated_tail_bytes = n - pos
            return
        (recv_us,) = _TS.unpack_from(data, pos)
        try:
            flen = _frame_length(data, pos + 8)
        except ValueError as exc:
            raise TlogError(f"{path}: record {index} at byte {start}: {exc}") from None
        if pos + 8 + flen > n:
            stats.truncated_tail_bytes = n - pos
            return
        frame = bytearray(data[pos + 8 : pos + 8 + flen])
        pos += 8 + flen
        stats.records += 1
        if recv_us < last_ts:
            stats.time_backwards += 1
        last_ts = recv_us
        try:
            msg = parser.decode(frame)
        except mavlink2.MAVError as exc:
            reason = "bad CRC" if "CRC" in str(exc) else "undecodable frame"
            stats.skipped[reason] += 1
            index += 1
            continue
        if isinstance(msg, mavlink2.MAVLink_unknown):
            stats.skipped[f"unknown message id {msg.get_msgId()}"] += 1
            index += 1
            continue
        stats.decoded += 1
        yield TlogRecord(recv_us=int(recv_us), msg=msg, index=index, offset=start)
        index += 1


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
