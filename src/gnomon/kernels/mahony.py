"""Compiled loops of the 9-axis explicit complementary filter.

Twin of ``gnomon.estimators.mahony.Mahony.update`` (tested sample by sample).
The shape of ``gnomon.kernels``: ``Coefficients`` (the gains), ``STATE`` (``q``,
``bias``), and one step written once, in ``_core``, on scalars, from its phases
(gyro prediction, ``_accel_error``, ``_mag_error``, the PI correction); the
single-stream loop and the batch-over-runs loop both call it. The batch loop runs the step for all
runs in a branch-light form that LLVM vectorises (the rotation exponential by
its Taylor series only) and then redoes, with the exact forms, the few runs
whose step needed them (a rotation of more than 0.05 rad) — so every run
equals its single-stream result.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from gnomon.kernels.entry import BAD_GYRO
from gnomon.kernels.linalg import cross as _cross
from gnomon.kernels.linalg import finite_or_nan
from gnomon.kernels.quat import dcm as _dcm
from gnomon.kernels.quat import exp_mul as _exp_mul

# Floating-point freedoms: fused multiply-add, reciprocals and re-association (results
# move by rounding only, ~1e-15; the tests hold the kernels to 1e-12 of the reference).
_FAST = {"contract", "arcp", "reassoc", "nsz"}

#: The single-stream state: ``q`` (4,) ``q_nb`` (ENU from body), ``bias`` (3,) rad/s, and
#: the time (s) since the accelerometer and the magnetometer were last used (each sensor
#: at its own rate: a correction is integrated over the interval since its last sample).
STATE = np.dtype([("q", "f8", (4,)), ("bias", "f8", (3,)), ("since_acc_s", "f8"),
                  ("since_mag_s", "f8")])


class Coefficients(NamedTuple):
    """The filter's gains in kernel form (see ``MahonyParams``)."""

    kp_acc_rad_s: float
    kp_mag_rad_s: float
    ki_rad_s2: float
    heading_only: bool
    max_dt_s: float


def coefficients(params) -> Coefficients:
    """``Coefficients`` of a ``MahonyParams``."""
    return Coefficients(float(params.kp_acc_rad_s), float(params.kp_mag_rad_s),
                        float(params.ki_rad_s2), bool(params.mag_heading_only),
                        float(params.max_dt_s))


def new_state(q0, bias0=(0.0, 0.0, 0.0)) -> np.ndarray:
    """A state (one-element ``STATE`` array) at ``q0`` (4,) and bias (3,) rad/s."""
    s = np.zeros(1, STATE)
    s["q"][0] = q0
    s["bias"][0] = bias0
    return s


@njit(inline="always", error_model="numpy", fastmath=_FAST)
def _accel_error(ux, uy, uz, ax, ay, az):
    """Accelerometer phase: ``e_acc = a/|a| × up_b`` (body; ``up_b`` the third row of
    ``R_nb``). Returns ``(ex, ey, ez, skipped)``; a zero vector gives a zero error."""
    na = math.sqrt(ax * ax + ay * ay + az * az)
    ia = 1.0 / na if na > 0.0 else 0.0
    ax *= ia
    ay *= ia
    az *= ia
    ex, ey, ez = _cross(ax, ay, az, ux, uy, uz)
    return ex, ey, ez, na == 0.0


@njit(inline="always", error_model="numpy", fastmath=_FAST)
def _mag_error(c00, c01, c02, c10, c11, c12, ux, uy, uz, mx, my, mz, heading_only):
    """Magnetometer phase: ``e_mag = m/|m| × R_nbᵀ ref`` with ``ref = [0, |h_xy|, h_z]``,
    ``h = R_nb m`` (rows ``c0*``, ``c1*`` and up ``u`` of ``R_nb``). Returns
    ``(fx, fy, fz, skipped)``.

    ``m × R_nbᵀ ref`` equals ``R_nbᵀ (h × ref)``, ``h × ref = [hz (hy - rn), -hx hz, hx rn]``
    (``rn = |h_xy|``): its vertical part ``hx·rn`` is the heading error, all that
    ``heading_only`` keeps (along up)."""
    nm = math.sqrt(mx * mx + my * my + mz * mz)
    im = 1.0 / nm if nm > 0.0 else 0.0
    mx *= im
    my *= im
    mz *= im
    hx = c00 * mx + c01 * my + c02 * mz
    hy = c10 * mx + c11 * my + c12 * mz
    rn = math.sqrt(hx * hx + hy * hy)
    if heading_only:
        d = hx * rn
        return d * ux, d * uy, d * uz, nm == 0.0
    hz = ux * mx + uy * my + uz * mz
    n0 = hz * (hy - rn)
    n1 = -hx * hz
    n2 = hx * rn
    return (c00 * n0 + c10 * n1 + ux * n2, c01 * n0 + c11 * n1 + uy * n2,
            c02 * n0 + c12 * n1 + uz * n2, nm == 0.0)


