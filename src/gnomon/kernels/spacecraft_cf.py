"""Compiled loops of the spacecraft complementary filters of seed 000.

Twins of the readable ``update`` methods of ``gnomon.estimators.ecf_spacecraft``
(explicit filter on vector pairs, ``ecf_*``) and ``gnomon.estimators.qcf`` (filter driven
by a measured quaternion, ``qcf_*``), and of the sequential Gauss-Newton solver
``gnomon.estimators.qcf.gauss_newton_sequence_py`` (``gn_sequence``). The tests compare
them sample by sample. The shared phases (``predict``, ``unit_pair``, ``vector_error``,
``pi_correct``) are also used by the spacecraft MEKF (``gnomon.kernels.mekf``).

Shape (see ``gnomon.kernels``): ``STATE`` is the record both filters keep, ``q`` (4,)
``q_ob`` (orbital from body) and ``bias`` (3,) the gyro-bias estimate (rad/s);
``ECFCoefficients`` / ``QCFCoefficients`` are built once from the filters' ``Params`` by
``ecf_coefficients`` / ``qcf_coefficients``. One sample (``ecf_step`` / ``qcf_step``) is
the gyro prediction, then the vector pairs (magnetometer, sun or its substitute) or the
measured quaternion, then the PI correction. The paper's ``d = K_P e + K_I ∫e`` is the
same filter with ``bias = −K_I ∫e`` (Mahony's form keeps the estimate continuous when
the integral gain switches between the two-pair and one-pair values).

The per-sample phases are ``inline="always"``: compiled as separate functions, the call
per sample with its array views cost about 40 % of the ECF loop (measured: 4.1 against
7.0 M samples/s before inlining; inlined, as fast as the one-function loop it replaces).

Flags per sample (int8 row of 4, or the bits ``1 << column`` the steps return): ``MAG``
mag pair unusable, ``SECOND`` sun/second pair (or measured quaternion) unusable, ``GAP``
time gap (gyro-only propagation), ``COAST`` no correction at all this sample.

The filters' own paths take raw samples: ``*_stream`` (a buffer of N rows) and
``*_sample`` (one row, called per sample through ``gnomon.kernels.entry.entry_point``) run
the same inline row (``ecf_row``, ``qcf_row``): the sun substitute (``second_pair``) from
the filter's tail of past samples (``RING``, ``delay_samples`` records written in turn;
the write position and the gyro's and the orbital frame's accumulated rotations are in
``STATE``), then the step. ``ecf_batch`` / ``qcf_batch`` run the step on pairs already
substituted (``gnomon.estimators.ecf_spacecraft.vector_pairs``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from gnomon.kernels.entry import BAD_GYRO
from gnomon.kernels.linalg import cross
from gnomon.kernels.quat import (
    mul,
    rotate_by,
    rotate_inv,
    rotate_quadratic,
    rotate_quadratic_jac,
)

MAG, SECOND, GAP, COAST = 0, 1, 2, 3  # flag columns
#: bit of a sample kernel's flags: the second pair was the delayed substitute
SUBSTITUTED = 32
#: ``sun_substitute`` as the coefficients' ``substitute``
SUBSTITUTES = {"none": 0, "delayed": 1, "delayed-gyro": 2}
NONE, DELAYED, DELAYED_GYRO = 0, 1, 2

#: The tail's fields of a filter's state: ``n_seen`` samples joined the tail so far (the
#: next one is written at ``n_seen % delay_samples``); ``q_b0b``, ``q_o0o`` (4,) the body's
#: rotation since the first sample by the raw gyro and the orbital frame's by ``w_io_o``
#: (``delayed-gyro`` only; the identity otherwise).
TAIL_STATE = [("n_seen", np.int64), ("q_b0b", np.float64, 4), ("q_o0o", np.float64, 4)]
#: The complementary filters' state: ``q`` (4,) q_ob, ``bias`` (3,) gyro bias (rad/s), the
#: tail's fields.
STATE = np.dtype([("q", np.float64, 4), ("bias", np.float64, 3)] + TAIL_STATE)
#: One past sample of the tail (``delay_samples`` of them): its magnetic pair ``mag_b``
#: (b), ``mag_o`` (o), the accumulated rotations ``q_b0b``, ``q_o0o`` at it and the
#: estimate ``q`` after it (the MEKF's swing since then).
RING = np.dtype([("mag_b", np.float64, 3), ("mag_o", np.float64, 3), ("q_b0b", np.float64, 4),
                 ("q_o0o", np.float64, 4), ("q", np.float64, 4)])


class ECFCoefficients(NamedTuple):
    """Gains of the explicit filter: ``kp_rad_s``/``ki_rad_s2`` with both pairs usable,
    ``*_single_*`` with one; pair weights; ``max_dt_s`` (longer intervals are gaps);
    ``min_sin``: pairs whose directions are closer than ``asin(min_sin)`` count as one;
    the sun's ``substitute`` (``SUBSTITUTES``) ``delay_samples`` ago."""

    kp_rad_s: float
    ki_rad_s2: float
    kp_single_rad_s: float
    ki_single_rad_s2: float
    k_mag: float
    k_sun: float
    max_dt_s: float
    min_sin: float
    substitute: int
    delay_samples: int


