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
prediction, then the magnetometer and sun rows of one joint update. ``ekf_row`` is one
raw sample (its unit vectors, the step, its known inputs held): the batch loop
``ekf_batch`` and the per-sample kernel ``ekf_sample`` both run it. Products and the
update's solve use the small-matrix loops of ``gnomon.kernels.linalg`` (``matmul``,
``spd_solve``), not numba's ``@`` / ``np.linalg`` (BLAS/LAPACK per call: 7.7 -> 6.2 µs
per sample, the rest is the arithmetic of the 7x7 Joseph update and its allocations).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from gnomon.kernels.linalg import cross_arr, matmul, matmul_bt, matvec, skew_arr, spd_solve
from gnomon.kernels.quat import (
    normalised,
    omega,
    rotate_quadratic,
    rotate_quadratic_jac,
    xi,
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
def d_rt_v(q, v):
    """Jacobian ``∂(R(q)ᵀ v)/∂q`` (3, 4): the paper's ``h_k`` columns."""
    out = np.empty((3, 4))
    rotate_quadratic_jac(q[0], -q[1], -q[2], -q[3], v[0], v[1], v[2], out)
    for i in range(3):  # ∂conj(q)/∂q = diag(1, −1, −1, −1)
        for j in range(1, 4):
            out[i, j] = -out[i, j]
    return out


@njit(cache=True)
def ekf_f(z, J, Jinv, h, hdot, tau, w_io_o, gg):
    """State derivative ``f(z)`` (7,) of ``z = [w_ib_b, q_ob]``.

    ``J ẇ = -w × (J w + h) - ḣ + τ + gg · (ô × J ô)``, ``ô = R_ob^T [0, 0, 1]`` (nadir in b),
    ``gg = 3 μ/r³`` (gravity gradient; 0 disables); ``q̇ = ½ q ⊗ [0, w - R_ob^T w_io_o]``.
    """
    w = z[0:3]
    q = z[3:7]
    Jw = matvec(J, w)
    torque = -cross_arr(w, Jw + h) - hdot + tau
    if gg != 0.0:
        nad = np.zeros(3)
        nad[2] = 1.0
        o = rt_v(q, nad)
        torque = torque + gg * cross_arr(o, matvec(J, o))
    out = np.empty(7)
    out[0:3] = matvec(Jinv, torque)
    w_bo = w - rt_v(q, w_io_o)
    out[3:7] = 0.5 * matvec(xi(q), w_bo)
    return out


@njit(cache=True)
def ekf_jacobian(z, J, Jinv, h, w_io_o, gg):
    """``F = ∂f/∂z`` (7, 7) of :func:`ekf_f` (analytic; tested against finite differences)."""
    w = z[0:3]
    q = z[3:7]
    F = np.zeros((7, 7))
    F[0:3, 0:3] = matmul(Jinv, skew_arr(matvec(J, w) + h) - matmul(skew_arr(w), J))
    if gg != 0.0:
        nad = np.zeros(3)
        nad[2] = 1.0
        o = rt_v(q, nad)
        d_o = d_rt_v(q, nad)
        F[0:3, 3:7] = gg * matmul(Jinv, matmul(matmul(skew_arr(o), J)
                                               - skew_arr(matvec(J, o)), d_o))
    X = xi(q)
    F[3:7, 0:3] = 0.5 * X
    w_bo = w - rt_v(q, w_io_o)
    F[3:7, 3:7] = 0.5 * omega(w_bo) - 0.5 * matmul(X, d_rt_v(q, w_io_o))
    return F


@njit(cache=True)
def predict_state(c, s, dt):
    """RK4 of :func:`ekf_f` over ``dt`` (``c.substeps`` steps) with the held inputs; the
    quaternion is renormalised. Returns the predicted ``z`` (7,)."""
    z = s.z.copy()
    J, Jinv, gg = c.J, c.Jinv, c.gg
    h, hdot, tau, w_io = s.h_b, s.hdot_b, s.tau_b, s.w_io_o
    hs = dt / c.substeps
    for _ in range(c.substeps):
        k1 = ekf_f(z, J, Jinv, h, hdot, tau, w_io, gg)
        k2 = ekf_f(z + 0.5 * hs * k1, J, Jinv, h, hdot, tau, w_io, gg)
        k3 = ekf_f(z + 0.5 * hs * k2, J, Jinv, h, hdot, tau, w_io, gg)
        k4 = ekf_f(z + hs * k3, J, Jinv, h, hdot, tau, w_io, gg)
        z = z + hs / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    z[3], z[4], z[5], z[6] = normalised(z[3], z[4], z[5], z[6])
    return z


@njit(cache=True)
def predict_covariance(c, s, z, dt):
    """``P <- Φ P Φᵀ + Q dt`` with ``Φ = I + F(z_{n+1|n}) dt``."""
    Phi = np.eye(7) + ekf_jacobian(z, c.J, c.Jinv, s.h_b, s.w_io_o, c.gg) * dt
    return matmul_bt(matmul(Phi, s.P), Phi) + c.Q * dt


@njit(cache=True)
def _vector_rows(q, u, ref, var, r0, H, y, R):
    """Rows ``r0 .. r0+2``: ``H = [0 | ∂(R(q)ᵀ ref)/∂q]``, ``y = u − R(q)ᵀ ref``, ``R = var I``;
    returns ``|y|``."""
    H[r0:r0 + 3, 3:7] = d_rt_v(q, ref)
    y[r0:r0 + 3] = u - rt_v(q, ref)
    for i in range(r0, r0 + 3):
        R[i, i] = var
    return math.sqrt(y[r0] ** 2 + y[r0 + 1] ** 2 + y[r0 + 2] ** 2)


@njit(cache=True)
def measurement_rows(c, q, mag_u, b_o_u, sun_u, s_o_u, sun_ok, innov):
    """Magnetometer rows, then sun rows, of the usable unit vectors (a zero vector is a
    dropout): ``(H (m, 7), y (m,), R (m, m))``; ``innov`` (2,) gets the innovation norms
    (NaN where a vector is not used)."""
    mag_ok = mag_u[0] ** 2 + mag_u[1] ** 2 + mag_u[2] ** 2 > 0.0
    sun_ok = sun_ok and sun_u[0] ** 2 + sun_u[1] ** 2 + sun_u[2] ** 2 > 0.0
    m = 3 * mag_ok + 3 * sun_ok
    H = np.zeros((m, 7))
    y = np.empty(m)
    R = np.zeros((m, m))
    innov[0] = np.nan
    innov[1] = np.nan
    if mag_ok:
        innov[0] = _vector_rows(q, mag_u, b_o_u, c.r_mag, 0, H, y, R)
    if sun_ok:
        innov[1] = _vector_rows(q, sun_u, s_o_u, c.r_sun, 3 * mag_ok, H, y, R)
    return H, y, R


@njit(cache=True)
def correct(z, P, H, y, R):
    """Joint update (Joseph form, symmetrised); the quaternion is renormalised. Returns the
    new ``(z, P)``."""
    HP = matmul(H, P)
    S = matmul_bt(HP, H) + R
    K = np.ascontiguousarray(spd_solve(S, HP).T)   # K = P Hᵀ S⁻¹ (S, P symmetric)
    z = z + matvec(K, y)
    IKH = np.eye(7) - matmul(K, H)
    P = matmul_bt(matmul(IKH, P), IKH) + matmul_bt(matmul(K, R), K)
    P = 0.5 * (P + P.T)
    z[3], z[4], z[5], z[6] = normalised(z[3], z[4], z[5], z[6])
    return z, P


@njit(cache=True)
def ekf_step(c, s, dt, mag_u, b_o_u, sun_u, s_o_u, sun_ok, innov):
    """One EKF sample on the record ``s``: predict over ``dt`` with the inputs held from the
    previous sample, then update with the unit vectors of this sample (in b: ``mag_u``,
    ``sun_u``; references in o: ``b_o_u``, ``s_o_u``); ``innov`` (2,) innovation norms."""
    z = predict_state(c, s, dt)
    P = predict_covariance(c, s, z, dt)
    H, y, R = measurement_rows(c, z[3:7], mag_u, b_o_u, sun_u, s_o_u, sun_ok, innov)
    if y.shape[0] > 0:
        z, P = correct(z, P, H, y, R)
    s.z[:] = z
    s.P[:, :] = P


@njit(cache=True)
def hold_inputs(s, w_io_o, h_b, hdot_b, tau_b):
    """Keep this sample's known inputs: they drive the prediction to the next sample."""
    for i in range(3):
        s.w_io_o[i] = w_io_o[i]
        s.h_b[i] = h_b[i]
        s.hdot_b[i] = hdot_b[i]
        s.tau_b[i] = tau_b[i]


@njit(cache=True)
def unit_or_zero(v):
    """``v`` (3,) normalised as a new array; zero (no vector) for a zero or non-finite one
    (the arithmetic of ``v / np.linalg.norm(v)``)."""
    out = np.zeros(3)
    n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if n > 0.0 and math.isfinite(n):
        out[0], out[1], out[2] = v[0] / n, v[1] / n, v[2] / n
    return out


@njit(cache=True)
def ekf_row(c, s, dt, mag_b, b_o, sun_b, s_o, sun_valid, w_io_o, h, hdot, tau, innov):
    """One raw sample on the record ``s``: the measured vectors ``mag_b``, ``sun_b`` (b) and
    their models ``b_o``, ``s_o`` (o) as unit vectors (any one unit; a zero or non-finite
    vector is none; the field is unused without its model, the sun without its model or
    ``sun_valid``), then :func:`ekf_step` over ``dt`` (none for the initial state of a fresh
    start, ``s.pending``), then this sample's known inputs held (``w_io_o``, ``h``,
    ``hdot``, ``tau``: they drive the prediction to the next sample); ``innov`` (2,)."""
    innov[0] = np.nan
    innov[1] = np.nan
    b_o_u = unit_or_zero(b_o)
    s_o_u = unit_or_zero(s_o)
    mag_u = unit_or_zero(mag_b) if b_o_u[0] != 0.0 or b_o_u[1] != 0.0 or b_o_u[2] != 0.0 \
        else np.zeros(3)
    sun_ok = c.use_sun and sun_valid and (s_o_u[0] != 0.0 or s_o_u[1] != 0.0
                                          or s_o_u[2] != 0.0)
    sun_u = unit_or_zero(sun_b) if sun_ok else np.zeros(3)
    if s.pending:
        s.pending = False
    else:
        ekf_step(c, s, dt, mag_u, b_o_u, sun_u, s_o_u, sun_ok, innov)
    hold_inputs(s, w_io_o, h, hdot, tau)


@njit(cache=True)
def ekf_sample(dt, mag_b, b_o, sun_b, s_o, w_io_o, h, hdot, tau, state, c, q_out):
    """One raw sample as a row of ``ekf_batch`` (the same arithmetic: ``ekf_row``), the
    vectors (3,) (a sun pair with a non-finite component: no sun); ``state`` updated in
    place; ``c`` the ``Coefficients``; ``q_out`` (4,) the estimate ``q_ob``. Returns 0 (the
    filter has no flags; it takes no gyro)."""
    s = state[0]
    ekf_row(c, s, dt, mag_b, b_o, sun_b, s_o, True, w_io_o, h, hdot, tau, np.empty(2))
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
    for k in range(dt.shape[0]):
        ekf_row(c, s, dt[k], mag_b[k], b_o[k], sun_b[k], s_o[k], sun_valid[k], w_io_o[k], h[k],
                hdot[k], tau[k], innov[k])
        z_out[k] = s.z
        for i in range(7):
            p_diag[k, i] = s.P[i, i]
