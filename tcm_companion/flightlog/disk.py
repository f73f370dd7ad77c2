"""The flight log's files on the disk: the free-space floor, and pushing a part's open
chunk to the OS (the crash-safety bound)."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path
from typing import IO

from mcap.writer import Writer


def disk_free(path: Path) -> int:
    """Free bytes on the file system of ``path``."""
    return shutil.disk_usage(path).free


def flush_writer(writer: Writer, fh: IO[bytes]) -> None:
    """End the open chunk and push everything to the OS (mcap's ``Writer.flush()``; the
    same steps through its private methods on versions before it existed)."""
    flush = getattr(writer, "flush", None)
    if callable(flush):
        flush()
    else:  # pragma: no cover - old mcap
        getattr(writer, "_Writer__finalize_chunk")()  # noqa: B009 (name-mangled)
        getattr(writer, "_Writer__flush")()  # noqa: B009
    fh.flush()


#: A megabyte of the ``[logging]`` sizes (10⁶ bytes).
MB = 1_000_000
#: Besides a chunk, what a new part's start needs (header, metadata record), bytes.
PART_START_BYTES = 65_536


class FreeSpace:
    """The free space of the log's directory against the ``min_free_mb`` floor.

    ``low`` is whether it was below the floor when last :meth:`checked`; a failing
    ``free_bytes`` (e.g. the directory is gone) changes nothing: the write path will tell.
    """

    def __init__(
        self,
        directory: Path,
        min_free_mb: float,
        free_bytes: Callable[[Path], int] | None = None,
    ) -> None:
        self.directory = directory
        self.floor_bytes = min_free_mb * MB
        self._free_bytes = free_bytes if free_bytes is not None else disk_free
        self.low = False

    def _free(self) -> int | None:
        try:
            return int(self._free_bytes(self.directory))
        except Exception:
            return None

    def checked(self) -> bool:
        """Look again; True when ``low`` changed."""
        free = self._free()
        if free is None:
            return False
        low = free < self.floor_bytes
        if low == self.low:
            return False
        self.low = low
        return True

    def room_for_a_part(self, chunk_size_bytes: int) -> bool:
        """After a full disk: free space for a part's start and a chunk (unknown: try)."""
        free = self._free()
        return free is None or free >= chunk_size_bytes + PART_START_BYTES
