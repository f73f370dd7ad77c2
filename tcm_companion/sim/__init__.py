"""Simulator: the paper's field rendered for any camera model, with synthetic telemetry.

``make_scenario(name, camera)`` gives an in-memory scenario that behaves like a loaded
``tcm-scenario/1`` directory; ``export_scenario(sim, out_dir)`` writes one (with
``detections=`` also a simulated detector's ``detections.csv``). Objects are the paper's
red balls or boxes, upright cylinders and discs (:mod:`.world`); ``docs/simulator.md``
lists the scenarios. Truth beyond ``truth.csv``: :mod:`.truth`; the simulated box
detector: :mod:`.detector_sim`; ``[[target]]`` and ``detections.csv`` I/O:
:mod:`.scenario_io`.

The names below are loaded on first use, so that importing a light submodule (the
scenario names of :mod:`.names`, for the command line) does not import the renderer.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from .names import OBJECT_SCENARIO_NAMES, PAPER_SCENARIO_NAMES, SCENARIO_NAMES

if TYPE_CHECKING:
    from .detector_sim import DetectorSimConfig, simulate_detections
    from .export import SimulatedScenario, export_scenario, make_scenario
    from .scenarios import default_camera, describe_scenario, flight_plan, plan_world

#: Where each lazily loaded name lives.
_LAZY = {
    "DetectorSimConfig": ".detector_sim",
    "simulate_detections": ".detector_sim",
    "SimulatedScenario": ".export",
    "export_scenario": ".export",
    "make_scenario": ".export",
    "default_camera": ".scenarios",
    "describe_scenario": ".scenarios",
    "flight_plan": ".scenarios",
    "plan_world": ".scenarios",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


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
