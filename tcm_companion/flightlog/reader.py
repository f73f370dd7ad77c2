"""Reading the flight log (MCAP files the :class:`~.writer.FlightLogWriter` wrote).

:func:`read_log` streams a file, or a directory of rotated parts in write order, with
mcap's non-seeking reader and stops quietly at a truncated tail (a killed writer's file
has no summary or footer; every complete chunk is read). :func:`read_metadata`,
:func:`decode_image` and :func:`decode_json` decode what it yields. Topic names are in
:mod:`.topics`.

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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from mcap.records import Channel, Message, Metadata, Schema
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


def read_log(path: str | Path, topics: Container[str] | None = None) -> Iterator[LogRecord]:
    """Every message of a file or of a directory's parts, in write order, read with the
    non-seeking reader; a truncated part (crash) yields what is readable, then the next."""
    for f in log_files(path):
        yield from _read_part(f, topics)


def _read_part(path: Path, wanted: Container[str] | None) -> Iterator[LogRecord]:
    with open(path, "rb") as fh:
        records = StreamReader(fh, validate_crcs=True).records
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        while True:
            try:
                rec = next(records)
            except StopIteration:
                return
            except Exception as e:  # truncated or corrupt tail: stop quietly
                log.debug("%s: stopped reading at a damaged record: %r", path, e)
                return
            if isinstance(rec, Message):
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
