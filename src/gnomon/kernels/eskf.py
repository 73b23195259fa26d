"""Compiled kernels of the error-state AHRS Kalman filter (seed 002, Bilous & Nesterenko).

Readable twin: ``gnomon.estimators.eskf`` (numpy matrices); the tests compare the
two sample by sample. Everything here is scalar arithmetic on small fixed-size
arrays, exploiting the structure of the problem:

* the transition matrix ``Φ = [A  cI; 0  I]`` (``A = I - [ω̂×]dt``, ``c = -dt/2``)
  is never formed as a 6x6 matrix;
* the measurement matrix is ``D = [D1  0]`` (measurements do not see the bias),
  so only its 3 attitude columns are stored and multiplied;
* the innovation covariance is factorised ``S = L·diag(d)·Lᵀ`` (no square roots),
  and only the upper triangles of symmetric matrices are computed.

``gain`` and ``joseph`` are deliberately plain Python functions (compiled with
``njit`` below as the loop version ``correct``):
``gnomon.estimators.eskf.count_gain_operations`` runs the very same source on
counting numbers to report how many multiplications and additions the
implementation performs (next to the paper's formula), and
``gnomon.kernels._codegen_eskf`` traces them into the straight-line functions
``eskf_unrolled.update_r3`` / ``update_r6`` that the batch run ``run_batch``
uses (every intermediate a local scalar: about 2x faster than the loops).

Frames and units as in ``gnomon.estimators.eskf``: ``q = q_nb`` (ENU from body,
``[w, x, y, z]``), gyro rad/s, accelerometer m/s², magnetometer normalised by
the reference field magnitude (dimensionless).

Importing this module imports numba; ``import gnomon`` does not.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from gnomon.kernels.eskf_unrolled import update_r3, update_r6
from gnomon.kernels.quat import dcm, rotate_by

MODE_PREDICT_ONLY = 0
MODE_R3 = 3
MODE_R6 = 6


# ---------------------------------------------------------------- Kalman gain
def gain(P, D1, Rd, r, PDt, S, K):
    """Kalman gain ``K = P Dᵀ (D P Dᵀ + R)⁻¹`` for ``D = [D1 0]`` (r x 6, bias columns zero).

    P (6, 6) covariance; D1 (r, 3) attitude columns of D; Rd (r,) diagonal of R.
    Scratch/outputs (caller-allocated): PDt (6, r) = P Dᵀ; S (r, r) receives the
    factorisation ``S = L diag(d) Lᵀ`` (L unit lower-triangular) stored as
    ``S[i, j] = L_ij d_j`` below the diagonal and ``1/d_j`` on it; K (6, r) the gain.

    Plain Python on purpose: compiled below as ``gain_nb`` and also run on
    counting numbers by ``count_gain_operations``.
    """
    # P Dᵀ: only the first three columns of P meet the non-zero columns of D
    for i in range(6):
        for k in range(r):
            PDt[i, k] = P[i, 0] * D1[k, 0] + P[i, 1] * D1[k, 1] + P[i, 2] * D1[k, 2]
    # S = D P Dᵀ + R (upper triangle, stored in the lower one for the factorisation)
    for k in range(r):
        for m in range(k, r):
            s = D1[k, 0] * PDt[0, m] + D1[k, 1] * PDt[1, m] + D1[k, 2] * PDt[2, m]
            if m == k:
                s = s + Rd[k]
            S[m, k] = s
    # LDLᵀ factorisation in place (lower triangle), no square roots:
    # afterwards S[i, j] = L_ij d_j (i > j) and S[j, j] = 1 / d_j
    for j in range(r):
        dj = S[j, j]
        for k in range(j):
            dj = dj - S[j, k] * S[j, k] * S[k, k]
        S[j, j] = 1.0 / dj
        for i in range(j + 1, r):
            s = S[i, j]
            for k in range(j):
                s = s - S[i, k] * S[j, k] * S[k, k]
            S[i, j] = s
    # K S = PDt, one row of K at a time: K_i L diag(d) Lᵀ = PDt_i
    for i in range(6):
        # forward, z Lᵀ = PDt_i with z = K_i L diag(d); stored w = z / d:
        # w_j = (p_j - sum_{k<j} w_k L_jk d_k) / d_j
        for j in range(r):
            s = PDt[i, j]
            for k in range(j):
                s = s - K[i, k] * S[j, k]
            K[i, j] = s * S[j, j]
        # back, K_i L = w: k_j = w_j - sum_{m>j} k_m L_mj
        for j in range(r - 2, -1, -1):
            s = K[i, j + 1] * S[j + 1, j]
            for m in range(j + 2, r):
                s = s + K[i, m] * S[m, j]
            K[i, j] = K[i, j] - s * S[j, j]


gain_nb = njit(cache=True, fastmath=True, error_model="numpy")(gain)


# ---------------------------------------------------------------- propagation
@njit(cache=True, fastmath=True, error_model="numpy")
def propagate(q, b, P, wx_m, wy_m, wz_m, dt, var_gyro, var_bias, A, T, U):
    """One strapdown step in place: ``q ← q ⊗ exp(ω̂ dt)``, ``P ← Φ P Φᵀ + Q``.

    ``ω̂ = ω_measured - b`` (rad/s, body). ``Φ = [A  cI; 0  I]``, ``A = I - [ω̂×] dt``,
    ``c = -dt/2``; ``Q = diag(var_gyro dt / 4 · I, var_bias dt · I)`` with the
    squared densities ``var_gyro`` ((rad/s)²/Hz) and ``var_bias`` ((rad/s)²/s).
    A, T, U are (3, 3) scratch arrays.
    """
    wx = wx_m - b[0]
    wy = wy_m - b[1]
    wz = wz_m - b[2]
    # quaternion exponential of the rotation vector ω̂ dt
    rotate_by(q, wx * dt, wy * dt, wz * dt)
    # covariance: Φ P Φᵀ = [T Aᵀ + cU, U; Uᵀ, P22], T = A P11 + c P21, U = A P12 + c P22
    c = -0.5 * dt
    A[0, 0] = 1.0
    A[0, 1] = wz * dt
    A[0, 2] = -wy * dt
    A[1, 0] = -wz * dt
    A[1, 1] = 1.0
    A[1, 2] = wx * dt
    A[2, 0] = wy * dt
    A[2, 1] = -wx * dt
    A[2, 2] = 1.0
    for i in range(3):
        for j in range(3):
            T[i, j] = (A[i, 0] * P[0, j] + A[i, 1] * P[1, j] + A[i, 2] * P[2, j]
                       + c * P[3 + i, j])
            U[i, j] = (A[i, 0] * P[0, 3 + j] + A[i, 1] * P[1, 3 + j] + A[i, 2] * P[2, 3 + j]
                       + c * P[3 + i, 3 + j])
    qa = 0.25 * var_gyro * dt
    qb = var_bias * dt
    for i in range(3):
        for j in range(i, 3):
            v = T[i, 0] * A[j, 0] + T[i, 1] * A[j, 1] + T[i, 2] * A[j, 2] + c * U[i, j]
            if i == j:
                v = v + qa
            P[i, j] = v
            P[j, i] = v
    for i in range(3):
        for j in range(3):
            P[i, 3 + j] = U[i, j]
            P[3 + j, i] = U[i, j]
        P[3 + i, 3 + i] = P[3 + i, 3 + i] + qb


# ---------------------------------------------------------------- measurement models
@njit(cache=True, fastmath=True, error_model="numpy")
def measure_r6(q, ax, ay, az, mx, my, mz, g, mag_h, mag_z, var_acc, var_mag, fa, fm, y, D1, Rd):
    """Full model: ``y = [a - Ĉ_bn g_n; m - Ĉ_bn m_n]``, ``D1 = [2[â×]; 2[m̂×]]`` (6x3).

    ``g_n = [0, 0, g]``, ``m_n = [0, H, -Z]`` (normalised field). ``fa``, ``fm``
    inflate the accelerometer / magnetometer variances (disturbance gating).
    """
    w, x, y_, z = q[0], q[1], q[2], q[3]
    # rows of C_nb = columns of C_bn; only what is needed: C_bn[:, 1] and C_bn[:, 2]
    # C_nb[1, :] (north row) and C_nb[2, :] (up row)
    c10 = 2.0 * (x * y_ + w * z)
    c11 = 1.0 - 2.0 * (x * x + z * z)
    c12 = 2.0 * (y_ * z - w * x)
    c20 = 2.0 * (x * z - w * y_)
    c21 = 2.0 * (y_ * z + w * x)
    c22 = 1.0 - 2.0 * (x * x + y_ * y_)
    # predicted readings in body: â = g · C_nb[2, :], m̂ = H C_nb[1, :] - Z C_nb[2, :]
    a0 = g * c20
    a1 = g * c21
    a2 = g * c22
    m0 = mag_h * c10 - mag_z * c20
    m1 = mag_h * c11 - mag_z * c21
    m2 = mag_h * c12 - mag_z * c22
    y[0] = ax - a0
    y[1] = ay - a1
    y[2] = az - a2
    y[3] = mx - m0
    y[4] = my - m1
    y[5] = mz - m2
    # D1 = 2 [v×] = [[0, -2v2, 2v1], [2v2, 0, -2v0], [-2v1, 2v0, 0]]
    D1[0, 0] = 0.0
    D1[0, 1] = -2.0 * a2
    D1[0, 2] = 2.0 * a1
    D1[1, 0] = 2.0 * a2
    D1[1, 1] = 0.0
    D1[1, 2] = -2.0 * a0
    D1[2, 0] = -2.0 * a1
    D1[2, 1] = 2.0 * a0
    D1[2, 2] = 0.0
    D1[3, 0] = 0.0
    D1[3, 1] = -2.0 * m2
    D1[3, 2] = 2.0 * m1
    D1[4, 0] = 2.0 * m2
    D1[4, 1] = 0.0
    D1[4, 2] = -2.0 * m0
    D1[5, 0] = -2.0 * m1
    D1[5, 1] = 2.0 * m0
    D1[5, 2] = 0.0
    ra = var_acc * fa
    rm = var_mag * fm
    Rd[0] = ra
    Rd[1] = ra
    Rd[2] = ra
    Rd[3] = rm
    Rd[4] = rm
    Rd[5] = rm


@njit(cache=True, fastmath=True, error_model="numpy")
def measure_r3(q, ax, ay, az, mx, my, mz, g, mag_h, mag_z, var_acc, var_mag, fa, fm, y, D1, Rd):
    """Reduced model: ``y = [ã_x/g, ã_y/g, m̃_x/H]``, ``ã = Ĉ_nb a``, ``m̃ = Ĉ_nb m``.

    ``D1 = D_n Ĉ_nb`` with ``D_n = [[0, -2, 0], [2, 0, 0], [0, 2 tan I, 2]]`` for the
    body-frame error ``q = q̂ ⊗ δq`` (derivation in ``docs/estimators/eskf.md``).
    The predicted measurement is zero.
    """
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = dcm(q[0], q[1], q[2], q[3])
    ig = 1.0 / g
    ih = 1.0 / mag_h
    y[0] = (c00 * ax + c01 * ay + c02 * az) * ig
    y[1] = (c10 * ax + c11 * ay + c12 * az) * ig
    y[2] = (c00 * mx + c01 * my + c02 * mz) * ih
    t2 = 2.0 * mag_z * ih
    D1[0, 0] = -2.0 * c10
    D1[0, 1] = -2.0 * c11
    D1[0, 2] = -2.0 * c12
    D1[1, 0] = 2.0 * c00
    D1[1, 1] = 2.0 * c01
    D1[1, 2] = 2.0 * c02
    D1[2, 0] = t2 * c10 + 2.0 * c20
    D1[2, 1] = t2 * c11 + 2.0 * c21
    D1[2, 2] = t2 * c12 + 2.0 * c22
    ra = var_acc * fa * ig * ig
    Rd[0] = ra
    Rd[1] = ra
    Rd[2] = var_mag * fm * ih * ih


# ---------------------------------------------------------------- update
def joseph(P, D1, Rd, y, K, r, L, M, G, dx):
    """Error estimate ``dx = K y`` and Joseph-form covariance (upper triangle into ``P``).

    ``P ← (I - K D) P (I - K D)ᵀ + K R Kᵀ`` with ``K D = [L 0]``, ``L = K D1``
    (6x3), evaluated as ``N = (I - K D) P = P - L P[0:3, :]`` (into ``M``; its
    first three columns and its upper triangle), ``G = K R - N Dᵀ`` (6 x r; zero
    for the exact optimal gain, which is what makes the form robust to
    rounding and to a sub-optimal gain), ``P ← N + G Kᵀ``: only the upper
    triangle ``P[i, j], j >= i`` is written (the caller mirrors it, which is
    the symmetrisation). Plain Python, compiled below and traced by the code
    generator like ``gain``.
    """
    for i in range(6):
        s = K[i, 0] * y[0]
        for k in range(1, r):
            s = s + K[i, k] * y[k]
        dx[i] = s
        for j in range(3):
            s = K[i, 0] * D1[0, j]
            for k in range(1, r):
                s = s + K[i, k] * D1[k, j]
            L[i, j] = s
    for i in range(6):
        for j in range(3):
            M[i, j] = P[i, j] - (L[i, 0] * P[0, j] + L[i, 1] * P[1, j] + L[i, 2] * P[2, j])
        for j in range(max(i, 3), 6):
            M[i, j] = P[i, j] - (L[i, 0] * P[0, j] + L[i, 1] * P[1, j] + L[i, 2] * P[2, j])
    for i in range(6):
        for k in range(r):
            G[i, k] = K[i, k] * Rd[k] - (M[i, 0] * D1[k, 0] + M[i, 1] * D1[k, 1]
                                         + M[i, 2] * D1[k, 2])
    for i in range(6):
        for j in range(i, 6):
            s = G[i, 0] * K[j, 0]
            for k in range(1, r):
                s = s + G[i, k] * K[j, k]
            P[i, j] = M[i, j] + s


joseph_nb = njit(cache=True, fastmath=True, error_model="numpy")(joseph)


@njit(cache=True, fastmath=True, error_model="numpy")
def inject(q, b, dx):
    """``q ← normalise(q ⊗ [1, δe])``, ``b ← b + δb`` (the error state is then reset to zero)."""
    ex, ey, ez = dx[0], dx[1], dx[2]
    qw, qx, qy, qz = q[0], q[1], q[2], q[3]
    nw = qw - qx * ex - qy * ey - qz * ez
    nx = qw * ex + qx + qy * ez - qz * ey
    ny = qw * ey - qx * ez + qy + qz * ex
    nz = qw * ez + qx * ey - qy * ex + qz
    inv = 1.0 / np.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
    q[0] = nw * inv
    q[1] = nx * inv
    q[2] = ny * inv
    q[3] = nz * inv
    b[0] += dx[3]
    b[1] += dx[4]
    b[2] += dx[5]


@njit(cache=True, fastmath=True, error_model="numpy")
def correct(q, b, P, y, D1, Rd, r, PDt, S, K, L, M, dx):
    """Kalman update in place with loops (``gain``, ``joseph``, mirror, ``inject``).

    The batch run uses the straight-line twins generated from the same two
    functions (``eskf_unrolled.correct_r3`` / ``correct_r6``); this loop
    version is kept as the readable compiled form and tested against them.
    """
    gain_nb(P, D1, Rd, r, PDt, S, K)
    joseph_nb(P, D1, Rd, y, K, r, L, M, PDt, dx)
    for i in range(6):
        for j in range(i + 1, 6):
            P[j, i] = P[i, j]
    inject(q, b, dx)


@njit(cache=True, fastmath=True, error_model="numpy")
def accel_lowpass(q, ax, ay, az, lp, w, out):
    """Low-pass the accelerometer in the computed navigation frame (in place in ``lp``).

    ``lp ← lp + w (Ĉ_nb a - lp)`` (``w = 1`` restarts it), ``out = Ĉ_bn lp``: gravity
    is constant in the navigation frame while a linear acceleration averages out there
    (the idea of VQF's inertial-frame low-pass, Laidig & Seel 2023), so the filtered
    reading, rotated back into the body frame, is the better gravity measurement.
    """
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = dcm(q[0], q[1], q[2], q[3])
    lp[0] += w * (c00 * ax + c01 * ay + c02 * az - lp[0])
    lp[1] += w * (c10 * ax + c11 * ay + c12 * az - lp[1])
    lp[2] += w * (c20 * ax + c21 * ay + c22 * az - lp[2])
    out[0] = c00 * lp[0] + c10 * lp[1] + c20 * lp[2]
    out[1] = c01 * lp[0] + c11 * lp[1] + c21 * lp[2]
    out[2] = c02 * lp[0] + c12 * lp[1] + c22 * lp[2]


@njit(cache=True, fastmath=True, error_model="numpy")
def gate_factor(dev, gate):
    """Variance inflation ``1 + (dev/gate)²`` (1 when ``gate <= 0``: gating off)."""
    if gate <= 0.0:
        return 1.0
    u = dev / gate
    return 1.0 + u * u


# ---------------------------------------------------------------- batch
@njit(cache=True, fastmath=True, error_model="numpy")
def run_batch(gyro, accel, mag, dt, q0, b0, P0, var_gyro, var_bias, var_acc, var_mag,
              g, dip_s0, dip_n0, dip_tau, acc_lp_tau, gate_acc, gate_mag, mode,
              q_out, b_out, innov_out, pdiag_out, P_out, lp0, lp_started0, state_out,
              skipped_out):
    """Run the filter over N samples; outputs are written into the given arrays.

    gyro, accel (N, 3) rad/s and m/s²; mag (N, 3) normalised by the reference
    field magnitude; dt (N,) s, ``dt[k] = t[k] - t[k-1]`` (``dt[0]`` is used as
    given, 0 for no propagation at the first sample). q0 (4,), b0 (3,), P0 (6, 6)
    initial state. The reference field ``[0, H, -Z]`` (normalised) follows the
    running mean ``s`` of ``a·m / (g |m|)`` (``= cos(angle(a, m)) = -Z`` without the
    bias a normalised noisy accelerometer would add), started at ``dip_s0`` with
    weight ``dip_n0`` samples, then ``s += w (cos - s)``, ``w = max(1/count, dt/dip_tau)``
    (``dip_tau <= 0``: fixed at ``dip_s0``). ``acc_lp_tau > 0``: the accelerometer
    is low-pass filtered in the computed navigation frame first (``accel_lowpass``).
    mode: 0 predict only, 3 reduced,
    6 full measurement model.
    ``lp0`` (3,): the low-pass state of an earlier run, used when ``lp_started0`` (else the
    low-pass starts at the first sample; no NaN sentinel: this kernel uses fastmath).
    A sample whose accelerometer or magnetometer vector is zero (a dropout) is only
    propagated: ``skipped_out[k]`` is set and its innovation row left as given.
    Outputs: q_out (N, 4), b_out (N, 3), innov_out (N, 6) (first r columns
    used), pdiag_out (N, 6), P_out (6, 6) the final covariance, ``state_out`` (6,)
    the final ``[dip_s, dip_count, lp_x, lp_y, lp_z, lp_started]`` (to continue later).
    """
    n = gyro.shape[0]
    q = q0.copy()
    b = b0.copy()
    P = P0.copy()
    A = np.empty((3, 3))
    T = np.empty((3, 3))
    U = np.empty((3, 3))
    r = 6 if mode == MODE_R6 else 3
    y = np.empty(6)
    D1 = np.empty((6, 3))
    Rd = np.empty(6)
    dx = np.empty(6)
    dip_s = dip_s0
    count = dip_n0
    lp = lp0.copy()
    lp_started = lp_started0
    acc_f = np.empty(3)
    for k in range(n):
        propagate(q, b, P, gyro[k, 0], gyro[k, 1], gyro[k, 2], dt[k], var_gyro, var_bias, A, T, U)
        skipped_out[k] = False
        if mode != MODE_PREDICT_ONLY:
            ax, ay, az = accel[k, 0], accel[k, 1], accel[k, 2]
            mx, my, mz = mag[k, 0], mag[k, 1], mag[k, 2]
            na = np.sqrt(ax * ax + ay * ay + az * az)
            nm = np.sqrt(mx * mx + my * my + mz * mz)
            if not (na > 0.0 and nm > 0.0):
                skipped_out[k] = True
        if mode != MODE_PREDICT_ONLY and not skipped_out[k]:
            cos_am = (ax * mx + ay * my + az * mz) / (g * nm)
            fa = gate_factor(abs(na - g), gate_acc)
            fm = gate_factor(max(abs(nm - 1.0), abs(cos_am - dip_s)), gate_mag)
            if dip_tau > 0.0 and fm < 2.0 and fa < 2.0:
                count += 1.0
                w = max(1.0 / count, dt[k] / dip_tau)
                dip_s += w * (cos_am - dip_s)
                dip_s = min(max(dip_s, -0.999), 0.999)  # as estimators.eskf.update_dip
            mag_z = -dip_s
            mag_h = np.sqrt(1.0 - dip_s * dip_s)
            if acc_lp_tau > 0.0:
                if not lp_started:
                    lp[:] = 0.0
                accel_lowpass(q, ax, ay, az, lp,
                              min(1.0, dt[k] / acc_lp_tau) if lp_started else 1.0, acc_f)
                lp_started = True
                ax, ay, az = acc_f[0], acc_f[1], acc_f[2]
            # straight-line updates generated from gain + joseph (eskf_unrolled)
            if mode == MODE_R6:
                measure_r6(q, ax, ay, az, mx, my, mz, g, mag_h, mag_z, var_acc, var_mag,
                           fa, fm, y, D1, Rd)
                update_r6(P, D1, Rd, y, dx)
                inject(q, b, dx)
            else:
                measure_r3(q, ax, ay, az, mx, my, mz, g, mag_h, mag_z, var_acc, var_mag,
                           fa, fm, y, D1, Rd)
                update_r3(P, D1, Rd, y, dx)
                inject(q, b, dx)
            for j in range(r):
                innov_out[k, j] = y[j]
        for j in range(4):
            q_out[k, j] = q[j]
        for j in range(3):
            b_out[k, j] = b[j]
        for j in range(6):
            pdiag_out[k, j] = P[j, j]
    for i in range(6):
        for j in range(6):
            P_out[i, j] = P[i, j]
    state_out[5] = 1.0 if lp_started else 0.0
    state_out[0] = dip_s
    state_out[1] = count
    state_out[2] = lp[0]
    state_out[3] = lp[1]
    state_out[4] = lp[2]
