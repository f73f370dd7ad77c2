"""Write ``tcm-scenario/1`` directories (shared/docs/scenario-format.md; the reader is
:mod:`.scenario`).

One writer for both producers of scenarios: the simulator's ``sim export``
(:func:`tcm_companion.sim.scene.export.export_scenario`) and the flight-log converter's
``export`` (:func:`tcm_companion.logtools.convert.log_to_scenario`). A
:class:`ScenarioWriter` owns one directory: ``frames/NNNNNN.png`` and ``frames.csv``
(capture times, µs on the telemetry's clock), ``telemetry.tlog``, ``truth.csv``,
``detections.csv`` and ``scenario.toml`` (:func:`scenario_toml`), and removes what a
previous, longer scenario left there (frames past the last one, a ``detections.csv``
that no longer applies). Each producer calls what it has, in its own order; the bytes
of every file are the same as before the two shared this module.

A rig (``[[cameras]]``) is written by a :class:`RigWriter`: ``scenario.toml``
(:func:`rig_scenario_toml`) and ``telemetry.tlog`` at the top, and one
:class:`ScenarioWriter` per camera in ``cameras/NAME`` for its frames, ``frames.csv``,
``truth.csv`` and ``detections.csv``.

``scenario.toml`` keeps the two layouts its producers have always written (the same
keys and values, read alike): the simulator writes each array on one line
(``layout="inline"``), the log converter writes it with ``tomli_w``, one item a line
(``layout="tomli_w"``).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np

from ..core.camera import CameraModel
from .scenario import FORMAT, FRAMES_HEADER, TRUTH_HEADER
from .scenario_extras import Detection, write_detections_csv
from .tlog import TlogWriter
from .truth import Truth

__all__ = [
    "FRAME_NAME",
    "RigWriter",
    "ScenarioWriter",
    "TomlLayout",
    "rig_scenario_toml",
    "scenario_toml",
]

#: A frame file of ``frames/``: ``NNNNNN.png``, six digits, the frame's index.
FRAME_NAME = re.compile(r"^\d{6}\.png$")

TomlLayout = Literal["inline", "tomli_w"]


def _toml_value(v: Any) -> str:
    """One value of the ``inline`` layout (arrays on one line)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        text = repr(v)
        return text if any(c in text for c in ".eE") else text + ".0"
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def scenario_toml(
    name: str,
    description: str,
    camera: CameraModel,
    *,
    extra: str = "",
    layout: TomlLayout = "inline",
) -> str:
    """The text of ``scenario.toml``: the format, ``name``, ``description``,
    ``frames_dir = "frames"`` and the ``[camera]`` table of ``camera``; ``extra``
    (further tables, e.g. the simulator's ``[[target]]``s) is appended as it is.
    ``layout``: how arrays are written (module docstring)."""
    doc: dict[str, Any] = {
        "format": FORMAT,
        "name": name,
        "description": description,
        "frames_dir": "frames",
        "camera": camera.to_dict(),
    }
    if layout == "tomli_w":
        import tomli_w

        return tomli_w.dumps(doc) + extra
    lines = [f"{k} = {_toml_value(v)}" for k, v in doc.items() if k != "camera"]
    lines += ["", "[camera]"]
    lines += [f"{k} = {_toml_value(v)}" for k, v in doc["camera"].items()]
    return "\n".join(lines) + "\n" + extra


def rig_camera_dir(camera_name: str) -> str:
    """Where a rig's writer puts camera ``camera_name``'s files: ``cameras/NAME``."""
    return f"cameras/{camera_name}"


def rig_scenario_toml(
    name: str,
    description: str,
    cameras: Sequence[tuple[str, CameraModel]],
    *,
    extra: str = "",
) -> str:
    """The text of a rig's ``scenario.toml``: the format, ``name``, ``description`` and
    one ``[[cameras]]`` table per ``(camera name, lens)`` in camera-id order (``name``,
    ``dir = "cameras/NAME"``, the lens's keys; arrays on one line); ``extra`` appended."""
    lines = [
        f"format = {_toml_value(FORMAT)}",
        f"name = {_toml_value(name)}",
        f"description = {_toml_value(description)}",
    ]
    for cam_name, camera in cameras:
        lines += ["", "[[cameras]]", f"name = {_toml_value(cam_name)}"]
        lines.append(f"dir = {_toml_value(rig_camera_dir(cam_name))}")
        lines += [f"{k} = {_toml_value(v)}" for k, v in camera.to_dict().items()]
    return "\n".join(lines) + "\n" + extra


