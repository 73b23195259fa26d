"""Compiled loop of the 3D tilt complementary filter of seed 004 (``tilt-cf``).

Readable twin: ``gnomon.estimators.complementary.TiltComplementaryFilter.update_reference``
(through ``tilt_step_reference``), tested sample by sample. The batch loop
(``tilt_cf_batch``) and the per-sample kernel of the filter's ``update``
(``tilt_cf_sample``, the coefficients as a record) run the same row (``_row``; a fresh
filter's first row is ``_start_row``). The filter's shape
follows ``gnomon.kernels`` (Coefficients NamedTuple, State record, phases):

* ``Coefficients``: ``time_constant_s`` (T), ``bias_gain_1_s2`` (r₂),
  ``accel_rejection_rel``, ``gravity_m_s2``;
* ``STATE``: ``q`` (4,) ``q_nb`` (ENU from body), ``bias`` (3,) rad/s,
  ``since_acc_s`` (time since the accelerometer's previous sample: each correction is
  integrated over it, so an accelerometer slower than the gyro keeps its gain),
  ``acc_rejected`` (the last sample's accelerometer was not used);
* phases: ``predict`` (gyro), ``correct_accel`` (the fraction ``dt/(T + dt)`` of the
  rotation taking the measured up direction onto the predicted one, and the bias
  integral).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from gnomon.kernels.entry import BAD_GYRO
from gnomon.kernels.linalg import cross, finite_or_nan
from gnomon.kernels.quat import exp_mul, up_row

#: flag bit of the batch rows and the sample kernel: the accelerometer was not used
ACC_REJECTED = 1

STATE = np.dtype([("q", "f8", (4,)), ("bias", "f8", (3,)), ("since_acc_s", "f8"),
                  ("acc_rejected", "?")], align=True)


class Coefficients(NamedTuple):
    """The filter's tuning in kernel form (see ``TiltCFParams``)."""

    time_constant_s: float
    bias_gain_1_s2: float
    accel_rejection_rel: float
    gravity_m_s2: float


def coefficients(params) -> Coefficients:
    """``Coefficients`` of a ``TiltCFParams``."""
    return Coefficients(float(params.time_constant_s), float(params.bias_gain_1_s2),
                        float(params.accel_rejection_rel), float(params.gravity_m_s2))


def new_state(q0, bias0=(0.0, 0.0, 0.0)) -> np.ndarray:
    """A state (one-element ``STATE`` array) at attitude ``q0`` (4,) and bias (3,) rad/s."""
    s = np.zeros(1, STATE)
    s["q"][0] = q0
    s["bias"][0] = bias0
    return s


@njit(inline="always", error_model="numpy")
def predict(s, dt, gx, gy, gz):
    """Gyro phase: ``q ← normalise(q ⊗ exp((ω − b̂) dt))``."""
    q = s.q
    q[0], q[1], q[2], q[3], _ = exp_mul(q[0], q[1], q[2], q[3], (gx - s.bias[0]) * dt,
                                        (gy - s.bias[1]) * dt, (gz - s.bias[2]) * dt, True, True)


@njit(cache=True, error_model="numpy")
def correct_accel(s, c, dt, ax, ay, az):
    """Accelerometer phase. Rotation vector ``e`` (body) taking the measured up direction
    ``a/|a|`` onto the predicted ``R_nbᵀ e_z``; ``q ← q ⊗ exp(h/(T + h) e)``,
    ``b̂ ← b̂ − r₂ h e`` with ``h`` the time since the accelerometer's previous sample
    (``dt`` when it runs with the gyro). Skipped (``acc_rejected``) for a zero or NaN
    vector (no new sample) or when ``||a| − g| > accel_rejection_rel · g``."""
    s.acc_rejected = True
    s.since_acc_s += dt
    if not ax == ax:  # no new sample in this row
        return
    dt = s.since_acc_s
    s.since_acc_s = 0.0
    nf = math.sqrt(ax * ax + ay * ay + az * az)
    g = c.gravity_m_s2
    if not nf > 0.0 or (c.accel_rejection_rel > 0.0
                        and abs(nf - g) > c.accel_rejection_rel * g):
        return
    s.acc_rejected = False
    mx, my, mz = ax / nf, ay / nf, az / nf
    q = s.q
    w, x, y, z = q[0], q[1], q[2], q[3]
    ux, uy, uz = up_row(w, x, y, z)  # up in body
    cx, cy, cz = cross(mx, my, mz, ux, uy, uz)
    sn = math.sqrt(cx * cx + cy * cy + cz * cz)
    if sn > 0.0:
        k = math.atan2(sn, mx * ux + my * uy + mz * uz) / sn
        ex, ey, ez = k * cx, k * cy, k * cz
        r2 = c.bias_gain_1_s2
        if r2 > 0.0:
            s.bias[0] -= r2 * dt * ex
            s.bias[1] -= r2 * dt * ey
            s.bias[2] -= r2 * dt * ez
        f = dt / (c.time_constant_s + dt)
        q[0], q[1], q[2], q[3], _ = exp_mul(w, x, y, z, f * ex, f * ey, f * ez, True, True)


