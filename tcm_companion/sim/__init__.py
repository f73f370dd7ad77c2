"""Simulator: the paper's field rendered for any camera model, with synthetic telemetry.

``make_scenario(name, camera)`` gives an in-memory scenario that behaves like a loaded
``tcm-scenario/1`` directory; ``export_scenario(sim, out_dir)`` writes one (with
``detections=`` also a simulated detector's ``detections.csv``). Objects are the paper's
red balls or boxes, upright cylinders and discs (:mod:`.world`); ``docs/simulator.md``
lists the scenarios. Truth beyond ``truth.csv``: :mod:`.truth`; the simulated box
detector: :mod:`.detector_sim`; ``[[target]]`` and ``detections.csv`` I/O:
:mod:`.scenario_io`.
"""

from .detector_sim import DetectorSimConfig, simulate_detections
from .export import SimulatedScenario, export_scenario, make_scenario
from .scenarios import (
    OBJECT_SCENARIO_NAMES,
    PAPER_SCENARIO_NAMES,
    SCENARIO_NAMES,
    default_camera,
    describe_scenario,
    flight_plan,
    plan_world,
)

__all__ = [
    "OBJECT_SCENARIO_NAMES",
    "PAPER_SCENARIO_NAMES",
    "SCENARIO_NAMES",
    "DetectorSimConfig",
    "SimulatedScenario",
    "default_camera",
    "describe_scenario",
    "export_scenario",
    "flight_plan",
    "make_scenario",
    "plan_world",
    "simulate_detections",
]
