"""Simulator: export round trip, geometry of the rendered ball, telemetry, determinism.

(Objects of other shapes, the new scenarios, truth and the detector simulator:
``test_sim_objects.py``.)"""

from __future__ import annotations

import hashlib
import math
import os
import platform
import subprocess
import sys
from collections import Counter

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from tcm_companion.core.camera import CameraModel, Equirectangular, Fisheye, Pinhole
from tcm_companion.core.frames import slerp_rotation
from tcm_companion.core.telemetry import AttitudeSample, PositionSample
from tcm_companion.io.scenario import load_scenario
from tcm_companion.io.tlog import iter_tlog
from tcm_companion.sim import SCENARIO_NAMES, export_scenario, flight_plan, make_scenario
from tcm_companion.sim.scene.render import Renderer
from tcm_companion.sim.scene.scenarios import PAPER_SCENARIO_NAMES, euler_zyx_rad, plan_world

from .numerics import numeric_kind

CAMERAS: dict[str, CameraModel] = {
    "equirectangular": Equirectangular(360, 220),
    "pinhole": Pinhole(
        320,
        240,
        (0.0, -10.0, 90.0),
        fx=200.0,
        fy=200.0,
        cx=160.0,
        cy=120.0,
        dist=(-0.05, 0.01, 0.0, 0.0, 0.0),
    ),
    "fisheye": Fisheye(
        320,
        320,
        (0.0, -10.0, 60.0),
        fx=100.0,
        fy=100.0,
        cx=160.0,
        cy=160.0,
        dist=(0.02, -0.005, 0.001, 0.0),
    ),
}


def red_mask(bgr: np.ndarray) -> np.ndarray:
    """Saturated red pixels (the ball, shaded side included; not the brown dirt)."""
    b, g, r = (bgr[..., i].astype(np.int32) for i in range(3))
    return (r > 40) & (r * 10 > 16 * g) & (r * 10 > 16 * b)


def attitude_at(sim, t_us: int) -> np.ndarray:
    """Telemetry attitude at a frame time: boot clock → companion clock by the lower
    envelope of (receive - boot), then slerp between the bracketing samples."""
    att = [s for s in sim.telemetry if isinstance(s, AttitudeSample)]
    offset = min(s.recv_us - s.time_boot_us for s in att)
    boot = np.array([s.time_boot_us for s in att])
    tb = t_us - offset
    j = int(np.searchsorted(boot, tb))
    a, b = att[j - 1], att[j]
    s = (tb - a.time_boot_us) / (b.time_boot_us - a.time_boot_us)
    return slerp_rotation(a.R_ned_from_body, b.R_ned_from_body, s)


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def test_export_round_trip(tmp_path):
    sim = make_scenario("TWO", camera=Equirectangular(120, 74), duration_s=0.2, seed=3)
    out = export_scenario(sim, tmp_path / "two", progress=False)
    sc = load_scenario(out)
    assert sc.warnings == []
    assert sc.name == sim.name == "TWO"
    assert sc.description == sim.description
    assert sc.camera.to_dict() == sim.camera.to_dict()
    np.testing.assert_array_equal(sc.frame_times_us, sim.frame_times_us)
    assert sc.n_frames == sim.n_frames == 5
    assert len(sc.telemetry) == len(sim.telemetry) > 0
    for a, b in zip(sc.telemetry, sim.telemetry):
        assert type(a) is type(b)
        assert (a.time_boot_us, a.recv_us) == (b.time_boot_us, b.recv_us)
        if isinstance(a, AttitudeSample):
            np.testing.assert_array_equal(a.R_ned_from_body, b.R_ned_from_body)
    assert sc.tlog_stats.decoded == sim.tlog_stats.decoded
    assert sc.truth is not None
    np.testing.assert_array_equal(sc.truth.frame, sim.truth.frame)
    np.testing.assert_array_equal(sc.truth.object_id, sim.truth.object_id)
    np.testing.assert_array_equal(sc.truth.moving, sim.truth.moving)
    np.testing.assert_allclose(sc.truth.obj_ned_m, sim.truth.obj_ned_m, atol=1e-6)
    np.testing.assert_allclose(sc.truth.veh_ned_m, sim.truth.veh_ned_m, atol=1e-6)
    assert sorted(set(sc.truth.object_id.tolist())) == [1, 2]
    for (i, t, img), (j, u, ref) in zip(sc.iter_frames(), sim.iter_frames()):
        assert (i, t) == (j, u)
        np.testing.assert_array_equal(img, ref)
    header = (out / "truth.csv").read_text().splitlines()[0]
    assert header == "frame,object_id,moving,obj_n,obj_e,obj_d,obj_radius_m,veh_n,veh_e,veh_d"
    assert (out / "frames.csv").read_text().splitlines()[0] == "frame,t_us"
    assert sorted(p.name for p in (out / "frames").iterdir()) == [f"{i:06d}.png" for i in range(5)]


