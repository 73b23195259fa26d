"""Compiled loops of the two spacecraft multiplicative EKFs, side by side.

Both are Lefferts, Markley & Shuster's MEKF (JGCD 5(5), 1982; Markley & Crassidis 2014,
ch. 6): estimate ``q_ob`` (orbital from body) and the gyro bias, error state
``[θ, δb]`` with ``q = q̂ ⊗ exp(θ)`` (θ in the body frame), unit-vector measurements with
``H = [[m̂×], 0]``, ``m̂ = R_bo v_o``. They were written for two papers and differ in the
details below; issue #22 merges them into one filter whose presets reproduce each.
Readable twins: ``gnomon.estimators.mekf_spacecraft``.

How they differ (``delayed_*``: ``mekf-delayed``, seed 000 | ``spacecraft_*``:
``mekf-spacecraft``, seed 001):

* readable twin: ``MagGyroMEKF.step`` in numpy, written apart | the kernel's ``.py_func``
* gyro sample propagating over ``t_k−1..t_k``: this sample's | the previous one (held in
  the state)
* attitude block of Φ: ``I − [ω×] dt`` (first order) | ``exp(−[ω×] dt)``
* process noise: ``arw² dt``, ``bias_rw² dt`` from rad/√s, rad/s/√s | variances ``arw_var dt``,
  ``rrw_var dt``
* update: sequential per vector, ``P ← P − K H P`` | joint (mag + sun rows), Joseph form
* measurement noise: ``σ`` rad per direction | ``r`` variance per unit-vector component
* correction: ``q ⊗ exp(δθ)`` | ``normalise(q ⊗ [1, δθ/2])``
* extras: sun loss by the delayed magnetometer pair weighted by the estimated swing, gaps
  (``max_dt_s``) and bad samples flagged | innovation norms and the covariance diagonal out

Shape (see ``gnomon.kernels``): per filter a ``*_STATE`` record and a ``*Coefficients``
NamedTuple built by ``*_coefficients(params)``; the step is split into the gyro
prediction, the magnetometer and the sun (or second pair) phases; the batch loop calls
the step and writes the outputs. The seed-000 filter's phases are ``inline="always"``
(as in ``gnomon.kernels.spacecraft_cf``: a call per sample would cost a third of its
speed); the seed-001 filter's numpy-style phases allocate their matrices and stay
functions (their call costs nothing next to that).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from gnomon.kernels.linalg import inv3_into, skew_arr, symmetrise
from gnomon.kernels.quat import dcm, exp, mul, normalised, rotate_inv, rotate_quadratic
from gnomon.kernels.spacecraft_cf import COAST, GAP, MAG, SECOND, predict, turn, unit_pair

# ================================================================ seed 000: mekf-delayed
#: ``q`` (4,) q_ob, ``bias`` (3,) rad/s, ``P`` (6, 6) covariance of ``[θ (rad), δb (rad/s)]``.
DELAYED_STATE = np.dtype([("q", np.float64, 4), ("bias", np.float64, 3),
                          ("P", np.float64, (6, 6))])


class DelayedCoefficients(NamedTuple):
    """``sigma_mag_rad``/``sigma_sun_rad`` direction noise of the pairs; ``arw_rad_rt_s``,
    ``bias_rw_rad_s_rt_s`` process noise; ``max_dt_s`` gaps; the delayed pair's
    ``delay_samples`` M and ``swing_gain``."""

    sigma_mag_rad: float
    sigma_sun_rad: float
    arw_rad_rt_s: float
    bias_rw_rad_s_rt_s: float
    max_dt_s: float
    delay_samples: int
    swing_gain: float


def delayed_coefficients(p) -> DelayedCoefficients:
    """From a ``MagGyroMEKFParams`` (read by attribute)."""
    return DelayedCoefficients(float(p.sigma_mag_rad), float(p.sigma_sun_rad),
                               float(p.arw_rad_rt_s), float(p.bias_rw_rad_s_rt_s),
                               float(p.max_dt_s), int(p.delay_samples), float(p.swing_gain))


class _Work(NamedTuple):
    """Scratch matrices of one vector update and of the covariance propagation."""

    K: np.ndarray  # (6, 3) gain
    S: np.ndarray  # (3, 3) innovation covariance
    Sinv: np.ndarray  # (3, 3)
    PHt: np.ndarray  # (6, 3) P Hᵀ
    dx: np.ndarray  # (6,) correction [θ, δb]
    A: np.ndarray  # (3, 3) attitude block of Φ
    PP: np.ndarray  # (6, 6) Φ P


@njit(inline="always")
def _work():
    return _Work(np.empty((6, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((6, 3)),
                 np.empty(6), np.empty((3, 3)), np.empty((6, 6)))


@njit(inline="always", error_model="numpy")
def delayed_propagate_covariance(c, P, wx, wy, wz, dt, work):
    """``P <- Φ P Φᵀ + diag(arw² dt I, bias_rw² dt I)``, ``Φ = [[I − [ω×] dt, −I dt], [0, I]]``
    (``ω = ω_ib − b̂`` rad/s), by blocks."""
    A, PP = work.A, work.PP
    A[0, 0] = 1.0
    A[0, 1] = wz * dt
    A[0, 2] = -wy * dt
    A[1, 0] = -wz * dt
    A[1, 1] = 1.0
    A[1, 2] = wx * dt
    A[2, 0] = wy * dt
    A[2, 1] = -wx * dt
    A[2, 2] = 1.0
    for k in range(6):  # PP = Φ P
        for a in range(3):
            PP[a, k] = (A[a, 0] * P[0, k] + A[a, 1] * P[1, k] + A[a, 2] * P[2, k]
                        - dt * P[3 + a, k])
            PP[3 + a, k] = P[3 + a, k]
    for a in range(6):  # P = PP Φᵀ
        for k in range(3):
            P[a, k] = (PP[a, 0] * A[k, 0] + PP[a, 1] * A[k, 1] + PP[a, 2] * A[k, 2]
                       - dt * PP[a, 3 + k])
            P[a, 3 + k] = PP[a, 3 + k]
    for a in range(3):
        P[a, a] += c.arw_rad_rt_s * c.arw_rad_rt_s * dt
        P[3 + a, 3 + a] += c.bias_rw_rad_s_rt_s * c.bias_rw_rad_s_rt_s * dt


@njit(inline="always", error_model="numpy")
def delayed_vector_update(q, bias, P, ub, uo, sigma, work):
    """One unit-vector measurement (body ``ub``, reference ``uo``, tuples) with direction
    noise ``sigma`` (rad): ``K = P Hᵀ (H P Hᵀ + σ² I)⁻¹``, ``[θ; δb] = K (ub − m̂)``,
    ``P <- P − K H P``; False (nothing changed) if the innovation covariance is singular."""
    K, S, Sinv, PHt, dx = work.K, work.S, work.Sinv, work.PHt, work.dx
    mx, my, mz = rotate_inv(q[0], q[1], q[2], q[3], uo[0], uo[1], uo[2])  # m̂ = R_bo uo
    for a in range(6):  # P Hᵀ, H = [[m̂×], 0]
        PHt[a, 0] = -mz * P[a, 1] + my * P[a, 2]
        PHt[a, 1] = mz * P[a, 0] - mx * P[a, 2]
        PHt[a, 2] = -my * P[a, 0] + mx * P[a, 1]
    for k in range(3):
        S[0, k] = -mz * PHt[1, k] + my * PHt[2, k]
        S[1, k] = mz * PHt[0, k] - mx * PHt[2, k]
        S[2, k] = -my * PHt[0, k] + mx * PHt[1, k]
    for a in range(3):
        S[a, a] += sigma * sigma
    det = inv3_into(S, Sinv)
    if not (det > 0.0 and det < 1e300):
        return False
    for a in range(6):
        for k in range(3):
            K[a, k] = PHt[a, 0] * Sinv[0, k] + PHt[a, 1] * Sinv[1, k] + PHt[a, 2] * Sinv[2, k]
    y0, y1, y2 = ub[0] - mx, ub[1] - my, ub[2] - mz
    for a in range(6):
        dx[a] = K[a, 0] * y0 + K[a, 1] * y1 + K[a, 2] * y2
    for a in range(6):
        for k in range(6):
            P[a, k] -= K[a, 0] * PHt[k, 0] + K[a, 1] * PHt[k, 1] + K[a, 2] * PHt[k, 2]
    symmetrise(P)
    turn(q, dx[0], dx[1], dx[2])
    bias[0] += dx[3]
    bias[1] += dx[4]
    bias[2] += dx[5]
    return True


@njit(inline="always", error_model="numpy")
def delayed_second_sigma(c, q, substituted, has_old, q_old):
    """Noise (rad) of the second pair, or -1 (do not use it): ``sigma_sun_rad`` for the sun;
    for the paper's delayed magnetometer pair ``sqrt(σ_mag² + (swing_gain·Δ)²)``, Δ the
    angle between the estimate now and ``q_old`` M samples ago (-1 before M samples)."""
    if not substituted:
        return c.sigma_sun_rad
    if not has_old:
        return -1.0
    cq = abs(q[0] * q_old[0] + q[1] * q_old[1] + q[2] * q_old[2] + q[3] * q_old[3])
    swing = 2.0 * math.acos(min(1.0, cq))
    return math.sqrt(c.sigma_mag_rad * c.sigma_mag_rad + (c.swing_gain * swing) ** 2)


@njit(inline="always", error_model="numpy")
def delayed_step(c, s, dt, g, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid, substituted,
                 has_old, q_old, flags, work):
    """One sample of ``mekf-delayed`` on the record ``s``: gyro prediction (attitude and
    covariance), the magnetometer pair, the second pair (sun, or the delayed substitute
    weighted by the swing since ``q_old``); ``flags`` (4,) as the complementary filters'."""
    q, bias, P = s.q, s.bias, s.P
    for j in range(4):
        flags[j] = 0
    if not (dt > 0.0 and dt < 1e300):
        return
    # -- gyro prediction
    if predict(q, bias, dt, g, w_io_o):
        wx, wy, wz = g[0] - bias[0], g[1] - bias[1], g[2] - bias[2]
    else:
        flags[COAST] = 1
        wx = wy = wz = 0.0
    delayed_propagate_covariance(c, P, wx, wy, wz, dt, work)
    if dt > c.max_dt_s:
        flags[GAP] = 1
        flags[COAST] = 1
        return
    # -- magnetometer
    ok_m, ub, uo = unit_pair(mag_b, mag_o)
    if ok_m:
        ok_m = delayed_vector_update(q, bias, P, ub, uo, c.sigma_mag_rad, work)
    # -- sun, or the delayed magnetometer pair in its place
    ok_s = False
    if sec_valid:
        ok_s, ub, uo = unit_pair(sec_b, sec_o)
    if ok_s:
        sigma = delayed_second_sigma(c, q, substituted, has_old, q_old)
        ok_s = sigma >= 0.0 and delayed_vector_update(q, bias, P, ub, uo, sigma, work)
    flags[MAG] = 0 if ok_m else 1
    flags[SECOND] = 0 if ok_s else 1
    if not (ok_m or ok_s):
        flags[COAST] = 1


