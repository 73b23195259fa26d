"""Compiled loop of the seed-001 spacecraft EKF (gyro-less, rigid-body dynamics).

Readable twin: every function here is plain Python/numpy that numba compiles;
``fn.py_func`` is the same code run by the interpreter, and the tests compare the
compiled batch loop with it sample by sample (``tests/test_ekf_spacecraft.py``). The
model equations are documented in :mod:`gnomon.estimators.ekf_spacecraft`.

Conventions: quaternions ``[w, x, y, z]`` Hamilton; ``q`` is ``q_ob`` (orbital from body).
``rt_v(q, v) = R(q)ᵀ v`` (a vector of the orbital frame in the body frame) uses the
quadratic form of ``R`` (``gnomon.kernels.quat.rotate_quadratic``), a polynomial in q
whose Jacobian ``d_rt_v`` is exact also off the unit sphere (the RK4 stages leave it).

Shape (see ``gnomon.kernels``): ``STATE`` holds ``z = [w_ib_b, q_ob]`` (7,), ``P``
(7, 7) and the known inputs of the last sample, which drive the prediction to the next
one; ``Coefficients`` the inertia, noise and options, built by ``coefficients``. One
sample (``ekf_step``) is the state prediction (RK4 of the dynamics), the covariance
prediction, then the magnetometer and sun rows of the update (the paper's joint update,
taken a row at a time: ``correct``). ``ekf_row`` is one
raw sample (its unit vectors, the step, its known inputs held): the batch loop
``ekf_batch`` and the per-sample kernel ``ekf_sample`` both run it.

How it is fast: 7x7 matrices are too small for numba's ``@`` and ``np.linalg`` (a
BLAS/LAPACK call per product costs more than its arithmetic), so the products are plain
loops; the dynamics ``f`` (four times per sample in the RK4) and the Jacobian are scalar
code without temporaries; the sample loop allocates nothing (``Work``: scratch arrays
made once per batch; ``predict_state``, ``_vector_rows`` and ``correct`` are given the
arrays they use); and the update takes its rows one at a time (a
scalar Joseph update each, no Cholesky; R is diagonal), skipping the zero rate columns
of ``H``. One seed-001 orbit (6,001 samples): 7.7 -> 3.1 µs per sample (an earlier,
faster machine); on the 2-core machine of 2026-12-07, interleaved best of 20, 23.9 ->
10.6 ms (4.0 -> 1.8 µs per sample; the estimates equal to 1e-14).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from gnomon.kernels.linalg import (
    cross,
    mat3_load,
    mat3_vec,
)
from gnomon.kernels.quat import (
    normalised,
    omega_into,
    rotate_quadratic,
    rotate_quadratic_jac,
    xi_into,
)

#: ``z`` (7,) ``[w_ib_b (rad/s), q_ob]``, ``P`` (7, 7); held inputs of the last sample:
#: ``w_io_o`` (rad/s, orbital frame), wheel momentum ``h_b`` (N m s), its rate ``hdot_b``
#: (N m) and the known external torque ``tau_b`` (N m), all in b; ``pending``: the next
#: sample is the initial state (a fresh start: no step, its inputs held).
STATE = np.dtype([("z", np.float64, 7), ("P", np.float64, (7, 7)), ("w_io_o", np.float64, 3),
                  ("h_b", np.float64, 3), ("hdot_b", np.float64, 3), ("tau_b", np.float64, 3),
                  ("pending", np.bool_)])


class Coefficients(NamedTuple):
    """``J``/``Jinv`` (3, 3) the filter's inertia (kg m²); ``gg = 3 μ/r³`` (1/s², 0: no
    gravity gradient); ``Q`` (7, 7) process noise per second; ``r_mag``/``r_sun`` variances
    of a unit-vector component; ``use_sun``; ``substeps`` RK4 steps per sample."""

    J: np.ndarray
    Jinv: np.ndarray
    gg: float
    Q: np.ndarray
    r_mag: float
    r_sun: float
    use_sun: bool
    substeps: int


def coefficients(p, J, gg: float) -> Coefficients:
    """From an ``EKFSpacecraftParams`` (read by attribute), the inertia ``J`` (3, 3) and the
    gravity-gradient coefficient ``gg`` (1/s²), both taken per recording by the filter."""
    J = np.ascontiguousarray(J, float)
    Jd = np.diag(J).copy()
    Q = np.diag(list((p.torque_noise_n_m / Jd) ** 2) + [p.quat_noise_per_rt_s ** 2] * 4)
    return Coefficients(J, np.ascontiguousarray(np.linalg.inv(J)), float(gg), Q,
                        float(p.sigma_mag) ** 2, float(p.sigma_sun) ** 2, bool(p.use_sun),
                        int(p.substeps))


@njit(cache=True)
def rt_v(q, v):
    """``R(q)ᵀ v`` (3,) by the quadratic form (= R_bo v for a unit q)."""
    return np.array(rotate_quadratic(q[0], -q[1], -q[2], -q[3], v[0], v[1], v[2]))


@njit(cache=True)
def d_rt_v_into(qw, qx, qy, qz, vx, vy, vz, out):
    """``out`` (3, 4) ``<- ∂(R(q)ᵀ v)/∂q``: the paper's ``h_k`` columns."""
    rotate_quadratic_jac(qw, -qx, -qy, -qz, vx, vy, vz, out)
    for i in range(3):  # ∂conj(q)/∂q = diag(1, −1, −1, −1)
        for j in range(1, 4):
            out[i, j] = -out[i, j]


