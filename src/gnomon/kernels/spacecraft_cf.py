"""Compiled loops of the spacecraft complementary filters of seed 000.

Twins of the readable ``update`` methods in ``gnomon.estimators.ecf_spacecraft``
(explicit filter on vector pairs) and ``gnomon.estimators.qcf`` (filter driven
by a measured quaternion), and of the sequential Gauss-Newton solver
``gnomon.estimators.qcf.gauss_newton_sequence_py``. The tests compare them
sample by sample.

State conventions: ``q`` (4,) is ``q_ob`` (orbital from body), ``bias`` (3,) the
gyro-bias estimate (rad/s). The paper's ``d = K_P e + K_I ∫e`` is the same
filter with ``bias = −K_I ∫e`` (Mahony's form keeps the estimate continuous
when the integral gain switches between the two-pair and one-pair values).

Flags per sample (int8 columns): 0 mag pair unusable, 1 sun/second pair
unusable (or measured quaternion unusable), 2 time gap (gyro-only propagation),
3 coasting (no correction at all this sample).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from gnomon.kernels.quat import rotate_by


@njit(cache=True, error_model="numpy")
def _rotate_by(q, rx, ry, rz):
    """``q <- normalise(q ⊗ exp([rx, ry, rz]))`` in place (rotation vector, rad, body)."""
    if not (rx * rx + ry * ry + rz * rz < 1e12):  # non-finite or absurd: leave q unchanged
        return
    rotate_by(q, rx, ry, rz)


@njit(cache=True, error_model="numpy")
def _to_body(q, vx, vy, vz, out):
    """out = R_obᵀ v (orbital -> body) for unit q = q_ob."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    out[0] = (1.0 - 2.0 * (y * y + z * z)) * vx + 2.0 * (x * y + w * z) * vy \
        + 2.0 * (x * z - w * y) * vz
    out[1] = 2.0 * (x * y - w * z) * vx + (1.0 - 2.0 * (x * x + z * z)) * vy \
        + 2.0 * (y * z + w * x) * vz
    out[2] = 2.0 * (x * z + w * y) * vx + 2.0 * (y * z - w * x) * vy \
        + (1.0 - 2.0 * (x * x + y * y)) * vz


@njit(cache=True, error_model="numpy")
def _unit_pair(vb, vo, ub, uo):
    """Normalise a body/reference pair into ub, uo; False if either is zero or non-finite."""
    nb = math.sqrt(vb[0] * vb[0] + vb[1] * vb[1] + vb[2] * vb[2])
    no = math.sqrt(vo[0] * vo[0] + vo[1] * vo[1] + vo[2] * vo[2])
    if not (nb > 0.0 and no > 0.0 and nb < 1e300 and no < 1e300):
        return False
    for j in range(3):
        ub[j] = vb[j] / nb
        uo[j] = vo[j] / no
    return True


@njit(cache=True, error_model="numpy")
def _propagate(q, bias, dt, g, w_io_o, tmp):
    """Predict: q <- q ⊗ exp((ω_ib − R_bo ω_io − b̂) dt); False (no motion) if the gyro is bad."""
    gx, gy, gz = g[0], g[1], g[2]
    if not (abs(gx) < 1e6 and abs(gy) < 1e6 and abs(gz) < 1e6):
        return False
    _to_body(q, w_io_o[0], w_io_o[1], w_io_o[2], tmp)
    _rotate_by(q, (gx - tmp[0] - bias[0]) * dt, (gy - tmp[1] - bias[1]) * dt,
               (gz - tmp[2] - bias[2]) * dt)
    return True


@njit(cache=True, error_model="numpy")
def _vector_error(q, ub, uo, weight, e, tmp):
    """e += weight * ub × (R_bo uo)  (Mahony's explicit correction, body frame)."""
    _to_body(q, uo[0], uo[1], uo[2], tmp)
    e[0] += weight * (ub[1] * tmp[2] - ub[2] * tmp[1])
    e[1] += weight * (ub[2] * tmp[0] - ub[0] * tmp[2])
    e[2] += weight * (ub[0] * tmp[1] - ub[1] * tmp[0])


