"""The simulator's camera rigs (``sim.scene.cameras.rig_cameras``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tcm_companion.sim.scene.cameras import RIGS, rig_cameras


def _sees(cam, bearing_body: np.ndarray) -> bool:
    b_cam = cam.R_body_from_cam.T @ bearing_body
    if b_cam[0] <= 0:  # behind the lens
        return False
    return bool(cam.in_image(cam.pixel_from_bearing_cam(b_cam)))


@pytest.mark.parametrize("rig", RIGS)
def test_every_rig_has_unique_names_and_at_least_one_camera(rig):
    cams = rig_cameras(rig)
    names = [n for n, _ in cams]
    assert names and len(set(names)) == len(names)


def test_quad_sees_the_whole_horizon_and_neighbours_overlap():
    cams = [c for _, c in rig_cameras("quad")]
    for az in range(0, 360, 2):
        b = np.array([math.cos(math.radians(az)), math.sin(math.radians(az)), 0.0])
        seen = [i for i, c in enumerate(cams) if _sees(c, b)]
        assert seen, f"azimuth {az} unseen"
    b45 = np.array([math.cos(math.radians(45)), math.sin(math.radians(45)), 0.0])
    assert [i for i, c in enumerate(cams) if _sees(c, b45)] == [0, 1]


def test_front_back_leaves_the_sides_unseen():
    cams = [c for _, c in rig_cameras("front-back")]
    side = np.array([0.0, 1.0, 0.0])
    assert not any(_sees(c, side) for c in cams)


def test_an_unknown_rig_names_the_known_ones():
    with pytest.raises(ValueError, match="quad"):
        rig_cameras("hexa")
