"""Compiled loop of the 3D tilt complementary filter of seed 004 (``tilt-cf``).

Readable twin: ``gnomon.estimators.complementary.TiltComplementaryFilter.update``
(through ``tilt_step_reference``), tested sample by sample. The filter's shape
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

from gnomon.kernels.linalg import cross
from gnomon.kernels.quat import exp_mul, up_row

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


@njit(inline="always", error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def tilt_cf_step(state, c, dt, gx, gy, gz, ax, ay, az):
    """One sample in place on ``state`` (one-element ``STATE`` array); returns
    ``acc_rejected``."""
    s = state[0]
    predict(s, dt, gx, gy, gz)
    correct_accel(s, c, dt, ax, ay, az)
    return s.acc_rejected


@njit(cache=True, error_model="numpy")
def tilt_cf_run(t, gyro, accel, state, c, t_prev, q_out, b_out, rej_out):
    """Whole recording: ``t`` (N,) s, ``gyro`` (N, 3) rad/s, ``accel`` (N, 3) m/s² from
    ``state`` (updated in place); ``q_out`` (N, 4), ``b_out`` (N, 3), ``rej_out`` (N,).

    A fresh filter (``t_prev`` NaN) outputs its initial state at sample 0; a continued
    one (``t_prev`` the time of its last sample) steps from its state to ``t[0]`` first.
    """
    s = state[0]
    start = 0
    if math.isnan(t_prev):
        q_out[0, :] = s.q
        b_out[0, :] = s.bias
        rej_out[0] = not (accel[0, 0] ** 2 + accel[0, 1] ** 2 + accel[0, 2] ** 2 > 0.0)
        s.acc_rejected = rej_out[0]
        start = 1
    for k in range(start, t.shape[0]):
        dt = t[k] - (t[k - 1] if k > 0 else t_prev)
        predict(s, dt, gyro[k, 0], gyro[k, 1], gyro[k, 2])
        correct_accel(s, c, dt, accel[k, 0], accel[k, 1], accel[k, 2])
        rej_out[k] = s.acc_rejected
        q_out[k, :] = s.q
        b_out[k, :] = s.bias