class QCFCoefficients(NamedTuple):
    """Gains of the quaternion-driven filter: ``kp_rad_s``/``ki_rad_s2`` on the measured
    quaternion, ``*_single_*`` of the magnetometer-only fallback; ``max_dt_s``; the tail
    kept for the substitute of the sun in ``q_mes`` (``substitute``, ``delay_samples``)."""

    kp_rad_s: float
    ki_rad_s2: float
    kp_single_rad_s: float
    ki_single_rad_s2: float
    max_dt_s: float
    substitute: int
    delay_samples: int


class GaussNewtonCoefficients(NamedTuple):
    """Seed 000's q_mes solver: pair weights, steps per sample, the quality threshold."""

    w_mag: float
    w_sun: float
    iterations: int
    min_quality: float


def ecf_coefficients(p) -> ECFCoefficients:
    """From a ``SpacecraftCFParams`` (read by attribute; the kernel imports no estimator)."""
    return ECFCoefficients(float(p.kp_rad_s), float(p.ki_rad_s2), float(p.kp_single_rad_s),
                           float(p.ki_single_rad_s2), float(p.k_mag), float(p.k_sun),
                           float(p.max_dt_s), float(np.sin(np.radians(p.min_angle_deg))),
                           SUBSTITUTES[p.sun_substitute], int(p.delay_samples))


def qcf_coefficients(p) -> QCFCoefficients:
    """From a ``QuaternionCFParams``."""
    return QCFCoefficients(float(p.kp_rad_s), float(p.ki_rad_s2), float(p.kp_single_rad_s),
                           float(p.ki_single_rad_s2), float(p.max_dt_s),
                           SUBSTITUTES[p.sun_substitute], int(p.delay_samples))


def gauss_newton_coefficients(p) -> GaussNewtonCoefficients:
    """From a ``QuaternionCFParams`` (``k_mag``, ``k_sun``, ``gn_iterations``, ``min_quality``)."""
    return GaussNewtonCoefficients(float(p.k_mag), float(p.k_sun), int(p.gn_iterations),
                                   float(p.min_quality))


def new_state(q0, dtype=STATE) -> np.ndarray:
    """A ``dtype`` (``STATE``) array of one element at attitude ``q0`` (normalised), zero
    bias, an empty tail."""
    state = np.zeros(1, dtype)
    q0 = np.asarray(q0, float)
    state["q"][0] = q0 / np.linalg.norm(q0)
    state["q_b0b"][0, 0] = 1.0
    state["q_o0o"][0, 0] = 1.0
    return state


def new_ring(delay_samples: int) -> np.ndarray:
    """An empty tail: ``delay_samples`` ``RING`` records."""
    return np.zeros(int(delay_samples), RING)


# ---------------------------------------------------------------- phases shared by the filters
@njit(inline="always", error_model="numpy")
def turn(q, rx, ry, rz):
    """``q <- normalise(q ⊗ exp([rx, ry, rz]))`` in place (rotation vector, rad, body);
    a non-finite or absurd rotation leaves ``q`` unchanged."""
    if not (rx * rx + ry * ry + rz * rz < 1e12):
        return
    rotate_by(q, rx, ry, rz)


@njit(inline="always", error_model="numpy")
def predict(q, bias, dt, g, w_io_o):
    """Gyro phase: ``q <- q ⊗ exp((ω_ib − R_bo ω_io − b̂) dt)``; False (no motion) if the
    gyro sample ``g`` (3,) rad/s is unusable. ``w_io_o`` (3,) rad/s, orbital frame."""
    gx, gy, gz = g[0], g[1], g[2]
    if not (abs(gx) < 1e6 and abs(gy) < 1e6 and abs(gz) < 1e6):
        return False
    tx, ty, tz = rotate_inv(q[0], q[1], q[2], q[3], w_io_o[0], w_io_o[1], w_io_o[2])
    turn(q, (gx - tx - bias[0]) * dt, (gy - ty - bias[1]) * dt, (gz - tz - bias[2]) * dt)
    return True


