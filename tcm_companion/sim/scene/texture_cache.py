"""The simulator's textures, kept on disk between runs.

A scenario's ground and sky textures are pure functions of their seeds and settings
(:func:`~tcm_companion.sim.scene.world.ground_textures`), but building the ground's costs
~2 s of CPU (band-limited noise through FFTs, on a 4096² texel lawn): a quarter of a
20-s virtual-time SITL run, at every start of ``sitl``, ``eval``, ``demo`` and ``bench``.
They are kept in ``$TCM_COMPANION_CACHE`` (default ``$XDG_CACHE_HOME/tcm-companion``,
else ``~/.cache/tcm-companion``; ``TCM_COMPANION_CACHE=off`` turns the cache off) as
``.npz`` files named by a digest of what they depend on: the settings (their ``repr``),
the source of the module that builds them, and the numpy and OpenCV versions. A change
to any of these names another file, so a stale texture is never read; old files are
not removed (each is a few tens of MB: ``rm -r ~/.cache/tcm-companion`` frees them).

The cache is an optimisation only: a file that cannot be read (truncated, another
format, arrays of the wrong shape) is rebuilt and rewritten, and a directory that cannot
be written is skipped — in both cases the textures are the ones built from scratch, to
the bit (``np.savez`` keeps arrays exactly).
"""

from __future__ import annotations

import hashlib
import logging
import os
import tempfile
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path

import cv2
import numpy as np

log = logging.getLogger(__name__)

#: The environment variable naming the cache directory ("off": no cache).
CACHE_ENV = "TCM_COMPANION_CACHE"


def cache_dir() -> Path | None:
    """Where textures are kept, or None when the cache is off."""
    explicit = os.environ.get(CACHE_ENV, "")
    if explicit.strip().lower() in ("off", "0", "no", "false"):
        return None
    if explicit:
        return Path(explicit)
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "tcm-companion"


def _digest(kind: str, settings: object, source_file: str) -> str:
    h = hashlib.sha256()
    for part in (kind, repr(settings), np.__version__, cv2.__version__):
        h.update(part.encode() + b"\0")
    h.update(Path(source_file).read_bytes())
    return h.hexdigest()[:24]


def cached_arrays(
    kind: str,
    settings: object,
    source_file: str,
    keys: tuple[str, ...],
    build: Callable[[], Mapping[str, np.ndarray]],
) -> dict[str, np.ndarray]:
    """``build()``'s arrays (named ``keys``), from the cache when it holds them for these
    ``settings`` (and this ``source_file``, the module whose code builds them), else
    built and kept."""
    where = cache_dir()
    path = None if where is None else where / f"{kind}-{_digest(kind, settings, source_file)}.npz"
    if path is not None and path.is_file():
        try:
            with np.load(path, allow_pickle=False) as npz:
                if sorted(npz.files) != sorted(keys):
                    raise ValueError(f"holds {sorted(npz.files)}, not {sorted(keys)}")
                return {k: npz[k] for k in keys}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:  # damaged: rebuilt
            log.warning("texture cache %s unreadable (%s): rebuilding it", path, exc)
    arrays = dict(build())
    if path is not None:
        _store(path, arrays)
    return arrays


def _store(path: Path, arrays: Mapping[str, np.ndarray]) -> None:
    """Write atomically (a reader never sees half a file); any failure only costs the
    next run the build."""
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}-", suffix=".npz", dir=path.parent)
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)  # type: ignore[arg-type]
        os.replace(tmp, path)
        tmp = None
    except OSError as exc:
        log.info("texture cache %s not written: %s", path, exc)
    finally:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass
