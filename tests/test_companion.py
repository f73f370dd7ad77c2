"""The daemon's logic without IO (service/companion.py), on a simulated flight and a fake clock.

Each test drives a :class:`Companion` the way the daemon does — telemetry events as they
are received, frames at their capture times, a tick every second — and reads what the
endpoint would have sent to the autopilot.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from tcm_companion.core.camera import Equirectangular
from tcm_companion.core.pipeline import PipelineConfig
from tcm_companion.core.telemetry import AttitudeSample, PositionSample
from tcm_companion.mavlink import tcm_dialect as d
from tcm_companion.mavlink.endpoint import (
    CompanionEndpoint,
    ParamChanged,
    TelemetryReceived,
    TelemetryRejected,
)
from tcm_companion.service.companion import Companion, DaemonConfig
from tcm_companion.sim.export import SimulatedScenario
from tcm_companion.sim.scenarios import flight_plan

CAMERA = Equirectangular(360, 220)


@pytest.fixture(scope="module")
def flight() -> tuple[SimulatedScenario, list[np.ndarray]]:
    scenario = SimulatedScenario(flight_plan("TS", duration_s=5.0), CAMERA)
    frames = [img for _, _, img in scenario.iter_frames()]
    return scenario, frames


def decode(data: bytes) -> list[Any]:
    mav = d.MAVLink(None)
    mav.robust_parsing = True
    return [m for m in (mav.parse_buffer(data) or []) if m.get_type() != "BAD_DATA"]


class Driver:
    """Feeds a companion like the daemon: telemetry by receive time, frames, ticks."""

    def __init__(
        self,
        scenario: SimulatedScenario,
        frames: list[np.ndarray],
        config: DaemonConfig | None = None,
    ) -> None:
        self.scenario = scenario
        self.frames = frames
        self.telemetry = sorted(scenario.telemetry, key=lambda s: s.recv_us)
        t0 = int(scenario.frame_times_us[0]) - 500_000
        self.endpoint = CompanionEndpoint(now_us=t0)
        self.companion = Companion(
            [CAMERA], PipelineConfig(), self.endpoint, t0, config or DaemonConfig()
        )
        self.j = 0
        self.next_tick = t0 + 1_000_000
        self.sent: list[Any] = []
        self.results: list[Any] = []

    def telemetry_until(self, t_us: int, keep: Any = lambda s: True, nan_attitude: bool = False):
        while self.j < len(self.telemetry) and self.telemetry[self.j].recv_us <= t_us:
            s = self.telemetry[self.j]
            self.j += 1
            if not keep(s):
                continue
            if nan_attitude and isinstance(s, AttitudeSample):
                self.companion.handle_events([TelemetryRejected("attitude", "NaN")], s.recv_us)
                continue
            # As the endpoint does when it receives telemetry: its clock fit.
            self.endpoint.telemetry_clock.observe(s.time_boot_us, s.recv_us)
            self.companion.handle_events([TelemetryReceived(s)], s.recv_us)

    def run(self, first: int, last: int, **kw: Any) -> None:
        for i in range(first, last):
            t = int(self.scenario.frame_times_us[i])
            self.telemetry_until(t + 5_000, **kw)
            while self.next_tick <= t:
                self.companion.tick(self.next_tick)
                self.endpoint.poll(self.next_tick)
                self.next_tick += 1_000_000
            self.companion.note_frame_arrival(0, t + 1_000)
            self.results.append(self.companion.process(0, self.frames[i], t, t + 3_000))
            self.endpoint.poll(t + 3_000)  # the link's timer polls about this often
            self.sent += decode(self.endpoint.data_to_send())

    def statuses(self) -> list[Any]:
        return [m for m in self.sent if m.get_type() == "TCM_OBJECT_STATUS"]

    def texts(self) -> list[str]:
        return [m.text for m in self.sent if m.get_type() == "STATUSTEXT"]


def test_a_normal_flight_sends_decided_statuses(flight: Any) -> None:
    drv = Driver(*flight)
    drv.run(0, 100)
    st = drv.statuses()
    assert len(st) >= 90
    late = st[-30:]
    decided = [m for m in late if m.state != d.TCM_OBJECT_STATE_UNKNOWN]
    assert len(decided) >= 25
    # TS: the ball is stationary, and TCM says so.
    assert all(m.state == d.TCM_OBJECT_STATE_STATIONARY for m in decided)
    assert drv.companion.stats.frames_processed == 100
    assert (
        drv.companion.health_flags(int(flight[0].frame_times_us[99]))
        & (d.TCM_HEALTH_ATTITUDE_STALE | d.TCM_HEALTH_CAMERA_LOST)
        == 0
    )


def test_a_frame_ahead_of_the_attitude_waits_for_the_next_sample(flight: Any) -> None:
    drv = Driver(*flight)
    drv.run(0, 10)
    comp = drv.companion
    newest = comp.cameras[0].pipeline.telemetry.latest_attitude_time_us()
    assert newest is not None
    cfg = comp.config
    # Within the allowed lead: at once (interpolated or briefly extrapolated).
    assert comp.frame_deadline_us(0, int(newest) + cfg.attitude_lead_max_us - 1) is None
    # Beyond it: wait, but never longer than attitude_wait_max_us after capture.
    t = int(newest) + cfg.attitude_lead_max_us + 5_000
    assert comp.frame_deadline_us(0, t) == t + cfg.attitude_wait_max_us
    # The sample after the frame arrives: go.
    tel = comp.cameras[0].pipeline.telemetry
    after = AttitudeSample.from_euler(
        int(t - tel.clock.offset_us) + 1_000, t + 3_000, 0.0, 0.0, 0.0
    )
    comp.handle_events([TelemetryReceived(after)], t + 3_000)
    assert comp.frame_deadline_us(0, t) is None


def test_stale_attitude_makes_objects_unknown_and_is_reported(flight: Any) -> None:
    drv = Driver(*flight)
    drv.run(0, 60)
    before = drv.statuses()[-1]
    assert before.state != d.TCM_OBJECT_STATE_UNKNOWN
    # The autopilot's attitude stops (position keeps coming).
    drv.run(60, 85, keep=lambda s: isinstance(s, PositionSample))
    t = int(flight[0].frame_times_us[84])
    comp = drv.companion
    assert comp.health_flags(t) & d.TCM_HEALTH_ATTITUDE_STALE
    last = drv.statuses()[-5:]
    assert last and all(m.state == d.TCM_OBJECT_STATE_UNKNOWN for m in last)
    comp.tick(t)  # the once-a-second health check
    drv.endpoint.poll(t + 1_000_000)
    drv.sent += decode(drv.endpoint.data_to_send())
    assert "TCM: attitude stale" in drv.texts()
    # It comes back: objects are decided again once the attitude is healthy.
    drv.run(85, 125)
    assert drv.statuses()[-1].state == d.TCM_OBJECT_STATE_STATIONARY


def test_nan_attitude_is_invalid_not_silently_stale(flight: Any) -> None:
    drv = Driver(*flight)
    drv.run(0, 60)
    drv.run(60, 64, nan_attitude=True)
    t = int(flight[0].frame_times_us[63])
    st = drv.companion.inputs.status(t)["attitude"]
    assert st.alive and not st.valid and st.problem == "attitude invalid"
    assert all(m.state == d.TCM_OBJECT_STATE_UNKNOWN for m in drv.statuses()[-3:])
    assert drv.companion.stats.faults["attitude rejected"] > 0


def test_a_pipeline_exception_costs_one_frame_and_repeated_ones_rebuild(
    flight: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    drv = Driver(*flight, DaemonConfig(rebuild_after_errors=3))
    drv.run(0, 30)
    pipe = drv.companion.cameras[0].pipeline
    real_step = pipe.step
    calls = {"n": 0}

    def failing(*a: Any, **k: Any) -> Any:
        calls["n"] += 1
        raise RuntimeError("boom")

    monkeypatch.setattr(pipe, "step", failing)
    drv.run(30, 31)
    assert drv.results[-1] is None and drv.companion.stats.frames_failed == 1
    assert any("pipeline error RuntimeError" in text for text in drv.texts())
    monkeypatch.setattr(pipe, "step", real_step)
    drv.run(31, 32)
    assert drv.results[-1] is not None  # one bad frame, then business as usual
    monkeypatch.setattr(pipe, "step", failing)
    drv.run(32, 35)
    assert drv.companion.stats.pipeline_rebuilds == 1
    assert drv.companion.cameras[0].pipeline is not pipe  # a fresh pipeline ...
    drv.run(35, 40)
    assert all(r is not None for r in drv.results[-5:])  # ... that works
    assert drv.companion.stats.frames_processed == 30 + 1 + 5


def test_a_stale_camera_tells_the_autopilot_its_objects_are_unknown(flight: Any) -> None:
    drv = Driver(*flight)
    drv.run(0, 60)
    comp = drv.companion
    assert comp.cameras[0].last_objects
    t = int(flight[0].frame_times_us[59])
    n = len(drv.statuses())
    changes = comp.tick(t + 800_000)  # no frame for 0.8 s
    assert ("camera0", "camera0 stale") in changes
    drv.sent += decode(drv.endpoint.data_to_send())
    new = drv.statuses()[n:]
    assert new and all(m.state == d.TCM_OBJECT_STATE_UNKNOWN for m in new)
    assert comp.health_report(t + 800_000).health_flags & d.TCM_HEALTH_CAMERA_LOST
    # Said once, not every tick.
    comp.tick(t + 1_800_000)
    assert len(decode(drv.endpoint.data_to_send())) == 0 or not [
        m for m in decode(drv.endpoint.data_to_send()) if m.get_type() == "TCM_OBJECT_STATUS"
    ]


def test_a_parameter_change_rebuilds_the_pipeline_and_keeps_the_telemetry(flight: Any) -> None:
    drv = Driver(*flight)
    drv.run(0, 40)
    comp = drv.companion
    old = comp.cameras[0].pipeline
    drv.endpoint.params.set("TCM_THRESH", 0.2)
    comp.handle_events([ParamChanged("TCM_THRESH", 0.2)], 0)
    new = comp.cameras[0].pipeline
    assert new is not old and new.config.classifier.tcm_threshold == pytest.approx(0.2)
    assert new.telemetry is old.telemetry
    # An output switch does not touch the pipeline.
    drv.endpoint.params.set("TCM_OUT_OBST", 1)
    comp.handle_events([ParamChanged("TCM_OUT_OBST", 1)], 0)
    assert comp.cameras[0].pipeline is new
    drv.run(40, 100)
    assert any(m.state == d.TCM_OBJECT_STATE_STATIONARY for m in drv.statuses()[-10:])


def test_an_autopilot_reboot_clock_jump_is_survived(flight: Any) -> None:
    """The autopilot's boot clock restarts mid-flight: the fit restarts, objects recover."""
    scenario, frames = flight
    drv = Driver(scenario, frames)
    drv.run(0, 40)
    jump = 30_000_000  # boot times 30 s earlier from here on
    drv.telemetry = drv.telemetry[: drv.j] + [
        dataclasses.replace(s, time_boot_us=max(0, s.time_boot_us - jump))
        for s in drv.telemetry[drv.j :]
    ]
    drv.run(40, 100)
    assert drv.companion.stats.frames_processed == 100
    assert any(m.state == d.TCM_OBJECT_STATE_STATIONARY for m in drv.statuses()[-10:])


