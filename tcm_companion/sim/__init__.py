"""Simulator: the paper's field rendered for any camera model, with synthetic telemetry.

``make_scenario(name, camera)`` gives an in-memory scenario that behaves like a loaded
``tcm-scenario/1`` directory; ``export_scenario(sim, out_dir)`` writes one.
"""

from .export import SimulatedScenario, export_scenario, make_scenario
from .scenarios import SCENARIO_NAMES, default_camera, flight_plan

__all__ = [
    "SCENARIO_NAMES",
    "SimulatedScenario",
    "default_camera",
    "export_scenario",
    "flight_plan",
    "make_scenario",
]