@njit(cache=True)
def d_rt_v(q, v):
    """Jacobian ``∂(R(q)ᵀ v)/∂q`` (3, 4) as a new array (:func:`d_rt_v_into`)."""
    out = np.empty((3, 4))
    d_rt_v_into(q[0], q[1], q[2], q[3], v[0], v[1], v[2], out)
    return out


class Work(NamedTuple):
    """Scratch arrays of one sample (``workspace``), allocated once per batch (the sample
    loop allocates nothing; it made about 36 small arrays per sample)."""

    z: np.ndarray    #: (7,) the state being predicted and corrected
    k: np.ndarray    #: (5, 7) the RK4 stages k1..k4 and the stage's state
    F: np.ndarray    #: (7, 7) the Jacobian, then Φ
    M: np.ndarray    #: (3, 3) a block of the Jacobian
    D: np.ndarray    #: (3, 4) a ∂(R(q)ᵀ v)/∂q
    T: np.ndarray    #: (7, 7) Φ P
    P: np.ndarray    #: (7, 7) the predicted, then corrected covariance
    u: np.ndarray    #: (4, 3) the unit vectors: mag (b), field (o), sun (b), sun (o)
    Hq: np.ndarray   #: (6, 4) the quaternion columns of H
    y: np.ndarray    #: (6,) innovations
    r: np.ndarray    #: (6,) measurement variances
    dz: np.ndarray   #: (7,) the correction so far
    p: np.ndarray    #: (7,) P hᵀ of a row
    kg: np.ndarray   #: (7,) the gain of a row
    Xi: np.ndarray   #: (4, 3) Ξ(q)
    Om: np.ndarray   #: (4, 4) Ω(w_bo)


@njit(cache=True)
def workspace():
    """A ``Work`` of fresh scratch arrays."""
    return Work(np.empty(7), np.empty((5, 7)), np.empty((7, 7)), np.empty((3, 3)),
                np.empty((3, 4)), np.empty((7, 7)), np.empty((7, 7)), np.empty((4, 3)),
                np.empty((6, 4)), np.empty(6), np.empty(6), np.empty(7), np.empty(7),
                np.empty(7), np.empty((4, 3)), np.empty((4, 4)))


