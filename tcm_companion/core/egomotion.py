"""Direction of the vehicle's translation between two frames, in the local-level NED frame.

TCM needs the unit translation ``T̂`` between frames ``n-k`` and ``n``. Three sources:

- **vision** (the paper's way): NED-aligned bearing pairs of static scenery points from
  :class:`tcm_companion.core.flow.FlowTracker`. After derotation with the autopilot
  attitude, a static point's bearings ``b0``, ``b1`` and ``T`` are coplanar, so
  ``m = b0 × b1`` satisfies ``T̂ · m = 0``. A two-point RANSAC (``T̂ = m_i × m_j``, all
  hypotheses scored at once) finds the inliers; a robust Gauss–Newton then refines
  ``T̂`` jointly with a small residual rotation ω: the attitude's error between the two
  frames acts exactly like a rotational flow and, left in, is the largest error of all
  (with the pipeline's live attitude, 3° at k = 25 and 13° at k = 5 without ω, 1° with
  it; tools/egomotion_study.py). When the residuals are large against the parallax, a
  second start from a global grid search is tried. Magnitude is unknown.
- **autopilot**: ``q1 - q0`` from LOCAL_POSITION_NED (or integrated velocity), with the
  metric magnitude; valid only for baselines long against the position noise.
- **fused**: inverse-variance mean when both agree, else the more certain one.

Each result carries its quality (inliers, translational parallax, angular uncertainty)
so the classifier can say ``unknown`` when the direction is noise (hover, turnarounds).

Angles of the vision estimate are relative to the attitude's NED frame: a constant
attitude bias rotates ``T̂`` with it, as it does the object bearings TCM compares
``T̂`` with.

Pure numpy, deterministic (seeded RNG), no IO.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .frames import FloatArray, cross3, vector_norm

try:  # np.einsum without optimize= is this C function behind a Python dispatch layer
    from numpy._core.multiarray import c_einsum as _einsum
except ImportError:  # pragma: no cover - another numpy layout
    _einsum = np.einsum

_SOLVE1: Any
try:  # the LAPACK gufunc behind np.linalg.solve (see _solve)
    from numpy.linalg import _umath_linalg

    _SOLVE1 = _umath_linalg.solve1
except (ImportError, AttributeError):  # pragma: no cover - another numpy layout
    _SOLVE1 = None

_NAN3 = np.full(3, np.nan)


@dataclass(frozen=True)
class TranslationEstimate:
    """Translation direction between two frames and how far to trust it.

    ``t_hat_ned``: (3,) unit vector in NED, NaN when unavailable. ``magnitude_m``: |T| in
    metres (NaN for vision). ``parallax_rad``: median over the inliers of the angle
    between matched bearings once the residual rotation is removed, i.e. the parallax due
    to translation (vision; NaN otherwise). ``sigma_rad``: 1-σ angular uncertainty of
    ``t_hat_ned`` (RMS over the two directions across it), including a systematic floor
    for vision. ``rotation_ned_rad``: (3,) rotation vector ω of the residual rotation
    estimated by vision: ``Rotation.from_rotvec(ω).apply(b1)`` (≈ ``b1 + ω × b1``)
    corrects a second-frame NED bearing for the attitude error between the two frames
    relative to the first (zeros when not estimated). The same correction applies to an
    object's bearing at the second frame.
    """

    t_hat_ned: FloatArray
    source: str
    magnitude_m: float
    parallax_rad: float
    inlier_ratio: float
    n_points: int
    sigma_rad: float
    valid: bool
    n_inliers: int = 0
    residual_rad: float = math.nan  # robust spread of inlier residuals (vision)
    rotation_ned_rad: FloatArray = field(default_factory=lambda: np.zeros(3))

    @staticmethod
    def invalid(source: str, n_points: int = 0) -> TranslationEstimate:
        return TranslationEstimate(
            t_hat_ned=_NAN3.copy(),
            source=source,
            magnitude_m=math.nan,
            parallax_rad=math.nan,
            inlier_ratio=0.0,
            n_points=n_points,
            sigma_rad=math.nan,
            valid=False,
        )


@dataclass(frozen=True)
class EgomotionConfig:
    """Parameters of the vision estimate and of the fusion.

    ``ransac_threshold_rad``: RANSAC residual threshold; wide, because the hypotheses
    ignore the residual rotation. ``inlier_threshold_rad``: the final inlier threshold the
    refinement anneals down to. Both are bearing errors in radians (the epipolar residual
    is normalised to be one). ``bearing_sigma_rad``: floor of the per-point
    bearing noise used for the uncertainty. ``systematic_rad``: bearing error shared by
    many points (flow drift, attitude interpolation, lens model), which adds
    ``systematic_rad / parallax`` to σ. ``rotation_prior_rad``: 1-σ prior of the residual
    rotation between the two frames (attitude error; the pipeline's live, extrapolated
    attitude shows ~0.8° per axis between frames); 0 disables its estimation.
    ``min_parallax_rad``: median translational parallax (rotation removed) below which
    the direction is not trusted — measured: between 0.7° and 0.9° a quarter of the
    estimates are off by more than 10°, between 0.9° and 1.15° a tenth, above 1.15° ≤ 1 %
    (tools/egomotion_study.py). ``restart_ratio``:
    residual spread / parallax above which a second, global start is tried.
    ``refine_iterations`` … ``max_refine_iterations``: Gauss–Newton steps, continuing past
    the minimum while a step exceeds ``step_tolerance_rad``.
    ``max_sigma_rad``: an estimate less certain than this is invalid.
    ``position_sigma_m``: noise of one autopilot position (LOCAL_POSITION_NED, as
    interpolated to frame times; measured ≈ 1.4 cm against truth).
    ``fuse_gate``: vision and autopilot directions agree if their angle is below this many
    combined σ.
    """

    n_hypotheses: int = 64
    ransac_threshold_rad: float = 0.025
    inlier_threshold_rad: float = 0.01
    bearing_sigma_rad: float = 0.002
    systematic_rad: float = 0.001
    min_parallax_rad: float = 0.02
    restart_ratio: float = 0.04
    min_inliers: int = 12
    min_inlier_ratio: float = 0.3
    rotation_prior_rad: float = 0.02
    refine_iterations: int = 3
    max_refine_iterations: int = 8
    step_tolerance_rad: float = 1e-3
    # A loose sanity bound: whether a direction is good enough depends on the object's
    # geometry, which the classifier judges (ClassifierConfig.max_disparity_sigma).
    max_sigma_rad: float = math.radians(15.0)
    position_sigma_m: float = 0.015
    fuse_gate: float = 3.0


def _unit(v: FloatArray) -> FloatArray:
    """Rows scaled to unit length (zero rows become NaN)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.asarray(v * (1.0 / np.sqrt(_einsum("ij,ij->i", v, v)))[:, None])


