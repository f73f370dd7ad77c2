"""Process replay of a flight log: the logged inputs through the companion, again.

openpilot's process replay, for our daemon: the log holds every MAVLink byte received
(with its receive time), every camera frame (lossless with ``[logging] image_format =
"png"``) and, per processed frame, when it was processed, the clock offset the pipeline
used and the input-health override. Replaying drives a fresh
:class:`~tcm_companion.service.companion.Companion` — the daemon's own decisions, on a
fresh :class:`~tcm_companion.mavlink.endpoint.CompanionEndpoint` — with the received
bytes in the order and at the times they came (so telemetry filtering, parameter changes
from the ground station and the pipeline rebuilds they cause happen as they did), and
steps each logged frame at the point it was processed
(:meth:`~tcm_companion.service.companion.Companion.replay_frame`, with the logged clock
offset and override) — so with lossless frames the replayed results equal the logged ones
exactly (``tests/test_log_replay.py``).

Exactly means on the same install and machine. Elsewhere the last bits can move: numpy's
bundled OpenBLAS picks its kernels by CPU (or ``OPENBLAS_CORETYPE``), numpy picks SIMD
loops by CPU, and other numpy/OpenCV releases round differently. :func:`compare` is
bit-exact by default; ``rel_tol`` accepts such rounding differences in the disparity
(states and tracks must still agree exactly). ``docs/logging.md`` says which is which.

A truncated or damaged log (a killed daemon, a copy taken while it was written) replays as
far as it is readable; what was not is in the :class:`~tcm_companion.flightlog.reader.LogReport`
given to :func:`replay_log` (``replay --check`` fails on it).

A log with holes replays too. The writer drops frames by design (a full queue, the
disk's free-space floor, a full disk; counted in the health records), and a damaged
part loses its tail: a processed frame whose image is not in the log cannot be
recomputed (:class:`MissingFrame`), nor one whose result is not (a jump in the logged
``frame_index``). Replay skips it, counts it and goes on, but from then on its pipeline
lacks a frame the daemon's had (flow, tracks and their histories differ), so the frames
after the first hole are recomputed without being comparable to the flight's
(:attr:`ReplayedFrame.after_gap`): ``replay --check`` compares the frames before it.
Other messages the writer dropped (MAVLink bytes, box-feed datagrams: inputs replay then
lacks) are told by the health records' log counters, once a second: the frames processed
after the last health record before the count went up are after a hole too (replay
holds each frame back until the next health record, or 5 s of the log, to know).
"""

from __future__ import annotations

import copy
import json
import math
import tomllib
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from ..config import AppConfig, config_from_dict, drop_deprecated
from ..core.camera import CameraModel, camera_from_dict
from ..core.pipeline import FrameResult
from ..flightlog import topics as log_topics
from ..io.detector_model import read_detector_model
from ..mavlink.endpoint import CompanionEndpoint
from ..service.companion import Companion

if TYPE_CHECKING:
    from ..flightlog.reader import LogReport


class LogReplayError(ValueError):
    """The log cannot be replayed (no metadata, no frames, an unknown camera)."""


@dataclass(frozen=True)
class ReplayedFrame:
    logged: dict[str, Any]  # the /tcm/result document written in flight
    result: FrameResult  # the same frame, recomputed
    # A frame the daemon processed before this one could not be replayed (its image or
    # its result is not in the log): this one's pipeline state is not the flight's.
    after_gap: bool = False

    @property
    def camera_id(self) -> int:
        """The camera whose frame this is (the logged result's)."""
        return int(self.logged.get("camera_id", 0))


@dataclass(frozen=True)
class MissingFrame:
    """What replay lacks, by ``kind``: a processed frame's image (``"image"``;
    ``t_capture_us`` says which), the results of ``count`` processed frames (``"result"``,
    told by a jump in the logged ``frame_index``; ``t_capture_us`` is then the next logged
    frame's), or ``count`` other messages the writer dropped (``"messages"``: MAVLink,
    box-feed datagrams...; told by the health records; ``t_capture_us`` is then the time
    of the health record before them)."""

    t_capture_us: int
    why: str  # "not logged" (dropped by the writer) or "lost with a damaged part"
    count: int = 1
    kind: str = "image"  # "image", "result" or "messages"


#: How long replay holds frames back waiting for a health record (µs of the log).
_HEALTH_WAIT_US = 5_000_000


def _log_drops(doc: dict[str, Any]) -> int | None:
    """Messages (not frames) the writer had dropped, by a health record's log counters."""
    lg = doc.get("log")
    if not isinstance(lg, dict):
        return None
    keys = ("messages_dropped_queue", "messages_dropped_disk", "messages_dropped_error")
    return sum(int(v) for k in keys if isinstance(v := lg.get(k), int))


