"""Background Subtraction Method (BSM), the paper's motion-contrast baseline.

The current frame is derotated into the earlier frame's orientation and every ground
pixel is de-translated (flat ground at ``ground_d_m`` in NED, metric translation and
height from the autopilot); pixels above the horizon are treated as infinitely far. The
absolute difference with the earlier frame is thresholded per pixel and the
supra-threshold pixels around the object are counted: moving iff the count exceeds a
threshold. A stationary object raised above the ground leaves a residue (parallax), so
BSM calls it moving — the trap TCM avoids. The whole-frame warp is what makes BSM
costly, as in the paper.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .camera import CameraModel
from .frames import FloatArray


@dataclass(frozen=True)
class BSMConfig:
    pixel_threshold: int = 40  # grey-level difference counted as change
    window_radius_factor: float = 2.5  # count within this many object radii of its centre
    ground_d_m: float = 0.0  # NED down coordinate of the (flat) ground
    min_window_px: int = 4


class BackgroundSubtractor:
    """Egomotion-compensated frame differencing between two frames of one camera."""

    def __init__(self, camera: CameraModel, config: BSMConfig = BSMConfig()) -> None:
        self.camera = camera
        self.config = config
        self._bearings = camera.bearing_map_cam.reshape(-1, 3)

    def warp_current_into_earlier(
        self,
        gray_current: np.ndarray,
        R_ned_from_cam_earlier: FloatArray,
        R_ned_from_cam_current: FloatArray,
        pos_ned_earlier_m: FloatArray,
        pos_ned_current_m: FloatArray,
    ) -> np.ndarray:
        """The current image resampled on the earlier frame's pixel grid (ground-plane model)."""
        cam = self.camera
        b_ned = self._bearings @ R_ned_from_cam_earlier.T
        height = self.config.ground_d_m - float(pos_ned_earlier_m[2])
        with np.errstate(invalid="ignore", divide="ignore"):
            ground = b_ned[:, 2] > 1e-3
            scale = np.where(ground, height / b_ned[:, 2], 0.0)
        rel = b_ned * scale[:, None] + (pos_ned_earlier_m - pos_ned_current_m) * ground[:, None]
        # Sky and far structure: pure rotation (infinitely far).
        rel = np.where(ground[:, None], rel, b_ned)
        px = cam.pixel_from_bearing_cam(rel @ R_ned_from_cam_current)
        map_xy = np.nan_to_num((px - 0.5).astype(np.float32), nan=-1.0)
        map_x = map_xy[:, 0].reshape(cam.height, cam.width)
        map_y = map_xy[:, 1].reshape(cam.height, cam.width)
        if cam.model_name == "equirectangular":
            border = cv2.BORDER_WRAP
        else:
            border = cv2.BORDER_CONSTANT
        return cv2.remap(gray_current, map_x, map_y, cv2.INTER_LINEAR, borderMode=border)

    def score(
        self,
        gray_earlier: np.ndarray,
        warped_current: np.ndarray,
        centroid_px_earlier: tuple[float, float],
        radius_px: float,
    ) -> float:
        """Number of supra-threshold difference pixels around the object (earlier frame)."""
        cfg = self.config
        r = max(cfg.min_window_px, round(cfg.window_radius_factor * radius_px))
        u, v = int(centroid_px_earlier[0]), int(centroid_px_earlier[1])
        h, w = gray_earlier.shape[:2]
        y0, y1 = max(0, v - r), min(h, v + r + 1)
        x0, x1 = max(0, u - r), min(w, u + r + 1)
        if y1 <= y0 or x1 <= x0:
            return float("nan")
        diff = cv2.absdiff(gray_earlier[y0:y1, x0:x1], warped_current[y0:y1, x0:x1])
        return float(np.count_nonzero(diff > cfg.pixel_threshold))