def _frame_across(t: FloatArray) -> FloatArray:
    """(3, 3) rows ``[T̂, e1, e2]``: unit ``t`` and two orthonormal vectors across it
    (scalar code: np.cross and np.stack on one vector cost tens of microseconds)."""
    tx, ty, tz = t.tolist()
    if abs(tx) < 0.9:  # e1 = t × x̂
        e1 = (0.0, tz, -ty)
    else:  # e1 = t × ŷ
        e1 = (-tz, 0.0, tx)
    k = 1.0 / math.sqrt(e1[0] ** 2 + e1[1] ** 2 + e1[2] ** 2)
    a, b, c = e1[0] * k, e1[1] * k, e1[2] * k
    return np.array([[tx, ty, tz], [a, b, c], [ty * c - tz * b, tz * a - tx * c, tx * b - ty * a]])


def translation_from_bearings(
    b0_ned: FloatArray,
    b1_ned: FloatArray,
    config: EgomotionConfig | None = None,
    rng_seed: int = 0,
) -> TranslationEstimate:
    """Translation direction from NED-aligned bearing pairs of (mostly) static points.

    ``b0_ned``, ``b1_ned``: (N, 3) unit bearings of the same points at the earlier and the
    later frame, already derotated with the attitude. Rows with NaN are ignored.
    Deterministic for a given ``rng_seed``.

    The residual rotation ``ω`` (attitude error between the two frames) enters
    linearised: ``b0 × (b1 + ω × b1) = m + (b0·b1) ω - (b0·ω) b1``, exact to O(|ω|²),
    i.e. ~1e-4 rad for a 1° error.
    """
    cfg = config or EgomotionConfig()
    b0 = np.asarray(b0_ned, np.float64).reshape(-1, 3)
    b1 = np.asarray(b1_ned, np.float64).reshape(-1, 3)
    if not math.isfinite(float(b0.sum() + b1.sum())):
        ok = np.isfinite(b0).all(axis=1) & np.isfinite(b1).all(axis=1)
        b0, b1 = b0[ok], b1[ok]
    b0, b1 = _unit(b0), _unit(b1)
    n = len(b0)
    if n < max(cfg.min_inliers, 2):
        return TranslationEstimate.invalid("vision", n)
    m = cross3(b0, b1)
    dot = _einsum("ij,ij->i", b0, b1)
    sin_par = np.sqrt(_einsum("ij,ij->i", m, m))

    t = _ransac(m, sin_par, cfg.ransac_threshold_rad, cfg, rng_seed)
    refined = None if t is None else _refine(t, b0, b1, m, dot, cfg)
    # When the rotation error is comparable with the parallax (short intervals), the
    # two-point hypotheses are poor and the refinement can settle in a wrong basin,
    # typically ~90° off, with residuals large against the parallax. Then a start from
    # the global grid search (rotation included) is refined too and the lower robust
    # cost wins.
    if refined is None or _suspicious(refined, cfg):
        lam = _prior_weight(cfg)
        alt = _refine(_grid_start(b0, b1, m, dot, lam), b0, b1, m, dot, cfg)
        if alt is not None and (refined is None or _cost(alt, cfg) < _cost(refined, cfg)):
            refined = alt
    if refined is None:
        return _weak("vision", n, np.arctan2(sin_par, dot))
    t, omega, info, q, inl, par_t = refined

    n_inl = int(np.count_nonzero(inl))
    # Static points move away from T̂: the angle to T̂ grows, so T̂·b falls. Judged on
    # b1 corrected for the residual rotation, which at short intervals can move the
    # bearings more than the translation does.
    # (b0 - (b1 + ω × b1))·T̂ = (b0 - b1)·T̂ - b1·(T̂ × ω)
    tx, ty, tz = (float(x) for x in t)
    wx, wy, wz = (float(x) for x in omega)
    t_cross_w = np.array([ty * wz - tz * wy, tz * wx - tx * wz, tx * wy - ty * wx])
    recede = (b0[inl] - b1[inl]) @ t - b1[inl] @ t_cross_w
    if np.count_nonzero(recede > 0) < np.count_nonzero(recede < 0):
        t = -t

    par_med = math.asin(min(_median_of_copy(par_t[inl]), 1.0))
    # Robust noise level of the residuals (MAD), floored by the configured bearing noise.
    spread = 1.4826 * math.sqrt(_median_of_copy(q[inl]))
    # The statistical σ assumes independent bearing errors; errors shared by many
    # points (flow drift, attitude interpolation, lens model) do not average out and
    # tilt T̂ by about (systematic error / parallax).
    sigma_stat = _sigma_from_info(info, max(spread, cfg.bearing_sigma_rad))
    sigma_t = math.hypot(sigma_stat, cfg.systematic_rad / max(par_med, 1e-9))
    ratio = n_inl / n
    valid = bool(
        n_inl >= cfg.min_inliers
        and ratio >= cfg.min_inlier_ratio
        and par_med >= cfg.min_parallax_rad
        and sigma_t <= cfg.max_sigma_rad
    )
    return TranslationEstimate(
        t_hat_ned=t,
        source="vision",
        magnitude_m=math.nan,
        parallax_rad=par_med,
        inlier_ratio=ratio,
        n_points=n,
        sigma_rad=sigma_t,
        valid=valid,
        n_inliers=n_inl,
        residual_rad=spread,
        rotation_ned_rad=omega,
    )


