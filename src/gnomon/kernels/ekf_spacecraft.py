"""Compiled loops of the spacecraft EKF (seed 001) and of the gyro-aided MEKF.

Readable twins: every function here is plain Python/numpy that numba compiles;
``fn.py_func`` is the same code run by the interpreter, and the tests compare
the compiled batch loops with it sample by sample
(``tests/test_ekf_spacecraft.py``). The model equations are documented in
:mod:`gnomon.estimators.ekf_spacecraft`.

Conventions: quaternions ``[w, x, y, z]`` Hamilton; ``q`` is ``q_ob`` (orbital
from body); ``R(q)`` below is ``R_ob`` written with the quadratic (not
normalised) formula, so that ``rt_v(q, v) = R_ob^T v`` (a vector of the orbital
frame expressed in the body frame) is a polynomial in q whose Jacobian
``d_rt_v`` is exact also off the unit sphere.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def skew(v):
    """[v×] (3, 3)."""
    m = np.zeros((3, 3))
    m[0, 1] = -v[2]
    m[0, 2] = v[1]
    m[1, 0] = v[2]
    m[1, 2] = -v[0]
    m[2, 0] = -v[1]
    m[2, 1] = v[0]
    return m


@njit(cache=True)
def cross(a, b):
    out = np.empty(3)
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    return out


@njit(cache=True)
def qmul(p, q):
    """Hamilton product p ⊗ q."""
    out = np.empty(4)
    out[0] = p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3]
    out[1] = p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2]
    out[2] = p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1]
    out[3] = p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0]
    return out


@njit(cache=True)
def normalize(q):
    return q / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])


@njit(cache=True)
def rt_v(q, v):
    """``R(q)^T v`` with ``R(q) = (w² - e·e) I + 2 e eᵀ + 2 w [e×]`` (= R_ob for unit q)."""
    w = q[0]
    e = q[1:4]
    ee = e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
    ev = e[0] * v[0] + e[1] * v[1] + e[2] * v[2]
    exv = cross(e, v)
    return (w * w - ee) * v + 2.0 * ev * e - 2.0 * w * exv


@njit(cache=True)
def d_rt_v(q, v):
    """Jacobian ``∂(R(q)^T v)/∂q`` (3, 4): the paper's ``h_k`` columns."""
    w = q[0]
    e = q[1:4]
    ev = e[0] * v[0] + e[1] * v[1] + e[2] * v[2]
    out = np.empty((3, 4))
    exv = cross(e, v)
    for i in range(3):
        out[i, 0] = 2.0 * w * v[i] - 2.0 * exv[i]
    sv = skew(v)
    for i in range(3):
        for j in range(3):
            val = -2.0 * v[i] * e[j] + 2.0 * e[i] * v[j] + 2.0 * w * sv[i, j]
            if i == j:
                val += 2.0 * ev
            out[i, 1 + j] = val
    return out


@njit(cache=True)
def xi(q):
    """``Ξ(q)`` (4, 3): ``q ⊗ [0, v] = Ξ(q) v``."""
    m = np.empty((4, 3))
    w, x, y, z = q[0], q[1], q[2], q[3]
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
    return m


@njit(cache=True)
def omega(v):
    """``Ω(v)`` (4, 4): ``q ⊗ [0, v] = Ω(v) q``."""
    m = np.zeros((4, 4))
    m[0, 1] = -v[0]
    m[0, 2] = -v[1]
    m[0, 3] = -v[2]
    m[1, 0] = v[0]
    m[1, 2] = v[2]
    m[1, 3] = -v[1]
    m[2, 0] = v[1]
    m[2, 1] = -v[2]
    m[2, 3] = v[0]
    m[3, 0] = v[2]
    m[3, 1] = v[1]
    m[3, 2] = -v[0]
    return m