def _metadata(path: Path, flight: str | None = None) -> dict[str, str]:
    from ..flightlog.reader import check_log, read_metadata

    meta = read_metadata(path, flight)
    if not meta:
        damaged = check_log(path, flight).problems()
        if damaged:  # cut or damaged before (or inside) its first record
            raise LogReplayError(
                f"{path}: no tcm-companion metadata record readable: " + "; ".join(damaged)
            )
        raise LogReplayError(f"{path}: no tcm-companion metadata record (not a flight log?)")
    return meta


#: Settings counted in frames before the method's time base moved to seconds, and the
#: keys that replaced them: (table, old key) -> (new key, frames -> seconds at ``fps``).
_FRAME_KEYS: dict[tuple[str, str], tuple[str, Any]] = {
    ("classifier", "frame_interval"): ("interval_s", lambda n, fps: n / fps),
    ("classifier", "extra_intervals"): ("extra_intervals_s", lambda v, fps: [n / fps for n in v]),
    ("classifier", "hold_frames"): ("hold_s", lambda n, fps: n / fps),
    ("classifier", "min_frame_interval"): ("min_interval_s", lambda n, fps: n / fps),
    ("classifier", "frame_tolerance"): ("interval_tolerance_s", lambda n, fps: n / fps),
    ("ttc", "window_frames"): ("window_s", lambda n, fps: n / fps),
    ("ttc", "min_frames"): ("min_span_s", lambda n, fps: max(n - 1, 1) / fps),
    ("tracking", "history_frames"): ("history_s", lambda n, fps: n / fps),
}
_FRAME_PARAMS = {"TCM_INTERVAL": "TCM_INTERVAL_S", "TCM_HOLD": "TCM_HOLD_S"}


def from_frame_counts(
    doc: dict[str, Any], params: dict[str, float]
) -> tuple[dict[str, Any], dict[str, float]]:
    """A configuration and parameters written before the time base moved to seconds
    (``frame_interval``, ``TCM_HOLD``, ...), in today's keys at the log's camera rate
    (``[camera] fps``, else 25 Hz: the paper's and the daemon's default then). Newer
    ones come back unchanged."""
    fps = float(doc.get("camera", {}).get("fps", 25.0) or 25.0)
    out = copy.deepcopy(doc)
    # the pipeline's tables, at the top (config.toml) or under [pipeline] (config check)
    holders = [out] + ([out["pipeline"]] if isinstance(out.get("pipeline"), dict) else [])
    for (table, old), (new, convert) in _FRAME_KEYS.items():
        for holder in holders:
            section = holder.get(table)
            if isinstance(section, dict) and old in section:
                section[new] = convert(section.pop(old), fps)
    new_params = {_FRAME_PARAMS.get(k, k): v for k, v in params.items()}
    for old, new in _FRAME_PARAMS.items():
        if old in params:
            new_params[new] = params[old] / fps
    return out, new_params


def log_config(path: str | Path, flight: str | None = None) -> tuple[AppConfig, dict[str, float]]:
    """The configuration and the parameter values in force when the log (``flight``
    of a directory of several) started (a log written before the time base moved to
    seconds is read in today's keys; deprecated keys are dropped)."""
    meta = _metadata(Path(path), flight)
    try:
        doc = tomllib.loads(meta.get("config", ""))
    except tomllib.TOMLDecodeError as exc:
        raise LogReplayError(f"{path}: metadata config is not TOML: {exc}") from None
    params = {k: float(v) for k, v in json.loads(meta.get("params", "{}")).items()}
    doc, params = from_frame_counts(doc, params)
    # Keys no longer read ([replay] telemetry_wait_us) had no effect on the daemon that
    # wrote the log: dropped without the warning a config file gets.
    doc, _ = drop_deprecated(doc)
    config = config_from_dict(doc, f"{path}: metadata")
    return config, params


def _cameras(meta: dict[str, str], where: Path) -> tuple[list[CameraModel], list[str]]:
    """Every camera of the log, in order (camera0, camera1, ...), and their names."""
    models: list[CameraModel] = []
    while f"camera{len(models)}" in meta:
        key = f"camera{len(models)}"
        models.append(camera_from_dict(json.loads(meta[key]), where=f"{where}: {key}"))
    try:
        names = [str(n) for n in json.loads(meta.get("cameras", "[]"))]
    except ValueError:
        names = []
    if len(names) != len(models):
        names = [f"camera{i}" for i in range(len(models))]
    return models, names