@njit(cache=True)
def ekf_f_into(z, J, Jinv, h, hdot, tau, w_io_o, gg, out):
    """State derivative ``f(z)`` of ``z = [w_ib_b, q_ob]`` into ``out`` (7,).

    ``J ẇ = -w × (J w + h) - ḣ + τ + gg · (ô × J ô)``, ``ô = R_ob^T [0, 0, 1]`` (nadir in b),
    ``gg = 3 μ/r³`` (gravity gradient; 0 disables); ``q̇ = ½ q ⊗ [0, w - R_ob^T w_io_o]``.
    Scalar arithmetic, no allocation (it runs 4 times per sample in the RK4)."""
    w0, w1, w2 = z[0], z[1], z[2]
    qw, qx, qy, qz = z[3], z[4], z[5], z[6]
    Jm = mat3_load(J)
    jw0, jw1, jw2 = mat3_vec(Jm, w0, w1, w2)
    c0, c1, c2 = cross(w0, w1, w2, jw0 + h[0], jw1 + h[1], jw2 + h[2])
    t0, t1, t2 = -c0 - hdot[0] + tau[0], -c1 - hdot[1] + tau[1], -c2 - hdot[2] + tau[2]
    if gg != 0.0:
        o0, o1, o2 = rotate_quadratic(qw, -qx, -qy, -qz, 0.0, 0.0, 1.0)
        jo0, jo1, jo2 = mat3_vec(Jm, o0, o1, o2)
        g0, g1, g2 = cross(o0, o1, o2, jo0, jo1, jo2)
        t0, t1, t2 = t0 + gg * g0, t1 + gg * g1, t2 + gg * g2
    out[0], out[1], out[2] = mat3_vec(mat3_load(Jinv), t0, t1, t2)
    r0, r1, r2 = rotate_quadratic(qw, -qx, -qy, -qz, w_io_o[0], w_io_o[1], w_io_o[2])
    v0, v1, v2 = w0 - r0, w1 - r1, w2 - r2
    # ½ Ξ(q) v
    out[3] = 0.5 * (-qx * v0 - qy * v1 - qz * v2)
    out[4] = 0.5 * (qw * v0 - qz * v1 + qy * v2)
    out[5] = 0.5 * (qz * v0 + qw * v1 - qx * v2)
    out[6] = 0.5 * (-qy * v0 + qx * v1 + qw * v2)


@njit(cache=True)
def ekf_f(z, J, Jinv, h, hdot, tau, w_io_o, gg):
    """:func:`ekf_f_into` as a new array (7,)."""
    out = np.empty(7)
    ekf_f_into(z, J, Jinv, h, hdot, tau, w_io_o, gg, out)
    return out


@njit(cache=True)
def _cross_columns(a0, a1, a2, J, b0, b1, b2, out):
    """``out[:, j] = a × J[:, j] − b × e_j`` (3, 3): the columns of ``[a×] J − [b×]``."""
    for j in range(3):
        c0, c1, c2 = cross(a0, a1, a2, J[0, j], J[1, j], J[2, j])
        e0, e1, e2 = (1.0 if j == 0 else 0.0), (1.0 if j == 1 else 0.0), (1.0 if j == 2 else 0.0)
        d0, d1, d2 = cross(b0, b1, b2, e0, e1, e2)
        out[0, j], out[1, j], out[2, j] = c0 - d0, c1 - d1, c2 - d2


