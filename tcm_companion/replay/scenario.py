"""Replay a recorded or simulated scenario through the same pipeline the daemon runs.

Telemetry is handed to the pipeline in receive order, and a frame sees only what had
arrived by ``capture time + telemetry_wait_us`` — what the daemon would have had when it
processed that frame live. Anything with the scenario interface works: a directory read
by :func:`tcm_companion.io.scenario.load_scenario` or a simulated scenario in memory.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from typing import Any, Protocol

import numpy as np

from ..config import AppConfig
from ..core.classify import Method
from ..core.pipeline import FrameResult, Pipeline
from ..core.telemetry import TelemetrySample


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


def run_replay(
    scenario: ScenarioLike, config: AppConfig, pipeline: Pipeline | None = None
) -> Iterator[FrameResult]:
    """Yield one :class:`FrameResult` per frame of ``scenario``."""
    pipe = pipeline or Pipeline(scenario.camera, config.pipeline)
    buffer = pipe.telemetry
    telemetry = sorted(scenario.telemetry, key=lambda s: s.recv_us)
    wait = config.replay.telemetry_wait_us
    j = 0
    for _index, t_us, image in scenario.iter_frames():
        start = j
        while j < len(telemetry) and telemetry[j].recv_us <= t_us + wait:
            j += 1
        buffer.extend(telemetry[start:j])
        yield pipe.step(image, t_us)