def log_cameras(path: str | Path, flight: str | None = None) -> list[str]:
    """The names of the log's cameras, in camera-id order."""
    p = Path(path)
    return _cameras(_metadata(p, flight), p)[1]


def replay_log(
    path: str | Path,
    camera_id: int | None = None,
    report: LogReport | None = None,
    flight: str | None = None,
    missing: list[MissingFrame] | None = None,
) -> Iterator[ReplayedFrame]:
    """Yield every processed frame of the log, recomputed (only camera ``camera_id``'s
    when given).

    A log of a camera rig (two cameras or more) replays the whole rig whatever
    ``camera_id`` says: every camera's frames, in the order the daemon processed them,
    through one Companion, whose :class:`~tcm_companion.core.rig.RigTracker` needs them all
    (rig-wide track ids, the objects another camera measures left out); ``camera_id`` then
    only picks which frames are yielded.

    A truncated or damaged part is replayed as far as it is readable, then the next part
    (a frame processed there whose image was lost with the damaged tail is skipped);
    ``report`` says, once the iterator is exhausted, which parts were and how much of each
    was read (:meth:`~tcm_companion.flightlog.reader.LogReport.problems`). A directory of
    several flights replays the one ``flight`` picks
    (:func:`~tcm_companion.flightlog.reader.select_flight`). A processed frame the log
    lacks is skipped and appended to ``missing`` (see the module docstring); the frames
    after it come with ``after_gap``."""
    from ..flightlog.reader import LogReport, decode_image, decode_json, read_log

    p = Path(path)
    report = report if report is not None else LogReport()
    meta = _metadata(p, flight)
    config, params = log_config(p, flight)
    models, names = _cameras(meta, p)
    if camera_id is not None and not 0 <= camera_id < len(models):
        raise LogReplayError(f"{p}: no camera {camera_id} in the log's metadata")
    # One camera: its frames alone (a log may name cameras the daemon never processed).
    # A rig: every camera, since each one's results depend on the others' (core.rig).
    replayed = set(range(len(models))) if len(models) >= 2 else {camera_id or 0}
    cv2.setNumThreads(max(0, config.daemon.opencv_threads))

    endpoint = CompanionEndpoint(config.mavlink.endpoint, params)
    companion: Companion | None = None
    images: dict[tuple[int, int], np.ndarray] = {}  # (camera id, capture µs) -> image
    gap = False
    last_index: dict[int, int | None] = {}
    # Frames held back until a health record says whether messages were dropped meanwhile.
    held: list[ReplayedFrame] = []
    drops = 0  # messages dropped by the last health record
    health_us: int | None = None  # its time
    # Link bytes and box datagrams (receive time, is it MAVLink, data), handed to the
    # Companion in their order up to each processed frame's start.
    inputs: deque[tuple[int, bool, bytes]] = deque()
    image_topics = {log_topics.camera_image(c) for c in replayed}
    topics = {log_topics.MAVLINK_IN, *image_topics, log_topics.RESULT, log_topics.BOXES}
    topics.add(log_topics.HEALTH)
    for rec in read_log(p, topics, report, flight):
        t_mono_us = rec.publish_time_ns // 1000
        if companion is None:
            companion = Companion(
                models,
                config.pipeline,
                endpoint,
                t_mono_us,
                config.daemon,
                names,
                detector_model=read_detector_model(config.pipeline.detection),
            )
        if held and t_mono_us - held[0].result.t_us > _HEALTH_WAIT_US:
            yield from held  # no health record to wait for
            held.clear()
        if rec.topic == log_topics.HEALTH:
            now = _log_drops(decode_json(rec))
            if now is not None and now > drops:
                # dropped since the last health record: what came after that one lacks them
                since = health_us if health_us is not None else -1
                held = [
                    f
                    if f.after_gap or int(f.logged.get("t_process_us", 0)) <= since
                    else ReplayedFrame(f.logged, f.result, True)
                    for f in held
                ]
                gap = True
                if missing is not None:
                    missing.append(MissingFrame(since, "not logged", now - drops, "messages"))
            if now is not None:
                drops = now
            health_us = t_mono_us
            yield from held
            held.clear()
        elif rec.topic == log_topics.MAVLINK_IN:
            inputs.append((t_mono_us, True, rec.data))
        elif rec.topic == log_topics.BOXES:  # the live box feed, as the daemon received it
            inputs.append((t_mono_us, False, str(decode_json(rec).get("datagram", "")).encode()))
        elif rec.topic in image_topics:
            image_cam, t_capture, image = decode_image(rec)
            images[(image_cam, t_capture)] = image
        else:
            doc = decode_json(rec)
            logged_cam = doc.get("camera_id")
            if not isinstance(logged_cam, int) or logged_cam not in replayed:
                continue
            cam = logged_cam
            t_capture = int(doc["t_capture_us"])
            frame_image = images.pop((cam, t_capture), None)
            # Frames superseded before processing were logged but never processed.
            for old in [k for k in images if k[0] == cam and k[1] < t_capture]:
                del images[old]
            # A damaged part's unread tail held the images captured before the next part
            # began (its results too: those are not here to ask for them).
            cur = report.parts[-1]
            lost = (
                len(report.parts) > 1
                and report.parts[-2].damaged
                and cur.first_time_ns is not None
                and t_capture * 1000 < cur.first_time_ns
            )
            why = "lost with a damaged part" if lost else "not logged"
            index = doc.get("frame_index")
            last = last_index.get(cam)
            if isinstance(index, int) and last is not None and index > last + 1:
                # results of processed frames are not in the log (a reset, on a pipeline
                # rebuild, counts down: not a hole)
                gap = True
                if missing is not None:
                    missing.append(MissingFrame(t_capture, why, index - last - 1, "result"))
            last_index[cam] = index if isinstance(index, int) else None
            if frame_image is None:  # dropped by the writer, or lost with a damaged tail
                gap = True
                if missing is not None:
                    missing.append(MissingFrame(t_capture, why))
                continue
            # What the daemon had received when it started on the frame, and no more: a
            # turn's results are logged after its bytes are written, and bytes received
            # meanwhile (after the frame's processing began) come before them in the log.
            t_process = int(doc.get("t_process_us", t_mono_us))
            while inputs and inputs[0][0] <= t_process:
                _receive(companion, *inputs.popleft())
            offset = doc.get("clock_offset_us")
            result = companion.replay_frame(
                cam,
                frame_image,
                t_capture,
                t_process,
                clock_offset_us=float(offset) if offset is not None else None,
                override=str(doc.get("override") or ""),
            )
            if result is None:
                raise LogReplayError(f"{p}: the pipeline raised on the frame at {t_capture} us")
            if camera_id is None or cam == camera_id:
                held.append(ReplayedFrame(doc, result, gap))
    yield from held