@njit(cache=True)
def ekf_f(z, J, Jinv, h, hdot, tau, w_io_o, gg):
    """State derivative ``f(z)`` (7,) of ``z = [w_ib_b, q_ob]``.

    ``J ẇ = -w × (J w + h) - ḣ + τ + gg · (ô × J ô)``, ``ô = R_ob^T [0, 0, 1]`` (nadir in b),
    ``gg = 3 μ/r³`` (gravity gradient; 0 disables); ``q̇ = ½ q ⊗ [0, w - R_ob^T w_io_o]``.
    """
    w = z[0:3]
    q = z[3:7]
    Jw = J @ w
    torque = -cross(w, Jw + h) - hdot + tau
    if gg != 0.0:
        nad = np.zeros(3)
        nad[2] = 1.0
        o = rt_v(q, nad)
        torque = torque + gg * cross(o, J @ o)
    out = np.empty(7)
    out[0:3] = Jinv @ torque
    w_bo = w - rt_v(q, w_io_o)
    out[3:7] = 0.5 * (xi(q) @ w_bo)
    return out


@njit(cache=True)
def ekf_jacobian(z, J, Jinv, h, w_io_o, gg):
    """``F = ∂f/∂z`` (7, 7) of :func:`ekf_f` (analytic; tested against finite differences)."""
    w = z[0:3]
    q = z[3:7]
    F = np.zeros((7, 7))
    F[0:3, 0:3] = Jinv @ (skew(J @ w + h) - skew(w) @ J)
    if gg != 0.0:
        nad = np.zeros(3)
        nad[2] = 1.0
        o = rt_v(q, nad)
        d_o = d_rt_v(q, nad)
        F[0:3, 3:7] = gg * (Jinv @ ((skew(o) @ J - skew(J @ o)) @ d_o))
    X = xi(q)
    F[3:7, 0:3] = 0.5 * X
    w_bo = w - rt_v(q, w_io_o)
    F[3:7, 3:7] = 0.5 * omega(w_bo) - 0.5 * (X @ d_rt_v(q, w_io_o))
    return F


@njit(cache=True)
def ekf_step(z, P, Ts, mag_u, sun_u, sun_ok, b_o_u, s_o_u, w_io_o, J, Jinv, h, hdot, tau, gg,
             Q, r_mag, r_sun, substeps, innov):
    """One EKF sample: predict over ``Ts`` with the inputs of the previous sample (``w_io_o``,
    ``h``, ``hdot``, ``tau``), then update with the vectors of this sample. Returns the new
    ``(z, P)``; ``innov`` (2,) receives the innovation norms (NaN when not used)."""
    # --- state prediction: RK4 of f with the inputs held over the step
    hs = Ts / substeps
    for _ in range(substeps):
        k1 = ekf_f(z, J, Jinv, h, hdot, tau, w_io_o, gg)
        k2 = ekf_f(z + 0.5 * hs * k1, J, Jinv, h, hdot, tau, w_io_o, gg)
        k3 = ekf_f(z + 0.5 * hs * k2, J, Jinv, h, hdot, tau, w_io_o, gg)
        k4 = ekf_f(z + hs * k3, J, Jinv, h, hdot, tau, w_io_o, gg)
        z = z + hs / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    z[3:7] = normalize(z[3:7])
    # --- covariance prediction with Phi = I + F(z_{n+1|n}) Ts
    eye7 = np.eye(7)
    Phi = eye7 + ekf_jacobian(z, J, Jinv, h, w_io_o, gg) * Ts
    P = Phi @ P @ Phi.T + Q * Ts
    # --- update with the vectors available now (a zero vector is a dropout: not used)
    q = z[3:7]
    mag_ok = mag_u[0] ** 2 + mag_u[1] ** 2 + mag_u[2] ** 2 > 0.0
    sun_ok = sun_ok and sun_u[0] ** 2 + sun_u[1] ** 2 + sun_u[2] ** 2 > 0.0
    m = 3 * mag_ok + 3 * sun_ok
    innov[0] = np.nan
    innov[1] = np.nan
    if m == 0:
        return z, P
    H = np.zeros((m, 7))
    y = np.empty(m)
    R = np.zeros((m, m))
    r0 = 0
    if mag_ok:
        H[0:3, 3:7] = d_rt_v(q, b_o_u)
        y[0:3] = mag_u - rt_v(q, b_o_u)
        for i in range(3):
            R[i, i] = r_mag
        innov[0] = math.sqrt(y[0] ** 2 + y[1] ** 2 + y[2] ** 2)
        r0 = 3
    if sun_ok:
        H[r0:r0 + 3, 3:7] = d_rt_v(q, s_o_u)
        y[r0:r0 + 3] = sun_u - rt_v(q, s_o_u)
        for i in range(r0, r0 + 3):
            R[i, i] = r_sun
        innov[1] = math.sqrt(y[r0] ** 2 + y[r0 + 1] ** 2 + y[r0 + 2] ** 2)
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    z = z + K @ y
    IKH = eye7 - K @ H
    P = IKH @ P @ IKH.T + K @ R @ K.T
    P = 0.5 * (P + P.T)
    z[3:7] = normalize(z[3:7])
    return z, P


