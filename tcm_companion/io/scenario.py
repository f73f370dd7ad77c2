"""Read ``tcm-scenario/1`` directories (see shared/docs/scenario-format.md).

Every check that fails raises :class:`ScenarioError` with the file, the line (where the
file has lines) and the problem, so a hand-built scenario can be fixed from the message
alone. Frames are read lazily, one at a time, in order.

A camera rig (``[[cameras]]``, docs/scenario-format.md "Camera rigs") is read by
:func:`load_rig` into a :class:`RigScenario`: one :class:`Scenario` per camera (its own
directory, frame times, truth and detections) sharing the rig's telemetry;
:func:`load_any` reads either form, and :func:`load_scenario` keeps reading one camera
only, exactly as before.

Damaged data is kept where intact and reported, not refused: a ``.tlog`` cut short, with
junk appended or with a corrupt stretch inside is read around the damage
(:mod:`.tlog`), and what was skipped, where, and how many records were kept is one of
:attr:`Scenario.warnings` (with ``tlog_stats``); only a ``.tlog`` with nothing usable is an
error. Unreadable frames: :meth:`Scenario.iter_frames_tolerant`.
"""

from __future__ import annotations

import csv
import math
import re
import tomllib
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from ..core.camera import _KEYS as _LENS_KEYS
from ..core.camera import (
    CameraModel,
    CameraModelError,
    Equirectangular,
    camera_from_dict,
)
from ..core.telemetry import AttitudeSample, PositionSample, TelemetrySample
from ..mavlink.samples import sample_from_message
from .tlog import TlogError, TlogStats, read_tlog
from .truth import Truth as Truth  # truth.csv's rows (scoring against them: .scoring)

if TYPE_CHECKING:
    from .scenario_extras import Detection, TargetSpec

FORMAT = "tcm-scenario/1"
FRAMES_HEADER = ["frame", "t_us"]
TRUTH_HEADER = [
    "frame",
    "object_id",
    "moving",
    "obj_n",
    "obj_e",
    "obj_d",
    "obj_radius_m",
    "veh_n",
    "veh_e",
    "veh_d",
]


class ScenarioError(ValueError):
    """A scenario is malformed; the message names the file, line and problem."""