@njit(inline="always", error_model="numpy")
def unit_pair(vb, vo):
    """``(ok, ub, uo)``: a body/reference pair (3,) (any units) as unit tuples; ok False
    (and zeros) if either vector is zero or non-finite."""
    nb = math.sqrt(vb[0] * vb[0] + vb[1] * vb[1] + vb[2] * vb[2])
    no = math.sqrt(vo[0] * vo[0] + vo[1] * vo[1] + vo[2] * vo[2])
    if not (nb > 0.0 and no > 0.0 and nb < 1e300 and no < 1e300):
        return False, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    return True, (vb[0] / nb, vb[1] / nb, vb[2] / nb), (vo[0] / no, vo[1] / no, vo[2] / no)


@njit(inline="always", error_model="numpy")
def vector_error(q, ub, uo, weight, e):
    """``e + weight · ub × (R_bo uo)`` (Mahony's explicit correction, body frame), tuples."""
    t = rotate_inv(q[0], q[1], q[2], q[3], uo[0], uo[1], uo[2])
    c = cross(ub[0], ub[1], ub[2], t[0], t[1], t[2])
    return e[0] + weight * c[0], e[1] + weight * c[1], e[2] + weight * c[2]


@njit(inline="always", error_model="numpy")
def pi_correct(q, bias, kp, ki, e, dt):
    """Correction phase: ``b̂ <- b̂ − K_I e dt``, ``q <- q ⊗ exp(K_P e dt)``."""
    for j in range(3):
        bias[j] -= ki * e[j] * dt
    turn(q, kp * e[0] * dt, kp * e[1] * dt, kp * e[2] * dt)


@njit(inline="always", error_model="numpy")
def start_sample(q, bias, dt, g, w_io_o, max_dt):
    """What every seed-000 filter does first: propagate with the gyro over ``dt``. Returns
    ``(go, flags)``: ``go`` when the sample goes on to the measurements (a real interval,
    not a gap), ``flags`` the bits so far (a gap or an unusable gyro)."""
    if not (dt > 0.0 and dt < 1e300):
        return False, 0
    f = 0
    if not predict(q, bias, dt, g, w_io_o):
        f = 1 << COAST
    if dt > max_dt:
        return False, (1 << GAP) | (1 << COAST)
    return True, f


@njit(inline="always")
def write_flags(f, flags):
    """The bits ``f`` of a step as the int8 columns ``flags`` (4,)."""
    for j in range(4):
        flags[j] = (f >> j) & 1


# ---------------------------------------------------------------- the tail: the sun's substitute
@njit(inline="always", error_model="numpy")
def _usable(x):
    """A rate component, 0 where unusable (non-finite or absurd, |x| >= 1e6 rad/s)."""
    return x if abs(x) < 1e6 else 0.0


@njit(inline="always", error_model="numpy")
def _carried(q_now, q_then, v):
    """``R(q_now⁻¹ ⊗ q_then) v`` (tuple): a vector of the frame at ``q_then`` in the frame
    at ``q_now``, both accumulated from the first sample (the arithmetic of
    ``gnomon.rotation.quat_rotate`` of ``quat_mul(quat_conj(q_now), q_then)``)."""
    w, x, y, z = mul(q_now[0], -q_now[1], -q_now[2], -q_now[3],
                     q_then[0], q_then[1], q_then[2], q_then[3])
    tx, ty, tz = cross(x, y, z, v[0], v[1], v[2])
    tx, ty, tz = 2.0 * tx, 2.0 * ty, 2.0 * tz
    cx, cy, cz = cross(x, y, z, tx, ty, tz)
    return (v[0] + w * tx) + cx, (v[1] + w * ty) + cy, (v[2] + w * tz) + cz


@njit(inline="always", error_model="numpy")
def _accumulate_turns(mode, s, dt, g, w_io_o):
    """``delayed-gyro``: the body's and the orbital frame's rotations since the first sample
    turned by this sample's raw gyro and ``w_io_o`` over ``dt`` (unusable values count
    as 0; the first sample turns nothing)."""
    if mode == DELAYED_GYRO and s.n_seen > 0:
        h = dt if math.isfinite(dt) else 0.0
        turn(s.q_b0b, _usable(g[0]) * h, _usable(g[1]) * h, _usable(g[2]) * h)
        turn(s.q_o0o, _usable(w_io_o[0]) * h, _usable(w_io_o[1]) * h, _usable(w_io_o[2]) * h)


@njit(inline="always", error_model="numpy")
def _remember(mode, s, ring, slot, mag_b, mag_o):
    """This sample joins the tail at ``slot``: its magnetic pair (the accumulated rotations
    for ``delayed-gyro``; nothing without a substitute: the tail is not read then; ``q`` is
    written after the step)."""
    if mode != NONE:
        r = ring[slot]
        for j in range(3):
            r.mag_b[j] = mag_b[j]
            r.mag_o[j] = mag_o[j]
        if mode == DELAYED_GYRO:
            for j in range(4):
                r.q_b0b[j] = s.q_b0b[j]
                r.q_o0o[j] = s.q_o0o[j]
    s.n_seen += 1


