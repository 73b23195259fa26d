"""Compiled error-state Rauch-Tung-Striebel smoother on the ESKF (issue 20, offline).

Readable twin: ``gnomon.estimators.eskf_offline.rts_reference`` (numpy matrices, the same
recursion sample by sample); ``tests/test_eskf_smoother.py`` compares the two, checks the
recursion (``rts_core``) against the batch least-squares solution of a linear-Gaussian
problem, and the whole smoother against simulated truth (error, NEES).

Two passes over ``Inputs`` (``gnomon.kernels.eskf``):

* ``forward_pass``: the ESKF itself, ``gnomon.kernels.eskf.step`` in the same loop as its
  ``run_batch`` (so ``q_fwd`` equals ``run_batch``'s ``q``: bit for bit, or a few 1e-15
  apart where fastmath orders a sum differently in this loop), storing per sample the
  updated ``q⁺`` (``q_fwd``), ``b⁺`` (``bias``) and the 21 unique entries of ``P⁺``
  (``P``, upper triangle row by row: ``P00 P01 … P05 P11 … P55``);
* ``backward_pass``: for ``k = N-2 … 0``, with ``ω̂ = ω_{k+1} - b⁺_k``, ``dt = dt_{k+1}``,
  ``Φ = [A cI; 0 I]`` (``A = I - [ω̂×]dt``, ``c = -dt/2``), ``Q = diag(σ_g²dt/4 I, σ_b²dt I)``
  (the ESKF's ``predict``):

  - ``P⁻ = Φ P⁺_k Φᵀ + Q``, ``q⁻ = q⁺_k ⊗ exp(ω̂ dt)`` (the prediction of sample k+1);
  - ``δ = [δe; δb]`` the smoothed state of k+1 as an error of that prediction:
    ``δe = vec(δq)/w(δq)``, ``δq = q⁻* ⊗ q_s,k+1`` (the exact inverse of ``inject``'s
    ``q ← normalise(q ⊗ [1, δe])``; half-angles, ``≈ vec(δq)``), ``δb = b_s,k+1 - b⁺_k``;
  - gain ``C = P⁺_k Φᵀ (P⁻)⁻¹``, found as ``Cᵀ = (P⁻)⁻¹ (Φ P⁺_k)`` by an ``LDLᵀ``
    factorisation of ``P⁻`` and six solves (no inverse);
  - ``δx = C δ``; ``q_s,k = normalise(q⁺_k ⊗ [1, δx_e])``, ``b_s,k = b⁺_k + δx_b`` (within
    ``±bias_limit``, as the filter's), ``P_s,k = P⁺_k + C (P_s,k+1 - P⁻) Cᵀ``;

  writing the smoothed ``q``, ``bias`` (over the forward ``b⁺``, which it no longer
  needs) and the per-axis 1-sigma rotation angle ``att_std = 2 sqrt(P_s,ii)`` (rad, body
  axes of the error; ``δe`` is a half-angle); ``att_cov`` (upper triangle of the
  attitude block ``4 P_s[0:3, 0:3]``, rad²) only when it has N rows.

The last sample's smoothed state is the filter's. Rao, Rauch, Tung & Striebel, AIAA J.
3(8), 1965; the error-state form as in Sola, "Quaternion kinematics for the
error-state Kalman filter" (2017), with the reset of the error after each update
(``δ`` is re-expressed about each sample's own nominal state).

Memory: the forward pass stores 21 + 3 + 4 floats per sample (the covariance as its
unique entries, float64: the gain divides by small differences of its entries), the
backward pass writes 4 + 3 more (plus 6 with ``att_cov``): 280 bytes per sample, 0.56 GB
for two million samples. The scratch matrices of the backward step are allocated once.

Frames and units: as ``gnomon.kernels.eskf`` (``q_nb`` ENU from body, bias rad/s, body).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from gnomon.kernels.eskf import MODE_PREDICT_ONLY, MODE_R3, MODE_R6, SCRATCH, step, workspace
from gnomon.kernels.linalg import clip
from gnomon.kernels.quat import exp_mul, mul, normalised

__all__ = ["N_UPPER", "Passes", "new_passes", "forward_pass", "backward_pass", "smooth",
           "rts_core", "unpack_upper", "pack_upper", "consistency_terms"]

#: unique entries of a symmetric 6x6 matrix
N_UPPER = 21
#: a pivot of ``P⁻``'s ``LDLᵀ`` at most this fraction of its diagonal entry is taken as 0:
#: a direction the model gives no uncertainty (``bias_rw = 0`` and a converged bias),
#: which the smoother leaves as the filter has it (pseudo-inverse) instead of dividing
#: by rounding noise
PIVOT_FLOOR = 1e-13

_JIT = {"cache": True, "fastmath": True, "error_model": "numpy"}


class Passes(NamedTuple):
    """Per-sample arrays of the two passes (``new_passes(n)``)."""

    q_fwd: np.ndarray    #: (N, 4) q_nb after each sample's update (the causal estimate)
    bias: np.ndarray     #: (N, 3) rad/s: b⁺ after the forward pass, smoothed after backward
    P: np.ndarray        #: (N, 21) upper triangle of P⁺, row by row
    q: np.ndarray        #: (N, 4) smoothed q_nb
    att_std: np.ndarray  #: (N, 3) rad, per-axis 1-sigma rotation angle of the smoothed error
    att_cov: np.ndarray  #: (N, 6) or (0, 6): upper triangle of 4 P_s[0:3, 0:3], rad²


def new_passes(n: int, attitude_cov: bool = False) -> Passes:
    """``Passes`` for ``n`` samples (``att_cov`` with ``n`` rows only if ``attitude_cov``)."""
    return Passes(np.empty((n, 4)), np.empty((n, 3)), np.empty((n, N_UPPER)),
                  np.empty((n, 4)), np.empty((n, 3)),
                  np.empty((n if attitude_cov else 0, 6)))


@njit(inline="always", **_JIT)
def unpack_upper(row, P):
    """``P`` (6, 6) symmetric from its upper triangle ``row`` (21,), row by row."""
    m = 0
    for i in range(6):
        for j in range(i, 6):
            P[i, j] = row[m]
            P[j, i] = row[m]
            m += 1


@njit(inline="always", **_JIT)
def pack_upper(P, row):
    """The upper triangle of ``P`` (6, 6), row by row, into ``row`` (21,)."""
    m = 0
    for i in range(6):
        for j in range(i, 6):
            row[m] = P[i, j]
            m += 1


# ---------------------------------------------------------------- forward: the filter
@njit(**_JIT)
def _forward_loop(inputs, s, c, out, w, mode, scratch):
    """``gnomon.kernels.eskf._loop`` storing ``q⁺``, ``b⁺`` and ``P⁺`` (its other outputs
    are not needed here)."""
    since = s.since_acc_s
    q_fwd, bias, Pu = out.q_fwd, out.bias, out.P
    for k in range(inputs.dt.shape[0]):
        r, since = step(s, c, mode, inputs, k, w, since, scratch)
        for j in range(4):
            q_fwd[k, j] = s.q[j]
        for j in range(3):
            bias[k, j] = s.bias[j]
        P = s.P
        m = 0
        for i in range(6):
            for j in range(i, 6):
                Pu[k, m] = P[i, j]
                m += 1
    s.since_acc_s = since


@njit(**_JIT)
def forward_pass(inputs, state, c, out):
    """The ESKF over ``inputs`` from ``state`` (updated in place, as ``run_batch``) with the
    coefficients ``c``; writes ``out.q_fwd``, ``out.bias`` (b⁺) and ``out.P`` (P⁺)."""
    local = state.copy()  # as run_batch: nothing else can alias the state in the loop
    s = local[0]
    w = workspace()
    scratch = np.empty(SCRATCH)
    if c.mode == MODE_R6:
        _forward_loop(inputs, s, c, out, w, MODE_R6, scratch)
    elif c.mode == MODE_R3:
        _forward_loop(inputs, s, c, out, w, MODE_R3, scratch)
    else:
        _forward_loop(inputs, s, c, out, w, MODE_PREDICT_ONLY, scratch)
    state[0] = local[0]


# ---------------------------------------------------------------- backward: the RTS step
@njit(**_JIT)
def rts_core(P, Ps, d, wx, wy, wz, dt, qa, qb, M, Pm, L, invd, X, dx):
    """One RTS step on the error state for ``Φ = [A cI; 0 I]``, ``Q = diag(qa I, qb I)``.

    ``P`` (6, 6) the filtered ``P⁺_k``; ``Ps`` (6, 6) ``P_s,k+1`` on entry, ``P_s,k`` on
    return; ``d`` (6,) the smoothed state of k+1 minus the prediction; ``(wx, wy, wz)``
    the bias-corrected rate ω̂ (rad/s) and ``dt`` (s) of ``Φ``; ``qa = σ_g² dt / 4``,
    ``qb = σ_b² dt``. Writes ``dx = C d`` (6,), ``C = P Φᵀ (P⁻)⁻¹``. Scratch (6, 6):
    ``M = Φ P``, ``Pm = P⁻``, ``L`` (unit lower factor), ``X = Cᵀ``; ``invd`` (6,).
    """
    c = -0.5 * dt
    a01 = wz * dt
    a02 = -wy * dt
    a12 = wx * dt
    # M = Φ P: rows 0-2 = A P[0:3, :] + c P[3:6, :], rows 3-5 = P[3:6, :]
    for j in range(6):
        p0, p1, p2 = P[0, j], P[1, j], P[2, j]
        M[0, j] = p0 + a01 * p1 + a02 * p2 + c * P[3, j]
        M[1, j] = -a01 * p0 + p1 + a12 * p2 + c * P[4, j]
        M[2, j] = -a02 * p0 - a12 * p1 + p2 + c * P[5, j]
        M[3, j] = P[3, j]
        M[4, j] = P[4, j]
        M[5, j] = P[5, j]
    # P⁻ = M Φᵀ + Q (lower triangle): M Φᵀ = [T Aᵀ + c U, U; Uᵀ, P22], T|U = M[0:3, :]
    for i in range(3):
        m0, m1, m2 = M[i, 0], M[i, 1], M[i, 2]
        Pm[i, 0] = m0 + a01 * m1 + a02 * m2 + c * M[i, 3]
        if i >= 1:
            Pm[i, 1] = -a01 * m0 + m1 + a12 * m2 + c * M[i, 4]
        if i >= 2:
            Pm[i, 2] = -a02 * m0 - a12 * m1 + m2 + c * M[i, 5]
        Pm[i, i] += qa
    for i in range(3, 6):
        for j in range(3):
            Pm[i, j] = M[j, i]
        for j in range(3, i + 1):
            Pm[i, j] = P[i, j]
        Pm[i, i] += qb
    # ΔP = P_s,k+1 - P⁻ (full, in Ps), before P⁻ is factorised
    for i in range(6):
        for j in range(i + 1):
            v = Ps[i, j] - Pm[i, j]
            Ps[i, j] = v
            Ps[j, i] = v
    # P⁻ = L diag(d) Lᵀ (L unit lower); a pivot at the floor counts as 0 (PIVOT_FLOOR)
    for j in range(6):
        dj = Pm[j, j]
        for k in range(j):
            dj -= L[j, k] * L[j, k] * Pm[k, k]
        ok = dj > PIVOT_FLOOR * Pm[j, j]
        Pm[j, j] = dj  # Pm's diagonal now holds d (read by the rows below)
        inv = 1.0 / dj if ok else 0.0
        invd[j] = inv
        for i in range(j + 1, 6):
            v = Pm[i, j]
            for k in range(j):
                v -= L[i, k] * L[j, k] * Pm[k, k]
            L[i, j] = v * inv
    # X = Cᵀ = (P⁻)⁻¹ M, one column of M at a time
    for col in range(6):
        for i in range(6):
            v = M[i, col]
            for k in range(i):
                v -= L[i, k] * X[k, col]
            X[i, col] = v
        for i in range(6):
            X[i, col] *= invd[i]
        for i in range(4, -1, -1):
            v = X[i, col]
            for k in range(i + 1, 6):
                v -= L[k, i] * X[k, col]
            X[i, col] = v
    # dx = C d = Xᵀ d
    for i in range(6):
        v = 0.0
        for k in range(6):
            v += X[k, i] * d[k]
        dx[i] = v
    # P_s,k = P + Xᵀ ΔP X (upper triangle, mirrored); M is free again: M = ΔP X
    for i in range(6):
        for j in range(6):
            v = 0.0
            for k in range(6):
                v += Ps[i, k] * X[k, j]
            M[i, j] = v
    for i in range(6):
        for j in range(i, 6):
            v = P[i, j]
            for k in range(6):
                v += X[k, i] * M[k, j]
            Ps[i, j] = v
            Ps[j, i] = v


@njit(**_JIT)
def _write_attitude(out, k, Ps):
    """``att_std`` (and ``att_cov`` when it has rows) of sample ``k`` from ``P_s,k``."""
    for i in range(3):
        out.att_std[k, i] = 2.0 * math.sqrt(max(Ps[i, i], 0.0))
    if out.att_cov.shape[0] > 0:
        m = 0
        for i in range(3):
            for j in range(i, 3):
                out.att_cov[k, m] = 4.0 * Ps[i, j]
                m += 1


@njit(**_JIT)
def backward_pass(inputs, c, out):
    """The RTS pass over ``out`` after ``forward_pass`` on the same ``inputs`` and ``c``
    (module docstring); writes ``out.q``, ``out.bias`` (smoothed, over b⁺),
    ``out.att_std`` and ``out.att_cov`` (if it has rows)."""
    n = inputs.dt.shape[0]
    if n == 0:
        return
    gyro, dts = inputs.gyro, inputs.dt
    q_fwd, bias, q_s = out.q_fwd, out.bias, out.q
    lim = c.bias_limit
    P = np.empty((6, 6))
    Ps = np.empty((6, 6))
    M = np.empty((6, 6))
    Pm = np.empty((6, 6))
    L = np.zeros((6, 6))
    X = np.empty((6, 6))
    invd = np.empty(6)
    d = np.empty(6)
    dx = np.empty(6)
    # the last sample: the filter's estimate
    unpack_upper(out.P[n - 1], Ps)
    sw, sx, sy, sz = q_fwd[n - 1, 0], q_fwd[n - 1, 1], q_fwd[n - 1, 2], q_fwd[n - 1, 3]
    q_s[n - 1, 0], q_s[n - 1, 1], q_s[n - 1, 2], q_s[n - 1, 3] = sw, sx, sy, sz
    sb0, sb1, sb2 = bias[n - 1, 0], bias[n - 1, 1], bias[n - 1, 2]
    _write_attitude(out, n - 1, Ps)
    for k in range(n - 2, -1, -1):
        unpack_upper(out.P[k], P)
        fw, fx, fy, fz = q_fwd[k, 0], q_fwd[k, 1], q_fwd[k, 2], q_fwd[k, 3]
        b0, b1, b2 = bias[k, 0], bias[k, 1], bias[k, 2]
        dt = dts[k + 1]
        wx = gyro[k + 1, 0] - b0
        wy = gyro[k + 1, 1] - b1
        wz = gyro[k + 1, 2] - b2
        # the filter's prediction of k+1 (as predict's rotate_by) and δ about it
        pw, px, py, pz, _ = exp_mul(fw, fx, fy, fz, wx * dt, wy * dt, wz * dt, True, True)
        ew, ex, ey, ez = mul(pw, -px, -py, -pz, sw, sx, sy, sz)
        iw = 1.0 / ew
        d[0], d[1], d[2] = ex * iw, ey * iw, ez * iw
        d[3], d[4], d[5] = sb0 - b0, sb1 - b1, sb2 - b2
        rts_core(P, Ps, d, wx, wy, wz, dt, 0.25 * c.var_gyro * dt, c.var_bias * dt,
                 M, Pm, L, invd, X, dx)
        sw, sx, sy, sz = mul(fw, fx, fy, fz, 1.0, dx[0], dx[1], dx[2])
        sw, sx, sy, sz = normalised(sw, sx, sy, sz)
        sb0, sb1, sb2 = clip(b0 + dx[3], lim), clip(b1 + dx[4], lim), clip(b2 + dx[5], lim)
        q_s[k, 0], q_s[k, 1], q_s[k, 2], q_s[k, 3] = sw, sx, sy, sz
        bias[k, 0], bias[k, 1], bias[k, 2] = sb0, sb1, sb2
        _write_attitude(out, k, Ps)


@njit(**_JIT)
def smooth(inputs, state, c, out):
    """``forward_pass`` then ``backward_pass``: the smoothed estimate in ``out``."""
    forward_pass(inputs, state, c, out)
    backward_pass(inputs, c, out)


@njit(**_JIT)
def consistency_terms(out, num, den):
    """Per sample, the two sides of the smoother's consistency check
    (``gnomon.estimators.eskf_offline``): ``num`` (N,) the squared rotation angle between
    the causal ``q_fwd`` and the smoothed ``q`` (rad²) and ``den`` (N,) its expectation
    under the model, ``Σ_i max(4 P⁺_ii - att_std_i², 0)`` (rad², the attitude block)."""
    for k in range(out.q.shape[0]):
        aw, ax, ay, az = out.q[k, 0], out.q[k, 1], out.q[k, 2], out.q[k, 3]
        bw, bx, by, bz = out.q_fwd[k, 0], out.q_fwd[k, 1], out.q_fwd[k, 2], out.q_fwd[k, 3]
        ew, ex, ey, ez = mul(aw, -ax, -ay, -az, bw, bx, by, bz)
        angle = 2.0 * math.atan2(math.sqrt(ex * ex + ey * ey + ez * ez), abs(ew))
        num[k] = angle * angle
        s = 0.0
        for i, m in enumerate((0, 6, 11)):  # P00, P11, P22 of the upper triangle
            s += max(4.0 * out.P[k, m] - out.att_std[k, i] ** 2, 0.0)
        den[k] = s