@pytest.mark.parametrize("cam_name", list(CAMERAS))
def test_truth_ball_projects_onto_red_pixels(cam_name):
    cam = CAMERAS[cam_name]
    sim = make_scenario("T45", camera=cam, duration_s=1.0, seed=1)
    bearings = cam.bearing_map_cam
    for i in (0, 12, 24):
        img = sim.read_frame(i)
        red = red_mask(img)
        assert red.sum() > 30, f"frame {i}: ball not visible"
        row = sim.truth.rows_for_frame(i)[0]
        b_ned = sim.truth.obj_ned_m[row] - sim.truth.veh_ned_m[row]
        b_ned /= np.linalg.norm(b_ned)
        R = attitude_at(sim, int(sim.frame_times_us[i])) @ cam.R_body_from_cam
        b_cam = R.T @ b_ned
        uv = cam.pixel_from_bearing_cam(b_cam)
        assert cam.in_image(uv)
        # Within the telemetry's bias + noise (~1.5°) of the red blob, and its centroid.
        nearest = angle_deg(bearings[red], b_cam).min()
        assert nearest < 1.5, f"frame {i}: {nearest:.2f}° from the nearest red pixel"
        centroid = bearings[red].mean(axis=0)
        assert angle_deg(centroid / np.linalg.norm(centroid), b_cam) < 1.5


@pytest.mark.parametrize(
    "cam",
    [Equirectangular(720, 440), CAMERAS["pinhole"], CAMERAS["fisheye"]],
    ids=["equirectangular", "pinhole", "fisheye"],
)
def test_ball_area_matches_angular_radius(cam):
    sim = make_scenario("TS", camera=cam, duration_s=0.2, noise=0.0)
    pos, R = sim.vehicle_pose(2)
    centre, radius = sim.truth.obj_ned_m[2], float(sim.truth.obj_radius_m[2])
    rho = math.asin(radius / np.linalg.norm(centre - pos))
    disc_sr = 2.0 * math.pi * (1.0 - math.cos(rho))
    omega = cam.solid_angle_map_sr
    coverage = sim.renderer.sphere_coverage(centre, radius, pos, R)
    assert np.sum(coverage * omega) == pytest.approx(disc_sr, rel=0.01)
    red = red_mask(sim.read_frame(2))
    assert np.sum(omega[red]) == pytest.approx(disc_sr, rel=0.04)


def test_fisheye_black_outside_field_of_view():
    cam = Fisheye(200, 200, fx=45.0, fy=45.0, cx=100.0, cy=100.0)  # lens wider than 180°
    sim = make_scenario("TS", camera=cam, duration_s=0.04)
    img = sim.read_frame(0)
    theta = np.degrees(np.arccos(np.clip(cam.bearing_map_cam[..., 0], -1, 1)))
    outside = ~np.isfinite(theta) | (theta > 90.0)
    assert outside.any() and (~outside).any()
    assert np.all(img[outside] == 0)
    assert img[~outside].mean() > 40


