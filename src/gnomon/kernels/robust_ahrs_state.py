"""The robust decoupled AHRS's coefficients and state (``gnomon.kernels.robust_ahrs``):
plain numpy, no compiled code.

``Coefficients`` (a named tuple, built once by ``coefficients(params, ts_s, ts_acc_s,
ts_mag_s)`` from the parameters and the nominal sample times: second-order Butterworth
low-passes by ``butter2``, gains from time constants) and ``STATE`` (the structured dtype
of the evolving state, with its low-pass filters and hard-iron sums as nested records;
``new_state(params)`` gives a fresh one-element array). The kernel module re-exports
every name; its docstring describes the step.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

__all__ = ["LowPass", "Coefficients", "coefficients", "butter2", "STATE", "LOWPASS_2",
           "LOWPASS_3", "LOWPASS_33", "HARD_IRON", "new_state"]


# ---------------------------------------------------------------- coefficients
class LowPass(NamedTuple):
    """A second-order Butterworth low-pass ``y = (b0 + b1 z⁻¹ + b2 z⁻²) / (1 + a1 z⁻¹ +
    a2 z⁻²) x`` that starts as a running mean for its first ``tau_s`` seconds (sample
    time ``ts_s``)."""

    b0: float
    b1: float
    b2: float
    a1: float
    a2: float
    tau_s: float
    ts_s: float


class Coefficients(NamedTuple):
    """Everything the step needs that does not evolve, derived once from the parameters
    and the nominal sample time (``coefficients``). Angles in rad, rates in rad/s."""

    ts_s: float  # nominal gyro sample time
    ts_acc_s: float  # nominal accelerometer sample time (its own rate)
    max_dt_s: float  # longer intervals are gaps (gyro only)
    # rest detection
    rest_bias: bool
    rest_lp: LowPass  # the gyro (sample time ts_s)
    rest_acc_lp: LowPass  # the accelerometer (sample time ts_acc_s)
    rest_th_gyro2: float  # (rad/s)², on |ω - lp(ω)|²
    rest_th_acc2: float  # (m/s²)², on |a - lp(a)|²
    rest_min_s: float
    rest_th_rate: float  # rad/s, on |lp(ω) - b| (inf-norm): beyond it a rest needs rest_min_large_s
    rest_min_large_s: float
    rest_mag_lp: LowPass  # the magnetometer in the body frame (its own sample time)
    rest_th_turn2: float  # squared chord of rest_th_turn_deg between unit vectors (0: off)
    rest_reset: bool  # the first rest of the start-up sets the inclination and the heading
    # inclination
    acc_lp: LowPass  # the accelerometer in frame I
    # gyro-bias Kalman filter, run on every bias_every-th accelerometer sample
    motion_bias: bool
    bias_every: int
    bias_lp: LowPass  # R_6b and R_6b b, sample time ts_acc_s * bias_every
    bias_p0: float  # (rad/s)²: the variance stops growing there
    bias_v: float  # (rad/s)² per bias update: process noise
    w_rest: float  # (rad/s)²: measurement variances
    w_motion: float
    w_vertical: float
    bias_clip: float  # rad/s: bound on the bias estimate (and on lp(ω) for a rest)
    huber: float  # rad/s: Huber threshold of the bias filter's innovations in motion
    # magnetometer, the heading filter run on the mean field of every mag_every samples
    mag_every: int
    ts_mag: float  # the magnetometer's nominal sample time * mag_every
    hi_lambda: float  # hard-iron window: forgetting factor per heading update (0: off)
    hi_reg: float
    hi_gate: float
    mag_rejection: bool
    mag_lp: LowPass  # the field's norm and dip
    k_mag_ref: float  # gain of the learned reference (norm, dip) per heading update
    mag_norm_th: float  # relative
    mag_dip_th: float  # rad
    mag_new_s: float
    mag_new_first_s: float
    mag_new_min_gyro2: float  # (rad/s)²
    mag_min_undisturbed_s: float
    mag_max_reject_s: float
    mag_reject_factor: float
    mag_heading_dis: float  # rad (0: off)
    soft_norm: float  # 1 / mag_soft_norm² (0: off)
    soft_dip: float  # 1 / mag_soft_dip² (1/rad², 0: off)
    # heading
    tau_mag_s: float
    k_mag: float  # first-order gain per heading update
    heading_kf: bool
    r_head: float  # heading KF: measurement variance, random walk per update, per |ω|² dt
    q_head: float
    q_rate: float
    inv_bias_ref2: float  # 1/(rad/s)²: heading_bias_ref_deg_s⁻² (0: off)
    k_mag_bias: float  # 1/s: heading-rate bias loop (0: off)


def butter2(tau_s: float, ts_s: float) -> np.ndarray:
    """Second-order Butterworth low-pass ``[b0, b1, b2, a1, a2]`` (bilinear transform).

    Cutoff ``fc = √2 / (2π τ)`` (``τ`` is the time constant of the non-oscillating part
    of the step response). A cutoff at or above 0.45·fs gives the identity filter.
    """
    fc = math.sqrt(2.0) / (2.0 * math.pi * tau_s) if tau_s > 0 else math.inf
    if fc * ts_s >= 0.45:
        return np.array([1.0, 0.0, 0.0, 0.0, 0.0])
    c = math.tan(math.pi * fc * ts_s)
    d = c * c + math.sqrt(2.0) * c + 1.0
    b0 = c * c / d
    a2 = (1.0 - math.sqrt(2.0) * c + c * c) / d
    return np.array([b0, 2.0 * b0, b0, 2.0 * (c * c - 1.0) / d, a2])


def _lowpass(tau_s: float, ts_s: float) -> LowPass:
    return LowPass(*(float(b) for b in butter2(tau_s, ts_s)), float(tau_s), float(ts_s))


def _gain(tau_s: float, ts_s: float) -> float:
    """First-order filter gain ``1 - exp(-ts/τ)`` (τ = 0: 1)."""
    return 1.0 if tau_s <= 0 else 1.0 - math.exp(-ts_s / tau_s)


def coefficients(p, ts_s: float, ts_acc_s: float | None = None,
                 ts_mag_s: float | None = None) -> Coefficients:
    """The step's coefficients for the parameters ``p`` (a ``RobustAHRSParams``) and the
    nominal sample times (s) of the gyro ``ts_s``, the accelerometer ``ts_acc_s`` and the
    magnetometer ``ts_mag_s`` (each sensor at its own rate; None: the gyro's)."""
    d2r = math.pi / 180.0
    ts_s = float(ts_s)
    ts_acc = ts_s if ts_acc_s is None else float(ts_acc_s)
    ts_m = ts_s if ts_mag_s is None else float(ts_mag_s)
    tsm = ts_m * p.mag_every  # the heading filter's interval
    ts_b = ts_acc * p.bias_every  # the bias filter's interval
    # bias process noise: the variance grows by (0.1 deg/s)² in bias_forgetting_s; the
    # measurement variances make the steady-state std the stated sigma
    bias_v = (0.1 * d2r) ** 2 * ts_b / p.bias_forgetting_s
    pm = (p.bias_sigma_motion_deg_s * d2r) ** 2
    pr = (p.bias_sigma_rest_deg_s * d2r) ** 2
    w_motion = pm * pm / bias_v + pm
    # heading KF in units where the heading variance grows at rate 1 (per s) at rest: the
    # measurement variance per update is tau_mag² / tsm (steady-state time constant
    # tau_mag), the random walk per update makes the steady-state gain exactly k_mag
    k_mag = _gain(p.tau_mag_s, tsm)
    r_head = p.tau_mag_s ** 2 / tsm if p.tau_mag_s > 0 else 1.0
    new_gyro = p.mag_new_min_gyro_deg_s * d2r
    return Coefficients(
        ts_s=ts_s, ts_acc_s=ts_acc, max_dt_s=float(p.max_dt_s),
        rest_bias=bool(p.rest_bias), rest_lp=_lowpass(p.rest_tau_s, ts_s),
        rest_acc_lp=_lowpass(p.rest_tau_s, ts_acc),
        rest_th_gyro2=(p.rest_th_gyro_deg_s * d2r) ** 2, rest_th_acc2=p.rest_th_acc_m_s2 ** 2,
        rest_min_s=float(p.rest_min_s), rest_th_rate=p.rest_th_rate_deg_s * d2r,
        rest_min_large_s=float(p.rest_min_large_bias_s),
        rest_mag_lp=_lowpass(p.rest_tau_s, ts_m),
        rest_th_turn2=(2.0 * math.sin(0.5 * p.rest_th_turn_deg * d2r)) ** 2,
        rest_reset=bool(p.rest_reset),
        acc_lp=_lowpass(p.tau_acc_s, ts_acc),
        motion_bias=bool(p.motion_bias), bias_every=int(p.bias_every),
        bias_lp=_lowpass(p.tau_acc_s, ts_b),
        bias_p0=(p.bias_sigma_init_deg_s * d2r) ** 2, bias_v=bias_v,
        w_rest=pr * pr / bias_v + pr, w_motion=w_motion,
        w_vertical=w_motion / p.bias_vertical_forgetting, bias_clip=p.bias_clip_deg_s * d2r,
        huber=p.bias_huber_deg_s * d2r,
        mag_every=int(p.mag_every), ts_mag=tsm,
        hi_lambda=math.exp(-tsm / p.hard_iron_tau_s) if p.hard_iron_tau_s > 0 else 0.0,
        hi_reg=float(p.hard_iron_reg), hi_gate=float(p.hard_iron_gate),
        mag_rejection=bool(p.mag_rejection), mag_lp=_lowpass(p.mag_current_tau_s, tsm),
        k_mag_ref=_gain(p.mag_ref_tau_s, tsm), mag_norm_th=float(p.mag_norm_th),
        mag_dip_th=p.mag_dip_th_deg * d2r, mag_new_s=float(p.mag_new_s),
        mag_new_first_s=float(p.mag_new_first_s), mag_new_min_gyro2=new_gyro * new_gyro,
        mag_min_undisturbed_s=float(p.mag_min_undisturbed_s),
        mag_max_reject_s=float(p.mag_max_reject_s),
        mag_reject_factor=float(p.mag_reject_factor),
        mag_heading_dis=p.mag_heading_dis_deg * d2r,
        soft_norm=1.0 / p.mag_soft_norm ** 2 if p.mag_soft_norm > 0 else 0.0,
        soft_dip=1.0 / (p.mag_soft_dip_deg * d2r) ** 2 if p.mag_soft_dip_deg > 0 else 0.0,
        tau_mag_s=float(p.tau_mag_s), k_mag=k_mag, heading_kf=bool(p.heading_kf),
        r_head=r_head, q_head=r_head * k_mag * k_mag / (1.0 - k_mag) if k_mag < 1.0 else 1e12,
        q_rate=p.heading_rate_noise_s ** 2,
        inv_bias_ref2=1.0 / (p.heading_bias_ref_deg_s * d2r) ** 2
        if p.heading_bias_ref_deg_s > 0 else 0.0, k_mag_bias=float(p.mag_bias_gain_per_s),
    )


# ---------------------------------------------------------------- state
def _lowpass_state(shape) -> np.dtype:
    """State of a ``LowPass`` of values of ``shape``: ``z0``, ``z1`` (the direct form II
    transposed; during the start-up ``z0`` holds the running sum) and ``n``, the number of
    samples in the running mean (-1 once the filter runs)."""
    return np.dtype([("z0", np.float64, shape), ("z1", np.float64, shape), ("n", np.int64)],
                    align=True)


LOWPASS_2 = _lowpass_state((2,))
LOWPASS_3 = _lowpass_state((3,))
LOWPASS_33 = _lowpass_state((3, 3))

#: Exponentially weighted sums of the hard-iron fit (``hard_iron``) and the offset in use.
HARD_IRON = np.dtype([
    ("w", np.float64),  # Σ 1
    ("S", np.float64, (3, 3)),  # Σ R_6b
    ("rm", np.float64, (3,)),  # Σ R_6b m (the raw field)
    ("m", np.float64, (3,)),  # Σ m
    ("mm", np.float64),  # Σ |m|²
    ("o", np.float64, (3,)),  # the offset in use (body, magnetometer unit; 0: none)
    ("block_m", np.float64, (3,)),  # Σ m, Σ |m|² over the current block of mag_every
    ("block_mm", np.float64),
    ("block_S", np.float64, (3, 3)),  # Σ R_6b, Σ R_6b m (raw) over the block, each sample
    ("block_rm", np.float64, (3,)),   # with its own R_6b
], align=True)

#: The filter's evolving state (one record; see the module docstring for the frames). The
#: dtypes are aligned (``align=True``: padding after the booleans), so that numba reads every
#: float at its natural alignment.
STATE = np.dtype([
    ("q_gyr", np.float64, (4,)),  # q_Ib: strapdown of the bias-corrected gyro
    ("q_acc", np.float64, (4,)),  # q_6I: inclination correction
    ("delta", np.float64),  # rad: heading of frame 6 in ENU, q_n6 = q_z(delta)
    ("cos_half_delta", np.float64),
    ("sin_half_delta", np.float64),
    ("bias", np.float64, (3,)),  # rad/s, body
    ("P", np.float64, (3, 3)),  # (rad/s)²: bias covariance
    # rest detection
    ("rest_gyro_lp", LOWPASS_3),
    ("gyro_lp", np.float64, (3,)),  # rad/s: its output (the rest-phase bias measurement)
    ("rest_acc_lp", LOWPASS_3),
    ("rest_t", np.float64),  # s spent within the thresholds
    ("rest_mag_lp", LOWPASS_3),  # the magnetometer, body frame
    ("mag_body_lp", np.float64, (3,)),  # its output
    ("rest_a0", np.float64, (3,)),  # unit low-passed accelerometer when the candidacy began
    ("rest_m0", np.float64, (3,)),  # the low-passed magnetometer then (raw)
    ("rest_q", np.float64, (4,)),  # body then <- body now: the gyro (minus bias) since
    ("rest", np.bool_),
    ("bias_at_limit", np.bool_),  # a component of the bias at ±bias_clip (in the padding)
    ("mag_body_ok", np.bool_),  # mag_body_lp holds a sample
    ("rest_m0_ok", np.bool_),  # rest_m0 was taken
    ("reset_done", np.bool_),  # the first rest came (and reset the start-up's estimate)
    ("heading_reset", np.bool_),  # the next magnetometer sample sets the heading
    # inclination and bias in motion
    ("acc_lp", LOWPASS_3),  # m/s², frame I
    ("acc_rate", np.float64),  # rad/s: sine of the last correction angle / ts
    ("bias_count", np.int64),  # accelerometer samples since the last bias update, mod k
    ("bias_R_lp", LOWPASS_33),  # R_6b
    ("bias_Rb_lp", LOWPASS_2),  # (R_6b b)_xy
    # magnetometer
    ("mag_sum", np.float64, (3,)),  # Σ R_6b (m - o) over the current block
    ("mag_count", np.int64),
    ("mag_lp", LOWPASS_2),  # norm, dip (rad) of the mean field in frame 6
    ("mag_ref_norm", np.float64),  # learned reference (0: none yet)
    ("mag_ref_dip", np.float64),
    ("mag_undisturbed_t", np.float64),
    ("mag_reject_t", np.float64),
    ("mag_disturbed", np.bool_),
    ("cand_norm", np.float64),  # a candidate new field, and how long it held in motion
    ("cand_dip", np.float64),
    ("cand_t", np.float64),
    ("k_mag_init", np.float64),  # running-mean gain at start (0 once over)
    ("k_mag_used", np.float64),  # heading gain of the last update (0 while rejected)
    ("mag_dis", np.float64),  # rad: the last heading disagreement
    ("p_head", np.float64),  # heading variance (units: see Coefficients)
    ("rot2", np.float64),  # ∫|ω - b|² dt since the last heading update, rad²/s
    ("hard_iron", HARD_IRON),
], align=True)


def new_state(p) -> np.ndarray:
    """A fresh state for the parameters ``p``: an array of one ``STATE`` record."""
    state = np.zeros(1, STATE)
    s = state[0]
    s["q_gyr"][0] = 1.0
    s["q_acc"][0] = 1.0
    s["rest_q"][0] = 1.0
    s["cos_half_delta"] = 1.0
    s["P"] = np.eye(3) * (p.bias_sigma_init_deg_s * math.pi / 180.0) ** 2
    s["mag_disturbed"] = True
    s["mag_reject_t"] = p.mag_max_reject_s
    s["cand_norm"] = -1.0
    s["k_mag_init"] = 1.0
    s["p_head"] = 1e6
    return state