@njit(inline="always", error_model="numpy")
def tail_push(c, mode, s, ring, dt, g, w_io_o, mag_b, mag_o):
    """This sample joins the tail (no second pair is made of it: the quaternion-driven
    filter, whose ``q_mes`` comes from its caller); ``mode`` is ``c.substitute`` (a
    constant in the buffer loops: one copy of the loop per substitute, its branches
    folded). Returns its slot."""
    slot = s.n_seen % c.delay_samples
    _accumulate_turns(mode, s, dt, g, w_io_o)
    _remember(mode, s, ring, slot, mag_b, mag_o)
    return slot


@njit(inline="always", error_model="numpy")
def second_pair(c, mode, s, ring, dt, g, w_io_o, mag_b, mag_o, sun_b, sun_o, sun_valid):
    """The second vector pair of a sample, as ``vector_pairs`` makes it: the sun
    (``sun_b`` in b, ``sun_o`` in o) where valid and finite; else the substitute, the
    magnetic pair ``delay_samples`` samples ago (``delayed``; carried to now by the
    accumulated gyro and orbital rotations for ``delayed-gyro``, a non-finite one kept
    as it is) once there is one; else none. The sample then joins the tail. ``mode`` is
    ``c.substitute`` (a constant in the buffer loops, see ``tail_push``). Returns
    ``(sec_b, sec_o, sec_valid, substituted, slot)`` (tuples, bools, the sample's slot: it
    still holds the estimate ``q`` after the sample ``delay_samples`` ago, if any)."""
    m = c.delay_samples
    k = s.n_seen
    slot = k % m
    _accumulate_turns(mode, s, dt, g, w_io_o)
    zero = (0.0, 0.0, 0.0)
    sb, so, valid, sub = zero, zero, False, False
    if (sun_valid and math.isfinite(sun_b[0]) and math.isfinite(sun_b[1])
            and math.isfinite(sun_b[2]) and math.isfinite(sun_o[0])
            and math.isfinite(sun_o[1]) and math.isfinite(sun_o[2])):
        sb, so, valid = (sun_b[0], sun_b[1], sun_b[2]), (sun_o[0], sun_o[1], sun_o[2]), True
    elif mode != NONE and k >= m:
        r = ring[slot]
        sb = (r.mag_b[0], r.mag_b[1], r.mag_b[2])
        so = (r.mag_o[0], r.mag_o[1], r.mag_o[2])
        valid, sub = True, True
        if mode == DELAYED_GYRO and (
                math.isfinite(sb[0]) and math.isfinite(sb[1]) and math.isfinite(sb[2])
                and math.isfinite(so[0]) and math.isfinite(so[1]) and math.isfinite(so[2])):
            sb = _carried(s.q_b0b, r.q_b0b, sb)
            so = _carried(s.q_o0o, r.q_o0o, so)
    _remember(mode, s, ring, slot, mag_b, mag_o)
    return sb, so, valid, sub, slot


@njit(cache=True, error_model="numpy")
def pairs_stream(c, state, ring, dt, gyro, w_io_o, mag_b, mag_o, sun_b, sun_o, sun_valid,
                 sec_b, sec_o, sec_valid, substituted):
    """``second_pair`` over N rows continuing ``state``'s tail (``ring``), both updated:
    the second pairs ``sec_b``, ``sec_o`` (N, 3), ``sec_valid``, ``substituted`` (N,) of
    the rows (the pairs ``q_mes`` is measured from)."""
    s = state[0]
    for i in range(dt.shape[0]):
        sb, so, ok, sub, _ = second_pair(c, c.substitute, s, ring, dt[i], gyro[i], w_io_o[i],
                                         mag_b[i], mag_o[i], sun_b[i], sun_o[i], sun_valid[i])
        for j in range(3):
            sec_b[i, j] = sb[j]
            sec_o[i, j] = so[j]
        sec_valid[i] = ok
        substituted[i] = sub


@njit(inline="always", error_model="numpy")
def finite3(v):
    """Whether the three components of ``v`` are finite."""
    return math.isfinite(v[0]) and math.isfinite(v[1]) and math.isfinite(v[2])


# ---------------------------------------------------------------- explicit filter (ECF)
@njit(inline="always", error_model="numpy")
def ecf_pairs(c, mag_b, mag_o, sec_b, sec_o, sec_valid):
    """Vector-pair phase: ``(ok_m, ubm, uom, ok_s, ubs, uos)``; the second pair is unusable
    when invalid, zero, or closer to the magnetic pair than ``asin(c.min_sin)``."""
    ok_m, ubm, uom = unit_pair(mag_b, mag_o)
    ok_s, ubs, uos = False, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    if sec_valid:
        ok_s, ubs, uos = unit_pair(sec_b, sec_o)
    if ok_m and ok_s:
        cx, cy, cz = cross(uom[0], uom[1], uom[2], uos[0], uos[1], uos[2])
        if math.sqrt(cx * cx + cy * cy + cz * cz) < c.min_sin:
            ok_s = False
    return ok_m, ubm, uom, ok_s, ubs, uos


