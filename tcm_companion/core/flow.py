"""Sparse optic-flow tracks whose NED-aligned bearings feed the egomotion estimate.

About ``n_points`` points are seeded on a grid over the part of the image that can show
static scenery (valid pixels, below a sky elevation in the local-level frame, outside
the caller's object boxes, textured enough to track), and followed frame to frame with
pyramidal Lucas–Kanade and a forward–backward consistency check. Every live track keeps
a bounded history of its pixel position and its unit bearing in the local-level NED
frame (``R_ned_from_cam @ bearing_cam``), so that :meth:`FlowTracker.correspondences`
can return the derotated bearing pairs of any two recent frames, which is what
:mod:`tcm_companion.core.egomotion` needs for the translation direction.

Pixel coordinates in and out of this module are the scenario format's (pixel centres at
``i + 0.5``); OpenCV's (centres at ``i``) are used only inside, shifted by 0.5.

A full-circle equirectangular panorama is tracked on an image padded with wrapped
columns, so tracks cross the left/right seam and keep their identity.

Pure: images, frame indices and rotations are arguments; no camera, file or clock IO.

Default parameters are measured (``tools/egomotion_study.py``, one core, OpenCV 5): a
9×9 window with one pyramid level (faster than 7×7 in OpenCV 5, as accurate as 11×11 and
as the textbook 15×15 × 3 levels at a fifth of its cost), the forward–backward check
staggered over 3 frames (as accurate as checking every frame, ~25 % cheaper), one track
per grid cell. At 360×220 the tracker costs ~0.8 ms per frame (median), at 900×550
~1.1 ms with the automatic 2× downscale (full resolution: ~1.5 ms, no more accurate
with the autopilot attitude).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .camera import CameraModel, Equirectangular
from .frames import FloatArray

BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]

_X_UNIT = np.array([[1.0, 0.0]], np.float32)
_TEXTURE_MAX_AGE = 10  # frames a lattice point's texture score is reused for


@dataclass(frozen=True)
class FlowConfig:
    """Tracker parameters. Pixel sizes refer to the image the tracker works on.

    - ``n_points``: tracks kept alive (seeded on a grid over the usable area).
    - ``win_size_px``, ``max_level``, ``max_iterations``, ``epsilon_px``: Lucas–Kanade
      window, pyramid levels above the base image, and stopping rule. One level covers
      about 6 px of motion per frame with a 9×9 window (150°/s of yaw at 360×220).
    - ``predict_rotation``, ``max_level_predicted``: start LK where the attitude change
      alone moves each point and use this many levels then (the remaining, translational
      flow is a pixel or two at 25 Hz), which follows any yaw rate. Off by default: on
      the simulator it cost ~15 % in the p90 of the direction error against one plain
      pyramid level, for little time saved. Without a rotation for both frames,
      ``max_level`` applies.
    - ``fb_threshold_px``: a track back-tracked to where it was ``fb_every`` frames
      earlier must land within this distance (full-resolution pixels).
    - ``fb_every``: each track is checked once per this many frames, over the whole span,
      starting the back-tracking at its old position; tracks are staggered so that every
      frame checks a ``1/fb_every`` share in one LK call and the cost stays even
      (1: the classic check every frame).
    - ``max_patch_error``: largest mean absolute grey-level difference between a point's
      window in two consecutive frames (LK's error); good tracks show 1–4, occluded ones
      12 and more. Catches occlusions on smooth texture, where a forward–backward check
      falls back into the origin's basin.
    - ``min_eigen``: texture threshold for seeding, the smaller eigenvalue of the mean
      gradient structure tensor over the window, in (grey levels per pixel)²; sensor
      noise alone gives about 1.
    - ``sky_elevation_rad``: points whose NED bearing is above this elevation are not
      seeded and tracks that rise above it are dropped: the sky has no parallax, clouds
      drift.
    - ``max_history``: frames of bearings kept per track (≥ the longest interval + 1; the
      pipeline raises it to cover its longest interval in seconds at 60 fps).
    - ``exclude_margin_px``: dilation of the caller's object boxes.
    - ``reseed_fraction``, ``reseed_interval``: seeding runs when fewer than this share of
      ``n_points`` is alive, and every ``reseed_interval`` frames anyway.
    - ``cull_cell_fraction``: tracks closer than this fraction of the seeding grid cell
      are thinned to the oldest (0: never); they pile up where the flow converges.
    - ``downscale``: integer factor by which frames are shrunk (area averaging) before
      tracking; positions are reported at full resolution. 0 picks the largest factor
      that keeps the tracked image at least ``AUTO_TRACK_WIDTH_PX`` wide (and divides a
      full panorama's width): 1 at 360×220 and 640×480, 2 at 900×550, where it measured
      as accurate as full resolution with live attitude, at about half the cost.
    """

    n_points: int = 400
    win_size_px: int = 9
    max_level: int = 1
    predict_rotation: bool = False
    max_level_predicted: int = 0
    max_iterations: int = 10
    epsilon_px: float = 0.03
    fb_threshold_px: float = 0.75
    max_patch_error: float = 10.0
    fb_every: int = 3
    min_eigen: float = 2.0
    sky_elevation_rad: float = 0.0
    max_history: int = 48
    exclude_margin_px: int = 4
    reseed_fraction: float = 0.9
    reseed_interval: int = 5
    cull_cell_fraction: float = 0.5
    downscale: int = 0

    def __post_init__(self) -> None:
        if self.n_points < 1:
            raise ValueError("flow.n_points must be positive")
        if self.win_size_px < 3:
            raise ValueError("flow.win_size_px must be at least 3")
        if self.max_level < 0:
            raise ValueError("flow.max_level must be non-negative")
        if self.fb_every < 1:
            raise ValueError("flow.fb_every must be at least 1")
        if self.max_history < 2:
            raise ValueError("flow.max_history must be at least 2")
        if self.downscale < 0:
            raise ValueError("flow.downscale must be 0 (automatic) or a positive factor")
        if self.reseed_interval < 1:
            raise ValueError("flow.reseed_interval must be at least 1")
        if not 0.0 < self.reseed_fraction <= 1.0:
            raise ValueError("flow.reseed_fraction must lie in (0, 1]")


@dataclass(frozen=True)
class FlowStats:
    """What one :meth:`FlowTracker.update` did."""

    frame_index: int
    n_live: int  # tracks alive after this frame (including new seeds)
    n_tracked: int  # tracks carried over from the previous frame
    n_seeded: int
    n_lost_lk: int  # LK did not converge or left the usable image
    n_lost_fb: int  # failed the forward–backward check
    n_dropped: int  # entered an excluded box or the sky
    n_culled: int  # removed from crowded grid cells
    n_fb_checked: int  # tracks back-tracked to their checkpoint this frame
    median_flow_px: float  # median frame-to-frame displacement of tracked points (full res)
    has_bearings: bool  # False when no rotation was given for this frame


AUTO_TRACK_WIDTH_PX = 400


def auto_downscale(camera: CameraModel) -> int:
    """The factor ``FlowConfig(downscale=0)`` uses for this camera."""
    f = max(1, camera.width // AUTO_TRACK_WIDTH_PX)
    if isinstance(camera, Equirectangular):
        while f > 1 and camera.width % f:
            f -= 1
    return f


class FlowTracker:
    """Grid-seeded Lucas–Kanade tracks with a bounded per-frame bearing history."""

    def __init__(self, camera: CameraModel, config: FlowConfig | None = None) -> None:
        self.camera = camera
        self.config = config or FlowConfig()
        cfg = self.config
        f = cfg.downscale or auto_downscale(camera)
        self._downscale = f
        self._scale = float(f)
        self._w = camera.width // f
        self._h = camera.height // f
        self._wrap = (
            isinstance(camera, Equirectangular)
            and abs(camera.azimuth_max_deg - camera.azimuth_min_deg - 360.0) < 1e-9
            and camera.width % f == 0
        )
        # Wrapped columns on each side so that LK windows and pyramid levels near the
        # seam see the other side of the panorama, plus room for a frame's motion.
        self._pad = (cfg.win_size_px // 2 + 8) * (1 << cfg.max_level) if self._wrap else 0
        self._pad_xy = np.float32(self._pad) * _X_UNIT  # (1, 2): the padding's x shift
        self._pad_x = self._pad_xy[0]
        self._win = (cfg.win_size_px, cfg.win_size_px)
        self._criteria = (
            cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT,
            cfg.max_iterations,
            cfg.epsilon_px,
        )
        self._build_masks()
        self._capacity = 2 * cfg.n_points  # dead tracks keep their history for a while
        self.reset()

    # -- set-up -------------------------------------------------------------------------
    def _build_masks(self) -> None:
        """Usable-pixel mask and the seed lattice at the tracking resolution."""
        cfg = self.config
        f = self._downscale
        valid_full = self.camera.valid_mask
        h, w = self._h, self._w
        valid = np.asarray(
            valid_full[: h * f, : w * f].reshape(h, f, w, f).all(axis=(1, 3)), np.uint8
        )
        # A track is usable where its window lies on valid pixels; a seed also needs
        # room for its texture patch.
        r = cfg.win_size_px // 2
        kernel = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
        border = cv2.BORDER_WRAP if self._wrap else cv2.BORDER_CONSTANT
        if self._wrap:
            padded = cv2.copyMakeBorder(valid, 0, 0, r + 1, r + 1, border)
            eroded = cv2.erode(padded, kernel, borderType=cv2.BORDER_REPLICATE)
            self._usable = eroded[:, r + 1 : r + 1 + w].astype(bool)
        else:
            self._usable = cv2.erode(
                valid, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0
            ).astype(bool)
        # Keep seeds a full window inside the frame (top/bottom always; sides unless
        # the panorama wraps) so that their texture patch needs no border handling.
        edge = r + 1
        self._usable[:edge] = False
        self._usable[h - edge :] = False
        if not self._wrap:
            self._usable[:, :edge] = False
            self._usable[:, w - edge :] = False
        n_usable = int(self._usable.sum())
        # Fine lattice: about four candidates per track, so a free cell has a choice.
        step = max(2.0, math.sqrt(max(n_usable, 1) / (4.0 * cfg.n_points)))
        us = np.arange(step / 2, w, step)
        vs = np.arange(step / 2, h, step)
        uu, vv = np.meshgrid(us, vs)
        lat = np.stack([uu.ravel(), vv.ravel()], axis=1)
        iu = np.floor(lat[:, 0]).astype(np.int64)
        iv = np.floor(lat[:, 1]).astype(np.int64)
        keep = self._usable[iv, iu]
        # Lattice points sit on pixel centres (OpenCV integer coordinates).
        self._lat_cv = np.stack([iu[keep], iv[keep]], axis=1).astype(np.float32)
        self._lat_px = (self._lat_cv.astype(np.float64) + 0.5) * self._scale
        self._lat_bearing_cam = self.camera.bearing_cam_from_pixel(self._lat_px)
        self._lat_step = step

    def reset(self) -> None:
        """Forget every track, image and history row."""
        cfg = self.config
        cap = self._capacity
        self._prev_img: np.ndarray | None = None
        self._prev_R: FloatArray | None = None
        self._last_frame: int | None = None
        self._pts_cv = np.zeros((cap, 2), np.float32)  # current positions, tracking scale
        self._alive = np.zeros(cap, bool)
        self._died_at = np.full(cap, -(2**62), np.int64)  # frame index of death (LRU reuse)
        self._born_at = np.zeros(cap, np.int64)
        self._hist_bearing = np.full((cfg.max_history, cap, 3), np.nan)
        self._hist_px = np.full((cfg.max_history, cap, 2), np.nan, np.float32)
        self._row_frame = np.full(cfg.max_history, -1, np.int64)
        # Forward–backward checks are per track and staggered by slot (see
        # _forward_backward): every frame back-tracks about 1/fb_every of the tracks in
        # one LK call, so the cost is the same in every frame.
        self._images: dict[int, np.ndarray] = {}  # prepared images of recent frames
        self._next_check = np.full(cap, -1, np.int64)  # -1: no span started yet
        self._ckpt_pts = np.full((cap, 2), np.nan, np.float32)
        self._lat_tex = np.zeros(len(self._lat_cv))
        self._lat_tex_frame = np.full(len(self._lat_cv), -(2**62), np.int64)

    # -- per frame ----------------------------------------------------------------------
    def update(
        self,
        gray: np.ndarray,
        frame_index: int,
        R_ned_from_cam: FloatArray | None,
        exclude_boxes_px: Sequence[tuple[int, int, int, int]] = (),
    ) -> FlowStats:
        """Track into a new frame, drop bad tracks, reseed, and record bearings.

        ``gray``: (H, W) uint8 (a BGR image is converted). ``R_ned_from_cam``: the
        frame's camera orientation; None when unknown, in which case tracks still follow
        in pixels but get no bearing for this frame and no points are seeded.
        ``exclude_boxes_px``: ``(u_min, v_min, u_max, v_max)`` pixel rectangles (full
        resolution, max exclusive) of detected objects; nothing is seeded in them (after
        dilation by ``exclude_margin_px``) and tracks entering them are dropped, since
        moving objects break the static-scene assumption. On a full panorama a box may
        extend past either edge and wraps.

        Frame indices must increase; a repeated or earlier index restarts the tracker.
        """
        cfg = self.config
        if self._last_frame is not None and frame_index <= self._last_frame:
            self.reset()
        img = self._prepare(gray)
        self._start_row(frame_index)
        R = None if R_ned_from_cam is None else np.asarray(R_ned_from_cam, np.float64)
        if R is not None and not np.isfinite(R).all():
            R = None

        n_lost_lk = n_lost_fb = 0
        median_flow = math.nan
        live = self._alive.nonzero()[0]
        if self._prev_img is not None and live.size:
            p0 = self._pts_cv[live]
            guess = self._predict(p0, R) if cfg.predict_rotation else None
            level = cfg.max_level if guess is None else cfg.max_level_predicted
            p1, ok = self._track(self._prev_img, img, p0, guess_b=guess, max_level=level)
            n_lost_lk = int(live.size - np.count_nonzero(ok))
            if n_lost_lk:
                self._kill(live[~ok], frame_index)
                live, p0, p1 = live[ok], p0[ok], p1[ok]
            self._pts_cv[live] = p1
            if live.size:
                d = p1 - p0
                if self._wrap:
                    d[:, 0] = (d[:, 0] + self._w / 2) % self._w - self._w / 2
                flow = np.hypot(d[:, 0], d[:, 1])
                median_flow = float(np.partition(flow, flow.size // 2)[flow.size // 2])
                median_flow *= self._scale
        n_checked = 0
        if live.size:
            n_checked, n_lost_fb = self._forward_backward(img, live, frame_index)
            if n_lost_fb:
                live = self._alive.nonzero()[0]

        # Bearings of the surviving tracks: needed for the sky test and the history.
        row = frame_index % cfg.max_history
        p = self._pts_cv[live]
        px = (p.astype(np.float64) + 0.5) * self._scale
        drop = self._in_boxes(px, exclude_boxes_px)
        b_ned: FloatArray | None = None
        if R is not None and live.size:
            b_ned = self.camera.bearing_cam_from_pixel(px) @ R.T
            drop |= self._is_sky_ned(b_ned)
        n_dropped = int(np.count_nonzero(drop))
        if n_dropped:
            self._kill(live[drop], frame_index)
            keep = ~drop
            live, px = live[keep], px[keep]
            if b_ned is not None:
                b_ned = b_ned[keep]
        self._hist_px[row, live] = px
        if b_ned is not None:
            self._hist_bearing[row, live] = b_ned
        n_tracked = int(live.size)

        n_seeded = n_culled = 0
        if R is not None and (
            n_tracked < cfg.reseed_fraction * cfg.n_points or frame_index % cfg.reseed_interval == 0
        ):
            n_seeded, n_culled = self._seed(img, R, exclude_boxes_px, frame_index)

        self._prev_R = R
        self._images[frame_index] = img
        for old in [f for f in self._images if f < frame_index - cfg.fb_every]:
            del self._images[old]
        self._prev_img = img
        self._last_frame = frame_index
        return FlowStats(
            frame_index=frame_index,
            n_live=n_tracked - n_culled + n_seeded,
            n_tracked=n_tracked,
            n_seeded=n_seeded,
            n_lost_lk=n_lost_lk,
            n_lost_fb=n_lost_fb,
            n_dropped=n_dropped,
            n_culled=n_culled,
            n_fb_checked=n_checked,
            median_flow_px=median_flow,
            has_bearings=R is not None,
        )

    def _prepare(self, gray: np.ndarray) -> np.ndarray:
        img = np.asarray(gray)
        if img.ndim == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        if img.dtype != np.uint8:
            img = np.clip(img, 0, 255).astype(np.uint8)
        if img.shape != (self.camera.height, self.camera.width):
            raise ValueError(
                f"image is {img.shape[1]}x{img.shape[0]}, camera is "
                f"{self.camera.width}x{self.camera.height}"
            )
        f = self._downscale
        if f > 1:
            img = cv2.resize(
                img[: self._h * f, : self._w * f], (self._w, self._h), interpolation=cv2.INTER_AREA
            )
        if self._wrap:
            img = cv2.copyMakeBorder(img, 0, 0, self._pad, self._pad, cv2.BORDER_WRAP)
        return np.ascontiguousarray(img)

    def _track(
        self,
        img_a: np.ndarray,
        img_b: np.ndarray,
        p_a: np.ndarray,
        check_usable: bool = True,
        guess_b: np.ndarray | None = None,
        max_level: int | None = None,
    ) -> tuple[np.ndarray, BoolArray]:
        """LK from ``img_a`` to ``img_b``; returns wrapped positions and a usable mask.

        ``guess_b``: initial positions in ``img_b`` (else ``p_a``).
        """
        pad = self._pad
        src = p_a.reshape(-1, 1, 2)
        if pad:
            src = src + self._pad_xy
        flags = 0
        if guess_b is None:
            # nextPts doubles as the output buffer; it is read only with the flag.
            init = src.copy()
        else:
            init = guess_b.reshape(-1, 1, 2).astype(np.float32)
            if pad:
                init = init + self._pad_xy
            if self._wrap:
                # The guess must sit on the same side of the seam as the source.
                d = init[:, 0, 0] - src[:, 0, 0]
                init[:, 0, 0] -= np.round(d / self._w) * self._w
            flags = cv2.OPTFLOW_USE_INITIAL_FLOW
        dst, status, err = cv2.calcOpticalFlowPyrLK(
            img_a,
            img_b,
            src,
            init,
            winSize=self._win,
            maxLevel=self.config.max_level if max_level is None else max_level,
            criteria=self._criteria,
            flags=flags,
        )
        p_b = dst.reshape(-1, 2)
        if pad:
            p_b = p_b - self._pad_x
        # The patch difference catches occlusions that the forward–backward check misses
        # on smooth texture, where both directions fall back into the origin's basin.
        ok = (
            status.ravel().astype(bool)
            & (err.ravel() <= self.config.max_patch_error)
            & np.isfinite(p_b).all(axis=1)
        )
        if self._wrap:
            p_b[:, 0] = np.mod(p_b[:, 0], self._w)
        if check_usable:
            ok &= self._is_usable(p_b)
        return p_b, ok

    def _predict(self, p_cv: np.ndarray, R: FloatArray | None) -> np.ndarray | None:
        """Where the rotation alone (attitude of the two frames) moves the points.

        Starting LK there leaves it only the translational flow (and the attitude
        error), so a rotating vehicle needs no extra pyramid levels. None when either
        frame lacks a rotation.
        """
        R0 = self._prev_R
        if R is None or R0 is None:
            return None
        px = (p_cv.astype(np.float64) + 0.5) * self._scale
        b_cam1 = self.camera.bearing_cam_from_pixel(px) @ (R0.T @ R)  # rows of R1ᵀ R0 b0
        q = self.camera.pixel_from_bearing_cam(b_cam1) / self._scale - 0.5
        bad = ~np.all(np.isfinite(q), axis=1)
        q[bad] = p_cv[bad]
        return np.asarray(q, np.float32)

    def _is_usable(self, p_cv: np.ndarray) -> BoolArray:
        iu = np.floor(p_cv[:, 0] + 0.5)
        iv = np.floor(p_cv[:, 1] + 0.5)
        with np.errstate(invalid="ignore"):
            inside = (iu >= 0) & (iu < self._w) & (iv >= 0) & (iv < self._h)
        out = np.zeros(len(p_cv), bool)
        out[inside] = self._usable[iv[inside].astype(np.int64), iu[inside].astype(np.int64)]
        return out

    def _forward_backward(
        self, img: np.ndarray, live: IntArray, frame_index: int
    ) -> tuple[int, int]:
        """Back-track the tracks whose check is due; drop those that miss; anchor others.

        Track ``s`` belongs to class ``s % fb_every`` and is checked at the frames of its
        class, against its position ``fb_every`` frames earlier: all tracks due in a frame
        share that reference frame, so one LK call per frame does it. A new track waits
        for the next frame of its class to set its first checkpoint (the few frames
        before are covered by the patch-error test only). Returns ``(checked, failed)``.
        A failed track loses its history after its checkpoint too: the error happened
        somewhere in that span.
        """
        cfg = self.config
        fb = cfg.fb_every
        nxt = self._next_check[live]
        due = live[nxt == frame_index]
        # Checks missed because frames were skipped: start a new span instead.
        late = live[(nxt >= 0) & (nxt < frame_index)]
        pending = live[(nxt < 0) & (live % fb == frame_index % fb)]
        ref = self._images.get(frame_index - fb)
        checked = failed = 0
        if due.size and ref is None:
            late = np.concatenate([late, due])
        elif due.size:
            assert ref is not None
            # Started at the checkpoint: the span can hold more motion than the pyramid
            # covers, and what is checked is whether the track drifted off it.
            back, ok = self._track(
                img, ref, self._pts_cv[due], check_usable=False, guess_b=self._ckpt_pts[due]
            )
            err = back - self._ckpt_pts[due]
            if self._wrap:
                err[:, 0] = (err[:, 0] + self._w / 2) % self._w - self._w / 2
            with np.errstate(invalid="ignore"):
                ok &= np.hypot(err[:, 0], err[:, 1]) <= cfg.fb_threshold_px / self._scale
            bad = due[~ok]
            if bad.size:
                rows = (self._row_frame > frame_index - fb).nonzero()[0]
                self._hist_bearing[np.ix_(rows, bad)] = np.nan
                self._hist_px[np.ix_(rows, bad)] = np.nan
                self._kill(bad, frame_index)
            checked, failed = int(due.size), int(bad.size)
            self._anchor(due[ok], frame_index)
        self._anchor(late, frame_index)
        self._anchor(pending, frame_index)
        return checked, failed

    def _anchor(self, slots: IntArray, frame_index: int) -> None:
        """Start a new forward–backward span at the current positions."""
        if slots.size:
            self._ckpt_pts[slots] = self._pts_cv[slots]
            self._next_check[slots] = frame_index + self.config.fb_every

    def _kill(self, slots: IntArray, frame_index: int) -> None:
        self._alive[slots] = False
        self._died_at[slots] = frame_index

    def _in_boxes(self, px: FloatArray, boxes: Sequence[tuple[int, int, int, int]]) -> BoolArray:
        """Points (full-resolution pixel coordinates) inside any dilated box."""
        inside = np.zeros(len(px), bool)
        if not boxes:
            return inside
        m = self.config.exclude_margin_px
        u, v = px[:, 0], px[:, 1]
        width = float(self.camera.width)
        for u0, v0, u1, v1 in boxes:
            in_v = (v >= v0 - m) & (v < v1 + m)
            if self._wrap:
                span = (u1 - u0) + 2 * m
                in_u = np.mod(u - (u0 - m), width) < span
            else:
                in_u = (u >= u0 - m) & (u < u1 + m)
            inside |= in_u & in_v
        return inside

    def _is_sky_ned(self, b_ned: FloatArray) -> BoolArray:
        # Elevation above the threshold <=> the up component (-down) above its sine.
        with np.errstate(invalid="ignore"):
            return np.asarray(-b_ned[:, 2] > math.sin(self.config.sky_elevation_rad))

    def _seed(
        self,
        img: np.ndarray,
        R: FloatArray,
        boxes: Sequence[tuple[int, int, int, int]],
        frame_index: int,
    ) -> tuple[int, int]:
        """Thin crowded cells, then add tracks in free cells, best texture first.

        Returns ``(seeded, culled)``. Tracks pile up where the flow converges (the focus
        of contraction) and leave other areas empty; one track per cell keeps the
        bearings spread over the view, which is what constrains the translation. The
        oldest track of a cell survives: its history serves the longest intervals.
        """
        cfg = self.config
        lat = self._lat_cv
        lat_b_ned = self._lat_bearing_cam @ R.T
        seedable = ~self._is_sky_ned(lat_b_ned)
        if boxes:
            seedable &= ~self._in_boxes(self._lat_px, boxes)
        n_seedable = int(seedable.sum())
        if n_seedable == 0:
            return 0, 0
        # Cells sized so that the seedable area holds about n_points of them.
        cell = self._lat_step * math.sqrt(n_seedable / cfg.n_points)
        ncols = math.ceil(self._w / cell) + 1
        nrows = math.ceil(self._h / cell) + 1
        live = self._alive.nonzero()[0]
        live_cell = self._cell_of(self._pts_cv[live], cell, ncols)
        n_culled = 0
        if cfg.cull_cell_fraction > 0 and live.size:
            # A finer grid than the seeding one: tracks drift across cell borders, and
            # culling every pair that happens to share a seeding cell would cut short
            # too many long tracks.
            cc = cell * cfg.cull_cell_fraction
            ccols = math.ceil(self._w / cc) + 1
            cull_cell = self._cell_of(self._pts_cv[live], cc, ccols)
            order = np.lexsort((self._born_at[live], cull_cell))
            _, first = np.unique(cull_cell[order], return_index=True)
            keep = np.zeros(live.size, bool)
            keep[order[first]] = True
            n_culled = int(live.size - first.size)
            if n_culled:
                self._kill(live[~keep], frame_index)
        need = cfg.n_points - int(np.count_nonzero(self._alive))
        if need <= 0:
            return 0, n_culled
        occupied = np.zeros(ncols * nrows, bool)
        occupied[live_cell] = True
        cand = seedable.nonzero()[0]
        cand_cell = self._cell_of(lat[cand], cell, ncols)
        free = ~occupied[cand_cell]
        cand, cand_cell = cand[free], cand_cell[free]
        if not cand.size:
            return 0, n_culled
        # Texture scores are cached per lattice point for a few frames: the same free
        # (often textureless) cells come up at every seeding, and the scene moves by
        # only a pixel or so per frame.
        stale = cand[frame_index - self._lat_tex_frame[cand] > _TEXTURE_MAX_AGE]
        if stale.size:
            self._lat_tex[stale] = self._texture(img, lat[stale])
            self._lat_tex_frame[stale] = frame_index
        score = self._lat_tex[cand]
        good = score >= cfg.min_eigen
        cand, cand_cell, score = cand[good], cand_cell[good], score[good]
        if not cand.size:
            return 0, n_culled
        # One seed per free cell, the best-textured candidate in it.
        order = np.lexsort((-score, cand_cell))
        _, first = np.unique(cand_cell[order], return_index=True)
        pick = order[first]
        if pick.size > need:
            pick = pick[np.argsort(-score[pick], kind="stable")[:need]]
        chosen = cand[pick]
        slots = self._allocate(len(chosen))
        self._pts_cv[slots] = lat[chosen]
        self._alive[slots] = True
        self._born_at[slots] = frame_index
        # Tracks of this frame's class start their span now, the others wait for a
        # frame of their class (see _forward_backward).
        self._next_check[slots] = -1
        self._anchor(slots[slots % cfg.fb_every == frame_index % cfg.fb_every], frame_index)
        row = frame_index % cfg.max_history
        self._hist_px[row, slots] = self._lat_px[chosen]
        self._hist_bearing[row, slots] = lat_b_ned[chosen]
        return len(slots), n_culled

    @staticmethod
    def _cell_of(p_cv: np.ndarray, cell: float, ncols: int) -> IntArray:
        # Clipped: a live point may sit up to half a pixel left of or above the image.
        cu = np.maximum(np.floor(p_cv[:, 0] / cell), 0).astype(np.int64)
        cv = np.maximum(np.floor(p_cv[:, 1] / cell), 0).astype(np.int64)
        return np.asarray(cv * ncols + cu)

    def _texture(self, img: np.ndarray, p_cv: np.ndarray) -> FloatArray:
        """Smaller eigenvalue of the mean structure tensor in the LK window at each point.

        Computed on patches gathered at the candidates only: seeding touches a few
        hundred points, far fewer than a whole-image corner map would.
        """
        r = self.config.win_size_px // 2
        offs = np.arange(-r - 1, r + 2)
        iu = p_cv[:, 0].astype(np.int64) + self._pad
        iv = p_cv[:, 1].astype(np.int64)
        rows = iv[:, None, None] + offs[None, :, None]
        cols = iu[:, None, None] + offs[None, None, :]
        patch = img[rows, cols].astype(np.float32)
        gx = 0.5 * (patch[:, 1:-1, 2:] - patch[:, 1:-1, :-2])
        gy = 0.5 * (patch[:, 2:, 1:-1] - patch[:, :-2, 1:-1])
        a = np.mean(gx * gx, axis=(1, 2))
        b = np.mean(gx * gy, axis=(1, 2))
        c = np.mean(gy * gy, axis=(1, 2))
        return np.asarray(0.5 * (a + c) - np.sqrt(0.25 * (a - c) ** 2 + b * b), np.float64)

    def _allocate(self, n: int) -> IntArray:
        """Free slots, longest-dead first, so recent dead tracks keep their history."""
        free = (~self._alive).nonzero()[0]
        slots = free[np.argsort(self._died_at[free], kind="stable")[:n]]
        self._hist_bearing[:, slots] = np.nan
        self._hist_px[:, slots] = np.nan
        return slots

    def _start_row(self, frame_index: int) -> None:
        """Claim the history row of this frame; rows of skipped frames become empty."""
        H = self.config.max_history
        if self._last_frame is not None:
            for skipped in range(self._last_frame + 1, min(frame_index, self._last_frame + H + 1)):
                self._row_frame[skipped % H] = -1
        row = frame_index % H
        self._row_frame[row] = frame_index
        self._hist_bearing[row] = np.nan
        self._hist_px[row] = np.nan

    # -- queries ------------------------------------------------------------------------
    def has_frame(self, frame_index: int) -> bool:
        """Whether ``frame_index`` is still in the history."""
        return bool(self._row_frame[frame_index % self.config.max_history] == frame_index)

    def correspondences(self, frame_a: int, frame_b: int) -> tuple[FloatArray, FloatArray]:
        """NED-aligned unit bearings ``(N, 3), (N, 3)`` of tracks seen in both frames.

        Empty arrays when either frame has left the history or had no rotation.
        """
        rows = self._rows_pair(frame_a, frame_b)
        if rows is None:
            return np.zeros((0, 3)), np.zeros((0, 3))
        a = self._hist_bearing[rows[0]]
        b = self._hist_bearing[rows[1]]
        ok = np.isfinite(a[:, 0]) & np.isfinite(b[:, 0])
        return a[ok].copy(), b[ok].copy()

    def pixel_correspondences(self, frame_a: int, frame_b: int) -> tuple[FloatArray, FloatArray]:
        """Pixel positions ``(N, 2), (N, 2)`` (scenario convention) of tracks in both frames."""
        rows = self._rows_pair(frame_a, frame_b)
        if rows is None:
            return np.zeros((0, 2)), np.zeros((0, 2))
        a = self._hist_px[rows[0]]
        b = self._hist_px[rows[1]]
        ok = np.isfinite(a[:, 0]) & np.isfinite(b[:, 0])
        return a[ok].astype(np.float64), b[ok].astype(np.float64)

    def _rows_pair(self, frame_a: int, frame_b: int) -> tuple[int, int] | None:
        if not (self.has_frame(frame_a) and self.has_frame(frame_b)):
            return None
        H = self.config.max_history
        return frame_a % H, frame_b % H

    @property
    def live_points_px(self) -> FloatArray:
        """Current positions ``(N, 2)`` of live tracks (scenario pixel convention)."""
        return np.asarray((self._pts_cv[self._alive].astype(np.float64) + 0.5) * self._scale)