class _ScenarioFiles:
    """What a scenario directory and a rig's have at their top: ``scenario.toml`` and
    ``telemetry.tlog`` (a rig's is the whole rig's), at ``root`` (made if missing)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def write_toml(self, text: str) -> None:
        """``scenario.toml`` (its text: :func:`scenario_toml`, :func:`rig_scenario_toml`)."""
        (self.root / "scenario.toml").write_text(text, encoding="utf-8")

    def write_telemetry(self, data: bytes) -> None:
        """``telemetry.tlog`` from a ``.tlog``'s bytes."""
        (self.root / "telemetry.tlog").write_bytes(data)

    def write_telemetry_records(self, records: Iterable[tuple[int, bytes]]) -> None:
        """``telemetry.tlog`` from ``(receive time µs, packed MAVLink frame)`` pairs."""
        with open(self.root / "telemetry.tlog", "wb") as fh:
            writer = TlogWriter(fh)
            for recv_us, frame in records:
                writer.write(recv_us, frame)


class RigWriter(_ScenarioFiles):
    """A rig scenario directory being written at ``root``: ``scenario.toml`` and
    ``telemetry.tlog`` at the top, each camera's files through :meth:`camera` (a
    :class:`ScenarioWriter` of ``cameras/NAME``)."""

    def camera(self, camera_name: str) -> ScenarioWriter:
        """The writer of camera ``camera_name``'s frames, ``frames.csv``, ``truth.csv``
        and ``detections.csv`` (in ``cameras/NAME``)."""
        return ScenarioWriter(self.root / rig_camera_dir(camera_name))


class ScenarioWriter(_ScenarioFiles):
    """One ``tcm-scenario/1`` directory being written at ``root`` (made, with its
    ``frames/``, if missing)."""

    def __init__(self, root: str | Path) -> None:
        super().__init__(root)
        self.frames_dir = self.root / "frames"
        self.frames_dir.mkdir(exist_ok=True)

    def write_frame(self, index: int, image: np.ndarray) -> None:
        """Frame ``index`` (BGR uint8) as ``frames/NNNNNN.png``; OSError if it cannot."""
        path = self.frames_dir / f"{index:06d}.png"
        if not cv2.imwrite(str(path), image):
            raise OSError(f"{path}: cv2.imwrite failed")

    def write_frames_csv(self, times_us: Iterable[int]) -> None:
        """``frames.csv``: frame ``i``'s capture time (µs, the telemetry's clock)."""
        with open(self.root / "frames.csv", "w", newline="") as fh:
            fh.write(",".join(FRAMES_HEADER) + "\n")
            for i, t in enumerate(times_us):
                fh.write(f"{i},{int(t)}\n")

    def write_truth(self, truth: Truth) -> None:
        """``truth.csv``: one row per frame and object (NED metres, 6 decimals)."""
        tr = truth
        with open(self.root / "truth.csv", "w", newline="") as fh:
            fh.write(",".join(TRUTH_HEADER) + "\n")
            for j in range(len(tr.frame)):
                o, v = tr.obj_ned_m[j], tr.veh_ned_m[j]
                fh.write(
                    f"{int(tr.frame[j])},{int(tr.object_id[j])},{int(tr.moving[j])},"
                    f"{o[0]:.6f},{o[1]:.6f},{o[2]:.6f},{tr.obj_radius_m[j]:.6f},"
                    f"{v[0]:.6f},{v[1]:.6f},{v[2]:.6f}\n"
                )

    def write_detections(self, rows: Iterable[Detection]) -> None:
        """``detections.csv``: an external detector's boxes, in frame order."""
        write_detections_csv(self.root / "detections.csv", rows)

    def remove_detections(self) -> None:
        """Remove a ``detections.csv`` left by an earlier scenario (none: nothing)."""
        (self.root / "detections.csv").unlink(missing_ok=True)

    def remove_stale_frames(self, n_frames: int) -> None:
        """Remove the ``frames/NNNNNN.png`` of index ``n_frames`` and above (left by an
        earlier, longer scenario); other files are left alone."""
        for stale in self.frames_dir.iterdir():
            if FRAME_NAME.match(stale.name) and int(stale.name[:6]) >= n_frames:
                stale.unlink()
