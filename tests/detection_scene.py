"""Synthetic red-ball frames for the detection tests: an analytic ray caster (a shaded
sphere, supersampled so its rim is anti-aliased) through every camera model, so the true
bearing and angular radius are exact; the backgrounds it draws on; and the errors of a
detection against the true ball. Shared by test_detection, test_detection_backends and
test_colour_lab.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from tcm_companion.core.camera import CameraModel, Equirectangular, Fisheye, Pinhole
from tcm_companion.core.detection import Detection
from tcm_companion.core.frames import angle_between, bearing_from_azel, normalize

CAMERAS: dict[str, CameraModel] = {
    "equirectangular": Equirectangular(360, 220),
    "pinhole": Pinhole(
        640, 480, (0.0, -10.0, 50.0), fx=320, fy=320, cx=320, cy=240, dist=(-0.05, 0.01, 0, 0, 0)
    ),
    "pinhole-strong": Pinhole(
        800, 600, fx=500, fy=480, cx=410, cy=290, dist=(-0.2, 0.05, 0.001, -0.002, 0.01)
    ),
    "fisheye": Fisheye(
        640, 640, (0.0, -10.0, -45.0), fx=200, fy=200, cx=320, cy=320, dist=(0.02, -0.005, 0.001, 0)
    ),
}

BALL_BGR = (35.0, 30.0, 205.0)
SKY_BGR = np.array([225.0, 190.0, 150.0])
GRASS_BGR = np.array([60.0, 130.0, 95.0])

Background = Callable[[np.ndarray], np.ndarray]


def field_background(bearing_cam: np.ndarray) -> np.ndarray:
    """Sky above the camera's horizon, grass below, both with slow shading (BGR float)."""
    b = np.nan_to_num(bearing_cam)
    up = -b[..., 2]
    az = np.arctan2(b[..., 1], b[..., 0])
    sky = SKY_BGR - 35.0 * up[..., None]
    grass = GRASS_BGR * (1.0 + 0.12 * np.sin(3.0 * az) * np.cos(4.0 * up))[..., None]
    img = np.where((up > 0.0)[..., None], sky, grass)
    return np.where(np.isfinite(bearing_cam[..., :1]), img, 0.0)


@dataclass(frozen=True)
class Ball:
    centre_cam: np.ndarray  # unit bearing, camera FRD
    alpha_rad: float
    albedo_bgr: tuple[float, float, float] = BALL_BGR


def ball_at(az_deg: float, el_deg: float, alpha_deg: float) -> Ball:
    centre = bearing_from_azel(math.radians(az_deg), math.radians(el_deg))
    return Ball(centre, math.radians(alpha_deg))


def _crop_for(cam: CameraModel, ball: Ball) -> tuple[int, int, int, int]:
    """Pixel box (x0, y0, x1, y1) holding the ball's image; x may pass a panorama's seam."""
    c = ball.centre_cam
    e1 = normalize(np.cross(c, [0.0, 0.0, 1.0] if abs(c[2]) < 0.9 else [0.0, 1.0, 0.0]))
    e2 = np.cross(c, e1)
    phi = np.linspace(0.0, 2.0 * math.pi, 360)[:, None]
    a = 1.3 * ball.alpha_rad
    ring = math.cos(a) * c + math.sin(a) * (np.cos(phi) * e1 + np.sin(phi) * e2)
    px = cam.pixel_from_bearing_cam(np.vstack([ring, c]))
    px = px[np.all(np.isfinite(px), axis=1)]
    xs = px[:, 0]
    if isinstance(cam, Equirectangular) and np.ptp(xs) > cam.width / 2:
        xs = np.where(xs < cam.width / 2, xs + cam.width, xs)
    x0, x1 = math.floor(xs.min()) - 2, math.ceil(xs.max()) + 2
    y0 = max(math.floor(px[:, 1].min()) - 2, 0)
    y1 = min(math.ceil(px[:, 1].max()) + 2, cam.height)
    if not isinstance(cam, Equirectangular):
        x0, x1 = max(x0, 0), min(x1, cam.width)
    return x0, y0, x1, y1