@njit(cache=True)
def ekf_jacobian_into(z, J, Jinv, h, w_io_o, gg, F, M, D, X, Om):
    """``F`` (7, 7) ``<- ∂f/∂z`` of :func:`ekf_f` (analytic; tested against finite
    differences); ``M`` (3, 3), ``D`` (3, 4), ``X`` (4, 3), ``Om`` (4, 4) scratch:
    ``∂ẇ/∂w = J⁻¹ ([(J w + h)×] − [w×] J)``, ``∂ẇ/∂q = gg J⁻¹ ([ô×] J − [(J ô)×]) ∂ô/∂q``,
    ``∂q̇/∂w = ½ Ξ(q)``, ``∂q̇/∂q = ½ Ω(w_bo) − ½ Ξ(q) ∂(R_ob^T w_io_o)/∂q``."""
    w0, w1, w2 = z[0], z[1], z[2]
    qw, qx, qy, qz = z[3], z[4], z[5], z[6]
    F[:, :] = 0.0
    Jm, Ji = mat3_load(J), mat3_load(Jinv)
    a0, a1, a2 = mat3_vec(Jm, w0, w1, w2)
    # [(Jw + h)×] − [w×] J = −([w×] J − [(Jw + h)×])
    _cross_columns(w0, w1, w2, J, a0 + h[0], a1 + h[1], a2 + h[2], M)
    for j in range(3):
        F[0, j], F[1, j], F[2, j] = mat3_vec(Ji, -M[0, j], -M[1, j], -M[2, j])
    if gg != 0.0:
        o0, o1, o2 = rotate_quadratic(qw, -qx, -qy, -qz, 0.0, 0.0, 1.0)
        jo0, jo1, jo2 = mat3_vec(Jm, o0, o1, o2)
        _cross_columns(o0, o1, o2, J, jo0, jo1, jo2, M)       # [ô×] J − [(J ô)×]
        d_rt_v_into(qw, qx, qy, qz, 0.0, 0.0, 1.0, D)         # ∂ô/∂q
        for b in range(4):
            v0 = M[0, 0] * D[0, b] + M[0, 1] * D[1, b] + M[0, 2] * D[2, b]
            v1 = M[1, 0] * D[0, b] + M[1, 1] * D[1, b] + M[1, 2] * D[2, b]
            v2 = M[2, 0] * D[0, b] + M[2, 1] * D[1, b] + M[2, 2] * D[2, b]
            f0, f1, f2 = mat3_vec(Ji, v0, v1, v2)
            F[0, 3 + b], F[1, 3 + b], F[2, 3 + b] = gg * f0, gg * f1, gg * f2
    xi_into(qw, qx, qy, qz, X)
    r0, r1, r2 = rotate_quadratic(qw, -qx, -qy, -qz, w_io_o[0], w_io_o[1], w_io_o[2])
    omega_into(w0 - r0, w1 - r1, w2 - r2, Om)
    d_rt_v_into(qw, qx, qy, qz, w_io_o[0], w_io_o[1], w_io_o[2], D)
    for i in range(4):
        for j in range(3):
            F[3 + i, j] = 0.5 * X[i, j]
        for b in range(4):
            F[3 + i, 3 + b] = 0.5 * Om[i, b] - 0.5 * (X[i, 0] * D[0, b] + X[i, 1] * D[1, b]
                                                      + X[i, 2] * D[2, b])


@njit(cache=True)
def ekf_jacobian(z, J, Jinv, h, w_io_o, gg):
    """``F = ∂f/∂z`` (7, 7) of :func:`ekf_f` as a new array (:func:`ekf_jacobian_into`)."""
    F = np.empty((7, 7))
    ekf_jacobian_into(z, J, Jinv, h, w_io_o, gg, F, np.empty((3, 3)), np.empty((3, 4)),
                      np.empty((4, 3)), np.empty((4, 4)))
    return F


@njit(cache=True)
def predict_state(c, s, dt, z, stages):
    """``z`` (7,) ``<-`` the RK4 of :func:`ekf_f` from ``s.z`` over ``dt``
    (``c.substeps`` steps) with the held inputs; the quaternion is renormalised.
    ``stages`` (5, 7) scratch."""
    z[:] = s.z
    J, Jinv, gg = c.J, c.Jinv, c.gg
    h, hdot, tau, w_io = s.h_b, s.hdot_b, s.tau_b, s.w_io_o
    hs = dt / c.substeps
    k1, k2, k3, k4, zt = stages[0], stages[1], stages[2], stages[3], stages[4]
    for _ in range(c.substeps):
        ekf_f_into(z, J, Jinv, h, hdot, tau, w_io, gg, k1)
        for i in range(7):
            zt[i] = z[i] + 0.5 * hs * k1[i]
        ekf_f_into(zt, J, Jinv, h, hdot, tau, w_io, gg, k2)
        for i in range(7):
            zt[i] = z[i] + 0.5 * hs * k2[i]
        ekf_f_into(zt, J, Jinv, h, hdot, tau, w_io, gg, k3)
        for i in range(7):
            zt[i] = z[i] + hs * k3[i]
        ekf_f_into(zt, J, Jinv, h, hdot, tau, w_io, gg, k4)
        for i in range(7):
            z[i] = z[i] + hs / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    z[3], z[4], z[5], z[6] = normalised(z[3], z[4], z[5], z[6])


