"""The daemon's logic without IO (service/companion.py), on a simulated flight and a fake clock.

Each test drives a :class:`Companion` through its surface only, the way the daemon does:
telemetry as it is received, frames as cameras deliver them (``on_frame``), and
``process_due`` at every deadline the Companion names (``next_deadline_us``), in time
order (:class:`Driver`), reading what it would have sent to the autopilot
(``data_to_send``).
"""

from __future__ import annotations

import dataclasses
import math
import re
from typing import Any

import numpy as np
import pytest

from tcm_companion.core.pipeline import Pipeline, PipelineConfig
from tcm_companion.core.telemetry import AttitudeSample, PositionSample
from tcm_companion.mavlink import tcm_dialect as d
from tcm_companion.mavlink.endpoint import CompanionEndpoint, TelemetryReceived
from tcm_companion.service.companion import Companion
from tcm_companion.service.daemon_config import DaemonConfig
from tcm_companion.service.health import latency_percentile_ms
from tcm_companion.service.outputs import FrameProcessed, ParamsChanged
from tcm_companion.sim.scene.export import SimulatedScenario

from .helpers import CAMERA, Driver, decode, simulated_flight


@pytest.fixture(scope="module")
def flight() -> tuple[SimulatedScenario, list[np.ndarray]]:
    return simulated_flight(5.0)


def gcs_bytes(msg: Any) -> bytes:
    """``msg`` as a ground station (255/190) would send it."""
    mav = d.MAVLink(None, srcSystem=255, srcComponent=190)
    return bytes(msg.pack(mav))


@pytest.mark.slow  # over a second of CPU
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
    # The health check ran once a second, on its own deadlines.
    assert 4 <= len(drv.health_checks()) <= 6
    assert "fps" in drv.health_checks()[-1].status_line
    # No frame's output was reported written (frame_sent): no latency yet, and no "nan".
    assert all("latency n/a" in h.status_line for h in drv.health_checks())


def test_every_latency_figure_is_one_percentile(flight: Any) -> None:
    """The status line, TCM_PIPELINE_HEALTH and a run's summary read the latencies the
    same way (latency_percentile_ms: NumPy's linear interpolation)."""
    from tcm_companion.service.host import DaemonSummary

    lat = [5.0, 6.0, 7.0, 30.0]
    assert latency_percentile_ms(lat, 50) == pytest.approx(6.5)
    assert latency_percentile_ms(lat, 99) == pytest.approx(np.percentile(lat, 99))
    assert math.isnan(latency_percentile_ms([], 50))
    drv = Driver(*flight)
    drv.run(0, 30)
    comp = drv.companion
    comp.latencies_ms.clear()
    comp.latencies_ms.extend(lat)
    now = int(flight[0].frame_times_us[29])
    assert comp.health_report(now).latency_ms == pytest.approx(6.5)
    assert "latency p50 6.5 p99 29.3 ms" in comp.status_line(now)
    summary = DaemonSummary(0.0, 0, 0, 0, 0, 0, lat, comp.stats, {}, {}, 0, 0)
    assert summary.latency_percentile_ms(99) == latency_percentile_ms(lat, 99)


def test_a_frame_ahead_of_the_attitude_waits_for_the_next_sample(flight: Any) -> None:
    drv = Driver(*flight)
    drv.run(0, 10)
    comp = drv.companion
    newest = comp.telemetry.latest_attitude_time_us()
    assert newest is not None
    cfg = comp.config
    # Within the allowed lead: at once (interpolated or briefly extrapolated).
    assert comp.frame_deadline_us(0, int(newest) + cfg.attitude_lead_max_us - 1) is None
    # Beyond it: wait, but never longer than attitude_wait_max_us after capture.
    t = int(newest) + cfg.attitude_lead_max_us + 5_000
    assert comp.frame_deadline_us(0, t) == t + cfg.attitude_wait_max_us
    # Through the slot: delivered, the frame is not processed before its deadline ...
    comp.on_frame(0, drv.frames[10], t, t + 1_000)
    assert comp.next_deadline_us() <= t + cfg.attitude_wait_max_us
    n = comp.stats.frames_processed
    outs = comp.process_due(t + 2_000)
    assert not [o for o in outs if isinstance(o, FrameProcessed)]
    # ... the sample after it arrives: it is ready now, and goes.
    after = AttitudeSample.from_euler(int(t - comp.clock.offset_us) + 1_000, t + 3_000, 0, 0, 0)
    comp.on_events([TelemetryReceived(after)], t + 3_000)
    assert comp.frame_deadline_us(0, t) is None
    assert comp.next_deadline_us() <= t + 3_000
    outs = comp.process_due(t + 3_000)
    done = [o for o in outs if isinstance(o, FrameProcessed)]
    assert len(done) == 1 and done[0].waited and comp.stats.frames_processed == n + 1
    assert comp.stats.frames_waited == 1


