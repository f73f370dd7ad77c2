"""Small files that survive restarts: parameter values, the signing key and timestamp.

All writes are atomic (temporary file, fsync, rename), so a power cut leaves either the
old or the new file, never half of one. Reads never crash the daemon on a damaged file:
a corrupt parameter file is set aside (``.corrupt``) and the defaults are used, with a
message saying so. The signing key is the exception: a key readable by other users is
refused outright, because signing with it would be theatre.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import stat
from pathlib import Path


class SigningKeyError(ValueError):
    """The signing key file is missing, unreadable, malformed or too open."""


def atomic_write(path: Path, data: bytes, mode: int = 0o600) -> None:
    tmp = path.with_name(path.name + ".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, path)


def _set_aside(path: Path) -> Path:
    """Move ``path`` to ``NAME.corrupt`` (``NAME.corrupt.1``, ... when an earlier one is
    there: a second damaged file never replaces the first); the new name."""
    for n in range(1000):
        aside = path.with_name(path.name + ".corrupt" + (f".{n}" if n else ""))
        try:
            os.link(path, aside)  # fails if aside exists: nothing is ever replaced
        except FileExistsError:
            continue
        except OSError:  # no hard links here (vfat): look, then rename
            if os.path.lexists(aside):
                continue
            os.rename(path, aside)
            return aside
        os.unlink(path)
        return aside
    raise FileExistsError(f"{path}: 1000 files set aside beside it already")


class ParamStore:
    """Parameter values as JSON (``{"TCM_THRESH": 0.09, ...}``)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.warnings: list[str] = []

    def load(self) -> dict[str, float]:
        try:
            raw = self.path.read_bytes()
        except FileNotFoundError:
            return {}
        try:
            doc = json.loads(raw)
            if not isinstance(doc, dict):
                raise ValueError("not a JSON object")
            values = {str(k): float(v) for k, v in doc.items() if isinstance(v, int | float)}
            if any(not math.isfinite(v) for v in values.values()):
                raise ValueError("non-finite value")
        except ValueError as exc:
            aside = _set_aside(self.path)
            self.warnings.append(f"{self.path}: {exc}; moved to {aside}, using defaults")
            return {}
        return values

    def save(self, values: dict[str, float]) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(
            self.path, json.dumps(values, indent=1, sort_keys=True).encode() + b"\n", 0o644
        )


def load_signing_key(path: str | Path) -> bytes:
    """The 32-byte MAVLink signing key from ``path``.

    The file holds 64 hex digits, 32 raw bytes, or a passphrase (hashed with SHA-256, as
    MAVProxy's ``signing setup`` does). It must not be readable by group or others.
    """
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        raise SigningKeyError(f"{p}: signing key file does not exist") from None
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise SigningKeyError(
            f"{p}: signing key is accessible to other users (mode {stat.S_IMODE(st.st_mode):04o}); "
            f"run: chmod 600 {p}"
        )
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise SigningKeyError(f"{p}: cannot read signing key: {exc.strerror}") from None
    text = raw.strip()
    if len(text) == 64:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (ValueError, UnicodeDecodeError):
            pass
    if len(raw) == 32:
        return raw
    if not text:
        raise SigningKeyError(f"{p}: signing key file is empty")
    return hashlib.sha256(text).digest()


class TimestampStore:
    """The signing timestamp (10 µs units since 2015), so a restart never reuses one."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    def load(self) -> int:
        try:
            return max(0, int(self.path.read_text().strip()))
        except (FileNotFoundError, ValueError):
            return 0

    def save(self, timestamp: int) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(self.path, f"{int(timestamp)}\n".encode())