def test_telemetry_rates_and_clocks():
    duration = 4.0
    sim = make_scenario("T90", duration_s=duration, seed=2)
    records = list(iter_tlog(sim.tlog_bytes))
    span = duration + 2 * sim.telemetry_config.margin_s
    counts = Counter(r.msg.get_type() for r in records)
    for kind, hz in [
        ("HEARTBEAT", 1),
        ("ATTITUDE", 50),
        ("LOCAL_POSITION_NED", 10),
        ("GPS_RAW_INT", 5),
    ]:
        assert abs(counts[kind] - hz * span) <= 2, (kind, counts[kind])
    recv = np.array([r.recv_us for r in records])
    assert np.all(np.diff(recv) > 0), "records are in receive order"
    for r in records:
        assert (r.msg.get_srcSystem(), r.msg.get_srcComponent()) == (1, 1)
    hb = next(r.msg for r in records if r.msg.get_type() == "HEARTBEAT")
    assert hb.type == mavlink2.MAV_TYPE_QUADROTOR
    assert hb.autopilot == mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA

    true_offset = sim.clocks.epoch_us_at_t0 - sim.clocks.boot_us_at_t0
    for kind, period_ms in [("ATTITUDE", 20), ("LOCAL_POSITION_NED", 100)]:
        msgs = [r for r in records if r.msg.get_type() == kind]
        boot_ms = np.array([r.msg.time_boot_ms for r in msgs])
        assert boot_ms[0] > 120_000, "the autopilot booted minutes before"
        assert np.all(np.abs(np.diff(boot_ms) - period_ms) <= 2)
        latency = np.array([r.recv_us for r in msgs]) - boot_ms * 1000 - true_offset
        assert latency.min() >= 3000 and latency.max() <= 13_500
        assert np.median(latency) < 6000

    t = sim.frame_times_us
    assert np.all(np.abs(np.diff(t) - 40_000) <= 200)
    assert np.all(np.abs(t - (t[0] + np.round(np.arange(len(t)) * 40_000))) <= 200)
    # Frames and telemetry share the companion clock: the first frame falls inside the log.
    assert recv[0] < t[0] < t[-1] < recv[-1]

    att = [s for s in sim.telemetry if isinstance(s, AttitudeSample)]
    t_s = np.array([(s.time_boot_us - sim.clocks.boot_us_at_t0) / 1e6 for s in att])
    measured = np.array([euler_zyx_rad(s.R_ned_from_body) for s in att])
    err = np.degrees(measured - euler_zyx_rad(sim.plan.vehicle.R_ned_from_body(t_s)))
    assert np.all(np.abs(err.mean(axis=0)) < 0.9)
    assert np.all((err.std(axis=0) > 0.2) & (err.std(axis=0) < 0.4))
    pos = [s for s in sim.telemetry if isinstance(s, PositionSample)]
    tp = np.array([(s.time_boot_us - sim.clocks.boot_us_at_t0) / 1e6 for s in pos])
    perr = np.array([s.pos_ned_m for s in pos]) - sim.plan.vehicle.position_ned_m(tp)
    verr = np.array([s.vel_ned_mps for s in pos]) - sim.plan.vehicle.velocity_ned_mps(tp)
    assert 0.01 < perr.std() < 0.03 and 0.02 < verr.std() < 0.045


def test_determinism_with_seed():
    cam = Equirectangular(120, 74)
    a = make_scenario("T90", camera=cam, duration_s=0.4, seed=5)
    b = make_scenario("T90", camera=cam, duration_s=0.4, seed=5)
    c = make_scenario("T90", camera=cam, duration_s=0.4, seed=6)
    assert a.tlog_bytes == b.tlog_bytes != c.tlog_bytes
    np.testing.assert_array_equal(a.frame_times_us, b.frame_times_us)
    later = a.read_frame(7)
    np.testing.assert_array_equal(a.read_frame(2), b.read_frame(2))
    np.testing.assert_array_equal(later, b.read_frame(7))
    assert not np.array_equal(a.read_frame(2), c.read_frame(2))


