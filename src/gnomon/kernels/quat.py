"""Scalar quaternion kernels shared by the compiled filters (numba, inlined).

``dcm`` gives the rotation matrix entries of ``q``. ``exp_mul`` is the one place where a
filter turns ``q`` by a rotation vector:
``q ⊗ exp(r)``, with a Taylor series for |r| < 0.05 rad that equals the
trigonometric form to double precision (so the batch-over-runs loops can use
it without branches, see ``gnomon.kernels.mahony``).
"""

from __future__ import annotations

import math

from numba import njit

SMALL_TH2 = 0.0025  # (0.05 rad)²: below it the Taylor form equals the trigonometric one


@njit(inline="always", error_model="numpy")
def exp_mul(w, x, y, z, rx, ry, rz, trig, normalise):
    """``q ⊗ exp(r)`` (normalised if asked), and whether |r| >= 0.05 rad.

    ``q = [w, x, y, z]``, ``r`` a rotation vector (rad) in q's body frame. ``trig``: use the
    exact trigonometric form for |r| >= 0.05 rad (else the Taylor form everywhere, for
    branch-free vector loops that redo the large rotations). The product of two unit
    quaternions is unit to rounding: normalising once per filter step is enough.
    """
    th2 = rx * rx + ry * ry + rz * rz
    big = th2 >= SMALL_TH2
    if trig and big:
        th = math.sqrt(th2)
        dw = math.cos(0.5 * th)
        k = math.sin(0.5 * th) / th
    else:
        # Taylor series of cos(θ/2) and sin(θ/2)/θ to θ⁸: the first omitted terms are
        # below 1e-22 for θ < 0.05 rad
        dw = 1.0 - th2 * (1.0 / 8.0 - th2 * (1.0 / 384.0 - th2 * (1.0 / 46080.0
                                                               - th2 / 10321920.0)))
        k = 0.5 - th2 * (1.0 / 48.0 - th2 * (1.0 / 3840.0 - th2 * (1.0 / 645120.0
                                                              - th2 / 185794560.0)))
    dx = k * rx
    dy = k * ry
    dz = k * rz
    nw = w * dw - x * dx - y * dy - z * dz
    nx = w * dx + x * dw + y * dz - z * dy
    ny = w * dy - x * dz + y * dw + z * dx
    nz = w * dz + x * dy - y * dx + z * dw
    if not normalise:
        return nw, nx, ny, nz, big
    s = 1.0 / math.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
    return nw * s, nx * s, ny * s, nz * s, big


@njit(inline="always", error_model="numpy")
def rotate_by(q, rx, ry, rz):
    """``q <- normalise(q ⊗ exp([rx, ry, rz]))`` in place on the array ``q`` (4,)."""
    q[0], q[1], q[2], q[3], _ = exp_mul(q[0], q[1], q[2], q[3], rx, ry, rz, True, True)


@njit(inline="always")
def dcm(w, x, y, z):
    """The nine entries ``c00, c01, ..., c22`` of ``R(q)`` (row-major) for a unit ``q``."""
    return (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
            2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
            2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))