@njit(cache=True)
def ekf_batch(dt, mag_u, sun_u, sun_valid, b_o_u, s_o_u, w_io_o, J, Jinv, h, hdot, tau, gg,
              z0, P0, Q, r_mag, r_sun, use_sun, substeps):
    """The paper's EKF over N samples (:func:`ekf_step` per sample).

    Inputs (N rows): ``dt`` (N,) s (``dt[k] = t[k] - t[k-1]``, ``dt[0]`` unused); measured
    unit vectors ``mag_u``, ``sun_u`` in b; ``sun_valid`` (N,) bool; reference unit vectors
    ``b_o_u``, ``s_o_u`` in o; ``w_io_o`` (N, 3) rad/s; ``J``/``Jinv`` (3, 3) the filter's
    inertia; ``h``, ``hdot``, ``tau`` (N, 3) known wheel momentum, its rate and external
    torque; ``z0`` (7,), ``P0`` (7, 7), ``Q`` (7, 7) per second, ``r_mag``/``r_sun``
    variances of the unit-vector components; ``substeps`` RK4 steps per sample.

    Returns ``z`` (N, 7), the covariance diagonal (N, 7), the innovation norms (N, 2; NaN
    where a vector was not used) and the final covariance (7, 7).
    """
    n = dt.shape[0]
    zs = np.empty((n, 7))
    pd = np.empty((n, 7))
    innov = np.full((n, 2), np.nan)
    z = z0.copy()
    P = P0.copy()
    zs[0] = z
    for i in range(7):
        pd[0, i] = P[i, i]
    for k in range(1, n):
        z, P = ekf_step(z, P, dt[k], mag_u[k], sun_u[k], use_sun and sun_valid[k], b_o_u[k],
                        s_o_u[k], w_io_o[k - 1], J, Jinv, h[k - 1], hdot[k - 1], tau[k - 1],
                        gg, Q, r_mag, r_sun, substeps, innov[k])
        zs[k] = z
        for i in range(7):
            pd[k, i] = P[i, i]
    return zs, pd, innov, P


@njit(cache=True)
def quat_exp_half(v):
    """Unit quaternion of the rotation vector ``v`` (rad)."""
    a = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    out = np.empty(4)
    if a < 1e-12:
        out[0] = 1.0
        out[1:4] = 0.5 * v
        return normalize(out)
    s = math.sin(0.5 * a) / a
    out[0] = math.cos(0.5 * a)
    out[1:4] = s * v
    return out