def test_a_waiting_frame_goes_at_its_deadline_without_the_sample(flight: Any) -> None:
    drv = Driver(*flight)
    drv.run(0, 10)
    comp = drv.companion
    newest = int(comp.telemetry.latest_attitude_time_us() or 0)
    t = newest + comp.config.attitude_lead_max_us + 5_000
    comp.on_frame(0, drv.frames[10], t, t + 1_000)
    deadline = t + comp.config.attitude_wait_max_us
    assert not [o for o in comp.process_due(deadline - 1) if isinstance(o, FrameProcessed)]
    assert comp.next_deadline_us() == deadline
    assert [o for o in comp.process_due(deadline) if isinstance(o, FrameProcessed)]


def test_a_newer_frame_replaces_an_unprocessed_one_and_the_old_one_is_dropped(
    flight: Any,
) -> None:
    drv = Driver(*flight)
    drv.run(0, 20)
    comp = drv.companion
    t1, t2 = (int(flight[0].frame_times_us[i]) for i in (20, 21))
    drv.advance(t2 + 1_000)
    comp.on_frame(0, drv.frames[20], t1, t2 + 1_000)
    comp.on_frame(0, drv.frames[21], t2, t2 + 1_000)  # before the first was processed
    assert comp.stats.frames_dropped == 1
    n = len(drv.outputs)
    drv.advance(t2 + 41_000)
    done = [o for o in drv.outputs[n:] if isinstance(o, FrameProcessed)]
    assert len(done) == 1 and done[0].capture_mono_us == t2  # only the newest
    assert comp.health_flags(t2 + 41_000) & d.TCM_HEALTH_OVERLOADED
    # At stop, a frame still in its slot is dropped too.
    comp.on_frame(0, drv.frames[22], t2 + 40_000, t2 + 41_000)
    assert comp.discard_pending(t2 + 41_000) == 1 and comp.stats.frames_dropped == 2


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
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
    # The next once-a-second health check says so (the attitude still silent).
    drv.keep = lambda s: isinstance(s, PositionSample)

    def said() -> bool:
        return any(("attitude", "attitude stale") in h.changes for h in drv.health_checks())

    until = t
    while not said() and until < t + 1_000_000:
        until += 40_000
        drv.advance(until)
    drv.advance(until + 300_000)  # the STATUSTEXT queue sends one text per 250 ms
    assert said() and "TCM: attitude stale" in drv.texts()
    # It comes back: objects are decided again once the attitude is healthy.
    first = int(np.searchsorted(flight[0].frame_times_us, drv.now, side="right"))
    assert first <= 100
    drv.run(first, 125)
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
    comp = drv.companion
    pipe = comp.pipeline(0)
    real_step = Pipeline.step
    failing = {"on": False}

    def step(self: Pipeline, *a: Any, **k: Any) -> Any:
        if failing["on"]:
            raise RuntimeError("boom")
        return real_step(self, *a, **k)

    monkeypatch.setattr(Pipeline, "step", step)
    failing["on"] = True
    drv.run(30, 31)
    assert drv.results[-1] is None and comp.stats.frames_failed == 1
    assert any("pipeline error RuntimeError" in text for text in drv.texts())
    failing["on"] = False
    drv.run(31, 32)
    assert drv.results[-1] is not None  # one bad frame, then business as usual
    failing["on"] = True
    drv.run(32, 35)
    assert comp.stats.pipeline_rebuilds == 1
    assert comp.pipeline(0) is not pipe  # a fresh pipeline ...
    failing["on"] = False
    drv.run(35, 40)
    assert all(r is not None for r in drv.results[-5:])  # ... that works
    assert comp.stats.frames_processed == 30 + 1 + 5


