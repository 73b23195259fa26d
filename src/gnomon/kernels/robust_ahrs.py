"""Compiled batch loop of the robust decoupled AHRS (``gnomon.estimators.robust_ahrs``).

Twin of ``RobustAHRS.update`` (the tests compare the two sample by sample). The
state is one flat float array whose layout (``S_*`` offsets) and the
coefficient vector (``C_*``) are defined in the estimator module, so that the
readable update and this kernel share them.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from gnomon.estimators.robust_ahrs import (  # noqa: I001
    C_ACC_LP,
    C_BIAS_CLIP,
    C_BIAS_EVERY,
    C_BIAS_LP,
    C_BIAS_P0,
    C_BIAS_V,
    C_HEADING_KF,
    C_HI_GATE,
    C_HI_LAMBDA,
    C_HI_REG,
    C_K_MAG,
    C_K_MAG_BIAS,
    C_K_MAG_REF,
    C_MAG_CUR_LP,
    C_MAG_DIP_TH,
    C_MAG_EVERY,
    C_MAG_MAX_REJECT,
    C_MAG_MIN_UNDIST,
    C_MAG_NEW,
    C_MAG_NEW_FIRST,
    C_MAG_NEW_MIN_GYRO,
    C_MAG_NORM_TH,
    C_MAG_REJECT,
    C_MAG_REJECT_FACTOR,
    C_MAX_DT,
    C_MOTION_BIAS,
    C_Q_HEAD,
    C_Q_RATE,
    C_R_HEAD,
    C_REST_BIAS,
    C_REST_LP,
    C_REST_MIN,
    C_REST_TH_ACC2,
    C_REST_TH_GYRO2,
    C_SOFT_D,
    C_SOFT_N,
    C_TAU_ACC,
    C_TAU_MAG,
    C_TAU_MAG_CUR,
    C_TAU_REST,
    C_TS,
    C_TS_BIAS,
    C_TS_MAG,
    C_W_MOTION,
    C_W_REST,
    C_W_VERTICAL,
    S_ACC_RATE,
    S_ALP,
    S_BIAS,
    S_BIAS_CNT,
    S_BLP,
    S_CAND_DIP,
    S_CAND_NORM,
    S_CAND_T,
    S_CD,
    S_DELTA,
    S_HI_BM,
    S_HI_BMM,
    S_HI_M,
    S_HI_MM,
    S_HI_O,
    S_HI_RM,
    S_HI_S,
    S_HI_W,
    S_K_MAG_INIT,
    S_K_MAG_USED,
    S_MAG_CNT,
    S_MAG_DIS,
    S_MAG_DIST,
    S_MAG_REF_DIP,
    S_MAG_REF_NORM,
    S_MAG_REJECT_T,
    S_MAG_UNDIST_T,
    S_MN,
    S_MSUM,
    S_P,
    S_P_HEAD,
    S_QA,
    S_QG,
    S_RA,
    S_REST,
    S_REST_T,
    S_RG,
    S_RG_OUT,
    S_RLP,
    S_ROT2,
    S_SD,
)


@njit(cache=True, error_model="numpy", inline="always")
def _lp(s, off, n, x, out, c, coff, tau, ts):
    """Second-order low-pass of ``x[:n]`` into ``out[:n]``; state ``s[off : off + 2n + 1]``.

    For the first ``tau`` seconds the output is the running mean (the count is
    ``s[off + 2n]``, the sums ``s[off : off + n]``); then the filter starts in the
    steady state of that mean (count set to -1).
    """
    cnt = s[off + 2 * n]
    b0 = c[coff]
    b1 = c[coff + 1]
    b2 = c[coff + 2]
    a1 = c[coff + 3]
    a2 = c[coff + 4]
    if cnt >= 0.0:
        cnt += 1.0
        for i in range(n):
            s[off + i] += x[i]
            out[i] = s[off + i] / cnt
        if cnt * ts >= tau:
            for i in range(n):
                y = out[i]
                s[off + i] = y * (1.0 - b0)
                s[off + n + i] = y * (b2 - a2)
            cnt = -1.0
        s[off + 2 * n] = cnt
        return
    for i in range(n):
        xi = x[i]
        y = b0 * xi + s[off + i]
        s[off + i] = b1 * xi - a1 * y + s[off + n + i]
        s[off + n + i] = b2 * xi - a2 * y
        out[i] = y


@njit(cache=True, error_model="numpy", inline="always")
def _qmul_into(s, o, pw, px, py, pz):
    """``s[o:o+4] <- normalise([pw,px,py,pz] ⊗ s[o:o+4])``."""
    w, x, y, z = s[o], s[o + 1], s[o + 2], s[o + 3]
    nw = pw * w - px * x - py * y - pz * z
    nx = pw * x + px * w + py * z - pz * y
    ny = pw * y - px * z + py * w + pz * x
    nz = pw * z + px * y - py * x + pz * w
    k = 1.0 / math.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
    s[o] = nw * k
    s[o + 1] = nx * k
    s[o + 2] = ny * k
    s[o + 3] = nz * k


@njit(cache=True, error_model="numpy", inline="always")
def _q6_dcm(s, d6):
    """``d6[0:4] <- q_6b = q_acc ⊗ q_gyr``, ``d6[4:13] <- R_6b`` (row-major)."""
    pw, px, py, pz = s[S_QA], s[S_QA + 1], s[S_QA + 2], s[S_QA + 3]
    w, x, y, z = s[S_QG], s[S_QG + 1], s[S_QG + 2], s[S_QG + 3]
    qw = pw * w - px * x - py * y - pz * z
    qx = pw * x + px * w + py * z - pz * y
    qy = pw * y - px * z + py * w + pz * x
    qz = pw * z + px * y - py * x + pz * w
    d6[0] = qw
    d6[1] = qx
    d6[2] = qy
    d6[3] = qz
    d6[4] = 1.0 - 2.0 * (qy * qy + qz * qz)
    d6[5] = 2.0 * (qx * qy - qw * qz)
    d6[6] = 2.0 * (qx * qz + qw * qy)
    d6[7] = 2.0 * (qx * qy + qw * qz)
    d6[8] = 1.0 - 2.0 * (qx * qx + qz * qz)
    d6[9] = 2.0 * (qy * qz - qw * qx)
    d6[10] = 2.0 * (qx * qz - qw * qy)
    d6[11] = 2.0 * (qy * qz + qw * qx)
    d6[12] = 1.0 - 2.0 * (qx * qx + qy * qy)


@njit(cache=True, error_model="numpy", inline="always")
def _hard_iron_solve(s, reg, gate, tmp):
    """``o = (w²(1+reg) I - SᵀS)⁻¹ (w M - Sᵀ RM)`` into ``s[S_HI_O]`` (least squares of
    ``R m = h + R o`` over the weighted window with the prior ``reg·w |o|²``)."""
    w = s[S_HI_W]
    d = w * w * (1.0 + reg)
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += s[S_HI_S + 3 * k + i] * s[S_HI_S + 3 * k + j]
            tmp[3 * i + j] = (d if i == j else 0.0) - acc
    r0 = w * s[S_HI_M] - (s[S_HI_S] * s[S_HI_RM] + s[S_HI_S + 3] * s[S_HI_RM + 1]
                          + s[S_HI_S + 6] * s[S_HI_RM + 2])
    r1 = w * s[S_HI_M + 1] - (s[S_HI_S + 1] * s[S_HI_RM] + s[S_HI_S + 4] * s[S_HI_RM + 1]
                              + s[S_HI_S + 7] * s[S_HI_RM + 2])
    r2 = w * s[S_HI_M + 2] - (s[S_HI_S + 2] * s[S_HI_RM] + s[S_HI_S + 5] * s[S_HI_RM + 1]
                              + s[S_HI_S + 8] * s[S_HI_RM + 2])
    a, b, cc = tmp[0], tmp[1], tmp[2]
    dd, e, f = tmp[3], tmp[4], tmp[5]
    g, hh, i_ = tmp[6], tmp[7], tmp[8]
    c0 = e * i_ - f * hh
    c1 = -(dd * i_ - f * g)
    c2 = dd * hh - e * g
    det = a * c0 + b * c1 + cc * c2
    if det <= 0.0:
        return
    inv = 1.0 / det
    o0 = (c0 * r0 - (b * i_ - cc * hh) * r1 + (b * f - cc * e) * r2) * inv
    o1 = (c1 * r0 + (a * i_ - cc * g) * r1 - (a * f - cc * dd) * r2) * inv
    o2 = (c2 * r0 - (a * hh - b * g) * r1 + (a * e - b * dd) * r2) * inv
    # residual energy of the fit with the offset (E1) and without it (E0, h = mean of R m)
    rm0, rm1, rm2 = s[S_HI_RM], s[S_HI_RM + 1], s[S_HI_RM + 2]
    e0 = s[S_HI_MM] - (rm0 * rm0 + rm1 * rm1 + rm2 * rm2) / w
    h0 = (rm0 - (s[S_HI_S] * o0 + s[S_HI_S + 1] * o1 + s[S_HI_S + 2] * o2)) / w
    h1 = (rm1 - (s[S_HI_S + 3] * o0 + s[S_HI_S + 4] * o1 + s[S_HI_S + 5] * o2)) / w
    h2 = (rm2 - (s[S_HI_S + 6] * o0 + s[S_HI_S + 7] * o1 + s[S_HI_S + 8] * o2)) / w
    e1 = s[S_HI_MM] - (h0 * rm0 + h1 * rm1 + h2 * rm2) - (o0 * s[S_HI_M] + o1 * s[S_HI_M + 1]
                                                          + o2 * s[S_HI_M + 2])
    if e1 < gate * e0:  # the offset explains most of the field's variation in frame 6
        s[S_HI_O] = o0
        s[S_HI_O + 1] = o1
        s[S_HI_O + 2] = o2
    else:
        s[S_HI_O] = 0.0
        s[S_HI_O + 1] = 0.0
        s[S_HI_O + 2] = 0.0


@njit(cache=True, error_model="numpy", inline="always")
def _dcm(q, r):
    """Row-major 3x3 rotation matrix of unit quaternion ``q`` into ``r[:9]``."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    r[0] = 1.0 - 2.0 * (y * y + z * z)
    r[1] = 2.0 * (x * y - w * z)
    r[2] = 2.0 * (x * z + w * y)
    r[3] = 2.0 * (x * y + w * z)
    r[4] = 1.0 - 2.0 * (x * x + z * z)
    r[5] = 2.0 * (y * z - w * x)
    r[6] = 2.0 * (x * z - w * y)
    r[7] = 2.0 * (y * z + w * x)
    r[8] = 1.0 - 2.0 * (x * x + y * y)


