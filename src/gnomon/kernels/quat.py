"""Quaternion kernels shared by the compiled filters and simulators (numba): the one
place where a kernel multiplies, rotates, exponentiates or normalises a quaternion.

Conventions (``docs/conventions.md``): Hamilton, scalar first ``[w, x, y, z]``;
``R(q)`` is the matrix with ``R(q) v = q ⊗ [0, v] ⊗ q*``, so for ``q = q_ab`` it maps
b-coordinates to a-coordinates (``rotate``) and ``R(q)ᵀ`` maps back (``rotate_inv``).

Scalar helpers take and return plain floats (tuples), are inlined into the filters'
loops and keep the state in registers: ``mul``, ``normalised``, ``exp``, ``rotate``,
``rotate_inv``, ``dcm``. ``mul_arr`` / ``rotate_arr`` / ``rotate_inv_arr`` are their array
forms for the matrix-style kernels (EKFs). ``exp_mul`` is the one place where a filter
turns ``q`` by a rotation vector: ``q ⊗ exp(r)``, with a Taylor series for
|r| < 0.05 rad that equals the trigonometric form to double precision and a
normalisation by one Newton step (so the batch-over-runs loops can use them without branches, see
``gnomon.kernels.mahony``, and a single filter stream has no sqrt or division
on this part of its dependency chain).

Array loops: ``chain_products`` and ``integrate_rates`` turn a sequence of
rotations into an attitude history (simulators' truth, strapdown integration).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

SMALL_TH2 = 0.0025  # (0.05 rad)²: below it the Taylor form equals the trigonometric one
NEAR_UNIT = 1e-7  # | |q|² - 1 | below it: normalised by one Newton step (error < 4e-15)


@njit(inline="always", error_model="numpy")
def exp_mul(w, x, y, z, rx, ry, rz, trig, normalise):
    """``q ⊗ exp(r)`` (normalised if asked), and whether the exact forms were needed.

    ``q = [w, x, y, z]``, ``r`` a rotation vector (rad) in q's body frame. ``trig``: use
    the exact forms where the short ones are not exact: the trigonometric one for
    |r| >= 0.05 rad and ``1/sqrt`` for a product far from unit norm. With ``trig`` False
    the short forms are used everywhere (branch-free vector loops) and the second value
    flags the steps to redo exactly. The product of two unit quaternions is unit to
    rounding: normalising once per filter step is enough.
    """
    th2 = rx * rx + ry * ry + rz * rz
    big = th2 >= SMALL_TH2
    if trig and big:
        th = math.sqrt(th2)
        dw = math.cos(0.5 * th)
        k = math.sin(0.5 * th) / th
    else:
        # Taylor series of cos(θ/2) and sin(θ/2)/θ to θ⁶: for θ < 0.05 rad the first
        # omitted terms, θ⁸/10321920 and θ⁸/185794560, are below 4e-18, under half an
        # ulp of the result. Estrin's form: a shorter dependency chain than Horner's,
        # which matters in a filter whose every step waits on the last.
        t4 = th2 * th2
        dw = (1.0 - th2 * (1.0 / 8.0)) + t4 * (1.0 / 384.0 - th2 * (1.0 / 46080.0))
        k = (0.5 - th2 * (1.0 / 48.0)) + t4 * (1.0 / 3840.0 - th2 * (1.0 / 645120.0))
    dx = k * rx
    dy = k * ry
    dz = k * rz
    nw = w * dw - x * dx - y * dy - z * dz
    nx = w * dx + x * dw + y * dz - z * dy
    ny = w * dy - x * dz + y * dw + z * dx
    nz = w * dz + x * dy - y * dx + z * dw
    if not normalise:
        return nw, nx, ny, nz, big
    # |q|² = 1 + ε with ε of a few ulp when q and exp(r) are unit: one Newton step for
    # 1/sqrt from 1, s = 1 - ε/2, is then exact to ε² (no sqrt, no division on the chain)
    n2 = (nw * nw + nx * nx) + (ny * ny + nz * nz)
    near = abs(n2 - 1.0) < NEAR_UNIT
    if trig and not near:
        s = 1.0 / math.sqrt(n2)
    else:
        s = 1.5 - 0.5 * n2
    return nw * s, nx * s, ny * s, nz * s, big or not near


@njit(inline="always", error_model="numpy")
def rotate_by(q, rx, ry, rz):
    """``q <- normalise(q ⊗ exp([rx, ry, rz]))`` in place on the array ``q`` (4,)."""
    q[0], q[1], q[2], q[3], _ = exp_mul(q[0], q[1], q[2], q[3], rx, ry, rz, True, True)


@njit(inline="always")
def mul(pw, px, py, pz, qw, qx, qy, qz):
    """Hamilton product ``p ⊗ q`` as a tuple ``(w, x, y, z)``."""
    return (pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw)


@njit(inline="always")
def mul_arr(p, q):
    """Hamilton product ``p ⊗ q`` of arrays (4,) as a new array (4,)."""
    out = np.empty(4)
    out[0], out[1], out[2], out[3] = mul(p[0], p[1], p[2], p[3], q[0], q[1], q[2], q[3])
    return out


@njit(inline="always", error_model="numpy")
def normalised(w, x, y, z):
    """``q / |q|`` (exact ``1/sqrt``) as a tuple."""
    s = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
    return w * s, x * s, y * s, z * s


@njit(inline="always", error_model="numpy")
def exp(rx, ry, rz):
    """``exp(r)``: the unit quaternion of the rotation vector ``r`` (rad), as a tuple.

    Exact to double precision (``exp_mul`` applied to the identity)."""
    w, x, y, z, _ = exp_mul(1.0, 0.0, 0.0, 0.0, rx, ry, rz, True, False)
    return w, x, y, z


@njit(inline="always")
def rotate(w, x, y, z, vx, vy, vz):
    """``R(q) v`` for a unit ``q`` (for ``q = q_ab``: v from b- to a-coordinates)."""
    return ((1.0 - 2.0 * (y * y + z * z)) * vx + 2.0 * (x * y - w * z) * vy
            + 2.0 * (x * z + w * y) * vz,
            2.0 * (x * y + w * z) * vx + (1.0 - 2.0 * (x * x + z * z)) * vy
            + 2.0 * (y * z - w * x) * vz,
            2.0 * (x * z - w * y) * vx + 2.0 * (y * z + w * x) * vy
            + (1.0 - 2.0 * (x * x + y * y)) * vz)


@njit(inline="always")
def rotate_inv(w, x, y, z, vx, vy, vz):
    """``R(q)ᵀ v`` for a unit ``q`` (for ``q = q_ab``: v from a- to b-coordinates)."""
    return ((1.0 - 2.0 * (y * y + z * z)) * vx + 2.0 * (x * y + w * z) * vy
            + 2.0 * (x * z - w * y) * vz,
            2.0 * (x * y - w * z) * vx + (1.0 - 2.0 * (x * x + z * z)) * vy
            + 2.0 * (y * z + w * x) * vz,
            2.0 * (x * z + w * y) * vx + 2.0 * (y * z - w * x) * vy
            + (1.0 - 2.0 * (x * x + y * y)) * vz)


@njit(inline="always")
def rotate_arr(q, v):
    """``R(q) v`` of arrays ``q`` (4,), ``v`` (3,) as a new array (3,)."""
    out = np.empty(3)
    out[0], out[1], out[2] = rotate(q[0], q[1], q[2], q[3], v[0], v[1], v[2])
    return out


@njit(inline="always")
def rotate_inv_arr(q, v):
    """``R(q)ᵀ v`` of arrays ``q`` (4,), ``v`` (3,) as a new array (3,)."""
    out = np.empty(3)
    out[0], out[1], out[2] = rotate_inv(q[0], q[1], q[2], q[3], v[0], v[1], v[2])
    return out


@njit(inline="always")
def dcm(w, x, y, z):
    """The nine entries ``c00, c01, ..., c22`` of ``R(q)`` (row-major) for a unit ``q``."""
    return (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
            2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
            2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))


@njit(inline="always")
def up_row(w, x, y, z):
    """The third row ``c20, c21, c22`` of ``R(q)`` for a unit ``q = q_nb``: the navigation
    frame's up axis in body coordinates (``R_nbᵀ e_z``)."""
    return 2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)