@dataclass
class Scenario:
    """One flight on disk: camera, frame times, telemetry and optional truth."""

    root: Path
    name: str
    description: str
    camera: CameraModel
    frame_times_us: np.ndarray  # int64, strictly increasing
    telemetry: list[TelemetrySample]  # in receive order
    tlog_stats: TlogStats
    truth: Truth | None
    frames_dir: Path | None = None
    video: Path | None = None
    warnings: list[str] = field(default_factory=list)
    # what the objects look like ([[target]]; empty: saturated red spheres)
    targets: list[TargetSpec] = field(default_factory=list)
    # boxes of an external detector (detections.csv), in frame order; None: no file
    detections: list[Detection] | None = None

    @property
    def n_frames(self) -> int:
        return len(self.frame_times_us)

    def frame_path(self, index: int) -> Path:
        assert self.frames_dir is not None
        return self.frames_dir / f"{index:06d}.png"

    def iter_frames(self) -> Iterator[tuple[int, int, np.ndarray]]:
        """Yield ``(index, t_us, BGR image)`` in order; an unreadable frame is an error."""
        for i, t, img in self.iter_frames_tolerant(None):
            assert img is not None
            yield i, t, img

    def iter_frames_tolerant(
        self, on_unreadable: Callable[[int, str], None] | None
    ) -> Iterator[tuple[int, int, np.ndarray | None]]:
        """Yield ``(index, t_us, image)`` in order. With ``on_unreadable``, a frame that
        cannot be read (missing, empty, corrupt, wrong size; a video that stops decoding)
        is reported to it and yielded as ``None`` instead of raising :class:`ScenarioError`."""

        def bad(i: int, exc: ScenarioError) -> None:
            if on_unreadable is None:
                raise exc
            on_unreadable(i, str(exc))

        if self.frames_dir is not None:
            # The next image is read (PNG decoding: ~1.5 ms at 360×220, the GIL released)
            # on a thread while the caller processes this one; the order and the reports
            # are those of reading them one after the other.
            def load(i: int) -> tuple[np.ndarray | None, ScenarioError | None]:
                try:
                    return self.read_frame(i), None
                except ScenarioError as exc:
                    return None, exc

            n = len(self.frame_times_us)
            with ThreadPoolExecutor(1, thread_name_prefix="tcm-frame-reader") as pool:
                ahead = pool.submit(load, 0) if n else None
                for i, t in enumerate(self.frame_times_us):
                    assert ahead is not None
                    img, exc = ahead.result()
                    ahead = pool.submit(load, i + 1) if i + 1 < n else None
                    if exc is not None:
                        bad(i, exc)
                    yield i, int(t), img
            return
        assert self.video is not None
        cap = cv2.VideoCapture(str(self.video))
        decoding = True
        try:
            for i, t in enumerate(self.frame_times_us):
                img = None
                if decoding:
                    ok, img = cap.read()
                    if not ok or img is None:
                        decoding = False  # a video that stops decoding does not resume
                        img = None
                        bad(
                            i,
                            ScenarioError(
                                f"{self.video}: frame {i} cannot be decoded (frames.csv lists"
                                f" {self.n_frames} frames); the rest are unreadable too"
                            ),
                        )
                    else:
                        try:
                            self._check_size(img, f"{self.video}: frame {i}")
                        except ScenarioError as exc:
                            bad(i, exc)
                            img = None
                yield i, int(t), img
        finally:
            cap.release()

    def read_frame(self, index: int) -> np.ndarray:
        """One frame of a frames directory as a BGR uint8 image."""
        path = self.frame_path(index)
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise ScenarioError(f"{path}: cannot be read as an image")
        self._check_size(img, str(path))
        return img

    def _check_size(self, img: np.ndarray, where: str) -> None:
        h, w = img.shape[:2]
        if (w, h) != (self.camera.width, self.camera.height):
            raise ScenarioError(
                f"{where}: image is {w}x{h} but scenario.toml [camera] says "
                f"{self.camera.width}x{self.camera.height}"
            )

    def attitude_samples(self) -> list[AttitudeSample]:
        return [s for s in self.telemetry if isinstance(s, AttitudeSample)]

    def position_samples(self) -> list[PositionSample]:
        return [s for s in self.telemetry if isinstance(s, PositionSample)]


def load_scenario(root: str | Path, check_frames: bool = True) -> Scenario:
    """Read and validate a one-camera scenario directory (``[camera]``).

    ``check_frames`` opens the first frame to check its size against the camera model
    (every frame is checked again when read). A rig (``[[cameras]]``) is refused here with
    a pointer to :func:`load_rig` (or :func:`load_any`, which reads either form).
    """
    root, toml_path, meta, text = _open_scenario(root)
    _refuse_both(toml_path, meta, text)
    if "cameras" in meta:
        raise ScenarioError(
            f"{toml_path}: this scenario is a camera rig ([[cameras]]), and this reads"
            " one-camera scenarios ([camera]); replay and eval read rigs (load_rig)"
        )
    name, description = _name_and_description(root, toml_path, meta)
    cam_table = meta.get("camera")
    if not isinstance(cam_table, dict):
        raise ScenarioError(f"{toml_path}: missing [camera] table")
    try:
        camera = camera_from_dict(cam_table, where=f"{toml_path}: camera")
    except CameraModelError as exc:
        raise ScenarioError(str(exc)) from None

    has_dir, has_video = "frames_dir" in meta, "video" in meta
    if has_dir == has_video:
        raise ScenarioError(f"{toml_path}: give exactly one of frames_dir or video")
    frames_dir, video, times = _frame_source(
        root, meta.get("frames_dir"), meta.get("video"), toml_path, ""
    )
    telemetry, stats, warnings = _read_telemetry(root / "telemetry.tlog", int(times[0]))

    from .scenario_extras import read_targets

    targets = read_targets(root)
    truth, detections = _camera_extras(root, camera, len(times))
    scenario = Scenario(
        root=root,
        name=name,
        description=str(description),
        camera=camera,
        frame_times_us=times,
        telemetry=telemetry,
        tlog_stats=stats,
        truth=truth,
        frames_dir=frames_dir,
        video=video,
        warnings=warnings,
        targets=targets,
        detections=detections,
    )
    if check_frames and frames_dir is not None and len(times):
        scenario.read_frame(0)
    return scenario