@njit(inline="always", error_model="numpy", fastmath=_FAST)
def _core(w, x, y, z, b0, b1, b2, dt, gx, gy, gz, ax, ay, az, mx, my, mz, c, trig, ra, rm):
    """One corrected step (0 < dt <= max_dt) on scalars, coefficients ``c``.

    Gyro prediction, the two vector errors, then the PI correction
    ``ḃ = -k_I (e_acc + e_mag)``, ``q ← q ⊗ exp((k_a e_acc + k_m e_mag) dt)``, each error
    weighted by ``ra``, ``rm``: the interval since that sensor's previous sample over
    ``dt`` (1 when every sensor is sampled with the gyro).
    Returns ``(w, x, y, z, b0, b1, b2, flags, redo)``: flags bit 1 accelerometer skipped,
    bit 2 magnetometer skipped; ``redo``: with ``trig`` False, the step needed the exact
    forms (a rotation of >= 0.05 rad, see ``gnomon.kernels.quat.exp_mul``).
    """
    w, x, y, z, redo1 = _exp_mul(w, x, y, z, (gx - b0) * dt, (gy - b1) * dt, (gz - b2) * dt,
                                trig, False)
    c00, c01, c02, c10, c11, c12, ux, uy, uz = _dcm(w, x, y, z)
    ex, ey, ez, skip_a = _accel_error(ux, uy, uz, ax, ay, az)
    fx, fy, fz, skip_m = _mag_error(c00, c01, c02, c10, c11, c12, ux, uy, uz, mx, my, mz,
                                    c.heading_only)
    ex, ey, ez = ex * ra, ey * ra, ez * ra
    fx, fy, fz = fx * rm, fy * rm, fz * rm
    ki = c.ki_rad_s2
    b0 -= ki * (ex + fx) * dt
    b1 -= ki * (ey + fy) * dt
    b2 -= ki * (ez + fz) * dt
    ka, km = c.kp_acc_rad_s, c.kp_mag_rad_s
    w, x, y, z, redo2 = _exp_mul(w, x, y, z, (ka * ex + km * fx) * dt, (ka * ey + km * fy) * dt,
                                (ka * ez + km * fz) * dt, trig, True)
    flags = (1 if skip_a else 0) | (2 if skip_m else 0)
    return w, x, y, z, b0, b1, b2, flags, redo1 or redo2


@njit(cache=True, error_model="numpy", fastmath=_FAST)
def mahony_step(q, b, c, dt, gx, gy, gz, ax, ay, az, mx, my, mz):
    """One sample in place on ``q`` (4,) ``q_nb`` and ``b`` (3,) bias, coefficients ``c``.

    Returns flags as bits: 1 accelerometer skipped, 2 magnetometer skipped, 4 gap.
    """
    if dt <= 0.0:
        return 0
    if dt > c.max_dt_s:  # gap: gyro propagation only
        q[0], q[1], q[2], q[3], _ = _exp_mul(q[0], q[1], q[2], q[3], (gx - b[0]) * dt,
                                             (gy - b[1]) * dt, (gz - b[2]) * dt, True, True)
        return 4
    q[0], q[1], q[2], q[3], b[0], b[1], b[2], flags, _ = _core(
        q[0], q[1], q[2], q[3], b[0], b[1], b[2], dt, gx, gy, gz, ax, ay, az, mx, my, mz,
        c, True, 1.0, 1.0)
    return flags


