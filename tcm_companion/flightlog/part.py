"""One part (file) of the flight log as MCAP: its start (header and the metadata record),
its channels and schemas registered as topics first appear, messages numbered per
channel, flushing the open chunk, and its finish (summary, footer, fsync)."""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Mapping
from typing import IO

from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

from .. import __version__
from .disk import flush_writer
from .encoding import proto_schema
from .reader import METADATA_NAME


class LogPart:
    """An MCAP writer on ``fh`` (a new file, open for writing): :meth:`start` it, then
    :meth:`write`, :meth:`flush` and :meth:`finish`. Every failure raises (the flight
    log's writer turns it into its fault state)."""

    def __init__(self, fh: IO[bytes], chunk_size_bytes: int) -> None:
        self.fh = fh
        self.mcap = Writer(fh, chunk_size=chunk_size_bytes, compression=CompressionType.ZSTD)
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._sequence: dict[int, int] = {}
        #: Messages were added since the last flush.
        self.dirty = False

    def start(self, metadata: Mapping[str, str]) -> None:
        """The header and the ``"tcm-companion"`` metadata record, pushed to the OS."""
        self.mcap.start(profile="", library=f"tcm-companion/{__version__} {LIBRARY_IDENTIFIER}")
        self.mcap.add_metadata(METADATA_NAME, dict(metadata))
        self.fh.flush()

    def write(self, topic: str, channel_kind: str, log_ns: int, pub_ns: int, data: bytes) -> None:
        """One message on ``topic`` (its channel registered the first time); ``log_ns``
        wall-clock and ``pub_ns`` monotonic time stamps, ns."""
        channel_id = self._channels.get(topic)
        if channel_id is None:
            channel_id = self._register(topic, channel_kind)
        seq = self._sequence.get(channel_id, 0)
        self._sequence[channel_id] = (seq + 1) & 0xFFFFFFFF
        self.mcap.add_message(
            channel_id=channel_id, log_time=log_ns, data=data, publish_time=pub_ns, sequence=seq
        )
        self.dirty = True

    def _register(self, topic: str, channel_kind: str) -> int:
        if channel_kind == "mavlink":
            schema_id, encoding = 0, "mavlink"
        elif channel_kind == "json":
            schema = json.dumps({"title": topic, "type": "object"}).encode()
            schema_id = self.mcap.register_schema(name=topic, encoding="jsonschema", data=schema)
            encoding = "json"
        else:
            if channel_kind not in self._schemas:
                self._schemas[channel_kind] = self.mcap.register_schema(
                    name=channel_kind, encoding="protobuf", data=proto_schema(channel_kind)
                )
            schema_id, encoding = self._schemas[channel_kind], "protobuf"
        channel_id = self.mcap.register_channel(
            topic=topic, message_encoding=encoding, schema_id=schema_id
        )
        self._channels[topic] = channel_id
        return channel_id

    def flush(self) -> int:
        """End the open chunk and push it to the OS; the file's size (bytes) after it."""
        flush_writer(self.mcap, self.fh)
        self.dirty = False
        return self.fh.tell()

    def finish(self) -> int:
        """The summary and footer, fsync'ed, and the file closed; its size (bytes)."""
        self.mcap.finish()
        self.fh.flush()
        with contextlib.suppress(OSError):
            os.fsync(self.fh.fileno())
        size = self.fh.tell()
        self.fh.close()
        return size
