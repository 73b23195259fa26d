"""Numba kernels of the simulators, batched over runs: the IMU truth and its sensors.

:func:`ahrs_batch` computes what ``gnomon.simulation.ahrs.simulate_ahrs_reference``
(the readable numpy twin the tests compare it with) computes, for R runs in one call.
The random numbers are not drawn here: each run's ``numpy.random.Generator`` draws
them in the reference's order and hands them in, so a seed gives the reference's
samples (to rounding, about 1e-13 of each value).

Conventions (``docs/conventions.md``): Hamilton quaternions, scalar first
``[w, x, y, z]``; ``q_nb`` maps body coordinates to navigation (ENU) coordinates; SI
units (s, rad, rad/s, m/s²), the magnetometer in µT.

How it is fast: the runs of a block of :data:`BLOCK` are the innermost loop (their
arithmetic is independent, so it vectorises and the chain of quaternion products of
one run does not wait on itself), and sums of sinusoids ``Σ_h a_h sin(2π f_h t + φ_h)``
are evaluated without a sine per value: at sample ``k`` the phasor ``(a cos θ_k,
a sin θ_k)``, ``θ_k = 2π f t_k + φ``, is rotated on from sample ``k - 1`` by the exact
rotation of one interval (re-anchored with ``cos``/``sin`` every :data:`ANCHOR_EVERY`
samples, so its rounding stays below 1e-14 of ``a``), and the value ``τ`` after ``t_k``
is ``a sin θ_k cos 2πfτ + a cos θ_k sin 2πfτ``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from gnomon.kernels.quat import SMALL_TH2, exp_mul, mul, rotate_inv

__all__ = ["ANCHOR_EVERY", "BLOCK", "CONING", "GAUSS_C", "sinusoid_tables", "ahrs_batch",
           "normals_by_sample"]

#: samples between two exact evaluations of a sinusoid's phase (the others by rotation)
ANCHOR_EVERY = 64
#: runs computed side by side (the innermost loop)
BLOCK = 8
#: the Gauss-Legendre points of a substep of length h sit at h (1/2 ∓ GAUSS_C)
GAUSS_C = math.sqrt(3.0) / 6.0
#: the commutator term of the 4th-order Magnus step: CONING h² (w_a × w_b)
CONING = math.sqrt(3.0) / 12.0


@njit(cache=True)
def normals_by_sample(rng, bias, gyro, accel, mag):
    """Standard normal draws of ``rng`` (a ``numpy.random.Generator``) into the four
    (N, 3) arrays, sample by sample: for each k the bias step, the gyro, the
    accelerometer and the magnetometer noise, three each. The numbers of
    ``rng.standard_normal((N, 12))`` split by columns (numba runs numpy's own normal
    algorithm on ``rng``'s bit generator, so the stream is numpy's, and the generator
    is advanced as numpy's call would advance it); drawn here, one compiled loop per
    run, because that is faster than numpy's fill (with an SFC64 generator, 7.2 against
    10.7 ns per value on the 2-core machine).
    """
    for k in range(bias.shape[0]):
        for j in range(3):
            bias[k, j] = rng.standard_normal()
        for j in range(3):
            gyro[k, j] = rng.standard_normal()
        for j in range(3):
            accel[k, j] = rng.standard_normal()
        for j in range(3):
            mag[k, j] = rng.standard_normal()


@njit(cache=True)
def sinusoid_tables(f_hz, phase, amp, dt, offsets, rot, off, coef):
    """The constants of sums of sinusoids of a block of runs, axes and runs innermost.

    ``f_hz``, ``phase``, ``amp`` (B, H, 3): frequency (Hz), phase (rad), amplitude of
    harmonic h of axis j of run b; ``dt`` s the sample interval; ``offsets`` (S,) s the
    times after a sample at which values are wanted. Column ``j * BLOCK + b`` of the
    outputs belongs to axis j of run b: ``rot`` (H, 2, 3 BLOCK) cos and sin of
    ``2π f dt``; ``off`` (S, H, 2, 3 BLOCK) cos and sin of ``2π f τ_s``; ``coef``
    (H, 3, 3 BLOCK) ``2π f``, ``φ``, ``a`` (for the exact anchors).
    """
    for b in range(f_hz.shape[0]):
        for hh in range(f_hz.shape[1]):
            for j in range(3):
                col = j * BLOCK + b
                w = 2.0 * np.pi * f_hz[b, hh, j]
                rot[hh, 0, col] = math.cos(w * dt)
                rot[hh, 1, col] = math.sin(w * dt)
                for s in range(offsets.shape[0]):
                    off[s, hh, 0, col] = math.cos(w * offsets[s])
                    off[s, hh, 1, col] = math.sin(w * offsets[s])
                coef[hh, 0, col] = w
                coef[hh, 1, col] = phase[b, hh, j]
                coef[hh, 2, col] = amp[b, hh, j]


@njit(cache=True)
def _phasors(anchor, t_k, nb, coef, rot, cs):
    """Phasors ``cs`` (H, 2, 3 BLOCK) = ``a cos θ_k``, ``a sin θ_k`` at sample time ``t_k``
    (s): exact if ``anchor``, else rotated on from the previous sample's by ``rot``
    (:func:`sinusoid_tables`)."""
    for hh in range(cs.shape[0]):
        if anchor:
            for col in range(cs.shape[2]):
                if col % BLOCK >= nb:
                    continue
                th = coef[hh, 0, col] * t_k + coef[hh, 1, col]
                cs[hh, 0, col] = coef[hh, 2, col] * math.cos(th)
                cs[hh, 1, col] = coef[hh, 2, col] * math.sin(th)
        else:
            for j in range(3):
                for col in range(j * BLOCK, j * BLOCK + nb):
                    c = cs[hh, 0, col]
                    s = cs[hh, 1, col]
                    cs[hh, 0, col] = c * rot[hh, 0, col] - s * rot[hh, 1, col]
                    cs[hh, 1, col] = s * rot[hh, 0, col] + c * rot[hh, 1, col]


@njit(cache=True)
def _sum_now(cs, gate, out):
    """``out`` (3 BLOCK,) = ``gate`` times the sums of sinusoids at the phasors' sample."""
    for col in range(out.shape[0]):
        v = 0.0
        for hh in range(cs.shape[0]):
            v += cs[hh, 1, col]
        out[col] = v * gate


