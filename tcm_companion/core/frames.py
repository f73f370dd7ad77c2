"""Coordinate frames and rotations used everywhere in the core.

Frames (all right-handed, metres and radians unless a name says otherwise):

| name   | axes                              | what it is                                  |
|--------|-----------------------------------|---------------------------------------------|
| ned    | x north, y east, z down           | local-level world frame (MAVLink LOCAL_NED) |
| body   | x forward, y right, z down (FRD)  | the vehicle                                 |
| cam    | x optical axis, y right, z down   | "camera FRD" of the scenario format         |
| cv     | x right, y down, z optical axis   | OpenCV camera coordinates                   |

Rotation matrices are named ``R_a_from_b`` so that ``v_a = R_a_from_b @ v_b`` and
products read right to left: ``R_ned_from_cam = R_ned_from_body @ R_body_from_cam``.

Euler angles follow MAVLink: ZYX (yaw, then pitch, then roll) of the body relative to
NED, ``R_ned_from_body = Rz(yaw) @ Ry(pitch) @ Rx(roll)``. The camera mount uses the same
composition, ``R_body_from_cam = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

Quaternions here are scalar-first ``(w, x, y, z)`` like MAVLink (SciPy's are
scalar-last; the tests check these against SciPy).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: OpenCV camera axes expressed in camera FRD: v_cam = R_cam_from_cv @ v_cv.
R_CAM_FROM_CV: FloatArray = np.array(
    [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], dtype=np.float64
)
R_CV_FROM_CAM: FloatArray = R_CAM_FROM_CV.T.copy()


def rot_from_euler_zyx(roll_rad: float, pitch_rad: float, yaw_rad: float) -> FloatArray:
    """Return ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (3×3), MAVLink's Euler convention."""
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    cp, sp = np.cos(pitch_rad), np.sin(pitch_rad)
    cy, sy = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ],
        dtype=np.float64,
    )


def euler_zyx_from_rot(R_a_from_b: FloatArray) -> tuple[float, float, float]:
    """Inverse of :func:`rot_from_euler_zyx`: ``(roll_rad, pitch_rad, yaw_rad)``."""
    pitch = float(np.arcsin(np.clip(-R_a_from_b[2, 0], -1.0, 1.0)))
    roll = float(np.arctan2(R_a_from_b[2, 1], R_a_from_b[2, 2]))
    yaw = float(np.arctan2(R_a_from_b[1, 0], R_a_from_b[0, 0]))
    return roll, pitch, yaw


def mount_rotation(mount_rpy_deg: tuple[float, float, float] | list[float]) -> FloatArray:
    """``R_body_from_cam`` from the scenario's ``mount_rpy_deg = [roll, pitch, yaw]``."""
    r, p, y = np.deg2rad(np.asarray(mount_rpy_deg, dtype=np.float64))
    return rot_from_euler_zyx(float(r), float(p), float(y))


def vector_norm(v: FloatArray) -> float:
    """``float(np.linalg.norm(v))``, to the bit; for a 1-D float64 array (the per-frame
    case) computed as numpy does, ``sqrt(v·v)``, without the wrapper's checks."""
    if isinstance(v, np.ndarray) and v.ndim == 1 and v.dtype == np.float64:
        return math.sqrt(float(v.dot(v)))
    return float(np.linalg.norm(v))


def quat_wxyz_from_rot(R_a_from_b: FloatArray) -> FloatArray:
    """Scalar-first unit quaternion ``(w, x, y, z)``, ``w >= 0``, of a rotation matrix.

    Shepperd's method (the largest of the four candidates is computed first), in plain
    numpy because this runs for every attitude sample.
    """
    R = np.asarray(R_a_from_b, dtype=np.float64)
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    cands = (tr, R[0, 0], R[1, 1], R[2, 2])
    i = int(np.argmax(cands))
    if i == 0:
        w = 0.5 * math.sqrt(max(1.0 + tr, 0.0))
        f = 0.25 / w
        q = np.array([w, (R[2, 1] - R[1, 2]) * f, (R[0, 2] - R[2, 0]) * f, (R[1, 0] - R[0, 1]) * f])
    elif i == 1:
        x = 0.5 * math.sqrt(max(1.0 + R[0, 0] - R[1, 1] - R[2, 2], 0.0))
        f = 0.25 / x
        q = np.array([(R[2, 1] - R[1, 2]) * f, x, (R[0, 1] + R[1, 0]) * f, (R[0, 2] + R[2, 0]) * f])
    elif i == 2:
        y = 0.5 * math.sqrt(max(1.0 - R[0, 0] + R[1, 1] - R[2, 2], 0.0))
        f = 0.25 / y
        q = np.array([(R[0, 2] - R[2, 0]) * f, (R[0, 1] + R[1, 0]) * f, y, (R[1, 2] + R[2, 1]) * f])
    else:
        z = 0.5 * math.sqrt(max(1.0 - R[0, 0] - R[1, 1] + R[2, 2], 0.0))
        f = 0.25 / z
        q = np.array([(R[1, 0] - R[0, 1]) * f, (R[0, 2] + R[2, 0]) * f, (R[1, 2] + R[2, 1]) * f, z])
    q /= vector_norm(q)
    return q if q[0] >= 0 else -q