@njit(cache=True, error_model="numpy")
def delayed_batch(c, state, dt, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid,
                  substituted, q_out, bias_out, flags):
    """``mekf-delayed`` over N samples (the seed-000 remedy for the sun-sensor loss).

    ``c`` ``DelayedCoefficients``, ``state`` a ``DELAYED_STATE`` array of one element
    (continued in place). Inputs as ``spacecraft_cf.ecf_batch``, plus ``substituted`` (N,)
    bool: the second pair is the paper's magnetometer pair delayed by M samples, used
    with the noise ``sqrt(σ_mag² + (swing_gain·Δ)²)``, Δ the angle between the estimate
    now and M samples ago (this batch's own output; not before M samples). Outputs
    ``q_out`` (N, 4), ``bias_out`` (N, 3), ``flags`` (N, 4) int8.
    """
    s = state[0]
    work = _work()
    m = c.delay_samples
    for i in range(dt.shape[0]):
        has_old = i >= m
        delayed_step(c, s, dt[i], gyro[i], w_io_o[i], mag_b[i], mag_o[i], sec_b[i], sec_o[i],
                     sec_valid[i], substituted[i], has_old, q_out[i - m if has_old else i],
                     flags[i], work)
        for j in range(4):
            q_out[i, j] = s.q[j]
        for j in range(3):
            bias_out[i, j] = s.bias[j]