#: A rig camera's name: what the results CSV's ``camera`` column and file names carry.
CAMERA_NAME = re.compile(r"^[A-Za-z0-9_-]+$")
#: The keys of a ``[[cameras]]`` table besides the lens's (``camera_from_dict``'s).
RIG_CAMERA_KEYS = ("name", "dir", "frames_dir", "video")
#: Files a rig's top directory must not hold: each camera has its own, in its ``dir``.
_PER_CAMERA_FILES = ("frames.csv", "truth.csv", "detections.csv")


@dataclass
class RigScenario:
    """A camera rig on disk (``[[cameras]]``): several cameras on one vehicle, one
    telemetry. ``cameras[i]`` is camera id ``i`` as a one-camera :class:`Scenario` (its
    ``root`` the camera's ``dir``, its ``name`` ``"<rig>/<camera>"``, its own frame times,
    truth and detections; ``telemetry`` the rig's, the same list for every camera)."""

    root: Path
    name: str
    description: str
    camera_names: list[str]
    cameras: list[Scenario]
    telemetry: list[TelemetrySample]
    tlog_stats: TlogStats
    warnings: list[str] = field(default_factory=list)
    targets: list[TargetSpec] = field(default_factory=list)

    @property
    def n_frames(self) -> int:
        """Frames of every camera together."""
        return sum(c.n_frames for c in self.cameras)

    @property
    def has_truth(self) -> bool:
        return all(c.truth is not None for c in self.cameras)

    def attitude_samples(self) -> list[AttitudeSample]:
        return [s for s in self.telemetry if isinstance(s, AttitudeSample)]

    def position_samples(self) -> list[PositionSample]:
        return [s for s in self.telemetry if isinstance(s, PositionSample)]


def is_rig(root: str | Path) -> bool:
    """Whether scenario directory ``root``'s ``scenario.toml`` has ``[[cameras]]`` (a
    missing or unreadable one: False, and the reader says what is wrong)."""
    if not Path(root).is_dir():
        return False
    try:
        return "cameras" in _read_toml(Path(root) / "scenario.toml")
    except (ScenarioError, OSError):
        return False


def load_any(root: str | Path, check_frames: bool = True) -> Scenario | RigScenario:
    """A scenario directory of either form: :func:`load_rig` for ``[[cameras]]``, else
    :func:`load_scenario`."""
    return load_rig(root, check_frames) if is_rig(root) else load_scenario(root, check_frames)


