"""Initial attitude of an IMU from resting samples: tilt from gravity, heading from the field.

Navigation frame ENU (x east, y north, z up); a resting accelerometer reads
``[0, 0, +g]`` in ENU, the Earth's field points north and (in the northern
hemisphere) down. TRIAD with the accelerometer as the exact direction:

    u_b = a / |a|                 (up, in body coordinates)
    e_b = (m × u_b) / |m × u_b|   (east: north × up)
    n_b = u_b × e_b               (north)
    R_nb = [e_b; n_b; u_b]        (rows: ENU axes in body coordinates)

Without a magnetometer the yaw (z-y'-x'' Euler angle) of the result is zero.
"""

from __future__ import annotations

import numpy as np

from gnomon.errors import InputError
from gnomon.rotation import as_vec3, quat_from_dcm, quat_from_euler

__all__ = ["attitude_from_acc_mag", "initial_attitude"]


def attitude_from_acc_mag(acc_b, mag_b=None) -> np.ndarray:
    """``q_nb`` (ENU from body) from accelerometer and (optional) magnetometer vectors.

    ``acc_b`` (..., 3) any unit, pointing up at rest; ``mag_b`` (..., 3) any unit.
    Returns (..., 4). Without ``mag_b`` (or where the field is parallel to
    gravity) the yaw is zero. Raises ``InputError`` for a zero accelerometer vector.
    """
    a = as_vec3(acc_b, "acc_b")
    na = np.linalg.norm(a, axis=-1, keepdims=True)
    if np.any(na == 0.0):
        raise InputError("zero accelerometer vector: cannot find the vertical", field="accel")
    u = a / na
    roll = np.arctan2(u[..., 1], u[..., 2])
    pitch = np.arctan2(-u[..., 0], np.hypot(u[..., 1], u[..., 2]))
    q_tilt = quat_from_euler(np.stack([roll, pitch, np.zeros_like(roll)], -1))
    if mag_b is None:
        return q_tilt
    m = as_vec3(mag_b, "mag_b")
    e = np.cross(m, u)
    ne = np.linalg.norm(e, axis=-1, keepdims=True)
    ok = ne > 1e-9 * np.maximum(np.linalg.norm(m, axis=-1, keepdims=True), 1e-300)
    e = e / np.where(ok, ne, 1.0)
    n = np.cross(u, e)
    q_full = quat_from_dcm(np.stack([e, n, u], axis=-2))
    return np.where(ok, q_full, q_tilt)


def initial_attitude(acc, mag=None, samples: int = 1) -> np.ndarray:
    """``q_nb`` from the mean of the first ``samples`` usable rows of ``acc`` and ``mag`` (N, 3).

    Rows with a zero or non-finite vector are skipped (a sensor that starts with a
    dropout); with no usable accelerometer row at all the identity is returned,
    and without a usable magnetometer row the yaw is zero.
    """
    k = max(1, int(samples))
    acc = np.asarray(acc, float)
    mag = None if mag is None else np.asarray(mag, float)
    rows = _first_usable(acc, k)
    if rows.size == 0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    a = np.mean(acc[rows], axis=0)
    m = None
    if mag is not None:
        mrows = _first_usable(mag, k)
        if mrows.size:
            m = np.mean(mag[mrows], axis=0)
    return attitude_from_acc_mag(a, m)


def _first_usable(v: np.ndarray, k: int) -> np.ndarray:
    """Indices of the first ``k`` rows of ``v`` (N, 3) that are finite and non-zero.

    Looks at a growing prefix, so a long recording costs no more than its start.
    """
    stop = max(4 * k, 256)
    while True:
        head = v[:stop]
        ok = np.all(np.isfinite(head), axis=1) & (np.linalg.norm(head, axis=1) > 0)
        rows = np.flatnonzero(ok)[:k]
        if rows.size == k or stop >= len(v):
            return rows
        stop *= 8