@njit(inline="always", error_model="numpy", fastmath=_FAST)
def _row(w, x, y, z, b0, b1, b2, sa, sm, h, gx, gy, gz, ax, ay, az, mx, my, mz, c,
         multi_rate):
    """One row of the batch loop on the state in registers (``q``, ``bias``, the times
    since the accelerometer and the magnetometer were used): returns them updated and the
    row's flags. ``multi_rate``: a NaN ``acc``/``mag`` row is no new sample of that sensor
    (a new one is integrated over the time since its previous sample); a constant in each
    compiled copy of the callers."""
    f = 0
    if h > c.max_dt_s:  # gap: gyro propagation only
        w, x, y, z, _ = _exp_mul(w, x, y, z, (gx - b0) * h, (gy - b1) * h, (gz - b2) * h,
                                 True, True)
        sa, sm = 0.0, 0.0
        f = 4
    elif h > 0.0:
        ra, rm = 1.0, 1.0
        if multi_rate:
            max_dt = c.max_dt_s
            sa, sm = sa + h, sm + h
            new_a = ax == ax
            new_m = mx == mx
            ra = (1.0 if sa == h else min(sa, max_dt) / h) if new_a else 0.0
            rm = (1.0 if sm == h else min(sm, max_dt) / h) if new_m else 0.0
            sa = 0.0 if new_a else sa
            sm = 0.0 if new_m else sm
            if not new_a:  # no sample: a zero vector (a zero error, flagged skipped)
                ax, ay, az = 0.0, 0.0, 0.0
            if not new_m:
                mx, my, mz = 0.0, 0.0, 0.0
        w, x, y, z, b0, b1, b2, f, _ = _core(w, x, y, z, b0, b1, b2, h, gx, gy, gz, ax, ay, az,
                                             mx, my, mz, c, True, ra, rm)
    return w, x, y, z, b0, b1, b2, sa, sm, f


@njit(inline="always", error_model="numpy", fastmath=_FAST)
def _batch_loop(dt, gyro, acc, mag, s, c, q_out, b_out, flags, multi_rate):
    """The loop of ``mahony_batch``: ``_row`` per sample, the state in registers;
    ``multi_rate`` is a constant in each of its two copies (without it, the single-rate
    loop carries no bookkeeping of sample times)."""
    w, x, y, z = s.q[0], s.q[1], s.q[2], s.q[3]
    b0, b1, b2 = s.bias[0], s.bias[1], s.bias[2]
    sa, sm = s.since_acc_s, s.since_mag_s
    for i in range(dt.shape[0]):
        w, x, y, z, b0, b1, b2, sa, sm, f = _row(
            w, x, y, z, b0, b1, b2, sa, sm, dt[i], gyro[i, 0], gyro[i, 1], gyro[i, 2],
            acc[i, 0], acc[i, 1], acc[i, 2], mag[i, 0], mag[i, 1], mag[i, 2], c, multi_rate)
        flags[i] = f
        q_out[i, 0] = w
        q_out[i, 1] = x
        q_out[i, 2] = y
        q_out[i, 3] = z
        b_out[i, 0] = b0
        b_out[i, 1] = b1
        b_out[i, 2] = b2
    s.q[0], s.q[1], s.q[2], s.q[3] = w, x, y, z
    s.since_acc_s, s.since_mag_s = sa, sm
    s.bias[0], s.bias[1], s.bias[2] = b0, b1, b2


@njit(cache=True, error_model="numpy", fastmath=_FAST)
def mahony_batch(dt, gyro, acc, mag, state, c, q_out, b_out, flags, multi_rate):
    """Run N samples: ``dt`` (N,) s (dt[0] = 0 keeps the initial state), sensors (N, 3).

    ``state`` (one-element ``STATE`` array) is updated in place; outputs ``q_out`` (N, 4),
    ``b_out`` (N, 3) and ``flags`` (N,) uint8 with the bits of ``mahony_step``. The state
    stays in registers over the loop (same arithmetic as ``mahony_step``). ``multi_rate``:
    the accelerometer and magnetometer rows may be NaN (no new sample; each correction
    then covers the time since that sensor's previous sample); False: every row holds a
    sample of each (the single-rate form, a loop without that bookkeeping).
    """
    s = state[0]
    if multi_rate:
        _batch_loop(dt, gyro, acc, mag, s, c, q_out, b_out, flags, True)
    else:
        _batch_loop(dt, gyro, acc, mag, s, c, q_out, b_out, flags, False)