def load_rig(root: str | Path, check_frames: bool = True) -> RigScenario:
    """Read and validate a rig scenario directory (``[[cameras]]``, docs/scenario-format.md).

    Errors name the file, the line and the problem: for a ``[[cameras]]`` table, the line
    of its header (``scenario.toml: line 9: [[cameras]] 2 (rear): ...``)."""
    root, toml_path, meta, text = _open_scenario(root)
    _refuse_both(toml_path, meta, text)
    tables = meta.get("cameras")
    if tables is None:
        raise ScenarioError(f"{toml_path}: no [[cameras]] tables (a one-camera scenario?)")
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise ScenarioError(f"{toml_path}: cameras must be an array of tables ([[cameras]])")
    if not tables:
        raise ScenarioError(f"{toml_path}: [[cameras]]: a rig needs at least one camera")
    for key in ("frames_dir", "video"):
        if key in meta:
            raise ScenarioError(
                f"{toml_path}: line {_key_line(text, key)}: {key} is a [[cameras]] key in a rig"
                " (each camera's frames are in its own dir)"
            )
    for fname in _PER_CAMERA_FILES:
        if (root / fname).exists():
            raise ScenarioError(
                f"{root / fname}: a rig keeps {fname} in each camera's dir, not at the top"
            )
    name, description = _name_and_description(root, toml_path, meta)
    real_root = root.resolve()
    seen_names: dict[str, int] = {}
    seen_dirs: dict[Path, int] = {}
    parsed: list[tuple[str, Path, CameraModel, Path | None, Path | None, np.ndarray]] = []
    for k, table in enumerate(tables):
        line = _header_line(text, "cameras", k, double=True)
        where = f"{toml_path}: line {line}: [[cameras]] {k + 1}"
        cam_name = table.get("name")
        if not isinstance(cam_name, str) or not CAMERA_NAME.match(cam_name):
            raise ScenarioError(
                f"{where}: name must be letters, digits, '_' or '-', got {cam_name!r}"
            )
        where = f"{where} ({cam_name})"
        if cam_name in seen_names:
            raise ScenarioError(
                f"{where}: name {cam_name!r} is already camera {seen_names[cam_name] + 1}'s"
            )
        seen_names[cam_name] = k
        cam_dir_text = table.get("dir")
        if not isinstance(cam_dir_text, str) or not cam_dir_text:
            raise ScenarioError(f"{where}: dir must be a relative path, got {cam_dir_text!r}")
        cam_dir = root / cam_dir_text
        if Path(cam_dir_text).is_absolute() or not cam_dir.resolve().is_relative_to(real_root):
            raise ScenarioError(f"{where}: dir {cam_dir_text!r} is not inside the scenario")
        if cam_dir.resolve() == real_root:
            raise ScenarioError(
                f"{where}: dir {cam_dir_text!r} is the scenario's top: each camera has its own"
            )
        if not cam_dir.is_dir():
            raise ScenarioError(f"{where}: dir {cam_dir} is not a directory")
        if cam_dir.resolve() in seen_dirs:
            raise ScenarioError(
                f"{where}: dir {cam_dir_text!r} is already camera"
                f" {seen_dirs[cam_dir.resolve()] + 1}'s"
            )
        seen_dirs[cam_dir.resolve()] = k
        if "frames_dir" in table and "video" in table:
            raise ScenarioError(f"{where}: give at most one of frames_dir or video")
        for key in ("frames_dir", "video"):
            value = table.get(key)
            if key in table and (
                not isinstance(value, str)
                or not value
                or Path(value).is_absolute()
                or not (cam_dir / value).resolve().is_relative_to(real_root)
            ):
                raise ScenarioError(f"{where}: {key} {value!r} is not a path inside the scenario")
        lens = {key: v for key, v in table.items() if key not in RIG_CAMERA_KEYS}
        allowed = {
            "model",
            "width",
            "height",
            "mount_rpy_deg",
            *_LENS_KEYS.get(str(lens.get("model")), ()),
        }
        unknown = sorted(set(lens) - allowed)
        if unknown and lens.get("model") in _LENS_KEYS:  # else: the model's error first
            raise ScenarioError(f"{where}: unknown key {unknown[0]!r}")
        try:
            camera = camera_from_dict(lens, where=f"{where}: camera")
        except CameraModelError as exc:
            raise ScenarioError(str(exc)) from None
        frames_dir, video, times = _frame_source(
            cam_dir,
            None if "video" in table else table.get("frames_dir", "frames"),
            table.get("video"),
            toml_path,
            f"line {line}: [[cameras]] {k + 1} ({cam_name}): ",
        )
        parsed.append((cam_name, cam_dir, camera, frames_dir, video, times))

    first_us = min(int(p[5][0]) for p in parsed)
    telemetry, stats, warnings = _read_telemetry(root / "telemetry.tlog", first_us)
    from .scenario_extras import read_targets

    targets = read_targets(root)
    cameras: list[Scenario] = []
    for cam_name, cam_dir, camera, frames_dir, video, times in parsed:
        truth, detections = _camera_extras(cam_dir, camera, len(times))
        sc = Scenario(
            root=cam_dir,
            name=f"{name}/{cam_name}",
            description=str(description),
            camera=camera,
            frame_times_us=times,
            telemetry=telemetry,
            tlog_stats=stats,
            truth=truth,
            frames_dir=frames_dir,
            video=video,
            targets=targets,
            detections=detections,
        )
        if check_frames and frames_dir is not None:
            sc.read_frame(0)
        cameras.append(sc)
    truths = [c.truth is not None for c in cameras]
    if any(truths) and not all(truths):
        missing = [n for n, t in zip(seen_names, truths) if not t]
        raise ScenarioError(
            f"{cameras[truths.index(False)].root / 'truth.csv'}: missing (cameras"
            f" {', '.join(missing)} have no truth.csv and the others have one: all or none)"
        )
    return RigScenario(
        root=root,
        name=name,
        description=str(description),
        camera_names=list(seen_names),
        cameras=cameras,
        telemetry=telemetry,
        tlog_stats=stats,
        warnings=warnings,
        targets=targets,
    )


