"""Replay a recorded or simulated scenario through the same pipeline the daemon runs.

Telemetry is handed to the pipeline in receive order, and a frame sees only what had
arrived by ``capture time + [daemon] attitude_wait_max_us`` — what the daemon, which
waits at most that long for the attitude after a frame, would have had when it
processed that frame live (:func:`telemetry_wait_us`). Anything with the scenario interface works: a directory read
by :func:`tcm_companion.io.scenario.load_scenario` or a simulated scenario in memory.

With ``[detection] backend = "boxes"`` the scenario's ``detections.csv`` rows (its
``detections``, or those given) are pushed to the pipeline's boxes backend with each
frame's capture time just before the frame, as a live feeder would push them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator
from typing import Any, Protocol

import numpy as np

from ..config import AppConfig
from ..core.classify import Method
from ..core.detection import Box, BoxesDetector
from ..core.pipeline import FrameResult, Pipeline
from ..core.telemetry import TelemetrySample
from ..io.detector_model import read_detector_model
from ..io.scenario_extras import Detection


class ScenarioLike(Protocol):
    name: str
    camera: Any
    frame_times_us: np.ndarray
    telemetry: list[TelemetrySample]

    @property
    def n_frames(self) -> int: ...

    def iter_frames(self) -> Iterator[tuple[int, int, np.ndarray]]: ...


def with_method(config: AppConfig, method: Method | None, bsm: bool = False) -> AppConfig:
    """``config`` with the classifier method replaced (and BSM forced on if asked)."""
    pipe = config.pipeline
    if method is not None:
        pipe = dataclasses.replace(
            pipe, classifier=dataclasses.replace(pipe.classifier, method=method)
        )
    if bsm:
        pipe = dataclasses.replace(pipe, bsm_enabled=True)
    return dataclasses.replace(config, pipeline=pipe)


#: One row of ``detections.csv``: the io reader's rows (and the simulated detector's).
DetectionRow = Detection


def boxes_by_frame(rows: Iterable[DetectionRow]) -> dict[int, list[Box]]:
    """``detections.csv`` rows as each frame's boxes."""
    out: dict[int, list[Box]] = {}
    for r in rows:
        box = Box(r.x_min, r.y_min, r.x_max, r.y_max, r.score, r.label)
        out.setdefault(int(r.frame), []).append(box)
    return out


def telemetry_wait_us(config: AppConfig) -> int:
    """How long after a frame's capture the telemetry it sees may have arrived: the
    daemon's ``[daemon] attitude_wait_max_us``, its longest wait for the attitude after a
    frame (the one setting; ``[replay] telemetry_wait_us`` is no longer read)."""
    return int(config.daemon.attitude_wait_max_us)


def run_replay(
    scenario: ScenarioLike,
    config: AppConfig,
    pipeline: Pipeline | None = None,
    detections: Iterable[DetectionRow] | None = None,
) -> Iterator[FrameResult]:
    """Yield one :class:`FrameResult` per frame of ``scenario``.

    ``detections``: the external detector's boxes for the boxes backend (default: the
    scenario's ``detections``, i.e. its ``detections.csv``); ignored by other backends.
    """
    pipe = pipeline or Pipeline(
        scenario.camera,
        config.pipeline,
        detector_model=read_detector_model(config.pipeline.detection),
    )
    buffer = pipe.telemetry
    telemetry = sorted(scenario.telemetry, key=lambda s: s.recv_us)
    wait = telemetry_wait_us(config)
    feeder = pipe.detector if isinstance(pipe.detector, BoxesDetector) else None
    boxes: dict[int, list[Box]] = {}
    if feeder is not None:
        rows = detections if detections is not None else getattr(scenario, "detections", None)
        if rows is None:
            raise ValueError(
                f'{scenario.name}: [detection] backend "boxes" replays the boxes of the '
                "scenario's detections.csv, and it has none"
            )
        boxes = boxes_by_frame(rows)
    j = 0
    for index, t_us, image in scenario.iter_frames():
        start = j
        while j < len(telemetry) and telemetry[j].recv_us <= t_us + wait:
            j += 1
        buffer.extend(telemetry[start:j])
        if feeder is not None:
            feeder.push(t_us, boxes.get(index, ()))
        yield pipe.step(image, t_us)
