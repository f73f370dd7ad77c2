"""A two-camera rig against real ArduCopter SITL (issue 26 §5): the crossing ball
appears in the front camera, the vehicle turns 40° left, and the ball reaches it through
the right camera; the applet still brakes within 0.5 s of the first alarming status.

Both cameras are rendered from the pose the firmware reports (one
:class:`~tcm_companion.sim.scene.autopilot_camera.AutopilotSimCamera` on SERIAL2, the
right camera a :class:`~tcm_companion.sim.scene.autopilot_camera.RigView` of it); the
daemon runs them as two cameras. Skipped with a one-line reason when the binary is absent
(``$TCM_ARDUPILOT_SITL``, ``../shared/ardupilot-sitl``).
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from tcm_companion.config import AppConfig
from tcm_companion.sitl.ardupilot import APPLET, SITL_PARAMS, fly_scene, rig_plan
from tcm_companion.sitl.ardupilot_process import skip_reason
from tcm_companion.sitl.ardupilot_vehicle import ArduPilotSitl

SKIP_REASON = skip_reason()
pytestmark = [
    pytest.mark.skipif(bool(SKIP_REASON), reason=SKIP_REASON or "ArduCopter SITL present"),
    pytest.mark.xdist_group("sitl"),  # real time: one at a time (see tests/test_daemon.py)
    pytest.mark.timeout(150),
    pytest.mark.slow,
]


def test_a_ball_handed_from_the_front_camera_to_the_right_one_still_brakes(
    tmp_path: Path,
) -> None:
    plan = rig_plan("crossing", "front-right")
    with ArduPilotSitl(params=SITL_PARAMS, scripts=[APPLET]) as sitl:
        r = asyncio.run(fly_scene(AppConfig(), sitl, plan, state_dir=str(tmp_path)))
    lines = "\n".join(r.lines())
    print(lines)
    assert r.cameras == ("front", "right"), lines
    assert r.launch is not None and r.turn_s is not None, lines
    # Seen first in the front camera, then (after the turn) in the right one.
    front, right = r.first_matched_s.get(0), r.first_matched_s.get(1)
    assert front is not None and right is not None and front < r.turn_s < right + 1.0, lines
    assert r.matched_by_camera.get(0, 0) >= 10 and r.matched_by_camera.get(1, 0) >= 10, lines
    # The alarm comes from the right camera, and the applet brakes within 0.5 s of it.
    assert r.alarms and r.alarms[0].camera_id == 1, lines
    assert r.alarm_to_brake_s is not None and 0.0 <= r.alarm_to_brake_s <= 0.5, lines
    assert r.brake_text.startswith(f"TCM: collision course id {r.alarms[0].track_id} "), lines
    assert r.left_brake_while_alarm == [], lines
    assert r.min_clearance_m > 0.5, lines  # braked in time: no contact
    assert r.ok, lines