# ================================================================ seed 001: mekf-spacecraft
#: ``q`` (4,) q_ob, ``bias`` (3,) rad/s, ``P`` (6, 6) covariance of ``[δθ, δb]``; the inputs
#: held from the last sample to propagate to the next: ``gyro_b`` ω_ib_b and ``w_io_o``
#: (rad/s).
SPACECRAFT_STATE = np.dtype([("q", np.float64, 4), ("bias", np.float64, 3),
                             ("P", np.float64, (6, 6)), ("gyro_b", np.float64, 3),
                             ("w_io_o", np.float64, 3)])


class SpacecraftCoefficients(NamedTuple):
    """``arw_var`` rad²/s and ``rrw_var`` rad²/s³ (gyro angle and rate random walks),
    ``r_mag``/``r_sun`` variances of a unit-vector component, ``use_sun``."""

    arw_var: float
    rrw_var: float
    r_mag: float
    r_sun: float
    use_sun: bool


def spacecraft_coefficients(p) -> SpacecraftCoefficients:
    """From a ``MEKFSpacecraftParams`` (read by attribute)."""
    return SpacecraftCoefficients(float(p.gyro_arw_rad_rt_s) ** 2,
                                  float(p.gyro_rrw_rad_s_rt_s) ** 2, float(p.sigma_mag) ** 2,
                                  float(p.sigma_sun) ** 2, bool(p.use_sun))


