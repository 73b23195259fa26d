"""Rotation kernels: quaternions, direction-cosine matrices, Euler angles, rotation vectors.

Conventions (``docs/conventions`` / ``shared/spec/conventions.md``), used everywhere in gnomon:

* Hamilton algebra, scalar first: ``q = [w, x, y, z]`` with ``i*j = k``.
* ``q_ab`` ("a from b") maps coordinates of a vector in frame b to frame a:
  ``v_a = q_ab ⊗ [0, v_b] ⊗ conj(q_ab)``; ``R_ab`` is the same map as a matrix,
  ``v_a = R_ab @ v_b``. Composition: ``q_ac = q_ab ⊗ q_bc`` (``R_ac = R_ab @ R_bc``).
* Kinematics: ``dq_ab/dt = 0.5 * q_ab ⊗ [0, w_b]`` with ``w_b`` the rate of b
  relative to a, in b coordinates.
* Euler angles: aerospace sequence z-y'-x'' (yaw ψ, pitch θ, roll φ); arrays of
  Euler angles are ordered ``[roll, pitch, yaw]`` in radians, and
  ``R_ab = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

Every function vectorises over leading axes: a quaternion argument has shape
``(..., 4)``, a vector ``(..., 3)``, a matrix ``(..., 3, 3)``; a ``(4,)`` input
gives a ``(4,)`` output. Malformed input raises ``ValueError`` naming the argument.

Why hand-written rather than ``scipy.spatial.transform.Rotation``: scipy is
scalar-last, works on flat stacks only and validates on every call, which
costs more than the arithmetic in the filters' inner loops. These kernels are
plain numpy expressions (and the ``*_s`` scalar versions are numba-compilable);
the tests check them against scipy on 10,000+ random rotations.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "as_quat",
    "as_vec3",
    "quat_mul",
    "quat_conj",
    "quat_normalize",
    "quat_rotate",
    "quat_from_dcm",
    "dcm_from_quat",
    "quat_from_euler",
    "euler_from_quat",
    "quat_from_rotvec",
    "rotvec_from_quat",
    "quat_slerp",
    "error_angle",
    "quat_identity",
    "quat_positive",
    "skew",
]

_TWO_PI = 2.0 * np.pi


# ---------------------------------------------------------------- validation
def _as_array(x, name: str, last: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim < len(last) or a.shape[a.ndim - len(last):] != last:
        raise ValueError(
            f"{name}: expected shape (..., {', '.join(map(str, last))}), got {a.shape}"
        )
    if not np.all(np.isfinite(a)):
        idx = np.argwhere(~np.isfinite(a))[0]
        raise ValueError(f"{name}: non-finite value at index {tuple(int(i) for i in idx)}")
    return a


def as_quat(q, name: str = "q") -> np.ndarray:
    """Validate an array of quaternions: shape ``(..., 4)``, finite. Returns float array."""
    return _as_array(q, name, (4,))


def as_vec3(v, name: str = "v") -> np.ndarray:
    """Validate an array of 3-vectors: shape ``(..., 3)``, finite. Returns float array."""
    return _as_array(v, name, (3,))


def _as_dcm(m, name: str = "R") -> np.ndarray:
    return _as_array(m, name, (3, 3))


# ---------------------------------------------------------------- algebra
def quat_identity(shape: tuple[int, ...] = ()) -> np.ndarray:
    """Identity quaternion(s) ``[1, 0, 0, 0]`` of shape ``shape + (4,)``."""
    q = np.zeros(tuple(shape) + (4,))
    q[..., 0] = 1.0
    return q


def quat_mul(p, q) -> np.ndarray:
    """Hamilton product ``p ⊗ q`` (broadcast over leading axes).

    With ``p = q_ab`` and ``q = q_bc`` the result is ``q_ac``.
    """
    p = as_quat(p, "p")
    q = as_quat(q, "q")
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def quat_conj(q) -> np.ndarray:
    """Conjugate ``[w, -x, -y, -z]``; for a unit ``q_ab`` this is ``q_ba``."""
    q = as_quat(q)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_normalize(q) -> np.ndarray:
    """Unit quaternion(s) ``q / |q|``. A zero quaternion raises ``ValueError``."""
    q = as_quat(q)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n == 0.0):
        idx = np.argwhere(n[..., 0] == 0.0)[0]
        raise ValueError(f"q: zero-norm quaternion at index {tuple(int(i) for i in idx)}")
    return q / n


def quat_positive(q) -> np.ndarray:
    """Same rotation with ``w >= 0`` (canonical sign for display and comparison only)."""
    q = as_quat(q)
    return np.where(q[..., :1] < 0.0, -q, q)


def quat_rotate(q_ab, v_b) -> np.ndarray:
    """Rotate vectors: ``v_a = q_ab ⊗ [0, v_b] ⊗ conj(q_ab)``, shape ``(..., 3)``.

    ``q_ab`` need not be normalised exactly; it is used as given (unit expected).
    """
    q = as_quat(q_ab, "q_ab")
    v = as_vec3(v_b, "v_b")
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def skew(v) -> np.ndarray:
    """Cross-product matrix ``[v×]`` with ``skew(v) @ u == cross(v, u)``; shape ``(..., 3, 3)``."""
    v = as_vec3(v)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    o = np.zeros_like(x)
    return np.stack(
        [np.stack([o, -z, y], -1), np.stack([z, o, -x], -1), np.stack([-y, x, o], -1)], -2
    )


# ---------------------------------------------------------------- DCM
def dcm_from_quat(q_ab) -> np.ndarray:
    """Direction-cosine matrix ``R_ab`` (``v_a = R_ab @ v_b``), shape ``(..., 3, 3)``."""
    q = quat_normalize(as_quat(q_ab, "q_ab"))
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def quat_from_dcm(R_ab) -> np.ndarray:
    """Unit quaternion ``q_ab`` from a rotation matrix ``R_ab``, shape ``(..., 4)``.

    Shepperd's method: the largest of ``w², x², y², z²`` is computed from the
    diagonal and the others from off-diagonal sums, so the result is accurate
    near 180° as well as near the identity. The sign is chosen so that the
    largest component is positive.
    """
    m = _as_dcm(R_ab, "R_ab")
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    tr = m00 + m11 + m22
    # 4*[w², x², y², z²] candidates
    cand = np.stack([1 + tr, 1 + 2 * m00 - tr, 1 + 2 * m11 - tr, 1 + 2 * m22 - tr], -1)
    k = np.argmax(cand, axis=-1)
    s = 2.0 * np.sqrt(np.maximum(np.take_along_axis(cand, k[..., None], -1)[..., 0], 1e-300))
    d21 = m[..., 2, 1] - m[..., 1, 2]
    d02 = m[..., 0, 2] - m[..., 2, 0]
    d10 = m[..., 1, 0] - m[..., 0, 1]
    s21 = m[..., 2, 1] + m[..., 1, 2]
    s02 = m[..., 0, 2] + m[..., 2, 0]
    s10 = m[..., 1, 0] + m[..., 0, 1]
    q0 = np.stack([0.25 * s, d21 / s, d02 / s, d10 / s], -1)
    q1 = np.stack([d21 / s, 0.25 * s, s10 / s, s02 / s], -1)
    q2 = np.stack([d02 / s, s10 / s, 0.25 * s, s21 / s], -1)
    q3 = np.stack([d10 / s, s02 / s, s21 / s, 0.25 * s], -1)
    q = np.choose(k[..., None], [q0, q1, q2, q3])
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


# ---------------------------------------------------------------- Euler z-y'-x''
def quat_from_euler(rpy) -> np.ndarray:
    """Quaternion ``q_ab`` from Euler angles ``[roll, pitch, yaw]`` (rad), sequence z-y'-x''.

    ``R_ab = Rz(yaw) @ Ry(pitch) @ Rx(roll)``: for a body frame b and a
    navigation frame a this is the usual aerospace attitude.
    """
    a = as_vec3(rpy, "rpy")
    hr, hp, hy = 0.5 * a[..., 0], 0.5 * a[..., 1], 0.5 * a[..., 2]
    cr, sr = np.cos(hr), np.sin(hr)
    cp, sp = np.cos(hp), np.sin(hp)
    cy, sy = np.cos(hy), np.sin(hy)
    return np.stack(
        [
            cy * cp * cr + sy * sp * sr,
            cy * cp * sr - sy * sp * cr,
            cy * sp * cr + sy * cp * sr,
            sy * cp * cr - cy * sp * sr,
        ],
        -1,
    )


def euler_from_quat(q_ab) -> np.ndarray:
    """Euler angles ``[roll, pitch, yaw]`` (rad) of ``q_ab``, sequence z-y'-x''.

    Ranges: roll and yaw in (-π, π], pitch in [-π/2, π/2]. At gimbal lock
    (|pitch| = 90°) roll and yaw are not separable; roll is then set to 0.
    """
    q = quat_normalize(as_quat(q_ab, "q_ab"))
    w, x, y, z = np.moveaxis(q, -1, 0)
    sp = np.clip(2.0 * (w * y - x * z), -1.0, 1.0)
    pitch = np.arcsin(sp)
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    lock = np.abs(sp) > 1.0 - 1e-12
    if np.any(lock):
        yaw_lock = -2.0 * np.sign(sp) * np.arctan2(x, w)
        roll = np.where(lock, 0.0, roll)
        yaw = np.where(lock, np.angle(np.exp(1j * yaw_lock)), yaw)
    return np.stack([roll, pitch, yaw], -1)


# ---------------------------------------------------------------- rotation vector
def quat_from_rotvec(rv) -> np.ndarray:
    """Exponential map: rotation vector ``θ·u`` (rad) to unit quaternion ``[cos θ/2, sin θ/2 u]``.

    Uses a Taylor series of ``sin(θ/2)/θ`` for small ``θ``, exact to double precision.
    """
    v = as_vec3(rv, "rv")
    th = np.linalg.norm(v, axis=-1, keepdims=True)
    small = th < 1e-4
    th2 = th * th
    safe = np.where(small, 1.0, th)
    k = np.where(small, 0.5 - th2 / 48.0 + th2 * th2 / 3840.0, np.sin(0.5 * safe) / safe)
    return np.concatenate([np.cos(0.5 * th), k * v], -1)


def rotvec_from_quat(q) -> np.ndarray:
    """Logarithm map: unit quaternion to rotation vector (rad), angle in [0, π].

    Sign-safe: ``q`` and ``-q`` give the same rotation vector.
    """
    q = quat_normalize(as_quat(q))
    q = np.where(q[..., :1] < 0.0, -q, q)
    w = q[..., :1]
    u = q[..., 1:]
    s = np.linalg.norm(u, axis=-1, keepdims=True)
    th = 2.0 * np.arctan2(s, w)
    small = s < 1e-6
    safe = np.where(small, 1.0, s)
    # th/s for small s: 2/w * (1 + s²/(3 w²))
    k = np.where(small, 2.0 / w * (1.0 + s * s / (3.0 * w * w)), th / safe)
    return k * u


def quat_slerp(q0, q1, t) -> np.ndarray:
    """Spherical linear interpolation from ``q0`` (t=0) to ``q1`` (t=1) along the short arc.

    ``t`` broadcasts against the leading axes of the quaternions.
    """
    q0 = quat_normalize(as_quat(q0, "q0"))
    q1 = quat_normalize(as_quat(q1, "q1"))
    t = np.asarray(t, dtype=float)
    d = quat_mul(quat_conj(q0), q1)
    return quat_mul(q0, quat_from_rotvec(t[..., None] * rotvec_from_quat(d)))


# ---------------------------------------------------------------- error
def error_angle(q_true, q_est) -> np.ndarray:
    """Attitude error angle (rad, in [0, π]) between ``q_est`` and ``q_true`` (same frames).

    ``δq = conj(q_true) ⊗ q_est``, angle ``2·atan2(|δq_xyz|, |δq_w|)`` — sign-safe
    and accurate for small angles (no ``acos``).
    """
    d = quat_mul(quat_conj(as_quat(q_true, "q_true")), as_quat(q_est, "q_est"))
    return 2.0 * np.arctan2(np.linalg.norm(d[..., 1:], axis=-1), np.abs(d[..., 0]))
