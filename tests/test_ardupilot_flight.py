"""The daemon flies against real ArduCopter SITL, with the applet loaded in the firmware.

No hand-made frames: the daemon (on SERIAL1) sees a simulated ball through a camera that
renders the field from the pose the firmware reports (SERIAL2), and its own statuses make
the applet in the firmware switch to BRAKE. One SITL instance flies the three flights
in turn (north, south, north, so the vehicle stays in the field's clear area); the
proximity and parameter checks use a second one, on the ground. Every flight prints its
report (pytest -s, or on failure). Skipped with a one-line reason when the binary is
absent (``$TCM_ARDUPILOT_SITL``, ``../shared/ardupilot-sitl``).
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tcm_companion.config import AppConfig
from tcm_companion.sim.scene.autopilot_camera import SceneConfig
from tcm_companion.sitl.ardupilot import (
    APPLET,
    SITL_PARAMS,
    FlightPlanAP,
    FlightReport,
    fly_scene,
)
from tcm_companion.sitl.ardupilot_process import skip_reason
from tcm_companion.sitl.ardupilot_vehicle import ArduPilotSitl

SKIP_REASON = skip_reason()
pytestmark = [
    pytest.mark.skipif(bool(SKIP_REASON), reason=SKIP_REASON or "ArduCopter SITL present"),
    pytest.mark.xdist_group("sitl"),  # real time: one at a time (see tests/test_daemon.py)
    pytest.mark.timeout(150),
]


#: ADS-B in over MAVLink and AP_Avoidance on (its default action: report)
ADSB_PARAMS = {"ADSB_TYPE": 1, "AVD_ENABLE": 1}


@pytest.fixture(scope="module")
def flying() -> Iterator[ArduPilotSitl]:
    with ArduPilotSitl(params={**SITL_PARAMS, **ADSB_PARAMS}, scripts=[APPLET]) as sitl:
        yield sitl


def _fly(sitl: ArduPilotSitl, plan: FlightPlanAP, tmp_path: Path) -> FlightReport:
    report = asyncio.run(fly_scene(AppConfig(), sitl, plan, state_dir=str(tmp_path)))
    print("\n".join(report.lines()))
    return report


def _assert_braked_for_the_alarm(r: FlightReport, max_true_ttc_s: float = math.inf) -> None:
    """``max_true_ttc_s``: the true time to contact when the first alarm was raised is
    below this (the applet alarms below 3 s estimated)."""
    lines = "\n".join(r.lines())
    assert r.launch is not None, lines
    assert r.alarms, lines
    assert r.brake_s is not None, lines
    truth = r.first_alarm_truth
    assert truth is not None and truth.ttc_true_s < max_true_ttc_s, lines
    # within 0.5 s of the daemon's first alarming status (the applet runs every 20 ms)
    assert r.alarm_to_brake_s is not None and 0.0 <= r.alarm_to_brake_s <= 0.5, lines
    assert r.brake_text.startswith(f"TCM: collision course id {r.alarms[0].track_id} "), lines
    assert r.left_brake_while_alarm == [], lines  # braked for as long as the alarm held
    assert not any(t.startswith("Lua") for _, t in r.texts), lines
    assert r.summary is not None and r.summary.frames_balance, lines
    assert r.sitl_clock is not None and r.stale, lines  # the report saw the clock and TCM_STALE


def test_crossing_collision_course_brakes(flying: ArduPilotSitl, tmp_path: Path) -> None:
    # ... and our ADSB_VEHICLE for the moving ball (range from its known radius) reaches
    # AP_Avoidance, which rates it a threat (COLLISION from the autopilot, our ICAO id)
    plan = FlightPlanAP(
        SceneConfig("crossing"),
        heading_deg=0.0,
        companion_params=(("TCM_OUT_ADSB", 1), ("TCM_OBJ_RADIUS", 0.375)),
    )
    r = _fly(flying, plan, tmp_path)
    lines = "\n".join(r.lines())
    _assert_braked_for_the_alarm(r)
    assert r.states.get("moving", 0) > r.states.get("stationary", 0), lines
    assert r.min_clearance_m > 0.5  # it braked in time: no contact
    ids = {ident for _, ident, _, _ in r.collisions}
    assert 0x7C0000 + r.alarms[0].track_id in ids, lines
    assert max(threat for _, _, threat, _ in r.collisions) >= 1, lines  # LOW or above
    assert r.ok, lines


def test_headon_brakes_although_the_state_is_unknown(flying: ArduPilotSitl, tmp_path: Path) -> None:
    r = _fly(flying, FlightPlanAP(SceneConfig("headon"), heading_deg=180.0), tmp_path)
    # Head-on the looming is clean: the alarm comes when the ball is truly ~3 s away
    # (3.1-3.3 s in every flight measured). The crossing ball's alarm can still come early
    # (docs/ardupilot.md, "Where the method falls short"); the young-track case that read
    # 2.7 s for a true 6.8 s is tests/test_ttc.py's.
    _assert_braked_for_the_alarm(r, max_true_ttc_s=4.5)
    first = r.alarms[0]
    assert (first.state, first.reason) == ("unknown", "head-on"), "\n".join(r.lines())
    assert r.min_clearance_m > 0.5
    # the alarm holds and then clears (the vehicle stopped short of the ball)
    assert r.alarm_held_s is not None and r.alarm_held_s > 0.5, "\n".join(r.lines())
    assert r.ok, "\n".join(r.lines())


def test_pilot_mode_change_makes_the_applet_stand_down(
    flying: ArduPilotSitl, tmp_path: Path
) -> None:
    plan = FlightPlanAP(
        SceneConfig("headon"), heading_deg=0.0, pilot_mode="LOITER", pilot_after_s=0.3
    )
    r = _fly(flying, plan, tmp_path)
    lines = "\n".join(r.lines())
    assert r.brake_s is not None and r.pilot_mode_s is not None, lines
    assert r.stand_down_text_s is not None and r.stand_down_text_s >= r.pilot_mode_s, lines
    # the pilot's mode stands: the applet never switches back to BRAKE
    after = [m for t, m in r.modes if t > r.pilot_mode_s]
    assert after and after[-1] == "LOITER" and "BRAKE" not in after, (after, lines)
    assert r.ok, lines


def test_proximity_and_parameters_through_ardupilot(tmp_path: Path) -> None:
    """OBSTACLE_DISTANCE from the daemon makes PRX1 healthy, and stopping the daemon makes it
    unhealthy; the daemon's TCM_* parameters are read and set from the ground station's
    link, through ArduPilot's routing."""
    from tcm_companion.sim.scene.autopilot_camera import AutopilotSimCamera
    from tcm_companion.sitl.ardupilot import daemon_on_sitl

    params = {**SITL_PARAMS, "PRX1_TYPE": 2}

    async def scenario(sitl: ArduPilotSitl) -> dict[str, object]:
        config = AppConfig()
        camera = AutopilotSimCamera(config.camera.model, sitl.serial2_url, SceneConfig("static"))
        out: dict[str, object] = {}
        async with daemon_on_sitl(config, sitl, camera, str(tmp_path)) as (task, endpoint):
            # the ground station reads our parameter through ArduPilot (component 191) ...
            out["TCM_THRESH"] = await asyncio.to_thread(sitl.gcs.get_param, "TCM_THRESH", 191, 10.0)
            out["healthy_before"] = sitl.proximity_healthy()
            # ... and sets one: OBSTACLE_DISTANCE on
            t_set = time.monotonic()
            await asyncio.to_thread(sitl.gcs.set_param, "TCM_OUT_OBST", 1, 10.0, 191)
            out["daemon_value"] = endpoint.params.values["TCM_OUT_OBST"]
            await asyncio.to_thread(
                sitl.gcs.wait_for, lambda: sitl.proximity_healthy() is True, 10.0, "PRX healthy"
            )
            out["healthy_after_s"] = time.monotonic() - t_set
        task.result()  # the daemon ended cleanly
        t_stop = time.monotonic()
        await asyncio.to_thread(
            sitl.gcs.wait_for, lambda: sitl.proximity_healthy() is False, 5.0, "PRX unhealthy"
        )
        out["unhealthy_after_s"] = time.monotonic() - t_stop
        return out

    with ArduPilotSitl(params=params, scripts=[APPLET]) as sitl:
        out = asyncio.run(scenario(sitl))
    print(out)
    assert out["TCM_THRESH"] == pytest.approx(
        AppConfig().pipeline.classifier.tcm_threshold, rel=1e-6
    )
    assert out["healthy_before"] is False
    assert out["daemon_value"] == 1
    assert isinstance(out["healthy_after_s"], float) and out["healthy_after_s"] < 5.0
    assert isinstance(out["unhealthy_after_s"], float) and out["unhealthy_after_s"] < 3.0
    assert math.isfinite(out["unhealthy_after_s"])