def test_a_stale_camera_tells_the_autopilot_its_objects_are_unknown(flight: Any) -> None:
    drv = Driver(*flight)
    drv.run(0, 60)
    comp = drv.companion
    assert comp.last_objects(0)
    t = int(flight[0].frame_times_us[59])
    n = len(drv.statuses())
    drv.advance(t + 1_600_000)  # no frame for 1.6 s: at least one health check after 0.5 s
    changes = [c for h in drv.health_checks() for c in h.changes]
    assert ("camera0", "camera0 stale") in changes
    new = drv.statuses()[n:]
    # Said once (not every check), and as unknown.
    assert len(new) == len(comp.last_objects(0)) or len(new) >= 1
    assert new and all(m.state == d.TCM_OBJECT_STATE_UNKNOWN for m in new)
    assert comp.health_report(t + 800_000).health_flags & d.TCM_HEALTH_CAMERA_LOST
    m = len(drv.statuses())
    drv.advance(t + 3_000_000)
    assert len(drv.statuses()) == m


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_a_parameter_change_rebuilds_the_pipeline_and_keeps_the_telemetry(flight: Any) -> None:
    drv = Driver(*flight)
    drv.run(0, 40)
    comp = drv.companion
    old = comp.pipeline(0)
    mav = d.MAVLink(None)
    param_set = mav.param_set_encode(1, 191, b"TCM_THRESH", 0.2, d.MAV_PARAM_TYPE_REAL32)
    outs = comp.receive_data(gcs_bytes(param_set), drv.now)
    assert [o for o in outs if isinstance(o, ParamsChanged) and o.name == "TCM_THRESH"]
    new = comp.pipeline(0)
    assert new is not old and new.config.classifier.tcm_threshold == pytest.approx(0.2)
    assert new.telemetry is old.telemetry
    # An output switch does not touch the pipeline.
    out_obst = mav.param_set_encode(1, 191, b"TCM_OUT_OBST", 1, d.MAV_PARAM_TYPE_REAL32)
    assert comp.receive_data(gcs_bytes(out_obst), drv.now)
    assert comp.pipeline(0) is new
    drv.run(40, 100)
    assert any(m.state == d.TCM_OBJECT_STATE_STATIONARY for m in drv.statuses()[-10:])


def test_parameters_that_cannot_be_applied_together_are_refused_not_raised(
    flight: Any,
) -> None:
    """TCM_HUE_MIN = -40 is within its own range, but a seed range of [-40, 12] leaves the
    grow range [-30, 14]: applying it raised ValueError out of the event handling (a GCS
    could stop the daemon with one PARAM_SET). It is refused like an out-of-range value:
    the table keeps the old value, the reply says so, and a STATUSTEXT says why."""
    drv = Driver(*flight)
    drv.run(0, 10)
    comp = drv.companion
    before = comp.pipeline(0)
    mav = d.MAVLink(None)
    comp.data_to_send()
    bad = mav.param_set_encode(1, 191, b"TCM_HUE_MIN", -40.0, d.MAV_PARAM_TYPE_REAL32)
    outs = comp.receive_data(gcs_bytes(bad), drv.now)
    assert not [o for o in outs if isinstance(o, ParamsChanged)]
    assert comp.endpoint.params.values["TCM_HUE_MIN"] == -15.0 and comp.pipeline(0) is before
    comp.process_due(drv.now + 1)
    sent = decode(comp.data_to_send())
    replies = [m for m in sent if m.get_type() == "PARAM_VALUE" and m.param_id == "TCM_HUE_MIN"]
    assert replies and replies[-1].param_value == pytest.approx(-15.0)
    texts = "".join(m.text for m in sent if m.get_type() == "STATUSTEXT")  # chunks
    assert "TCM_HUE_MIN: seed_hue_deg must lie inside grow_hue_deg" in texts, texts
    assert comp.endpoint.stats["parameter refused"] == 1
    # The parameters have their settings' ranges ([0, 10] s for the interval, whose
    # setting is (0, 10]): the zero that range admits is refused by the same check, and a
    # seed range upside down too.
    for name, value in ((b"TCM_INTERVAL_S", 0.0), (b"TCM_HUE_MIN", 20.0)):
        raw = mav.param_set_encode(1, 191, name, value, d.MAV_PARAM_TYPE_REAL32)
        assert not [
            o for o in comp.receive_data(gcs_bytes(raw), drv.now) if isinstance(o, ParamsChanged)
        ]
    assert comp.endpoint.stats["parameter refused"] == 3
    assert comp.pipeline(0) is before
    # A value that fits is still applied.
    ok = mav.param_set_encode(1, 191, b"TCM_HUE_MIN", -20.0, d.MAV_PARAM_TYPE_REAL32)
    outs = comp.receive_data(gcs_bytes(ok), drv.now)
    assert [o for o in outs if isinstance(o, ParamsChanged) and o.name == "TCM_HUE_MIN"]
    assert comp.pipeline(0).config.detection.seed_hue_deg == (-20.0, 12.0)


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
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


