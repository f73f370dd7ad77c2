"""The renderer's pixel layout: pixels in *tile-major* order (tiles of ``tile_px`` ×
``tile_px`` pixels stored contiguously), each tile with a bounding cone of its bearings so
an object is tested only against the tiles its own cone meets; and the per-frame buffers
(pose, rotated bearings, colour and depth) one render works on."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ...core.camera import CameraModel, Fisheye
from ...core.frames import FloatArray


class TileLayout:
    """Pixels of one camera in tile-major order, with per-tile bounding cones."""

    def __init__(self, camera: CameraModel, tile_px: int, fisheye_fov_deg: float) -> None:
        h, w = camera.height, camera.width
        ts = tile_px
        ty, tx = -(-h // ts), -(-w // ts)
        hp, wp = ty * ts, tx * ts
        self.width, self.height = w, h
        self.tile_px, self.tiles_y, self.tiles_x = ts, ty, tx
        self.t2 = ts * ts

        bear = np.asarray(camera.bearing_map_cam, dtype=np.float64)
        valid = np.isfinite(bear[..., 0])
        if isinstance(camera, Fisheye):
            with np.errstate(invalid="ignore"):
                valid &= bear[..., 0] >= math.cos(math.radians(fisheye_fov_deg / 2.0)) - 1e-12
        pix = np.asarray(camera.pixel_size_map_rad, dtype=np.float64)
        fallback = float(np.median(pix[valid])) if valid.any() else 1e-2
        bear_p = np.zeros((hp, wp, 3))
        bear_p[..., 0] = 1.0
        bear_p[:h, :w][valid] = bear[valid]
        valid_p = np.zeros((hp, wp), bool)
        valid_p[:h, :w] = valid
        pix_p = np.full((hp, wp), fallback)
        pix_p[:h, :w] = np.where(valid & (pix > 0), pix, fallback)

        bear_t = self._to_tiles(bear_p)  # (N, 3)
        self.bearing_cam = np.ascontiguousarray(bear_t.T, dtype=np.float32)  # (3, N)
        self.valid = self._to_tiles(valid_p)
        self.pix_rad = self._to_tiles(pix_p).astype(np.float32)
        self.n = self.valid.shape[0]

        nt = ty * tx
        bt = bear_t.reshape(nt, self.t2, 3)
        vt = self.valid.reshape(nt, self.t2)
        pt = self.pix_rad.reshape(nt, self.t2)
        centre = np.where(vt[..., None], bt, 0.0).sum(axis=1)
        norm = np.linalg.norm(centre, axis=1)
        keep = (norm > 1e-9) & vt.any(axis=1)
        centre = centre[keep] / norm[keep, None]
        cosang = np.einsum("tkc,tc->tk", bt[keep], centre)
        ang = np.arccos(np.clip(cosang, -1.0, 1.0)) + 1.5 * pt[keep]
        radius = np.where(vt[keep], ang, 0.0).max(axis=1)
        self.tile_ids = np.nonzero(keep)[0]
        self.tile_centre_cam = centre  # (T, 3)
        self.tile_cos = np.cos(radius)
        self.tile_sin = np.sin(radius)
        self._tile_cones = np.empty((self.tile_ids.size, 5))
        self._tile_cones[:, 3] = -self.tile_cos
        self._tile_cones[:, 4] = self.tile_sin
        self._ar = np.arange(self.t2)
        # Invalid pixels of the image (the padding past its edges is cropped away anyway).
        in_image = np.zeros((hp, wp), bool)
        in_image[:h, :w] = True
        self.invalid_idx = np.nonzero(self._to_tiles(in_image) & ~self.valid)[0]
        self._camera = camera
        self._pixel_axes: tuple[np.ndarray, np.ndarray] | None = None
        self._pixel_rc: np.ndarray | None = None

    def tile_cones(self, R_ned_from_cam: FloatArray) -> np.ndarray:
        """(T, 5) per tile: its cone's axis in NED, ``-cos r``, ``sin r`` (r its radius):
        dotted with ``(u, cos ρ, sin ρ)`` it is ``u·axis - cos(r + ρ)``, which is >= 0
        where the tile's cone meets the cone of axis ``u`` and radius ρ."""
        cones = self._tile_cones.copy()
        np.matmul(self.tile_centre_cam, R_ned_from_cam.T, out=cones[:, :3])
        return cones

    def pixel_axes_cam(self) -> tuple[np.ndarray, np.ndarray]:
        """(3, N) float32 bearing change across each pixel along u and along v (camera
        FRD): a ray at ``(u + su, v + sv)`` is about ``b + su·du + sv·dv`` (su, sv in
        [-½, ½]). Built on first use (only worlds with non-spherical targets need it)."""
        if self._pixel_axes is None:
            cam = self._camera
            u = np.arange(cam.width, dtype=np.float64) + 0.5
            v = np.arange(cam.height, dtype=np.float64) + 0.5
            uu, vv = np.meshgrid(u, v)

            def diff(du: float, dv: float) -> np.ndarray:
                a = cam.bearing_cam_from_pixel(np.stack([uu - du, vv - dv], axis=-1))
                b = cam.bearing_cam_from_pixel(np.stack([uu + du, vv + dv], axis=-1))
                d = np.where(np.isfinite(a) & np.isfinite(b), b - a, 0.0)
                hp, wp = self.tiles_y * self.tile_px, self.tiles_x * self.tile_px
                out = np.zeros((hp, wp, 3))
                out[: cam.height, : cam.width] = d
                return np.ascontiguousarray(self._to_tiles(out).T, dtype=np.float32)

            self._pixel_axes = (diff(0.5, 0.0), diff(0.0, 0.5))
        return self._pixel_axes

    def pixel_rc(self) -> np.ndarray:
        """Row and column (2, N) int32 of each tile-major pixel in the padded image."""
        if self._pixel_rc is None:
            hp, wp = self.tiles_y * self.tile_px, self.tiles_x * self.tile_px
            rr, cc = np.mgrid[0:hp, 0:wp].astype(np.int32)
            self._pixel_rc = np.stack([self._to_tiles(rr), self._to_tiles(cc)])
        return self._pixel_rc

    def _to_tiles(self, a: np.ndarray) -> np.ndarray:
        ts = self.tile_px
        rest = a.shape[2:]
        t = a.reshape(self.tiles_y, ts, self.tiles_x, ts, *rest).swapaxes(1, 2)
        return np.ascontiguousarray(t).reshape(self.tiles_y * self.tiles_x * ts * ts, *rest)

    def to_image(self, planar: np.ndarray) -> np.ndarray:
        """(C, N) tile-major planar data → (H, W, C) image (or (H, W) for C = 1 / 1-D)."""
        ts = self.tile_px
        data = planar if planar.ndim == 2 else planar[None, :]
        c = data.shape[0]
        t = data.reshape(c, self.tiles_y, self.tiles_x, ts, ts).transpose(1, 3, 2, 4, 0)
        img = t.reshape(self.tiles_y * ts, self.tiles_x * ts, c)[: self.height, : self.width]
        img = np.ascontiguousarray(img)
        return img if planar.ndim == 2 else img[..., 0]

    def to_bgr_image(self, rgb: np.ndarray) -> np.ndarray:
        """(3, N) uint8 planar RGB → (H, W, 3) BGR image (:meth:`to_image` of the
        channels reversed): interleave with ``cv2.merge``, then move whole tile rows."""
        ts = self.tile_px
        bgr = cv2.merge([rgb[2], rgb[1], rgb[0]])
        t = bgr.reshape(self.tiles_y, self.tiles_x, ts, ts, 3).transpose(0, 2, 1, 3, 4)
        img = t.reshape(self.tiles_y * ts, self.tiles_x * ts, 3)[: self.height, : self.width]
        return np.ascontiguousarray(img)

    def pixels_of_tiles(self, kept_tiles: np.ndarray) -> np.ndarray:
        tiles = self.tile_ids[kept_tiles]
        return (tiles[:, None] * self.t2 + self._ar[None, :]).ravel()


#: The ground span's first pixel, end, and its points' north, east and footprint (m).
GroundHits = tuple[int, int, np.ndarray, np.ndarray, np.ndarray]


@dataclass
class FrameBuffers:
    """Per-frame state: pose, rotated bearings, the colour and depth buffers."""

    origin: FloatArray  # camera position, NED m
    B: np.ndarray  # (3, N) float32 bearings in NED
    tile_cones: FloatArray  # (T, 5) tile cones in NED (:meth:`TileLayout.tile_cones`)
    colour: np.ndarray  # (3, N) float32 linear RGB
    depth: np.ndarray  # (N,) float32 range along the ray, m
    ground: np.ndarray  # (N,) bool: ray meets the ground within the far range (render._T_FAR_M)
    R_ned_from_cam: FloatArray | None = None
    ground_t: np.ndarray | None = None  # (N,) float32 ground range where the ground was drawn