@njit(cache=True)
def mekf_step(q, b, P, Ts, gyro_prev, mag_u, sun_u, sun_ok, b_o_u, s_o_u, w_io_o_prev,
              arw_var, rrw_var, r_mag, r_sun, innov):
    """One MEKF sample: propagate with the previous gyro sample over ``Ts``, update with the
    vectors of this sample. Returns ``(q, b, P)``; ``innov`` (2,) gets the innovation norms."""
    w = gyro_prev - b
    w_bo = w - rt_v(q, w_io_o_prev)
    q = normalize(qmul(q, quat_exp_half(w_bo * Ts)))
    Phi = np.eye(6)
    dq = quat_exp_half(-w * Ts)
    # exp(-[w×]Ts) = R(dq) as a DCM (the transpose of the body's step rotation)
    Rw = np.empty((3, 3))
    for j in range(3):
        e = np.zeros(3)
        e[j] = 1.0
        Rw[:, j] = rt_v(dq, e)
    Phi[0:3, 0:3] = Rw.T
    for i in range(3):
        Phi[i, 3 + i] = -Ts
    P = Phi @ P @ Phi.T
    for i in range(3):
        P[i, i] += arw_var * Ts
        P[3 + i, 3 + i] += rrw_var * Ts
    mag_ok = mag_u[0] ** 2 + mag_u[1] ** 2 + mag_u[2] ** 2 > 0.0
    sun_ok = sun_ok and sun_u[0] ** 2 + sun_u[1] ** 2 + sun_u[2] ** 2 > 0.0
    m = 3 * mag_ok + 3 * sun_ok
    innov[0] = np.nan
    innov[1] = np.nan
    if m == 0:  # no usable vector (dropouts): propagation only
        return q, b, P
    H = np.zeros((m, 6))
    y = np.empty(m)
    R = np.zeros((m, m))
    r0 = 0
    if mag_ok:
        yh = rt_v(q, b_o_u)
        H[0:3, 0:3] = skew(yh)
        y[0:3] = mag_u - yh
        for i in range(3):
            R[i, i] = r_mag
        innov[0] = math.sqrt(y[0] ** 2 + y[1] ** 2 + y[2] ** 2)
        r0 = 3
    if sun_ok:
        ys = rt_v(q, s_o_u)
        H[r0:r0 + 3, 0:3] = skew(ys)
        y[r0:r0 + 3] = sun_u - ys
        for i in range(r0, r0 + 3):
            R[i, i] = r_sun
        innov[1] = math.sqrt(y[r0] ** 2 + y[r0 + 1] ** 2 + y[r0 + 2] ** 2)
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    dx = K @ y
    IKH = np.eye(6) - K @ H
    P = IKH @ P @ IKH.T + K @ R @ K.T
    P = 0.5 * (P + P.T)
    corr = np.empty(4)
    corr[0] = 1.0
    corr[1:4] = 0.5 * dx[0:3]
    q = normalize(qmul(q, corr))
    b = b + dx[3:6]
    return q, b, P


@njit(cache=True)
def mekf_batch(dt, gyro, mag_u, sun_u, sun_valid, b_o_u, s_o_u, w_io_o, q0, b0, P0,
               arw_var, rrw_var, r_mag, r_sun, use_sun):
    """Multiplicative EKF with gyro bias over N samples (:func:`mekf_step` per sample).

    Error state ``[δθ (body), δb]`` with ``q_ob,true = q̂_ob ⊗ [1, δθ/2]``; propagation
    ``q ← q ⊗ exp((ω - b - R_ob^T w_io_o) Ts)`` with the gyro sample of the step's start;
    ``Φ = [[exp(-[ω×]Ts), -I Ts], [0, I]]``, ``Q = diag(arw_var Ts I, rrw_var Ts I)``
    (``arw_var`` rad²/s, ``rrw_var`` rad²/s³); vector update ``H = [[ŷ×], 0]``.

    Returns ``q`` (N, 4), bias (N, 3) rad/s, covariance diagonal (N, 6), innovations (N, 2;
    NaN where a vector was not used) and the final covariance (6, 6).
    """
    n = dt.shape[0]
    qs = np.empty((n, 4))
    bs = np.empty((n, 3))
    pd = np.empty((n, 6))
    innov = np.full((n, 2), np.nan)
    q = q0.copy()
    b = b0.copy()
    P = P0.copy()
    qs[0] = q
    bs[0] = b
    for i in range(6):
        pd[0, i] = P[i, i]
    for k in range(1, n):
        q, b, P = mekf_step(q, b, P, dt[k], gyro[k - 1], mag_u[k], sun_u[k],
                            use_sun and sun_valid[k], b_o_u[k], s_o_u[k], w_io_o[k - 1],
                            arw_var, rrw_var, r_mag, r_sun, innov[k])
        qs[k] = q
        bs[k] = b
        for i in range(6):
            pd[k, i] = P[i, i]
    return qs, bs, pd, innov, P
