"""``[logging]``: where and how the flight log is written (:class:`LoggingConfig`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class LoggingConfig:
    """Table ``[logging]`` of config.toml."""

    enabled: bool = True
    directory: str = ""  # "": resolved by the caller ($LOGS_DIRECTORY or a default)
    image_format: Literal["jpeg", "png"] = "jpeg"  # png = lossless (exact replay)
    jpeg_quality: int = 65  # ~9.7 kB per 360x220 frame: under 1 GB per hour at 25 Hz
    queue_items: int = 256  # bounded queue between the daemon and the writer thread
    chunk_size_bytes: int = 262_144
    flush_interval_s: float = 0.5  # at most this much is lost on a kill -9
    rotate_size_mb: float = 1024.0
    rotate_interval_s: float = 3600.0
    min_free_mb: float = 500.0  # below this free space, frames stop being logged

    def __post_init__(self) -> None:
        def bad(name: str, want: str) -> ValueError:
            return ValueError(f"{name} must be {want}, got {getattr(self, name)!r}")

        if not isinstance(self.enabled, bool):
            raise bad("enabled", "true or false")
        if not isinstance(self.directory, str):
            raise bad("directory", "a string")
        if self.image_format not in ("jpeg", "png"):
            raise bad("image_format", '"jpeg" or "png"')
        if not _is_int(self.jpeg_quality) or not 1 <= self.jpeg_quality <= 100:
            raise bad("jpeg_quality", "an integer in 1..100")
        if not _is_int(self.queue_items) or not 1 <= self.queue_items <= 1_000_000:
            raise bad("queue_items", "an integer in 1..1000000")
        if not _is_int(self.chunk_size_bytes) or not 1024 <= self.chunk_size_bytes <= 1 << 30:
            raise bad("chunk_size_bytes", "an integer in 1024..1073741824")
        if not _is_num(self.flush_interval_s) or not 0 < self.flush_interval_s <= 60:
            raise bad("flush_interval_s", "in (0, 60] s")
        if not _is_num(self.rotate_size_mb) or not self.rotate_size_mb > 0:
            raise bad("rotate_size_mb", "> 0")
        if not _is_num(self.rotate_interval_s) or not self.rotate_interval_s > 0:
            raise bad("rotate_interval_s", "> 0 s")
        if not _is_num(self.min_free_mb) or not self.min_free_mb >= 0:
            raise bad("min_free_mb", ">= 0")


def _is_int(x: object) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _is_num(x: object) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
