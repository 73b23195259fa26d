"""Compiled loop of the spacecraft multiplicative EKF ``mekf`` (and its presets).

Lefferts, Markley & Shuster's MEKF (JGCD 5(5), 1982; Markley & Crassidis 2014, ch. 6):
estimate ``q_ob`` (orbital from body) with the error state

    x = [θ (rad), δb (rad/s), δm (nT, optional), δs (1, optional)]      n = 6, 9 or 12

``q = q̂ ⊗ exp(θ)`` (θ in body axes), ``δb`` the gyro bias error, ``δm`` the
magnetometer bias error (``estimate_mag_bias``), ``δs`` the gyro scale-factor error
(``estimate_gyro_scale``; the gyro measures ``(I + diag(s)) ω + b``). The readable twin,
phase by phase in numpy, is ``gnomon.estimators.mekf_reference.ReadableMEKF.step``
(tested against this kernel sample by sample); the equations are in
``gnomon.estimators.mekf``'s docstring.

The numerical form is chosen by four options, so that the two filters gnomon had
before (``mekf-delayed`` for seed 000, ``mekf-spacecraft`` for seed 001) are presets of
this one and reproduce their earlier results:

* ``previous_gyro``: the gyro sample that propagates over ``t_k−1..t_k`` is the one of
  ``t_k−1`` (held in the state) | of ``t_k``;
* ``exponential``: attitude block of the transition ``exp(−[ω×] dt)`` | ``I − [ω×] dt``;
* ``relinearise``: each unit vector is linearised about the attitude already corrected
  by the ones before it in the same sample (iterated, sequential) | all about the
  predicted attitude (sequential processing of the linear measurement: the joint
  update of all rows);
* ``exp_correction``: the attitude correction ``q̂ ⊗ exp(θ)`` (exact for the error
  definition) | ``normalise(q̂ ⊗ [1, θ/2])`` (first order).

Shape (see ``gnomon.kernels``): ``STATE`` (one record), ``Coefficients`` from
``coefficients(params)``; the step's phases are the gyro prediction (attitude, then
covariance), the vector updates (magnetometer, then the sun or the delayed pair) and
the star tracker; ``row`` (one raw sample: the second pair from the tail, the step,
the gyro sample held, the estimate into the tail) is what the buffer loop
``mekf_stream`` and the per-sample kernel ``mekf_sample`` both run. The step, the
prediction and the vector update are ``inline="always"`` (a call per sample passes a
dozen arrays: measured 1.5x slower); the magnetometer, its magnitude row and the star
tracker are plain compiled functions (with everything inlined, numba took ~100 s to
compile the batch loop). Matrices live in ``(12, 12)`` storage; the
loops run over the ``n`` states in use, so a 6-state filter does 6-state work.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from gnomon.kernels.entry import BAD_GYRO
from gnomon.kernels.linalg import inv3_into, skew_into
from gnomon.kernels.quat import dcm, exp, mul, normalised, rotate_inv
from gnomon.kernels.spacecraft_cf import (
    COAST,
    GAP,
    MAG,
    RING,
    SECOND,
    SUBSTITUTED,
    SUBSTITUTES,
    TAIL_STATE,
    finite3,
    second_pair,
    turn,
    unit_pair,
)

#: flag column of a star-tracker measurement that was due and not used (gated out or
#: unusable); columns 0-3 are those of ``gnomon.kernels.spacecraft_cf``
STAR = 4
NX = 12  # storage size of the error state

#: ``q`` (4,) q_ob; ``bias`` (3,) rad/s; ``mag_bias`` (3,) nT; ``scale`` (3,) gyro scale
#: factors (1); ``P`` (12, 12) covariance of the error state (the first n rows in use);
#: ``gyro_b`` (3,) rad/s and ``w_io_o`` (3,) rad/s: the last sample's gyro and orbital
#: rate (they propagate to the next sample when ``previous_gyro``); the tail's position
#: (``spacecraft_cf.TAIL_STATE``: the delayed pair's past samples are in a ``RING``).
STATE = np.dtype([("q", np.float64, 4), ("bias", np.float64, 3),
                  ("mag_bias", np.float64, 3), ("scale", np.float64, 3),
                  ("P", np.float64, (NX, NX)), ("gyro_b", np.float64, 3),
                  ("w_io_o", np.float64, 3)] + TAIL_STATE)


class Coefficients(NamedTuple):
    """Noise: ``sigma_mag_rad``/``sigma_sun_rad`` (direction, rad), ``mag_noise_nT`` (the
    magnetometer's, adding ``(mag_noise_nT/|B|)²`` to its direction variance; 0: none),
    ``sigma_mag_norm_nT`` (of ``|B − m̂| − |B_model|``, the magnitude row used with the
    magnetometer bias; 0: no such row), ``arw_rad_rt_s``,
    ``bias_rw_rad_s_rt_s``, ``mag_bias_rw_nT_rt_s``, ``scale_rw_rt_s`` (process);
    layout: ``n`` states, ``i_mag``/``i_scale`` the first index of ``δm``/``δs`` (-1:
    not estimated); ``max_dt_s`` gaps; the delayed pair's ``delay_samples`` and
    ``swing_gain``; the form (module docstring); the star tracker's
    ``st_sigma_cross_rad``, ``st_sigma_about_rad``, ``st_latency_s``, ``st_gate_chi2``
    (0: no gate); the sun's ``substitute`` (``spacecraft_cf.SUBSTITUTES``) and
    ``use_sun`` (false: no second pair at all)."""

    sigma_mag_rad: float
    mag_noise_nT: float
    sigma_mag_norm_nT: float
    sigma_sun_rad: float
    arw_rad_rt_s: float
    bias_rw_rad_s_rt_s: float
    mag_bias_rw_nT_rt_s: float
    scale_rw_rt_s: float
    n: int
    i_mag: int
    i_scale: int
    max_dt_s: float
    delay_samples: int
    swing_gain: float
    previous_gyro: bool
    exponential: bool
    relinearise: bool
    exp_correction: bool
    st_sigma_cross_rad: float
    st_sigma_about_rad: float
    st_latency_s: float
    st_gate_chi2: float
    substitute: int
    use_sun: bool


def coefficients(p) -> Coefficients:
    """From an ``MEKFParams`` (read by attribute)."""
    n, i_mag, i_scale = 6, -1, -1
    if p.estimate_mag_bias:
        i_mag, n = n, n + 3
    if p.estimate_gyro_scale:
        i_scale, n = n, n + 3
    return Coefficients(float(p.sigma_mag_rad), float(p.mag_noise_nT),
                        float(p.sigma_mag_norm_nT), float(p.sigma_sun_rad), float(p.arw_rad_rt_s),
                        float(p.bias_rw_rad_s_rt_s), float(p.mag_bias_rw_nT_rt_s),
                        float(p.gyro_scale_rw_rt_s), n, i_mag, i_scale, float(p.max_dt_s),
                        int(p.delay_samples), float(p.swing_gain),
                        p.gyro_sample == "previous", p.transition == "exponential",
                        bool(p.relinearise), p.correction == "exponential",
                        float(p.st_sigma_cross_rad),
                        float(p.st_sigma_about_rad), float(p.st_latency_s),
                        float(p.st_gate_chi2), SUBSTITUTES[p.sun_substitute], bool(p.use_sun))


class _Work(NamedTuple):
    """Scratch of one update and of the covariance propagation."""

    H: np.ndarray  # (3, NX) measurement rows
    PHt: np.ndarray  # (NX, 3) P Hᵀ
    K: np.ndarray  # (NX, 3) gain
    S: np.ndarray  # (3, 3) innovation covariance
    Sinv: np.ndarray  # (3, 3)
    R: np.ndarray  # (3, 3) measurement noise
    dx: np.ndarray  # (NX,) correction accumulated over the sample's updates
    A: np.ndarray  # (3, 3) attitude block of Φ
    PP: np.ndarray  # (NX, NX) Φ P; P before a gated update
    innov: np.ndarray  # (1,) the last vector update's innovation norm |y|


@njit(inline="always")
def _work():
    return _Work(np.zeros((3, NX)), np.empty((NX, 3)), np.empty((NX, 3)), np.empty((3, 3)),
                 np.empty((3, 3)), np.zeros((3, 3)), np.zeros(NX), np.empty((3, 3)),
                 np.empty((NX, NX)), np.zeros(1))


# ---------------------------------------------------------------- gyro prediction
@njit(inline="always", error_model="numpy")
def rate(c, s, gx, gy, gz):
    """``ω̂_ib = (g − b̂) / (1 + ŝ)`` (rad/s) of the gyro sample ``g``; False with zeros if
    ``g`` is unusable."""
    if not (abs(gx) < 1e6 and abs(gy) < 1e6 and abs(gz) < 1e6):
        return False, 0.0, 0.0, 0.0
    wx, wy, wz = gx - s.bias[0], gy - s.bias[1], gz - s.bias[2]
    if c.i_scale >= 0:
        wx, wy, wz = wx / (1.0 + s.scale[0]), wy / (1.0 + s.scale[1]), wz / (1.0 + s.scale[2])
    return True, wx, wy, wz


@njit(inline="always", error_model="numpy")
def predict_attitude(q, wx, wy, wz, iox, ioy, ioz, dt):
    """``q <- normalise(q ⊗ exp((ω̂_ib − R_bo ω_io) dt))``."""
    tx, ty, tz = rotate_inv(q[0], q[1], q[2], q[3], iox, ioy, ioz)
    turn(q, (wx - tx) * dt, (wy - ty) * dt, (wz - tz) * dt)


@njit(inline="always", error_model="numpy")
def propagate_covariance(c, P, wx, wy, wz, dt, work):
    """``P <- Φ P Φᵀ + Q dt``. Φ is the identity but for the attitude rows
    ``[A, −I dt, 0, −diag(ω̂) dt]``, ``A = exp(−[ω̂×] dt)`` or ``I − [ω̂×] dt`` (the
    latter only for turns ``|ω̂| dt`` up to 0.1 rad, where it holds);
    ``Q = diag(arw², bias_rw², mag_bias_rw², scale_rw²)``."""
    A, PP, n, isc = work.A, work.PP, c.n, c.i_scale
    # the first-order form only holds for a small turn: beyond 0.1 rad, the exponential
    if c.exponential or (wx * wx + wy * wy + wz * wz) * dt * dt > 0.01:
        ew, ex, ey, ez = exp(-wx * dt, -wy * dt, -wz * dt)
        r = dcm(ew, ex, ey, ez)  # exp(−[ω×] dt) = R(exp(−ω dt))
        for a in range(3):
            for k in range(3):
                A[a, k] = r[3 * a + k]
    else:  # I − [ω×] dt
        skew_into(A, 0, -dt, wx, wy, wz)
        A[0, 0] = 1.0
        A[1, 1] = 1.0
        A[2, 2] = 1.0
    w = (wx, wy, wz)
    for k in range(n):  # PP = Φ P
        for a in range(3):
            v = A[a, 0] * P[0, k] + A[a, 1] * P[1, k] + A[a, 2] * P[2, k] - dt * P[3 + a, k]
            if isc >= 0:
                v -= w[a] * dt * P[isc + a, k]
            PP[a, k] = v
        for a in range(3, n):
            PP[a, k] = P[a, k]
    for a in range(n):  # P = PP Φᵀ
        for k in range(3):
            v = PP[a, 0] * A[k, 0] + PP[a, 1] * A[k, 1] + PP[a, 2] * A[k, 2] - dt * PP[a, 3 + k]
            if isc >= 0:
                v -= w[k] * dt * PP[a, isc + k]
            P[a, k] = v
        for k in range(3, n):
            P[a, k] = PP[a, k]
    for a in range(3):
        P[a, a] += c.arw_rad_rt_s * c.arw_rad_rt_s * dt
        P[3 + a, 3 + a] += c.bias_rw_rad_s_rt_s * c.bias_rw_rad_s_rt_s * dt
        if c.i_mag >= 0:
            P[c.i_mag + a, c.i_mag + a] += c.mag_bias_rw_nT_rt_s ** 2 * dt
        if isc >= 0:
            P[isc + a, isc + a] += c.scale_rw_rt_s ** 2 * dt


# ---------------------------------------------------------------- updates
@njit(inline="always", error_model="numpy")
def update3(n, P, y0, y1, y2, i_h2, work):
    """One 3-row update of the rows ``work.H`` with noise ``work.R`` and innovation ``y``
    (about the point before this sample's corrections ``work.dx``):
    ``K = P Hᵀ S⁻¹``, ``dx += K (y − H dx)``, ``P <- P − K H P`` (symmetrised). ``H`` is
    zero but in columns 0-2 and, if ``i_h2 >= 0``, ``i_h2 .. i_h2+2`` (the loops skip the
    zeros). Returns the innovation's ``χ² = rᵀ S⁻¹ r`` (``r = y − H dx``), or -1 (nothing
    changed) if ``S`` is singular."""
    H, PHt, K, S, Sinv, R, dx = work.H, work.PHt, work.K, work.S, work.Sinv, work.R, work.dx
    for a in range(n):  # P Hᵀ
        for j in range(3):
            v = P[a, 0] * H[j, 0] + P[a, 1] * H[j, 1] + P[a, 2] * H[j, 2]
            if i_h2 >= 0:
                v += (P[a, i_h2] * H[j, i_h2] + P[a, i_h2 + 1] * H[j, i_h2 + 1]
                      + P[a, i_h2 + 2] * H[j, i_h2 + 2])
            PHt[a, j] = v
    for i in range(3):
        for j in range(3):
            v = H[i, 0] * PHt[0, j] + H[i, 1] * PHt[1, j] + H[i, 2] * PHt[2, j]
            if i_h2 >= 0:
                v += (H[i, i_h2] * PHt[i_h2, j] + H[i, i_h2 + 1] * PHt[i_h2 + 1, j]
                      + H[i, i_h2 + 2] * PHt[i_h2 + 2, j])
            S[i, j] = v + R[i, j]
    det = inv3_into(S, Sinv)
    if not (det > 0.0 and det < 1e300):
        return -1.0
    r0, r1, r2 = y0, y1, y2
    for k in range(n):  # H dx (dx is zero but after an earlier update of this sample)
        if dx[k] != 0.0:
            r0 -= H[0, k] * dx[k]
            r1 -= H[1, k] * dx[k]
            r2 -= H[2, k] * dx[k]
    chi2 = (r0 * (Sinv[0, 0] * r0 + Sinv[0, 1] * r1 + Sinv[0, 2] * r2)
            + r1 * (Sinv[1, 0] * r0 + Sinv[1, 1] * r1 + Sinv[1, 2] * r2)
            + r2 * (Sinv[2, 0] * r0 + Sinv[2, 1] * r1 + Sinv[2, 2] * r2))
    for a in range(n):
        for j in range(3):
            K[a, j] = PHt[a, 0] * Sinv[0, j] + PHt[a, 1] * Sinv[1, j] + PHt[a, 2] * Sinv[2, j]
    for a in range(n):
        dx[a] += K[a, 0] * r0 + K[a, 1] * r1 + K[a, 2] * r2
    for a in range(n):
        for k in range(n):
            P[a, k] -= K[a, 0] * PHt[k, 0] + K[a, 1] * PHt[k, 1] + K[a, 2] * PHt[k, 2]
    for a in range(n):
        for k in range(a):
            v = 0.5 * (P[a, k] + P[k, a])
            P[a, k] = v
            P[k, a] = v
    return chi2


@njit(inline="always", error_model="numpy")
def apply_correction(c, s, work):
    """``q <- normalise(q ⊗ exp(θ))`` (or ``normalise(q ⊗ [1, θ/2])``), ``b̂ += δb``
    (``m̂ += δm``, ``ŝ += δs``); clears ``work.dx``."""
    dx, q = work.dx, s.q
    if c.exp_correction:
        turn(q, dx[0], dx[1], dx[2])
    else:
        nw, nx, ny, nz = mul(q[0], q[1], q[2], q[3], 1.0, 0.5 * dx[0], 0.5 * dx[1], 0.5 * dx[2])
        q[0], q[1], q[2], q[3] = normalised(nw, nx, ny, nz)
    for a in range(3):
        s.bias[a] += dx[3 + a]
        if c.i_mag >= 0:
            s.mag_bias[a] += dx[c.i_mag + a]
        if c.i_scale >= 0:
            s.scale[a] += dx[c.i_scale + a]
    for a in range(c.n):
        dx[a] = 0.0


@njit(inline="always", error_model="numpy")
def vector_update(c, s, ub, uo, sigma, mag_norm, work):
    """One unit-vector measurement (body ``ub``, reference ``uo``, tuples; noise ``sigma``
    rad per direction): ``m̂ = R_bo uo``, ``H = [[m̂×], 0, (I − ub ubᵀ)/|B| (the
    magnetometer with its bias estimated: ``mag_norm`` = |B − m̂_bias| > 0), 0]``,
    ``y = ub − m̂``. Applied at once when ``relinearise``. False if unusable."""
    q, H, R = s.q, work.H, work.R
    mx, my, mz = rotate_inv(q[0], q[1], q[2], q[3], uo[0], uo[1], uo[2])
    for j in range(3):
        for k in range(c.n):
            H[j, k] = 0.0
    H[0, 1], H[0, 2] = -mz, my
    H[1, 0], H[1, 2] = mz, -mx
    H[2, 0], H[2, 1] = -my, mx
    if mag_norm > 0.0:
        u = (ub[0], ub[1], ub[2])
        for j in range(3):
            for k in range(3):
                H[j, c.i_mag + k] = ((1.0 if j == k else 0.0) - u[j] * u[k]) / mag_norm
    for j in range(3):
        for k in range(3):
            R[j, k] = sigma * sigma if j == k else 0.0
    y0, y1, y2 = ub[0] - mx, ub[1] - my, ub[2] - mz
    work.innov[0] = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    if update3(c.n, s.P, y0, y1, y2, c.i_mag if mag_norm > 0.0 else -1, work) < 0.0:
        return False
    if c.relinearise:
        apply_correction(c, s, work)
    return True


@njit(cache=True, error_model="numpy")
def magnetometer(c, s, mag_b, mag_o, work):
    """The magnetometer pair, its bias removed when estimated (``mag_b`` and ``mag_o`` in nT
    then); a zero or non-finite ``mag_b`` is a dropout. Direction noise ``sigma_mag_rad``,
    or ``sqrt(sigma_mag_rad² + (mag_noise_nT/|B|)²)``. With the bias estimated and
    ``sigma_mag_norm_nT``, also the magnitude row ``|B − m̂| − |B_model| = uᵀ δm``."""
    nb = mag_b[0] * mag_b[0] + mag_b[1] * mag_b[1] + mag_b[2] * mag_b[2]
    if not (nb > 0.0 and nb < 1e300):
        return False
    m = s.mag_bias
    v = (mag_b[0] - m[0], mag_b[1] - m[1], mag_b[2] - m[2])  # m̂ is zero unless estimated
    ok, ub, uo = unit_pair(v, mag_o)
    if not ok:
        return False
    norm = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    sigma = c.sigma_mag_rad
    if c.mag_noise_nT > 0.0:
        sigma = math.sqrt(sigma * sigma + (c.mag_noise_nT / norm) ** 2)
    if not vector_update(c, s, ub, uo, sigma, norm if c.i_mag >= 0 else 0.0, work):
        return False
    if c.i_mag >= 0 and c.sigma_mag_norm_nT > 0.0:
        n_o = math.sqrt(mag_o[0] * mag_o[0] + mag_o[1] * mag_o[1] + mag_o[2] * mag_o[2])
        magnitude_update(c, s, ub, norm - n_o, work)
    return True


@njit(cache=True, error_model="numpy")
def magnitude_update(c, s, u, y, work):
    """The scalar row ``y = |B − m̂| − |B_model| = uᵀ δm + noise`` (``u`` the unit measured
    field, noise ``sigma_mag_norm_nT``): the field's magnitude, which the unit vector
    drops, tells the bias along the field (TWOSTEP's information, in the filter).
    Kalman update of one row (about this sample's earlier corrections ``work.dx``)."""
    n, i, P, dx, ph = c.n, c.i_mag, s.P, work.dx, work.PHt
    for a in range(n):  # P Hᵀ (column 0 of the scratch)
        ph[a, 0] = P[a, i] * u[0] + P[a, i + 1] * u[1] + P[a, i + 2] * u[2]
    S = u[0] * ph[i, 0] + u[1] * ph[i + 1, 0] + u[2] * ph[i + 2, 0] + c.sigma_mag_norm_nT ** 2
    if not (S > 0.0 and S < 1e300):
        return
    r = y - (u[0] * dx[i] + u[1] * dx[i + 1] + u[2] * dx[i + 2])
    for a in range(n):
        dx[a] += ph[a, 0] / S * r
    for a in range(n):
        for k in range(n):
            P[a, k] -= ph[a, 0] * ph[k, 0] / S
    for a in range(n):
        for k in range(a):
            v = 0.5 * (P[a, k] + P[k, a])
            P[a, k] = v
            P[k, a] = v
    if c.relinearise:
        apply_correction(c, s, work)


@njit(inline="always", error_model="numpy")
def second_sigma(c, q, substituted, has_old, q_old):
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


@njit(cache=True, error_model="numpy")
def star_tracker(c, s, st_q, bore, wx, wy, wz, work):
    """The star tracker's attitude ``st_q = q_oi(t) ⊗ q̂_ib(t − L)`` (inertial, measured
    ``L = st_latency_s`` before its stamp t, turned into o at t), carried to t with the
    inertial rate ``ω̂_ib``: ``q_m = st_q ⊗ exp(ω̂_ib L)``; ``y = rotvec(q̂⁻¹ ⊗ q_m)``,
    ``H = [I, 0]``, ``R = σ_c² (I − b bᵀ) + σ_a² b bᵀ`` (``b`` the unit boresight in b),
    the gain that of ``P − arw² L I`` on the attitude (the gyro noise over L is in the
    prediction and in the carried measurement alike); gated at ``χ² > st_gate_chi2``.
    Applied at once. False if unusable or gated out."""
    if not (abs(st_q[0]) <= 1.0 and abs(st_q[1]) <= 1.0 and abs(st_q[2]) <= 1.0
            and abs(st_q[3]) <= 1.0):
        return False
    nb = math.sqrt(bore[0] * bore[0] + bore[1] * bore[1] + bore[2] * bore[2])
    if not (nb > 0.0 and nb < 1e300):
        return False
    L = c.st_latency_s
    mw, mx, my, mz = exp(wx * L, wy * L, wz * L)
    mw, mx, my, mz = mul(st_q[0], st_q[1], st_q[2], st_q[3], mw, mx, my, mz)
    q = s.q
    dw, dx_, dy, dz = mul(q[0], -q[1], -q[2], -q[3], mw, mx, my, mz)  # q̂⁻¹ ⊗ q_m
    if dw < 0.0:
        dw, dx_, dy, dz = -dw, -dx_, -dy, -dz
    v = math.sqrt(dx_ * dx_ + dy * dy + dz * dz)
    f = 2.0 * math.atan2(v, dw) / v if v > 1e-12 else 2.0
    H, R = work.H, work.R
    for j in range(3):
        for k in range(c.n):
            H[j, k] = 1.0 if j == k else 0.0
    b = (bore[0] / nb, bore[1] / nb, bore[2] / nb)
    sc2, sa2 = c.st_sigma_cross_rad ** 2, c.st_sigma_about_rad ** 2
    for j in range(3):
        for k in range(3):
            R[j, k] = (sa2 - sc2) * b[j] * b[k] + (sc2 if j == k else 0.0)
    saved = work.PP
    for a in range(c.n):
        for k in range(c.n):
            saved[a, k] = s.P[a, k]
    # the measurement sees the error of t − L: the gyro noise since then (arw² L) is in
    # P(t) and in the carried measurement alike, so the gain is that of P(t) − Q_L
    lat = c.arw_rad_rt_s * c.arw_rad_rt_s * L
    for a in range(3):
        s.P[a, a] -= lat
    chi2 = update3(c.n, s.P, f * dx_, f * dy, f * dz, -1, work)
    for a in range(3):
        s.P[a, a] += lat
    if chi2 < 0.0 or (c.st_gate_chi2 > 0.0 and chi2 > c.st_gate_chi2):  # an outlier: undo
        for a in range(c.n):
            work.dx[a] = 0.0
            for k in range(c.n):
                s.P[a, k] = saved[a, k]
        return False
    apply_correction(c, s, work)
    return True


# ---------------------------------------------------------------- one sample, the batch
@njit(inline="always", error_model="numpy")
def step(c, s, dt, g, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid, substituted, has_old,
         q_old, st_q, st_valid, st_bore, flags, innov, work):
    """One sample on the record ``s``: gyro prediction over ``dt`` (attitude, covariance),
    the magnetometer, the second pair (sun, or the delayed substitute weighted by the
    swing since ``q_old``), the star tracker; ``flags`` (5,) (columns of
    ``spacecraft_cf`` and ``STAR``), ``innov`` (2,) the innovation norms of the
    magnetometer and the second pair (NaN where not used). The gyro sample is ``g`` or,
    with ``previous_gyro``, the one held in ``s`` (with its ``w_io_o``)."""
    q = s.q
    for j in range(5):
        flags[j] = 0
    innov[0] = np.nan
    innov[1] = np.nan
    if not (dt > 0.0 and dt < 1e300):
        return
    # -- gyro prediction
    if c.previous_gyro:
        gx, gy, gz = s.gyro_b[0], s.gyro_b[1], s.gyro_b[2]
        iox, ioy, ioz = s.w_io_o[0], s.w_io_o[1], s.w_io_o[2]
    else:
        gx, gy, gz = g[0], g[1], g[2]
        iox, ioy, ioz = w_io_o[0], w_io_o[1], w_io_o[2]
    ok_g, wx, wy, wz = rate(c, s, gx, gy, gz)
    if ok_g:
        predict_attitude(q, wx, wy, wz, iox, ioy, ioz, dt)
    else:
        flags[COAST] = 1
    propagate_covariance(c, s.P, wx, wy, wz, dt, work)
    if dt > c.max_dt_s:
        flags[GAP] = 1
        flags[COAST] = 1
        return
    # -- magnetometer, then the sun or the delayed magnetometer pair in its place
    ok_m = magnetometer(c, s, mag_b, mag_o, work)
    if ok_m:
        innov[0] = work.innov[0]
    ok_s = False
    if sec_valid:
        ok_s, ub, uo = unit_pair(sec_b, sec_o)
    if ok_s:
        sigma = second_sigma(c, q, substituted, has_old, q_old)
        ok_s = sigma >= 0.0 and vector_update(c, s, ub, uo, sigma, 0.0, work)
        if ok_s:
            innov[1] = work.innov[0]
    if not c.relinearise and (ok_m or ok_s):
        apply_correction(c, s, work)
    # -- star tracker
    ok_t = False
    if st_valid:
        ok_t = star_tracker(c, s, st_q, st_bore, wx, wy, wz, work)
        flags[STAR] = 0 if ok_t else 1
    flags[MAG] = 0 if ok_m else 1
    flags[SECOND] = 0 if ok_s else 1
    if not (ok_m or ok_s or ok_t):
        flags[COAST] = 1


@njit(inline="always", error_model="numpy")
def row(c, s, ring, dt, g, w_io_o, mag_b, mag_o, sun_b, sun_o, sun_valid, substituted, given,
        st_q, st_valid, st_bore, flags, innov, work):
    """One raw sample on the record ``s`` and its tail ``ring``: the second pair (the sun,
    or the magnetometer pair ``delay_samples`` ago: ``spacecraft_cf.second_pair``; with
    ``given``, ``sun_b``/``sun_o``/``sun_valid``/``substituted`` are that pair already),
    ``step`` (the delayed pair weighted by the swing since the estimate in the tail), the
    gyro sample held, the estimate into the tail. Returns whether the second pair was the
    substitute."""
    m = c.delay_samples
    k = s.n_seen
    if given:
        slot = k % m
        s.n_seen = k + 1
        sb, so = (sun_b[0], sun_b[1], sun_b[2]), (sun_o[0], sun_o[1], sun_o[2])
        ok, sub = sun_valid, substituted
    else:
        sb, so, ok, sub, slot = second_pair(c, c.substitute, s, ring, dt, g, w_io_o, mag_b,
                                            mag_o, sun_b, sun_o, sun_valid)
        ok = ok and c.use_sun
    step(c, s, dt, g, w_io_o, mag_b, mag_o, sb, so, ok, sub, k >= m, ring[slot].q, st_q,
         st_valid, st_bore, flags, innov, work)
    for j in range(3):  # hold: propagates to the next sample when previous_gyro
        s.gyro_b[j] = g[j]
        s.w_io_o[j] = w_io_o[j]
    if c.substitute > 0:  # the tail is read only for the delayed pair
        q_then = ring[slot].q
        for j in range(4):
            q_then[j] = s.q[j]
    return sub


@njit(cache=True, error_model="numpy")
def mekf_stream(c, state, ring, dt, gyro, w_io_o, mag_b, mag_o, sun_b, sun_o, sun_valid,
                substituted, given, st_q, st_valid, st_bore, q_out, bias_out, mag_bias_out,
                scale_out, p_out, flags, innov):
    """``mekf`` over N raw samples (``row`` per row), continuing ``state`` and its tail
    ``ring`` (``spacecraft_cf.RING``, ``delay_samples`` records) in place.

    ``c`` ``Coefficients``. Inputs (N rows): ``dt`` s (row k steps from row k−1; 0 or
    non-finite: no step), ``gyro`` ω_ib_b rad/s, ``w_io_o`` rad/s (o), the magnetometer
    pair ``mag_b`` (b, nT) / ``mag_o`` (o), the sun pair ``sun_b`` / ``sun_o`` with
    ``sun_valid`` (where it is not, the paper's magnetometer pair delayed by
    ``delay_samples`` from the tail if ``c.substitute``, used with the noise
    ``sqrt(σ_mag² + (swing_gain·Δ)²)``, Δ the angle between the estimate now and M
    samples ago); ``substituted`` (N,) bool written with the rows whose second pair was
    the substitute (``given``: the second pairs ``sun_b``, ``sun_o``, ``sun_valid`` are
    given already, ``substituted`` says which are the substitute); the star tracker's
    ``st_q`` q̂_ob (N, 4) with ``st_valid`` and its boresight ``st_bore`` (b). Outputs:
    ``q_out`` (N, 4) q_ob, ``bias_out`` (N, 3) rad/s, ``mag_bias_out`` (N, 3) nT,
    ``scale_out`` (N, 3), ``p_out`` (N, n, n) the covariance (or (N, 0, 0): not kept),
    ``flags`` (N, 5) int8, ``innov`` (N, 2) the innovation norms of the magnetometer and
    the second pair (NaN where not used).
    """
    s = state[0]
    work = _work()
    keep_p = p_out.shape[1] > 0
    for i in range(dt.shape[0]):
        substituted[i] = row(c, s, ring, dt[i], gyro[i], w_io_o[i], mag_b[i], mag_o[i],
                             sun_b[i], sun_o[i], sun_valid[i], substituted[i], given, st_q[i],
                             st_valid[i], st_bore[i], flags[i], innov[i], work)
        for j in range(4):
            q_out[i, j] = s.q[j]
        for j in range(3):
            bias_out[i, j] = s.bias[j]
            mag_bias_out[i, j] = s.mag_bias[j]
            scale_out[i, j] = s.scale[j]
        if keep_p:
            for a in range(c.n):
                for k in range(c.n):
                    p_out[i, a, k] = s.P[a, k]


@njit(cache=True, error_model="numpy")
def mekf_sample(dt, gyro, w_io_o, mag_b, mag_o, sun_b, sun_o, st_q, st_bore, state, ring, c,
                q_out):
    """One raw sample as a row of ``mekf_stream`` (the same arithmetic): ``dt`` (s), the
    vectors (3,) and the star tracker's ``st_q`` (4,) (a sun pair or a tracker attitude
    with a non-finite component: none); ``state``, ``ring`` updated in place; ``c`` the
    coefficients as a record (``gnomon.kernels.entry.record``); ``q_out`` (4,) the
    estimate. Returns the flag bits ``1 << column`` (``SUBSTITUTED`` too), or ``BAD_GYRO``
    alone for a non-finite gyro sample (nothing done)."""
    if not finite3(gyro):
        return BAD_GYRO
    s = state[0]
    flags = np.zeros(5, np.int8)
    innov = np.empty(2)
    st_valid = (finite3(st_q) and math.isfinite(st_q[3]))
    sub = row(c[0], s, ring, dt, gyro, w_io_o, mag_b, mag_o, sun_b, sun_o, True, False, False,
              st_q, st_valid, st_bore, flags, innov, _work())
    f = SUBSTITUTED if sub else 0
    for j in range(5):
        f |= int(flags[j]) << j
    for j in range(4):
        q_out[j] = s.q[j]
    return f


def mekf_batch(c, state, dt, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid,
               substituted, st_q, st_valid, st_bore, q_out, bias_out, mag_bias_out,
               scale_out, p_out, flags, innov):
    """``mekf`` over N samples whose second pairs are made already (``sec_b``, ``sec_o``,
    ``sec_valid``, ``substituted``: ``gnomon.estimators.ecf_spacecraft.vector_pairs``),
    continuing ``state``: ``mekf_stream`` with ``given`` (the delayed pair's swing from
    a tail of this call's estimates; the rest as there). Seed 000's speed table times it."""
    mekf_stream(c, state, np.zeros(c.delay_samples, RING), dt, gyro, w_io_o, mag_b, mag_o,
                sec_b, sec_o, sec_valid, np.asarray(substituted, np.bool_).copy(), True, st_q,
                st_valid, st_bore, q_out, bias_out, mag_bias_out, scale_out, p_out, flags,
                innov)