@njit(cache=True)
def predict_covariance(c, s, dt, w):
    """``w.P <- Φ P Φᵀ + Q dt`` with ``Φ = I + F(z_{n+1|n}) dt`` (``z_{n+1|n}``: ``w.z``;
    ``P``: ``s.P``)."""
    Phi, T, P, P0, Q = w.F, w.T, w.P, s.P, c.Q
    ekf_jacobian_into(w.z, c.J, c.Jinv, s.h_b, s.w_io_o, c.gg, Phi, w.M, w.D, w.Xi, w.Om)
    for i in range(7):
        for j in range(7):
            Phi[i, j] = Phi[i, j] * dt
        Phi[i, i] += 1.0
    for i in range(7):                      # T = Φ P
        for j in range(7):
            v = 0.0
            for r in range(7):
                v += Phi[i, r] * P0[r, j]
            T[i, j] = v
    for i in range(7):                      # P = T Φᵀ + Q dt
        for j in range(7):
            v = 0.0
            for r in range(7):
                v += T[i, r] * Phi[j, r]
            P[i, j] = v
    for i in range(7):
        for j in range(7):
            P[i, j] += Q[i, j] * dt


@njit(cache=True)
def _vector_rows(z, u, ref, var, r0, D, Hq, y, r):
    """Rows ``r0 .. r0+2``: ``Hq = ∂(R(q)ᵀ ref)/∂q`` (the rate block of ``H`` is zero),
    ``y = u − R(q)ᵀ ref``, variances ``r = var`` (``q``: ``z[3:7]``; ``D`` (3, 4)
    scratch); returns ``|y|``."""
    qw, qx, qy, qz = z[3], z[4], z[5], z[6]
    d_rt_v_into(qw, qx, qy, qz, ref[0], ref[1], ref[2], D)
    for i in range(3):
        for b in range(4):
            Hq[r0 + i, b] = D[i, b]
    m0, m1, m2 = rotate_quadratic(qw, -qx, -qy, -qz, ref[0], ref[1], ref[2])
    y0, y1, y2 = u[0] - m0, u[1] - m1, u[2] - m2
    y[r0], y[r0 + 1], y[r0 + 2] = y0, y1, y2
    for i in range(r0, r0 + 3):
        r[i] = var
    return math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)


@njit(cache=True)
def measurement_rows(c, sun_ok, innov, w):
    """Magnetometer rows, then sun rows, of the usable unit vectors ``w.u`` (mag in b,
    field in o, sun in b, sun in o; a zero vector is a dropout) into ``w.Hq``, ``w.y``,
    ``w.r``: the measurement matrix ``H = [0 | Hq]`` by its quaternion block (the vectors
    do not depend on the rate) and the diagonal of ``R``, of the predicted ``w.z``;
    returns their number m; ``innov`` (2,) gets the innovation norms (NaN where a vector
    is not used)."""
    mag_u, b_o_u, sun_u, s_o_u = w.u[0], w.u[1], w.u[2], w.u[3]
    mag_ok = mag_u[0] ** 2 + mag_u[1] ** 2 + mag_u[2] ** 2 > 0.0
    sun_ok = sun_ok and sun_u[0] ** 2 + sun_u[1] ** 2 + sun_u[2] ** 2 > 0.0
    innov[0] = np.nan
    innov[1] = np.nan
    if mag_ok:
        innov[0] = _vector_rows(w.z, mag_u, b_o_u, c.r_mag, 0, w.D, w.Hq, w.y, w.r)
    if sun_ok:
        innov[1] = _vector_rows(w.z, sun_u, s_o_u, c.r_sun, 3 * mag_ok, w.D, w.Hq, w.y,
                                 w.r)
    return 3 * mag_ok + 3 * sun_ok