@njit(cache=True, error_model="numpy")
def _imu_samples(r0, nb, k0, count, qbuf, wbuf, abuf, dbuf, acc_n, m_n, bias0, sigma,
                 walk, gyro, bias, accel, mag, q_nb, w_true):
    """Samples ``k0 .. k0 + count - 1`` of runs ``r0 .. r0 + nb - 1`` (see
    :func:`ahrs_batch`) from the block's buffers: ``qbuf`` (C, 4, BLOCK) ``q_nb``,
    ``wbuf`` (C, 3 BLOCK) the true rate read, ``abuf``, ``dbuf`` (C, 3 BLOCK) the linear
    acceleration (m/s²) and the field disturbance (µT) in n; ``walk`` (3, BLOCK) the
    bias random walk so far (advanced here); ``acc_n``, ``m_n`` (R, 3), ``sigma`` (R, 4)
    per run."""
    for b in range(nb):
        r = r0 + b
        s_rw, s_gyro, s_acc, s_mag = sigma[r, 0], sigma[r, 1], sigma[r, 2], sigma[r, 3]
        a0x, a0y, a0z = acc_n[r, 0], acc_n[r, 1], acc_n[r, 2]
        m0x, m0y, m0z = m_n[r, 0], m_n[r, 1], m_n[r, 2]
        wx, wy, wz = walk[0, b], walk[1, b], walk[2, b]
        for kk in range(count):
            k = k0 + kk
            qw, qx, qy, qz = qbuf[kk, 0, b], qbuf[kk, 1, b], qbuf[kk, 2, b], qbuf[kk, 3, b]
            q_nb[r, k, 0], q_nb[r, k, 1], q_nb[r, k, 2], q_nb[r, k, 3] = qw, qx, qy, qz
            wx += s_rw * bias[r, k, 0]
            wy += s_rw * bias[r, k, 1]
            wz += s_rw * bias[r, k, 2]
            bx, by, bz = bias0[r, 0] + wx, bias0[r, 1] + wy, bias0[r, 2] + wz
            bias[r, k, 0], bias[r, k, 1], bias[r, k, 2] = bx, by, bz
            gx, gy, gz = wbuf[kk, b], wbuf[kk, BLOCK + b], wbuf[kk, 2 * BLOCK + b]
            w_true[r, k, 0], w_true[r, k, 1], w_true[r, k, 2] = gx, gy, gz
            gyro[r, k, 0] = (gx + bx) + s_gyro * gyro[r, k, 0]
            gyro[r, k, 1] = (gy + by) + s_gyro * gyro[r, k, 1]
            gyro[r, k, 2] = (gz + bz) + s_gyro * gyro[r, k, 2]
            ax, ay, az = rotate_inv(qw, qx, qy, qz, a0x + abuf[kk, b],
                                    a0y + abuf[kk, BLOCK + b], a0z + abuf[kk, 2 * BLOCK + b])
            accel[r, k, 0] = ax + s_acc * accel[r, k, 0]
            accel[r, k, 1] = ay + s_acc * accel[r, k, 1]
            accel[r, k, 2] = az + s_acc * accel[r, k, 2]
            mx, my, mz = rotate_inv(qw, qx, qy, qz, m0x + dbuf[kk, b],
                                    m0y + dbuf[kk, BLOCK + b], m0z + dbuf[kk, 2 * BLOCK + b])
            mag[r, k, 0] = mx + s_mag * mag[r, k, 0]
            mag[r, k, 1] = my + s_mag * mag[r, k, 1]
            mag[r, k, 2] = mz + s_mag * mag[r, k, 2]
        walk[0, b], walk[1, b], walk[2, b] = wx, wy, wz


