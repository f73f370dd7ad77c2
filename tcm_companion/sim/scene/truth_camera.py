"""The simulator's camera: renders the field test live at the vehicle's true pose (SITL).

A live source ticking at ``fps`` on absolute deadlines of the clock it is given
(``clock_us``: by default the companion monotonic clock, ``_mono_us``; in virtual-time
SITL the simulated one), ``t0 + k / fps``, no drift. Each ``read()`` waits for the next
tick, asks ``truth_us(tick_us)`` for the vehicle's exact state at that instant — in SITL
the mock autopilot's (:meth:`SimulatedCamera.for_mock`) — and renders the world the
scenario flies in (:func:`~tcm_companion.sim.scene.scenarios.plan_world` of the scenario's
:func:`~tcm_companion.sim.scene.scenarios.flight_plan`, as
:class:`~tcm_companion.sim.scene.export.SimulatedScenario` builds it). The frame's
``t_capture_us`` is the tick. By default (``render_ahead``) the frame is rendered before
its tick — the simulated truth is known ahead — and handed over at the tick, so the
daemon's capture-to-output latency is measured without the renderer's ~8 ms; with
``render_ahead=False`` it is delivered a render time after the tick, like a camera with
a slow readout. If rendering or the reader fell behind, the ticks already past are
skipped (``skipped_ticks``) so the series stays on its 25 Hz grid.

In virtual time (:mod:`tcm_companion.sitl.virtual`) the camera is given the
simulated clock and :func:`no_sleep`: ``read()`` then returns at once with the next tick
(in the simulated future), and the simulation hands the frame over at that instant.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from ...io.aio import monotonic_us
from ...io.cameras.base import CameraError, CameraGone, FrameSource, Waker
from ...io.cameras.settings import TruthFn

if TYPE_CHECKING:
    from ...core.camera import CameraModel
    from .render import Renderer
    from .scenarios import FlightPlan

__all__ = ["DyingCamera", "SimulatedCamera", "TruthFn", "no_sleep"]


def no_sleep(seconds: float) -> None:
    """The sleep of a camera on a simulated clock: the simulation moves time, not us."""
    return None


class SimulatedCamera(FrameSource):
    """Render scenario ``scenario`` (e.g. ``"T90"``) through ``camera_model`` at ``fps``.

    ``noise_dn`` is the sensor noise σ in digital numbers; ``seed`` picks the flight
    plan's variant (ball phases — it must match the autopilot's) and the noise sequence.
    ``plan`` overrides the flight plan (the mock autopilot's own, by :meth:`for_mock`).
    When ``truth_us`` returns None the frame is returned empty (None) and counted as
    rejected by the reader. ``sleep`` defaults to an interruptible wait woken by
    :meth:`interrupt`.
    """

    live = True

    def __init__(
        self,
        camera_model: CameraModel,
        scenario: str,
        truth_us: TruthFn,
        fps: float = 25.0,
        seed: int = 0,
        noise_dn: float = 2.5,
        clock_us: Callable[[], int] = monotonic_us,
        sleep: Callable[[float], object] | None = None,
        *,
        plan: FlightPlan | None = None,
        fisheye_fov_deg: float = 180.0,
        name: str | None = None,
        render_ahead: bool = True,
    ) -> None:
        from .scenarios import flight_plan

        if not fps > 0:
            raise ValueError(f"fps must be positive, got {fps!r}")
        if not noise_dn >= 0:
            raise ValueError(f"noise_dn must be >= 0, got {noise_dn!r}")
        if plan is None:
            try:
                plan = flight_plan(scenario, seed=seed)
            except ValueError as exc:
                raise CameraError(f"simulated camera: {exc}") from None
        super().__init__(name or f"sim-{plan.name}", camera_model.width, camera_model.height)
        self.camera_model = camera_model
        self.plan = plan
        self.truth_us = truth_us
        self.fps = float(fps)
        self.seed = seed
        self.noise_dn = float(noise_dn)
        self.fisheye_fov_deg = fisheye_fov_deg
        self.clock_us = clock_us
        self._waker = Waker()
        self._sleep = sleep if sleep is not None else self._waker.sleep
        self._rng = np.random.default_rng(np.random.SeedSequence([20160628, seed, 2]))
        self._renderer: Renderer | None = None
        self._open = False
        self._t0_us: int | None = None  # tick 0 (first read after open)
        self._k = 0  # next tick index
        self.skipped_ticks = 0  # ticks that passed while rendering or waiting on the reader
        self.rendered = 0
        self.render_ahead = render_ahead
        self.late_frames = 0  # render_ahead: rendering finished after the frame's instant

    @classmethod
    def for_mock(
        cls, camera_model: CameraModel, mock_autopilot: Any, **kwargs: Any
    ) -> SimulatedCamera:
        """A camera on the mock autopilot's vehicle: truth from
        ``mock_autopilot.vehicle_truth(t_mono_us)`` (exact position and attitude, no
        telemetry noise), world and seed from its flight plan. The mock must be driven by
        the same clock as this camera (``clock_us``: the companion monotonic clock, or a
        simulated one, µs)."""

        def truth(t_mono_us: int) -> tuple[float, np.ndarray, np.ndarray]:
            v = mock_autopilot.vehicle_truth(t_mono_us)
            return float(v.t_s), np.asarray(v.position_ned_m), np.asarray(v.R_ned_from_body)

        config = mock_autopilot.config
        kwargs.setdefault("seed", int(config.seed))
        kwargs.setdefault("plan", mock_autopilot.plan)
        return cls(camera_model, str(config.scenario), truth, **kwargs)

    @property
    def renderer(self) -> Renderer:
        """The ray caster (built on first use: ~1.5 s the first time in a process)."""
        if self._renderer is None:
            from .render import Renderer
            from .scenarios import plan_world

            world = plan_world(self.plan)  # balls, other targets, the scene's extras
            self._renderer = Renderer(
                world, self.camera_model, fisheye_fov_deg=self.fisheye_fov_deg, seed=self.seed
            )
        return self._renderer

    def open(self) -> None:
        self._waker.reset()
        try:
            _ = self.renderer
        except Exception as exc:
            raise CameraError(f"camera {self.name}: cannot build the renderer: {exc}") from exc
        self._t0_us, self._k, self._open = None, 0, True

    def _tick_us(self, k: int) -> int:
        assert self._t0_us is not None
        return self._t0_us + round(k * 1e6 / self.fps)

    def read(self) -> tuple[np.ndarray | None, int | None]:
        if not self._open:
            raise CameraGone(f"camera {self.name}: not open")
        now = int(self.clock_us())
        if self._t0_us is None:
            # The first tick leaves time to render it, so it is not late by construction.
            self._t0_us, k = now + round(1e6 / self.fps), 0
        else:
            k = self._k
            if now > self._tick_us(k):  # fell behind: next tick still in the future
                k_next = max(k + 1, math.floor((now - self._t0_us) * self.fps / 1e6))
                while self._tick_us(k_next) <= now:
                    k_next += 1
                self.skipped_ticks += k_next - k
                k = k_next
        tick_us = self._tick_us(k)
        self._k = k + 1
        if not self.render_ahead:
            now = int(self.clock_us())
            if tick_us > now:
                self._sleep((tick_us - now) / 1e6)
        truth = self.truth_us(tick_us)
        image = None
        if truth is not None:
            t_s, pos_ned_m, R_ned_from_body = truth
            image = self.renderer.render(
                float(t_s),
                np.asarray(pos_ned_m, dtype=np.float64),
                np.asarray(R_ned_from_body, dtype=np.float64),
                noise_dn=self.noise_dn,
                rng=self._rng,
            )
            self.rendered += 1
        if self.render_ahead:
            # Rendered before its instant (the truth of a simulated flight is known ahead);
            # hand it over at the instant, as a camera whose readout took no time. Then
            # capture-to-output latency in SITL is the daemon's own, not the renderer's.
            now = int(self.clock_us())
            if tick_us > now:
                self._sleep((tick_us - now) / 1e6)
            else:
                self.late_frames += 1
        return image, tick_us

    def interrupt(self) -> None:
        self._waker.interrupt()

    def close(self) -> None:
        self._open = False


class DyingCamera(FrameSource):
    """``inner`` until ``dies_at_us`` on ``clock_us`` (µs), then gone for good: ``read()``
    raises :class:`CameraGone` (a frame whose capture time is at or after the instant is
    not delivered) and every later ``open()`` fails, so the reader keeps reconnecting with
    backoff and the daemon sees the camera's input go stale (SITL's "a camera dies")."""

    live = True

    def __init__(self, inner: FrameSource, dies_at_us: int, clock_us: Callable[[], int]) -> None:
        super().__init__(inner.name, inner.width, inner.height)
        self.inner = inner
        self.dies_at_us = int(dies_at_us)
        self.clock_us = clock_us

    @property
    def dead(self) -> bool:
        return int(self.clock_us()) >= self.dies_at_us

    def open(self) -> None:
        if self.dead:
            raise CameraError(f"camera {self.name}: dead (simulated loss)")
        self.inner.open()

    def read(self) -> tuple[np.ndarray | None, int | None]:
        if self.dead:
            raise CameraGone(f"camera {self.name}: stopped delivering (simulated loss)")
        image, t_us = self.inner.read()
        if t_us is not None and t_us >= self.dies_at_us:
            raise CameraGone(f"camera {self.name}: stopped delivering (simulated loss)")
        return image, t_us

    def interrupt(self) -> None:
        self.inner.interrupt()

    def close(self) -> None:
        self.inner.close()