@njit(cache=True, error_model="numpy")
def ecf_batch(dt, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid, q, bias,
              kp, ki, kp_single, ki_single, k_mag, k_sec, max_dt, min_sin,
              q_out, bias_out, flags):
    """Explicit complementary filter on two vector pairs (seed 000 baseline, Mahony 2008).

    Inputs (N rows): ``dt`` s (dt[0] = 0 keeps the initial state), ``gyro`` ω_ib_b
    rad/s, ``w_io_o`` (N, 3) rate of the orbital frame in o (rad/s), ``mag_b``,
    ``mag_o`` the magnetic pair (body, orbital; any units), ``sec_b``, ``sec_o`` the
    second pair (sun or its substitute), ``sec_valid`` (N,) bool. With both pairs
    usable the gains are ``kp``, ``ki``; with only one, ``kp_single``,
    ``ki_single``. Pairs closer than ``asin(min_sin)`` count as one (the magnetic
    pair). ``q`` (4,) q_ob and ``bias`` (3,) rad/s are updated in place.
    Outputs: q_out (N, 4), bias_out (N, 3), flags (N, 4) int8.
    """
    n = dt.shape[0]
    ubm = np.empty(3)
    uom = np.empty(3)
    ubs = np.empty(3)
    uos = np.empty(3)
    tmp = np.empty(3)
    e = np.empty(3)
    ki_now = ki
    for i in range(n):
        for j in range(4):
            flags[i, j] = 0
        h = dt[i]
        if h > 0.0 and h < 1e300:
            if not _propagate(q, bias, h, gyro[i], w_io_o[i], tmp):
                flags[i, 3] = 1
            if h > max_dt:
                flags[i, 2] = 1
                flags[i, 3] = 1
            else:
                ok_m = _unit_pair(mag_b[i], mag_o[i], ubm, uom)
                ok_s = sec_valid[i] and _unit_pair(sec_b[i], sec_o[i], ubs, uos)
                if ok_m and ok_s:
                    cx = uom[1] * uos[2] - uom[2] * uos[1]
                    cy = uom[2] * uos[0] - uom[0] * uos[2]
                    cz = uom[0] * uos[1] - uom[1] * uos[0]
                    if math.sqrt(cx * cx + cy * cy + cz * cz) < min_sin:
                        ok_s = False
                flags[i, 0] = 0 if ok_m else 1
                flags[i, 1] = 0 if ok_s else 1
                e[0] = 0.0
                e[1] = 0.0
                e[2] = 0.0
                if ok_m:
                    _vector_error(q, ubm, uom, k_mag, e, tmp)
                if ok_s:
                    _vector_error(q, ubs, uos, k_sec, e, tmp)
                if ok_m and ok_s:
                    g_p = kp
                    ki_now = ki
                elif ok_m or ok_s:
                    g_p = kp_single
                    ki_now = ki_single
                else:
                    g_p = 0.0
                    flags[i, 3] = 1
                if ok_m or ok_s:
                    for j in range(3):
                        bias[j] -= ki_now * e[j] * h
                    _rotate_by(q, g_p * e[0] * h, g_p * e[1] * h, g_p * e[2] * h)
        for j in range(4):
            q_out[i, j] = q[j]
        for j in range(3):
            bias_out[i, j] = bias[j]