def render(
    cam: CameraModel,
    balls: Sequence[Ball],
    *,
    light_cam: Sequence[float] = (0.2, 0.8, -0.55),
    ambient: float = 0.25,
    specular: float = 0.0,
    supersample: int = 8,
    noise: float = 2.0,
    blur_px: float = 0.0,
    seed: int = 0,
    background: Background = field_background,
    mix_exponent: float = 1.0,
) -> np.ndarray:
    """BGR uint8 frame of shaded spheres, anti-aliased by supersampling, in camera FRD.

    Each sphere is Lambertian (``ambient`` + diffuse towards ``light_cam``, the
    direction to the light) with an optional Phong highlight; samples are averaged on
    the 8-bit scale like a simple renderer's anti-aliasing (``mix_exponent`` 1), or in
    linear light for a display gamma of ``mix_exponent`` (2: as the simulator and a
    camera's optics mix an edge).
    """
    img = background(cam.bearing_map_cam)
    light = normalize(np.asarray(light_cam, dtype=np.float64))
    sub = (np.arange(supersample) + 0.5) / supersample
    for ball in balls:
        x0, y0, x1, y1 = _crop_for(cam, ball)
        u = (np.arange(x0, x1)[:, None] + sub[None, :]).reshape(-1)
        v = (np.arange(y0, y1)[:, None] + sub[None, :]).reshape(-1)
        uu, vv = np.meshgrid(u, v)
        if isinstance(cam, Equirectangular):
            uu = uu % cam.width
        d = cam.bearing_cam_from_pixel(np.stack([uu, vv], axis=-1))
        ok = np.isfinite(d[..., 0])
        d = np.nan_to_num(d)
        c = ball.centre_cam
        dist = 1.0 / math.sin(ball.alpha_rad)  # unit sphere radius
        cos_g = d @ c
        disc = 1.0 - dist * dist * (1.0 - cos_g**2)
        hit = ok & (disc > 0.0) & (cos_g > 0.0)
        t = dist * cos_g - np.sqrt(np.maximum(disc, 0.0))
        normal = t[..., None] * d - dist * c
        shade = ambient + (1.0 - ambient) * np.clip(normal @ light, 0.0, None)
        colour = np.asarray(ball.albedo_bgr) * shade[..., None]
        if specular > 0.0:
            half = normalize(light - d)
            colour = (
                colour
                + 255.0 * specular * (np.clip(np.sum(normal * half, -1), 0, 1) ** 40)[..., None]
            )
        samples = np.where(hit[..., None], np.clip(colour, 0.0, 255.0), background(d))
        samples = np.where(ok[..., None], samples, 0.0)
        lin = (samples / 255.0) ** mix_exponent
        block = lin.reshape(y1 - y0, supersample, x1 - x0, supersample, 3).mean(axis=(1, 3))
        block = 255.0 * block ** (1.0 / mix_exponent)
        cols = np.arange(x0, x1) % cam.width
        img[y0:y1, cols] = block
    if blur_px > 0.0:
        img = cv2.GaussianBlur(img, (0, 0), blur_px)
    if noise > 0.0:
        img = img + np.random.default_rng(seed).normal(0.0, noise, img.shape)
    img = np.where(np.isfinite(cam.bearing_map_cam[..., :1]), img, 0.0)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def pixel_errors(cam: CameraModel, det: Detection, ball: Ball) -> tuple[float, float]:
    """(relative radius error, bearing error in pixels at the ball's centre)."""
    px = cam.pixel_from_bearing_cam(ball.centre_cam)
    pixel_rad = float(cam.pixel_size_map_rad[int(px[1]), int(px[0]) % cam.width])
    bearing_err = float(angle_between(det.bearing_cam, ball.centre_cam)) / pixel_rad
    return det.angular_radius_rad / ball.alpha_rad - 1.0, bearing_err


def sky_background(bearing_cam: np.ndarray) -> np.ndarray:
    """Bright sky everywhere, brighter towards the zenith (BGR float)."""
    up = -np.nan_to_num(bearing_cam)[..., 2]
    img = SKY_BGR - 35.0 * up[..., None]
    return np.where(np.isfinite(bearing_cam[..., :1]), img, 0.0)
