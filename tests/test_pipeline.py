"""The pipeline as a whole: bad input is counted and survived; results are consistent."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tcm_companion.config import AppConfig
from tcm_companion.core.pipeline import Pipeline
from tcm_companion.core.telemetry import AttitudeSample
from tcm_companion.io.scenario import load_scenario
from tcm_companion.replay import run_replay

from .conftest import example_path


@pytest.fixture(scope="module")
def pinhole():  # type: ignore[no-untyped-def]
    s = load_scenario(example_path("EX-PINHOLE"))
    return s, list(s.iter_frames()), sorted(s.telemetry, key=lambda x: x.recv_us)


def feed(pipe: Pipeline, frames, telemetry, wait_us: int = 40_000, mutate=None):  # type: ignore[no-untyped-def]
    j, out = 0, []
    for i, t_us, img in frames:
        start = j
        while j < len(telemetry) and telemetry[j].recv_us <= t_us + wait_us:
            j += 1
        batch = list(telemetry[start:j])
        if mutate is not None:
            batch = mutate(i, batch)
        pipe.telemetry.extend(batch)
        out.append(pipe.step(img, t_us))
    return out


def test_replay_matches_manual_feeding(pinhole) -> None:  # type: ignore[no-untyped-def]
    s, frames, tel = pinhole
    a = feed(Pipeline(s.camera), frames, tel)
    b = list(run_replay(s, AppConfig()))
    assert [len(r.objects) for r in a] == [len(r.objects) for r in b]
    assert [o.state for r in a for o in r.objects] == [o.state for r in b for o in r.objects]


def test_static_ball_is_stationary_and_bearings_are_consistent(pinhole) -> None:  # type: ignore[no-untyped-def]
    s, frames, tel = pinhole
    results = feed(Pipeline(s.camera), frames, tel)
    states = [o.state for r in results for o in r.objects]
    # Warm-up: stationary is only claimed after the full 25-frame interval.
    assert states[:25] == ["unknown"] * 25
    assert set(states[25:]) == {"stationary"}
    o = results[-1].objects[0]
    cam = s.camera
    np.testing.assert_allclose(cam.R_body_from_cam @ o.bearing_cam, o.bearing_body, atol=1e-12)
    assert o.reason == "" and math.isfinite(o.disparity) and o.disparity < 0.09
    assert set(results[-1].timings_ms) >= {"detect", "flow", "track", "classify", "total"}


def test_nan_attitude_is_refused_and_counted(pinhole) -> None:  # type: ignore[no-untyped-def]
    s, frames, tel = pinhole

    def poison(i, batch):  # type: ignore[no-untyped-def]
        out = []
        for smp in batch:
            if isinstance(smp, AttitudeSample) and i % 3 == 0:
                R = smp.R_ned_from_body.copy()
                R[0, 0] = np.nan
                smp = AttitudeSample(smp.time_boot_us, smp.recv_us, R)
            out.append(smp)
        return out

    pipe = Pipeline(s.camera)
    results = feed(pipe, frames, tel, mutate=poison)
    assert pipe.telemetry.health.rejected["attitude not finite or not a rotation"] > 10
    assert {o.state for o in results[-1].objects} == {"stationary"}


def test_no_telemetry_gives_no_bearings_but_no_crash(pinhole) -> None:  # type: ignore[no-untyped-def]
    s, frames, _ = pinhole
    pipe = Pipeline(s.camera)
    results = feed(pipe, frames[:5], [])
    assert all(not r.attitude_ok and r.objects == () for r in results)
    assert pipe.health.frames_without_attitude == 5


def test_time_going_backwards_resets_history(pinhole) -> None:  # type: ignore[no-untyped-def]
    s, frames, tel = pinhole
    pipe = Pipeline(s.camera)
    feed(pipe, frames[:15], tel)
    _, t_us, img = frames[15]
    r = pipe.step(img, t_us - 10_000_000)
    assert pipe.health.time_backwards == 1
    assert all(o.state == "unknown" for o in r.objects)


def test_bad_frames_are_counted_and_skipped(pinhole) -> None:  # type: ignore[no-untyped-def]
    s, frames, tel = pinhole
    pipe = Pipeline(s.camera)
    feed(pipe, frames[:3], tel)
    r = pipe.step(np.zeros((10, 10, 3), np.uint8), int(frames[3][1]))
    assert r.objects == () and pipe.health.bad_frames == 1
    r = pipe.step(np.zeros((480, 640), np.uint8), int(frames[4][1]))
    assert pipe.health.bad_frames == 2
    _, t_us, img = frames[5]
    assert len(pipe.step(img, t_us).objects) == 1