@njit(inline="always", error_model="numpy")
def ecf_step(c, q, bias, dt, g, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid):
    """One sample of the explicit filter (Mahony 2008) on ``q``, ``bias`` in place; returns
    its flag bits."""
    go, f = start_sample(q, bias, dt, g, w_io_o, c.max_dt_s)
    if not go:
        return f
    ok_m, ubm, uom, ok_s, ubs, uos = ecf_pairs(c, mag_b, mag_o, sec_b, sec_o, sec_valid)
    f |= (0 if ok_m else 1 << MAG) | (0 if ok_s else 1 << SECOND)
    if not (ok_m or ok_s):
        return f | (1 << COAST)
    e = (0.0, 0.0, 0.0)
    if ok_m:
        e = vector_error(q, ubm, uom, c.k_mag, e)
    if ok_s:
        e = vector_error(q, ubs, uos, c.k_sun, e)
    if ok_m and ok_s:
        pi_correct(q, bias, c.kp_rad_s, c.ki_rad_s2, e, dt)
    else:
        pi_correct(q, bias, c.kp_single_rad_s, c.ki_single_rad_s2, e, dt)
    return f


@njit(inline="always", error_model="numpy")
def ecf_row(c, mode, s, q, bias, ring, dt, g, w_io_o, mag_b, mag_o, sun_b, sun_o, sun_valid):
    """One raw sample of the explicit filter on the record ``s`` (``q``, ``bias`` its
    fields) and its tail ``ring``: ``second_pair`` (``mode`` the substitute), then
    ``ecf_step``. Returns ``(flags, substituted)``: the flag bits and whether the second
    pair was the substitute (apart: packed into one int, the loop ran 25 % slower)."""
    sb, so, ok, sub, _ = second_pair(c, mode, s, ring, dt, g, w_io_o, mag_b, mag_o, sun_b,
                                     sun_o, sun_valid)
    return ecf_step(c, q, bias, dt, g, w_io_o, mag_b, mag_o, sb, so, ok), sub


@njit(inline="always", error_model="numpy")
def _ecf_loop(c, mode, state, ring, dt, gyro, w_io_o, mag_b, mag_o, sun_b, sun_o, sun_valid,
              q_out, bias_out, flags, substituted):
    s = state[0]
    q, bias = s.q, s.bias
    for i in range(dt.shape[0]):
        f, sub = ecf_row(c, mode, s, q, bias, ring, dt[i], gyro[i], w_io_o[i], mag_b[i],
                         mag_o[i], sun_b[i], sun_o[i], sun_valid[i])
        write_flags(f, flags[i])
        substituted[i] = sub
        for j in range(4):
            q_out[i, j] = q[j]
        for j in range(3):
            bias_out[i, j] = bias[j]


@njit(cache=True, error_model="numpy")
def ecf_stream(c, state, ring, dt, gyro, w_io_o, mag_b, mag_o, sun_b, sun_o, sun_valid, q_out,
               bias_out, flags, substituted):
    """The explicit filter over N raw samples (``ecf_row`` per row), continuing ``state``
    and its tail ``ring`` in place: inputs as ``ecf_batch`` but the sun pair ``sun_b``,
    ``sun_o`` (N, 3) with ``sun_valid`` (N,) in place of the second pair; outputs as
    ``ecf_batch`` and ``substituted`` (N,) bool. One copy of the loop per substitute (a
    constant in each: measured 0.60 against 0.84 ms for 6000 rows with the branches of all
    three in one loop)."""
    if c.substitute == DELAYED_GYRO:
        _ecf_loop(c, DELAYED_GYRO, state, ring, dt, gyro, w_io_o, mag_b, mag_o, sun_b, sun_o,
                  sun_valid, q_out, bias_out, flags, substituted)
    elif c.substitute == DELAYED:
        _ecf_loop(c, DELAYED, state, ring, dt, gyro, w_io_o, mag_b, mag_o, sun_b, sun_o,
                  sun_valid, q_out, bias_out, flags, substituted)
    else:
        _ecf_loop(c, NONE, state, ring, dt, gyro, w_io_o, mag_b, mag_o, sun_b, sun_o,
                  sun_valid, q_out, bias_out, flags, substituted)


