"""Small linear algebra for the compiled filters (numba): 3-vectors and 3x3 matrices.

The one place where a kernel takes a cross product, inverts or solves a 3x3 system,
multiplies 3x3 matrices, clips a value or symmetrises a covariance. Scalar forms take
and return floats (tuples; inlined, kept in registers); ``*_arr`` forms work on numpy
arrays. Written by hand because numba's ``np.linalg`` calls LAPACK, and its ``@`` BLAS,
through a wrapper per call that costs more than the arithmetic of a 3x3 product (the
spacecraft EKF spent 7.7 µs per sample in about 30 such calls, 2.6 µs with plain loops),
and a 3x3 inverse by cofactors is exact enough for the well-conditioned matrices of
these filters (tested against ``numpy.linalg``). The 7x7 products of the spacecraft EKF
are loops in its own kernel (``gnomon.kernels.ekf_spacecraft``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(inline="always")
def cross(ax, ay, az, bx, by, bz):
    """``a × b`` as a tuple."""
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


@njit(inline="always")
def cross_arr(a, b):
    """``a × b`` of arrays (3,) as a new array (3,)."""
    out = np.empty(3)
    out[0], out[1], out[2] = cross(a[0], a[1], a[2], b[0], b[1], b[2])
    return out


@njit(inline="always")
def skew_arr(v):
    """``[v×]`` (3, 3): ``skew_arr(a) @ b == a × b``."""
    m = np.zeros((3, 3))
    m[0, 1] = -v[2]
    m[0, 2] = v[1]
    m[1, 0] = v[2]
    m[1, 2] = -v[0]
    m[2, 0] = -v[1]
    m[2, 1] = v[0]
    return m


@njit(inline="always")
def clip(v, lim):
    """``v`` clipped to ``[-lim, lim]``."""
    return lim if v > lim else (-lim if v < -lim else v)


@njit(inline="always", error_model="numpy")
def inv3(a, b, c, d, e, f, g, h, i):
    """Inverse of the row-major 3x3 matrix ``[[a, b, c], [d, e, f], [g, h, i]]`` by
    cofactors: ``(det, i00, i01, i02, i10, i11, i12, i20, i21, i22)``. The entries are
    inf/NaN when ``det`` is 0: callers test ``det`` first where that can happen."""
    c0 = e * i - f * h
    c1 = -(d * i - f * g)
    c2 = d * h - e * g
    det = a * c0 + b * c1 + c * c2
    s = 1.0 / det
    return (det, c0 * s, -(b * i - c * h) * s, (b * f - c * e) * s,
            c1 * s, (a * i - c * g) * s, -(a * f - c * d) * s,
            c2 * s, -(a * h - b * g) * s, (a * e - b * d) * s)


@njit(inline="always", error_model="numpy")
def inv3_into(m, out):
    """``out <- m⁻¹`` for row-major 3x3 arrays (``(3, 3)`` or flat ``(9,)``); returns
    ``det`` (``out`` is not meaningful when it is 0)."""
    a = m.ravel()
    r = inv3(a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], a[8])
    o = out.ravel()
    for k in range(9):
        o[k] = r[k + 1]
    return r[0]


@njit(inline="always")
def symmetrise(P):
    """``P <- (P + Pᵀ) / 2`` in place (n, n): keeps a covariance symmetric against the
    rounding of the short update forms over millions of steps."""
    n = P.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            m = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = m
            P[j, i] = m


# 3x3 matrices as row-major 9-tuples (a00, a01, a02, a10, ..., a22): kept in registers by
# the scalar kernels, which read a matrix from a state record once (``mat3_load``), work
# on tuples and write it back once (``mat3_store``). Sums run left to right over the inner
# index, as in ``sum(a[i, k] * b[k, j] for k in range(3))``.
@njit(inline="always")
def mat3_load(m):
    """The entries of the (3, 3) array ``m`` as a row-major 9-tuple."""
    return (m[0, 0], m[0, 1], m[0, 2], m[1, 0], m[1, 1], m[1, 2], m[2, 0], m[2, 1], m[2, 2])


@njit(inline="always")
def mat3_store(m, a):
    """``m[:] <- a``: the row-major 9-tuple ``a`` into the (3, 3) array ``m``."""
    m[0, 0], m[0, 1], m[0, 2] = a[0], a[1], a[2]
    m[1, 0], m[1, 1], m[1, 2] = a[3], a[4], a[5]
    m[2, 0], m[2, 1], m[2, 2] = a[6], a[7], a[8]


@njit(inline="always")
def mat3_vec(a, x, y, z):
    """``A v`` for a row-major 9-tuple ``A`` and ``v = (x, y, z)``, as a 3-tuple."""
    return (a[0] * x + a[1] * y + a[2] * z,
            a[3] * x + a[4] * y + a[5] * z,
            a[6] * x + a[7] * y + a[8] * z)


@njit(inline="always")
def mat3_tvec(a, x, y, z):
    """``Aᵀ v`` for a row-major 9-tuple ``A`` and ``v = (x, y, z)``, as a 3-tuple."""
    return (a[0] * x + a[3] * y + a[6] * z,
            a[1] * x + a[4] * y + a[7] * z,
            a[2] * x + a[5] * y + a[8] * z)


@njit(inline="always")
def mat3_mul(a, b):
    """``A B`` of row-major 9-tuples, as a 9-tuple."""
    return (a[0] * b[0] + a[1] * b[3] + a[2] * b[6],
            a[0] * b[1] + a[1] * b[4] + a[2] * b[7],
            a[0] * b[2] + a[1] * b[5] + a[2] * b[8],
            a[3] * b[0] + a[4] * b[3] + a[5] * b[6],
            a[3] * b[1] + a[4] * b[4] + a[5] * b[7],
            a[3] * b[2] + a[4] * b[5] + a[5] * b[8],
            a[6] * b[0] + a[7] * b[3] + a[8] * b[6],
            a[6] * b[1] + a[7] * b[4] + a[8] * b[7],
            a[6] * b[2] + a[7] * b[5] + a[8] * b[8])


@njit(inline="always")
def mat3_mul_bt(a, b):
    """``A Bᵀ`` of row-major 9-tuples, as a 9-tuple."""
    return (a[0] * b[0] + a[1] * b[1] + a[2] * b[2],
            a[0] * b[3] + a[1] * b[4] + a[2] * b[5],
            a[0] * b[6] + a[1] * b[7] + a[2] * b[8],
            a[3] * b[0] + a[4] * b[1] + a[5] * b[2],
            a[3] * b[3] + a[4] * b[4] + a[5] * b[5],
            a[3] * b[6] + a[4] * b[7] + a[5] * b[8],
            a[6] * b[0] + a[7] * b[1] + a[8] * b[2],
            a[6] * b[3] + a[7] * b[4] + a[8] * b[5],
            a[6] * b[6] + a[7] * b[7] + a[8] * b[8])


@njit(inline="always")
def mat3_tmul(a, b):
    """``Aᵀ B`` of row-major 9-tuples, as a 9-tuple."""
    return (a[0] * b[0] + a[3] * b[3] + a[6] * b[6],
            a[0] * b[1] + a[3] * b[4] + a[6] * b[7],
            a[0] * b[2] + a[3] * b[5] + a[6] * b[8],
            a[1] * b[0] + a[4] * b[3] + a[7] * b[6],
            a[1] * b[1] + a[4] * b[4] + a[7] * b[7],
            a[1] * b[2] + a[4] * b[5] + a[7] * b[8],
            a[2] * b[0] + a[5] * b[3] + a[8] * b[6],
            a[2] * b[1] + a[5] * b[4] + a[8] * b[7],
            a[2] * b[2] + a[5] * b[5] + a[8] * b[8])


@njit(inline="always")
def skew_into(out, row, scale, vx, vy, vz):
    """``out[row:row + 3, 0:3] <- scale·[v×]`` in place (``[v×] b = v × b``): a block of a
    measurement matrix such as ``D = [2[â×]; 2[m̂×]]``, written without allocating."""
    out[row, 0] = 0.0
    out[row, 1] = -scale * vz
    out[row, 2] = scale * vy
    out[row + 1, 0] = scale * vz
    out[row + 1, 1] = 0.0
    out[row + 1, 2] = -scale * vx
    out[row + 2, 0] = -scale * vy
    out[row + 2, 1] = scale * vx
    out[row + 2, 2] = 0.0


@njit(inline="always")
def finite_or_nan(x, y, z):
    """A sample's three components, or three NaN (no sample) when any is not finite: a
    partly broken sample never reaches a filter's state."""
    if math.isfinite(x) and math.isfinite(y) and math.isfinite(z):
        return x, y, z
    return math.nan, math.nan, math.nan
