"""Simulated scenarios in memory (:class:`SimulatedScenario`) and on disk (``tcm-scenario/1``).

:func:`make_scenario` builds a flight of :mod:`.scenarios`, its clocks and telemetry;
the object quacks like :class:`tcm_companion.io.scenario.Scenario` (same attributes and
frame iterator), rendering frames lazily. Its ``telemetry`` is decoded from the very
``.tlog`` bytes that :func:`export_scenario` writes, through the same reader, so replaying
the in-memory scenario and the exported directory gives identical inputs.

Determinism: everything follows from ``seed`` (clocks, turbulence, telemetry noise and
latency, sensor noise of frame ``i`` — independent of the order frames are rendered).

:func:`export_scenario` writes the optional ``[[target]]`` tables when an object is not
the default red sphere, and ``detections.csv`` from the simulated box detector
(:mod:`.detector_sim`) when asked. Truth beyond ``truth.csv`` (range to an object's
centre, range ratios, its image): :meth:`SimulatedScenario.true_range_m`,
:meth:`~SimulatedScenario.true_range_ratio`, :meth:`~SimulatedScenario.object_views`.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ...core.camera import CameraModel
from ...core.frames import FloatArray
from ...core.telemetry import AttitudeSample, PositionSample, TelemetrySample
from ...io.scenario import Truth
from ...io.scenario_writer import ScenarioWriter, scenario_toml
from ...io.tlog import TlogStats, iter_tlog
from ...mavlink.samples import sample_from_message
from ..vehicle.telemetry import (
    TelemetryConfig,
    frame_times,
    make_clocks,
    synthesize_tlog,
    tlog_bytes,
)
from .render import Renderer
from .scenario_io import targets_toml
from .scenarios import (
    SCENARIO_NAMES,
    FlightPlan,
    FlightTooLong,
    default_camera,
    flight_plan,
    plan_world,
)
from .world import World

if TYPE_CHECKING:
    from .detector_sim import DetectorSimConfig, TrueBox
    from .truth import ObjectView

__all__ = ["SCENARIO_NAMES", "SimulatedScenario", "export_scenario", "make_scenario"]

SENSOR_NOISE_DN = 2.5


class SimulatedScenario:
    """A simulated flight with the interface of :class:`~tcm_companion.io.scenario.Scenario`."""

    root: Path | None = None
    frames_dir: Path | None = None
    video: Path | None = None

    def __init__(
        self,
        plan: FlightPlan,
        camera: CameraModel,
        seed: int = 0,
        noise: float = 1.0,
        telemetry_config: TelemetryConfig | None = None,
        fisheye_fov_deg: float = 180.0,
        world: World | None = None,
    ) -> None:
        self.plan = plan
        self.name = plan.name
        self.description = f"{plan.description} (simulated, seed {seed}, noise {float(noise):g})"
        self.camera = camera
        self.seed = seed
        self.noise = float(noise)
        self.fisheye_fov_deg = fisheye_fov_deg
        self.world = world if world is not None else plan_world(plan)
        self.telemetry_config = telemetry_config or TelemetryConfig()
        self.warnings: list[str] = []

        streams = np.random.SeedSequence([20160628, seed]).spawn(3)
        clock_rng, frame_rng, tlm_rng = (np.random.default_rng(s) for s in streams)
        self.clocks = make_clocks(clock_rng)
        self.frame_times_us, self.frame_times_s = frame_times(
            plan.n_frames, plan.fps, self.clocks, self.telemetry_config, frame_rng
        )
        margin = self.telemetry_config.margin_s
        self.tlog_records = synthesize_tlog(
            plan.vehicle,
            float(self.frame_times_s[0]) - margin,
            float(self.frame_times_s[-1]) + margin,
            self.clocks,
            tlm_rng,
            self.telemetry_config,
            noise=self.noise,
        )
        self.tlog_bytes = tlog_bytes(self.tlog_records)
        self.tlog_stats = TlogStats()
        self.telemetry: list[TelemetrySample] = []
        for rec in iter_tlog(self.tlog_bytes, f"<simulated {self.name}>", self.tlog_stats):
            sample = sample_from_message(rec.msg, rec.recv_us)
            if sample is not None:
                self.telemetry.append(sample)
        self.truth: Truth = self._make_truth()
        self._renderer: Renderer | None = None

    # -- Scenario interface ------------------------------------------------------------
    @property
    def n_frames(self) -> int:
        return len(self.frame_times_us)

    def iter_frames(self) -> Iterator[tuple[int, int, np.ndarray]]:
        """Yield ``(index, t_us, BGR image)`` in order, rendering each frame on demand."""
        for i, t in enumerate(self.frame_times_us):
            yield i, int(t), self.read_frame(i)

    def read_frame(self, index: int) -> np.ndarray:
        """Render frame ``index`` (BGR uint8); the same image every time for a given seed."""
        pos, R = self.vehicle_pose(index)
        rng = np.random.default_rng(np.random.SeedSequence([20160628, self.seed, 1, index]))
        return self.renderer.render(
            float(self.frame_times_s[index]), pos, R, noise_dn=SENSOR_NOISE_DN * self.noise, rng=rng
        )

    def read_frame_with_coverage(self, index: int) -> tuple[np.ndarray, dict[int, np.ndarray]]:
        """:meth:`read_frame`'s image (the same bytes) and each object's visible coverage
        (:meth:`~.render.Renderer.render_with_coverage`)."""
        pos, R = self.vehicle_pose(index)
        rng = np.random.default_rng(np.random.SeedSequence([20160628, self.seed, 1, index]))
        return self.renderer.render_with_coverage(
            float(self.frame_times_s[index]), pos, R, noise_dn=SENSOR_NOISE_DN * self.noise, rng=rng
        )

    def attitude_samples(self) -> list[AttitudeSample]:
        return [s for s in self.telemetry if isinstance(s, AttitudeSample)]

    def position_samples(self) -> list[PositionSample]:
        return [s for s in self.telemetry if isinstance(s, PositionSample)]

    # -- simulator extras --------------------------------------------------------------
    def with_camera(self, camera: CameraModel) -> SimulatedScenario:
        """The same flight (plan, seed, telemetry) seen through another camera."""
        return SimulatedScenario(
            self.plan,
            camera,
            seed=self.seed,
            noise=self.noise,
            telemetry_config=self.telemetry_config,
            fisheye_fov_deg=self.fisheye_fov_deg,
            world=self.world,
        )

    @property
    def renderer(self) -> Renderer:
        if self._renderer is None:
            self._renderer = Renderer(
                self.world, self.camera, fisheye_fov_deg=self.fisheye_fov_deg, seed=self.seed
            )
        return self._renderer

    def vehicle_pose(self, index: int) -> tuple[FloatArray, FloatArray]:
        """True ``(pos_ned_m, R_ned_from_body)`` at frame ``index``'s capture time."""
        t = float(self.frame_times_s[index])
        return self.plan.vehicle.position_ned_m(t), self.plan.vehicle.R_ned_from_body(t)

    def true_range_m(self, frame: int, object_id: int) -> float:
        """Range (m) from the camera centre to object ``object_id``'s centre."""
        from .truth import true_range_m

        return true_range_m(self, frame, object_id)

    def true_range_ratio(self, frame0: int, frame1: int, object_id: int) -> float:
        """True ``d0 / d1`` of object ``object_id`` between two frames."""
        from .truth import true_range_ratio

        return true_range_ratio(self, frame0, frame1, object_id)

    def object_views(self, frame: int) -> list[ObjectView]:
        """Every object's image at frame ``frame``: centre pixel, silhouette box,
        angular extent, range (exact geometry at the true pose; see :mod:`.truth`)."""
        from .truth import object_views

        return object_views(self, frame)

    def _make_truth(self) -> Truth:
        t = self.frame_times_s
        veh = self.plan.vehicle.position_ned_m(t)
        frames, ids, moving, obj, radius, vehs = [], [], [], [], [], []
        for i in range(self.n_frames):
            for o in self.plan.objects:
                frames.append(i)
                ids.append(o.object_id)
                moving.append(o.moving)
                obj.append(o.centre_ned_m(float(t[i])))
                radius.append(o.bounding_radius_m)
                vehs.append(veh[i])
        return Truth(
            frame=np.asarray(frames, dtype=np.int64),
            object_id=np.asarray(ids, dtype=np.int64),
            moving=np.asarray(moving, dtype=bool),
            obj_ned_m=np.asarray(obj, dtype=np.float64).reshape(-1, 3),
            obj_radius_m=np.asarray(radius, dtype=np.float64),
            veh_ned_m=np.asarray(vehs, dtype=np.float64).reshape(-1, 3),
        )