@njit(cache=True, error_model="numpy")
def qcf_batch(dt, gyro, w_io_o, q_mes, mes_valid, mag_b, mag_o, q, bias, kp, ki,
              kp_single, ki_single, max_dt, q_out, bias_out, flags):
    """Complementary filter driven by a measured quaternion (seed 000's proposal).

    ``q_mes`` (N, 4) q_ob measured (any Wahba solver), ``mes_valid`` (N,) bool.
    Correction: ``e = conj(q̂) ⊗ q_mes`` (sign chosen so that e_w >= 0), PI on its
    vector part: ``q̂ <- q̂ ⊗ exp(kp vec(e) dt)``, ``bias -= ki vec(e) dt``. Without a
    usable q_mes but with a usable magnetic pair the filter falls back to the
    explicit single-vector correction with ``kp_single``, ``ki_single`` (the
    magnetometer + gyro filter; set both to 0 to coast on the gyro). Flags as in
    ``ecf_batch`` (column 1: q_mes unusable).
    """
    n = dt.shape[0]
    ubm = np.empty(3)
    uom = np.empty(3)
    tmp = np.empty(3)
    e = np.empty(3)
    ki_now = ki
    for i in range(n):
        for j in range(4):
            flags[i, j] = 0
        h = dt[i]
        if h > 0.0 and h < 1e300:
            if not _propagate(q, bias, h, gyro[i], w_io_o[i], tmp):
                flags[i, 3] = 1
            if h > max_dt:
                flags[i, 2] = 1
                flags[i, 3] = 1
            else:
                mw, mx, my, mz = q_mes[i, 0], q_mes[i, 1], q_mes[i, 2], q_mes[i, 3]
                nm = math.sqrt(mw * mw + mx * mx + my * my + mz * mz)
                ok_q = mes_valid[i] and nm > 0.5 and nm < 2.0
                ok_m = _unit_pair(mag_b[i], mag_o[i], ubm, uom)
                flags[i, 0] = 0 if ok_m else 1
                flags[i, 1] = 0 if ok_q else 1
                if ok_q:
                    mw /= nm
                    mx /= nm
                    my /= nm
                    mz /= nm
                    w, x, y, zz = q[0], -q[1], -q[2], -q[3]
                    ew = w * mw - x * mx - y * my - zz * mz
                    ex = w * mx + x * mw + y * mz - zz * my
                    ey = w * my - x * mz + y * mw + zz * mx
                    ez = w * mz + x * my - y * mx + zz * mw
                    if ew < 0.0:
                        ex = -ex
                        ey = -ey
                        ez = -ez
                    e[0] = ex
                    e[1] = ey
                    e[2] = ez
                    g_p = kp
                    ki_now = ki
                elif ok_m and (kp_single > 0.0 or ki_single > 0.0):
                    e[0] = 0.0
                    e[1] = 0.0
                    e[2] = 0.0
                    _vector_error(q, ubm, uom, 1.0, e, tmp)
                    g_p = kp_single
                    ki_now = ki_single
                else:
                    flags[i, 3] = 1
                    g_p = -1.0
                if g_p >= 0.0:
                    for j in range(3):
                        bias[j] -= ki_now * e[j] * h
                    _rotate_by(q, g_p * e[0] * h, g_p * e[1] * h, g_p * e[2] * h)
        for j in range(4):
            q_out[i, j] = q[j]
        for j in range(3):
            bias_out[i, j] = bias[j]


@njit(cache=True, error_model="numpy")
def _rot_unnorm(q, v, out):
    w, ux, uy, uz = q[0], q[1], q[2], q[3]
    uu = ux * ux + uy * uy + uz * uz
    uv = ux * v[0] + uy * v[1] + uz * v[2]
    cx = uy * v[2] - uz * v[1]
    cy = uz * v[0] - ux * v[2]
    cz = ux * v[1] - uy * v[0]
    out[0] = (w * w - uu) * v[0] + 2.0 * uv * ux + 2.0 * w * cx
    out[1] = (w * w - uu) * v[1] + 2.0 * uv * uy + 2.0 * w * cy
    out[2] = (w * w - uu) * v[2] + 2.0 * uv * uz + 2.0 * w * cz


@njit(cache=True, error_model="numpy")
def _gn_jac(q, v, A):
    """A (3, 4) = ∂(R(q) v)/∂q of the unnormalised quadratic form."""
    w, ux, uy, uz = q[0], q[1], q[2], q[3]
    u = (ux, uy, uz)
    uv = ux * v[0] + uy * v[1] + uz * v[2]
    A[0, 0] = 2.0 * w * v[0] + 2.0 * (uy * v[2] - uz * v[1])
    A[1, 0] = 2.0 * w * v[1] + 2.0 * (uz * v[0] - ux * v[2])
    A[2, 0] = 2.0 * w * v[2] + 2.0 * (ux * v[1] - uy * v[0])
    for a in range(3):
        for c in range(3):
            val = -2.0 * v[a] * u[c] + 2.0 * u[a] * v[c]
            if a == c:
                val += 2.0 * uv
            A[a, 1 + c] = val
    # - 2 w [v×]
    A[0, 2] += 2.0 * w * v[2]
    A[0, 3] -= 2.0 * w * v[1]
    A[1, 1] -= 2.0 * w * v[2]
    A[1, 3] += 2.0 * w * v[0]
    A[2, 1] += 2.0 * w * v[1]
    A[2, 2] -= 2.0 * w * v[0]