def test_daemon_config_is_checked() -> None:
    with pytest.raises(ValueError, match="camera_timeout_us"):
        DaemonConfig(camera_timeout_us=0)
    with pytest.raises(ValueError, match="attitude_wait_max_us"):
        DaemonConfig(attitude_lead_max_us=50_000, attitude_wait_max_us=10_000)


def test_nothing_is_sent_before_the_autopilot_clock_is_known(flight: Any) -> None:
    drv = Driver(*flight)
    drv.run(0, 10, keep=lambda s: False)  # frames, but no telemetry at all
    assert drv.statuses() == []
    assert drv.companion.stats.frames_without_time_base == 10
    drv.run(10, 40)  # telemetry arrives: statuses flow, with real boot times
    st = drv.statuses()
    assert st and all(m.time_boot_ms > 0 for m in st)


def test_attitude_time_mapping_uses_timesync_and_removes_the_link_latency() -> None:
    """Telemetry arriving 3 ms after it was stamped biases the envelope fit by 3 ms;
    with a fresh, agreeing TIMESYNC offset the pipeline's clock has no bias."""
    from tcm_companion.service.companion import TimesyncClock

    offset = 5_000_000_000  # companion - autopilot boot (µs)
    latency = 3_000
    endpoint = CompanionEndpoint(now_us=offset)
    clock = TimesyncClock(endpoint)
    for k in range(200):
        boot = 1_000_000 + 20_000 * k
        clock.observe(boot, boot + offset + latency)
    assert clock.offset_us == pytest.approx(offset + latency)  # no TIMESYNC yet: the fit
    assert not clock.used_timesync
    # TIMESYNC replies with a symmetric 1 ms each way: offset exactly recovered.
    for k in range(5):
        sent = offset + 1_000_000 + 1_000_000 * k
        endpoint.timesync.add_reply(sent, (sent + 1_000 - offset) * 1000, sent + 2_000)
    clock.observe(5_000_000, 5_000_000 + offset + latency)
    assert clock.offset_us == pytest.approx(offset, abs=1)
    assert clock.used_timesync
    # A TIMESYNC offset that disagrees with the telemetry (a reboot seen by one side
    # first) is not used.
    for k in range(5):
        sent = offset + 7_000_000 + 1_000_000 * k
        endpoint.timesync.add_reply(sent, (sent + 1_000 - offset + 9_000_000) * 1000, sent + 2_000)
    assert clock.offset_us == pytest.approx(offset + latency)
    assert not clock.used_timesync