def test_the_flight_log_falling_behind_is_reported_at_the_health_check(flight: Any) -> None:
    drv = Driver(*flight)
    drv.run(0, 5)
    comp = drv.companion
    t = comp.next_deadline_us()
    while not comp.health_due(t):
        drv.turn(t)
        t = max(t + 1, comp.next_deadline_us())
    comp.set_log_state(d.TCM_LOG_STATE_FAULT, 3, 4)
    drv.turn(t)
    drv.advance(t + 300_000)
    assert "TCM: log behind, 3 frames, 4 msgs lost" in drv.texts()
    assert drv.health_checks()[-1].report.health_flags & d.TCM_HEALTH_LOG_FAULT


@pytest.mark.slow  # over a second of CPU
def test_replay_frame_forces_the_clock_offset_and_the_override(flight: Any) -> None:
    drv = Driver(*flight)
    drv.run(0, 30)
    comp = drv.companion
    t = int(flight[0].frame_times_us[30])
    offset = comp.clock_offset_us()
    result = comp.replay_frame(
        0, drv.frames[30], t, t + 3_000, clock_offset_us=offset, override="attitude stale"
    )
    assert result is not None and result.objects
    assert all(o.state == "unknown" and o.reason == "attitude stale" for o in result.objects)
    assert comp.clock_offset_us() == offset  # forced only for that frame
    # Nothing is sent: no status among what replay_frame queued (run() drained the rest).
    sent = decode(comp.data_to_send())
    assert not [m for m in sent if m.get_type() == "TCM_OBJECT_STATUS"]


def test_attitude_time_mapping_uses_timesync_and_removes_the_link_latency() -> None:
    """Telemetry arriving 3 ms after it was stamped biases the envelope fit by 3 ms;
    with a fresh, agreeing TIMESYNC offset the pipeline's clock has no bias."""
    from tcm_companion.service.timesync_clock import TimesyncClock

    offset = 5_000_000_000  # companion monotonic - autopilot boot (µs)
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
    # Replay forces what the live pipeline used, for one frame.
    clock.force(123.0)
    assert clock.offset_us == 123.0
    clock.force(None)
    assert clock.offset_us == pytest.approx(offset, abs=1)
    # A TIMESYNC offset that disagrees with the telemetry (a reboot seen by one side
    # first) is not used.
    for k in range(5):
        sent = offset + 7_000_000 + 1_000_000 * k
        endpoint.timesync.add_reply(sent, (sent + 1_000 - offset + 9_000_000) * 1000, sent + 2_000)
    assert clock.offset_us == pytest.approx(offset + latency)
    assert not clock.used_timesync


def jittering(n_frames: int, seed: int = 1) -> list[int]:
    """Frame indices of a camera at 6-12 Hz, jittering: 2 to 4 of the 25 Hz frames apart
    (80-160 ms), as the simulated camera ran on a loaded machine."""
    rng = np.random.default_rng(seed)
    out, i = [], 0
    while i < n_frames:
        out.append(i)
        i += int(rng.integers(2, 5))
    return out