@njit(cache=True, error_model="numpy", inline="always")
def _clip(v, lim):
    return lim if v > lim else (-lim if v < -lim else v)


@njit(cache=True, error_model="numpy", inline="always")
def _bias_update(s, c, h, e0, e1, e2, w0, w1, w2, clip, k33, tmp):
    """Kalman update of the bias with measurement ``e = y - H b`` (``H`` row-major in ``h``).

    ``K = P Hᵀ (W + H P Hᵀ)⁻¹``, ``b += K e``, ``P -= K H P``; ``e`` and ``b`` clipped.
    """
    e0 = _clip(e0, clip)
    e1 = _clip(e1, clip)
    e2 = _clip(e2, clip)
    # PHt = P Hᵀ (3x3), S = H PHt + W
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += s[S_P + 3 * i + k] * h[3 * j + k]
            tmp[3 * i + j] = acc
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += h[3 * i + k] * tmp[3 * k + j]
            k33[3 * i + j] = acc
    k33[0] += w0
    k33[4] += w1
    k33[8] += w2
    # inverse of S by cofactors into tmp[9:18]
    a, b, cc = k33[0], k33[1], k33[2]
    d, e, f = k33[3], k33[4], k33[5]
    g, hh, i_ = k33[6], k33[7], k33[8]
    c0 = e * i_ - f * hh
    c1 = -(d * i_ - f * g)
    c2 = d * hh - e * g
    det = a * c0 + b * c1 + cc * c2
    inv = 1.0 / det
    tmp[9] = c0 * inv
    tmp[10] = -(b * i_ - cc * hh) * inv
    tmp[11] = (b * f - cc * e) * inv
    tmp[12] = c1 * inv
    tmp[13] = (a * i_ - cc * g) * inv
    tmp[14] = -(a * f - cc * d) * inv
    tmp[15] = c2 * inv
    tmp[16] = -(a * hh - b * g) * inv
    tmp[17] = (a * e - b * d) * inv
    # K = PHt S⁻¹ into k33
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += tmp[3 * i + k] * tmp[9 + 3 * k + j]
            k33[3 * i + j] = acc
    for i in range(3):
        v = s[S_BIAS + i] + k33[3 * i] * e0 + k33[3 * i + 1] * e1 + k33[3 * i + 2] * e2
        s[S_BIAS + i] = _clip(v, clip)
    # P -= K H P = K (P Hᵀ)ᵀ (P symmetric); P Hᵀ is still in tmp[0:9]
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += k33[3 * i + k] * tmp[3 * j + k]
            tmp[9 + 3 * i + j] = acc
    for i in range(9):
        s[S_P + i] -= tmp[9 + i]
    # keep P symmetric (the short form above lets rounding asymmetry grow over 1e6+ updates)
    for i, j in ((0, 1), (0, 2), (1, 2)):
        m = 0.5 * (s[S_P + 3 * i + j] + s[S_P + 3 * j + i])
        s[S_P + 3 * i + j] = m
        s[S_P + 3 * j + i] = m


