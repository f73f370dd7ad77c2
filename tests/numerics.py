"""What decides the last bits of a float on this install and machine: the tests that
compare against recorded bytes (reference logs, rendered frames) ask it whether they are
on the machine kind their record was made on."""

from __future__ import annotations

import importlib
import platform
from importlib import metadata
from pathlib import Path
from typing import Any


def numeric_environment() -> dict[str, Any]:
    """What decides the last bits of the core's floats on this install and machine.

    The numpy, SciPy and OpenCV releases; the OpenBLAS kernel numpy's bundled BLAS runs
    (matmul, solve: chosen for the CPU when numpy loads, or by OPENBLAS_CORETYPE; the
    core calls no BLAS through SciPy or OpenCV); the SIMD loops numpy dispatches to on
    this CPU.
    """
    import numpy as np
    from threadpoolctl import threadpool_info

    try:
        umath = importlib.import_module("numpy._core._multiarray_umath")
    except ImportError:  # numpy 1.x
        umath = importlib.import_module("numpy.core._multiarray_umath")
    numpy_dir = Path(np.__file__).resolve().parent
    blas = [
        f"{i.get('internal_api')} {i.get('architecture')}"
        for i in threadpool_info()
        if i.get("user_api") == "blas"
        and Path(i["filepath"]).resolve().parent.name in ("numpy.libs", numpy_dir.name)
        and Path(i["filepath"]).resolve().parent.parent == numpy_dir.parent
    ]
    return {
        "machine": platform.machine(),
        "packages": {
            name: metadata.version(name) for name in ("numpy", "scipy", "opencv-python-headless")
        },
        "numpy_blas": blas[0] if len(blas) == 1 else blas,
        "numpy_simd": sorted(f for f in umath.__cpu_dispatch__ if umath.__cpu_features__.get(f)),
    }


def numpy_blas_kernel() -> str:
    """The OpenBLAS kernel numpy's bundled BLAS runs here ("Haswell", "SkylakeX", ...):
    matrix products differ between kernels in the last bit (FMA, blocking)."""
    blas = numeric_environment()["numpy_blas"]
    return str(blas).rpartition(" ")[2] if isinstance(blas, str) else "unknown"


def numeric_kind() -> str:
    """The machine kind a recorded digest belongs to: the OpenBLAS kernel numpy runs and
    the widest group of SIMD loops numpy dispatches to ("Haswell X86_V3"). Both change
    the renderer's last bits: the kernel in its matrix products, the SIMD group in
    numpy's own loops (measured: on an AVX2-only AMD EPYC the COLLISION frames differ
    from those of an AVX-512 Xeon under the same Haswell kernel, and
    NPY_DISABLE_CPU_FEATURES=X86_V3 changes them again)."""
    levels = [f for f in numeric_environment()["numpy_simd"] if f.startswith("X86_V")]
    return f"{numpy_blas_kernel()} {max(levels) if levels else 'baseline'}"