def test_a_slow_jittering_camera_is_one_fault_until_it_clears(flight: Any) -> None:
    """A camera at 6-12 Hz (25 expected) is slow the whole flight, its measured rate
    moving from tick to tick: one fault, one STATUSTEXT, its objects cleared once; the
    status line names the current rate and otherwise shows the objects being decided."""
    scenario, frames = flight
    drv = Driver(scenario, frames)
    drv.run_frames(jittering(len(frames)))
    drv.advance(drv.now + 300_000)  # the last STATUSTEXTs out of their queue
    comp = drv.companion
    checks = drv.health_checks()
    slow = [h for h in checks if "camera0 slow" in h.status_line]
    assert len(slow) >= 3
    # The measured rate moved while the condition held (what used to count as new faults).
    rates = {h.problems["camera0"] for h in slow}
    assert len(rates) >= 2, rates
    assert comp.stats.faults["camera0 slow"] == 1, dict(comp.stats.faults)
    assert [c for h in checks for c in h.changes if c[0] == "camera0"] == [
        ("camera0", slow[0].problems["camera0"])
    ]
    texts = [t for t in drv.texts() if "camera0 slow" in t]
    assert len(texts) == 1 and texts[0].endswith("Hz, expected 25)"), texts
    # Cleared once, at the onset; the ticks after show the objects being decided.
    empty = [h for h in slow[1:] if h.status_line.startswith("objects 0 ")]
    assert empty == [], [h.status_line for h in slow]


def test_a_camera_is_slow_against_its_own_frame_rate(flight: Any) -> None:
    """A 10 Hz camera ([camera] fps = 10) delivering 6-12 Hz is not slow; the same
    frames from a camera set to 25 Hz are."""
    scenario, frames = flight
    ten = Driver(scenario, frames, camera_rates_hz=[10.0])
    ten.run_frames(jittering(len(frames)))
    checks = ten.health_checks()
    assert len(checks) >= 4
    assert all("inputs OK" in h.status_line or "slow" not in h.status_line for h in checks)
    assert not any(k.startswith("camera0") for k in ten.companion.stats.faults)
    assert ten.companion.inputs.monitors["camera0"].spec.expected_hz == 10.0
    with pytest.raises(ValueError, match="camera rate"):
        Companion([CAMERA], PipelineConfig(), CompanionEndpoint(now_us=0), 0, camera_rates_hz=[])
    with pytest.raises(ValueError, match="positive"):
        Companion([CAMERA], PipelineConfig(), CompanionEndpoint(now_us=0), 0, camera_rates_hz=[0.0])


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_an_overloaded_pipeline_is_one_fault_and_decisions_go_on(flight: Any) -> None:
    """A pipeline that gets to only every other frame (each frame superseded by the next
    before it was processed, as on a slow core) is ``overloaded``: one fault, one
    STATUSTEXT naming the rate managed, shown on the status line; the objects are still
    decided at that rate (the method's durations are seconds); when frames stop being
    dropped it says it keeps up again."""
    scenario, frames = flight
    drv = Driver(scenario, frames)
    comp = drv.companion
    t_us = scenario.frame_times_us
    for i in range(0, 76, 2):  # 3 s: frame i still waits when frame i + 1 arrives
        arrive = int(t_us[i + 1]) + 1_000
        drv.advance(arrive)
        comp.on_frame(0, frames[i], int(t_us[i]), arrive)
        comp.on_frame(0, frames[i + 1], int(t_us[i + 1]), arrive)
        drv.advance(arrive + comp.config.attitude_wait_max_us)
    assert comp.stats.frames_dropped == 38
    overloaded = [h for h in drv.health_checks() if "overloaded" in h.status_line]
    assert len(overloaded) >= 2, [h.status_line for h in drv.health_checks()]
    assert re.search(r"overloaded: processing 1[23]\.\d of 25 fps$", overloaded[-1].status_line)
    assert d.TCM_HEALTH_OVERLOADED & overloaded[-1].report.health_flags
    # Decided at half the rate: TS's ball is stationary, and TCM says so.
    late = [o for r in drv.results[-10:] if r is not None for o in r.objects]
    assert late and all(o.state == "stationary" for o in late), [o.state for o in late]
    drv.run(76, len(frames))  # every frame processed again
    drv.advance(drv.now + 2_500_000)
    assert comp.stats.faults["pipeline overloaded"] == 1, dict(comp.stats.faults)
    texts = drv.texts()
    onset = [t for t in texts if "overloaded" in t]
    assert len(onset) == 1 and re.fullmatch(
        r"TCM: overloaded: processing \d+\.\d of 25 fps", onset[0]
    )
    assert "TCM: pipeline keeping up" in texts
    assert [c for h in drv.health_checks() for c in h.changes if c[0] == "pipeline"] == [
        ("pipeline", onset[0].removeprefix("TCM: ")),
        ("pipeline", ""),
    ]
    assert "overloaded" not in drv.health_checks()[-1].status_line
