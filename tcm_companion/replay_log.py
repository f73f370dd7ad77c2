"""Process replay of a flight log: the logged inputs through the core, again.

openpilot's process replay, for our daemon: the log holds every MAVLink byte received
(with its receive time), every camera frame (lossless with ``[logging] image_format =
"png"``) and, per processed frame, when it was processed, the clock offset the pipeline
used and the input-health override. Replaying feeds the received bytes through a fresh
:class:`~tcm_companion.mavlink.endpoint.CompanionEndpoint` (so telemetry filtering and
parameter changes from the ground station happen as they did), hands the resulting
samples to a fresh :class:`~tcm_companion.core.pipeline.Pipeline` in the same order, and
steps it on the same frames at the same points — so with lossless frames the replayed
results equal the logged ones exactly (``tests/test_log_replay.py``).

Exactly means on the same install and machine. Elsewhere the last bits can move: numpy's
bundled OpenBLAS picks its kernels by CPU (or ``OPENBLAS_CORETYPE``), numpy picks SIMD
loops by CPU, and other numpy/OpenCV releases round differently. :func:`compare` is
bit-exact by default; ``rel_tol`` accepts such rounding differences in the disparity
(states and tracks must still agree exactly). ``docs/logging.md`` says which is which.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .config import AppConfig, config_from_dict
from .core.camera import camera_from_dict
from .core.pipeline import FrameResult, Pipeline
from .core.telemetry import ClockSync, TelemetryBuffer
from .mavlink.endpoint import CompanionEndpoint, TelemetryReceived
from .mavlink.params import config_with_params
from .service.companion import mark_unknown


class LogReplayError(ValueError):
    """The log cannot be replayed (no metadata, no frames, an unknown camera)."""


class ReplayClock(ClockSync):
    """The telemetry clock fit, or the offset the live pipeline used for this frame."""

    def __init__(self) -> None:
        super().__init__()
        self.forced: float | None = None

    @property
    def offset_us(self) -> float:
        if self.forced is not None and math.isfinite(self.forced):
            return self.forced
        return super().offset_us


@dataclass(frozen=True)
class ReplayedFrame:
    logged: dict[str, Any]  # the /tcm/result document written in flight
    result: FrameResult  # the same frame, recomputed


def _metadata(path: Path) -> dict[str, str]:
    from .io.flightlog import read_metadata

    meta = read_metadata(path)
    if not meta:
        raise LogReplayError(f"{path}: no tcm-companion metadata record (not a flight log?)")
    return meta


def log_config(path: str | Path) -> tuple[AppConfig, dict[str, float]]:
    """The configuration and the parameter values in force when the log started."""
    meta = _metadata(Path(path))
    try:
        config = config_from_dict(tomllib.loads(meta.get("config", "")), f"{path}: metadata")
    except tomllib.TOMLDecodeError as exc:
        raise LogReplayError(f"{path}: metadata config is not TOML: {exc}") from None
    params = {k: float(v) for k, v in json.loads(meta.get("params", "{}")).items()}
    return config, params


def replay_log(path: str | Path, camera_id: int = 0) -> Iterator[ReplayedFrame]:
    """Yield every processed frame of camera ``camera_id`` of the log, recomputed."""
    from .io.flightlog import decode_image, decode_json, read_log

    p = Path(path)
    meta = _metadata(p)
    config, params = log_config(p)
    cam_key = f"camera{camera_id}"
    if cam_key not in meta:
        raise LogReplayError(f"{p}: no camera {camera_id} in the log's metadata")
    camera = camera_from_dict(json.loads(meta[cam_key]), where=f"{p}: {cam_key}")
    cv2.setNumThreads(max(0, config.daemon.opencv_threads))

    endpoint = CompanionEndpoint(config.mavlink.endpoint, params)
    base = config.pipeline
    pipe_cfg = config_with_params(base, endpoint.params.values)
    clock = ReplayClock()
    telemetry = TelemetryBuffer(clock=clock)
    pipe = Pipeline(camera, pipe_cfg, telemetry=telemetry)
    images: dict[int, np.ndarray] = {}
    image_topic = f"/camera{camera_id}/image"
    topics = {"/mavlink/in", image_topic, "/tcm/result"}
    for rec in read_log(p, topics):
        t_us = rec.publish_time_ns // 1000
        if rec.topic == "/mavlink/in":
            for ev in endpoint.receive_data(rec.data, t_us):
                if isinstance(ev, TelemetryReceived):
                    telemetry.add(ev.sample)
            new_cfg = config_with_params(base, endpoint.params.values)
            if new_cfg != pipe_cfg:  # a GCS changed a parameter: rebuilt as in flight
                pipe_cfg = new_cfg
                pipe = Pipeline(camera, pipe_cfg, telemetry=telemetry)
        elif rec.topic == image_topic:
            _, t_capture, image = decode_image(rec)
            images[t_capture] = image
        else:
            doc = decode_json(rec)
            if doc.get("camera_id") != camera_id:
                continue
            t_capture = int(doc["t_capture_us"])
            frame_image = images.pop(t_capture, None)
            # Frames superseded before processing were logged but never processed.
            for old in [t for t in images if t < t_capture]:
                del images[old]
            if frame_image is None:
                raise LogReplayError(
                    f"{p}: frame at {t_capture} us was processed but is not in the log"
                )
            offset = doc.get("clock_offset_us")
            clock.forced = float(offset) if offset is not None else None
            result = pipe.step(frame_image, t_capture)
            clock.forced = None
            if doc.get("override"):
                result = mark_unknown(result, str(doc["override"]))
            yield ReplayedFrame(doc, result)


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