def _open_scenario(root: str | Path) -> tuple[Path, Path, dict[str, Any], str]:
    """A scenario directory's root, ``scenario.toml`` path, parsed TOML and its text,
    the format checked."""
    root = Path(root)
    if not root.is_dir():
        raise ScenarioError(f"{root}: not a directory")
    toml_path = root / "scenario.toml"
    meta, text = read_toml_text(toml_path)
    if meta.get("format") != FORMAT:
        raise ScenarioError(f"{toml_path}: format must be {FORMAT!r}, got {meta.get('format')!r}")
    return root, toml_path, meta, text


def _refuse_both(toml_path: Path, meta: dict[str, Any], text: str) -> None:
    if "camera" in meta and "cameras" in meta:
        raise ScenarioError(
            f"{toml_path}: line {_header_line(text, 'camera', 0, double=False)}: both [camera]"
            " and [[cameras]]: a scenario has one camera ([camera]) or a rig ([[cameras]])"
        )


def _name_and_description(root: Path, toml_path: Path, meta: dict[str, Any]) -> tuple[str, str]:
    name = meta.get("name", root.name)
    if not isinstance(name, str):
        raise ScenarioError(f"{toml_path}: name must be a string")
    return name, str(meta.get("description", ""))


def _header_line(text: str, table: str, k: int, *, double: bool) -> int:
    """The line (1-based) of the ``k``-th ``[[table]]`` (or ``[table]``) header; 0 if
    not found."""
    pattern = rf"\s*\[\[\s*{table}\s*\]\]" if double else rf"\s*\[\s*{table}\s*\]"
    lines = [i + 1 for i, line in enumerate(text.splitlines()) if re.match(pattern, line)]
    return lines[k] if k < len(lines) else 0


def _key_line(text: str, key: str) -> int:
    """The line (1-based) of the first ``key = ...``; 0 if not found."""
    for i, line in enumerate(text.splitlines()):
        if re.match(rf"\s*{re.escape(key)}\s*=", line):
            return i + 1
    return 0


def _frame_source(
    base: Path, frames_dir_text: Any, video_text: Any, toml_path: Path, where: str
) -> tuple[Path | None, Path | None, np.ndarray]:
    """Frames of one camera in directory ``base``: its frames directory or video (one of
    the two given), and ``base/frames.csv``'s times, checked against each other."""
    frames_dir = video = None
    if frames_dir_text is not None:
        frames_dir = base / str(frames_dir_text)
        if not frames_dir.is_dir():
            raise ScenarioError(f"{toml_path}: {where}frames_dir {frames_dir} is not a directory")
    else:
        video = base / str(video_text)
        if not video.is_file():
            raise ScenarioError(f"{toml_path}: {where}video {video} does not exist")
    times = _read_frames_csv(base / "frames.csv")
    if frames_dir is not None:
        present = {p.name for p in frames_dir.iterdir()}
        for i in range(len(times)):
            if f"{i:06d}.png" not in present:
                raise ScenarioError(
                    f"{base / 'frames.csv'}: line {i + 2}: frame {i} has no file "
                    f"{frames_dir / f'{i:06d}.png'}"
                )
    else:
        assert video is not None
        cap = cv2.VideoCapture(str(video))
        if not cap.isOpened():
            raise ScenarioError(f"{video}: OpenCV cannot open this video")
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        cap.release()
        if 0 < count < len(times):
            raise ScenarioError(
                f"{base / 'frames.csv'}: lists {len(times)} frames but {video} holds {count}"
            )
    return frames_dir, video, times