@njit(cache=True, error_model="numpy")
def correct(m, z, P, Hq, y, r, dz, p, k):
    """Update of ``z`` (7,), ``P`` (7, 7) with the ``m`` rows of ``H = [0 | Hq]`` (``Hq``
    (m, 4): the quaternion columns), the innovations ``y`` and ``R = diag(r)``: the joint
    update of the paper, done a row at a time (``R`` is diagonal, so the rows are
    independent measurements and this is the same update to rounding, with ``H`` and
    ``y`` of the prediction: row i's residual is ``y_i − H_i Δz``, ``Δz`` the correction
    so far). Each row is a scalar Joseph update
    ``P⁺ = (I − k h) P (I − k h)ᵀ + k r kᵀ = P − k pᵀ − p kᵀ + s k kᵀ`` (``p = P hᵀ``,
    ``s = h p + r``, ``k = p / s``), written on one triangle and mirrored (symmetric
    exactly). No Cholesky, no m x m system: about half the joint form's arithmetic.
    The zero rate columns of ``H`` are skipped, not multiplied. The quaternion is
    renormalised. ``dz``, ``p``, ``k`` (7,) scratch."""
    for a in range(7):
        dz[a] = 0.0
    for i in range(m):
        h0, h1, h2, h3 = Hq[i, 0], Hq[i, 1], Hq[i, 2], Hq[i, 3]
        for a in range(7):                      # p = P hᵀ
            p[a] = ((P[a, 3] * h0 + P[a, 4] * h1) + P[a, 5] * h2) + P[a, 6] * h3
        s = (((h0 * p[3] + h1 * p[4]) + h2 * p[5]) + h3 * p[6]) + r[i]
        e = y[i] - (((h0 * dz[3] + h1 * dz[4]) + h2 * dz[5]) + h3 * dz[6])
        for a in range(7):
            k[a] = p[a] / s
            dz[a] += k[a] * e
        for a in range(7):
            ka, pa = k[a], p[a]
            for c in range(a, 7):
                v = P[a, c] - (ka * p[c] + pa * k[c]) + s * ka * k[c]
                P[a, c] = v
                P[c, a] = v
    for a in range(7):
        z[a] += dz[a]
    z[3], z[4], z[5], z[6] = normalised(z[3], z[4], z[5], z[6])


@njit(cache=True)
def ekf_step(c, s, dt, sun_ok, innov, w):
    """One EKF sample on the record ``s``: predict over ``dt`` with the inputs held from the
    previous sample, then update with the unit vectors of this sample ``w.u`` (in b: mag,
    sun; their references in o); ``innov`` (2,) innovation norms."""
    predict_state(c, s, dt, w.z, w.k)
    predict_covariance(c, s, dt, w)
    m = measurement_rows(c, sun_ok, innov, w)
    if m > 0:
        correct(m, w.z, w.P, w.Hq, w.y, w.r, w.dz, w.p, w.kg)
    s.z[:] = w.z
    s.P[:, :] = w.P


@njit(cache=True)
def hold_inputs(s, w_io_o, h_b, hdot_b, tau_b):
    """Keep this sample's known inputs: they drive the prediction to the next sample."""
    for i in range(3):
        s.w_io_o[i] = w_io_o[i]
        s.h_b[i] = h_b[i]
        s.hdot_b[i] = hdot_b[i]
        s.tau_b[i] = tau_b[i]


