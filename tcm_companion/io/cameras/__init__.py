"""Camera sources behind one interface, read by one thread per camera.

- :mod:`.base` — the contract: :class:`FrameSource` (``open``/``read``/``close``),
  :class:`Frame`, :class:`CameraStats`, the errors (the companion
  clock the capture times are on is :func:`tcm_companion.io.aio.monotonic_us`).
- :mod:`.reader` — :class:`CameraReader`, the per-camera daemon thread.
- Sources: :class:`OpenCVDevice`, :class:`GStreamerSource`, :class:`VideoFileSource`
  (:mod:`.opencv`), :class:`FramesDirSource`, :class:`ScenarioSource`,
  :class:`DualFisheyeSource` (with ``stitch.FisheyeStitcher``). The simulator's cameras
  are the simulator's (:mod:`tcm_companion.sim.sources`).
- :mod:`.settings` — ``[camera]`` of config.toml and :func:`open_source`, the registry
  (:func:`register_source` adds a kind).

Sources are imported lazily (``from tcm_companion.io.cameras import OpenCVDevice`` imports
only :mod:`.opencv`), as python-can imports its interfaces.
"""

from __future__ import annotations

import importlib
from typing import Any

from .base import (
    CameraError,
    CameraGone,
    CameraStats,
    EndOfStream,
    Frame,
    FrameSource,
)
from .reader import CameraReader

_LAZY = {
    "OpenCVDevice": ".opencv",
    "GStreamerSource": ".opencv",
    "VideoFileSource": ".opencv",
    "gstreamer_available": ".opencv",
    "FramesDirSource": ".frames_dir",
    "ScenarioSource": ".scenario_source",
    "DualFisheyeSource": ".dual_fisheye",
    "CameraSourceConfig": ".settings",
    "FisheyeCameraConfig": ".settings",
    "open_source": ".settings",
    "register_source": ".settings",
}

__all__ = [
    "CameraError",
    "CameraGone",
    "CameraReader",
    "CameraStats",
    "EndOfStream",
    "Frame",
    "FrameSource",
    *_LAZY,
]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(module, __name__), name)