@njit(cache=True, error_model="numpy")
def ecf_sample(dt, gyro, w_io_o, mag_b, mag_o, sun_b, sun_o, state, ring, c, q_out):
    """One raw sample as a row of ``ecf_stream`` (the same arithmetic): ``dt`` (s), the
    vectors (3,) (a sun pair with a non-finite component: no sun); ``state``, ``ring``
    updated in place; ``c`` the coefficients as a record (``gnomon.kernels.entry.record``);
    ``q_out`` (4,) the estimate. Returns the flag bits, or ``BAD_GYRO`` alone for a
    non-finite gyro sample (nothing done)."""
    if not finite3(gyro):
        return BAD_GYRO
    s = state[0]
    c = c[0]
    f, sub = ecf_row(c, c.substitute, s, s.q, s.bias, ring, dt, gyro, w_io_o, mag_b, mag_o,
                     sun_b, sun_o, True)
    for j in range(4):
        q_out[j] = s.q[j]
    return f | (SUBSTITUTED if sub else 0)


@njit(cache=True, error_model="numpy")
def ecf_batch(c, state, dt, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid, q_out,
              bias_out, flags):
    """Explicit complementary filter on two vector pairs over N samples (seed 000 baseline).

    ``c`` ``ECFCoefficients``; ``state`` a ``STATE`` array of one element, continued in
    place. Inputs (N rows): ``dt`` s (``dt[0] = 0`` keeps the initial state), ``gyro``
    ω_ib_b rad/s, ``w_io_o`` (N, 3) rate of the orbital frame in o (rad/s), ``mag_b``,
    ``mag_o`` the magnetic pair (body, orbital; any units), ``sec_b``, ``sec_o`` the
    second pair (sun or its substitute), ``sec_valid`` (N,) bool. Outputs: ``q_out``
    (N, 4) q_ob, ``bias_out`` (N, 3) rad/s, ``flags`` (N, 4) int8.
    """
    s = state[0]
    q, bias = s.q, s.bias
    for i in range(dt.shape[0]):
        write_flags(ecf_step(c, q, bias, dt[i], gyro[i], w_io_o[i], mag_b[i], mag_o[i],
                             sec_b[i], sec_o[i], sec_valid[i]), flags[i])
        for j in range(4):
            q_out[i, j] = q[j]
        for j in range(3):
            bias_out[i, j] = bias[j]


# ---------------------------------------------------------------- quaternion-driven filter
@njit(inline="always", error_model="numpy")
def measured_error(q, q_mes, mes_valid):
    """Measured-quaternion phase: ``(ok, vec(e))``, ``e = conj(q̂) ⊗ q_mes/|q_mes|`` with
    the sign that makes ``e_w >= 0``; unusable if invalid or ``|q_mes|`` outside (0.5, 2)."""
    mw, mx, my, mz = q_mes[0], q_mes[1], q_mes[2], q_mes[3]
    nm = math.sqrt(mw * mw + mx * mx + my * my + mz * mz)
    if not (mes_valid and nm > 0.5 and nm < 2.0):
        return False, (0.0, 0.0, 0.0)
    ew, ex, ey, ez = mul(q[0], -q[1], -q[2], -q[3], mw / nm, mx / nm, my / nm, mz / nm)
    if ew < 0.0:
        return True, (-ex, -ey, -ez)
    return True, (ex, ey, ez)


@njit(inline="always", error_model="numpy")
def qcf_step(c, q, bias, dt, g, w_io_o, q_mes, mes_valid, mag_b, mag_o):
    """One sample of the quaternion-driven filter on ``q``, ``bias`` in place: PI on the
    measured quaternion, else on the magnetometer pair alone (if its gains are not both
    zero), else coast. Returns its flag bits."""
    go, f = start_sample(q, bias, dt, g, w_io_o, c.max_dt_s)
    if not go:
        return f
    ok_q, e = measured_error(q, q_mes, mes_valid)
    ok_m, ubm, uom = unit_pair(mag_b, mag_o)
    f |= (0 if ok_m else 1 << MAG) | (0 if ok_q else 1 << SECOND)
    if ok_q:
        pi_correct(q, bias, c.kp_rad_s, c.ki_rad_s2, e, dt)
    elif ok_m and (c.kp_single_rad_s > 0.0 or c.ki_single_rad_s2 > 0.0):
        e = vector_error(q, ubm, uom, 1.0, (0.0, 0.0, 0.0))
        pi_correct(q, bias, c.kp_single_rad_s, c.ki_single_rad_s2, e, dt)
    else:
        f |= 1 << COAST
    return f


@njit(inline="always", error_model="numpy")
def qcf_row(c, mode, s, q, bias, ring, dt, g, w_io_o, q_mes, mes_valid, mag_b, mag_o):
    """One raw sample of the quaternion-driven filter on the record ``s`` (``q``, ``bias``
    its fields): the magnetic pair joins the tail ``ring`` (a later ``q_mes``
    measurement's substitute; ``mode`` the substitute), then ``qcf_step``. Returns the
    flag bits."""
    tail_push(c, mode, s, ring, dt, g, w_io_o, mag_b, mag_o)
    return qcf_step(c, q, bias, dt, g, w_io_o, q_mes, mes_valid, mag_b, mag_o)