def make_scenario(
    name: str,
    camera: CameraModel | None = None,
    duration_s: float | None = None,
    seed: int = 0,
    noise: float = 1.0,
    *,
    shorter_ok: bool = False,
) -> SimulatedScenario:
    """Scenario ``name`` (one of ``SCENARIO_NAMES``) through ``camera`` (default: the
    paper's 360×220 panorama). ``noise`` scales sensor and telemetry noise (0: none).
    A flight that cannot last ``duration_s`` (a collision or head-on course ends at
    contact) raises :class:`FlightTooLong`, or with ``shorter_ok`` keeps its own, shorter
    duration (``eval`` and the studies that run one duration over every flight)."""
    try:
        plan = flight_plan(name, duration_s=duration_s, seed=seed)
    except FlightTooLong:
        if not shorter_ok:
            raise
        plan = flight_plan(name, seed=seed)
    return SimulatedScenario(
        plan, camera if camera is not None else default_camera(), seed=seed, noise=noise
    )


# --------------------------------------------------------------------------------------
# Export
# --------------------------------------------------------------------------------------
def export_scenario(
    sim: SimulatedScenario,
    out_dir: str | Path,
    progress: bool | None = None,
    detections: DetectorSimConfig | bool | None = None,
) -> Path:
    """Write ``sim`` as a ``tcm-scenario/1`` directory; returns its path.

    Renders every frame (a progress bar shows when ``progress`` is true, or by default
    for more than 50 frames). Stale ``NNNNNN.png`` files beyond the last frame are removed.
    ``detections``: also write ``detections.csv`` from the simulated detector (True: its
    default settings; a :class:`~.detector_sim.DetectorSimConfig`: those), from the
    visible coverage rendered with each frame; otherwise a stale one is removed.
    """
    writer = ScenarioWriter(out_dir)
    # [[target]] tables only when an object is not the default sphere
    extra = targets_toml(sim.plan.objects)
    writer.write_toml(scenario_toml(sim.name, sim.description, sim.camera, extra=extra))
    writer.write_telemetry(sim.tlog_bytes)
    writer.write_frames_csv(sim.frame_times_us)
    writer.write_truth(sim.truth)
    writer.remove_stale_frames(sim.n_frames)

    det_config = detector_config(detections)
    if det_config is None:
        writer.remove_detections()
    write_frames(sim, writer, det_config, progress)
    return writer.root