def _read_telemetry(
    tlog_path: Path, first_frame_us: int
) -> tuple[list[TelemetrySample], TlogStats, list[str]]:
    """The scenario's telemetry, its reader's stats and the warnings about it."""
    warnings: list[str] = []
    if not tlog_path.is_file():
        raise ScenarioError(f"{tlog_path}: missing (telemetry is required)")
    try:
        records, stats = read_tlog(tlog_path)
    except TlogError as exc:
        raise ScenarioError(str(exc)) from None
    telemetry, types_seen = _telemetry_from_records(records)
    if not any(isinstance(s, AttitudeSample) for s in telemetry):
        raise ScenarioError(f"{tlog_path}: no ATTITUDE or ATTITUDE_QUATERNION from the autopilot")
    if "HEARTBEAT" not in types_seen:
        warnings.append(f"{tlog_path}: no HEARTBEAT")
    if not any(isinstance(s, PositionSample) for s in telemetry):
        warnings.append(f"{tlog_path}: no LOCAL_POSITION_NED (autopilot egomotion unavailable)")
    if stats.damaged or stats.time_backwards:
        # kept what is intact; say what was not, where, and when (from the first frame)
        warnings.append(f"{tlog_path}: {stats.summary(first_frame_us)}")
    return telemetry, stats, warnings


def _camera_extras(
    base: Path, camera: CameraModel, n_frames: int
) -> tuple[Truth | None, list[Detection] | None]:
    """One camera's optional ``truth.csv`` and ``detections.csv`` in directory ``base``."""
    from .scenario_extras import read_detections_csv

    truth_path = base / "truth.csv"
    truth = _read_truth_csv(truth_path, n_frames) if truth_path.is_file() else None
    det_path = base / "detections.csv"
    detections = None
    if det_path.is_file():
        full_panorama = isinstance(camera, Equirectangular) and math.isclose(
            camera.azimuth_max_deg - camera.azimuth_min_deg, 360.0
        )
        detections = read_detections_csv(
            det_path, n_frames, (camera.width, camera.height), wraps=full_panorama
        )
    return truth, detections


def _telemetry_from_records(records: list[Any]) -> tuple[list[TelemetrySample], set[str]]:
    """Telemetry samples from the autopilot (the system announcing itself as one)."""
    types_seen: set[str] = set()
    autopilot: tuple[int, int] | None = None
    for r in records:
        if r.msg.get_type() == "HEARTBEAT" and r.msg.autopilot != 8:  # 8: MAV_AUTOPILOT_INVALID
            autopilot = (r.msg.get_srcSystem(), r.msg.get_srcComponent())
            break
    samples: list[TelemetrySample] = []
    for r in records:
        types_seen.add(r.msg.get_type())
        if autopilot is not None and (r.msg.get_srcSystem(), r.msg.get_srcComponent()) != autopilot:
            continue
        s = sample_from_message(r.msg, r.recv_us)
        if s is not None:
            samples.append(s)
    return samples, types_seen


def _read_toml(path: Path) -> dict[str, Any]:
    return read_toml_text(path)[0]


def read_toml_text(path: Path) -> tuple[dict[str, Any], str]:
    """A scenario's ``scenario.toml``, parsed, and its text; ScenarioError when missing,
    not UTF-8 or not TOML."""
    try:
        text = path.read_text(encoding="utf-8")
        return tomllib.loads(text), text
    except FileNotFoundError:
        raise ScenarioError(f"{path}: missing (every scenario needs one)") from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: {exc}") from None
    except UnicodeDecodeError:
        raise ScenarioError(f"{path}: {not_utf8(path)}") from None


def not_utf8(path: Path | str) -> str:
    """Where a text file stops being UTF-8: one line for an error message."""
    data = Path(path).read_bytes()
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        return f"line {line}: not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start})"
    return "not UTF-8 text"


