"""Process-level tuning of glibc's allocator for frame-rate numpy work.

numpy allocates its temporaries per operation; arrays above glibc's mmap threshold
(128 KiB by default: a 360×220 float image is 620 KiB) are mapped fresh and unmapped on
free, so every operation pays page faults again. On the virtual machines measured here a
page fault is expensive enough that `pixel_from_bearing_cam` over a 360×220 image took
15 ms instead of 6 ms. Raising the mmap and trim thresholds keeps freed memory in the
heap for reuse. The same can be set from outside with MALLOC_MMAP_THRESHOLD_ and
MALLOC_TRIM_THRESHOLD_ (the systemd unit does); this function is for the CLI.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys
from typing import Any

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024  # glibc's largest allowed on 64-bit
TRIM_THRESHOLD_BYTES = 256 * 1024 * 1024


def _glibc_function(name: str) -> Any | None:
    """``name`` from the C library, or None where there is no glibc (not Linux, musl …)."""
    if not sys.platform.startswith("linux"):
        return None
    lib = ctypes.util.find_library("c")
    if lib is None:
        return None
    try:
        return getattr(ctypes.CDLL(lib), name)
    except (OSError, AttributeError):
        return None


def tune_allocator() -> bool:
    """Raise glibc's mmap/trim thresholds; False where there is no glibc (no change)."""
    mallopt = _glibc_function("mallopt")
    if mallopt is None:
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    ok = mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) == 1
    return mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) == 1 and ok


def trim_heap() -> bool:
    """Give the heap's free memory back to the kernel (glibc ``malloc_trim(0)``).

    With the raised trim threshold nothing is returned on its own, so memory that was
    only needed at start-up — compiling a module without a ``.pyc`` (the generated MAVLink
    dialect: ~70 MiB), building lookup tables — would stay resident. The daemon calls
    this once it is running. False where there is no glibc.
    """
    malloc_trim = _glibc_function("malloc_trim")
    if malloc_trim is None:
        return False
    malloc_trim.argtypes = [ctypes.c_size_t]
    malloc_trim.restype = ctypes.c_int
    malloc_trim(0)
    return True