@njit(cache=True, error_model="numpy")
def chain_products(q0, steps, out):
    """Attitude from per-interval rotations: ``out[0] = q0``,
    ``out[k + 1] = normalise(out[k] ⊗ steps[k])``; ``steps`` (N, 4), ``out`` (N + 1, 4)
    (the truth integration of the simulators)."""
    w, x, y, z = q0[0], q0[1], q0[2], q0[3]
    out[0, 0], out[0, 1], out[0, 2], out[0, 3] = w, x, y, z
    for k in range(steps.shape[0]):
        pw, px, py, pz = steps[k, 0], steps[k, 1], steps[k, 2], steps[k, 3]
        nw = w * pw - x * px - y * py - z * pz
        nx = w * px + x * pw + y * pz - z * py
        ny = w * py - x * pz + y * pw + z * px
        nz = w * pz + x * py - y * px + z * pw
        s = 1.0 / math.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
        w, x, y, z = nw * s, nx * s, ny * s, nz * s
        out[k + 1, 0], out[k + 1, 1], out[k + 1, 2], out[k + 1, 3] = w, x, y, z


@njit(cache=True, error_model="numpy")
def integrate_rates(q0, rate, dt, out):
    """Strapdown integration: ``out[0] = q0``, ``out[k + 1] = normalise(out[k] ⊗
    exp(rate[k] dt))``; ``rate`` (N, 3) rad/s in the body frame, ``dt`` s, ``out``
    (N + 1, 4)."""
    w, x, y, z = q0[0], q0[1], q0[2], q0[3]
    out[0, 0], out[0, 1], out[0, 2], out[0, 3] = w, x, y, z
    for k in range(rate.shape[0]):
        w, x, y, z, _ = exp_mul(w, x, y, z, rate[k, 0] * dt, rate[k, 1] * dt, rate[k, 2] * dt,
                                True, True)
        out[k + 1, 0], out[k + 1, 1], out[k + 1, 2], out[k + 1, 3] = w, x, y, z