@njit(cache=True)
def unit_into(v, out):
    """``out`` (3,) ``<- v`` (3,) normalised; zero (no vector) for a zero or non-finite one
    (the arithmetic of ``v / np.linalg.norm(v)``). Returns whether it is a vector."""
    n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if n > 0.0 and math.isfinite(n):
        out[0], out[1], out[2] = v[0] / n, v[1] / n, v[2] / n
        return True
    out[0] = out[1] = out[2] = 0.0
    return False


@njit(cache=True)
def ekf_row(c, s, dt, mag_b, b_o, sun_b, s_o, sun_valid, w_io_o, h, hdot, tau, innov, w):
    """One raw sample on the record ``s``: the measured vectors ``mag_b``, ``sun_b`` (b) and
    their models ``b_o``, ``s_o`` (o) as unit vectors (any one unit; a zero or non-finite
    vector is none; the field is unused without its model, the sun without its model or
    ``sun_valid``), then :func:`ekf_step` over ``dt`` (none for the initial state of a fresh
    start, ``s.pending``), then this sample's known inputs held (``w_io_o``, ``h``,
    ``hdot``, ``tau``: they drive the prediction to the next sample); ``innov`` (2,);
    ``w`` a ``Work``."""
    innov[0] = np.nan
    innov[1] = np.nan
    u = w.u
    field = unit_into(b_o, u[1])
    sun_ref = unit_into(s_o, u[3])
    if field:
        unit_into(mag_b, u[0])
    else:
        u[0, :] = 0.0
    sun_ok = c.use_sun and sun_valid and sun_ref
    if sun_ok:
        unit_into(sun_b, u[2])
    else:
        u[2, :] = 0.0
    if s.pending:
        s.pending = False
    else:
        ekf_step(c, s, dt, sun_ok, innov, w)
    hold_inputs(s, w_io_o, h, hdot, tau)


@njit(cache=True)
def ekf_sample(dt, mag_b, b_o, sun_b, s_o, w_io_o, h, hdot, tau, state, c, q_out):
    """One raw sample as a row of ``ekf_batch`` (the same arithmetic: ``ekf_row``), the
    vectors (3,) (a sun pair with a non-finite component: no sun); ``state`` updated in
    place; ``c`` the ``Coefficients``; ``q_out`` (4,) the estimate ``q_ob``. Returns 0 (the
    filter has no flags; it takes no gyro)."""
    s = state[0]
    ekf_row(c, s, dt, mag_b, b_o, sun_b, s_o, True, w_io_o, h, hdot, tau, np.empty(2),
            workspace())
    for i in range(4):
        q_out[i] = s.z[3 + i]
    return 0


@njit(cache=True)
def ekf_batch(c, state, dt, mag_b, b_o, sun_b, s_o, sun_valid, w_io_o, h, hdot, tau, z_out,
              p_diag, innov):
    """The paper's EKF over N raw samples (:func:`ekf_row` per sample).

    ``c`` ``Coefficients``; ``state`` a ``STATE`` array of one element, continued in place
    (row k steps over ``dt[k]`` s with the inputs held from row k−1, or from the state at
    k = 0; after a fresh start, row 0 is the initial state). Inputs (N rows): measured
    vectors ``mag_b``, ``sun_b`` in b; ``sun_valid`` (N,) bool; their models ``b_o``,
    ``s_o`` in o (any units: directions); ``w_io_o`` (N, 3) rad/s; ``h``, ``hdot``,
    ``tau`` (N, 3) known wheel momentum, its rate and external torque. Outputs: ``z_out``
    (N, 7), ``p_diag`` (N, 7) the covariance diagonal, ``innov`` (N, 2) innovation norms
    (NaN where a vector was not used).
    """
    s = state[0]
    w = workspace()
    for k in range(dt.shape[0]):
        ekf_row(c, s, dt[k], mag_b[k], b_o[k], sun_b[k], s_o[k], sun_valid[k], w_io_o[k], h[k],
                hdot[k], tau[k], innov[k], w)
        z_out[k] = s.z
        for i in range(7):
            p_diag[k, i] = s.P[i, i]