def test_scenario_catalogue():
    paper = ("TS", "T45", "T90", "RAISED", "INPLANE", "COLLISION", "HEADON", "TWO")
    assert PAPER_SCENARIO_NAMES == paper
    assert SCENARIO_NAMES[: len(paper)] == paper
    assert len(set(SCENARIO_NAMES)) == len(SCENARIO_NAMES)
    for name in PAPER_SCENARIO_NAMES:
        plan = flight_plan(name)
        short = name in ("COLLISION", "HEADON")
        assert (6.0 <= plan.duration_s <= 8.0) if short else plan.duration_s == 40.0
        assert plan.fps == 25.0
        t = np.linspace(0.0, plan.duration_s, 201)
        veh = plan.vehicle.position_ned_m(t)
        assert np.all(np.abs(veh[:, 2] + 2.0) < 0.1), "flies at 2 m"
        for ball in plan.balls:
            centre = ball.trajectory.position_ned_m(t)
            rng_m = np.linalg.norm(centre - veh, axis=1)
            assert rng_m.min() > 1.4
            assert ball.radius_m == 0.375
    ts = flight_plan("TS")
    assert [b.moving for b in ts.balls] == [False]
    assert [b.moving for b in flight_plan("T90").balls] == [True]
    assert sorted(b.moving for b in flight_plan("TWO").balls) == [False, True]
    raised = flight_plan("RAISED").balls[0].trajectory.position_ned_m(0.0)
    assert raised[2] <= -3.5
    inplane = flight_plan("INPLANE")
    t = np.linspace(0, 40, 401)
    assert np.allclose(inplane.balls[0].trajectory.position_ned_m(t)[:, 2], -2.0)

    col = flight_plan("COLLISION")
    t = np.linspace(0.0, col.duration_s, 50)
    rel = col.balls[0].trajectory.position_ned_m(t) - col.vehicle.position_ned_m(t)
    rng_m = np.linalg.norm(rel, axis=1)
    assert rng_m[0] > 12.0 and 1.4 < rng_m[-1] < 2.0 and np.all(np.diff(rng_m) < 0)
    assert angle_deg(rel[0], rel).max() < 2.0, "constant bearing"
    head = flight_plan("HEADON")
    rel = head.balls[0].trajectory.position_ned_m(0.0) - head.vehicle.position_ned_m(
        np.array([0.0, head.duration_s])
    )
    assert 14.0 < np.linalg.norm(rel[0]) < 16.0 and 1.5 < np.linalg.norm(rel[1]) < 2.5
    with pytest.raises(ValueError):
        flight_plan("nope")

    sim = make_scenario("TWO", duration_s=0.4)
    assert len(sim.truth.frame) == 2 * sim.n_frames


#: sha256 (first 16 hex digits) of the paper's scenarios rendered at 360×220 at t = 1.3 s
#: and 4.7 s (seed 0, noise from ``default_rng(int(t * 1000))``), recorded before the
#: simulator learnt objects of other shapes: their frames must stay byte-identical.
#: Only a deliberate change of the paper's scene may update them (and says so).
#: By the OpenBLAS kernel numpy runs (``tests/numerics.py``): the renderer's matrix
#: products round differently in the last bit on an AVX-512 machine (SkylakeX) than on
#: an AVX2 one (Haswell), which moves a pixel's rounding now and then (COLLISION and
#: HEADON happen not to differ). ``OPENBLAS_CORETYPE=Haswell`` reproduces the first on
#: the second.
PAPER_FRAME_SHA256 = {
    "Haswell X86_V4": {
        "TS": ("2d2c4a364fb0ad8c", "67bacbdea74bd4b4"),
        "T45": ("9dced490cef0dc3d", "b271e02ea56be858"),
        "T90": ("386c55a9b64334b2", "f1c83803a888de78"),
        "RAISED": ("106cb81c0de0784f", "13a5e0535765db04"),
        "INPLANE": ("7fe46a2824057f73", "88f1eb825110d347"),
        "COLLISION": ("1d65136674d702cf", "ffc0ef9d1456516d"),
        "HEADON": ("2b61b1ac01fcc7c1", "548c345c454e8a7b"),
        "TWO": ("b160e9d80099b9f9", "080c687a113a7344"),
    },
    "SkylakeX X86_V4": {
        "TS": ("2f7d24c4826a0bb8", "17ab2340b0bc7bd9"),
        "T45": ("a02b05b251cf54b0", "e393fb8c4a90c4c1"),
        "T90": ("fc8a1036285c86c1", "2cc51f67ef88cc7e"),
        "RAISED": ("edbb55ede0690112", "a0bd5a2ce44bbabb"),
        "INPLANE": ("5488c2236f70fa65", "a3b0dafb5ebde35b"),
        "COLLISION": ("1d65136674d702cf", "ffc0ef9d1456516d"),
        "HEADON": ("2b61b1ac01fcc7c1", "548c345c454e8a7b"),
        "TWO": ("7f16a8f2d1998711", "cfc3814b0d2889a7"),
    },
    # an AVX2-only AMD EPYC (2026-12-03): only COLLISION's frames differ from the Xeon's
    "Haswell X86_V3": {
        "TS": ("2d2c4a364fb0ad8c", "67bacbdea74bd4b4"),
        "T45": ("9dced490cef0dc3d", "b271e02ea56be858"),
        "T90": ("386c55a9b64334b2", "f1c83803a888de78"),
        "RAISED": ("106cb81c0de0784f", "13a5e0535765db04"),
        "INPLANE": ("7fe46a2824057f73", "88f1eb825110d347"),
        "COLLISION": ("e6a66a5ac1d33c5c", "50976eb151bfccbd"),
        "HEADON": ("2b61b1ac01fcc7c1", "548c345c454e8a7b"),
        "TWO": ("b160e9d80099b9f9", "080c687a113a7344"),
    },
}