def _receive(companion: Companion, t_mono_us: int, mavlink: bool, data: bytes) -> None:
    """Bytes the daemon received at ``t_mono_us``: from the link or the box feed."""
    if mavlink:
        companion.receive_data(data, t_mono_us)
    else:
        companion.on_box_datagram(data, t_mono_us)


#: Disparities this close (relative) differ by float rounding only: another CPU's SIMD loops
#: or BLAS kernel, another numpy/SciPy/OpenCV release (seen: a few ulp, up to 2.2e-15;
#: docs/logging.md "Bit-exact where?").
ROUNDING_REL_TOL = 1e-9


def relative_difference(a: float, b: float) -> float:
    """``|a - b| / max(|a|, |b|)``; 0 when equal (two zeros included), inf for nan/inf."""
    if a == b:
        return 0.0
    if not (math.isfinite(a) and math.isfinite(b)):
        return math.inf
    return abs(a - b) / max(abs(a), abs(b))


def compare(frame: ReplayedFrame, rel_tol: float = 0.0) -> list[str]:
    """Differences between a logged and a replayed frame ([]: the same).

    ``rel_tol = 0`` (the default, what ``replay --check`` uses): bit-exact, as process
    replay is on the install that wrote the log. ``rel_tol > 0``: a disparity also counts
    as the same when its :func:`relative_difference` is at most ``rel_tol`` (rounding of
    another numpy/OpenBLAS kernel or release). The number of objects, their track ids and
    states, and whether a disparity exists are compared exactly either way.
    """
    logged = frame.logged["objects"]
    replayed = frame.result.objects
    idx = frame.logged.get("frame_index")
    if len(logged) != len(replayed):
        return [f"frame {idx}: {len(logged)} objects logged, {len(replayed)} replayed"]
    out = []
    for a, b in zip(logged, replayed):
        if a["track_id"] != b.track_id or a["state"] != b.state:
            out.append(
                f"frame {idx} track {a['track_id']}: logged {a['state']}, "
                f"replayed track {b.track_id} {b.state}"
            )
            continue
        d = b.classification.disparity
        la = a.get("disparity")
        if (la is None) != (not math.isfinite(d)):
            out.append(f"frame {idx} track {a['track_id']}: disparity {la} logged, {d} replayed")
        elif la is not None and la != d:
            rel = relative_difference(float(la), d)
            if rel > rel_tol:
                out.append(
                    f"frame {idx} track {a['track_id']}: disparity {la} logged, {d} replayed "
                    f"(relative difference {rel:.1e})"
                )
    return out