@njit(cache=True, error_model="numpy", inline="always")
def robust_ahrs_step(s, c, dt, gx, gy, gz, ax, ay, az, mx, my, mz, v, r, h, k33, tmp, q):
    """One sample, in place on the state ``s``; scratch arrays ``v`` (9), ``r`` (9), ``h`` (9),
    ``k33`` (9), ``tmp`` (18), ``q`` (13: on return ``q_6b`` and ``R_6b``, see ``_q6_dcm``).
    Returns flag bits: 1 accelerometer skipped, 2 magnetometer skipped, 4 gap."""
    ts = c[C_TS]
    flags = 0
    rest_on = c[C_REST_BIAS] != 0.0
    reject_on = c[C_MAG_REJECT] != 0.0
    clip = c[C_BIAS_CLIP]
    # ---- rest detection, gyro part
    if rest_on or reject_on:
        v[0] = gx
        v[1] = gy
        v[2] = gz
        _lp(s, S_RG, 3, v, r, c, C_REST_LP, c[C_TAU_REST], ts)
        s[S_RG_OUT] = r[0]
        s[S_RG_OUT + 1] = r[1]
        s[S_RG_OUT + 2] = r[2]
        d0 = gx - r[0]
        d1 = gy - r[1]
        d2 = gz - r[2]
        big = max(abs(r[0]), max(abs(r[1]), abs(r[2])))
        if d0 * d0 + d1 * d1 + d2 * d2 >= c[C_REST_TH_GYRO2] or big > clip:
            s[S_REST_T] = 0.0
            s[S_REST] = 0.0
    # ---- strapdown integration of the bias-corrected gyro (almost-inertial frame)
    if dt > 0.0:
        wx = (gx - s[S_BIAS]) * dt
        wy = (gy - s[S_BIAS + 1]) * dt
        wz = (gz - s[S_BIAS + 2]) * dt
        th2 = wx * wx + wy * wy + wz * wz
        s[S_ROT2] += th2 / dt
        if th2 > 0.0:
            if th2 < 0.0025:
                # |θ| < 0.05 rad: Taylor series of cos(θ/2) and sin(θ/2)/θ to θ⁸ (first
                # omitted terms < 1e-22: equal to the trigonometric form in double precision)
                cw = 1.0 - th2 * (1.0 / 8.0 - th2 * (1.0 / 384.0 - th2 * (
                    1.0 / 46080.0 - th2 / 10321920.0)))
                k = 0.5 - th2 * (1.0 / 48.0 - th2 * (1.0 / 3840.0 - th2 * (
                    1.0 / 645120.0 - th2 / 185794560.0)))
            else:
                th = math.sqrt(th2)
                cw = math.cos(0.5 * th)
                k = math.sin(0.5 * th) / th
            # q_gyr <- q_gyr ⊗ exp(w dt): right multiplication
            w, x, y, z = s[S_QG], s[S_QG + 1], s[S_QG + 2], s[S_QG + 3]
            px, py, pz = k * wx, k * wy, k * wz
            nw = w * cw - x * px - y * py - z * pz
            nx = w * px + x * cw + y * pz - z * py
            ny = w * py - x * pz + y * cw + z * px
            nz = w * pz + x * py - y * px + z * cw
            kn = 1.0 / math.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
            s[S_QG] = nw * kn
            s[S_QG + 1] = nx * kn
            s[S_QG + 2] = ny * kn
            s[S_QG + 3] = nz * kn
    if dt > c[C_MAX_DT]:
        _q6_dcm(s, q)
        return 4
    # ---- accelerometer
    na2 = ax * ax + ay * ay + az * az
    if na2 > 0.0:
        if rest_on:
            v[0] = ax
            v[1] = ay
            v[2] = az
            _lp(s, S_RA, 3, v, r, c, C_REST_LP, c[C_TAU_REST], ts)
            d0 = ax - r[0]
            d1 = ay - r[1]
            d2 = az - r[2]
            if d0 * d0 + d1 * d1 + d2 * d2 >= c[C_REST_TH_ACC2]:
                s[S_REST_T] = 0.0
                s[S_REST] = 0.0
            else:
                s[S_REST_T] += ts
                if s[S_REST_T] >= c[C_REST_MIN]:
                    s[S_REST] = 1.0
        # specific force in the almost-inertial frame, low-pass filtered there
        w, x, y, z = s[S_QG], s[S_QG + 1], s[S_QG + 2], s[S_QG + 3]
        v[0] = (1.0 - 2.0 * (y * y + z * z)) * ax + 2.0 * (x * y - w * z) * ay \
            + 2.0 * (x * z + w * y) * az
        v[1] = 2.0 * (x * y + w * z) * ax + (1.0 - 2.0 * (x * x + z * z)) * ay \
            + 2.0 * (y * z - w * x) * az
        v[2] = 2.0 * (x * z - w * y) * ax + 2.0 * (y * z + w * x) * ay \
            + (1.0 - 2.0 * (x * x + y * y)) * az
        _lp(s, S_ALP, 3, v, r, c, C_ACC_LP, c[C_TAU_ACC], ts)
        # into the inclination-corrected frame, normalised
        w, x, y, z = s[S_QA], s[S_QA + 1], s[S_QA + 2], s[S_QA + 3]
        fx = (1.0 - 2.0 * (y * y + z * z)) * r[0] + 2.0 * (x * y - w * z) * r[1] \
            + 2.0 * (x * z + w * y) * r[2]
        fy = 2.0 * (x * y + w * z) * r[0] + (1.0 - 2.0 * (x * x + z * z)) * r[1] \
            + 2.0 * (y * z - w * x) * r[2]
        fz = 2.0 * (x * z - w * y) * r[0] + 2.0 * (y * z + w * x) * r[1] \
            + (1.0 - 2.0 * (x * x + y * y)) * r[2]
        nf = math.sqrt(fx * fx + fy * fy + fz * fz)
        if nf > 0.0:
            fx /= nf
            fy /= nf
            fz /= nf
            # rotation taking f onto up [0, 0, 1], applied on the left of q_acc
            cw = math.sqrt(max(0.5 * (fz + 1.0), 0.0))
            if cw > 1e-6:
                _qmul_into(s, S_QA, cw, 0.5 * fy / cw, -0.5 * fx / cw, 0.0)
            else:
                _qmul_into(s, S_QA, 0.0, 1.0, 0.0, 0.0)
            # sine of the correction angle per unit time (= the rate for small corrections)
            s[S_ACC_RATE] = math.sqrt(fx * fx + fy * fy) / ts
        _q6_dcm(s, q)
        # ---- gyro bias: Kalman filter in rest (H = I) and in motion (inclination residual)
        run_bias = s[S_BIAS_CNT] == 0.0
        s[S_BIAS_CNT] = (s[S_BIAS_CNT] + 1.0) % c[C_BIAS_EVERY]
        if (rest_on or c[C_MOTION_BIAS] != 0.0) and run_bias:
            ts_b = c[C_TS_BIAS]
            for i in range(9):
                h[i] = q[4 + i]
            b0, b1, b2 = s[S_BIAS], s[S_BIAS + 1], s[S_BIAS + 2]
            v[0] = h[0] * b0 + h[1] * b1 + h[2] * b2
            v[1] = h[3] * b0 + h[4] * b1 + h[5] * b2
            _lp(s, S_RLP, 9, h, r, c, C_BIAS_LP, c[C_TAU_ACC], ts_b)
            for i in range(9):
                h[i] = r[i]
            _lp(s, S_BLP, 2, v, r, c, C_BIAS_LP, c[C_TAU_ACC], ts_b)
            p0 = c[C_BIAS_P0]
            for i in range(3):
                if s[S_P + 4 * i] < p0:
                    s[S_P + 4 * i] += c[C_BIAS_V]
            if rest_on and s[S_REST] != 0.0:
                for i in range(9):
                    h[i] = 0.0
                h[0] = 1.0
                h[4] = 1.0
                h[8] = 1.0
                wr = c[C_W_REST]
                _bias_update(s, c, h, s[S_RG_OUT] - b0, s[S_RG_OUT + 1] - b1,
                             s[S_RG_OUT + 2] - b2, wr, wr, wr, clip, k33, tmp)
            elif c[C_MOTION_BIAS] != 0.0 and nf > 0.0:
                e0 = -fy / ts + r[0] - (h[0] * b0 + h[1] * b1 + h[2] * b2)
                e1 = fx / ts + r[1] - (h[3] * b0 + h[4] * b1 + h[5] * b2)
                e2 = -(h[6] * b0 + h[7] * b1 + h[8] * b2)
                wm = c[C_W_MOTION]
                _bias_update(s, c, h, e0, e1, e2, wm, wm, c[C_W_VERTICAL], clip, k33, tmp)
    else:
        flags |= 1
        _q6_dcm(s, q)
    # ---- magnetometer: heading only
    nm2 = mx * mx + my * my + mz * mz
    run_mag = False
    if nm2 > 0.0:
        if c[C_HI_LAMBDA] > 0.0:
            # hard-iron block sums of the raw field (the weighted sums are updated per block)
            s[S_HI_BM] += mx
            s[S_HI_BM + 1] += my
            s[S_HI_BM + 2] += mz
            s[S_HI_BMM] += nm2
            mx -= s[S_HI_O]
            my -= s[S_HI_O + 1]
            mz -= s[S_HI_O + 2]
        # field in frame 6, averaged over mag_every samples (the first sample at once)
        s[S_MSUM] += q[4] * mx + q[5] * my + q[6] * mz
        s[S_MSUM + 1] += q[7] * mx + q[8] * my + q[9] * mz
        s[S_MSUM + 2] += q[10] * mx + q[11] * my + q[12] * mz
        s[S_MAG_CNT] += 1.0
        run_mag = s[S_MAG_CNT] >= c[C_MAG_EVERY] or s[S_K_MAG_INIT] == 1.0
    if nm2 > 0.0 and not run_mag:
        pass  # accumulating: the heading filter runs on every mag_every-th sample
    elif nm2 > 0.0:
        tsm = c[C_TS_MAG]
        soft = 1.0
        cnt = s[S_MAG_CNT]
        inv = 1.0 / cnt
        ex = s[S_MSUM] * inv
        ey = s[S_MSUM + 1] * inv
        ez = s[S_MSUM + 2] * inv
        lam = c[C_HI_LAMBDA]
        if lam > 0.0:
            # hard-iron offset o (body): R m = h + R o with h fixed in frame 6. Exponentially
            # weighted sums (per block of cnt samples, R taken at the block's end) of 1, R,
            # R m, m and |m|² give o in closed form (see _hard_iron_solve).
            o0, o1, o2 = s[S_HI_O], s[S_HI_O + 1], s[S_HI_O + 2]
            s[S_HI_W] = lam * s[S_HI_W] + cnt
            for i in range(9):
                s[S_HI_S + i] = lam * s[S_HI_S + i] + cnt * q[4 + i]
            s[S_HI_RM] = lam * s[S_HI_RM] + s[S_MSUM] + cnt * (q[4] * o0 + q[5] * o1 + q[6] * o2)
            s[S_HI_RM + 1] = lam * s[S_HI_RM + 1] + s[S_MSUM + 1] + cnt * (
                q[7] * o0 + q[8] * o1 + q[9] * o2)
            s[S_HI_RM + 2] = lam * s[S_HI_RM + 2] + s[S_MSUM + 2] + cnt * (
                q[10] * o0 + q[11] * o1 + q[12] * o2)
            for i in range(3):
                s[S_HI_M + i] = lam * s[S_HI_M + i] + s[S_HI_BM + i]
                s[S_HI_BM + i] = 0.0
            s[S_HI_MM] = lam * s[S_HI_MM] + s[S_HI_BMM]
            s[S_HI_BMM] = 0.0
            _hard_iron_solve(s, c[C_HI_REG], c[C_HI_GATE], tmp)
        s[S_MSUM] = 0.0
        s[S_MSUM + 1] = 0.0
        s[S_MSUM + 2] = 0.0
        s[S_MAG_CNT] = 0.0
        if reject_on:
            nm = math.sqrt(ex * ex + ey * ey + ez * ez)
            v[0] = nm
            v[1] = -math.asin(min(max(ez / nm, -1.0), 1.0))
            _lp(s, S_MN, 2, v, r, c, C_MAG_CUR_LP, c[C_TAU_MAG_CUR], tsm)
            cur_norm = r[0]
            cur_dip = r[1]
            ref_n = s[S_MAG_REF_NORM]
            kref = c[C_K_MAG_REF]
            if abs(cur_norm - ref_n) < c[C_MAG_NORM_TH] * ref_n \
                    and abs(cur_dip - s[S_MAG_REF_DIP]) < c[C_MAG_DIP_TH]:
                s[S_MAG_UNDIST_T] += tsm
                if s[S_MAG_UNDIST_T] >= c[C_MAG_MIN_UNDIST]:
                    s[S_MAG_DIST] = 0.0
                    s[S_MAG_REF_NORM] += kref * (cur_norm - ref_n)
                    s[S_MAG_REF_DIP] += kref * (cur_dip - s[S_MAG_REF_DIP])
            else:
                s[S_MAG_UNDIST_T] = 0.0
                s[S_MAG_DIST] = 1.0
            # a new, steady field replaces the reference after long enough motion in it
            cand_n = s[S_CAND_NORM]
            if abs(cur_norm - cand_n) < c[C_MAG_NORM_TH] * cand_n \
                    and abs(cur_dip - s[S_CAND_DIP]) < c[C_MAG_DIP_TH]:
                g0, g1, g2 = s[S_RG_OUT], s[S_RG_OUT + 1], s[S_RG_OUT + 2]
                if g0 * g0 + g1 * g1 + g2 * g2 >= c[C_MAG_NEW_MIN_GYRO] ** 2:
                    s[S_CAND_T] += tsm
                s[S_CAND_NORM] += kref * (cur_norm - cand_n)
                s[S_CAND_DIP] += kref * (cur_dip - s[S_CAND_DIP])
                if s[S_MAG_DIST] != 0.0 and (
                        s[S_CAND_T] >= c[C_MAG_NEW]
                        or (s[S_MAG_REF_NORM] == 0.0 and s[S_CAND_T] >= c[C_MAG_NEW_FIRST])):
                    s[S_MAG_REF_NORM] = s[S_CAND_NORM]
                    s[S_MAG_REF_DIP] = s[S_CAND_DIP]
                    s[S_MAG_DIST] = 0.0
                    s[S_MAG_UNDIST_T] = c[C_MAG_MIN_UNDIST]
            else:
                s[S_CAND_T] = 0.0
                s[S_CAND_NORM] = cur_norm
                s[S_CAND_DIP] = cur_dip
            # soft de-weighting: distance of norm and dip from the reference
            if s[S_MAG_REF_NORM] > 0.0:
                dn = (cur_norm - s[S_MAG_REF_NORM]) / s[S_MAG_REF_NORM]
                dd = cur_dip - s[S_MAG_REF_DIP]
                soft = 1.0 + c[C_SOFT_N] * dn * dn + c[C_SOFT_D] * dd * dd
        dis = math.atan2(ex, ey) - s[S_DELTA]
        if dis > math.pi:
            dis -= 2.0 * math.pi
        elif dis < -math.pi:
            dis += 2.0 * math.pi
        s[S_MAG_DIS] = dis
        k = c[C_K_MAG]
        r_head = c[C_R_HEAD]
        hkf = c[C_HEADING_KF] != 0.0
        if hkf:
            s[S_P_HEAD] += c[C_Q_HEAD] + c[C_Q_RATE] * s[S_ROT2]
        s[S_ROT2] = 0.0
        if reject_on:
            if s[S_MAG_DIST] != 0.0:
                if s[S_MAG_REJECT_T] <= c[C_MAG_MAX_REJECT]:
                    s[S_MAG_REJECT_T] += tsm
                    k = 0.0
                    r_head = 0.0
                else:
                    k /= c[C_MAG_REJECT_FACTOR]
                    r_head = c[C_R_HEAD] * c[C_MAG_REJECT_FACTOR] * c[C_MAG_REJECT_FACTOR]
            else:
                s[S_MAG_REJECT_T] = max(s[S_MAG_REJECT_T] - c[C_MAG_REJECT_FACTOR] * tsm, 0.0)
        k /= soft
        r_head *= soft
        if hkf and r_head > 0.0:
            k = s[S_P_HEAD] / (s[S_P_HEAD] + r_head)
            s[S_P_HEAD] *= 1.0 - k
        ki = s[S_K_MAG_INIT]
        if ki != 0.0:
            if k < ki:
                k = ki
                s[S_P_HEAD] = ki * c[C_R_HEAD]
            ki = ki / (ki + 1.0)
            if ki * c[C_TAU_MAG] < tsm:
                ki = 0.0
            s[S_K_MAG_INIT] = ki
        s[S_K_MAG_USED] = k
        d = s[S_DELTA] + k * dis
        if d > math.pi:
            d -= 2.0 * math.pi
        elif d < -math.pi:
            d += 2.0 * math.pi
        s[S_DELTA] = d
        s[S_CD] = math.cos(0.5 * d)
        s[S_SD] = math.sin(0.5 * d)
        # heading-rate bias from the magnetometer (integral action about the vertical)
        kb = c[C_K_MAG_BIAS]
        if kb > 0.0 and k > 0.0 and s[S_K_MAG_INIT] == 0.0:
            # vertical of the navigation frame in body coordinates: third row of R_6b
            u0 = q[10]
            u1 = q[11]
            u2 = q[12]
            db = kb * (k / c[C_K_MAG]) * dis * tsm
            s[S_BIAS] = _clip(s[S_BIAS] + db * u0, clip)
            s[S_BIAS + 1] = _clip(s[S_BIAS + 1] + db * u1, clip)
            s[S_BIAS + 2] = _clip(s[S_BIAS + 2] + db * u2, clip)
    else:
        flags |= 2
    return flags


