"""TCM and ECM geometry: property tests on random triangles."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from tcm_companion.core.classify import ClassifierConfig, classify_pair, extent_disparity_sigma
from tcm_companion.core.frames import normalize
from tcm_companion.core.tcm import (
    ecm_omega_rad,
    stationary_range_m,
    tcm_disparity,
    triangle_geometry,
)

coord = st.floats(-20.0, 20.0)
vec3 = st.tuples(coord, coord, coord).map(lambda v: np.array(v, dtype=np.float64))
RADIUS_M = 0.375


def observe(q: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, float]:
    d = float(np.linalg.norm(p - q))
    return normalize(p - q), math.asin(RADIUS_M / d)


def distance_to_line(p: np.ndarray, q: np.ndarray, t_hat: np.ndarray) -> float:
    return float(np.linalg.norm(np.cross(p - q, t_hat)))


@pytest.mark.slow  # about a second of CPU (a property test; its deadline trips on a busy machine)
@settings(max_examples=300)
@given(q0=vec3, t=vec3, p=vec3)
def test_stationary_triangle_closes(q0: np.ndarray, t: np.ndarray, p: np.ndarray) -> None:
    q1 = q0 + t
    assume(np.linalg.norm(t) > 0.05)
    assume(min(np.linalg.norm(p - q0), np.linalg.norm(p - q1)) > 1.0)
    t_hat = normalize(t)
    b0, a0 = observe(q0, p)
    b1, a1 = observe(q1, p)
    geo = triangle_geometry(t_hat, b0, b1, a0, a1)
    assume(min(math.sin(geo.theta0_rad), math.sin(geo.theta1_rad)) > 0.05)
    assert float(geo.disparity) < 1e-9
    assert float(ecm_omega_rad(t_hat, b0, b1)) < 1e-6


@pytest.mark.slow  # over a second of CPU
@settings(max_examples=300)
@given(q0=vec3, t=vec3, p0=vec3, v=vec3)
def test_motion_changing_distance_to_flight_line_gives_positive_disparity(
    q0: np.ndarray, t: np.ndarray, p0: np.ndarray, v: np.ndarray
) -> None:
    q1 = q0 + t
    p1 = p0 + v
    assume(np.linalg.norm(t) > 0.05)
    assume(min(np.linalg.norm(p0 - q0), np.linalg.norm(p1 - q1)) > 1.0)
    t_hat = normalize(t)
    h0 = distance_to_line(p0, q0, t_hat)
    h1 = distance_to_line(p1, q1, t_hat)
    assume(h0 > 0.1 and abs(h1 - h0) > 0.05 * h0)
    b0, a0 = observe(q0, p0)
    b1, a1 = observe(q1, p1)
    d0, d1 = np.linalg.norm(p0 - q0), np.linalg.norm(p1 - q1)
    delta = float(tcm_disparity(t_hat, b0, b1, a0, a1))
    # Exact: δ = (d0/d1)·|h0 - h1|/h0 — the triangle fails to close by the change in the
    # object's distance from the line of travel.
    assert delta == pytest.approx((d0 / d1) * abs(h0 - h1) / h0, rel=1e-6, abs=1e-9)
    assert delta > 0.0


@given(q0=vec3, t=vec3, p0=vec3, s=st.floats(-3.0, 3.0))
def test_motion_parallel_to_translation_is_invisible(
    q0: np.ndarray, t: np.ndarray, p0: np.ndarray, s: float
) -> None:
    """Motion camouflage (method.md): no monocular method sees motion along T̂."""
    assume(np.linalg.norm(t) > 0.05)
    t_hat = normalize(t)
    q1, p1 = q0 + t, p0 + s * t
    assume(min(np.linalg.norm(p0 - q0), np.linalg.norm(p1 - q1)) > 1.0)
    assume(distance_to_line(p0, q0, t_hat) > 0.2)
    b0, a0 = observe(q0, p0)
    b1, a1 = observe(q1, p1)
    assert float(tcm_disparity(t_hat, b0, b1, a0, a1)) < 1e-8


def test_collision_course_fools_ecm_but_not_tcm() -> None:
    """Constant bearing, shrinking range: Ω = 0 but the looming betrays the motion."""
    q0, q1 = np.zeros(3), np.array([1.0, 0.0, 0.0])
    b = normalize(np.array([1.0, 1.0, 0.0]))
    p0, p1 = q0 + 8.0 * b, q1 + 6.0 * b  # same bearing from both positions
    b0, a0 = observe(q0, p0)
    b1, a1 = observe(q1, p1)
    t_hat = np.array([1.0, 0.0, 0.0])
    assert float(ecm_omega_rad(t_hat, b0, b1)) < 1e-9
    assert float(tcm_disparity(t_hat, b0, b1, a0, a1)) > 0.3


def test_ecm_sees_out_of_plane_motion() -> None:
    q0, q1 = np.zeros(3), np.array([1.0, 0.0, 0.0])
    p0 = np.array([2.0, 4.0, 0.0])
    p1 = p0 + np.array([0.0, 0.0, -1.0])
    t_hat = np.array([1.0, 0.0, 0.0])
    assert float(ecm_omega_rad(t_hat, observe(q0, p0)[0], observe(q1, p1)[0])) > 0.2


def test_stationary_range_from_metric_translation() -> None:
    q0, t = np.array([0.0, 0.0, -2.0]), np.array([1.0, 0.5, 0.0])
    p = np.array([3.0, 4.0, -1.0])
    b0, _ = observe(q0, p)
    b1, _ = observe(q0 + t, p)
    d0, d1 = stationary_range_m(t, b0, b1)
    assert float(d0) == pytest.approx(np.linalg.norm(p - q0), rel=1e-9)
    assert float(d1) == pytest.approx(np.linalg.norm(p - q0 - t), rel=1e-9)


def test_head_on_is_unknown_and_threshold_decides() -> None:
    cfg = ClassifierConfig()
    t_hat = np.array([1.0, 0.0, 0.0])
    ahead = normalize(np.array([1.0, 0.05, 0.0]))
    res = classify_pair(t_hat, ahead, ahead, 0.05, 0.06, cfg, 25)
    assert res.state == "unknown" and res.reason == "head-on"
    side0 = normalize(np.array([1.0, 1.0, 0.0]))
    side1 = normalize(np.array([0.8, 1.0, 0.0]))
    geo = triangle_geometry(t_hat, side0, side1, 0.05, 0.05)
    a1_still = math.asin(math.sin(0.05) * float(geo.r_geo))
    assert classify_pair(t_hat, side0, side1, 0.05, a1_still, cfg, 25).state == "stationary"
    moving = classify_pair(t_hat, side0, side1, 0.05, a1_still * 1.2, cfg, 25)
    assert moving.state == "moving" and moving.disparity > cfg.tcm_threshold


def _at_theta(theta_rad: float) -> np.ndarray:
    """A bearing ``theta_rad`` off the translation axis x, in the x–y plane."""
    return np.array([math.cos(theta_rad), math.sin(theta_rad), 0.0])


def test_a_big_object_just_off_the_axis_is_head_on_for_its_size() -> None:
    """HEADON-BOX's last pairs (a 2.4-m container 2.2–2.9 m away, 11–13° off the axis,
    angular radius 0.35 → 0.5 rad) were decided moving: the detection's centre follows
    the box's near face, and there TCM amplifies a bearing error by cot θ. The same
    bearings with a small object's size, or the same size across the track, decide."""
    cfg = ClassifierConfig()
    t_hat = np.array([1.0, 0.0, 0.0])
    b0, b1 = _at_theta(math.radians(11.0)), _at_theta(math.radians(13.0))
    big = classify_pair(t_hat, b0, b1, 0.35, 0.5, cfg, 25)
    assert (big.state, big.reason) == ("unknown", "head-on")
    assert math.isfinite(big.disparity)  # measured, only not decided
    small = classify_pair(t_hat, b0, b1, 0.035, 0.05, cfg, 25)
    assert small.state in ("moving", "stationary")
    side0, side1 = _at_theta(math.radians(80.0)), _at_theta(math.radians(95.0))
    across = classify_pair(t_hat, side0, side1, 0.35, 0.5, cfg, 25)
    assert across.state in ("moving", "stationary")
    off = replace(cfg, head_on_extent_fraction=0.0)
    assert classify_pair(t_hat, b0, b1, 0.35, 0.5, off, 25).state == "moving"


@settings(max_examples=200)
@given(
    th0=st.floats(0.2, 2.9),
    th1=st.floats(0.2, 2.9),
    a0=st.floats(0.001, 0.6),
    a1=st.floats(0.001, 0.6),
)
def test_the_extent_sigma_is_how_far_r_geo_moves_when_the_centres_wander(
    th0: float, th1: float, a0: float, a1: float
) -> None:
    """``extent_disparity_sigma`` against R_geo = sin θ1 / sin θ0 moved numerically by
    each end's wander (k α), the two added in quadrature."""
    k = 1e-4  # small enough for the linearisation
    r_geo = math.sin(th1) / math.sin(th0)
    # central differences: near θ = 90° the first derivative vanishes and a one-sided
    # difference would measure the second
    d0 = (math.sin(th1) / math.sin(th0 + k * a0) - math.sin(th1) / math.sin(th0 - k * a0)) / 2
    d1 = (math.sin(th1 + k * a1) - math.sin(th1 - k * a1)) / math.sin(th0) / 2
    want = math.hypot(d0, d1)
    got = extent_disparity_sigma(r_geo, th0, th1, a0, a1, k)
    assert got == pytest.approx(want, rel=1e-3, abs=1e-10)
