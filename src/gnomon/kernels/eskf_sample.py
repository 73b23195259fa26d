"""One sample of the error-state AHRS filter (``eskf-r3``, ``eskf-r6``) for its per-sample
``update``: a row of ``gnomon.kernels.eskf.run_batch``, the same ``step_row``, called from
Python once per sample through ``gnomon.kernels.entry.entry_point``.

``eskf_sample(dt, gyro, acc, mag, state, c, q_out) -> flags`` takes its coefficients as a
record (``sample_record``: a one-element structured array unboxes in ~60 ns where the
``Coefficients`` named tuple costs about a microsecond) that also holds the step's work
arrays, so that a sample allocates nothing. Frames and units: as ``gnomon.kernels.eskf``,
the magnetometer in the unit the record's ``tesla_per_unit`` names (µT for ``update``).
Importing this module imports numba; ``import gnomon`` does not.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from gnomon.kernels.entry import BAD_GYRO, record
from gnomon.kernels.eskf import (
    _JIT,
    MODE_PREDICT_ONLY,
    MODE_R3,
    MODE_R6,
    SCRATCH,
    Coefficients,
    Work,
    step_row,
)
from gnomon.kernels.linalg import finite_or_nan

__all__ = ["SKIPPED", "AT_LIMIT", "SAMPLE_Y", "SAMPLE_WORK", "sample_record", "eskf_sample"]

#: flag bits of ``eskf_sample``: not both sensors had a usable sample (the ``update_skipped``
#: signal); a component of the bias at ``bias_limit`` (``bias_at_limit``)
SKIPPED, AT_LIMIT = 1, 2
#: floats of ``work`` in ``sample_record``: ``Work``'s arrays (A, T, U, y, D1, Rd, dx at
#: these offsets), then the one-sensor correction's ``SCRATCH``
_W = (0, 9, 18, 27, 33, 51, 57, 63)
SAMPLE_Y = _W[3]
SAMPLE_WORK = _W[-1] + SCRATCH


def sample_record(c: Coefficients, b0_mag_T: float, tesla_per_unit: float) -> np.ndarray:
    """The coefficients of ``eskf_sample``: a one-element record of ``c``'s fields
    (``gnomon.kernels.entry.record``), the magnetometer's scale (``m · tesla_per_unit /
    b0_mag``, as ``run`` normalises it) and ``work``, the scratch of one step (so that a
    sample allocates nothing; the measurement ``y`` of the last sample at ``SAMPLE_Y``)."""
    base = record(c)
    out = np.zeros(1, np.dtype(base.dtype.descr + [
        ("tesla_per_unit", "f8"), ("b0_mag", "f8"), ("work", "f8", (SAMPLE_WORK,))]))
    for name in base.dtype.names:
        out[name] = base[name]
    out["tesla_per_unit"], out["b0_mag"] = tesla_per_unit, b0_mag_T
    return out


@njit(**_JIT)
def _sample_step(dt, gx, gy, gz, ax, ay, az, mx, my, mz, state, r, q_out):
    """``step_row`` on ``state[0]`` with the record ``r`` (``sample_record``) and its work
    arrays, one copy per mode as in ``run_batch``; the estimate into ``q_out``; the flags."""
    s = state[0]
    v = r.work
    w = Work(v[_W[0]:_W[1]].reshape(3, 3), v[_W[1]:_W[2]].reshape(3, 3),
             v[_W[2]:_W[3]].reshape(3, 3), v[_W[3]:_W[4]], v[_W[4]:_W[5]].reshape(6, 3),
             v[_W[5]:_W[6]], v[_W[6]:_W[7]])
    scratch = v[_W[7]:]
    since = s.since_acc_s
    if r.mode == MODE_R6:
        rows, since = step_row(s, r, MODE_R6, dt, gx, gy, gz, ax, ay, az, mx, my, mz, w,
                               since, scratch)
        full = 6
    elif r.mode == MODE_R3:
        rows, since = step_row(s, r, MODE_R3, dt, gx, gy, gz, ax, ay, az, mx, my, mz, w,
                               since, scratch)
        full = 3
    else:
        rows, since = step_row(s, r, MODE_PREDICT_ONLY, dt, gx, gy, gz, ax, ay, az, mx, my,
                               mz, w, since, scratch)
        full = 0
    s.since_acc_s = since
    q, b, lim = s.q, s.bias, r.bias_limit
    q_out[0], q_out[1], q_out[2], q_out[3] = q[0], q[1], q[2], q[3]
    f = SKIPPED if rows < full else 0
    if abs(b[0]) >= lim or abs(b[1]) >= lim or abs(b[2]) >= lim:
        f |= AT_LIMIT
    return f


@njit(cache=True, error_model="numpy")  # not fastmath: it would fold the finiteness tests away
def eskf_sample(dt, gyro, acc, mag, state, c, q_out):
    """One sample as a row of ``run_batch`` (the same ``step_row``): ``dt`` (s), ``gyro``
    (3,) rad/s, ``acc`` (3,) m/s², ``mag`` (3,) in the unit of ``c``'s ``tesla_per_unit``,
    body frame (an ``acc``/``mag`` with a non-finite component is no new sample of that
    sensor); ``state`` (a ``STATE`` array of one element) updated in place; ``c`` the
    ``sample_record``; ``q_out`` (4,) the estimate. Returns the flags (``SKIPPED``,
    ``AT_LIMIT``), or ``BAD_GYRO`` alone for a non-finite gyro sample (nothing done). The
    filter's ``update`` calls it through ``gnomon.kernels.entry.entry_point``; no memory
    is allocated."""
    gx, gy, gz = gyro[0], gyro[1], gyro[2]
    if not (math.isfinite(gx) and math.isfinite(gy) and math.isfinite(gz)):
        return BAD_GYRO
    ax, ay, az = finite_or_nan(acc[0], acc[1], acc[2])
    mx, my, mz = finite_or_nan(mag[0], mag[1], mag[2])
    r = c[0]
    k, b0 = r.tesla_per_unit, r.b0_mag  # (m · k) / b0: the arithmetic of ``run``'s numpy
    return _sample_step(dt, gx, gy, gz, ax, ay, az, mx * k / b0, my * k / b0, mz * k / b0,
                        state, r, q_out)