@njit(cache=True)
def spacecraft_predict(c, s, dt):
    """Gyro prediction over ``dt`` with the held gyro sample: ``q <- q ⊗ exp((ω − b̂ −
    R_bo ω_io) dt)``, ``P <- Φ P Φᵀ + Q dt``, ``Φ = [[exp(−[ω×] dt), −I dt], [0, I]]``."""
    q = s.q
    wx, wy, wz = s.gyro_b[0] - s.bias[0], s.gyro_b[1] - s.bias[1], s.gyro_b[2] - s.bias[2]
    io = s.w_io_o
    tx, ty, tz = rotate_quadratic(q[0], -q[1], -q[2], -q[3], io[0], io[1], io[2])
    ew, ex, ey, ez = exp((wx - tx) * dt, (wy - ty) * dt, (wz - tz) * dt)
    nw, nx, ny, nz = mul(q[0], q[1], q[2], q[3], ew, ex, ey, ez)
    q[0], q[1], q[2], q[3] = normalised(nw, nx, ny, nz)
    Phi = np.eye(6)
    dw, dx, dy, dz = exp(-wx * dt, -wy * dt, -wz * dt)
    r = dcm(dw, dx, dy, dz)  # exp(−[ω×] dt) = R(exp(−ω dt))
    for i in range(3):
        for j in range(3):
            Phi[i, j] = r[3 * i + j]
        Phi[i, 3 + i] = -dt
    P = Phi @ s.P @ Phi.T
    for i in range(3):
        P[i, i] += c.arw_var * dt
        P[3 + i, 3 + i] += c.rrw_var * dt
    s.P[:, :] = P


@njit(cache=True)
def _vector_rows(q, u, ref, var, r0, H, y, R):
    """Rows ``r0 .. r0+2`` of one unit vector ``u`` (b) with reference ``ref`` (o): predicted
    ``ŷ = R_bo ref``, ``H = [[ŷ×], 0]``, ``y = u − ŷ``, ``R = var I``; returns ``|y|``."""
    yh = np.array(rotate_quadratic(q[0], -q[1], -q[2], -q[3], ref[0], ref[1], ref[2]))
    H[r0:r0 + 3, 0:3] = skew_arr(yh)
    y[r0:r0 + 3] = u - yh
    for i in range(r0, r0 + 3):
        R[i, i] = var
    return math.sqrt(y[r0] ** 2 + y[r0 + 1] ** 2 + y[r0 + 2] ** 2)