@njit(cache=True, error_model="numpy")
def _solve4(N, g, x, L, y):
    """Solve N x = g (4x4, symmetric positive definite) by Cholesky (buffers L (4, 4), y (4,));
    False if not positive definite."""
    for i in range(4):
        for j in range(i + 1):
            s = N[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if not (s > 1e-14):
                    return False
                L[i, i] = math.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    for i in range(4):
        s = g[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    for i in range(3, -1, -1):
        s = y[i]
        for k in range(i + 1, 4):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]
    return True


@njit(cache=True, error_model="numpy")
def gn_sequence(r1, b1, r2, b2, w1, w2, valid, q0, iterations, min_quality, q_out, ok_out):
    """Seed 000's Gauss-Newton ("recursive least squares") q_ob measurement per sample.

    Pairs (N, 3): reference r1/r2 (orbital), body b1/b2 (any units, normalised
    here); weights w1, w2; ``valid`` (N,) says whether pair 2 is present. Each
    sample starts from the previous sample's solution (``q0`` (4,) at the first,
    updated in place) and takes ``iterations`` Gauss-Newton steps. ``ok_out``
    (N,) is False where the problem is degenerate (a pair unusable or the
    quality ``s2/s1`` below ``min_quality``); there q_out repeats the last good
    solution.
    """
    n = r1.shape[0]
    ur1 = np.empty(3)
    ub1 = np.empty(3)
    ur2 = np.empty(3)
    ub2 = np.empty(3)
    A = np.empty((3, 4))
    Nm = np.empty((4, 4))
    g = np.empty(4)
    dq = np.empty(4)
    pred = np.empty(3)
    L = np.zeros((4, 4))
    y4 = np.empty(4)
    q = q0
    a1 = 0.5
    a2 = 0.5
    for i in range(n):
        ok = _unit_pair(b1[i], r1[i], ub1, ur1) and valid[i] \
            and _unit_pair(b2[i], r2[i], ub2, ur2)
        if ok:
            ww = w1 + w2
            a1 = w1 / ww
            a2 = w2 / ww
            # quality s2/s1 of B = a1 r1 b1ᵀ + a2 r2 b2ᵀ from its Frobenius norm and s1 s2
            dr = ur1[0] * ur2[0] + ur1[1] * ur2[1] + ur1[2] * ur2[2]
            db = ub1[0] * ub2[0] + ub1[1] * ub2[1] + ub1[2] * ub2[2]
            fro2 = a1 * a1 + a2 * a2 + 2.0 * a1 * a2 * dr * db
            p = a1 * a2 * math.sqrt(max(0.0, 1.0 - dr * dr)) * math.sqrt(max(0.0, 1.0 - db * db))
            disc = math.sqrt(max(0.0, fro2 * fro2 - 4.0 * p * p))
            s1sq = 0.5 * (fro2 + disc)
            s2sq = 0.5 * (fro2 - disc)
            qual = math.sqrt(s2sq / s1sq) if s1sq > 0.0 else 0.0
            if qual < min_quality:
                ok = False
        if ok:
            for _ in range(iterations):
                for a in range(4):
                    g[a] = 0.0
                    for c in range(4):
                        Nm[a, c] = 0.0
                for pair in range(2):
                    if pair == 0:
                        wt = a1
                        _gn_jac(q, ub1, A)
                        _rot_unnorm(q, ub1, pred)
                        ex, ey, ez = ur1[0] - pred[0], ur1[1] - pred[1], ur1[2] - pred[2]
                    else:
                        wt = a2
                        _gn_jac(q, ub2, A)
                        _rot_unnorm(q, ub2, pred)
                        ex, ey, ez = ur2[0] - pred[0], ur2[1] - pred[1], ur2[2] - pred[2]
                    for a in range(4):
                        g[a] += wt * (A[0, a] * ex + A[1, a] * ey + A[2, a] * ez)
                        for c in range(4):
                            Nm[a, c] += wt * (A[0, a] * A[0, c] + A[1, a] * A[1, c]
                                              + A[2, a] * A[2, c])
                if not _solve4(Nm, g, dq, L, y4):
                    break
                s = 0.0
                for a in range(4):
                    q[a] += dq[a]
                    s += q[a] * q[a]
                s = math.sqrt(s)
                if not (s > 1e-12 and s < 1e300):
                    q[0], q[1], q[2], q[3] = 1.0, 0.0, 0.0, 0.0
                    ok = False
                    break
                for a in range(4):
                    q[a] /= s
        ok_out[i] = ok
        for a in range(4):
            q_out[i, a] = q[a]


@njit(cache=True, error_model="numpy")
def integrate_rates_batch(dt, w, out):
    """out[k] = out[k-1] ⊗ exp(w[k] dt[k]), out[0] = identity (rates in the moving axes)."""
    q = np.array([1.0, 0.0, 0.0, 0.0])
    for i in range(dt.shape[0]):
        if i > 0:
            _rotate_by(q, w[i, 0] * dt[i], w[i, 1] * dt[i], w[i, 2] * dt[i])
        for j in range(4):
            out[i, j] = q[j]


@njit(cache=True, error_model="numpy")
def _mekf_update(q, bias, P, ub, uo, sigma, tmp, K, S, Sinv, PHt, dx):
    """One vector measurement (unit body ub, unit reference uo) into the MEKF state."""
    _to_body(q, uo[0], uo[1], uo[2], tmp)  # predicted body direction m̂
    # H = [[m̂×], 0] (3x6); residual y = ub − m̂
    mx, my, mz = tmp[0], tmp[1], tmp[2]
    for a in range(6):
        PHt[a, 0] = -mz * P[a, 1] + my * P[a, 2]
        PHt[a, 1] = mz * P[a, 0] - mx * P[a, 2]
        PHt[a, 2] = -my * P[a, 0] + mx * P[a, 1]
    s2 = sigma * sigma
    for c in range(3):
        S[0, c] = -mz * PHt[1, c] + my * PHt[2, c]
        S[1, c] = mz * PHt[0, c] - mx * PHt[2, c]
        S[2, c] = -my * PHt[0, c] + mx * PHt[1, c]
    for a in range(3):
        S[a, a] += s2
    det = (S[0, 0] * (S[1, 1] * S[2, 2] - S[1, 2] * S[2, 1])
           - S[0, 1] * (S[1, 0] * S[2, 2] - S[1, 2] * S[2, 0])
           + S[0, 2] * (S[1, 0] * S[2, 1] - S[1, 1] * S[2, 0]))
    if not (det > 0.0 and det < 1e300):
        return False
    Sinv[0, 0] = (S[1, 1] * S[2, 2] - S[1, 2] * S[2, 1]) / det
    Sinv[0, 1] = (S[0, 2] * S[2, 1] - S[0, 1] * S[2, 2]) / det
    Sinv[0, 2] = (S[0, 1] * S[1, 2] - S[0, 2] * S[1, 1]) / det
    Sinv[1, 0] = (S[1, 2] * S[2, 0] - S[1, 0] * S[2, 2]) / det
    Sinv[1, 1] = (S[0, 0] * S[2, 2] - S[0, 2] * S[2, 0]) / det
    Sinv[1, 2] = (S[0, 2] * S[1, 0] - S[0, 0] * S[1, 2]) / det
    Sinv[2, 0] = (S[1, 0] * S[2, 1] - S[1, 1] * S[2, 0]) / det
    Sinv[2, 1] = (S[0, 1] * S[2, 0] - S[0, 0] * S[2, 1]) / det
    Sinv[2, 2] = (S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]) / det
    for a in range(6):
        for c in range(3):
            s = 0.0
            for k in range(3):
                s += PHt[a, k] * Sinv[k, c]
            K[a, c] = s
    y0, y1, y2 = ub[0] - mx, ub[1] - my, ub[2] - mz
    for a in range(6):
        dx[a] = K[a, 0] * y0 + K[a, 1] * y1 + K[a, 2] * y2
    # P <- P − K H P  (then symmetrised)
    for a in range(6):
        for c in range(6):
            s = 0.0
            for k in range(3):
                s += K[a, k] * PHt[c, k]
            P[a, c] -= s
    for a in range(6):
        for c in range(a + 1, 6):
            m = 0.5 * (P[a, c] + P[c, a])
            P[a, c] = m
            P[c, a] = m
    _rotate_by(q, dx[0], dx[1], dx[2])
    bias[0] += dx[3]
    bias[1] += dx[4]
    bias[2] += dx[5]
    return True