@njit(inline="always", error_model="numpy")
def _qcf_loop(c, mode, state, ring, dt, gyro, w_io_o, q_mes, mes_valid, mag_b, mag_o, q_out,
              bias_out, flags):
    s = state[0]
    q, bias = s.q, s.bias
    for i in range(dt.shape[0]):
        write_flags(qcf_row(c, mode, s, q, bias, ring, dt[i], gyro[i], w_io_o[i], q_mes[i],
                            mes_valid[i], mag_b[i], mag_o[i]), flags[i])
        for j in range(4):
            q_out[i, j] = q[j]
        for j in range(3):
            bias_out[i, j] = bias[j]


@njit(cache=True, error_model="numpy")
def qcf_stream(c, state, ring, dt, gyro, w_io_o, q_mes, mes_valid, mag_b, mag_o, q_out,
               bias_out, flags):
    """The quaternion-driven filter over N raw samples (``qcf_row`` per row), continuing
    ``state`` and its tail ``ring`` in place; arguments as ``qcf_batch``. One copy of the
    loop per substitute (as ``ecf_stream``)."""
    if c.substitute == DELAYED_GYRO:
        _qcf_loop(c, DELAYED_GYRO, state, ring, dt, gyro, w_io_o, q_mes, mes_valid, mag_b,
                  mag_o, q_out, bias_out, flags)
    elif c.substitute == DELAYED:
        _qcf_loop(c, DELAYED, state, ring, dt, gyro, w_io_o, q_mes, mes_valid, mag_b, mag_o,
                  q_out, bias_out, flags)
    else:
        _qcf_loop(c, NONE, state, ring, dt, gyro, w_io_o, q_mes, mes_valid, mag_b, mag_o,
                  q_out, bias_out, flags)


@njit(cache=True, error_model="numpy")
def qcf_sample(dt, gyro, w_io_o, q_mes, mag_b, mag_o, state, ring, c, q_out):
    """One raw sample as a row of ``qcf_stream``: ``q_mes`` (4,) the measured q_ob (a
    non-finite one: no measurement), the rest as ``ecf_sample``. Returns the flag bits, or
    ``BAD_GYRO`` alone for a non-finite gyro sample (nothing done)."""
    if not finite3(gyro):
        return BAD_GYRO
    s = state[0]
    c = c[0]
    f = qcf_row(c, c.substitute, s, s.q, s.bias, ring, dt, gyro, w_io_o, q_mes, True, mag_b,
                mag_o)
    for j in range(4):
        q_out[j] = s.q[j]
    return f


@njit(cache=True, error_model="numpy")
def qcf_batch(c, state, dt, gyro, w_io_o, q_mes, mes_valid, mag_b, mag_o, q_out, bias_out,
              flags):
    """Complementary filter driven by a measured quaternion over N samples (seed 000).

    ``c`` ``QCFCoefficients``, ``state`` as in ``ecf_batch``. ``q_mes`` (N, 4) q_ob measured
    (any Wahba solver), ``mes_valid`` (N,) bool; ``mag_b``, ``mag_o`` the magnetic pair of
    the fallback. Correction ``e = conj(q̂) ⊗ q_mes`` (``e_w >= 0``), PI on its vector part:
    ``q̂ <- q̂ ⊗ exp(K_P vec(e) dt)``, ``b̂ <- b̂ − K_I vec(e) dt``. Flags as ``ecf_batch``
    (column ``SECOND``: q_mes unusable).
    """
    s = state[0]
    q, bias = s.q, s.bias
    for i in range(dt.shape[0]):
        write_flags(qcf_step(c, q, bias, dt[i], gyro[i], w_io_o[i], q_mes[i], mes_valid[i],
                             mag_b[i], mag_o[i]), flags[i])
        for j in range(4):
            q_out[i, j] = q[j]
        for j in range(3):
            bias_out[i, j] = bias[j]


# ---------------------------------------------------------------- Gauss-Newton q_mes
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


@njit(inline="always", error_model="numpy")
def _pair_quality(a1, a2, ur1, ub1, ur2, ub2):
    """``s2/s1`` of ``B = a1 r1 b1ᵀ + a2 r2 b2ᵀ`` (unit vectors, weights summing to 1) from
    its Frobenius norm and ``s1 s2``."""
    dr = ur1[0] * ur2[0] + ur1[1] * ur2[1] + ur1[2] * ur2[2]
    db = ub1[0] * ub2[0] + ub1[1] * ub2[1] + ub1[2] * ub2[2]
    fro2 = a1 * a1 + a2 * a2 + 2.0 * a1 * a2 * dr * db
    p = a1 * a2 * math.sqrt(max(0.0, 1.0 - dr * dr)) * math.sqrt(max(0.0, 1.0 - db * db))
    disc = math.sqrt(max(0.0, fro2 * fro2 - 4.0 * p * p))
    s1sq = 0.5 * (fro2 + disc)
    s2sq = 0.5 * (fro2 - disc)
    return math.sqrt(s2sq / s1sq) if s1sq > 0.0 else 0.0


