"""The simulated scenarios' names, and nothing else: light enough for the command line's
``choices`` and help (``tcm-companion --help`` must not import numpy or the renderer).

:mod:`.scenarios` designs each of them (:func:`~.scenarios.describe_scenario` says in
one line what each shows); ``docs/simulator.md`` lists them.
"""

from __future__ import annotations

#: The longest simulated flight, s: an hour, 90 000 frames at 25 fps (a flight's plan
#: and truth are arrays of all its frames, held at once).
MAX_FLIGHT_S = 3600.0

#: The paper's flights and the traps around them (red balls only).
PAPER_SCENARIO_NAMES: tuple[str, ...] = (
    "TS",
    "T45",
    "T90",
    "RAISED",
    "INPLANE",
    "COLLISION",
    "HEADON",
    "TWO",
)
#: Objects of other kinds, and scenes that make angular size hard.
OBJECT_SCENARIO_NAMES: tuple[str, ...] = (
    "TS-BOX",
    "T45-BOX",
    "T90-BOX",
    "TS-CYL",
    "T45-CYL",
    "T90-CYL",
    "TS-DISC",
    "T45-DISC",
    "T90-DISC",
    "RAISED-DISC",
    "INPLANE-BOX",
    "COLLISION-CYL",
    "COLLISION-DISC",
    "HEADON-BOX",
    "DARKBG",
    "BACKLIT",
    "SKY2TREE",
    "MIXED",
)
#: Flights for camera rigs (``--rig quad``, issue 26): an object crossing from one camera's
#: view into the next, one held in two cameras' overlap, a camera dying mid-flight.
RIG_SCENARIO_NAMES: tuple[str, ...] = ("PASS", "OVERLAP", "CAMLOSS")
#: Every scenario the simulator (and the mock autopilot) can fly.
SCENARIO_NAMES: tuple[str, ...] = PAPER_SCENARIO_NAMES + OBJECT_SCENARIO_NAMES + RIG_SCENARIO_NAMES

#: The simulator's camera rigs (``sitl --rig``; :func:`~.cameras.rig_cameras` builds them).
RIGS: tuple[str, ...] = ("panorama", "quad", "front-back", "front-right")

#: Rig scenarios in which a camera of the rig stops delivering: scenario -> (camera name,
#: seconds after the start of the flight). ``CAMLOSS``: the ``front`` camera (of the
#: ``quad`` and ``front-back`` rigs) dies 8 s in.
CAMERA_LOSS: dict[str, tuple[str, float]] = {"CAMLOSS": ("front", 8.0)}

__all__ = [
    "CAMERA_LOSS",
    "OBJECT_SCENARIO_NAMES",
    "PAPER_SCENARIO_NAMES",
    "RIGS",
    "RIG_SCENARIO_NAMES",
    "SCENARIO_NAMES",
]
