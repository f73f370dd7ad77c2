"""Vectorised numpy ray caster of a :class:`~tcm_companion.sim.scene.world.World` for any camera model.

Every pixel's bearing comes from the camera model (``camera.bearing_map_cam``, computed
once), is rotated into NED by ``R_ned_from_cam = R_ned_from_body @ R_body_from_cam`` and
intersected with the ground plane, the clutter and the balls; the camera sits at the
vehicle position. Pixels are held in *tile-major* order (tiles of ``tile_px`` × ``tile_px``
pixels stored contiguously), and every tile carries a bounding cone of its bearings, so an
object is tested only against the pixels of the tiles whose cones meet the object's own
angular bounding cone; the ground and the sky are evaluated on every valid pixel. Per-pixel
data is planar, ``(channels, pixels)``, because numpy gathers and scatters along the last
axis are several times faster than row gathers. All canopies (and all trunks and posts)
are intersected in one vectorised pass, the nearest hit per pixel winning.

Appearance:

- ground: macro albedo (lawn, dirt, path) × periodic grass detail with stones, both
  sampled bilinearly with ``cv2.remap``; the detail is mip-mapped and blended between
  the two levels bracketing each pixel's ground footprint (trilinear), so distant grass
  does not alias; distance haze;
- light: a directional sun with Lambert shading, sky ambient (brighter from above) and
  a little bounce light from the grass, so a ball has a dark-red shaded side; soft cast
  shadows on the ground: the clutter's are static and baked once into the macro texture
  (10 cm texels), the balls' are cast per frame (penumbra from the sun's size);
- balls (and canopies, posts, trunks) are anti-aliased analytically: a pixel's coverage
  is ``clip((ρ - γ) / p + ½, 0, 1)`` with γ the angle between its bearing and the sphere's
  centre, ρ the sphere's angular radius and p the pixel's angular size
  (``camera.pixel_size_map_rad``), so the rendered disc's area matches the geometric
  one to a fraction of a pixel along its rim (box edges are hard);
- the other targets (:class:`~.world.BoxTarget`, :class:`~.world.CylinderTarget`,
  :class:`~.world.DiscTarget`) are ray cast exactly (:mod:`.shapes`) with 4 × 4 rays per
  pixel (spread over the pixel by the camera model's local derivatives): coverage is the
  fraction of rays that hit (and pass the depth test), colour the mean of their shading
  (Lambert + ambient + bounce as above, plus the target's Blinn-Phong ``specular``), so
  faces, edges and occluding contours are anti-aliased; their shadows on the ground are
  cast per frame (2 × 2 shadow rays per ground pixel). Objects of every kind are drawn far
  to near with a depth test against the clutter and each other. Objects receive no cast
  shadows (their shaded sides are Lambert's);
- output: linear RGB → display gamma 2 → 8 bits, plus Gaussian sensor noise (seeded),
  BGR ``uint8``. Fisheye pixels outside the model's valid region or outside
  ``fisheye_fov_deg`` are black.

Beside this module, one job each: :mod:`.tiles` (the tile-major pixel layout, its cones,
the per-frame buffers), :mod:`.planar` (gathers, scatters, blends and remap sampling of
planar pixel data) and :mod:`.shadows` (shadow coverage of each caster, the clutter's
shadows baked into the ground texture, a solid target's outline hull).
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import cv2
import numpy as np

from ...core.camera import CameraModel
from ...core.frames import FloatArray
from .planar import (
    RemapMaps,
    apply_shades,
    copy_where,
    planes_f32,
    put,
    smoothstep,
    span,
    take,
    take_all,
)
from .shadows import (
    SUN_PENUMBRA,
    convex_hull_2d,
    footprint,
    lit_macro,
    outline_points_ned,
    sphere_shadow,
)
from .shapes import ray_target_ned
from .tiles import FrameBuffers, GroundHits, TileLayout
from .world import (
    DETAIL_LEVELS,
    Ball,
    Box,
    GroundTextures,
    SolidTarget,
    Target,
    World,
    ground_textures,
    sky_textures,
)

_T_FAR_M = 1000.0  # ground beyond this range is drawn as horizon haze
_NOISE_BANK = 1 << 20
_BALL_SPECULAR = 0.08
_SPECULAR_EXPONENT = 30
_SUB = 4  # rays per pixel side for the non-spherical targets
_SUB_OFF = (np.arange(_SUB) + 0.5) / _SUB - 0.5
_SUB_U = np.tile(_SUB_OFF, _SUB)
_SUB_V = np.repeat(_SUB_OFF, _SUB)


class Renderer:
    """Render one :class:`World` through one camera model.

    ``render(t_s, pos_ned_m, R_ned_from_body)`` gives a BGR ``uint8`` frame at scenario
    time ``t_s`` (the balls move with time), camera at ``pos_ned_m``. ``seed`` seeds the
    bank the sensor noise is drawn from; each call's ``rng`` picks from it.
    """

    def __init__(
        self,
        world: World,
        camera: CameraModel,
        fisheye_fov_deg: float = 180.0,
        tile_px: int = 8,
        seed: int = 0,
    ) -> None:
        self.world = world
        self.camera = camera
        self.layout = TileLayout(camera, tile_px, fisheye_fov_deg)
        self.tex: GroundTextures = ground_textures(world.ground)
        self.macro = lit_macro(world.ground, world.sun, world.trees, world.posts, world.buildings)
        self.sky_tex = sky_textures(world.sky)
        self._L = world.sun.direction_ned
        self._sin_sun = -float(self._L[2])

        spheres = [s for t in world.trees for s in t.canopy]
        self._sph_centre = np.array([s.centre_ned_m for s in spheres], np.float64).reshape(-1, 3)
        self._sph_radius = np.array([s.radius_m for s in spheres], np.float64)
        self._sph_albedo = (
            np.array([s.albedo_rgb for s in spheres], np.float32).reshape(-1, 3).T.copy()
        )
        self._sph_leafy = np.array([s.leafy for s in spheres], bool)
        cyls = [t.trunk for t in world.trees] + list(world.posts)
        self._cyls = cyls
        self._cyl_base = np.array([c.base_ne_m for c in cyls], np.float64).reshape(-1, 2).T.copy()
        self._cyl_radius = np.array([c.radius_m for c in cyls], np.float64)
        self._cyl_height = np.array([c.height_m for c in cyls], np.float64)
        self._cyl_albedo = (
            np.array([c.albedo_rgb for c in cyls], np.float32).reshape(-1, 3).T.copy()
        )
        self._cyl_bound_centre = np.stack(
            [self._cyl_base[0], self._cyl_base[1], -self._cyl_height / 2.0], axis=1
        ).reshape(-1, 3)
        self._cyl_bound_radius = np.hypot(self._cyl_radius, self._cyl_height / 2.0)
        # The static clutter's bounding spheres, culled against the tiles in one pass:
        # buildings, then trunks and posts, then canopies.
        box_lo = np.array([b.min_ned_m for b in world.buildings], np.float64).reshape(-1, 3)
        box_hi = np.array([b.max_ned_m for b in world.buildings], np.float64).reshape(-1, 3)
        self._clutter_centre = np.concatenate(
            [(box_lo + box_hi) / 2.0, self._cyl_bound_centre, self._sph_centre]
        )
        self._clutter_radius = np.concatenate(
            [
                np.linalg.norm(box_hi - box_lo, axis=1) / 2.0,
                self._cyl_bound_radius,
                self._sph_radius,
            ]
        )
        self._scratch = np.full(self.layout.n, np.inf)
        self._half_pix_max = 0.5 * float(self.layout.pix_rad.max())

        # Constants and buffers of the ground and the sky.
        self._maps = RemapMaps()
        self._maps_far = RemapMaps()
        self._L32 = self._L.astype(np.float32)
        offs = self.tex.detail_offsets_px - 0.5
        # Per mip level k (the pixel's lower level, then k + 1): texel scale and atlas
        # offsets, as 256-entry float32 tables for cv2.LUT on uint8 level numbers (a
        # lookup: the same values as indexing, without int64 indices).
        scale = np.exp2(-np.arange(DETAIL_LEVELS, dtype=np.float32))
        ox = (offs[:, 0], offs[1:, 0])  # level k, level k + 1
        oy = (offs[:, 1], offs[1:, 1])

        def lut(values: np.ndarray) -> np.ndarray:
            table = np.zeros(256, np.float32)
            table[: values.shape[0]] = values
            return table

        self._detail_luts = tuple(
            (lut(scale * np.float32(0.5**lev)), lut(ox[lev]), lut(oy[lev])) for lev in (0, 1)
        )
        self._stone_rgb = np.asarray(world.ground.stone_rgb, np.float32)[:, None]
        sky = world.sky
        self._hor_rgb = np.asarray(sky.horizon_rgb, np.float32)[:, None]
        self._zen_minus_hor = np.asarray(sky.zenith_rgb, np.float32)[:, None] - self._hor_rgb
        self._haze_rgb = self._hor_rgb * np.float32(0.9)
        self._cloud_rgb = np.asarray(sky.cloud_rgb, np.float32)[:, None]
        self._hill_top = float(np.sin(self.sky_tex.hill_el_rad.max()))

        bank_rng = np.random.default_rng(np.random.SeedSequence([2718281, seed]))
        self._noise_bank = bank_rng.standard_normal(
            max(_NOISE_BANK, 3 * self.layout.n) + 3 * self.layout.n, dtype=np.float32
        )

    # ---------------------------------------------------------------------------------
    # Public API
    # ---------------------------------------------------------------------------------
    def render(
        self,
        t_s: float,
        pos_ned_m: FloatArray,
        R_ned_from_body: FloatArray,
        noise_dn: float = 2.5,
        rng: np.random.Generator | None = None,
    ) -> np.ndarray:
        """BGR ``uint8`` image (H, W, 3) with Gaussian sensor noise of σ = ``noise_dn`` DN.

        The noise of one call is the sum of two slices of a seeded Gaussian bank at
        offsets drawn from ``rng``, scaled to σ: i.i.d. within the frame, and as
        reproducible as ``rng``.
        """
        lin = self._render_flat(t_s, pos_ned_m, R_ned_from_body)
        return self._to_bgr(lin, noise_dn, rng)

    def render_with_coverage(
        self,
        t_s: float,
        pos_ned_m: FloatArray,
        R_ned_from_body: FloatArray,
        noise_dn: float = 2.5,
        rng: np.random.Generator | None = None,
    ) -> tuple[np.ndarray, dict[int, np.ndarray]]:
        """:meth:`render`'s image (the same bytes for the same ``rng``) and, per
        ``object_id``, the object's *visible* coverage (H, W) float32 in [0, 1]: the
        weight its colour has in each pixel after anti-aliasing and occlusion by the
        clutter and by nearer objects (absent from the dict: not in view)."""
        cov: dict[int, np.ndarray] = {}
        lin = self._render_flat(t_s, pos_ned_m, R_ned_from_body, coverage=cov)
        return self._to_bgr(lin, noise_dn, rng), cov

    def visible_coverage(
        self, t_s: float, pos_ned_m: FloatArray, R_ned_from_body: FloatArray
    ) -> dict[int, np.ndarray]:
        """Per ``object_id`` the visible coverage of :meth:`render_with_coverage`, without
        drawing the ground and the sky (about the cost of the objects and the clutter)."""
        cov: dict[int, np.ndarray] = {}
        self._render_flat(t_s, pos_ned_m, R_ned_from_body, coverage=cov, background=False)
        return cov

    def _to_bgr(
        self, lin: np.ndarray, noise_dn: float, rng: np.random.Generator | None
    ) -> np.ndarray:
        """Linear planar colour → display gamma 2 → 8 bits with sensor noise, BGR image."""
        out = lin.reshape(-1)
        np.clip(out, 0.0, 1.0, out=out)
        np.sqrt(out, out=out)
        out *= 255.0
        out += 0.5
        if noise_dn > 0:
            rng = rng if rng is not None else np.random.default_rng()
            n = out.shape[0]
            o1, o2 = (int(v) for v in rng.integers(0, self._noise_bank.shape[0] - n, 2))
            noise = self._noise_bank[o1 : o1 + n] + self._noise_bank[o2 : o2 + n]
            noise *= noise_dn / math.sqrt(2.0)
            out += noise
        np.clip(out, 0.0, 255.0, out=out)
        img = lin.astype(np.uint8)
        if self.layout.invalid_idx.size:
            img[:, self.layout.invalid_idx] = 0
        return self.layout.to_bgr_image(img)

    def render_linear(
        self, t_s: float, pos_ned_m: FloatArray, R_ned_from_body: FloatArray
    ) -> np.ndarray:
        """Noise-free linear RGB float32 (H, W, 3); black outside the camera's view."""
        lin = self._render_flat(t_s, pos_ned_m, R_ned_from_body)
        lin[:, ~self.layout.valid] = 0.0
        return self.layout.to_image(lin)

    def sphere_coverage(
        self,
        centre_ned_m: FloatArray,
        radius_m: float,
        pos_ned_m: FloatArray,
        R_ned_from_body: FloatArray,
    ) -> np.ndarray:
        """Anti-aliased coverage (H, W) in [0, 1] of a sphere, ignoring occlusion.

        The renderer's own formula: a ground-truth segmentation for tests and evaluation
        (Σ coverage × pixel solid angle is the disc's solid angle).
        """
        origin = np.asarray(pos_ned_m, dtype=np.float64)
        R = np.asarray(R_ned_from_body, dtype=np.float64) @ self.camera.R_body_from_cam
        B = R @ self.layout.bearing_cam.astype(np.float64)
        centre = np.asarray(centre_ned_m, np.float64).reshape(3, 1)
        alpha, _, _ = _sphere_terms(B, centre, np.array([radius_m]), origin, self.layout.pix_rad)
        alpha = np.where(self.layout.valid, alpha, 0.0).astype(np.float32)
        return self.layout.to_image(alpha)

    def object_coverage(
        self,
        obj: Target,
        t_s: float,
        pos_ned_m: FloatArray,
        R_ned_from_body: FloatArray,
    ) -> np.ndarray:
        """Anti-aliased coverage (H, W) in [0, 1] of any target at time ``t_s``, ignoring
        occlusion (the silhouette as the renderer draws it; :meth:`sphere_coverage` for a
        ball)."""
        centre = np.asarray(obj.centre_ned_m(t_s), np.float64)
        if isinstance(obj, Ball):
            return self.sphere_coverage(centre, obj.radius_m, pos_ned_m, R_ned_from_body)
        lay = self.layout
        origin = np.asarray(pos_ned_m, dtype=np.float64).reshape(3)
        R = np.asarray(R_ned_from_body, dtype=np.float64) @ self.camera.R_body_from_cam
        fr = FrameBuffers(
            origin=origin,
            B=R.astype(np.float32) @ lay.bearing_cam,
            tile_cones=lay.tile_cones(R),
            colour=np.zeros((3, lay.n), np.float32),
            depth=np.full(lay.n, np.inf, np.float32),
            ground=np.zeros(lay.n, bool),
            R_ned_from_cam=R,
        )
        alpha = np.zeros(lay.n, np.float32)
        drawn = self._draw_target(fr, centre, obj.R_ned_from_obj(t_s), obj)
        if drawn is not None:
            alpha[drawn[0]] = drawn[1]
        alpha[~lay.valid] = 0.0
        return lay.to_image(alpha)

    # ---------------------------------------------------------------------------------
    # Frame
    # ---------------------------------------------------------------------------------
    def _render_flat(
        self,
        t_s: float,
        pos_ned_m: FloatArray,
        R_ned_from_body: FloatArray,
        coverage: dict[int, np.ndarray] | None = None,
        background: bool = True,
    ) -> np.ndarray:
        """Planar linear colour (3, N). ``coverage``: filled with each object's visible
        coverage image; ``background=False`` skips the ground and the sky."""
        lay = self.layout
        origin = np.asarray(pos_ned_m, dtype=np.float64).reshape(3)
        R = np.asarray(R_ned_from_body, dtype=np.float64) @ self.camera.R_body_from_cam
        B = R.astype(np.float32) @ lay.bearing_cam
        height = -float(origin[2])
        if height > 1e-3:
            ground = lay.valid & (B[2] > height / _T_FAR_M)
        else:
            ground = np.zeros(lay.n, bool)
        fr = FrameBuffers(
            origin=origin,
            B=B,
            tile_cones=lay.tile_cones(R),
            colour=np.zeros((3, lay.n), np.float32),
            depth=np.full(lay.n, np.inf, np.float32),
            ground=ground,
            R_ned_from_cam=R,
        )
        balls = [(b.centre_ned_m(t_s), b) for b in self.world.balls]
        targets = [(tg.centre_ned_m(t_s), tg) for tg in self.world.targets]
        if background:
            self._draw_sky(fr, lay.valid & ~ground)
            self._draw_ground(fr, balls, targets, t_s)
        if self._clutter_radius.size:
            hit = self._tiles_hit(fr, self._clutter_centre, self._clutter_radius)
            nb, nc = len(self.world.buildings), self._cyl_radius.size
            for j, box in enumerate(self.world.buildings):
                self._draw_box(fr, box, hit[:, j])
            self._draw_cylinders(fr, hit[:, nb : nb + nc])
            self._draw_canopies(fr, hit[:, nb + nc :])
        objects: list[tuple[FloatArray, Target]] = [*balls, *targets]
        objects.sort(key=lambda cb: -float(np.linalg.norm(cb[0] - origin)))
        cov = np.zeros((len(objects), lay.n), np.float32) if coverage is not None else None
        for k, (centre, obj) in enumerate(objects):
            if isinstance(obj, Ball):
                drawn = self._draw_ball(fr, centre, obj)
            else:
                drawn = self._draw_target(fr, centre, obj.R_ned_from_obj(t_s), obj)
            if cov is not None and drawn is not None:
                ii, alpha = drawn
                a = alpha.astype(np.float32)
                cov[:k, ii] *= 1.0 - a  # what this object covers, the farther ones lose
                cov[k, ii] = a
        if coverage is not None and cov is not None:
            for k, (_, obj) in enumerate(objects):
                if np.any(cov[k] > 0):
                    cov[k, ~lay.valid] = 0.0
                    coverage[obj.object_id] = lay.to_image(cov[k])
        return fr.colour

    # ---------------------------------------------------------------------------------
    # Culling
    # ---------------------------------------------------------------------------------
    def _tiles_hit(self, fr: FrameBuffers, centres: FloatArray, radii: FloatArray) -> np.ndarray:
        """(T, K) bool: tile cone meets the bounding cone of sphere k (NED centre, radius)."""
        v = np.asarray(centres, np.float64).reshape(-1, 3) - fr.origin
        dist = np.linalg.norm(v, axis=1)
        inside = dist <= radii * 1.0001
        safe = np.where(inside, 1.0, dist)
        u = v / safe[:, None]
        sin_rho = np.clip(radii / safe, 0.0, 1.0)
        cos_rho = np.sqrt(1.0 - sin_rho * sin_rho)
        # cos(ρ + r) without a cosine on the (T, K) grid; ρ ≤ π/2 and tile radii are
        # small, so ρ + r < π where the cosine is monotonic. One product gives
        # u·axis - cos(ρ + r) for every pair (the cull is conservative by 1.5 pixels at
        # least, so its rounding decides nothing drawn).
        cone = np.empty((5, u.shape[0]))
        cone[:3] = u.T
        cone[3] = cos_rho
        cone[4] = sin_rho
        hit = (fr.tile_cones @ cone) >= 0.0
        hit[:, inside] = True
        return hit

    def _pairs(self, hit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(pixel, object) index pairs of every pixel in every tile an object may cover."""
        flat = np.flatnonzero(hit)  # row-major, as np.nonzero(hit) orders its pairs
        t, k = np.divmod(flat, hit.shape[1])
        t2 = self.layout.t2
        pix = (self.layout.tile_ids[t][:, None] * t2 + np.arange(t2)[None, :]).ravel()
        return pix, np.repeat(k, t2)

    def _sphere_pairs(
        self, fr: FrameBuffers, hit: np.ndarray, centres: FloatArray, radii: FloatArray
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_pairs` of ``hit`` (the spheres' tiles, :meth:`_tiles_hit`), less the pixels whose bearing is farther
        from a sphere's centre than its angular radius + half the largest pixel + 1 mrad
        (their coverage is 0: ``γ ≥ ρ + p/2``), in the same order. The test is a float32
        dot product on the tiles' bearings, 1 mrad conservative."""
        flat = np.flatnonzero(hit)
        if flat.size == 0:
            return flat, flat
        t, k = np.divmod(flat, hit.shape[1])
        v = centres - fr.origin
        dist = np.sqrt(np.sum(v * v, axis=1))
        inside = dist <= radii * 1.0001
        safe = np.where(inside, 1.0, dist)
        reach = np.arcsin(np.minimum(radii / safe, 1.0)) + (self._half_pix_max + 1e-3)
        cos_reach = np.where(inside | (reach >= math.pi), -2.0, np.cos(np.minimum(reach, math.pi)))
        u = (v / safe[:, None]).astype(np.float32)
        lay = self.layout
        t2 = lay.t2
        tiles = lay.tile_ids.take(t)
        bt = fr.B.reshape(3, -1, t2).take(tiles, axis=1)  # (3, P, t2)
        uk = u.take(k, axis=0)
        cosg = bt[0] * uk[:, 0:1]
        cosg += bt[1] * uk[:, 1:2]
        cosg += bt[2] * uk[:, 2:3]
        keep = np.flatnonzero(cosg >= cos_reach.astype(np.float32).take(k)[:, None])
        p, i = np.divmod(keep, t2)
        return tiles.take(p) * t2 + i, k.take(p)

    def _resolve(self, pix: np.ndarray, key: np.ndarray) -> np.ndarray:
        """Indices of the pairs with the smallest ``key`` for their pixel (one per pixel)."""
        scratch = self._scratch
        np.minimum.at(scratch, pix, key)
        win = np.nonzero(key <= scratch[pix])[0]
        scratch[pix] = np.inf
        # np.unique(pix[win], return_index=True) without its wrappers: a stable sort, the
        # first of each run of equal pixels (so the pairs come out by ascending pixel).
        pw = pix.take(win)
        perm = pw.argsort(kind="stable")
        aux = pw.take(perm)
        first = np.empty(aux.shape[0], bool)
        first[:1] = True
        np.not_equal(aux[1:], aux[:-1], out=first[1:])
        return win.take(perm.compress(first))

    # ---------------------------------------------------------------------------------
    # Ground and sky
    # ---------------------------------------------------------------------------------
    def _ground_hits(
        self, fr: FrameBuffers, g0: int, g1: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Range, north, east and footprint (all float32, metres) of the pixels ``g0:g1``
        (the span of the ground pixels). Pixels of the span that are not ground (the
        horizon band's sky, invalid pixels) get the values of a ray grazing the ground at
        ``_T_FAR_M``: finite, and never used."""
        B = fr.B
        bd = np.maximum(B[2, g0:g1], np.float32(-fr.origin[2] / _T_FAR_M))
        t = np.float32(-fr.origin[2]) / bd
        n = t * B[0, g0:g1]
        n += np.float32(fr.origin[0])
        e = t * B[1, g0:g1]
        e += np.float32(fr.origin[1])
        foot = t * self.layout.pix_rad[g0:g1]
        foot /= np.sqrt(bd)
        return t, n, e, foot

    def _sample_detail(self, n: np.ndarray, e: np.ndarray, foot_m: np.ndarray) -> np.ndarray:
        """Trilinear sample of the detail mip chain: (4, M) float32 (mult × 128, stone × 255)."""
        if n.shape[0] == 0:
            return np.zeros((4, 0), np.float32)
        tex = self.tex
        inv_texel = np.float32(1.0 / tex.detail_texel_m)
        period = np.float32(tex.detail_px)
        x0 = e * inv_texel
        y0 = n * -inv_texel
        for v in (x0, y0):
            wrap = v * (1.0 / period)
            np.floor(wrap, out=wrap)
            wrap *= period
            v -= wrap
        lam = foot_m * inv_texel
        np.maximum(lam, 1.0, out=lam)
        np.log2(lam, out=lam)
        np.clip(lam, 0.0, DETAIL_LEVELS - 1.001, out=lam)
        k = lam.astype(np.uint8)  # 0 .. DETAIL_LEVELS - 2
        # lam - k is exact in float32, so this equals the float64 weight it once was.
        w = lam
        w -= k
        levels = []
        for scale_lut, ox_lut, oy_lut in self._detail_luts:
            x, y = self._maps.coords(k.shape[0])
            scale = cv2.LUT(k, scale_lut).reshape(-1)
            np.multiply(x0, scale, out=x)
            x += cv2.LUT(k, ox_lut).reshape(-1)
            np.multiply(y0, scale, out=y)
            y += cv2.LUT(k, oy_lut).reshape(-1)
            levels.append(self._maps.sample(tex.detail_atlas, cv2.BORDER_REPLICATE))
        a = planes_f32(levels[0])
        b = planes_f32(levels[1])
        b -= a
        b *= w
        a += b
        return a

    def _ground_albedo(
        self, n: np.ndarray, e: np.ndarray, foot_m: np.ndarray, ground: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Linear albedo (3, M) of ground points and their static sunlit fraction (M,);
        ``ground`` (M,) marks the points that matter."""
        tex = self.tex
        on, oe = tex.macro_origin_ne_m
        t0, t1 = tex.macro_texels_m
        maps = self._maps
        mx0, my0 = maps.coords(n.shape[0])
        np.subtract(e, np.float32(oe), out=mx0)
        mx0 *= np.float32(1.0 / t0)
        mx0 -= 0.5
        np.subtract(np.float32(on), n, out=my0)
        my0 *= np.float32(1.0 / t0)
        my0 -= 0.5
        far = foot_m > t0
        far &= ground
        f0, f1 = span(far)
        if f0 < f1:
            # The coarse level where the footprint outgrows the fine texel: blended over
            # the span of those points (the others get weight 0: exactly unchanged).
            r = np.float32(t0 / t1)
            x1, y1 = self._maps_far.coords(f1 - f0)
            np.add(mx0[f0:f1], 0.5, out=x1)
            x1 *= r
            x1 -= 0.5
            np.add(my0[f0:f1], 0.5, out=y1)
            y1 *= r
            y1 -= 0.5
        macro = planes_f32(maps.sample(self.macro[0], cv2.BORDER_REPLICATE))
        if f0 < f1:
            m1 = planes_f32(self._maps_far.sample(self.macro[1], cv2.BORDER_REPLICATE))
            wm = foot_m[f0:f1] - t0
            wm *= 1.0 / (3.0 * t0)
            np.clip(wm, 0.0, 1.0, out=wm)
            for m0c, m1c in zip(macro, m1):
                m1c -= m0c[f0:f1]
                m1c *= wm
                m0c[f0:f1] += m1c
        lit = macro[3]
        lit *= np.float32(1.0 / 255.0)
        albedo = macro[:3]
        albedo *= np.float32(tex.macro_scale)
        det = self._sample_detail(n, e, foot_m)
        stone = det[3]
        stone *= np.float32(1.0 / 255.0)
        mix = self._stone_rgb - albedo
        mix *= stone
        albedo += mix
        albedo *= det[:3]
        albedo *= np.float32(1.0 / 128.0)
        return albedo, lit

    def _ground_under(
        self, fr: FrameBuffers, feet: list[tuple[FloatArray, float]]
    ) -> Iterator[tuple[int, np.ndarray]]:
        """``(k, pixels)`` for each shading object ``k`` whose shadow footprint ``feet[k]``
        (its ground point and reach, m: :func:`footprint`) falls on tiles with ground
        pixels: those pixels (flat indices, ascending). Objects shading no ground pixel are
        skipped."""
        hit = self._tiles_hit(fr, np.array([g for g, _ in feet]), np.array([r for _, r in feet]))
        for k in range(len(feet)):
            tiles = np.nonzero(hit[:, k])[0]
            if tiles.size == 0:
                continue
            idx = self.layout.pixels_of_tiles(tiles)
            idx = take(idx, np.nonzero(take(fr.ground, idx))[0])
            if idx.size:
                yield k, idx

    def _ball_shadows(
        self, fr: FrameBuffers, balls: list[tuple[FloatArray, Ball]], hits: GroundHits
    ) -> list[tuple[np.ndarray, np.ndarray]]:
        """Sunlit fraction left by each ball's shadow on the ground span, for the balls
        that shade a ground pixel: ``(loc, fraction)``, ``loc`` the pixels (ascending, from
        the span's start) :func:`_sunlit` multiplies."""
        shades: list[tuple[np.ndarray, np.ndarray]] = []
        if not balls:
            return shades
        g0, _, n_all, e_all, foot_all = hits
        feet = [footprint(c, b.radius_m, self._L) for c, b in balls]
        for k, idx in self._ground_under(fr, feet):
            centre, ball = balls[k]
            loc = idx - g0
            n, e, foot = take(n_all, loc), take(e_all, loc), take(foot_all, loc)
            cover = sphere_shadow(
                n.astype(np.float64), e.astype(np.float64), foot, centre, ball.radius_m, self._L
            )
            shades.append((loc, (1.0 - cover).astype(np.float32)))
        return shades

    def _draw_ground(
        self,
        fr: FrameBuffers,
        balls: list[tuple[FloatArray, Ball]],
        targets: list[tuple[FloatArray, SolidTarget]],
        t_s: float,
    ) -> None:
        """The ground, over the span of the ground pixels (tile-major order puts them
        nearly contiguous: below the horizon band), with the objects' shadows."""
        g0, g1 = span(fr.ground)
        if g0 >= g1:
            return
        gm = fr.ground[g0:g1]
        t, n, e, foot = self._ground_hits(fr, g0, g1)
        hits = (g0, g1, n, e, foot)
        ball_shades = self._ball_shadows(fr, balls, hits)
        target_shades = self._target_shadows(fr, targets, t_s, hits) if targets else []
        col, lit = self._ground_albedo(n, e, foot, gm)
        sun = self.world.sun
        if ball_shades or target_shades:
            apply_shades(lit, ball_shades, target_shades)
        lit *= np.float32(sun.irradiance * self._sin_sun)
        lit += np.float32(sun.ambient)
        col *= lit
        haze = t * np.float32(-1.0 / self.world.sky.haze_distance_m)
        np.exp(haze, out=haze)
        np.subtract(1.0, haze, out=haze)
        mix = self._haze_rgb - col
        mix *= haze
        col += mix
        copy_where(fr.colour[:, g0:g1], col, gm)
        copy_where(fr.depth[g0:g1], t, gm)
        if self.world.targets:
            fr.ground_t = np.full(self.layout.n, np.nan, np.float32)
            copy_where(fr.ground_t[g0:g1], t, gm)

    def _draw_sky(self, fr: FrameBuffers, sky_mask: np.ndarray) -> None:
        """The sky, written over the span of the sky pixels (the ground drawn after it
        overwrites the ground pixels of the horizon band)."""
        s0, s1 = span(sky_mask)
        if s0 >= s1:
            return
        sky, sun = self.world.sky, self.world.sun
        B = fr.B
        up = np.negative(B[2, s0:s1])
        s = np.clip(up, 0.0, 1.0)
        np.subtract(1.0, s, out=s)
        g = s * s
        g *= s
        np.subtract(1.0, g, out=g)
        col = fr.colour[:, s0:s1]
        np.multiply(self._zen_minus_hor, g, out=col)
        col += self._hor_rgb

        # Clouds on a flat layer (where up <= 0.03 the density is 0: exactly no change).
        upc = np.maximum(up, np.float32(0.03))
        k = np.float32(sky.cloud_height_m / self.sky_tex.cloud_texel_m) / upc
        size = np.float32(self.sky_tex.cloud.shape[0])
        x, y = self._maps.coords(s1 - s0)
        np.multiply(B[1, s0:s1], k, out=x)
        np.negative(k, out=k)
        np.multiply(B[0, s0:s1], k, out=y)
        for v in (x, y):
            wrap = v * (1.0 / size)
            np.floor(wrap, out=wrap)
            wrap *= size
            v -= wrap
            v -= 0.5
        c = cv2.transpose(self._maps.sample(self.sky_tex.cloud, cv2.BORDER_WRAP))  # (2, M)
        dens = smoothstep(0.03, 0.2, upc)
        dens *= c[0]
        cloud = self._cloud_rgb * c[1]
        cloud -= col
        cloud *= dens
        col += cloud

        # Sun disc and glow (the glow fades to zero 26° from the sun), on the sky pixels of
        # the tiles whose cones come within 0.45 rad of the sun (ascending, as before).
        # cos γ is the same matrix-vector product as ever, on those pixels' bearings: its
        # value for a column does not depend on the other columns, except for a product
        # with one column (numpy takes another path), so fewer than two fall back to all.
        cone = np.array([*self._L, math.cos(0.45), math.sin(0.45)])
        si = self.layout.pixels_of_tiles(np.flatnonzero(fr.tile_cones @ cone >= 0.0))
        si = si.compress(sky_mask.take(si))
        if si.size < 2:
            si = np.nonzero(sky_mask)[0]
        cosg = self._L32 @ take(B, si)
        near = np.nonzero(cosg > math.cos(0.45))[0]
        if near.size:
            gamma = np.arccos(np.clip(take(cosg, near), -1.0, 1.0))
            wide = np.maximum(1.0 - gamma * (1.0 / 0.45), 0.0)
            glow = 0.35 * np.exp(gamma * (-1.0 / 0.06)) + 0.15 * wide * wide
            rho = math.radians(sun.angular_radius_deg)
            pn = take(si, near)
            disc = np.clip((rho - gamma) / take(self.layout.pix_rad, pn) + 0.5, 0.0, 1.0)
            sun_rgb = np.array([1.0, 0.97, 0.9], np.float32)[:, None]
            loc = pn - s0
            put(col, loc, take(col, loc) + sun_rgb * (glow + 2.0 * disc))

        # Distant hills along the horizon.
        hl = np.nonzero((up < self._hill_top) & sky_mask[s0:s1])[0]
        if hl.size:
            bh = take(B[:, s0:s1], hl)
            az = np.arctan2(bh[1], bh[0])
            top = np.interp(az, self.sky_tex.hill_az_rad, self.sky_tex.hill_el_rad).astype(
                np.float32
            )
            el = np.arcsin(np.clip(take(up, hl), -1.0, 1.0))
            below = top - el
            cover = np.clip(below / self.layout.pix_rad[s0:s1][hl] + 0.5, 0.0, 1.0)
            shade = np.clip(1.0 - below * (1.0 / 0.05), 0.6, 1.0)
            hill = (
                np.asarray(sky.hill_rgb, np.float32)[:, None] * (0.6 * shade) + 0.4 * self._hor_rgb
            )
            cur = take(col, hl)
            put(col, hl, cur + (hill - cur) * cover)

    # ---------------------------------------------------------------------------------
    # Objects
    # ---------------------------------------------------------------------------------
    def _shade(self, albedo: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """(3, M) colour: Lambert sun + sky ambient (brighter from above) + grass bounce."""
        sun = self.world.sun
        L = self._L
        ndl = np.maximum(L[0] * normal[0] + L[1] * normal[1] + L[2] * normal[2], 0.0)
        up = -normal[2]
        amb = sun.ambient * (0.55 + 0.45 * up) + sun.ground_bounce * np.maximum(-up, 0.0)
        irr = (sun.irradiance * ndl + amb).astype(np.float32)
        return albedo * irr

    def _blend(
        self, fr: FrameBuffers, idx: np.ndarray, col: np.ndarray, alpha: np.ndarray, t: np.ndarray
    ) -> None:
        """Composite ``col`` over the buffer with coverage ``alpha``; solid pixels set depth."""
        cur = take(fr.colour, idx)
        cur += (col - cur) * alpha.astype(np.float32)
        put(fr.colour, idx, cur)
        solid = np.nonzero(alpha >= 0.5)[0]
        fr.depth[take(idx, solid)] = take(t, solid)

    def _draw_canopies(self, fr: FrameBuffers, hit: np.ndarray) -> None:
        """All tree canopies in one pass: per pixel the nearest covering sphere wins.
        ``hit`` (T, K): the tiles each canopy may cover (:meth:`_tiles_hit`)."""
        if self._sph_radius.size == 0:
            return
        pix, k = self._sphere_pairs(fr, hit, self._sph_centre, self._sph_radius)
        if pix.size == 0:
            return
        b = take(fr.B, pix).astype(np.float64)
        pw = take(self.layout.pix_rad, pix)
        centre = take(self._sph_centre.T, k)
        radius = take(self._sph_radius, k)
        alpha, th, tc = _sphere_terms(b, centre, radius, fr.origin, pw)
        ok = (alpha > 0) & (tc > 0) & (th < take(fr.depth, pix))
        sel = np.nonzero(ok)[0]
        if sel.size == 0:
            return
        pix, k, b, alpha, th = take_all(sel, pix, k, b, alpha, th)
        key = np.where(alpha >= 0.5, th, 1e9 - alpha)  # solid: nearest; else: most covering
        win = self._resolve(pix, key)
        pix, k, b, alpha, th = take_all(win, pix, k, b, alpha, th)
        hit = fr.origin[:, None] + th * b
        normal = (hit - take(self._sph_centre.T, k)) / take(self._sph_radius, k)
        albedo = take(self._sph_albedo, k)
        leafy = np.nonzero(take(self._sph_leafy, k))[0]
        if leafy.size:
            hl = take(hit, leafy)
            foot = (take(th, leafy) * take(self.layout.pix_rad, take(pix, leafy))).astype(
                np.float32
            )
            # Leaf clumps: the grass detail, stretched over the crown as a pseudo-3-D
            # pattern (fixed to the surface, so it moves with the tree in the image).
            pn = (hl[0] * 0.45 + hl[2] * 0.3).astype(np.float32)
            pe = (hl[1] * 0.45 - hl[2] * 0.25 + hl[0] * 0.1).astype(np.float32)
            det = self._sample_detail(pn, pe, foot * np.float32(0.45))
            lum = (det[0] + det[1] + det[2]) * np.float32(1.0 / 384.0)
            lum *= lum
            put(albedo, leafy, take(albedo, leafy) * (lum * lum))
        self._blend(fr, pix, self._shade(albedo, normal), alpha, th)

    def _draw_cylinders(self, fr: FrameBuffers, hit: np.ndarray) -> None:
        """Trunks and posts in one pass, anti-aliased across their width. ``hit`` (T, K):
        the tiles each may cover (:meth:`_tiles_hit` of their bounding spheres)."""
        if self._cyl_radius.size == 0:
            return
        pix, k = self._pairs(hit)
        if pix.size == 0:
            return
        b = take(fr.B, pix).astype(np.float64)
        o = fr.origin
        base = take(self._cyl_base, k)
        radius = take(self._cyl_radius, k)
        dn, de = o[0] - base[0], o[1] - base[1]
        a = np.maximum(b[0] * b[0] + b[1] * b[1], 1e-12)
        q = b[0] * dn + b[1] * de
        tc = -q / a  # ray parameter (= range, |b| = 1) of the closest approach to the axis
        perp2 = np.maximum(dn * dn + de * de - q * q / a, 0.0)
        alpha = np.clip(
            (radius - np.sqrt(perp2)) / (take(self.layout.pix_rad, pix) * np.maximum(tc, 1e-6))
            + 0.5,
            0.0,
            1.0,
        )
        th = tc - np.sqrt(np.maximum(radius * radius - perp2, 0.0) / a)
        d_hit = o[2] + th * b[2]
        ok = (
            (alpha > 0)
            & (tc > 0)
            & (d_hit <= 0.0)
            & (d_hit >= -take(self._cyl_height, k))
            & (th < take(fr.depth, pix))
        )
        sel = np.nonzero(ok)[0]
        if sel.size == 0:
            return
        pix, k, b, alpha, th = take_all(sel, pix, k, b, alpha, th)
        win = self._resolve(pix, np.where(alpha >= 0.5, th, 1e9 - alpha))
        pix, k, b, alpha, th = take_all(win, pix, k, b, alpha, th)
        base = take(self._cyl_base, k)
        hn = o[0] + th * b[0] - base[0]
        he = o[1] + th * b[1] - base[1]
        degenerate = np.hypot(hn, he) < 1e-9
        hn = np.where(degenerate, -b[0], hn)
        he = np.where(degenerate, -b[1], he)
        norm = np.maximum(np.hypot(hn, he), 1e-12)
        normal = np.stack([hn / norm, he / norm, np.zeros_like(hn)])
        self._blend(fr, pix, self._shade(take(self._cyl_albedo, k), normal), alpha, th)

    def _draw_box(self, fr: FrameBuffers, box: Box, hit_tiles: np.ndarray) -> None:
        """A building; ``hit_tiles`` (T,) the tiles its bounding sphere may cover."""
        lo3, hi3 = np.asarray(box.min_ned_m), np.asarray(box.max_ned_m)
        tiles = np.nonzero(hit_tiles)[0]
        if tiles.size == 0:
            return
        idx = self.layout.pixels_of_tiles(tiles)
        b = take(fr.B, idx).astype(np.float64)
        o = fr.origin[:, None]
        lo, hi = lo3[:, None], hi3[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / b
            t1 = (lo - o) * inv
            t2 = (hi - o) * inv
        tn = np.fmin(t1, t2)
        tnear = tn.max(axis=0)
        tfar = np.fmax(t1, t2).min(axis=0)
        ok = (tfar >= tnear) & (tnear > 0) & (tnear < take(fr.depth, idx))
        sel = np.nonzero(ok)[0]
        if sel.size == 0:
            return
        ii = take(idx, sel)
        th = take(tnear, sel)
        bb = take(b, sel)
        axis = take(tn, sel).argmax(axis=0)
        cols = np.arange(sel.size)
        normal = np.zeros((3, sel.size))
        normal[axis, cols] = -np.sign(bb[axis, cols])
        hit = o + th * bb
        roof = axis == 2
        along = np.where(axis == 0, hit[1] - lo[1], hit[0] - lo[0])
        height = -hit[2]
        frac = along / 1.6 - np.floor(along / 1.6)
        window = (~roof) & (height > 1.1) & (height < 2.2) & (frac > 0.3) & (frac < 0.7)
        wall = np.where(
            window,
            np.asarray(box.window_albedo_rgb)[:, None],
            np.asarray(box.wall_albedo_rgb)[:, None],
        )
        albedo = np.where(roof, np.asarray(box.roof_albedo_rgb)[:, None], wall)
        albedo = albedo * (0.9 + 0.1 * np.cos(height * 7.0 + along * 0.8))
        put(fr.colour, ii, self._shade(albedo, normal).astype(np.float32))
        fr.depth[ii] = th

    def _draw_ball(
        self, fr: FrameBuffers, centre: FloatArray, ball: Ball
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Draw a ball; returns the pixels it touched and their coverage (or None)."""
        hit_tiles = self._tiles_hit(fr, centre[None, :], np.array([ball.radius_m]))
        tiles = np.nonzero(hit_tiles[:, 0])[0]
        if tiles.size == 0 or np.linalg.norm(centre - fr.origin) <= ball.radius_m:
            return None
        idx = self.layout.pixels_of_tiles(tiles)
        b = take(fr.B, idx).astype(np.float64)
        alpha, th, tc = _sphere_terms(
            b,
            centre.reshape(3, 1),
            np.array([ball.radius_m]),
            fr.origin,
            take(self.layout.pix_rad, idx),
        )
        sel = np.nonzero((alpha > 0) & (tc > 0) & (th < take(fr.depth, idx)))[0]
        if sel.size == 0:
            return None
        ii, bb, th, alpha = take(idx, sel), take(b, sel), take(th, sel), take(alpha, sel)
        normal = (fr.origin[:, None] + th * bb - centre[:, None]) / ball.radius_m
        albedo = np.asarray(ball.albedo_rgb, np.float32)[:, None]
        col = self._shade(albedo, normal)
        half = self._L[:, None] - bb
        half /= np.sqrt(np.sum(half * half, axis=0))
        spec = np.clip(np.sum(normal * half, axis=0), 0.0, 1.0) ** 30
        col += (_BALL_SPECULAR * self.world.sun.irradiance * spec).astype(np.float32)
        self._blend(fr, ii, col, alpha, th)
        return ii, alpha

    def _draw_target(
        self, fr: FrameBuffers, centre: FloatArray, R_ned_from_obj: FloatArray, target: SolidTarget
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Draw a box, cylinder or disc; returns the pixels it touched and their coverage.

        Adaptive anti-aliasing: one ray per pixel first; a pixel whose ray hits (and passes
        the depth test) like all eight neighbours', on the same face, takes that ray's
        shading at full coverage; every pixel on a boundary (silhouette, occlusion, face
        edge) is resolved with 4 × 4 rays. Objects under three pixels thick get the 4 × 4
        rays everywhere (a sliver could pass between pixel centres).
        """
        rb = target.bounding_radius_m
        hit_tiles = self._tiles_hit(fr, centre[None, :], np.array([rb]))
        tiles = np.nonzero(hit_tiles[:, 0])[0]
        if tiles.size == 0:
            return None
        lay = self.layout
        idx = lay.pixels_of_tiles(tiles)
        v = centre - fr.origin
        dist = float(np.linalg.norm(v))
        thin = False
        if dist > rb * 1.0001:
            # Only pixels whose bearing is within the bounding cone (plus 1.5 pixels).
            pix = take(lay.pix_rad, idx)
            cos_b = np.clip((v / dist).astype(np.float32) @ take(fr.B, idx), -1.0, 1.0)
            keep = np.nonzero(np.arccos(cos_b) <= math.asin(rb / dist) + 1.5 * pix)[0]
            if keep.size == 0:
                return None
            idx = take(idx, keep)
            thin = min(target.size_m) / dist < 3.0 * float(take(pix, keep).max())
        depth = take(fr.depth, idx)
        if fr.ground_t is not None:
            # Where the ground is what the pixel shows, each ray meets it at its own range:
            # test against "above the ground" instead of the pixel centre's ground range.
            depth = np.where(depth == take(fr.ground_t, idx), np.float32(np.inf), depth)
        albedo = np.asarray(target.albedo_rgb, np.float32)[:, None]
        o_down = float(fr.origin[2])

        def visible(
            t_near: np.ndarray, t_far: np.ndarray, rays: np.ndarray, d: np.ndarray
        ) -> np.ndarray:
            """Rays that enter the target in front of the camera, before the depth buffer's
            range and above the ground."""
            return (
                (t_near <= t_far)
                & (t_near > 0)
                & (t_near < d)
                & (o_down + t_near * rays[2] <= 1e-9)
            )

        def shade(view: np.ndarray, normal: np.ndarray) -> np.ndarray:
            col = self._shade(albedo, normal)
            if target.specular > 0:
                half = self._L[:, None] - view
                half /= np.sqrt(np.sum(half * half, axis=0))
                spec = np.clip(np.sum(normal * half, axis=0), 0.0, 1.0) ** _SPECULAR_EXPONENT
                col += (target.specular * self.world.sun.irradiance * spec).astype(np.float32)
            return col

        parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        if thin:
            edge = np.arange(idx.size)
        else:
            b = take(fr.B, idx).astype(np.float64)
            t_near, t_far, normal = ray_target_ned(target, centre, R_ned_from_obj, fr.origin, b)
            hit = visible(t_near, t_far, b, depth)
            boundary = self._boundary(idx, hit, normal)
            inner = np.nonzero(hit & ~boundary)[0]
            if inner.size:
                col = shade(take(b, inner), take(normal, inner))
                parts.append((inner, col, np.ones(inner.size), take(t_near, inner)))
            edge = np.nonzero(boundary)[0]
        if edge.size:
            assert fr.R_ned_from_cam is not None
            du_cam, dv_cam = lay.pixel_axes_cam()
            R = fr.R_ned_from_cam
            pe = take(idx, edge)
            rays = (
                take(fr.B, pe).astype(np.float64)[:, :, None]
                + (R @ take(du_cam, pe).astype(np.float64))[:, :, None] * _SUB_U
                + (R @ take(dv_cam, pe).astype(np.float64))[:, :, None] * _SUB_V
            )
            rays /= np.sqrt(np.sum(rays * rays, axis=0))
            s = _SUB * _SUB
            flat = rays.reshape(3, edge.size * s)
            t_near, t_far, normal = ray_target_ned(target, centre, R_ned_from_obj, fr.origin, flat)
            hit = visible(t_near, t_far, flat, np.repeat(take(depth, edge), s))
            count = hit.reshape(edge.size, s).sum(axis=1)
            sel = np.nonzero(count > 0)[0]
            if sel.size:
                hi = np.nonzero(hit)[0]
                col = shade(take(flat, hi), take(normal, hi))
                owner = hi // s
                acc = np.stack(
                    [np.bincount(owner, weights=col[c], minlength=edge.size) for c in range(3)]
                )
                n_hit = take(count, sel)
                colour = (take(acc, sel) / n_hit).astype(np.float32)
                t_min = np.where(hit, t_near, np.inf).reshape(edge.size, s).min(axis=1)
                parts.append((take(edge, sel), colour, n_hit / float(s), take(t_min, sel)))
        if not parts:
            return None
        which = np.concatenate([p[0] for p in parts])
        colour = np.concatenate([p[1] for p in parts], axis=1).astype(np.float32)
        alpha = np.concatenate([p[2] for p in parts])
        t_hit = np.concatenate([p[3] for p in parts])
        ii = take(idx, which)
        self._blend(fr, ii, colour, alpha, t_hit)
        return ii, alpha

    def _boundary(self, idx: np.ndarray, hit: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """(M,) bool: pixels ``idx`` whose hit state differs from an 8-neighbour's, or
        whose surface normal does (a face edge). Works on the band of image rows the
        pixels span, plus a margin; columns wrap (the panorama's seam)."""
        rows, cols = take(self.layout.pixel_rc(), idx)
        r_off = int(rows.min()) - 1
        h = int(rows.max()) - r_off + 2
        w = self.layout.tiles_x * self.layout.tile_px
        r = rows - r_off
        hit_img = np.zeros((h, w), bool)
        hit_img[r, cols] = hit
        n_img = np.zeros((3, h, w), np.float32)
        n_img[:, r, cols] = np.where(hit, normal, 0.0)
        out = np.zeros((h, w), bool)
        for dy, dx in ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)):
            nb_hit = np.roll(hit_img, (dy, dx), axis=(0, 1))
            nb_n = np.roll(n_img, (dy, dx), axis=(1, 2))
            out |= hit_img != nb_hit
            out |= hit_img & nb_hit & (np.sum(n_img * nb_n, axis=0) < 0.9)
        return np.asarray(out[r, cols])

    def _target_shadows(
        self,
        fr: FrameBuffers,
        targets: list[tuple[FloatArray, SolidTarget]],
        t_s: float,
        hits: GroundHits,
    ) -> list[tuple[np.ndarray, np.ndarray]]:
        """Sunlit fraction left by the non-spherical targets' shadows on the ground span,
        as :meth:`_ball_shadows` gives the balls'.

        A convex solid's shadow on the ground is the convex hull of its points projected
        along the sun: a polygon; coverage is ``clip(-d / w + ½, 0, 1)`` with ``d`` the
        signed distance to the polygon (the largest over its edges), ``w`` the pixel's
        ground footprint or the sun's penumbra, whichever is wider.
        """
        g0, _, n_all, e_all, foot_all = hits
        shades: list[tuple[np.ndarray, np.ndarray]] = []
        L = self._L
        if L[2] > -1e-3:
            return shades
        feet = [footprint(c, tg.bounding_radius_m, L) for c, tg in targets]
        for k, idx in self._ground_under(fr, feet):
            centre, target = targets[k]
            pts = outline_points_ned(target, centre, target.R_ned_from_obj(t_s))
            ground_pts = pts[:, :2] - (pts[:, 2] / L[2])[:, None] * L[None, :2]
            hull = convex_hull_2d(ground_pts)
            loc = idx - g0
            n, e, foot = take(n_all, loc), take(e_all, loc), take(foot_all, loc)
            mid = hull.mean(axis=0)
            reach = float(np.hypot(*(hull - mid).T).max())
            rise = max(-float(centre[2]), 0.0) / -float(L[2])
            pen = max(rise * SUN_PENUMBRA, 1e-6)
            near = np.nonzero(np.hypot(n - mid[0], e - mid[1]) < reach + foot + pen)[0]
            if near.size == 0:
                continue
            loc, n, e, foot = take_all(near, loc, n, e, foot)
            a = hull
            bvec = np.roll(hull, -1, axis=0) - hull
            length = np.maximum(np.hypot(bvec[:, 0], bvec[:, 1]), 1e-12)
            out_n = np.stack([bvec[:, 1], -bvec[:, 0]], axis=1) / length[:, None]  # CCW hull
            d = (n.astype(np.float64)[:, None] - a[None, :, 0]) * out_n[None, :, 0] + (
                e.astype(np.float64)[:, None] - a[None, :, 1]
            ) * out_n[None, :, 1]
            dmax = d.max(axis=1)
            width = np.maximum(foot.astype(np.float64), pen)
            cover = np.clip(-dmax / width + 0.5, 0.0, 1.0)
            shades.append((loc, (1.0 - cover).astype(np.float32)))
        return shades


def _sphere_terms(
    b: np.ndarray, centre: np.ndarray, radius: np.ndarray, origin: FloatArray, pix: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coverage, hit range and closest-approach range of bearings ``b`` (3, M) on spheres.

    ``centre`` (3, M) or (3, 1) and ``radius`` (M,) or (1,) per bearing. Coverage is
    ``clip((ρ - γ)/p + ½)``; for grazing misses the hit range is the closest approach.
    A camera inside a sphere sees none of it.
    """
    oc = centre - origin[:, None]
    l2 = np.sum(oc * oc, axis=0)
    tc = np.sum(oc * b, axis=0)
    perp2 = np.maximum(l2 - tc * tc, 0.0)
    gamma = np.arctan2(np.sqrt(perp2), tc)
    rho = np.arcsin(np.minimum(radius / np.sqrt(l2), 1.0))
    alpha = np.clip((rho - gamma) / pix + 0.5, 0.0, 1.0)
    alpha = np.where(l2 > radius * radius, alpha, 0.0)
    th = tc - np.sqrt(np.maximum(radius * radius - perp2, 0.0))
    return alpha, th, tc