@njit(cache=True, error_model="numpy")
def mekf_batch(dt, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid, substituted, delay,
               swing_gain, q, bias, P, sigma_mag, sigma_sec, arw, bias_rw, max_dt, q_out,
               bias_out, flags):
    """Multiplicative EKF (Lefferts, Markley & Shuster 1982) with gyro bias, vector pairs.

    Error state ``[θ, δb]`` (q = q̂ ⊗ exp(θ), body frame); propagation
    ``θ̇ = −[(ω_ib − b̂)×] θ − δb`` (the ``−R_bo ω_io`` term's attitude dependence
    included), ``P ← Φ P Φᵀ + diag(arw² dt, bias_rw² dt)``; sequential unit-vector
    updates with ``H = [[m̂×], 0]``, noise ``sigma_mag`` / ``sigma_sec`` (rad). The
    magnetometer pair alone makes the bias observable as the field direction
    turns. Second-pair samples flagged ``substituted`` (the paper's magnetometer
    pair delayed by ``delay`` samples) are used with the noise
    ``sqrt(sigma_mag² + (swing_gain·Δ)²)``, Δ the angle between the estimate now and
    ``delay`` samples ago (the pair is exact only if the satellite kept its attitude
    in the orbital frame). ``P`` (6, 6) is updated in place. Flags as ``ecf_batch``.
    """
    n = dt.shape[0]
    ub = np.empty(3)
    uo = np.empty(3)
    tmp = np.empty(3)
    K = np.empty((6, 3))
    S = np.empty((3, 3))
    Sinv = np.empty((3, 3))
    PHt = np.empty((6, 3))
    A = np.empty((3, 3))
    PP = np.empty((6, 6))
    dx = np.empty(6)
    for i in range(n):
        for j in range(4):
            flags[i, j] = 0
        h = dt[i]
        if h > 0.0 and h < 1e300:
            g = gyro[i]
            if not _propagate(q, bias, h, g, w_io_o[i], tmp):
                flags[i, 3] = 1
                wx = wy = wz = 0.0
            else:
                wx, wy, wz = g[0] - bias[0], g[1] - bias[1], g[2] - bias[2]
            # Phi = [[A, -h I], [0, I]], A = I - h [w×]; P <- Phi P Phiᵀ by blocks
            A[0, 0] = 1.0
            A[0, 1] = wz * h
            A[0, 2] = -wy * h
            A[1, 0] = -wz * h
            A[1, 1] = 1.0
            A[1, 2] = wx * h
            A[2, 0] = wy * h
            A[2, 1] = -wx * h
            A[2, 2] = 1.0
            for c in range(6):  # PP = Phi P
                for a in range(3):
                    PP[a, c] = (A[a, 0] * P[0, c] + A[a, 1] * P[1, c] + A[a, 2] * P[2, c]
                                - h * P[3 + a, c])
                    PP[3 + a, c] = P[3 + a, c]
            for a in range(6):  # P = PP Phiᵀ
                for c in range(3):
                    P[a, c] = (PP[a, 0] * A[c, 0] + PP[a, 1] * A[c, 1] + PP[a, 2] * A[c, 2]
                               - h * PP[a, 3 + c])
                    P[a, 3 + c] = PP[a, 3 + c]
            for a in range(3):
                P[a, a] += arw * arw * h
                P[3 + a, 3 + a] += bias_rw * bias_rw * h
            if h > max_dt:
                flags[i, 2] = 1
                flags[i, 3] = 1
            else:
                ok_m = _unit_pair(mag_b[i], mag_o[i], ub, uo)
                if ok_m:
                    ok_m = _mekf_update(q, bias, P, ub, uo, sigma_mag, tmp, K, S, Sinv, PHt, dx)
                ok_s = sec_valid[i] and _unit_pair(sec_b[i], sec_o[i], ub, uo)
                sig = sigma_sec
                if ok_s and substituted[i]:
                    if i >= delay:
                        j = i - delay
                        c = abs(q[0] * q_out[j, 0] + q[1] * q_out[j, 1] + q[2] * q_out[j, 2]
                                + q[3] * q_out[j, 3])
                        swing = 2.0 * math.acos(min(1.0, c))
                        sig = math.sqrt(sigma_mag * sigma_mag + (swing_gain * swing) ** 2)
                    else:
                        ok_s = False
                if ok_s:
                    ok_s = _mekf_update(q, bias, P, ub, uo, sig, tmp, K, S, Sinv, PHt, dx)
                flags[i, 0] = 0 if ok_m else 1
                flags[i, 1] = 0 if ok_s else 1
                if not (ok_m or ok_s):
                    flags[i, 3] = 1
        for j in range(4):
            q_out[i, j] = q[j]
        for j in range(3):
            bias_out[i, j] = bias[j]