@njit(inline="always", error_model="numpy")
def _accumulate(q, wt, ub, ur, A, Nm, g):
    """Add one pair's normal equations ``wt AᵀA``, ``wt Aᵀ (r − R(q) b)`` to ``Nm``, ``g``."""
    rotate_quadratic_jac(q[0], q[1], q[2], q[3], ub[0], ub[1], ub[2], A)
    px, py, pz = rotate_quadratic(q[0], q[1], q[2], q[3], ub[0], ub[1], ub[2])
    ex, ey, ez = ur[0] - px, ur[1] - py, ur[2] - pz
    for a in range(4):
        g[a] += wt * (A[0, a] * ex + A[1, a] * ey + A[2, a] * ez)
        for k in range(4):
            Nm[a, k] += wt * (A[0, a] * A[0, k] + A[1, a] * A[1, k] + A[2, a] * A[2, k])


@njit(inline="always", error_model="numpy")
def _gauss_newton_steps(q, a1, ub1, ur1, a2, ub2, ur2, iterations, A, Nm, g, dq, L, y4):
    """``iterations`` steps ``q <- normalise(q + (AᵀWA)⁻¹ AᵀW e)`` in place; False if q ran
    away (then reset to the identity). A singular system ends the iteration early."""
    for _ in range(iterations):
        for a in range(4):
            g[a] = 0.0
            for k in range(4):
                Nm[a, k] = 0.0
        _accumulate(q, a1, ub1, ur1, A, Nm, g)
        _accumulate(q, a2, ub2, ur2, A, Nm, g)
        if not _solve4(Nm, g, dq, L, y4):
            break
        s = 0.0
        for a in range(4):
            q[a] += dq[a]
            s += q[a] * q[a]
        s = math.sqrt(s)
        if not (s > 1e-12 and s < 1e300):
            q[0], q[1], q[2], q[3] = 1.0, 0.0, 0.0, 0.0
            return False
        for a in range(4):
            q[a] /= s
    return True


@njit(cache=True, error_model="numpy")
def gn_sequence(c, r1, b1, r2, b2, valid, q0, q_out, ok_out):
    """Seed 000's Gauss-Newton ("recursive least squares") q_ob measurement per sample.

    ``c`` ``GaussNewtonCoefficients``. Pairs (N, 3): reference r1/r2 (orbital), body b1/b2
    (any units, normalised here); ``valid`` (N,) says whether pair 2 is present. Each
    sample starts from the previous sample's solution (``q0`` (4,) at the first, updated
    in place) and takes ``c.iterations`` Gauss-Newton steps. ``ok_out`` (N,) is False where
    the problem is degenerate (a pair unusable or the quality ``s2/s1`` below
    ``c.min_quality``); there ``q_out`` repeats the last good solution.
    """
    A = np.empty((3, 4))
    Nm = np.empty((4, 4))
    g = np.empty(4)
    dq = np.empty(4)
    L = np.zeros((4, 4))
    y4 = np.empty(4)
    q = q0
    ww = c.w_mag + c.w_sun
    a1, a2 = c.w_mag / ww, c.w_sun / ww
    for i in range(r1.shape[0]):
        ok, ub1, ur1 = unit_pair(b1[i], r1[i])
        ok2, ub2, ur2 = False, ub1, ur1
        if ok and valid[i]:
            ok2, ub2, ur2 = unit_pair(b2[i], r2[i])
        ok = ok2 and not (_pair_quality(a1, a2, ur1, ub1, ur2, ub2) < c.min_quality)
        if ok:
            ok = _gauss_newton_steps(q, a1, ub1, ur1, a2, ub2, ur2, c.iterations, A, Nm, g,
                                     dq, L, y4)
        ok_out[i] = ok
        for a in range(4):
            q_out[i, a] = q[a]


@njit(cache=True, error_model="numpy")
def integrate_rates_batch(dt, w, out):
    """out[k] = out[k-1] ⊗ exp(w[k] dt[k]), out[0] = identity (rates in the moving axes)."""
    q = np.array([1.0, 0.0, 0.0, 0.0])
    for i in range(dt.shape[0]):
        if i > 0:
            turn(q, w[i, 0] * dt[i], w[i, 1] * dt[i], w[i, 2] * dt[i])
        for j in range(4):
            out[i, j] = q[j]
