"""Output files and directories that appear whole or not at all.

A command that writes a results CSV, a scenario directory or a log writes it under a
temporary name beside the target and renames it into place only when it is complete, so
an interrupted or failed run never leaves a partial output behind (nor destroys the
previous one). An existing output is replaced only when asked (``--force``).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import TextIO


class OutputExists(FileExistsError):
    """The output is there already and replacing it was not asked for."""


def check_writable(path: Path | str, force: bool) -> Path:
    """``path`` as a Path; :class:`OutputExists` when it exists and ``force`` is off."""
    p = Path(path)
    if p.exists() and not force:
        kind = "directory" if p.is_dir() else "file"
        raise OutputExists(f"{p}: the {kind} exists; pass --force to replace it")
    return p


@contextlib.contextmanager
def atomic_text(path: Path | str, *, force: bool = False) -> Iterator[TextIO]:
    """A text file (newline="" for csv) written as ``.<name>.*.tmp`` beside ``path`` and
    renamed over it (after an fsync) when the ``with`` block ends without an error; on
    an error the temporary file is removed and ``path`` is untouched."""
    p = check_writable(path, force)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "w", newline="") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, p)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_path(path: Path | str, *, force: bool = False, is_dir: bool = False) -> Iterator[Path]:
    """A temporary path beside ``path`` for a writer that wants a path of its own (a
    directory when ``is_dir``, else a file name not yet created); moved over ``path``
    when the ``with`` block ends without an error, removed otherwise."""
    p = check_writable(path, force)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent))
    target = tmp if is_dir else tmp / p.name
    try:
        yield target
        if p.is_dir() and not p.is_symlink():
            old = Path(tempfile.mkdtemp(prefix=f".{p.name}.", suffix=".old", dir=p.parent))
            os.replace(p, old / p.name)
            os.replace(target, p)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(target, p)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