@njit(cache=True, error_model="numpy", inline="always")
def quat9(s, q):
    """``q[0:4] <- q_z(δ) ⊗ q[0:4]`` (ENU from body, ``q[0:4]`` holding ``q_6b``)."""
    cd = s[S_CD]  # cos(δ/2), sin(δ/2), updated with δ
    sd = s[S_SD]
    w, x, y, z = q[0], q[1], q[2], q[3]
    q[0] = cd * w - sd * z
    q[1] = cd * x - sd * y
    q[2] = cd * y + sd * x
    q[3] = cd * z + sd * w


@njit(cache=True, error_model="numpy")
def robust_ahrs_batch(dt, gyro, acc, mag, s, c, q_out, bias_out, rest_out, dist_out,
                      acc_rate_out, k_mag_out, hi_out, flags_out):
    """Run N samples (``dt`` (N,) s, sensors (N, 3)) from state ``s`` (updated in place).

    Outputs: ``q_out`` (N, 4) ``q_nb``, ``bias_out`` (N, 3) rad/s, ``rest_out``,
    ``dist_out`` (N,) bool, ``acc_rate_out``, ``k_mag_out`` (N,), ``hi_out`` (N, 3) hard-iron
    offset in use, ``flags_out`` (N,) int bits.
    """
    v = np.empty(9)
    r = np.empty(9)
    h = np.empty(9)
    k33 = np.empty(9)
    tmp = np.empty(18)
    q = np.empty(13)
    for i in range(dt.shape[0]):
        f = robust_ahrs_step(s, c, dt[i], gyro[i, 0], gyro[i, 1], gyro[i, 2], acc[i, 0],
                             acc[i, 1], acc[i, 2], mag[i, 0], mag[i, 1], mag[i, 2], v, r, h,
                             k33, tmp, q)
        quat9(s, q)
        q_out[i, 0] = q[0]
        q_out[i, 1] = q[1]
        q_out[i, 2] = q[2]
        q_out[i, 3] = q[3]
        bias_out[i, 0] = s[S_BIAS]
        bias_out[i, 1] = s[S_BIAS + 1]
        bias_out[i, 2] = s[S_BIAS + 2]
        rest_out[i] = s[S_REST] != 0.0
        dist_out[i] = s[S_MAG_DIST] != 0.0
        acc_rate_out[i] = s[S_ACC_RATE]
        k_mag_out[i] = s[S_K_MAG_USED]
        hi_out[i, 0] = s[S_HI_O]
        hi_out[i, 1] = s[S_HI_O + 1]
        hi_out[i, 2] = s[S_HI_O + 2]
        flags_out[i] = f