@pytest.mark.slow  # over half a second of CPU
def test_paper_scenarios_render_byte_identical():
    kernel = numeric_kind()
    if kernel not in PAPER_FRAME_SHA256:
        pytest.skip(
            f"frames recorded on machine kinds {sorted(PAPER_FRAME_SHA256)} (OpenBLAS kernel,"
            f" numpy SIMD), this one is {kernel}"
        )
    cam = Equirectangular(360, 220)
    for name, expected in PAPER_FRAME_SHA256[kernel].items():
        plan = flight_plan(name, seed=0)
        renderer = Renderer(plan_world(plan), cam, seed=0)
        got = []
        for t in (1.3, 4.7):
            pos, R = plan.vehicle.position_ned_m(t), plan.vehicle.R_ned_from_body(t)
            img = renderer.render(t, pos, R, rng=np.random.default_rng(int(t * 1000)))
            got.append(hashlib.sha256(img.tobytes()).hexdigest()[:16])
        assert tuple(got) == expected, f"{name} ({kernel})"


@pytest.mark.slow  # a subprocess
def test_the_rendered_frames_differ_between_blas_kernels_only_in_rounding() -> None:
    """What the per-kernel hashes above stand for: the same scene, a few pixels one code
    value apart (the image rendered again under the other kernel, in a subprocess)."""
    if platform.machine() != "x86_64":
        pytest.skip("OPENBLAS_CORETYPE names x86 kernels")
    code = (
        "import sys, numpy as np\n"
        "from tcm_companion.core.camera import Equirectangular\n"
        "from tcm_companion.sim.scene.render import Renderer\n"
        "from tcm_companion.sim.scene.scenarios import flight_plan, plan_world\n"
        "plan = flight_plan('T90', seed=0)\n"
        "r = Renderer(plan_world(plan), Equirectangular(360, 220), seed=0)\n"
        "t = 1.3\n"
        "img = r.render(t, plan.vehicle.position_ned_m(t), plan.vehicle.R_ned_from_body(t),\n"
        "               rng=np.random.default_rng(1300))\n"
        "sys.stdout.buffer.write(img.tobytes())\n"
    )
    images = {}
    for kernel in ("Haswell", "Sandybridge"):
        env = {**os.environ, "OPENBLAS_CORETYPE": kernel}
        proc = subprocess.run(
            [sys.executable, "-c", code], env=env, capture_output=True, timeout=120, check=True
        )
        images[kernel] = np.frombuffer(proc.stdout, np.uint8).astype(np.int16)
    diff = np.abs(images["Haswell"] - images["Sandybridge"])
    assert diff.size == 360 * 220 * 3
    assert diff.max() <= 1
    assert np.count_nonzero(diff) < 0.001 * diff.size


def test_a_flight_too_short_for_the_duration_raises_or_keeps_its_own() -> None:
    """A collision course ends at contact: asked for 60 s it says how long it can last,
    and with ``shorter_ok`` (the studies that run one duration over every flight) it keeps
    its own duration, the same flight as asked for by default."""
    with pytest.raises(ValueError, match="COLLISION lasts at most"):
        make_scenario("COLLISION", duration_s=60.0)
    short = make_scenario("COLLISION", duration_s=60.0, shorter_ok=True)
    own = make_scenario("COLLISION")
    assert short.n_frames == own.n_frames < 60 * 25
    assert make_scenario("T90", duration_s=2.0, shorter_ok=True).n_frames == 50