_Refined = tuple[FloatArray, FloatArray, FloatArray, FloatArray, np.ndarray, FloatArray]


def _prior_weight(cfg: EgomotionConfig) -> float:
    """``λ = σ_b²/σ_ω²``: the rotation prior in the units of the squared residuals."""
    if cfg.rotation_prior_rad <= 0.0:
        return 0.0
    return (cfg.bearing_sigma_rad / cfg.rotation_prior_rad) ** 2


def _cost(refined: _Refined, cfg: EgomotionConfig) -> float:
    """Truncated-quadratic cost of a solution, rotation prior included."""
    _, omega, _, q, _, _ = refined
    th2 = cfg.inlier_threshold_rad**2
    return float(np.minimum(q, th2).sum() + _prior_weight(cfg) * float(omega @ omega))


def _suspicious(refined: _Refined, cfg: EgomotionConfig) -> bool:
    """Residual spread large against the translational parallax: maybe a wrong basin."""
    _, _, _, q, inl, par_t = refined
    if np.count_nonzero(inl) < 3:
        return True
    spread = 1.4826 * math.sqrt(_median_of_copy(q[inl]))
    return spread > cfg.restart_ratio * _median_of_copy(par_t[inl])


def _hemisphere(n: int) -> FloatArray:
    """``n`` nearly uniform unit vectors with z ≥ 0 (Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    z = i / n
    r = np.sqrt(1.0 - z * z)
    phi = math.pi * (1.0 + math.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


_GRID = _hemisphere(200)  # ~10° apart; T̂ and -T̂ have the same cost
_GRID_OUTER = (_GRID[:, :, None] * _GRID[:, None, :]).reshape(len(_GRID), 9)


def _grid_start(
    b0: FloatArray, b1: FloatArray, m: FloatArray, dot: FloatArray, lam: float
) -> FloatArray:
    """Global start: the grid direction whose least-squares cost, ω optimised, is lowest.

    With ``Pᵢ = (b0·b1) I - b0 b1ᵀ`` the residual is ``T̂·mᵢ + ωᵀ Pᵢ T̂``, linear in ω,
    so for each candidate ``T̂`` the best ω solves a 3×3 system whose matrices are
    quadratic in ``T̂``: ``A(T̂) = Σ w Pᵢ T̂ T̂ᵀ Pᵢᵀ``, ``g(T̂) = Σ w Pᵢ T̂ (mᵢ·T̂)``. Their
    coefficients are summed over the points once (9×9 and 9×3), then every grid
    direction costs a few multiply-adds. Weights ``1/(|m|² + median |m|²)`` bound the
    influence of large-parallax outliers, which this least-squares cost cannot reject.
    """
    n = len(m)
    s2 = _einsum("ij,ij->i", m, m)
    w = 1.0 / (s2 + max(_median(s2), 1e-12))
    P = (dot[:, None, None] * np.eye(3) - b0[:, :, None] * b1[:, None, :]).reshape(n, 9)
    Pw = P * w[:, None]
    T4 = Pw.T @ P  # [(a, c), (b, d)]
    T3 = Pw.T @ m  # [(a, c), d]
    M2 = (m * w[:, None]).T @ m
    Y = T4.reshape(3, 3, 3, 3).transpose(0, 2, 1, 3).reshape(9, 9)  # [(a, b), (c, d)]
    k = len(_GRID)
    A = (_GRID_OUTER @ Y.T).reshape(k, 3, 3) + lam * np.eye(3)
    g = _GRID_OUTER @ T3.reshape(3, 9).T
    x = np.linalg.solve(A, g[:, :, None])[:, :, 0]
    cost = _GRID_OUTER @ M2.reshape(9) - _einsum("ka,ka->k", g, x)
    return np.asarray(_GRID[int(np.argmin(cost))])


def _refine(
    t: FloatArray,
    b0: FloatArray,
    b1: FloatArray,
    m: FloatArray,
    dot: FloatArray,
    cfg: EgomotionConfig,
) -> _Refined | None:
    """Robust Gauss–Newton on ``(T̂ on the sphere, ω)`` from a RANSAC hypothesis.

    Minimises ``Σ ρ(rᵢ) + λ|ω|²`` where ``rᵢ = T̂·m'ᵢ(ω) / gᵢ`` is the epipolar residual
    as a bearing error (``gᵢ = sqrt(sin²θ0 + sin²θ1)`` is its noise gain), ρ is Tukey's
    biweight, and ``λ = σ_b²/σ_ω²`` is the Gaussian prior on the residual rotation
    (``rotation_prior_rad = 0``: no rotation, ``T̂`` only).

    The RANSAC hypothesis ignores the rotation, so the inlier threshold starts wide and
    halves every step down to ``inlier_threshold_rad`` as ω is found. Within it the
    biweight's scale comes from the data (MAD): a hard cut-off lets a few 4–5σ outliers
    with large parallax (large leverage) pull T̂ by several σ. Outliers get zero weight
    rather than being gathered out, which is cheaper at these sizes.

    Returns ``(t, omega, info, r², inliers, translational parallax)``; ``info`` is the
    2×2 information of the two directions across ``T̂`` per unit bearing variance with ω
    marginalised out.
    """
    th = cfg.inlier_threshold_rad
    use_rot = cfg.rotation_prior_rad > 0.0
    lam = _prior_weight(cfg)
    n = len(m)
    # Component-major blocks [m | b1 | b0] as (3, 3N): one product with the frame
    # V = [T̂, e1, e2] gives T̂·m, the tangent Jacobian and T̂·b1, T̂·b0 for every point.
    # With the linearised rotation m' = m + (b0·b1) ω - (b0·ω) b1, so
    # V·m' = V·m + (V·ω) (b0·b1) - (V·b1) (b0·ω): nothing per point is rebuilt.
    blocks = np.empty((3, 3 * n))
    blocks[:, :n] = m.T
    blocks[:, n : 2 * n] = b1.T
    blocks[:, 2 * n :] = b0.T
    b0T = blocks[:, 2 * n :]
    omega = np.zeros(3)
    JT = np.empty((5 if use_rot else 2, n))
    A = np.zeros((2, 2))
    floor2 = (0.25 * cfg.bearing_sigma_rad) ** 2
    cut2 = floor2
    # At least refine_iterations steps (the threshold annealing), more while the steps
    # are still large: a start far off (large rotation error) needs a few more.
    n_min = max(cfg.refine_iterations, 1)
    n_iter = max(cfg.max_refine_iterations, n_min)
    lam_eye = lam * np.eye(3)
    dot_row = dot[None, :]
    # Per-step buffers (the same operations in the same order, written in place).
    P = np.empty((3, 3 * n))
    Vm = np.empty((3, n))
    tmp = np.empty((3, n))
    sq = np.empty(2 * n)
    g2 = np.empty(n)
    q = np.empty(n)
    w = np.empty(n)
    JwT = np.empty_like(JT)
    for it in range(n_iter + 1):
        V = _frame_across(t)
        np.matmul(V, blocks, out=P)
        Vb1 = P[:, n : 2 * n]
        c1 = Vb1[0]
        if use_rot:
            # Vm = V·m + (V·ω) (b0·b1) - (V·b1) (b0·ω), as in np.outer but without its checks.
            np.multiply((V @ omega)[:, None], dot_row, out=tmp)
            np.add(P[:, :n], tmp, out=Vm)
            np.multiply(Vb1, omega @ b0T, out=tmp)
            np.subtract(Vm, tmp, out=Vm)
        else:
            Vm[...] = P[:, :n]
        res = Vm[0]
        # gain² = max(2 - c0² - c1², 1e-12): c1 = T̂·b1 and c0 = T̂·b0 are P[0, n:] in a row.
        np.multiply(P[0, n:], P[0, n:], out=sq)
        np.subtract(2.0, sq[n:], out=g2)
        np.subtract(g2, sq[:n], out=g2)
        np.maximum(g2, 1e-12, out=g2)
        np.multiply(res, res, out=q)
        np.divide(q, g2, out=q)  # r²
        if it == n_iter:
            break
        if it < n_min:
            # The scale anneals during the first steps, then stays: a scale that keeps
            # moving makes the reweighting converge only linearly.
            th_it = max(th, cfg.ransac_threshold_rad * 0.5**it)
            inl = q < th_it * th_it
            if np.count_nonzero(inl) < 3:
                return None
            # cut = min(th_it, 4.685 · 1.4826 · median|r|), all squared.
            cut2 = min(th_it * th_it, max(_TUKEY_MAD2 * _median_of_copy(q[inl]), floor2))
        # w = (1 - min(r²/cut², 1))² / gain²
        np.multiply(q, 1.0 / cut2, out=w)
        np.minimum(w, 1.0, out=w)
        np.subtract(1.0, w, out=w)
        np.square(w, out=w)
        np.divide(w, g2, out=w)
        JT[:2] = Vm[1:]
        if use_rot:
            # d(T̂·m')/dω = b1 × (T̂ × b0) = (b0·b1) T̂ - (b1·T̂) b0
            np.multiply(t[:, None], dot_row, out=JT[2:])
            np.multiply(b0T, c1, out=tmp)
            np.subtract(JT[2:], tmp, out=JT[2:])
        np.multiply(JT, w, out=JwT)
        A = JwT @ JT.T
        g = JwT @ res
        if use_rot:
            A[2:, 2:] += lam_eye
            g[2:] += lam * omega
        try:
            step = _solve(A, -g)
        except np.linalg.LinAlgError:
            return None
        t = t + V[1:].T @ step[:2]
        t = t / math.sqrt(float(t @ t))
        if use_rot:
            omega = omega + step[2:]
        tol = cfg.step_tolerance_rad  # (all below it: np.max(np.abs(step)) < tol, NaN too)
        if it + 1 >= n_min and all(abs(x) < tol for x in step.tolist()):
            n_iter = it + 1  # one more pass for the residuals at the solution
    # The information of the last step's normal equations (weights one step old) is
    # accurate enough for an uncertainty.
    inl = q < th * th
    # Translational parallax: |b0 × (b1 corrected for ω)| = sin of the angle left once
    # the residual rotation is removed (the raw angle includes the rotation error).
    mc = m + dot[:, None] * omega - (b0 @ omega)[:, None] * b1 if use_rot else m
    par_t = np.sqrt(_einsum("ij,ij->i", mc, mc))
    return t, omega, _marginal_info(A), q, inl, par_t


def _median(x: FloatArray) -> float:
    """Upper median by partition (np.median costs several times more for small arrays)."""
    if not len(x):
        return math.nan
    k = len(x) // 2
    return float(np.partition(x, k)[k])


def _median_of_copy(x: np.ndarray) -> float:
    """:func:`_median` of an array the caller no longer needs (a fresh fancy-indexed
    copy): partitioned in place, the same value without a second copy."""
    if not len(x):
        return math.nan
    k = len(x) // 2
    x.partition(k)
    return float(x[k])


def _singular(err: object, flag: int) -> None:
    raise np.linalg.LinAlgError("Singular matrix")


def _solve(A: FloatArray, b: FloatArray) -> FloatArray:
    """``np.linalg.solve(A, b)`` for a float64 ``A`` (n, n) and ``b`` (n,): the same LAPACK
    call and the same singular-matrix error, without the wrapper's type and shape
    checks (three quarters of its cost at these sizes)."""
    if _SOLVE1 is None:  # pragma: no cover - another numpy layout
        return np.asarray(np.linalg.solve(A, b))
    with np.errstate(
        call=_singular, invalid="call", over="ignore", divide="ignore", under="ignore"
    ):
        return np.asarray(_SOLVE1(A, b, signature="dd->d"))


def _marginal_info(A: FloatArray) -> FloatArray:
    """Information of the two T̂ directions with the rotation block marginalised (Schur)."""
    if A.shape[0] == 2:
        return A
    try:
        return np.asarray(A[:2, :2] - A[:2, 2:] @ np.linalg.solve(A[2:, 2:], A[2:, :2]))
    except np.linalg.LinAlgError:
        return np.zeros((2, 2))


def _weak(source: str, n: int, parallax: FloatArray) -> TranslationEstimate:
    """No usable direction (degenerate sample, hover): invalid, with the parallax seen."""
    return TranslationEstimate(
        t_hat_ned=_NAN3.copy(),
        source=source,
        magnitude_m=math.nan,
        parallax_rad=_median(parallax),
        inlier_ratio=0.0,
        n_points=n,
        sigma_rad=math.nan,
        valid=False,
    )


_TUKEY_MAD2 = (4.685 * 1.4826) ** 2  # biweight constant (95 % efficiency) × MAD→σ, squared
_PREEMPT_POINTS = 96  # points every hypothesis is scored on first
_PREEMPT_KEEP = 12  # hypotheses then scored on all points


def _ransac(
    m: FloatArray, sin_par: FloatArray, threshold_rad: float, cfg: EgomotionConfig, rng_seed: int
) -> FloatArray | None:
    """Best two-point hypothesis by truncated-quadratic (MSAC) score, or None.

    Scored on the raw ``T̂·m``, whose noise is within a factor √2 of uniform except near
    the epipole, where points are uninformative anyway. Preemptive: all hypotheses on a
    spread subset of points, the best few on every point; float32 and small blocks,
    because (hypotheses × points) float64 temporaries cost more in allocation than in
    arithmetic.
    """
    n = len(m)
    # Points with parallax at the noise level have an epipolar plane of random
    # orientation: they may vote but must not propose.
    strong = (sin_par > 3.0 * cfg.bearing_sigma_rad).nonzero()[0]
    if strong.size < 2:
        return None
    rng = np.random.default_rng(rng_seed)
    h = cfg.n_hypotheses
    ij = strong[rng.integers(0, strong.size, 2 * h)]
    i, j = ij[:h], ij[h:]
    cand = cross3(m[i], m[j])
    norm = np.sqrt(_einsum("ij,ij->i", cand, cand))
    # Nearly parallel planes give an ill-conditioned intersection.
    good = norm > 0.05 * sin_par[i] * sin_par[j]
    if not good.any():
        return None
    cand = (cand[good] / norm[good, None]).astype(np.float32)
    th2 = np.float32(threshold_rad**2)
    mT = np.ascontiguousarray(m.T, dtype=np.float32)
    if n > _PREEMPT_POINTS and len(cand) > _PREEMPT_KEEP:
        stride = n // _PREEMPT_POINTS  # the tracker's slot order is spatially mixed
        cost = _msac_cost(cand, np.ascontiguousarray(mT[:, ::stride]), th2)
        keep = cost.argpartition(_PREEMPT_KEEP)[:_PREEMPT_KEEP]
        cand = cand[keep]
    cost = _msac_cost(cand, mT, th2)
    t = cand[int(cost.argmin())].astype(np.float64)
    return np.asarray(t / math.sqrt(float(t @ t)))


def _msac_cost(cand: np.ndarray, mT: np.ndarray, th2: np.float32) -> np.ndarray:
    r = cand @ mT
    np.multiply(r, r, out=r)
    np.minimum(r, th2, out=r)
    return np.asarray(r.sum(axis=1))


def _sigma_from_info(info: FloatArray, sigma_b: float) -> float:
    """RMS angular uncertainty of T̂ from its 2×2 information (per unit bearing variance)."""
    det = float(info[0, 0] * info[1, 1] - info[0, 1] * info[1, 0])
    if not det > 0.0:
        return math.inf
    # trace(inv(info)) = trace(info) / det for a 2×2 matrix.
    return math.sqrt(float(info[0, 0] + info[1, 1]) / det) * sigma_b


def translation_from_positions(
    pos0_ned_m: FloatArray,
    pos1_ned_m: FloatArray,
    config: EgomotionConfig | None = None,
    position_sigma_m: float | None = None,
) -> TranslationEstimate:
    """Translation ``pos1 - pos0`` from two autopilot positions (NED, metres).

    ``position_sigma_m`` (default from the config) is the noise of one position; the
    direction is valid when the baseline is at least three times the noise of the
    difference and the resulting σ is within ``max_sigma_rad``.
    """
    cfg = config or EgomotionConfig()
    sig = cfg.position_sigma_m if position_sigma_m is None else position_sigma_m
    p0 = np.asarray(pos0_ned_m, np.float64)
    p1 = np.asarray(pos1_ned_m, np.float64)
    return translation_from_vector(p1 - p0, math.sqrt(2.0) * sig, "autopilot", cfg.max_sigma_rad)


def translation_from_vector(
    T: FloatArray, noise_m: float, source: str, max_sigma_rad: float
) -> TranslationEstimate:
    """The estimate of a measured translation vector ``T`` (NED, metres) whose noise is
    ``noise_m`` (m, the σ of the measurement along each axis): its direction, valid when
    the baseline is at least three times the noise and the direction's σ (rad, across
    it) is within ``max_sigma_rad``. ``source`` names where ``T`` came from."""
    mag = vector_norm(T)
    if not math.isfinite(mag):
        return TranslationEstimate.invalid(source)
    t_hat = T / mag if mag > 0 else _NAN3.copy()
    # Noise across the direction over the baseline; RMS over the two transverse axes.
    sigma = math.atan2(math.sqrt(2.0) * noise_m, mag) if mag > 0 else math.pi
    return TranslationEstimate(
        t_hat_ned=t_hat,
        source=source,
        magnitude_m=mag,
        parallax_rad=math.nan,
        inlier_ratio=1.0,
        n_points=2,
        sigma_rad=sigma,
        valid=bool(mag > 3.0 * noise_m and sigma <= max_sigma_rad),
    )


def fuse(
    vision: TranslationEstimate,
    autopilot: TranslationEstimate,
    config: EgomotionConfig | None = None,
) -> TranslationEstimate:
    """Combine the vision and autopilot estimates.

    Both valid and within ``fuse_gate`` combined σ of each other: the inverse-variance
    weighted mean direction. Both valid but disagreeing: the one with the smaller σ
    (vision fails on a moving background, the autopilot on a position glitch; σ says
    which is likelier right). Only one valid: that one. Neither: invalid. The magnitude is
    the autopilot's when it has one.
    """
    cfg = config or EgomotionConfig()
    if not vision.valid and not autopilot.valid:
        # Keep what each saw of the motion: the classifier's hover test needs it.
        return replace(
            TranslationEstimate.invalid("fused", vision.n_points),
            parallax_rad=vision.parallax_rad,
            magnitude_m=autopilot.magnitude_m,
        )
    if not vision.valid:
        return autopilot
    if not autopilot.valid:
        return vision
    tv, ta = vision.t_hat_ned, autopilot.t_hat_ned
    sv, sa = max(vision.sigma_rad, 1e-9), max(autopilot.sigma_rad, 1e-9)
    angle = math.atan2(vector_norm(cross3(tv, ta)), float(tv @ ta))
    if angle > cfg.fuse_gate * math.hypot(sv, sa):
        return vision if sv < sa else autopilot
    wv, wa = 1.0 / sv**2, 1.0 / sa**2
    t = wv * tv + wa * ta
    t = t / vector_norm(t)
    return TranslationEstimate(
        t_hat_ned=t,
        source="fused",
        magnitude_m=autopilot.magnitude_m,
        parallax_rad=vision.parallax_rad,
        inlier_ratio=vision.inlier_ratio,
        n_points=vision.n_points,
        sigma_rad=1.0 / math.sqrt(wv + wa),
        valid=True,
        n_inliers=vision.n_inliers,
        residual_rad=vision.residual_rad,
        rotation_ned_rad=vision.rotation_ned_rad,
    )
