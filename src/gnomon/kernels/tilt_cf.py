"""Compiled batch loop of the 3D tilt complementary filter (``gnomon.estimators.complementary``).

Readable twin: ``gnomon.estimators.complementary._tilt_step_py`` (tested sample by sample).
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True)
def _expq(rx, ry, rz):
    th = math.sqrt(rx * rx + ry * ry + rz * rz)
    if th < 1e-4:
        th2 = th * th
        k = 0.5 - th2 / 48.0 + th2 * th2 / 3840.0
    else:
        k = math.sin(0.5 * th) / th
    return math.cos(0.5 * th), k * rx, k * ry, k * rz


@njit(cache=True)
def _qmul(pw, px, py, pz, qw, qx, qy, qz):
    return (pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw)


@njit(cache=True)
def tilt_cf_step(q, b, dt, gx, gy, gz, ax, ay, az, T, r2, rej_rel, g):
    """One sample in place on ``q`` (4,) ``q_nb`` and ``b`` (3,); returns True if rejected."""
    dw, dx, dy, dz = _expq((gx - b[0]) * dt, (gy - b[1]) * dt, (gz - b[2]) * dt)
    w, x, y, z = _qmul(q[0], q[1], q[2], q[3], dw, dx, dy, dz)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    rejected = True
    nf = math.sqrt(ax * ax + ay * ay + az * az)
    if nf > 0.0 and not (rej_rel > 0.0 and abs(nf - g) > rej_rel * g):
        rejected = False
        mx, my, mz = ax / nf, ay / nf, az / nf
        ux = 2.0 * (x * z - w * y)
        uy = 2.0 * (y * z + w * x)
        uz = 1.0 - 2.0 * (x * x + y * y)
        cx = my * uz - mz * uy
        cy = mz * ux - mx * uz
        cz = mx * uy - my * ux
        s = math.sqrt(cx * cx + cy * cy + cz * cz)
        if s > 0.0:
            k = math.atan2(s, mx * ux + my * uy + mz * uz) / s
            ex, ey, ez = k * cx, k * cy, k * cz
            if r2 > 0.0:
                b[0] -= r2 * dt * ex
                b[1] -= r2 * dt * ey
                b[2] -= r2 * dt * ez
            f = dt / (T + dt)
            dw, dx, dy, dz = _expq(f * ex, f * ey, f * ez)
            w, x, y, z = _qmul(w, x, y, z, dw, dx, dy, dz)
            n = math.sqrt(w * w + x * x + y * y + z * z)
            w, x, y, z = w / n, x / n, y / n, z / n
    q[0], q[1], q[2], q[3] = w, x, y, z
    return rejected


@njit(cache=True)
def tilt_cf_run(t, gyro, accel, q0, b0, t_prev, T, r2, rej_rel, g, q_out, b_out, rej_out):
    """Whole recording: ``q_out`` (N, 4), ``b_out`` (N, 3), ``rej_out`` (N,) filled in place.

    A fresh filter (``t_prev`` NaN) outputs ``q0`` at sample 0; a continued one
    (``t_prev`` the time of its last sample) steps from ``q0``, ``b0`` to ``t[0]`` first.
    """
    n = t.shape[0]
    q = q0.copy()
    b = b0.copy()
    start = 0
    if math.isnan(t_prev):
        q_out[0, :] = q
        b_out[0, :] = b
        rej_out[0] = not (accel[0, 0] ** 2 + accel[0, 1] ** 2 + accel[0, 2] ** 2 > 0.0)
        start = 1
    for k in range(start, n):
        dt = t[k] - (t[k - 1] if k > 0 else t_prev)
        rej_out[k] = tilt_cf_step(q, b, dt, gyro[k, 0], gyro[k, 1], gyro[k, 2],
                                  accel[k, 0], accel[k, 1], accel[k, 2], T, r2, rej_rel, g)
        q_out[k, :] = q
        b_out[k, :] = b