def csv_rows(path: Path, header: list[str]) -> Iterator[tuple[int, list[str]]]:
    """Rows of a scenario's CSV file with an exact header, as (line number, stripped
    fields), blank lines skipped; ScenarioError (file, line) when missing, not UTF-8, or
    a row has another number of fields."""
    try:
        fh = open(path, newline="", encoding="utf-8")
    except FileNotFoundError:
        raise ScenarioError(f"{path}: missing") from None
    with fh:
        reader = csv.reader(fh)
        try:
            first = next(reader, None)
            if first is None or [h.strip() for h in first] != header:
                raise ScenarioError(
                    f"{path}: line 1: header must be {','.join(header)!r}, got {first!r}"
                )
            for row in reader:
                if not row or all(not c.strip() for c in row):
                    continue
                if len(row) != len(header):
                    raise ScenarioError(
                        f"{path}: line {reader.line_num}: expected {len(header)} fields,"
                        f" got {len(row)}"
                    )
                yield reader.line_num, [c.strip() for c in row]
        except UnicodeDecodeError:
            raise ScenarioError(f"{path}: {not_utf8(path)}") from None


def int_field(path: Path, line: int, name: str, text: str) -> int:
    """Field ``name`` of a CSV line as an integer, else a ScenarioError naming it."""
    try:
        return int(text)
    except ValueError:
        raise ScenarioError(
            f"{path}: line {line}: {name} must be an integer, got {text!r}"
        ) from None


def float_field(path: Path, line: int, name: str, text: str) -> float:
    """Field ``name`` of a CSV line as a finite number, else a ScenarioError naming it."""
    try:
        value = float(text)
    except ValueError:
        raise ScenarioError(f"{path}: line {line}: {name} must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise ScenarioError(f"{path}: line {line}: {name} must be finite, got {text!r}")
    return value


def _read_frames_csv(path: Path) -> np.ndarray:
    times: list[int] = []
    for line, (f_text, t_text) in csv_rows(path, FRAMES_HEADER):
        frame = int_field(path, line, "frame", f_text)
        t_us = int_field(path, line, "t_us", t_text)
        if frame != len(times):
            raise ScenarioError(
                f"{path}: line {line}: frame {frame} out of order (expected {len(times)})"
            )
        if times and t_us <= times[-1]:
            raise ScenarioError(
                f"{path}: line {line}: t_us {t_us} does not increase (previous {times[-1]})"
            )
        times.append(t_us)
    if not times:
        raise ScenarioError(f"{path}: no frames")
    return np.asarray(times, dtype=np.int64)


def _read_truth_csv(path: Path, n_frames: int) -> Truth:
    cols: dict[str, list[float]] = {h: [] for h in TRUTH_HEADER}
    for line, row in csv_rows(path, TRUTH_HEADER):
        frame = int_field(path, line, "frame", row[0])
        if not 0 <= frame < n_frames:
            raise ScenarioError(f"{path}: line {line}: frame {frame} is not in frames.csv")
        obj = int_field(path, line, "object_id", row[1])
        moving = int_field(path, line, "moving", row[2])
        if moving not in (0, 1):
            raise ScenarioError(f"{path}: line {line}: moving must be 0 or 1, got {row[2]!r}")
        cols["frame"].append(frame)
        cols["object_id"].append(obj)
        cols["moving"].append(moving)
        for name, text in zip(TRUTH_HEADER[3:], row[3:]):
            cols[name].append(float_field(path, line, name, text))
        if cols["obj_radius_m"][-1] <= 0:
            raise ScenarioError(f"{path}: line {line}: obj_radius_m must be positive")
    return Truth(
        frame=np.asarray(cols["frame"], dtype=np.int64),
        object_id=np.asarray(cols["object_id"], dtype=np.int64),
        moving=np.asarray(cols["moving"], dtype=bool),
        obj_ned_m=np.column_stack([cols["obj_n"], cols["obj_e"], cols["obj_d"]]).astype(np.float64),
        obj_radius_m=np.asarray(cols["obj_radius_m"], dtype=np.float64),
        veh_ned_m=np.column_stack([cols["veh_n"], cols["veh_e"], cols["veh_d"]]).astype(np.float64),
    )
