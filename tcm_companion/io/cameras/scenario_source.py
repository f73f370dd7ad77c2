"""The frames of a ``tcm-scenario/1`` directory played as a camera.

Capture times are rebased onto the companion's monotonic clock: the first frame is at
``open()`` time and later frames keep the scenario's own spacing (``frames.csv``'s
``t_us`` differences, jitter included). Paced in real time (frame ``i`` is returned when
its rebased time comes, which is also its ``t_capture_us``) or as fast as possible
(nothing sleeps, the times are the same series). The scenario's own time of the frame
last returned is ``last_scenario_t_us`` (Unix epoch µs, the telemetry's clock), for
callers that replay the scenario's telemetry alongside.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..aio import monotonic_us
from ..scenario import ScenarioError, load_scenario
from .base import CameraError, CameraGone, EndOfStream, FrameSource, Pacer, Waker

log = logging.getLogger(__name__)


class ScenarioSource(FrameSource):
    """Frames of a scenario directory (or an in-memory scenario object such as
    :class:`~tcm_companion.sim.scene.export.SimulatedScenario`). Finite.

    The image size is the scenario camera's (``self.camera``, a
    :class:`~tcm_companion.core.camera.CameraModel`). A frame file that cannot be read is
    returned as None (counted as rejected by the reader); a video that stops decoding
    ends the stream. ``sleep`` defaults to an interruptible wait woken by :meth:`interrupt`.
    """

    live = False

    def __init__(
        self,
        scenario: str | Path | Any,
        realtime: bool = True,
        clock_us: Callable[[], int] = monotonic_us,
        sleep: Callable[[float], object] | None = None,
        *,
        name: str | None = None,
    ) -> None:
        if isinstance(scenario, str | Path):
            try:
                scenario = load_scenario(scenario, check_frames=False)
            except ScenarioError as exc:
                raise CameraError(str(exc)) from None
            except OSError as exc:
                raise CameraError(f"{scenario}: {exc}") from None
        self.scenario = scenario
        self.camera = scenario.camera
        super().__init__(name or str(scenario.name), self.camera.width, self.camera.height)
        times = np.asarray(scenario.frame_times_us, dtype=np.int64)
        if times.size == 0:
            raise CameraError(f"scenario {scenario.name}: no frames")
        self.rel_us = times - times[0]  # strictly increasing (checked by load_scenario)
        self.realtime = realtime
        self._waker = Waker()
        sleep = sleep if sleep is not None else self._waker.sleep
        spacing = int(np.median(np.diff(times))) if times.size > 1 else 40_000
        self.pacer = Pacer(clock_us, sleep, realtime, max_lag_us=max(1, spacing))
        self._frames_dir: Path | None = getattr(scenario, "frames_dir", None)
        self._iter: Iterator[tuple[int, int, np.ndarray]] | None = None
        self._index = 0
        self._open = False
        self.last_scenario_t_us: int | None = None

    @property
    def n_frames(self) -> int:
        return int(self.rel_us.size)

    def open(self) -> None:
        self.close()
        self._waker.reset()
        if self._frames_dir is not None and not Path(self._frames_dir).is_dir():
            raise CameraError(f"{self._frames_dir}: no such directory")
        if self._frames_dir is None:
            self._iter = iter(self.scenario.iter_frames())
        self._index, self._open = 0, True
        self.pacer.start()

    def read(self) -> tuple[np.ndarray | None, int | None]:
        if not self._open:
            raise CameraGone(f"scenario {self.name}: not open")
        i = self._index
        if i >= self.n_frames:
            raise EndOfStream(f"scenario {self.name}: end after {i} frames")
        image: np.ndarray | None
        if self._frames_dir is not None:
            path = self.scenario.frame_path(i)
            image = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if image is None:
                log.warning("%s: cannot be read as an image", path)
        else:
            assert self._iter is not None
            try:
                _, _, image = next(self._iter)
            except StopIteration:
                raise EndOfStream(f"scenario {self.name}: end after {i} frames") from None
            except ScenarioError as exc:
                log.error("scenario %s: %s; ending", self.name, exc)
                raise EndOfStream(str(exc)) from None
        t_us = self.pacer.wait(int(self.rel_us[i]))
        self.last_scenario_t_us = int(self.scenario.frame_times_us[i])
        self._index += 1
        return image, t_us

    def interrupt(self) -> None:
        self._waker.interrupt()

    def close(self) -> None:
        it, self._iter = self._iter, None
        if it is not None and hasattr(it, "close"):
            it.close()  # a generator releases its VideoCapture in its finally
        self._open = False