@njit(inline="always", error_model="numpy")
def _row(s, c, dt, gx, gy, gz, ax, ay, az):
    """One row of the batch loop (and the sample kernel): ``predict`` then
    ``correct_accel`` (a NaN accelerometer row: no new sample). Returns the row's flags
    (``ACC_REJECTED``)."""
    predict(s, dt, gx, gy, gz)
    correct_accel(s, c, dt, ax, ay, az)
    return ACC_REJECTED if s.acc_rejected else 0


@njit(inline="always", error_model="numpy")
def _start_row(s, ax, ay, az):
    """The start row of a fresh filter (its attitude just set from the accelerometer): the
    state is its estimate, nothing is integrated; flagged rejected (``ACC_REJECTED``) for a
    zero or NaN accelerometer vector."""
    s.acc_rejected = not (ax * ax + ay * ay + az * az > 0.0)
    return ACC_REJECTED if s.acc_rejected else 0


@njit(cache=True, error_model="numpy")
def tilt_cf_batch(dt, gyro, accel, state, c, start, q_out, b_out, rej_out):
    """N samples from ``state`` (one-element ``STATE`` array, updated in place): ``dt``
    (N,) s (each since the previous sample), ``gyro`` (N, 3) rad/s, ``accel`` (N, 3) m/s²
    (NaN rows: no new sample); ``q_out`` (N, 4), ``b_out`` (N, 3), ``rej_out`` (N,) bool.

    ``start``: row 0 is the start row of a fresh filter (``_start_row``: it outputs the
    initial state, its ``dt`` and gyro unused); else every row steps."""
    s = state[0]
    for k in range(dt.shape[0]):
        if start and k == 0:
            _start_row(s, accel[0, 0], accel[0, 1], accel[0, 2])
        else:
            _row(s, c, dt[k], gyro[k, 0], gyro[k, 1], gyro[k, 2], accel[k, 0], accel[k, 1],
                 accel[k, 2])
        rej_out[k] = s.acc_rejected
        q_out[k, 0], q_out[k, 1], q_out[k, 2], q_out[k, 3] = s.q[0], s.q[1], s.q[2], s.q[3]
        b_out[k, 0], b_out[k, 1], b_out[k, 2] = s.bias[0], s.bias[1], s.bias[2]


@njit(cache=True, error_model="numpy")
def tilt_cf_sample(dt, gyro, acc, state, c, start, q_out):
    """One sample as a row of ``tilt_cf_batch`` (the same arithmetic): ``dt`` (s),
    ``gyro``, ``acc`` (3,) body frame (an ``acc`` with a non-finite component is no new
    sample); ``state`` updated in place; ``c`` the coefficients as a record
    (``gnomon.kernels.entry.record``); ``start``: the start row (``_start_row``);
    ``q_out`` (4,) the estimate ``q_nb``. Returns the row's flags, or ``BAD_GYRO`` alone
    for a non-finite gyro sample (nothing done). The filter's ``update`` calls it through
    ``gnomon.kernels.entry.entry_point``; no memory is allocated."""
    gx, gy, gz = gyro[0], gyro[1], gyro[2]
    if not (math.isfinite(gx) and math.isfinite(gy) and math.isfinite(gz)):
        return BAD_GYRO
    ax, ay, az = finite_or_nan(acc[0], acc[1], acc[2])
    s = state[0]
    if start:
        f = _start_row(s, ax, ay, az)
    else:
        f = _row(s, c[0], dt, gx, gy, gz, ax, ay, az)
    q_out[0], q_out[1], q_out[2], q_out[3] = s.q[0], s.q[1], s.q[2], s.q[3]
    return f
