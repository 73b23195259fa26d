"""Compiled batch loop of the 9-axis explicit complementary filter.

Twin of ``gnomon.estimators.mahony.Mahony.update`` (tested sample by sample).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, fastmath=False)
def mahony_step(q, b, dt, gx, gy, gz, ax, ay, az, mx, my, mz,
                kp_acc, kp_mag, ki, heading_only, max_dt):
    """One sample in place on ``q`` (4,) ``q_nb`` and ``b`` (3,) bias.

    Returns flags as bits: 1 accelerometer skipped, 2 magnetometer skipped, 4 gap.
    """
    flags = 0
    if dt <= 0.0:
        return flags
    _rotate_by(q, (gx - b[0]) * dt, (gy - b[1]) * dt, (gz - b[2]) * dt)
    if dt > max_dt:
        return 4
    w, x, y, z = q[0], q[1], q[2], q[3]
    # up direction in body: R_nb^T [0,0,1] (third row of R_nb)
    ux = 2.0 * (x * z - w * y)
    uy = 2.0 * (y * z + w * x)
    uz = 1.0 - 2.0 * (x * x + y * y)
    ex = 0.0
    ey = 0.0
    ez = 0.0
    na = math.sqrt(ax * ax + ay * ay + az * az)
    if na > 0.0:
        ax /= na
        ay /= na
        az /= na
        ex = ay * uz - az * uy
        ey = az * ux - ax * uz
        ez = ax * uy - ay * ux
    else:
        flags |= 1
    fx = 0.0
    fy = 0.0
    fz = 0.0
    nm = math.sqrt(mx * mx + my * my + mz * mz)
    if nm > 0.0:
        mx /= nm
        my /= nm
        mz /= nm
        # h = R_nb m
        hx = (1.0 - 2.0 * (y * y + z * z)) * mx + 2.0 * (x * y - w * z) * my \
            + 2.0 * (x * z + w * y) * mz
        hy = 2.0 * (x * y + w * z) * mx + (1.0 - 2.0 * (x * x + z * z)) * my \
            + 2.0 * (y * z - w * x) * mz
        hz = 2.0 * (x * z - w * y) * mx + 2.0 * (y * z + w * x) * my \
            + (1.0 - 2.0 * (x * x + y * y)) * mz
        rn = math.sqrt(hx * hx + hy * hy)
        # predicted magnetic direction in body: R_nb^T [0, rn, hz]
        vx = 2.0 * (x * y + w * z) * rn + 2.0 * (x * z - w * y) * hz
        vy = (1.0 - 2.0 * (x * x + z * z)) * rn + 2.0 * (y * z + w * x) * hz
        vz = 2.0 * (y * z - w * x) * rn + (1.0 - 2.0 * (x * x + y * y)) * hz
        fx = my * vz - mz * vy
        fy = mz * vx - mx * vz
        fz = mx * vy - my * vx
        if heading_only:
            d = fx * ux + fy * uy + fz * uz
            fx = d * ux
            fy = d * uy
            fz = d * uz
    else:
        flags |= 2
    b[0] -= ki * (ex + fx) * dt
    b[1] -= ki * (ey + fy) * dt
    b[2] -= ki * (ez + fz) * dt
    _rotate_by(q, (kp_acc * ex + kp_mag * fx) * dt, (kp_acc * ey + kp_mag * fy) * dt,
               (kp_acc * ez + kp_mag * fz) * dt)
    return flags


@njit(cache=True)
def _rotate_by(q, rx, ry, rz):
    """``q <- normalise(q ⊗ exp([rx, ry, rz]))`` in place (rotation vector in rad)."""
    th2 = rx * rx + ry * ry + rz * rz
    if th2 < 0.0025:
        # |r| < 0.05 rad: Taylor series of cos(θ/2) and sin(θ/2)/θ to θ⁸; the first omitted
        # terms are below 1e-22, so this equals the trigonometric form to double precision
        dw = 1.0 - th2 * (1.0 / 8.0 - th2 * (1.0 / 384.0 - th2 * (1.0 / 46080.0
                                                               - th2 / 10321920.0)))
        k = 0.5 - th2 * (1.0 / 48.0 - th2 * (1.0 / 3840.0 - th2 * (1.0 / 645120.0
                                                              - th2 / 185794560.0)))
    else:
        th = math.sqrt(th2)
        dw = math.cos(0.5 * th)
        k = math.sin(0.5 * th) / th
    dx = k * rx
    dy = k * ry
    dz = k * rz
    w, x, y, z = q[0], q[1], q[2], q[3]
    nw = w * dw - x * dx - y * dy - z * dz
    nx = w * dx + x * dw + y * dz - z * dy
    ny = w * dy - x * dz + y * dw + z * dx
    nz = w * dz + x * dy - y * dx + z * dw
    s = 1.0 / math.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
    q[0] = nw * s
    q[1] = nx * s
    q[2] = ny * s
    q[3] = nz * s


@njit(cache=True)
def mahony_batch(dt, gyro, acc, mag, q, b, kp_acc, kp_mag, ki, heading_only, max_dt,
                 q_out, b_out, flags):
    """Run N samples: ``dt`` (N,) s (dt[0] = 0 keeps the initial state), sensors (N, 3).

    ``q`` (4,) and ``b`` (3,) are the state, updated in place; outputs (N, 4), (N, 3), (N, 3).
    """
    n = dt.shape[0]
    for i in range(n):
        f = mahony_step(q, b, dt[i], gyro[i, 0], gyro[i, 1], gyro[i, 2], acc[i, 0], acc[i, 1],
                        acc[i, 2], mag[i, 0], mag[i, 1], mag[i, 2], kp_acc, kp_mag, ki,
                        heading_only, max_dt)
        flags[i, 0] = (f & 1) != 0
        flags[i, 1] = (f & 2) != 0
        flags[i, 2] = (f & 4) != 0
        q_out[i, 0] = q[0]
        q_out[i, 1] = q[1]
        q_out[i, 2] = q[2]
        q_out[i, 3] = q[3]
        b_out[i, 0] = b[0]
        b_out[i, 1] = b[1]
        b_out[i, 2] = b[2]


@njit(cache=True)
def mahony_batch_runs(dt, gyro, acc, mag, q, b, kp_acc, kp_mag, ki, heading_only, max_dt,
                      q_out):
    """R independent filters over N samples, run-minor layout for SIMD over runs.

    ``dt`` (N,) s shared by the runs; ``gyro``, ``acc``, ``mag`` (N, 3, R); state ``q`` (4, R),
    ``b`` (3, R) updated in place; ``q_out`` (N, 4, R). Each run follows exactly the
    same arithmetic as ``mahony_step`` (flags are not recorded here).
    """
    n = dt.shape[0]
    r_count = q.shape[1]
    qq = np.empty(4)
    bb = np.empty(3)
    for i in range(n):
        for r in range(r_count):
            qq[0] = q[0, r]
            qq[1] = q[1, r]
            qq[2] = q[2, r]
            qq[3] = q[3, r]
            bb[0] = b[0, r]
            bb[1] = b[1, r]
            bb[2] = b[2, r]
            mahony_step(qq, bb, dt[i], gyro[i, 0, r], gyro[i, 1, r], gyro[i, 2, r],
                        acc[i, 0, r], acc[i, 1, r], acc[i, 2, r], mag[i, 0, r], mag[i, 1, r],
                        mag[i, 2, r], kp_acc, kp_mag, ki, heading_only, max_dt)
            q[0, r] = qq[0]
            q[1, r] = qq[1]
            q[2, r] = qq[2]
            q[3, r] = qq[3]
            b[0, r] = bb[0]
            b[1, r] = bb[1]
            b[2, r] = bb[2]
            q_out[i, 0, r] = qq[0]
            q_out[i, 1, r] = qq[1]
            q_out[i, 2, r] = qq[2]
            q_out[i, 3, r] = qq[3]