def detector_config(detections: DetectorSimConfig | bool | None) -> DetectorSimConfig | None:
    """What ``detections`` of :func:`export_scenario` asks for: the simulated detector's
    settings (``True``: the defaults), or None for no ``detections.csv``."""
    if detections is True:
        from .detector_sim import DetectorSimConfig

        return DetectorSimConfig()
    if detections is None or detections is False:
        return None
    return detections


def write_frames(
    sim: SimulatedScenario,
    writer: ScenarioWriter,
    det_config: DetectorSimConfig | None,
    progress: bool | None = None,
) -> None:
    """Render every frame of ``sim`` into ``writer`` (with a progress bar when
    ``progress``; default: above 50 frames) and, with ``det_config``, the simulated
    detector's boxes from the visible coverage rendered with each frame."""
    show = progress if progress is not None else sim.n_frames > 50
    indices: Iterable[int] = range(sim.n_frames)
    if show:
        from ...io.progress import track

        indices = track(indices, sim.n_frames, f"rendering {sim.name}")
    truth_boxes: list[list[TrueBox]] = []
    for i in indices:
        if det_config is None:
            img = sim.read_frame(i)
        else:
            from .detector_sim import true_boxes_from_coverage

            img, cov = sim.read_frame_with_coverage(i)
            truth_boxes.append(true_boxes_from_coverage(sim, i, cov))
        writer.write_frame(i, img)
    if det_config is not None:
        from .detector_sim import simulate_detections

        writer.write_detections(simulate_detections(sim, det_config, truth_boxes))