def rot_from_quat_wxyz(q_wxyz: FloatArray) -> FloatArray:
    """Rotation matrix of a scalar-first quaternion (normalised first; NaN if degenerate)."""
    q = np.asarray(q_wxyz, dtype=np.float64)
    norm = vector_norm(q)
    if not math.isfinite(norm) or norm < 1e-9:
        return np.full((3, 3), np.nan)
    w, x, y, z = q / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def slerp_quat(q0_wxyz: FloatArray, q1_wxyz: FloatArray, s: float) -> FloatArray:
    """Constant-rate interpolation of unit quaternions (extrapolates for s outside [0, 1])."""
    q0 = np.asarray(q0_wxyz, dtype=np.float64)
    q1 = np.asarray(q1_wxyz, dtype=np.float64)
    dot = float(q0 @ q1)
    if dot < 0.0:  # the short way round
        q1, dot = -q1, -dot
    dot = min(dot, 1.0)
    angle = math.acos(dot)
    if angle < 1e-9:
        q = q0 + s * (q1 - q0)
    else:
        sa = math.sin(angle)
        q = (math.sin((1.0 - s) * angle) / sa) * q0 + (math.sin(s * angle) / sa) * q1
    return np.asarray(q / vector_norm(q))


def slerp_rotation(R0: FloatArray, R1: FloatArray, s: float) -> FloatArray:
    """Spherical interpolation between two rotations, ``s`` in [0, 1] (extrapolates outside)."""
    return rot_from_quat_wxyz(slerp_quat(quat_wxyz_from_rot(R0), quat_wxyz_from_rot(R1), s))


def normalize(v: FloatArray) -> FloatArray:
    """Unit vectors along the last axis; zero vectors become NaN."""
    v = np.asarray(v, dtype=np.float64)
    # np.linalg.norm(v, axis=-1, keepdims=True) for real v, without its dispatch.
    n = np.sqrt(np.add.reduce(v * v, axis=-1, keepdims=True))
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / np.where(n > 0, n, np.nan)


def azel_from_bearing(bearing: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Azimuth and elevation (radians) of unit bearings in an FRD-like frame (N, E, D).

    Azimuth is clockwise from the x axis seen from above (towards y), elevation is
    positive up (towards -z). Accepts shape (3,) or (N, 3).
    """
    b = np.asarray(bearing, dtype=np.float64)
    az = np.arctan2(b[..., 1], b[..., 0])
    el = np.arctan2(-b[..., 2], np.hypot(b[..., 0], b[..., 1]))
    return az, el


def bearing_from_azel(az_rad: FloatArray, el_rad: FloatArray) -> FloatArray:
    """Unit bearing ``(cos el cos az, cos el sin az, -sin el)``; inverse of :func:`azel_from_bearing`."""
    az = np.asarray(az_rad, dtype=np.float64)
    el = np.asarray(el_rad, dtype=np.float64)
    ce = np.cos(el)
    return np.stack([ce * np.cos(az), ce * np.sin(az), -np.sin(el)], axis=-1)


def cross3(a: FloatArray, b: FloatArray) -> FloatArray:
    """Cross product over the last axis (length 3), broadcasting like ``np.cross``.

    Written out because ``np.cross`` spends tens of microseconds in axis bookkeeping,
    which dominates for the single vectors and small arrays of the per-frame path.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape == (3,) and b.shape == (3,):
        # One pair (the per-object path): the same products on Python floats.
        x0, x1, x2 = a.tolist()
        y0, y1, y2 = b.tolist()
        return np.array([x1 * y2 - x2 * y1, x2 * y0 - x0 * y2, x0 * y1 - x1 * y0])
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    # The three components written into one array (np.stack's bookkeeping costs more
    # than the arithmetic at the per-frame sizes).
    x = a1 * b2
    out = np.empty((*x.shape, 3))
    np.subtract(x, a2 * b1, out=out[..., 0])
    np.subtract(a2 * b0, a0 * b2, out=out[..., 1])
    np.subtract(a0 * b1, a1 * b0, out=out[..., 2])
    return out


def angle_between(a: FloatArray, b: FloatArray) -> FloatArray:
    """Angle (radians) between vectors along the last axis, stable near 0 and π."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    # np.linalg.norm(c, axis=-1) and np.sum(a * b, axis=-1) for real arrays are these
    # reductions; called directly, without the wrappers (a few calls per object-frame).
    c = cross3(a, b)
    cross = np.sqrt(np.add.reduce(c * c, axis=-1))
    dot = np.add.reduce(a * b, axis=-1)
    return np.arctan2(cross, dot)


def rotate_by_vector(v: FloatArray, rotvec: FloatArray) -> FloatArray:
    """``exp([ω]×) @ v`` (Rodrigues) for a rotation vector ``ω`` in radians."""
    w = np.asarray(rotvec, dtype=np.float64)
    theta = vector_norm(w)
    v = np.asarray(v, dtype=np.float64)
    if theta < 1e-15:
        return v
    k = w / theta
    return np.asarray(
        v * np.cos(theta)
        + cross3(k, v) * np.sin(theta)
        # np.outer(v @ k, k) is the product of each (v·k) with each k component
        + ((v @ k)[..., None] * k).reshape(v.shape) * (1 - np.cos(theta))
    )
