"""The simulator's camera sources in the camera registry: ``[camera] source = "sim"`` and
``"sim_autopilot"``.

:mod:`tcm_companion.io.cameras.settings` builds the devices and files; the simulator sits
above it, so it registers its own two kinds with
:func:`~tcm_companion.io.cameras.settings.register_source`. The application (``run``,
``sitl``) calls :func:`register_sim_sources` before it opens a camera; until then
``open_source`` refuses these kinds and names this module.

- ``"sim"``: :class:`~.scene.truth_camera.SimulatedCamera`, the field rendered from the
  mock autopilot's true pose (``truth_us``), SITL only.
- ``"sim_autopilot"``: :class:`~.scene.autopilot_camera.AutopilotSimCamera`, the field
  rendered from the pose any autopilot reports over its own MAVLink link (``sim_url``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..io.cameras.base import CameraError, FrameSource
from ..io.cameras.settings import CameraSourceConfig, TruthFn, register_source

if TYPE_CHECKING:
    from ..core.camera import CameraModel


def _sim(
    s: CameraSourceConfig, cam: CameraModel, truth_us: TruthFn | None, scenario: str
) -> FrameSource:
    if truth_us is None:
        raise CameraError(
            "camera.source = 'sim': the simulator renders the vehicle's true pose, so it "
            "needs the mock autopilot's truth (SITL: tcm-companion sitl); on a real vehicle "
            "set camera.source to 'device', 'gstreamer' or 'dual_fisheye'"
        )
    from .scene.truth_camera import SimulatedCamera

    return SimulatedCamera(
        cam, scenario, truth_us, fps=s.fps, seed=s.sim_seed, noise_dn=s.sim_noise_dn
    )


def _sim_autopilot(
    s: CameraSourceConfig, cam: CameraModel, truth_us: TruthFn | None, scenario: str
) -> FrameSource:
    from .scene.autopilot_camera import AutopilotSimCamera, SceneConfig, check_url

    try:
        check_url(s.sim_url)
    except CameraError as exc:
        raise CameraError(f"camera.sim_url: {exc}") from None
    scene = SceneConfig(
        kind=s.sim_scene,
        contact_s=s.sim_contact_s,
        ball_speed_mps=s.sim_ball_speed_mps,
        side_deg=s.sim_side_deg,
        ball_radius_m=s.sim_ball_radius_m,
        static_balls=s.sim_static_balls,
    )
    return AutopilotSimCamera(
        cam,
        s.sim_url,
        scene,
        fps=s.fps,
        heading_deg=s.sim_heading_deg,
        seed=s.sim_seed,
        noise_dn=s.sim_noise_dn,
    )


def register_sim_sources() -> None:
    """Register ``"sim"`` and ``"sim_autopilot"`` with the camera registry (idempotent)."""
    register_source("sim", _sim)
    register_source("sim_autopilot", _sim_autopilot)
