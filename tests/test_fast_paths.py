"""The per-frame fast paths of issue 15 give numpy's generic functions' results to the bit.

Each helper replaces a numpy call whose wrapper cost more than its arithmetic at the
pipeline's sizes; these tests hold each to the call it replaces, on random data with the
edge cases (zeros, NaN, broadcasting, ties) that could tell them apart.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tcm_companion.core import egomotion, frames
from tcm_companion.core.camera import Equirectangular
from tcm_companion.core.timebase import median, median_columns


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return (
        a.shape == b.shape
        and a.dtype == b.dtype
        and a.tobytes() == b.tobytes()  # to the bit, signed zeros and NaN payloads included
    )


def _cross_ref(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


SHAPES = [
    ((5, 3), (5, 3)),
    ((3,), (7, 3)),
    ((4, 1, 3), (1, 6, 3)),
    ((0, 3), (0, 3)),
    ((1, 3), (3,)),
]


@pytest.mark.parametrize(("sa", "sb"), SHAPES)
def test_cross_angle_and_normalize_equal_the_generic_numpy_calls(
    sa: tuple[int, ...], sb: tuple[int, ...]
) -> None:
    rng = np.random.default_rng(1)
    for k in range(50):
        a, b = rng.normal(size=sa), rng.normal(size=sb)
        if k % 5 == 0 and a.size:
            a[..., 1] = 0.0
        if k % 7 == 0 and a.size:
            a[...] = 0.0
        assert _same(frames.cross3(a, b), _cross_ref(a, b))
        ref_angle = np.arctan2(np.linalg.norm(_cross_ref(a, b), axis=-1), np.sum(a * b, axis=-1))
        assert _same(frames.angle_between(a, b), ref_angle)
        n = np.linalg.norm(a, axis=-1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            assert _same(frames.normalize(a), a / np.where(n > 0, n, np.nan))


def test_equirectangular_bearings_equal_the_stacked_formula() -> None:
    cam = Equirectangular(360, 220)
    rng = np.random.default_rng(2)
    for shape in [(400, 2), (2,), (3, 5, 2)]:
        p = rng.uniform(0, 360, size=shape)
        got = cam.bearing_cam_from_pixel(p)
        az = math.radians(cam.azimuth_min_deg) + (p[..., 0] / cam.width) * math.radians(
            cam.azimuth_max_deg - cam.azimuth_min_deg
        )
        el_max, el_min = math.radians(cam.elevation_max_deg), math.radians(cam.elevation_min_deg)
        el = el_max - (p[..., 1] / cam.height) * (el_max - el_min)
        ce = np.cos(el)
        assert _same(got, np.stack([ce * np.cos(az), ce * np.sin(az), -np.sin(el)], axis=-1))


def test_median_columns_equals_median_of_each_column() -> None:
    rng = np.random.default_rng(3)
    for n in range(12):
        for k in range(40):
            b = rng.normal(size=(n, 3))
            if k % 4 == 0:
                b = np.round(b)  # ties and signed zeros
            if k % 5 == 0 and n:
                b[rng.integers(n), rng.integers(3)] = np.nan
            got = median_columns(b)
            want = [median(b[:, j]) for j in range(3)]
            assert [x.hex() for x in got] == [x.hex() for x in want]


def test_solve_is_numpys_solve_and_raises_the_same_error() -> None:
    rng = np.random.default_rng(4)
    for n in (2, 3, 5):
        for _ in range(50):
            A = rng.normal(size=(n, n))
            b = rng.normal(size=n)
            assert _same(egomotion._solve(A, b), np.linalg.solve(A, b))
    with pytest.raises(np.linalg.LinAlgError):
        egomotion._solve(np.zeros((5, 5)), np.ones(5))


def test_median_of_copy_equals_median() -> None:
    rng = np.random.default_rng(5)
    for n in range(0, 40):
        x = rng.normal(size=n)
        if n > 3:
            x[1] = np.nan
        want = egomotion._median(x)
        got = egomotion._median_of_copy(x.copy())
        assert (math.isnan(want) and math.isnan(got)) or want.hex() == got.hex()


def test_classification_replaced_equals_dataclasses_replace() -> None:
    import dataclasses

    from tcm_companion.core.classify import Classification, _replaced

    c = Classification("unknown", "", disparity=0.25, omega_rad=0.1, interval_frames=25)
    for changes in (
        {"state": "moving"},
        {"reason": "head-on"},
        {"state": "stationary", "reason": ""},
    ):
        got, want = _replaced(c, **changes), dataclasses.replace(c, **changes)
        assert got == want and repr(got) == repr(want)
        assert list(vars(got)) == list(vars(want))
        with pytest.raises(dataclasses.FrozenInstanceError):
            got.state = "unknown"  # type: ignore[misc]


def test_vector_norm_and_rotate_by_vector_equal_numpy() -> None:
    rng = np.random.default_rng(6)
    for _ in range(200):
        v = rng.normal(size=4)
        assert frames.vector_norm(v).hex() == float(np.linalg.norm(v)).hex()
        w = rng.normal(size=3) * 10 ** rng.uniform(-8, 0)
        b = rng.normal(size=(5, 3))
        theta = float(np.linalg.norm(w))
        k = w / theta
        for x in (b, b[0]):  # (N, 3) and one (3,) vector
            want = (
                x * np.cos(theta)
                + frames.cross3(k, x) * np.sin(theta)
                + np.outer(x @ k, k).reshape(x.shape) * (1 - np.cos(theta))
            )
            assert _same(frames.rotate_by_vector(x, w), want)
    assert frames.vector_norm([3.0, 4.0]) == 5.0  # not an array: numpy's own call


# -- the daemon around the pipeline (docs/decisions.md §8.3) -------------------


def _annotation_circles_ref(result, camera):  # type: ignore[no-untyped-def]
    """docs.annotation_circles as it was, with np.clip (the reference)."""
    size = camera.pixel_size_map_rad
    out = []
    for o in result.objects:
        u, v = o.centroid_px
        if not (math.isfinite(u) and math.isfinite(v)):
            continue
        iu = int(np.clip(u, 0, camera.width - 1))
        iv = int(np.clip(v, 0, camera.height - 1))
        px = float(size[iv, iu])
        r_px = o.angular_radius_rad / px if px > 0 and math.isfinite(px) else 5.0
        label = f"{o.state} {o.track_id}"
        if math.isfinite(o.ttc_s):
            label += f" ttc {o.ttc_s:.1f}s"
        out.append((float(u), float(v), float(r_px), label))
    return out


def test_annotation_circles_clip_on_floats_as_np_clip_did() -> None:
    from tcm_companion.core.classify import Classification
    from tcm_companion.core.pipeline import FrameResult, ObjectResult
    from tcm_companion.flightlog.docs import annotation_circles

    cam = Equirectangular(360, 220)
    rng = np.random.default_rng(7)
    b = np.array([1.0, 0.0, 0.0])
    c = Classification("moving", "", disparity=0.4)
    edges = [-1e9, -1.0, -0.5, -0.0, 0.0, 0.4, 0.5, 0.999, 1.0, 218.5, 219.0, 219.5, 220.0]
    edges += [358.9999, 359.0, 359.5, 360.0, 361.0, 1e9, math.nan, math.inf, -math.inf]
    coords = [*edges, *rng.uniform(-50.0, 450.0, 300)]
    objs = []
    for i, u in enumerate(coords):
        v = coords[(7 * i + 3) % len(coords)]
        for uu, vv in ((u, v), (np.float64(u), np.float64(v)), (float(v), float(u))):
            ttc = math.nan if i % 3 == 0 else float(rng.uniform(0.1, 9.0))
            objs.append(
                ObjectResult(
                    i, True, "moving", "", b, b, b, 0.1, 0.0, 0.02, (uu, vv), c, ttc, False, 1.0
                )
            )
    result = FrameResult(0, 0, tuple(objs), True, None, {})
    assert annotation_circles(result, cam) == _annotation_circles_ref(result, cam)


def test_input_rate_count_by_bisection_equals_the_count_of_newer_arrivals() -> None:
    from tcm_companion.service.inputs import InputMonitor, InputSpec

    rng = np.random.default_rng(3)
    for k in range(40):
        spec = InputSpec("attitude", float(rng.choice([10.0, 50.0])), 200_000, window_us=2_000_000)
        mon = InputMonitor(spec, 0)
        t = 0
        for _ in range(int(rng.integers(0, 400))):
            t += int(rng.choice([0, 1, 20_000, 20_000, 20_001, 300_000]))  # ties included
            if k % 4 == 0 and rng.random() < 0.01:
                t -= 50_000  # a clock going back starts the window over
            mon.update(t, bool(rng.random() > 0.05))
            now = t + int(rng.integers(0, 3_000_000))
            if rng.random() < 0.3 and mon._arrivals:  # the window's edge on an arrival
                now = int(rng.choice(list(mon._arrivals))) + spec.window_us
            st = mon.status(now)
            arrivals = list(mon._arrivals)
            lo = now - spec.window_us
            n = sum(1 for a in arrivals if a > lo)  # the count as it was written
            since = min(mon._since_us, now)
            span_us = min(spec.window_us, max(now - since, 1))
            assert st.rate_hz == n / (span_us / 1e6)


def test_any_nonzero_of_a_frame_equals_numpys_any() -> None:
    from tcm_companion.io.cameras.reader import _any_nonzero

    rng = np.random.default_rng(5)
    h, w = 22, 36
    frames = [np.zeros((h, w, 3), np.uint8), rng.integers(0, 256, (h, w, 3), dtype=np.uint8)]
    for idx in [(0, 0, 0), (h - 1, w - 1, 2), (h // 2, 0, 1), (0, w - 1, 2), (h - 1, 0, 0)]:
        z = np.zeros((h, w, 3), np.uint8)
        z[idx] = int(rng.integers(1, 256))
        frames.append(z)
    big = np.zeros((2 * h, 2 * w, 3), np.uint8)
    big[1, 1, 1] = 7  # only in the rows/columns a strided view skips
    frames += [big[::2, ::2], big[1::2, 1::2], np.asfortranarray(frames[3]), frames[1][:, ::-1]]
    for f in frames:
        assert f.shape[2] == 3 and f.dtype == np.uint8
        assert _any_nonzero(f) is bool(f.any())
