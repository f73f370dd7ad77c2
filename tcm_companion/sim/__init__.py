"""Simulator: the paper's field rendered for any camera model, with synthetic telemetry,
and the vehicles that fly it.

- :mod:`.scene` — what the camera sees: the world (:mod:`.scene.world`: the paper's red
  balls or boxes, upright cylinders and discs), the renderer, the scenarios and their
  names, camera presets, scenario export, truth beyond ``truth.csv`` (:mod:`.scene.truth`),
  the simulated box detector (:mod:`.scene.detector_sim`), ``[[target]]`` and
  ``detections.csv`` I/O (:mod:`.scene.scenario_io`), and the simulated camera sources
  (:mod:`.scene.truth_camera`, :mod:`.scene.autopilot_camera`).
- :mod:`.vehicle` — what flies it: the telemetry an autopilot would send
  (:mod:`.vehicle.telemetry`), the mock autopilot and its parts (``mock_*``) and the
  ArduPilot applet inside it (:mod:`.vehicle.lua_applet`). Real ArduCopter SITL is no
  simulator of ours: :mod:`tcm_companion.sitl` runs it.
- :mod:`.sources` — registers the simulated cameras as ``[camera] source = "sim"`` and
  ``"sim_autopilot"``.

``make_scenario(name, camera)`` gives an in-memory scenario that behaves like a loaded
``tcm-scenario/1`` directory; ``export_scenario(sim, out_dir)`` writes one (with
``detections=`` also a simulated detector's ``detections.csv``); ``docs/simulator.md``
lists the scenarios.

The names below are loaded on first use, so that importing a light submodule (the
scenario names of :mod:`.scene.names`, for the command line) does not import the renderer.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from .scene.names import OBJECT_SCENARIO_NAMES, PAPER_SCENARIO_NAMES, SCENARIO_NAMES

if TYPE_CHECKING:
    from .scene.detector_sim import DetectorSimConfig, simulate_detections
    from .scene.export import SimulatedScenario, export_scenario, make_scenario
    from .scene.scenarios import default_camera, describe_scenario, flight_plan, plan_world

#: Where each lazily loaded name lives.
_LAZY = {
    "DetectorSimConfig": ".scene.detector_sim",
    "simulate_detections": ".scene.detector_sim",
    "SimulatedScenario": ".scene.export",
    "export_scenario": ".scene.export",
    "make_scenario": ".scene.export",
    "default_camera": ".scene.scenarios",
    "describe_scenario": ".scene.scenarios",
    "flight_plan": ".scene.scenarios",
    "plan_world": ".scene.scenarios",
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