@njit(cache=True)
def spacecraft_rows(c, q, mag_u, b_o_u, sun_u, s_o_u, sun_ok, innov):
    """Measurement phase (magnetometer rows, then sun rows): ``(H (m, 6), y (m,), R (m, m))``
    of the usable unit vectors (a zero vector is a dropout); ``innov`` (2,) receives the
    innovation norms (NaN where a vector is not used)."""
    mag_ok = mag_u[0] ** 2 + mag_u[1] ** 2 + mag_u[2] ** 2 > 0.0
    sun_ok = sun_ok and sun_u[0] ** 2 + sun_u[1] ** 2 + sun_u[2] ** 2 > 0.0
    m = 3 * mag_ok + 3 * sun_ok
    H = np.zeros((m, 6))
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
def spacecraft_correct(s, H, y, R):
    """Joint update: ``K = P Hᵀ S⁻¹``, ``δx = K y``, Joseph-form ``P``, ``q <- normalise(q ⊗
    [1, δθ/2])``, ``b̂ <- b̂ + δb``."""
    P = s.P
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    dx = K @ y
    IKH = np.eye(6) - K @ H
    Pn = IKH @ P @ IKH.T + K @ R @ K.T
    s.P[:, :] = 0.5 * (Pn + Pn.T)
    q = s.q
    nw, nx, ny, nz = mul(q[0], q[1], q[2], q[3], 1.0, 0.5 * dx[0], 0.5 * dx[1], 0.5 * dx[2])
    q[0], q[1], q[2], q[3] = normalised(nw, nx, ny, nz)
    for i in range(3):
        s.bias[i] += dx[3 + i]


@njit(cache=True)
def spacecraft_step(c, s, dt, mag_u, b_o_u, sun_u, s_o_u, sun_ok, innov):
    """One sample of ``mekf-spacecraft``: propagate over ``dt`` with the held gyro sample,
    update with this sample's vectors (``innov`` (2,) gets the innovation norms)."""
    spacecraft_predict(c, s, dt)
    H, y, R = spacecraft_rows(c, s.q, mag_u, b_o_u, sun_u, s_o_u, sun_ok, innov)
    if y.shape[0] > 0:  # no usable vector (dropouts): propagation only
        spacecraft_correct(s, H, y, R)


@njit(cache=True)
def spacecraft_hold(s, gyro_b, w_io_o):
    """Keep this sample's gyro and orbital rate: they propagate to the next sample."""
    for i in range(3):
        s.gyro_b[i] = gyro_b[i]
        s.w_io_o[i] = w_io_o[i]


@njit(cache=True)
def spacecraft_batch(c, state, first, dt, gyro, mag_u, sun_u, sun_valid, b_o_u, s_o_u, w_io_o,
                     q_out, bias_out, p_diag, innov):
    """``mekf-spacecraft`` over N samples (the seed-001 remedy: the gyro instead of dynamics).

    ``c`` ``SpacecraftCoefficients``; ``state`` a ``SPACECRAFT_STATE`` array of one element,
    continued in place. Rows ``k >= first`` are filter steps over ``dt[k]`` s (with the
    gyro and ``w_io_o`` held from row k−1, or from the state at k = 0); ``first = 1`` for
    a fresh start (row 0 is the initial state), 0 to continue an earlier run. Inputs
    (N rows): ``gyro`` ω_ib_b rad/s, unit vectors ``mag_u``, ``sun_u`` in b (zero = none),
    ``sun_valid`` bool, references ``b_o_u``, ``s_o_u`` in o, ``w_io_o`` rad/s. Outputs:
    ``q_out`` (N, 4) q_ob, ``bias_out`` (N, 3) rad/s, ``p_diag`` (N, 6) the covariance
    diagonal, ``innov`` (N, 2) innovation norms (NaN where a vector was not used).
    """
    s = state[0]
    use_sun = c.use_sun
    for k in range(dt.shape[0]):
        innov[k, 0] = np.nan
        innov[k, 1] = np.nan
        if k >= first:
            spacecraft_step(c, s, dt[k], mag_u[k], b_o_u[k], sun_u[k], s_o_u[k],
                            use_sun and sun_valid[k], innov[k])
        spacecraft_hold(s, gyro[k], w_io_o[k])
        q_out[k] = s.q
        bias_out[k] = s.bias
        for i in range(6):
            p_diag[k, i] = s.P[i, i]