# ---------------------------------------------------------------- the quadratic form of R(q)
# Gauss-Newton over the four quaternion components (seed 000's q_mes) and the seed-001 EKF's
# RK4 stages evaluate R(q) v off the unit sphere, where only the quadratic form is a
# polynomial with an exact Jacobian. ``R(q)ᵀ v`` is ``rotate_quadratic`` of ``conj(q)``
# (bitwise: a sign flip is exact) and its Jacobian that of ``conj(q)`` with the x, y, z
# columns negated.


@njit(inline="always")
def rotate_quadratic(w, x, y, z, vx, vy, vz):
    """``R(q) v = (w² − u·u) v + 2 (u·v) u + 2 w (u × v)``, ``u = [x, y, z]``, as a tuple.

    Equal to ``rotate`` for a unit ``q``; for any ``q`` it is ``|q|²`` times the rotation of
    ``v`` by ``q/|q|`` (a quadratic polynomial in the four components)."""
    uu = x * x + y * y + z * z
    uv = x * vx + y * vy + z * vz
    cx = y * vz - z * vy
    cy = z * vx - x * vz
    cz = x * vy - y * vx
    s = w * w - uu
    return (s * vx + 2.0 * uv * x + 2.0 * w * cx,
            s * vy + 2.0 * uv * y + 2.0 * w * cy,
            s * vz + 2.0 * uv * z + 2.0 * w * cz)


@njit(inline="always")
def rotate_quadratic_jac(w, x, y, z, vx, vy, vz, A):
    """``A (3, 4) <- ∂(R(q) v)/∂[w, x, y, z]`` of ``rotate_quadratic`` (exact for any q)::

        ∂/∂w = 2 w v + 2 u × v,   ∂/∂u = 2 (u·v) I − 2 v uᵀ + 2 u vᵀ − 2 w [v×]
    """
    uv2 = 2.0 * (x * vx + y * vy + z * vz)
    w2 = 2.0 * w
    A[0, 0] = w2 * vx + 2.0 * (y * vz - z * vy)
    A[1, 0] = w2 * vy + 2.0 * (z * vx - x * vz)
    A[2, 0] = w2 * vz + 2.0 * (x * vy - y * vx)
    # 2 (u·v) I − 2 v uᵀ + 2 u vᵀ (the diagonal of the last two cancels), then − 2 w [v×]
    A[0, 1] = (-2.0 * vx * x + 2.0 * x * vx) + uv2
    A[0, 2] = (-2.0 * vx * y + 2.0 * x * vy) + w2 * vz
    A[0, 3] = (-2.0 * vx * z + 2.0 * x * vz) - w2 * vy
    A[1, 1] = (-2.0 * vy * x + 2.0 * y * vx) - w2 * vz
    A[1, 2] = (-2.0 * vy * y + 2.0 * y * vy) + uv2
    A[1, 3] = (-2.0 * vy * z + 2.0 * y * vz) + w2 * vx
    A[2, 1] = (-2.0 * vz * x + 2.0 * z * vx) + w2 * vy
    A[2, 2] = (-2.0 * vz * y + 2.0 * z * vy) - w2 * vx
    A[2, 3] = (-2.0 * vz * z + 2.0 * z * vz) + uv2


@njit(cache=True)
def xi_into(w, x, y, z, m):
    """``m`` (4, 3) ``<- Ξ(q)``: ``q ⊗ [0, v] = Ξ(q) v``."""
    m[0, 0] = -x
    m[0, 1] = -y
    m[0, 2] = -z
    m[1, 0] = w
    m[1, 1] = -z
    m[1, 2] = y
    m[2, 0] = z
    m[2, 1] = w
    m[2, 2] = -x
    m[3, 0] = -y
    m[3, 1] = x
    m[3, 2] = w


@njit(cache=True)
def xi(q):
    """``Ξ(q)`` (4, 3) as a new array (:func:`xi_into`)."""
    m = np.empty((4, 3))
    xi_into(q[0], q[1], q[2], q[3], m)
    return m


@njit(cache=True)
def omega_into(vx, vy, vz, m):
    """``m`` (4, 4) ``<- Ω(v)``: ``q ⊗ [0, v] = Ω(v) q``."""
    m[0, 0] = 0.0
    m[0, 1] = -vx
    m[0, 2] = -vy
    m[0, 3] = -vz
    m[1, 0] = vx
    m[1, 1] = 0.0
    m[1, 2] = vz
    m[1, 3] = -vy
    m[2, 0] = vy
    m[2, 1] = -vz
    m[2, 2] = 0.0
    m[2, 3] = vx
    m[3, 0] = vz
    m[3, 1] = vy
    m[3, 2] = -vx
    m[3, 3] = 0.0


@njit(cache=True)
def omega(v):
    """``Ω(v)`` (4, 4) as a new array (:func:`omega_into`)."""
    m = np.empty((4, 4))
    omega_into(v[0], v[1], v[2], m)
    return m
