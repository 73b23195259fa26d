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
    """``q_nb`` (ENU from body) from one accelerometer and (optional) magnetometer vector.

    ``acc_b`` (3,) any unit, pointing up at rest; ``mag_b`` (3,) any unit.
    Without ``mag_b`` (or with a field parallel to gravity) the yaw is zero.
    Raises ``InputError`` for a zero accelerometer vector.
    """
    a = as_vec3(acc_b, "acc_b")
    na = np.linalg.norm(a)
    if na == 0.0:
        raise InputError("zero accelerometer vector: cannot find the vertical", field="accel")
    u = a / na
    if mag_b is not None:
        m = as_vec3(mag_b, "mag_b")
        e = np.cross(m, u)
        ne = np.linalg.norm(e)
        if ne > 1e-9 * max(np.linalg.norm(m), 1e-300):
            e = e / ne
            n = np.cross(u, e)
            return quat_from_dcm(np.stack([e, n, u]))
    roll = np.arctan2(u[1], u[2])
    pitch = np.arctan2(-u[0], np.hypot(u[1], u[2]))
    return quat_from_euler([roll, pitch, 0.0])


def initial_attitude(acc, mag=None, samples: int = 1) -> np.ndarray:
    """``q_nb`` from the mean of the first ``samples`` rows of ``acc`` (N, 3) and ``mag`` (N, 3)."""
    k = max(1, int(samples))
    a = np.mean(np.asarray(acc, float)[:k], axis=0)
    m = None if mag is None else np.mean(np.asarray(mag, float)[:k], axis=0)
    return attitude_from_acc_mag(a, m)