@njit(cache=True, error_model="numpy")
def ahrs_batch(t, dt, substeps, rest_s, window_s, rate_f, rate_ph, rate_amp, q0, acc_n,
               acc_f, acc_ph, acc_amp, m_n, dist_uT, dist_f, dist_ph, dist_amp, bias0,
               sigma, gyro, bias, accel, mag, q_nb, w_true):
    """Truth attitude and gyro / accelerometer / magnetometer samples of R runs.

    Model (``gnomon.simulation.ahrs``): the body rate ``w_b(t)`` (rad/s) is a sum of
    sinusoids (zero before ``rest_s`` s); the attitude is integrated from it with
    ``substeps`` 4th-order Magnus steps per sample interval (a substep of length ``h``:
    ``exp(h/2 (w_a + w_b) + √3/12 h² w_a × w_b)`` from the rates at its two
    Gauss-Legendre points; their product, then ``q_nb[k+1] = normalise(q_nb[k] ⊗
    step)``); the gyro reads the
    rate at the interval's midpoint (sample 0: at ``t[0]``) plus a bias (a constant plus
    a random walk) and white noise; the accelerometer ``R(q_nb)ᵀ (acc_n + a_lin)`` plus
    noise, the magnetometer ``R(q_nb)ᵀ (m_n + d)`` plus noise, with the linear
    acceleration ``a_lin`` (a sum of sinusoids, zero before ``rest_s``) and the
    disturbance ``d`` (``dist_uT`` times the unit direction of a sum of sinusoids) only
    while ``window_s[0] <= t < window_s[1]``.

    Arguments (R runs, N samples; each sum of sinusoids has its own number of
    harmonics per axis, H):

    * ``t`` (N,) s, uniform with step ``dt`` s; ``substeps`` int >= 1; ``rest_s`` s;
      ``window_s`` (2,) s.
    * ``rate_f``, ``rate_ph``, ``rate_amp`` (R, H, 3): Hz, rad, rad/s of ``w_b``;
      ``acc_*`` (R, H, 3) (amplitude m/s²) of ``a_lin``; ``dist_*`` (R, H, 3) of the
      direction of ``d`` (H = 0: no such term).
    * ``q0`` (R, 4): ``q_nb`` at ``t[0]``; ``acc_n`` (R, 3) m/s² the specific force at
      rest in n (``[0, 0, g]``); ``m_n`` (R, 3) µT the field in n; ``dist_uT`` (R,) µT.
    * ``bias0`` (R, 3) rad/s: the constant gyro bias; ``sigma`` (R, 4): the standard
      deviations per sample of the bias random-walk step (rad/s), the gyro noise
      (rad/s), the accelerometer noise (m/s²), the magnetometer noise (µT).
    * ``gyro``, ``bias``, ``accel``, ``mag`` (R, N, 3): on entry standard normal draws
      (the gyro noise, the bias steps, the accelerometer and magnetometer noise); on
      exit the gyro (rad/s), its bias (rad/s), accelerometer (m/s²), magnetometer (µT)
      samples in body axes.
    * ``q_nb`` (R, N, 4), ``w_true`` (R, N, 3) rad/s: written, the truth attitude and the
      true rate the gyro read (before bias and noise).
    """
    n = t.shape[0]
    h = dt / substeps
    n_runs = q0.shape[0]
    # times after sample k at which the rate is wanted: each substep's two Gauss-Legendre
    # points, then the interval's midpoint (the gyro's next sample)
    offsets = np.empty(2 * substeps + 1)
    for i in range(substeps):
        offsets[2 * i] = (i + 0.5 - GAUSS_C) * h
        offsets[2 * i + 1] = (i + 0.5 + GAUSS_C) * h
    offsets[2 * substeps] = 0.5 * dt
    half_h = 0.5 * h
    coning = CONING * h * h
    no_offset = np.zeros(0)
    hr, ha, hd = rate_f.shape[1], acc_f.shape[1], dist_f.shape[1]
    cols = 3 * BLOCK
    rot, coef, cs = np.zeros((hr, 2, cols)), np.zeros((hr, 3, cols)), np.zeros((hr, 2, cols))
    off = np.zeros((2 * substeps + 1, hr, 2, cols))
    rot_a, coef_a, cs_a = np.zeros((ha, 2, cols)), np.zeros((ha, 3, cols)), np.zeros((ha, 2, cols))
    rot_d, coef_d, cs_d = np.zeros((hd, 2, cols)), np.zeros((hd, 3, cols)), np.zeros((hd, 2, cols))
    off0 = np.zeros((0, 0, 2, cols))
    chunk = ANCHOR_EVERY
    qbuf = np.zeros((chunk, 4, BLOCK))
    wbuf = np.zeros((chunk, cols))
    abuf = np.zeros((chunk, cols))
    dbuf = np.zeros((chunk, cols))
    q = np.zeros((4, BLOCK))
    step = np.zeros((4, BLOCK))
    e = np.zeros((4, BLOCK))
    wsum = np.zeros((2 * substeps, cols))
    rv = np.zeros((3, BLOCK))
    w_next = np.zeros(cols)
    dvec = np.zeros(cols)
    walk = np.zeros((3, BLOCK))
    for r0 in range(0, n_runs, BLOCK):
        nb = min(BLOCK, n_runs - r0)
        sinusoid_tables(rate_f[r0:r0 + nb], rate_ph[r0:r0 + nb], rate_amp[r0:r0 + nb], dt,
                        offsets, rot, off, coef)
        sinusoid_tables(acc_f[r0:r0 + nb], acc_ph[r0:r0 + nb], acc_amp[r0:r0 + nb], dt,
                        no_offset, rot_a, off0, coef_a)
        sinusoid_tables(dist_f[r0:r0 + nb], dist_ph[r0:r0 + nb], dist_amp[r0:r0 + nb], dt,
                        no_offset, rot_d, off0, coef_d)
        for b in range(BLOCK):
            for j in range(4):
                q[j, b] = q0[r0 + b, j] if b < nb else (1.0 if j == 0 else 0.0)
            for j in range(3):
                walk[j, b] = 0.0
        for k in range(n):
            t_k = t[k]
            kk = k % chunk
            anchor = kk == 0
            _phasors(anchor, t_k, nb, coef, rot, cs)
            if k == 0:
                _sum_now(cs, 1.0 if t_k >= rest_s else 0.0, w_next)
            active = t_k >= window_s[0] and t_k < window_s[1]
            if ha > 0:
                _phasors(anchor, t_k, nb, coef_a, rot_a, cs_a)
                _sum_now(cs_a, 1.0 if (active and t_k >= rest_s) else 0.0, abuf[kk])
            if hd > 0:
                _phasors(anchor, t_k, nb, coef_d, rot_d, cs_d)
                _sum_now(cs_d, 1.0, dvec)
                for b in range(BLOCK):
                    dx, dy, dz = dvec[b], dvec[BLOCK + b], dvec[2 * BLOCK + b]
                    norm = max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-12)
                    g = dist_uT[r0 + b] / norm if (active and b < nb) else 0.0
                    dbuf[kk, b], dbuf[kk, BLOCK + b], dbuf[kk, 2 * BLOCK + b] = (
                        dx * g, dy * g, dz * g)
            # sample k into the buffers; written out every chunk
            for j in range(4):
                for b in range(BLOCK):
                    qbuf[kk, j, b] = q[j, b]
            for col in range(cols):
                wbuf[kk, col] = w_next[col]
            if kk == chunk - 1 or k == n - 1:
                _imu_samples(r0, nb, k - kk, kk + 1, qbuf, wbuf, abuf, dbuf, acc_n, m_n,
                             bias0, sigma, walk, gyro, bias, accel, mag, q_nb, w_true)
            if k == n - 1:
                break
            # the interval [t_k, t_k+1]: the rates at each substep's two Gauss points, then
            # the gyro's midpoint rate (each sum in a local variable, not an array element:
            # 12 % faster; the same sums in the same order)
            for i in range(0, 2 * substeps, 2):
                ga = 1.0 if t_k + offsets[i] >= rest_s else 0.0
                gb = 1.0 if t_k + offsets[i + 1] >= rest_s else 0.0
                for col in range(cols):
                    if col % BLOCK >= nb:
                        continue
                    sa = 0.0
                    sb = 0.0
                    for hh in range(hr):
                        sv = cs[hh, 1, col]
                        cv = cs[hh, 0, col]
                        sa += sv * off[i, hh, 0, col] + cv * off[i, hh, 1, col]
                        sb += sv * off[i + 1, hh, 0, col] + cv * off[i + 1, hh, 1, col]
                    wsum[i, col] = sa * ga
                    wsum[i + 1, col] = sb * gb
            gm = 1.0 if t[k + 1] - 0.5 * dt >= rest_s else 0.0
            im = 2 * substeps
            for col in range(cols):
                if col % BLOCK >= nb:
                    continue
                sm = 0.0
                for hh in range(hr):
                    sm += (cs[hh, 1, col] * off[im, hh, 0, col]
                           + cs[hh, 0, col] * off[im, hh, 1, col])
                w_next[col] = sm * gm
            for i in range(1, 2 * substeps, 2):
                wa = wsum[i - 1]
                wb = wsum[i]
                th2_max = 0.0
                for b in range(nb):
                    # the 4th-order Magnus rotation vector of the substep, then exp of it
                    # (Taylor form of gnomon.kernels.quat.exp_mul, exact below 0.05 rad)
                    ax, ay, az = wa[b], wa[BLOCK + b], wa[2 * BLOCK + b]
                    bx, by, bz = wb[b], wb[BLOCK + b], wb[2 * BLOCK + b]
                    rx = half_h * (ax + bx) + coning * (ay * bz - az * by)
                    ry = half_h * (ay + by) + coning * (az * bx - ax * bz)
                    rz = half_h * (az + bz) + coning * (ax * by - ay * bx)
                    rv[0, b], rv[1, b], rv[2, b] = rx, ry, rz
                    th2 = rx * rx + ry * ry + rz * rz
                    th2_max = max(th2_max, th2)
                    t4 = th2 * th2
                    kc = (0.5 - th2 * (1.0 / 48.0)) + t4 * (1.0 / 3840.0 - th2 * (1.0 / 645120.0))
                    e[0, b] = (1.0 - th2 * (1.0 / 8.0)) + t4 * (1.0 / 384.0 - th2 * (1.0 / 46080.0))
                    e[1, b] = kc * rx
                    e[2, b] = kc * ry
                    e[3, b] = kc * rz
                big = th2_max >= SMALL_TH2
                if big:
                    for b in range(nb):
                        ew, ex, ey, ez, _ = exp_mul(1.0, 0.0, 0.0, 0.0, rv[0, b], rv[1, b],
                                                    rv[2, b], True, False)
                        e[0, b], e[1, b], e[2, b], e[3, b] = ew, ex, ey, ez
                if i == 1:
                    for j in range(4):
                        for b in range(nb):
                            step[j, b] = e[j, b]
                else:
                    for b in range(nb):
                        step[0, b], step[1, b], step[2, b], step[3, b] = mul(
                            step[0, b], step[1, b], step[2, b], step[3, b],
                            e[0, b], e[1, b], e[2, b], e[3, b])
            for b in range(nb):
                qw, qx, qy, qz = mul(q[0, b], q[1, b], q[2, b], q[3, b],
                                     step[0, b], step[1, b], step[2, b], step[3, b])
                sc = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
                q[0, b], q[1, b], q[2, b], q[3, b] = qw * sc, qx * sc, qy * sc, qz * sc
