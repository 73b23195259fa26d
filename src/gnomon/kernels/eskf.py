"""Compiled kernel of the error-state AHRS Kalman filter (seed 002, Bilous & Nesterenko).

Readable twin: ``gnomon.estimators.eskf.Eskf.update_reference`` (numpy matrices, the
same phases on the same ``STATE`` record); ``tests/test_eskf.py`` compares the two step by
step.

Shape (see ``gnomon.kernels``):

* ``Coefficients`` (``coefficients(params)``): the squared noise densities, gravity,
  the gates, the time constants of the inclination estimate and of the accelerometer
  low-pass, and the ``mode`` (``MODE_R6``, ``MODE_R3`` or ``MODE_PREDICT_ONLY``);
* ``STATE`` (one-element structured array, ``new_state``): ``q`` (4,) = ``q_nb`` (ENU
  from body, ``[w, x, y, z]``), ``bias`` (3,) rad/s, ``P`` (6, 6) covariance of the error
  ``[δe; δb]``, the running inclination estimate ``dip_s`` (mean of ``a·m / (g|m|)``,
  ``= -Z``) with its weight ``dip_count``, the navigation-frame accelerometer
  low-pass ``acc_lp`` (3,) m/s² with ``acc_lp_started``, and ``acc_dev2``, the mean of
  ``(| |a| - g |)²`` of the bias gate;
* ``step`` = ``predict`` (gyro) → ``reference_and_gates`` (accelerometer and
  magnetometer: variance gates, inclination) → ``bias_gate`` → ``accel_lowpass`` →
  ``measure_r6`` or ``measure_r3`` (``y``, ``D1``, ``R``) → ``correct`` (gain, Joseph
  update, injection with the bias within ``±bias_limit``; ``hold_bias`` undoes its bias
  part while the gate is shut) → ``follow_correction`` (the low-pass turns with the
  correction);
* ``run_batch(inputs, state, coefficients, outputs)`` loops ``step`` over ``Inputs``
  and writes ``Outputs``; ``gnomon.kernels.eskf_sample`` runs one row (the same
  ``step_row``) for the filter's per-sample ``update``.

The structure of the problem is used throughout: the transition matrix
``Φ = [A  cI; 0  I]`` (``A = I - [ω̂×]dt``, ``c = -dt/2``) is never formed; the
measurement matrix is ``D = [D1  0]`` (measurements do not see the bias), so only its
3 attitude columns are stored and multiplied; the innovation covariance is
factorised ``S = L·diag(d)·Lᵀ`` (no square roots) and only upper triangles of
symmetric matrices are computed.

``gain`` and ``joseph`` (below, plain Python) are the arithmetic of the correction.
They are not compiled here: ``tools/codegen_eskf.py`` traces them into the
straight-line functions ``eskf_unrolled.update_r3`` / ``update_r6`` that ``correct``
calls (every intermediate a local scalar), and
``gnomon.estimators.eskf.count_update_operations`` runs the same source on counting
numbers for the operation counts of the paper's comparison.

Why generated rather than a plain loop kernel (issue #16). Measured on the shared
2-core machine: a batch loop of prediction, measurement and correction over the same
200 000 samples, the corrections swapped in one process, CPU-time medians of 15 and 21
interleaved repeats (two runs), as a fraction of the generated kernel's speed:

* ``gain``/``joseph`` as loops compiled with ``r`` a compile-time constant:
  0.63-0.71 (r = 3), 0.65-0.67 (r = 6);
* the same with the scratch matrices on the stack (an alloca: LLVM knows they alias
  nothing and can keep them in registers): 0.96-1.00 (r = 3), 0.84-0.85 (r = 6);
* and with loops reordered until LLVM unrolled them all at its default threshold:
  1.05 (r = 3), 0.85-0.89 (r = 6). Only a raised global LLVM unroll threshold (a
  process-wide option, not usable in a library) brought r = 6 to par.

r = 6 stays outside the 10 % the issue allows (and the 5 % the filters may lose), so
the generated code stays; its generator lives outside the package.

This kernel against the former one (28 positional arguments, one function), same
harness, defaults, 21 repeats: r = 3 0.98-1.04, r = 6 1.01-1.03, prediction only
1.15-1.22; the whole ``EskfR3().run`` / ``EskfR6().run`` on 10⁶ samples: 1.05 / 1.01.

Frames and units: gyro rad/s and accelerometer m/s² in the body frame, magnetometer
normalised by the reference field magnitude (dimensionless), ``dt`` s.
Importing this module imports numba; ``import gnomon`` does not.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from gnomon.kernels.eskf_unrolled import update_r3, update_r6
from gnomon.kernels.linalg import clip, skew_into
from gnomon.kernels.quat import dcm, mul, normalised, rotate, rotate_by, rotate_inv

__all__ = [
    "MODE_PREDICT_ONLY", "MODE_R3", "MODE_R6", "MAX_ABS_DIP", "STATE", "Coefficients",
    "Inputs", "Outputs", "Work", "coefficients", "new_state", "new_outputs", "workspace",
    "predict", "reference_and_gates", "accel_lowpass", "measure_r6", "measure_r3",
    "correct", "inject", "gate_factor", "follow_correction", "bias_gate", "bias_block",
    "hold_bias", "step", "step_row", "run_batch", "gain", "joseph",
]

MODE_PREDICT_ONLY = 0
MODE_R3 = 3
MODE_R6 = 6
#: |sin I| at most for the reference field (inclination below 87.4 deg): nearer the pole
#: (or with |a| > g making a·m/(g|m|) exceed 1) H = sqrt(1 - s²) would vanish or be NaN
MAX_ABS_DIP = 0.999
#: floats of scratch for the one-sensor correction's work matrices (``correct_rows``)
SCRATCH = 198

# Each phase is a compiled function of its own; only the few-line ones (``gate_factor``,
# ``bias_block``, ``inject``, ``correct``, ``step``) are inlined by numba. With every phase
# inlined, and the loop compiled once per mode, numba took 48 s to compile ``run_batch``
# for r = 3 (now 17 s); the loop runs about 1.25x slower than inlined (2-core machine).
_JIT = {"cache": True, "fastmath": True, "error_model": "numpy"}


# ---------------------------------------------------------------- named records
class Coefficients(NamedTuple):
    """Values derived once from the parameters (``coefficients``), read by name."""

    var_gyro: float    #: σ_g², (rad/s)²/Hz: gyro white-noise density squared
    var_bias: float    #: σ_b², (rad/s)²/s: bias random walk squared
    var_acc: float     #: σ_a², (m/s²)²: accelerometer noise per sample
    var_mag: float     #: σ_m² (of |B0|)²: magnetometer noise per sample
    gravity: float     #: g, m/s²
    dip_tau: float     #: s, time constant of the inclination estimate (0: fixed)
    acc_lp_tau: float  #: s, navigation-frame accelerometer low-pass (0: off)
    gate_acc: float    #: m/s², | |a| - g | doubling the accelerometer variance (0: off)
    gate_mag: float    #: 1, field deviation doubling the magnetometer variance (0: off)
    acc_lp_follow: float  #: 1, fraction of a correction the accelerometer low-pass follows
    bias_gate2: float  #: (m/s²)², mean (| |a| - g |)² above which the bias is held (0: off)
    bias_gate_rate: float  #: 1/s, 1 / the time constant of that mean
    bias_limit: float  #: rad/s, bound on each component of the bias estimate
    mode: int          #: MODE_R6, MODE_R3 or MODE_PREDICT_ONLY
    # reciprocals, so that the step multiplies where it would divide
    inv_gravity: float    #: 1/g
    inv_gate_acc: float   #: 1/gate_acc (0: gating off)
    inv_gate_mag: float   #: 1/gate_mag (0: gating off)
    dip_rate: float       #: 1/dip_tau (1/s)
    acc_lp_rate: float    #: 1/acc_lp_tau (1/s)


def coefficients(params, predict_only: bool = False) -> Coefficients:
    """``Coefficients`` of an ``EskfParams`` (read by attribute name; ``inclination_known``
    fixes the inclination: ``dip_tau = 0``). ``predict_only``: gyro integration only."""
    p = params
    mode = MODE_PREDICT_ONLY if predict_only else (MODE_R6 if p.measurement == "r6" else MODE_R3)
    return Coefficients(
        var_gyro=p.gyro_noise**2, var_bias=p.bias_rw**2, var_acc=p.accel_noise**2,
        var_mag=p.mag_noise**2, gravity=float(p.gravity),
        dip_tau=0.0 if p.inclination_known else float(p.dip_tau),
        acc_lp_tau=float(p.accel_lowpass_tau), gate_acc=float(p.accel_gate),
        gate_mag=float(p.mag_gate), acc_lp_follow=float(p.accel_lowpass_follow),
        bias_gate2=float(p.bias_gate) ** 2,  # 0: off (no inf: fastmath assumes none)
        bias_gate_rate=1.0 / float(p.bias_gate_tau), bias_limit=float(p.bias_limit), mode=mode,
        inv_gravity=1.0 / float(p.gravity),
        inv_gate_acc=1.0 / p.accel_gate if p.accel_gate > 0.0 else 0.0,
        inv_gate_mag=1.0 / p.mag_gate if p.mag_gate > 0.0 else 0.0,
        dip_rate=1.0 / p.dip_tau if p.dip_tau > 0.0 else 0.0,
        acc_lp_rate=1.0 / p.accel_lowpass_tau if p.accel_lowpass_tau > 0.0 else 0.0)


STATE = np.dtype([
    ("q", np.float64, (4,)),          # q_nb, ENU from body, [w, x, y, z]
    ("bias", np.float64, (3,)),       # gyro bias estimate, rad/s, body
    ("P", np.float64, (6, 6)),        # covariance of [δe; δb] (rad², (rad/s)²)
    ("dip_s", np.float64),            # running mean of a·m/(g|m|) = -Z (normalised field)
    ("dip_count", np.float64),        # its weight, samples
    ("acc_lp", np.float64, (3,)),     # low-passed accelerometer, navigation frame, m/s²
    ("acc_lp_started", np.bool_),     # acc_lp holds a value
    ("since_acc_s", np.float64),      # s since the accelerometer's previous sample
    ("acc_dev2", np.float64),         # mean of (| |a| - g |)², (m/s²)²: the bias gate
], align=True)


def new_state(q_nb, bias_rad_s, P, dip_s: float, dip_count: float, acc_lp=None) -> np.ndarray:
    """A ``STATE`` array of one element (``acc_lp`` None: the low-pass starts anew)."""
    st = np.zeros(1, STATE)
    st["q"][0] = q_nb
    st["bias"][0] = bias_rad_s
    st["P"][0] = P
    st["dip_s"][0] = dip_s
    st["dip_count"][0] = dip_count
    if acc_lp is not None:
        st["acc_lp"][0] = acc_lp
        st["acc_lp_started"][0] = True
    return st


class Inputs(NamedTuple):
    """Samples of a run (C-contiguous float arrays)."""

    gyro: np.ndarray   #: (N, 3) rad/s, body
    accel: np.ndarray  #: (N, 3) m/s², body; a zero row is a dropout (prediction only)
    mag: np.ndarray    #: (N, 3) normalised by |B0|, body; a zero row is a dropout
    dt: np.ndarray     #: (N,) s, dt[k] = t[k] - t[k-1] (dt[0] as given, 0: no propagation)


class Outputs(NamedTuple):
    """Per-sample results written by ``run_batch`` (``new_outputs(n)``)."""

    q: np.ndarray           #: (N, 4) q_nb after the sample
    bias: np.ndarray        #: (N, 3) rad/s
    innovation: np.ndarray  #: (N, 6), first r columns; left as given on skipped samples
    cov_diag: np.ndarray    #: (N, 6) diagonal of P
    skipped: np.ndarray     #: (N,) bool: accelerometer or magnetometer dropout
    at_limit: np.ndarray    #: (N,) bool: a component of the bias at ``bias_limit``


def new_outputs(n: int) -> Outputs:
    """``Outputs`` for ``n`` samples (innovation zeroed, skipped False)."""
    return Outputs(np.empty((n, 4)), np.empty((n, 3)), np.zeros((n, 6)), np.empty((n, 6)),
                   np.zeros(n, np.bool_), np.empty(n, np.bool_))


class Work(NamedTuple):
    """Scratch arrays of one step (``workspace``), allocated once per batch."""

    A: np.ndarray   #: (3, 3) I - [ω̂×] dt
    T: np.ndarray   #: (3, 3) A P11 + c P21
    U: np.ndarray   #: (3, 3) A P12 + c P22
    y: np.ndarray   #: (6,) measurement (first r entries)
    D1: np.ndarray  #: (6, 3) attitude columns of D (first r rows)
    Rd: np.ndarray  #: (6,) diagonal of R (first r entries)
    dx: np.ndarray  #: (6,) error estimate [δe; δb]


@njit(**_JIT)
def workspace():
    """A ``Work`` of fresh scratch arrays."""
    return Work(np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty(6),
                np.empty((6, 3)), np.empty(6), np.empty(6))


# ---------------------------------------------------------------- phase 1: gyro prediction
@njit(**_JIT)
def predict(s, c, gx, gy, gz, dt, A, T, U):
    """Strapdown step on the record ``s``: ``q ← q ⊗ exp(ω̂ dt)``, ``P ← Φ P Φᵀ + Q``.

    ``ω̂ = ω_measured - b`` (rad/s, body). ``Φ = [A  cI; 0  I]``, ``A = I - [ω̂×] dt``,
    ``c = -dt/2``; ``Q = diag(σ_g² dt / 4 · I, σ_b² dt · I)``. A, T, U: (3, 3) scratch.
    """
    q, P = s.q, s.P
    wx = gx - s.bias[0]
    wy = gy - s.bias[1]
    wz = gz - s.bias[2]
    rotate_by(q, wx * dt, wy * dt, wz * dt)
    # Φ P Φᵀ = [T Aᵀ + cU, U; Uᵀ, P22], T = A P11 + c P21, U = A P12 + c P22
    cc = -0.5 * dt
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
                       + cc * P[3 + i, j])
            U[i, j] = (A[i, 0] * P[0, 3 + j] + A[i, 1] * P[1, 3 + j] + A[i, 2] * P[2, 3 + j]
                       + cc * P[3 + i, 3 + j])
    qa = 0.25 * c.var_gyro * dt
    qb = c.var_bias * dt
    for i in range(3):
        for j in range(i, 3):
            v = T[i, 0] * A[j, 0] + T[i, 1] * A[j, 1] + T[i, 2] * A[j, 2] + cc * U[i, j]
            if i == j:
                v = v + qa
            P[i, j] = v
            P[j, i] = v
    for i in range(3):
        for j in range(3):
            P[i, 3 + j] = U[i, j]
            P[3 + j, i] = U[i, j]
        P[3 + i, 3 + i] = P[3 + i, 3 + i] + qb


# ---------------------------------------------------------------- phase 2: accel + mag
@njit(inline="always", **_JIT)
def gate_factor(dev, inv_gate):
    """Variance inflation ``1 + (dev/gate)²`` for ``inv_gate = 1/gate`` (0: gating off, 1)."""
    u = dev * inv_gate
    return 1.0 + u * u


@njit(**_JIT)
def reference_and_gates(s, c, ax, ay, az, mx, my, mz, na, nm, dt):
    """Variance gates and the reference field ``[0, H, -Z]`` for one usable sample.

    ``fa = gate(| |a| - g |)``, ``fm = gate(max(| |m| - 1 |, |cos - s|))`` with
    ``cos = a·m / (g |m|)`` (``= -Z`` when undisturbed: rotation invariant, so it can be
    averaged while the body moves; dividing by g rather than |a| keeps accelerometer
    noise from biasing it). When both gates are below 2 and ``dip_tau > 0``, the running
    mean ``s`` moves: ``count += 1``, ``s += max(1/count, dt/dip_tau) (cos - s)``,
    ``|s| <= MAX_ABS_DIP``. ``na``, ``nm``: the norms of a and m. Returns
    ``(fa, fm, H, Z)`` with ``Z = -s``, ``H = sqrt(1 - s²)``.
    """
    cos_am = (ax * mx + ay * my + az * mz) * c.inv_gravity / nm
    fa = gate_factor(abs(na - c.gravity), c.inv_gate_acc)
    fm = gate_factor(max(abs(nm - 1.0), abs(cos_am - s.dip_s)), c.inv_gate_mag)
    if c.dip_tau > 0.0 and fm < 2.0 and fa < 2.0:
        s.dip_count += 1.0
        w = dt * c.dip_rate  # max(1/count, dt/dip_tau), the division only while it is 1/count
        if w * s.dip_count < 1.0:
            w = 1.0 / s.dip_count
        s.dip_s = clip(s.dip_s + w * (cos_am - s.dip_s), MAX_ABS_DIP)
    return fa, fm, math.sqrt(1.0 - s.dip_s * s.dip_s), -s.dip_s


@njit(**_JIT)
def accel_lowpass(s, c, ax, ay, az, dt):
    """Low-pass the accelerometer in the computed navigation frame; returns it in body.

    ``lp ← lp + w (Ĉ_nb a - lp)``, ``w = min(1, dt/acc_lp_tau)`` (``w = 1`` when it
    starts; ``dt`` the time since the accelerometer's previous sample), returns
    ``Ĉ_bn lp``: gravity is constant in the navigation frame while a
    linear acceleration averages out there (the idea of VQF's inertial-frame low-pass,
    Laidig & Seel, Inf. Fusion 2023), so the filtered reading is the better gravity
    measurement.
    """
    q, lp = s.q, s.acc_lp
    if s.acc_lp_started:
        w = min(1.0, dt * c.acc_lp_rate)
    else:
        lp[:] = 0.0
        w = 1.0
    nx, ny, nz = rotate(q[0], q[1], q[2], q[3], ax, ay, az)
    lp[0] += w * (nx - lp[0])
    lp[1] += w * (ny - lp[1])
    lp[2] += w * (nz - lp[2])
    s.acc_lp_started = True
    return rotate_inv(q[0], q[1], q[2], q[3], lp[0], lp[1], lp[2])


@njit(**_JIT)
def follow_correction(s, c, bx, by, bz):
    """After a correction of ``q``: the low-pass state moves by ``acc_lp_follow`` of the way
    to the filtered reading ``(bx, by, bz)`` (body, as it was before the correction) seen
    through the corrected attitude, ``lp ← lp + λ (Ĉ_nb b - lp)``.

    With ``λ = 1`` the low-pass lives in a frame that turns with every correction (as
    VQF's almost-inertial frame, corrected only on its left) and a corrected tilt leaves
    the average at once; with ``λ = 0`` (the former filter) a corrected tilt stayed in the
    average for ``acc_lp_tau`` and was measured, and corrected, again and again, which
    under sustained motion drove the bias estimate away (walking, swinging: 14-19 °/s).
    Between the two, a corrected tilt is measured again for about ``1/λ`` samples: a
    stronger tilt loop than the Kalman gain alone, without feeding the bias."""
    q, lp = s.q, s.acc_lp
    nx, ny, nz = rotate(q[0], q[1], q[2], q[3], bx, by, bz)
    lam = c.acc_lp_follow
    lp[0] += lam * (nx - lp[0])
    lp[1] += lam * (ny - lp[1])
    lp[2] += lam * (nz - lp[2])


@njit(**_JIT)
def bias_gate(s, c, na, dt):
    """Update the mean of ``(| |a| - g |)²`` (weight ``min(1, dt / bias_gate_tau)``, ``dt``
    the time since the accelerometer's previous sample) and return whether it exceeds
    ``bias_gate²``: strong sustained linear acceleration (walking, running), whose
    low-passed residue the accelerometer rows cannot tell from a tilt error. The
    correction then leaves the bias alone (``hold_bias``). Off (``bias_gate = 0``, the
    default): False, the mean not kept."""
    if c.bias_gate2 <= 0.0:
        return False
    dev = na - c.gravity
    s.acc_dev2 += min(1.0, dt * c.bias_gate_rate) * (dev * dev - s.acc_dev2)
    return s.acc_dev2 > c.bias_gate2


@njit(inline="always", **_JIT)
def bias_block(s):
    """The bias estimate and its covariance block (upper triangle), to be restored by
    ``hold_bias``."""
    b, P = s.bias, s.P
    return (b[0], b[1], b[2], P[3, 3], P[3, 4], P[3, 5], P[4, 4], P[4, 5], P[5, 5])


@njit(**_JIT)
def hold_bias(s, k):
    """Undo a correction's effect on the bias: ``b`` and ``P_bb`` back to ``k``
    (``bias_block`` before it). What remains is exactly the Schmidt ("consider") update
    with zero bias gain: the attitude gain and the attitude-bias covariance of the
    optimal update do not depend on the bias gain (``K_a = P_aa Dᵀ S⁻¹``,
    ``P_ab ← (I - K_a D) P_ab``), so the covariance stays consistent."""
    b, P = s.bias, s.P
    b[0], b[1], b[2] = k[0], k[1], k[2]
    P[3, 3], P[4, 4], P[5, 5] = k[3], k[6], k[8]
    P[3, 4] = P[4, 3] = k[4]
    P[3, 5] = P[5, 3] = k[5]
    P[4, 5] = P[5, 4] = k[7]


@njit(**_JIT)
def measure_r6(q, c, ax, ay, az, mx, my, mz, mag_h, mag_z, fa, fm, y, D1, Rd):
    """Full model: ``y = [a - Ĉ_bn g_n; m - Ĉ_bn m_n]``, ``D1 = [2[â×]; 2[m̂×]]`` (6x3).

    ``g_n = [0, 0, g]``, ``m_n = [0, H, -Z]`` (normalised field); ``Rd`` the diagonal of
    ``R = diag(σ_a² fa I, σ_m² fm I)`` (``fa``, ``fm``: the gates' inflation).
    """
    _, _, _, c10, c11, c12, c20, c21, c22 = dcm(q[0], q[1], q[2], q[3])
    # predicted readings in body: â = g C_nb[2, :], m̂ = H C_nb[1, :] - Z C_nb[2, :]
    g = c.gravity
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
    skew_into(D1, 0, 2.0, a0, a1, a2)
    skew_into(D1, 3, 2.0, m0, m1, m2)
    ra = c.var_acc * fa
    rm = c.var_mag * fm
    for i in range(3):
        Rd[i] = ra
        Rd[3 + i] = rm


@njit(**_JIT)
def measure_r3(q, c, ax, ay, az, mx, my, mz, mag_h, mag_z, fa, fm, y, D1, Rd):
    """Reduced model: ``y = [ã_x/g, ã_y/g, m̃_x/H]``, ``ã = Ĉ_nb a``, ``m̃ = Ĉ_nb m``.

    ``D1 = D_n Ĉ_nb`` with ``D_n = [[0, -2, 0], [2, 0, 0], [0, 2 tan I, 2]]`` for the
    body-frame error ``q = q̂ ⊗ δq`` (derivation in ``docs/estimators/eskf.md``); the
    predicted measurement is zero. ``R = diag(σ_a² fa/g², σ_a² fa/g², σ_m² fm/H²)``.
    """
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = dcm(q[0], q[1], q[2], q[3])
    ig = c.inv_gravity
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
    ra = c.var_acc * fa * ig * ig
    Rd[0] = ra
    Rd[1] = ra
    Rd[2] = c.var_mag * fm * ih * ih


# ---------------------------------------------------------------- phase 3: Kalman correction
def gain(P, D1, Rd, r, PDt, S, K):
    """Kalman gain ``K = P Dᵀ (D P Dᵀ + R)⁻¹`` for ``D = [D1 0]`` (r x 6, bias columns zero).

    P (6, 6) covariance; D1 (r, 3) attitude columns of D; Rd (r,) diagonal of R.
    Scratch/outputs (caller-allocated): PDt (6, r) = P Dᵀ; S (r, r) receives the
    factorisation ``S = L diag(d) Lᵀ`` (L unit lower-triangular) stored as
    ``S[i, j] = L_ij d_j`` below the diagonal and ``1/d_j`` on it; K (6, r) the gain.

    Plain Python on purpose: traced into ``eskf_unrolled`` and run on counting numbers
    (module docstring).
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


def joseph(P, D1, Rd, y, K, r, L, M, G, dx):
    """Error estimate ``dx = K y`` and Joseph-form covariance (upper triangle into ``P``).

    ``P ← (I - K D) P (I - K D)ᵀ + K R Kᵀ`` with ``K D = [L 0]``, ``L = K D1``
    (6x3), evaluated as ``N = (I - K D) P = P - L P[0:3, :]`` (into ``M``; its
    first three columns and its upper triangle), ``G = K R - N Dᵀ`` (6 x r; zero
    for the exact optimal gain, which is what makes the form robust to
    rounding and to a sub-optimal gain), ``P ← N + G Kᵀ``: only the upper
    triangle ``P[i, j], j >= i`` is written (the caller mirrors it, which is
    the symmetrisation). Plain Python, like ``gain``.
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


@njit(inline="always", **_JIT)
def inject(q, b, dx, lim):
    """``q ← normalise(q ⊗ [1, δe])``, ``b ← b + δb`` with each component within ``±lim``
    (the error state is then reset to zero)."""
    w, x, y, z = mul(q[0], q[1], q[2], q[3], 1.0, dx[0], dx[1], dx[2])
    q[0], q[1], q[2], q[3] = normalised(w, x, y, z)
    b[0] = clip(b[0] + dx[3], lim)
    b[1] = clip(b[1] + dx[4], lim)
    b[2] = clip(b[2] + dx[5], lim)


@njit(inline="always", **_JIT)
def correct(s, c, mode, y, D1, Rd, dx):
    """Kalman correction of the record ``s``: ``gain`` + ``joseph`` + mirror of P (the
    straight-line ``eskf_unrolled.update_r6`` / ``update_r3``), then ``inject``."""
    if mode == MODE_R6:
        update_r6(s.P, D1, Rd, y, dx)
    else:
        update_r3(s.P, D1, Rd, y, dx)
    inject(s.q, s.bias, dx, c.bias_limit)


_gain_loops = njit(**_JIT)(gain)
_joseph_loops = njit(**_JIT)(joseph)


# ---------------------------------------------------------------- step and batch
@njit(**_JIT)
def correct_rows(s, c, r, y, D1, Rd, dx, scratch):
    """Kalman correction with the first ``r`` rows of ``y``, ``D1``, ``Rd`` (any ``r``: the
    loop forms of ``gain`` and ``joseph``, compiled), P mirrored, then ``inject``.
    ``scratch``: (SCRATCH,) floats for their work matrices (one array: the loop that
    passes it along stays as lean as the single-rate loop)."""
    PDt = scratch[0:36].reshape(6, 6)
    S = scratch[36:72].reshape(6, 6)
    K = scratch[72:108].reshape(6, 6)
    L = scratch[108:126].reshape(6, 3)
    M = scratch[126:162].reshape(6, 6)
    G = scratch[162:198].reshape(6, 6)
    _gain_loops(s.P, D1, Rd, r, PDt, S, K)
    _joseph_loops(s.P, D1, Rd, y, K, r, L, M, G, dx)
    for i in range(6):
        for j in range(i + 1, 6):
            s.P[j, i] = s.P[i, j]
    inject(s.q, s.bias, dx, c.bias_limit)


@njit(**_JIT)
def one_sensor(s, c, mode, ax, ay, az, mx, my, mz, na, nm, new_a, w):
    """The correction by the one sensor that has a new sample in this row (each sensor
    at its own rate): the accelerometer's or the magnetometer's rows of the measurement.

    Its gate as in ``reference_and_gates``; for the magnetometer alone the field's
    vertical is read through the attitude estimate (``(Ĉ_nb m)_z / |m|`` in place of
    ``a·m / (g |m|)``; no accelerometer value is reused), and the inclination estimate
    does not move. Returns the number of rows used (r6: 3 and 3; r3: 2 and 1)."""
    q = s.q
    dip = s.dip_s
    mag_h, mag_z = math.sqrt(1.0 - dip * dip), -dip
    if new_a:
        fa, fm = gate_factor(abs(na - c.gravity), c.inv_gate_acc), 1.0
        if c.acc_lp_tau > 0.0:
            ax, ay, az = accel_lowpass(s, c, ax, ay, az, s.since_acc_s)
        mx, my, mz = 0.0, 0.0, 0.0
    else:
        _, _, vz = rotate(q[0], q[1], q[2], q[3], mx, my, mz)
        fa, fm = 1.0, gate_factor(max(abs(nm - 1.0), abs(vz / nm - dip)), c.inv_gate_mag)
        ax, ay, az = 0.0, 0.0, 0.0
    if mode == MODE_R6:
        measure_r6(q, c, ax, ay, az, mx, my, mz, mag_h, mag_z, fa, fm, w.y, w.D1, w.Rd)
        first, r = (0, 3) if new_a else (3, 3)
    else:
        measure_r3(q, c, ax, ay, az, mx, my, mz, mag_h, mag_z, fa, fm, w.y, w.D1, w.Rd)
        first, r = (0, 2) if new_a else (2, 1)
    for i in range(r):
        w.y[i] = w.y[first + i]
        w.Rd[i] = w.Rd[first + i]
        for j in range(3):
            w.D1[i, j] = w.D1[first + i, j]
    return r


@njit(**_JIT)
def _one_sensor_correction(s, c, mode, ax, ay, az, mx, my, mz, na, nm, new_a, w, scratch):
    """``one_sensor`` then ``correct_rows``: a function of its own, called (not inlined)
    from the loop, which it would slow by a sixth with its size for rows that only a
    multi-rate recording has. The bias gate (``bias_gate``, on an accelerometer sample;
    its state otherwise) and the low-pass's following of the correction as in ``step``.
    Returns the rows used."""
    hold = c.bias_gate2 > 0.0 and s.acc_dev2 > c.bias_gate2
    if new_a:
        hold = bias_gate(s, c, na, s.since_acc_s)
    r = one_sensor(s, c, mode, ax, ay, az, mx, my, mz, na, nm, new_a, w)
    if new_a:
        s.since_acc_s = 0.0
    q, lp = s.q, s.acc_lp
    follow = c.acc_lp_tau > 0.0 and c.acc_lp_follow > 0.0 and s.acc_lp_started
    bx, by, bz = rotate_inv(q[0], q[1], q[2], q[3], lp[0], lp[1], lp[2])
    k = bias_block(s)
    correct_rows(s, c, r, w.y, w.D1, w.Rd, w.dx, scratch)
    if hold:
        hold_bias(s, k)
    if follow:
        follow_correction(s, c, bx, by, bz)
    return r


@njit(inline="always", **_JIT)
def step(s, c, mode, inputs, k, w, since, scratch):
    """Sample ``k`` of ``inputs`` on the record ``s``: ``step_row`` on its values."""
    return step_row(s, c, mode, inputs.dt[k], inputs.gyro[k, 0], inputs.gyro[k, 1],
                    inputs.gyro[k, 2], inputs.accel[k, 0], inputs.accel[k, 1],
                    inputs.accel[k, 2], inputs.mag[k, 0], inputs.mag[k, 1], inputs.mag[k, 2],
                    w, since, scratch)


@njit(**_JIT)
def step_row(s, c, mode, dt, gx, gy, gz, ax, ay, az, mx, my, mz, w, since, scratch):
    """One sample (``dt`` s, gyro rad/s, accelerometer m/s², normalised magnetometer; a
    NaN or zero ``a``/``m``: no sample of that sensor) on the record ``s`` (``w``: a
    ``Work``; ``mode`` is ``c.mode``, the same for every sample of a ``run_batch``;
    ``since``: the time since the accelerometer's previous sample, kept in a register by
    the loop rather than in ``s.since_acc_s``). Returns ``(rows, since)``: how many
    measurement rows corrected the state: 0 when neither sensor has a usable new sample
    (a zero vector, or NaN: no sample in this row), r when both do, fewer when only one
    does (``one_sensor``); ``w.y`` holds those rows."""
    predict(s, c, gx, gy, gz, dt, w.A, w.T, w.U)
    if mode == MODE_PREDICT_ONLY:
        return 0, since
    na = math.sqrt(ax * ax + ay * ay + az * az)
    nm = math.sqrt(mx * mx + my * my + mz * mz)
    since += dt
    new_a, new_m = na > 0.0, nm > 0.0  # False for a zero vector and for NaN (no sample)
    if not (new_a and new_m):
        if not (new_a or new_m):
            return 0, since
        s.since_acc_s = since
        r = _one_sensor_correction(s, c, mode, ax, ay, az, mx, my, mz, na, nm, new_a, w,
                                   scratch)
        return r, s.since_acc_s
    fa, fm, mag_h, mag_z = reference_and_gates(s, c, ax, ay, az, mx, my, mz, na, nm, dt)
    hold = bias_gate(s, c, na, since)
    if c.acc_lp_tau > 0.0:
        ax, ay, az = accel_lowpass(s, c, ax, ay, az, since)
    if mode == MODE_R6:
        measure_r6(s.q, c, ax, ay, az, mx, my, mz, mag_h, mag_z, fa, fm, w.y, w.D1, w.Rd)
    else:
        measure_r3(s.q, c, ax, ay, az, mx, my, mz, mag_h, mag_z, fa, fm, w.y, w.D1, w.Rd)
    if hold:
        k = bias_block(s)
        correct(s, c, mode, w.y, w.D1, w.Rd, w.dx)
        hold_bias(s, k)
    else:
        correct(s, c, mode, w.y, w.D1, w.Rd, w.dx)
    if c.acc_lp_tau > 0.0 and c.acc_lp_follow > 0.0:
        follow_correction(s, c, ax, ay, az)  # (ax, ay, az): the filtered reading, body
    return (6 if mode == MODE_R6 else 3), 0.0


@njit(**_JIT)
def _loop(inputs, s, c, outputs, w, mode, scratch):
    """The loop over samples in ``mode`` (``c.mode``: one compiled loop for every mode)."""
    r_full = 6 if mode == MODE_R6 else 3
    since = s.since_acc_s
    lim = c.bias_limit
    for k in range(inputs.dt.shape[0]):
        r, since = step(s, c, mode, inputs, k, w, since, scratch)
        outputs.skipped[k] = mode != MODE_PREDICT_ONLY and r < r_full
        if r == r_full:
            for j in range(r):
                outputs.innovation[k, j] = w.y[j]
        for j in range(4):
            outputs.q[k, j] = s.q[j]
        b0, b1, b2 = s.bias[0], s.bias[1], s.bias[2]
        outputs.bias[k, 0], outputs.bias[k, 1], outputs.bias[k, 2] = b0, b1, b2
        outputs.at_limit[k] = abs(b0) >= lim or abs(b1) >= lim or abs(b2) >= lim
        for j in range(6):
            outputs.cov_diag[k, j] = s.P[j, j]
    s.since_acc_s = since


@njit(**_JIT)
def run_batch(inputs, state, c, outputs):
    """Run the filter over ``inputs`` (``Inputs``), continuing from ``state`` (a ``STATE``
    array of one element, updated in place) with ``c`` (``Coefficients``); writes
    ``outputs`` (``Outputs``, N rows). One loop for every mode (the mode a runtime value:
    compiled once per mode as a constant, the loop took 1.7x as long to compile for no
    measurable speed)."""
    local = state.copy()  # a fresh array: nothing else can alias the state in the loop
    s = local[0]
    w = workspace()
    scratch = np.empty(SCRATCH)
    _loop(inputs, s, c, outputs, w, c.mode, scratch)
    state[0] = local[0]
