"""The flight log's files on the disk: free space, and pushing a part's open chunk to
the OS (the crash-safety bound)."""

from __future__ import annotations

import shutil
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