@njit(cache=True, error_model="numpy", fastmath=_FAST)
def mahony_sample(dt, gyro, acc, mag, state, c, q_out):
    """One sample as a row of ``mahony_batch`` in its multi-rate form (the same
    arithmetic): ``dt`` (s), ``gyro``, ``acc``, ``mag`` (3,) body frame (an ``acc``/``mag``
    with a NaN is no new sample of that sensor); ``state`` updated in place; ``c`` the
    coefficients as a record (``gnomon.kernels.entry.record``); ``q_out`` (4,) the
    estimate. Returns the flags of ``mahony_step``, or ``BAD_GYRO`` alone for a non-finite
    gyro sample (nothing done). The filter's ``update`` calls it through
    ``gnomon.kernels.entry.entry_point``; no memory is allocated."""
    gx, gy, gz = gyro[0], gyro[1], gyro[2]
    if not (math.isfinite(gx) and math.isfinite(gy) and math.isfinite(gz)):
        return BAD_GYRO
    ax, ay, az = finite_or_nan(acc[0], acc[1], acc[2])
    mx, my, mz = finite_or_nan(mag[0], mag[1], mag[2])
    s = state[0]
    w, x, y, z, b0, b1, b2, sa, sm, f = _row(
        s.q[0], s.q[1], s.q[2], s.q[3], s.bias[0], s.bias[1], s.bias[2], s.since_acc_s,
        s.since_mag_s, dt, gx, gy, gz, ax, ay, az, mx, my, mz, c[0], True)
    s.q[0], s.q[1], s.q[2], s.q[3] = w, x, y, z
    s.bias[0], s.bias[1], s.bias[2] = b0, b1, b2
    s.since_acc_s, s.since_mag_s = sa, sm
    q_out[0], q_out[1], q_out[2], q_out[3] = w, x, y, z
    return f


@njit(inline="always", error_model="numpy", fastmath=_FAST)
def _run_step(one, bias, c, h, gyro, acc, mag, i, r):
    """``mahony_step`` on ``one``, ``bias`` with sample ``i`` of run ``r`` (inputs (N, 3, R))."""
    mahony_step(one, bias, c, h, gyro[i, 0, r], gyro[i, 1, r], gyro[i, 2, r], acc[i, 0, r],
                acc[i, 1, r], acc[i, 2, r], mag[i, 0, r], mag[i, 1, r], mag[i, 2, r])


@njit(cache=True, error_model="numpy", fastmath=_FAST)
def mahony_batch_runs(dt, gyro, acc, mag, q, b, c, q_out):
    """R independent filters over N samples, run-minor layout for SIMD over runs.

    ``dt`` (N,) s shared by the runs; ``gyro``, ``acc``, ``mag`` (N, 3, R); state ``q`` (4, R),
    ``b`` (3, R) updated in place (run-minor arrays rather than R ``STATE`` records: the
    layout that lets LLVM vectorise over runs); coefficients ``c`` shared; ``q_out``
    (N, 4, R). Every run follows the arithmetic
    of ``mahony_step`` (flags are not recorded here). The vector loop turns ``q`` in place
    and writes the new bias aside; a step to redo starts again from ``q_out[i - 1]``:
    no copy of the state before each step, and no scan for redos when it counted none.
    """
    n = dt.shape[0]
    r_count = q.shape[1]
    max_dt = c.max_dt_s
    q_first = q.copy()  # the state before the first step (later: q_out[i - 1])
    b_next = np.empty((3, r_count))
    redo = np.zeros(r_count, np.bool_)
    one = np.empty(4)
    bias = np.empty(3)
    for i in range(n):
        h = dt[i]
        if h > 0.0 and h <= max_dt:
            n_redo = 0
            for r in range(r_count):  # vectorised: no trigonometry, no branches
                (q[0, r], q[1, r], q[2, r], q[3, r], b_next[0, r], b_next[1, r],
                 b_next[2, r], _, red) = _core(
                    q[0, r], q[1, r], q[2, r], q[3, r], b[0, r], b[1, r], b[2, r], h,
                    gyro[i, 0, r], gyro[i, 1, r], gyro[i, 2, r], acc[i, 0, r],
                    acc[i, 1, r], acc[i, 2, r], mag[i, 0, r], mag[i, 1, r], mag[i, 2, r],
                    c, False, 1.0, 1.0)
                redo[r] = red
                n_redo += red
            for r in range(r_count if n_redo else 0):  # the rare exact steps, again
                if redo[r]:
                    one[:] = q_first[:, r] if i == 0 else q_out[i - 1, :, r]
                    bias[:] = b[:, r]
                    _run_step(one, bias, c, h, gyro, acc, mag, i, r)
                    q[:, r] = one
                    b_next[:, r] = bias
            b[:, :] = b_next
        elif h > max_dt:
            for r in range(r_count):
                one[:] = q[:, r]
                bias[:] = b[:, r]
                _run_step(one, bias, c, h, gyro, acc, mag, i, r)
                q[:, r] = one
        q_out[i, :, :] = q
