"""Robust decoupled AHRS for real IMUs: rest detection, gyro bias estimation in rest and
motion, inertial-frame accelerometer filtering, heading-only magnetometer correction with
disturbance rejection, a heading Kalman gain and an online hard-iron offset.

The structure follows VQF (Laidig & Seel, "VQF: Highly accurate IMU orientation
estimation with bias estimation and magnetic disturbance rejection", Information
Fusion 91:187-204, 2023, arXiv:2203.17024); the implementation, the parameter
units and the extra heading-bias loop are gnomon's. Frames: body b (sensor),
almost-inertial frame I (where the strapdown integration lives), the
inclination-corrected frame 6 (its z axis is up) and the navigation frame
n = ENU. The estimate is

    q_nb = q_z(δ) ⊗ q_6I ⊗ q_Ib

* **Strapdown** ``q_Ib ← q_Ib ⊗ exp((ω - b̂) dt)``.
* **Inclination** (``tau_acc_s``): the accelerometer is rotated into I and
  low-pass filtered there (second-order Butterworth, time constant ``tau_acc_s``;
  the first ``tau_acc_s`` seconds are a running mean, which also initialises the
  tilt from the first samples). Linear accelerations are short-lived in I and
  average out, while gravity, fixed in I, passes. ``q_6I`` is then corrected by
  the rotation that takes the filtered vector (seen in frame 6) to up; with the
  filtering already done, the full correction is applied every sample.
* **Rest detection** (``rest_bias``): gyro and accelerometer low-passed with
  ``rest_tau_s``; rest when both deviate from their low-pass by less than
  ``rest_th_gyro_deg_s`` / ``rest_th_acc_m_s2`` for ``rest_min_s``.
* **Gyro bias** (3-state Kalman filter, rad/s): at rest the measurement is the
  low-passed gyro (``H = I``, std ``bias_sigma_rest_deg_s``); in motion
  (``motion_bias``) the inclination correction is the measurement of the
  horizontal components of ``R_6b b`` (both sides low-passed like the
  accelerometer), std ``bias_sigma_motion_deg_s``; the vertical component is
  only weakly pulled to zero (``bias_vertical_forgetting``). The covariance
  grows so that the uncertainty reaches 0.1 deg/s after ``bias_forgetting_s``.
* **Heading** (``tau_mag_s``): the magnetometer, seen in frame 6, gives the
  heading disagreement ``atan2(m_E, m_N) - δ``; ``δ`` follows it with a
  first-order filter. The magnetometer never touches the inclination. During
  the first ``tau_mag_s`` seconds the gain is at least ``1/k`` (running mean).
* **Heading Kalman gain** (``heading_kf``, ``heading_rate_noise_s``, gnomon's
  addition): ``δ`` has a scalar variance that grows at rate 1/s plus
  ``heading_rate_noise_s² |ω|²`` and is reduced by each heading update with
  measurement variance ``tau_mag_s² / T`` (steady gain = the first-order gain of
  ``tau_mag_s`` at rest). While the field is rejected the variance grows, so the
  heading recovers fast afterwards; fast rotation raises the gain too.
* **Online hard-iron offset** (``hard_iron_tau_s``, gnomon's addition): with a
  magnet fixed to the sensor, ``R_6b m = h + R_6b o`` with ``h`` fixed in frame 6.
  Exponentially weighted sums (window ``hard_iron_tau_s``) give the least-squares
  ``o`` in closed form, ``(w²(1+reg) I - SᵀS) o = w Σm - Sᵀ Σ R m`` (``S = Σ R``,
  prior ``hard_iron_reg``). ``o`` is subtracted from the magnetometer only while
  it explains the field (residual energy below ``hard_iron_gate`` of the
  residual without an offset); a field that varies in space is not explained by
  a body-fixed offset and leaves ``o = 0``.
* **Soft de-weighting** (``mag_soft_norm``, ``mag_soft_dip_deg``, off): the
  heading measurement variance grows with the field's norm/dip distance from
  the reference.
* **Rates**: the heading filter and disturbance detection run on the mean field
  (frame 6) of every ``mag_every`` samples, the bias filter on every
  ``bias_every``-th sample, each with its coefficients for that interval.
* **Heading-rate bias loop** (``mag_bias_gain_per_s``, gnomon's addition, off): the
  heading disagreement also integrates into the gyro bias along the vertical
  (a PI instead of a P heading loop), so that a vertical bias that the
  accelerometer cannot see does not leave a steady heading lag of ``b·tau_mag``.
* **Magnetic disturbance** (``mag_rejection``): the field's norm and dip (in
  frame 6, low-passed with ``mag_current_tau_s``) are compared with a learned
  reference (``mag_ref_tau_s``); outside ``mag_norm_th`` (relative) or
  ``mag_dip_th_deg`` the field is flagged as disturbed and ignored for up to
  ``mag_max_reject_s`` (then used with gain / ``mag_reject_factor``); it is
  accepted again after ``mag_min_undisturbed_s`` inside the bounds. A new field
  that stays steady for ``mag_new_s`` of motion (``mag_new_first_s`` when no
  reference exists yet) becomes the reference.

Filter coefficients use the nominal sample time ``ts`` (the median of the first
100 regular intervals of the first recording run, or the first positive ``dt`` of
``update``, or ``start(ts_s)``); the gyro
is integrated over the actual intervals. Intervals longer than ``max_dt_s`` are
gaps (gyro only). A zero accelerometer or magnetometer vector skips its update.

Signals of ``run``: ``bias_rad_s`` (N, 3), ``rest`` (bool), ``mag_disturbed``
(bool), ``acc_correction_rad_s`` (inclination correction rate: sine of the
correction angle / ts), ``hard_iron`` (N, 3) offset in use (magnetometer unit),
``mag_gain``
(heading gain used, 0 while rejected), ``acc_skipped``, ``mag_skipped``, ``gap``.

The readable per-sample ``update`` is the reference; ``run`` uses the numba
kernel ``gnomon.kernels.robust_ahrs`` (tested sample by sample against it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gnomon.errors import InputError
from gnomon.estimators.base import Estimate, Estimator, Params, param
from gnomon.recording import Recording
from gnomon.rotation import dcm_from_quat, quat_from_rotvec, quat_mul

__all__ = ["RobustAHRSParams", "RobustAHRS", "coefficients", "butter2", "new_state"]


@dataclass(frozen=True)
class RobustAHRSParams(Params):
    tau_acc_s: float = param(2.5, "s", "time constant of the accelerometer low-pass in the "
                             "almost-inertial frame (inclination correction)")
    tau_mag_s: float = param(30.0, "s", "time constant of the heading correction")
    rest_bias: bool = param(True, "", "rest detection and bias estimation at rest")
    motion_bias: bool = param(True, "", "bias estimation in motion (from the inclination "
                              "correction)")
    mag_rejection: bool = param(True, "", "magnetic disturbance detection and rejection")
    heading_kf: bool = param(True, "", "heading gain from a scalar Kalman filter: the "
                             "heading variance grows while the field is rejected, so the "
                             "heading recovers fast afterwards (steady gain: tau_mag_s)")
    heading_rate_noise_s: float = param(0.3, "s", "heading KF: heading random walk per "
                                        "rotation, variance rate q_r |w|^2 with q_r = this^2 "
                                        "(heading variance rate 1 without rotation), so fast "
                                        "motion raises the gain")
    mag_bias_gain_per_s: float = param(0.0, "1/s", "heading-rate bias loop: integral gain "
                                       "of the heading disagreement into the vertical bias "
                                       "(0: off)")
    bias_sigma_init_deg_s: float = param(0.5, "deg/s", "initial bias uncertainty (std)")
    bias_forgetting_s: float = param(100.0, "s", "time for the bias uncertainty to grow by "
                                     "0.1 deg/s")
    bias_clip_deg_s: float = param(2.0, "deg/s", "bound on the bias estimate and its "
                                   "innovations")
    bias_sigma_motion_deg_s: float = param(0.1, "deg/s", "bias measurement std in motion")
    bias_vertical_forgetting: float = param(1e-4, "", "vertical bias in motion: weight "
                                            "relative to the horizontal components")
    bias_sigma_rest_deg_s: float = param(0.03, "deg/s", "bias measurement std at rest")
    rest_min_s: float = param(1.5, "s", "minimum duration of a rest phase")
    rest_tau_s: float = param(0.5, "s", "low-pass time constant of the rest detection")
    rest_th_gyro_deg_s: float = param(2.0, "deg/s", "rest threshold on the gyro deviation")
    rest_th_acc_m_s2: float = param(0.5, "m/s^2", "rest threshold on the accelerometer "
                                    "deviation")
    mag_current_tau_s: float = param(0.05, "s", "low-pass of the field's norm and dip")
    mag_ref_tau_s: float = param(20.0, "s", "time constant of the learned field reference")
    mag_norm_th: float = param(0.1, "", "relative norm deviation that flags a disturbance")
    mag_dip_th_deg: float = param(10.0, "deg", "dip deviation that flags a disturbance")
    mag_new_s: float = param(20.0, "s", "steady new field accepted after this much motion")
    mag_new_first_s: float = param(5.0, "s", "same, when no reference exists yet")
    mag_new_min_gyro_deg_s: float = param(20.0, "deg/s", "rate counted as motion for a new "
                                          "field")
    mag_min_undisturbed_s: float = param(0.5, "s", "undisturbed time before the field is "
                                         "used again")
    mag_max_reject_s: float = param(60.0, "s", "longest full rejection of a disturbed field")
    mag_reject_factor: float = param(2.0, "", "gain divisor after that; rejection time "
                                     "recovers this much faster")
    max_dt_s: float = param(1.0, "s", "longer sample intervals are gaps: gyro only")
    mag_soft_norm: float = param(0.0, "", "soft de-weighting: relative norm deviation that "
                                 "doubles the heading measurement variance (0: off)")
    mag_soft_dip_deg: float = param(0.0, "deg", "soft de-weighting: dip deviation that "
                                    "doubles the heading measurement variance (0: off)")
    hard_iron_tau_s: float = param(3.0, "s", "online hard-iron offset estimation: time "
                                   "constant of its weighted window (0: off)")
    hard_iron_reg: float = param(0.05, "", "hard-iron prior weight (relative): offsets are "
                                 "only estimated where the rotation makes them observable")
    hard_iron_gate: float = param(0.2, "", "the offset is used only when it leaves less than "
                                  "this fraction of the field's variation in frame 6")
    mag_every: int = param(4, "samples", "the heading filter and the disturbance detection "
                           "run on the mean field of every k magnetometer samples (speed; 1: "
                           "every sample)")
    bias_every: int = param(4, "samples", "the bias Kalman filter (and its low-pass filters) "
                            "runs on every k-th accelerometer sample (speed; 1: every sample)")

    def validate(self):
        self._require("bias_every", self.bias_every >= 1, "must be >= 1")
        self._require("mag_every", self.mag_every >= 1, "must be >= 1")
        for name in ("tau_acc_s", "rest_tau_s", "bias_sigma_init_deg_s", "bias_forgetting_s",
                     "bias_clip_deg_s", "bias_sigma_motion_deg_s", "bias_sigma_rest_deg_s",
                     "max_dt_s", "mag_reject_factor", "bias_vertical_forgetting"):
            self._require(name, getattr(self, name) > 0, "must be > 0")
        for name in ("tau_mag_s", "rest_min_s", "rest_th_gyro_deg_s",
                     "rest_th_acc_m_s2", "mag_current_tau_s", "mag_ref_tau_s", "mag_norm_th",
                     "mag_dip_th_deg", "mag_new_s", "mag_new_first_s", "mag_soft_norm",
                     "mag_soft_dip_deg",
                     "mag_new_min_gyro_deg_s", "mag_min_undisturbed_s", "mag_max_reject_s"):
            self._require(name, getattr(self, name) >= 0, "must be >= 0")


# ---------------------------------------------------------------- state layout
def _layout(spec):
    out, off = {}, 0
    for name, size in spec:
        out[name] = off
        off += size
    return out, off


_S, STATE_SIZE = _layout([
    ("QG", 4), ("QA", 4), ("DELTA", 1), ("BIAS", 3), ("P", 9),
    ("ALP", 7), ("RLP", 19), ("BLP", 5), ("RG", 7), ("RG_OUT", 3), ("RA", 7), ("MN", 5),
    ("REST_T", 1), ("REST", 1), ("MAG_REF_NORM", 1), ("MAG_REF_DIP", 1),
    ("MAG_UNDIST_T", 1), ("MAG_REJECT_T", 1), ("CAND_NORM", 1), ("CAND_DIP", 1),
    ("CAND_T", 1), ("MAG_DIST", 1), ("K_MAG_INIT", 1), ("ACC_RATE", 1), ("K_MAG_USED", 1),
    ("MAG_DIS", 1), ("P_HEAD", 1), ("ROT2", 1), ("BIAS_CNT", 1), ("MAG_CNT", 1), ("MSUM", 3),
    ("HI_W", 1), ("HI_S", 9), ("HI_RM", 3), ("HI_M", 3), ("HI_O", 3), ("HI_MM", 1),
    ("HI_BM", 3), ("HI_BMM", 1),
    ("CD", 1), ("SD", 1),
])
S_QG, S_QA, S_DELTA, S_BIAS, S_P = _S["QG"], _S["QA"], _S["DELTA"], _S["BIAS"], _S["P"]
S_ALP, S_RLP, S_BLP, S_RG, S_RG_OUT = _S["ALP"], _S["RLP"], _S["BLP"], _S["RG"], _S["RG_OUT"]
S_RA, S_MN, S_REST_T, S_REST = _S["RA"], _S["MN"], _S["REST_T"], _S["REST"]
S_MAG_REF_NORM, S_MAG_REF_DIP = _S["MAG_REF_NORM"], _S["MAG_REF_DIP"]
S_MAG_UNDIST_T, S_MAG_REJECT_T = _S["MAG_UNDIST_T"], _S["MAG_REJECT_T"]
S_CAND_NORM, S_CAND_DIP, S_CAND_T = _S["CAND_NORM"], _S["CAND_DIP"], _S["CAND_T"]
S_MAG_DIST, S_K_MAG_INIT, S_ACC_RATE = _S["MAG_DIST"], _S["K_MAG_INIT"], _S["ACC_RATE"]
S_K_MAG_USED, S_MAG_DIS, S_P_HEAD = _S["K_MAG_USED"], _S["MAG_DIS"], _S["P_HEAD"]

_C, COEF_SIZE = _layout([
    ("TS", 1), ("ACC_LP", 5), ("REST_LP", 5), ("MAG_CUR_LP", 5), ("K_MAG", 1),
    ("K_MAG_REF", 1), ("BIAS_P0", 1), ("BIAS_V", 1), ("W_MOTION", 1), ("W_VERTICAL", 1),
    ("W_REST", 1), ("BIAS_CLIP", 1), ("REST_TH_GYRO2", 1), ("REST_TH_ACC2", 1),
    ("REST_MIN", 1), ("TAU_ACC", 1), ("TAU_REST", 1), ("TAU_MAG_CUR", 1), ("MAG_NORM_TH", 1),
    ("MAG_DIP_TH", 1), ("MAG_NEW", 1), ("MAG_NEW_FIRST", 1), ("MAG_NEW_MIN_GYRO", 1),
    ("MAG_MIN_UNDIST", 1), ("MAG_MAX_REJECT", 1), ("MAG_REJECT_FACTOR", 1), ("TAU_MAG", 1),
    ("MAX_DT", 1), ("REST_BIAS", 1), ("MOTION_BIAS", 1), ("MAG_REJECT", 1),
    ("K_MAG_BIAS", 1), ("HEADING_KF", 1), ("Q_HEAD", 1), ("Q_RATE", 1), ("R_HEAD", 1),
    ("BIAS_LP", 5), ("BIAS_EVERY", 1), ("TS_BIAS", 1), ("MAG_EVERY", 1), ("TS_MAG", 1),
    ("SOFT_N", 1), ("SOFT_D", 1), ("HI_LAMBDA", 1), ("HI_REG", 1), ("HI_GATE", 1),
])
C_TS, C_ACC_LP, C_REST_LP = _C["TS"], _C["ACC_LP"], _C["REST_LP"]
C_MAG_CUR_LP = _C["MAG_CUR_LP"]
C_K_MAG, C_K_MAG_REF = _C["K_MAG"], _C["K_MAG_REF"]
C_BIAS_P0, C_BIAS_V = _C["BIAS_P0"], _C["BIAS_V"]
C_W_MOTION, C_W_VERTICAL, C_W_REST = _C["W_MOTION"], _C["W_VERTICAL"], _C["W_REST"]
C_BIAS_CLIP = _C["BIAS_CLIP"]
C_REST_TH_GYRO2, C_REST_TH_ACC2 = _C["REST_TH_GYRO2"], _C["REST_TH_ACC2"]
C_REST_MIN, C_TAU_ACC, C_TAU_REST, C_TAU_MAG_CUR = (_C["REST_MIN"], _C["TAU_ACC"], _C["TAU_REST"],
                                                   _C["TAU_MAG_CUR"])
C_MAG_NORM_TH, C_MAG_DIP_TH, C_MAG_NEW = _C["MAG_NORM_TH"], _C["MAG_DIP_TH"], _C["MAG_NEW"]
C_MAG_NEW_FIRST, C_MAG_NEW_MIN_GYRO = _C["MAG_NEW_FIRST"], _C["MAG_NEW_MIN_GYRO"]
C_MAG_MIN_UNDIST, C_MAG_MAX_REJECT = _C["MAG_MIN_UNDIST"], _C["MAG_MAX_REJECT"]
C_MAG_REJECT_FACTOR, C_TAU_MAG, C_MAX_DT = _C["MAG_REJECT_FACTOR"], _C["TAU_MAG"], _C["MAX_DT"]
C_REST_BIAS, C_MOTION_BIAS, C_MAG_REJECT = _C["REST_BIAS"], _C["MOTION_BIAS"], _C["MAG_REJECT"]
C_K_MAG_BIAS, C_HEADING_KF, C_Q_HEAD = _C["K_MAG_BIAS"], _C["HEADING_KF"], _C["Q_HEAD"]
C_Q_RATE, S_ROT2, S_BIAS_CNT = _C["Q_RATE"], _S["ROT2"], _S["BIAS_CNT"]
C_R_HEAD = _C["R_HEAD"]
C_BIAS_LP, C_BIAS_EVERY, C_TS_BIAS = _C["BIAS_LP"], _C["BIAS_EVERY"], _C["TS_BIAS"]
C_MAG_EVERY, C_TS_MAG, S_MAG_CNT = _C["MAG_EVERY"], _C["TS_MAG"], _S["MAG_CNT"]
S_CD, S_SD, S_MSUM = _S["CD"], _S["SD"], _S["MSUM"]
C_SOFT_N, C_SOFT_D = _C["SOFT_N"], _C["SOFT_D"]
S_HI_W, S_HI_S, S_HI_RM = _S["HI_W"], _S["HI_S"], _S["HI_RM"]
S_HI_M, S_HI_O, S_HI_MM = _S["HI_M"], _S["HI_O"], _S["HI_MM"]
S_HI_BM, S_HI_BMM = _S["HI_BM"], _S["HI_BMM"]
C_HI_LAMBDA, C_HI_REG, C_HI_GATE = _C["HI_LAMBDA"], _C["HI_REG"], _C["HI_GATE"]


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


def _gain(tau_s: float, ts_s: float) -> float:
    """First-order filter gain ``1 - exp(-ts/τ)`` (τ = 0: 1)."""
    return 1.0 if tau_s <= 0 else 1.0 - math.exp(-ts_s / tau_s)


def coefficients(p: RobustAHRSParams, ts_s: float) -> np.ndarray:
    """The kernel's coefficient vector for parameters ``p`` and nominal sample time ``ts_s``."""
    c = np.zeros(COEF_SIZE)
    d2r = math.pi / 180.0
    c[C_TS] = ts_s
    c[C_ACC_LP:C_ACC_LP + 5] = butter2(p.tau_acc_s, ts_s)
    c[C_REST_LP:C_REST_LP + 5] = butter2(p.rest_tau_s, ts_s)
    # the heading filter runs every mag_every samples: its gains are for that interval
    tsm = ts_s * p.mag_every
    c[C_TS_MAG] = tsm
    c[C_MAG_EVERY] = p.mag_every
    c[C_HI_LAMBDA] = math.exp(-tsm / p.hard_iron_tau_s) if p.hard_iron_tau_s > 0 else 0.0
    c[C_HI_REG] = p.hard_iron_reg
    c[C_HI_GATE] = p.hard_iron_gate
    c[C_SOFT_N] = 1.0 / p.mag_soft_norm ** 2 if p.mag_soft_norm > 0 else 0.0
    c[C_SOFT_D] = 1.0 / (p.mag_soft_dip_deg * d2r) ** 2 if p.mag_soft_dip_deg > 0 else 0.0
    c[C_MAG_CUR_LP:C_MAG_CUR_LP + 5] = butter2(p.mag_current_tau_s, tsm)
    c[C_K_MAG] = _gain(p.tau_mag_s, tsm)
    c[C_K_MAG_REF] = _gain(p.mag_ref_tau_s, tsm)
    c[C_BIAS_P0] = (p.bias_sigma_init_deg_s * d2r) ** 2
    # process noise: the variance grows by (0.1 deg/s)^2 in bias_forgetting_s
    # the bias filter runs every bias_every samples: its own low-pass and noise per update
    ts_b = ts_s * p.bias_every
    c[C_TS_BIAS] = ts_b
    c[C_BIAS_EVERY] = p.bias_every
    c[C_BIAS_LP:C_BIAS_LP + 5] = butter2(p.tau_acc_s, ts_b)
    c[C_BIAS_V] = (0.1 * d2r) ** 2 * ts_b / p.bias_forgetting_s
    # measurement variance chosen so that the steady-state std is the stated sigma
    pm = (p.bias_sigma_motion_deg_s * d2r) ** 2
    c[C_W_MOTION] = pm * pm / c[C_BIAS_V] + pm
    c[C_W_VERTICAL] = c[C_W_MOTION] / p.bias_vertical_forgetting
    pr = (p.bias_sigma_rest_deg_s * d2r) ** 2
    c[C_W_REST] = pr * pr / c[C_BIAS_V] + pr
    c[C_BIAS_CLIP] = p.bias_clip_deg_s * d2r
    c[C_REST_TH_GYRO2] = (p.rest_th_gyro_deg_s * d2r) ** 2
    c[C_REST_TH_ACC2] = p.rest_th_acc_m_s2 ** 2
    c[C_REST_MIN] = p.rest_min_s
    c[C_TAU_ACC] = p.tau_acc_s
    c[C_TAU_REST] = p.rest_tau_s
    c[C_TAU_MAG_CUR] = p.mag_current_tau_s
    c[C_MAG_NORM_TH] = p.mag_norm_th
    c[C_MAG_DIP_TH] = p.mag_dip_th_deg * d2r
    c[C_MAG_NEW] = p.mag_new_s
    c[C_MAG_NEW_FIRST] = p.mag_new_first_s
    c[C_MAG_NEW_MIN_GYRO] = p.mag_new_min_gyro_deg_s * d2r
    c[C_MAG_MIN_UNDIST] = p.mag_min_undisturbed_s
    c[C_MAG_MAX_REJECT] = p.mag_max_reject_s
    c[C_MAG_REJECT_FACTOR] = p.mag_reject_factor
    c[C_TAU_MAG] = p.tau_mag_s
    c[C_MAX_DT] = p.max_dt_s
    c[C_REST_BIAS] = float(p.rest_bias)
    c[C_MOTION_BIAS] = float(p.motion_bias)
    c[C_MAG_REJECT] = float(p.mag_rejection)
    c[C_K_MAG_BIAS] = p.mag_bias_gain_per_s
    c[C_HEADING_KF] = float(p.heading_kf)
    # heading KF in units where the heading variance grows at rate 1 (per s) at rest: the
    # measurement variance per update is tau_mag² / tsm (steady-state time constant tau_mag),
    # the random walk per update is chosen so that the steady-state gain is exactly k_mag
    k = c[C_K_MAG]
    c[C_R_HEAD] = p.tau_mag_s ** 2 / tsm if p.tau_mag_s > 0 else 1.0
    c[C_Q_HEAD] = c[C_R_HEAD] * k * k / (1.0 - k) if k < 1.0 else 1e12
    c[C_Q_RATE] = p.heading_rate_noise_s ** 2
    return c


def new_state(p: RobustAHRSParams) -> np.ndarray:
    """A fresh filter state (flat array, layout ``S_*``)."""
    s = np.zeros(STATE_SIZE)
    s[S_QG] = 1.0
    s[S_QA] = 1.0
    s[S_P:S_P + 9] = np.eye(3).ravel() * (p.bias_sigma_init_deg_s * math.pi / 180.0) ** 2
    s[S_MAG_DIST] = 1.0
    s[S_MAG_REJECT_T] = p.mag_max_reject_s
    s[S_CAND_NORM] = -1.0
    s[S_K_MAG_INIT] = 1.0
    s[S_P_HEAD] = 1e6
    s[S_CD] = 1.0
    return s


# ---------------------------------------------------------------- readable reference
class _LowPass:
    """Readable twin of the kernel's ``_lp`` on a slice of the flat state."""

    def __init__(self, s, off, n, b, tau, ts):
        self.s, self.off, self.n, self.b, self.tau, self.ts = s, off, n, b, tau, ts

    def __call__(self, x):
        s, o, n = self.s, self.off, self.n
        b0, b1, b2, a1, a2 = self.b
        z0 = s[o:o + n]           # views into the state
        z1 = s[o + n:o + 2 * n]
        if s[o + 2 * n] >= 0.0:   # start-up: running mean
            s[o + 2 * n] += 1.0
            z0 += x
            y = z0 / s[o + 2 * n]
            if s[o + 2 * n] * self.ts >= self.tau:
                z0[:] = y * (1.0 - b0)
                z1[:] = y * (b2 - a2)
                s[o + 2 * n] = -1.0
            return y
        y = b0 * x + z0
        z0[:] = b1 * x - a1 * y + z1
        z1[:] = b2 * x - a2 * y
        return y


def _wrap(a):
    return a - 2 * math.pi if a > math.pi else (a + 2 * math.pi if a < -math.pi else a)


class RobustAHRS(Estimator):
    """Decoupled 9-axis AHRS with rest/motion bias estimation and magnetic rejection (ENU)."""

    name = "robust-ahrs"
    summary = ("Decoupled AHRS (VQF structure): inertial-frame accelerometer filter, rest and "
               "motion bias KF, heading-only magnetometer with disturbance rejection, heading "
               "Kalman gain, online hard-iron offset")
    Params = RobustAHRSParams
    needs = ("gyro", "accel", "mag")
    state_fields = ("s", "ts", "t_last")

    def reset(self) -> None:
        self.s = new_state(self.params)  # flat state, layout S_*
        self.ts = None  # s, nominal sample time of the filter coefficients
        self.t_last = None  # s, time of the last sample processed by ``run``

    def start(self, ts_s: float) -> None:
        """Fix the nominal sample time (s) used for the filter coefficients."""
        if not (ts_s > 0 and math.isfinite(ts_s)):
            raise InputError(f"sample time must be > 0, got {ts_s!r}", field="ts_s")
        self.ts = float(ts_s)

    # views of the state
    @property
    def q(self) -> np.ndarray:
        """Current ``q_nb`` (ENU from body)."""
        q6 = quat_mul(self.s[S_QA:S_QA + 4], self.s[S_QG:S_QG + 4])
        return quat_mul(np.array([self.s[S_CD], 0.0, 0.0, self.s[S_SD]]), q6)

    @property
    def bias(self) -> np.ndarray:
        return self.s[S_BIAS:S_BIAS + 3].copy()

    def update(self, dt_s: float, gyro, acc, mag) -> np.ndarray:
        """One sample: ``gyro`` rad/s, ``acc`` m/s², ``mag`` any unit (body). Returns ``q_nb``."""
        if self.ts is None:
            if not dt_s > 0:
                raise InputError("call start(ts_s) first or pass dt_s > 0", field="dt_s")
            self.start(dt_s)
        p, s, ts = self.params, self.s, self.ts
        c = coefficients(p, ts)
        self.flags = {"acc_skipped": False, "mag_skipped": False, "gap": False}
        g = np.asarray(gyro, float)
        a = np.asarray(acc, float)
        m = np.asarray(mag, float)
        clip = c[C_BIAS_CLIP]
        bias = s[S_BIAS:S_BIAS + 3]  # view
        # rest detection (gyro)
        if p.rest_bias or p.mag_rejection:
            g_lp = _LowPass(s, S_RG, 3, c[C_REST_LP:C_REST_LP + 5], p.rest_tau_s, ts)(g)
            s[S_RG_OUT:S_RG_OUT + 3] = g_lp
            dev = g - g_lp
            if dev @ dev >= c[C_REST_TH_GYRO2] or np.max(np.abs(g_lp)) > clip:
                s[S_REST_T] = 0.0
                s[S_REST] = 0.0
        # strapdown
        if dt_s > 0.0:
            s[S_ROT2] += float((g - bias) @ (g - bias)) * dt_s  # ∫|ω|² dt
        if dt_s > 0.0 and np.any(g != bias):
            s[S_QG:S_QG + 4] = _normalise(quat_mul(s[S_QG:S_QG + 4],
                                                   quat_from_rotvec((g - bias) * dt_s)))
        if dt_s > p.max_dt_s:
            self.flags["gap"] = True
            return self.q
        # accelerometer
        if a @ a > 0.0:
            if p.rest_bias:
                a_lp = _LowPass(s, S_RA, 3, c[C_REST_LP:C_REST_LP + 5], p.rest_tau_s, ts)(a)
                dev = a - a_lp
                if dev @ dev >= c[C_REST_TH_ACC2]:
                    s[S_REST_T] = 0.0
                    s[S_REST] = 0.0
                else:
                    s[S_REST_T] += ts
                    if s[S_REST_T] >= p.rest_min_s:
                        s[S_REST] = 1.0
            acc_lp = _LowPass(s, S_ALP, 3, c[C_ACC_LP:C_ACC_LP + 5], p.tau_acc_s, ts)(
                dcm_from_quat(s[S_QG:S_QG + 4]) @ a)
            f = dcm_from_quat(s[S_QA:S_QA + 4]) @ acc_lp
            nf = np.linalg.norm(f)
            if nf > 0.0:
                f = f / nf
                cw = math.sqrt(max(0.5 * (f[2] + 1.0), 0.0))
                corr = (np.array([cw, 0.5 * f[1] / cw, -0.5 * f[0] / cw, 0.0]) if cw > 1e-6
                        else np.array([0.0, 1.0, 0.0, 0.0]))
                s[S_QA:S_QA + 4] = _normalise(quat_mul(corr, s[S_QA:S_QA + 4]))
                s[S_ACC_RATE] = math.hypot(f[0], f[1]) / ts  # sin(correction angle) / ts
            run_bias = s[S_BIAS_CNT] == 0.0
            s[S_BIAS_CNT] = (s[S_BIAS_CNT] + 1.0) % p.bias_every
            if (p.rest_bias or p.motion_bias) and run_bias:
                ts_b = c[C_TS_BIAS]
                R = dcm_from_quat(quat_mul(s[S_QA:S_QA + 4], s[S_QG:S_QG + 4]))
                rb = (R @ bias)[:2]
                R_lp = _LowPass(s, S_RLP, 9, c[C_BIAS_LP:C_BIAS_LP + 5], p.tau_acc_s, ts_b)(
                    R.ravel()).reshape(3, 3)
                rb_lp = _LowPass(s, S_BLP, 2, c[C_BIAS_LP:C_BIAS_LP + 5], p.tau_acc_s, ts_b)(rb)
                P = s[S_P:S_P + 9].reshape(3, 3)  # view
                for i in range(3):
                    if P[i, i] < c[C_BIAS_P0]:
                        P[i, i] += c[C_BIAS_V]
                H = e = w = None
                if p.rest_bias and s[S_REST] != 0.0:
                    H, e = np.eye(3), s[S_RG_OUT:S_RG_OUT + 3] - bias
                    w = np.full(3, c[C_W_REST])
                elif p.motion_bias and nf > 0.0:
                    H = R_lp
                    e = np.array([-f[1] / ts + rb_lp[0], f[0] / ts + rb_lp[1], 0.0]) - R_lp @ bias
                    w = np.array([c[C_W_MOTION], c[C_W_MOTION], c[C_W_VERTICAL]])
                if H is not None:
                    e = np.clip(e, -clip, clip)
                    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + np.diag(w))
                    bias[:] = np.clip(bias + K @ e, -clip, clip)
                    P -= K @ H @ P
                    P[:] = 0.5 * (P + P.T)  # symmetric against rounding over long runs
        else:
            self.flags["acc_skipped"] = True
        # magnetometer: heading only
        run_mag = False
        if m @ m > 0.0:
            R6 = dcm_from_quat(quat_mul(s[S_QA:S_QA + 4], s[S_QG:S_QG + 4]))
            if c[C_HI_LAMBDA] > 0.0:  # hard-iron block sums of the raw field
                s[S_HI_BM:S_HI_BM + 3] += m
                s[S_HI_BMM] += m @ m
                m = m - s[S_HI_O:S_HI_O + 3]
            # field in frame 6, averaged over mag_every samples (the first sample at once)
            s[S_MSUM:S_MSUM + 3] += R6 @ m
            s[S_MAG_CNT] += 1.0
            run_mag = s[S_MAG_CNT] >= p.mag_every or s[S_K_MAG_INIT] == 1.0
        if m @ m > 0.0 and not run_mag:
            pass  # accumulating: the heading filter runs on every mag_every-th sample
        elif m @ m > 0.0:
            tsm = c[C_TS_MAG]
            cnt = s[S_MAG_CNT]
            m6 = s[S_MSUM:S_MSUM + 3] / cnt
            lam = c[C_HI_LAMBDA]
            if lam > 0.0:  # weighted sums per block, R at the block's end
                R6 = dcm_from_quat(quat_mul(s[S_QA:S_QA + 4], s[S_QG:S_QG + 4]))
                s[S_HI_W] = lam * s[S_HI_W] + cnt
                s[S_HI_S:S_HI_S + 9] = lam * s[S_HI_S:S_HI_S + 9] + cnt * R6.ravel()
                s[S_HI_RM:S_HI_RM + 3] = (lam * s[S_HI_RM:S_HI_RM + 3] + s[S_MSUM:S_MSUM + 3]
                                          + cnt * (R6 @ s[S_HI_O:S_HI_O + 3]))
                s[S_HI_M:S_HI_M + 3] = lam * s[S_HI_M:S_HI_M + 3] + s[S_HI_BM:S_HI_BM + 3]
                s[S_HI_MM] = lam * s[S_HI_MM] + s[S_HI_BMM]
                s[S_HI_BM:S_HI_BM + 4] = 0.0
                s[S_HI_O:S_HI_O + 3] = self._hard_iron(c)
            s[S_MSUM:S_MSUM + 3] = 0.0
            s[S_MAG_CNT] = 0.0
            if p.mag_rejection:
                soft = self._mag_disturbance(m6, c, tsm)
            else:
                soft = 1.0
            dis = _wrap(math.atan2(m6[0], m6[1]) - s[S_DELTA])
            s[S_MAG_DIS] = dis
            k = c[C_K_MAG]
            r_head = c[C_R_HEAD]  # heading measurement variance
            if p.heading_kf:
                s[S_P_HEAD] += c[C_Q_HEAD] + c[C_Q_RATE] * s[S_ROT2]
            s[S_ROT2] = 0.0
            if p.mag_rejection:
                if s[S_MAG_DIST] != 0.0:
                    if s[S_MAG_REJECT_T] <= p.mag_max_reject_s:
                        s[S_MAG_REJECT_T] += tsm
                        k = 0.0
                        r_head = 0.0
                    else:
                        k /= p.mag_reject_factor
                        r_head = c[C_R_HEAD] * p.mag_reject_factor ** 2
                else:
                    s[S_MAG_REJECT_T] = max(s[S_MAG_REJECT_T] - p.mag_reject_factor * tsm, 0.0)
            k /= soft  # soft de-weighting by the field's distance from the reference
            r_head *= soft
            if p.heading_kf and r_head > 0.0:
                k = s[S_P_HEAD] / (s[S_P_HEAD] + r_head)
                s[S_P_HEAD] *= 1.0 - k
            ki = s[S_K_MAG_INIT]
            if ki != 0.0:  # running mean at start: gain at least 1/k
                if k < ki:
                    k = ki
                    s[S_P_HEAD] = ki * c[C_R_HEAD]
                ki = ki / (ki + 1.0)
                s[S_K_MAG_INIT] = 0.0 if ki * p.tau_mag_s < tsm else ki
            s[S_K_MAG_USED] = k
            s[S_DELTA] = _wrap(s[S_DELTA] + k * dis)
            s[S_CD] = math.cos(0.5 * s[S_DELTA])
            s[S_SD] = math.sin(0.5 * s[S_DELTA])
            if p.mag_bias_gain_per_s > 0.0 and k > 0.0 and s[S_K_MAG_INIT] == 0.0:
                up_b = dcm_from_quat(quat_mul(s[S_QA:S_QA + 4], s[S_QG:S_QG + 4]))[2]
                db = p.mag_bias_gain_per_s * (k / c[C_K_MAG]) * dis * tsm
                bias[:] = np.clip(bias + db * up_b, -clip, clip)
        else:
            self.flags["mag_skipped"] = True
        return self.q

    def _hard_iron(self, c) -> np.ndarray:
        """Hard-iron offset ``o`` (body) from the weighted sums (readable).

        Least squares of ``R_6b m = h + R_6b o`` over the window (``h`` fixed in frame 6)
        with the prior ``reg·w·|o|²``: ``(w²(1+reg) I - SᵀS) o = w Σm - Sᵀ Σ R m`` with
        ``S = Σ R``, ``w = Σ 1``. Used only if it leaves less than ``hard_iron_gate`` of the
        residual energy without an offset (``h`` = the mean of ``R m``); else zero.
        """
        s = self.s
        w = s[S_HI_W]
        S = s[S_HI_S:S_HI_S + 9].reshape(3, 3)
        rm, msum, mm = s[S_HI_RM:S_HI_RM + 3], s[S_HI_M:S_HI_M + 3], s[S_HI_MM]
        A = w * w * (1.0 + c[C_HI_REG]) * np.eye(3) - S.T @ S
        if np.linalg.det(A) <= 0.0:
            return s[S_HI_O:S_HI_O + 3].copy()
        o = np.linalg.solve(A, w * msum - S.T @ rm)
        h = (rm - S @ o) / w
        e0 = mm - rm @ rm / w
        e1 = mm - h @ rm - o @ msum
        return o if e1 < c[C_HI_GATE] * e0 else np.zeros(3)

    def _mag_disturbance(self, m6, c, ts) -> float:
        """Norm/dip test against the learned reference; new-field acceptance (readable).

        Returns the soft de-weighting factor ``1 + (Δnorm/norm/σ_n)² + (Δdip/σ_d)²``."""
        p, s = self.params, self.s
        nm = float(np.linalg.norm(m6))
        cur = _LowPass(s, S_MN, 2, c[C_MAG_CUR_LP:C_MAG_CUR_LP + 5], p.mag_current_tau_s, ts)(
            np.array([nm, -math.asin(min(max(m6[2] / nm, -1.0), 1.0))]))
        kref = c[C_K_MAG_REF]
        dip_th = c[C_MAG_DIP_TH]
        ref_n = s[S_MAG_REF_NORM]
        if abs(cur[0] - ref_n) < p.mag_norm_th * ref_n and abs(cur[1] - s[S_MAG_REF_DIP]) < dip_th:
            s[S_MAG_UNDIST_T] += ts
            if s[S_MAG_UNDIST_T] >= p.mag_min_undisturbed_s:
                s[S_MAG_DIST] = 0.0
                s[S_MAG_REF_NORM] += kref * (cur[0] - ref_n)
                s[S_MAG_REF_DIP] += kref * (cur[1] - s[S_MAG_REF_DIP])
        else:
            s[S_MAG_UNDIST_T] = 0.0
            s[S_MAG_DIST] = 1.0
        cand_n = s[S_CAND_NORM]
        if abs(cur[0] - cand_n) < p.mag_norm_th * cand_n and abs(cur[1] - s[S_CAND_DIP]) < dip_th:
            g_lp = s[S_RG_OUT:S_RG_OUT + 3]
            if g_lp @ g_lp >= c[C_MAG_NEW_MIN_GYRO] ** 2:
                s[S_CAND_T] += ts
            s[S_CAND_NORM] += kref * (cur[0] - cand_n)
            s[S_CAND_DIP] += kref * (cur[1] - s[S_CAND_DIP])
            if s[S_MAG_DIST] != 0.0 and (s[S_CAND_T] >= p.mag_new_s or (
                    s[S_MAG_REF_NORM] == 0.0 and s[S_CAND_T] >= p.mag_new_first_s)):
                s[S_MAG_REF_NORM] = s[S_CAND_NORM]
                s[S_MAG_REF_DIP] = s[S_CAND_DIP]
                s[S_MAG_DIST] = 0.0
                s[S_MAG_UNDIST_T] = p.mag_min_undisturbed_s
        else:
            s[S_CAND_T] = 0.0
            s[S_CAND_NORM] = cur[0]
            s[S_CAND_DIP] = cur[1]
        if s[S_MAG_REF_NORM] > 0.0:
            dn = (cur[0] - s[S_MAG_REF_NORM]) / s[S_MAG_REF_NORM]
            dd = cur[1] - s[S_MAG_REF_DIP]
            return 1.0 + c[C_SOFT_N] * dn * dn + c[C_SOFT_D] * dd * dd
        return 1.0

    def run(self, rec: Recording) -> Estimate:
        """Whole recording through the compiled kernel; ``rec.frames['reference']`` must be ENU."""
        from gnomon.kernels.robust_ahrs import robust_ahrs_batch

        self.check_inputs(rec)
        n = len(rec)
        dt = np.empty(n)
        dt[0] = self.first_dt(rec)
        dt[1:] = np.diff(rec.t)
        if self.ts is None:
            # nominal sample time: median of the first (up to) 100 regular intervals, so
            # that a run split after 100 samples resumes exactly
            pos = dt[(dt > 0) & (dt <= self.params.max_dt_s)][:100]
            self.start(float(np.median(pos)) if pos.size else 0.01)
        c = coefficients(self.params, self.ts)
        out = {"q": np.empty((n, 4)), "bias": np.empty((n, 3)), "rest": np.empty(n, np.bool_),
               "dist": np.empty(n, np.bool_), "acc_rate": np.empty(n), "k_mag": np.empty(n),
               "hi": np.empty((n, 3)),
               "flags": np.empty(n, np.int64)}
        # strided views are fine for the kernel (no copy)
        robust_ahrs_batch(dt, np.asarray(rec.gyro, dtype=float),
                          np.asarray(rec.accel, dtype=float),
                          np.asarray(rec.mag, dtype=float), self.s, c, out["q"],
                          out["bias"], out["rest"], out["dist"], out["acc_rate"], out["k_mag"],
                          out["hi"], out["flags"])
        self.t_last = float(rec.t[-1])
        f = out["flags"]
        return Estimate(
            t=rec.t, q=out["q"], estimator=self.name, params=self.params.as_dict(),
            frames={"reference": rec.frames.get("reference", "ENU"), "body": "sensor"},
            signals={"bias_rad_s": out["bias"], "rest": out["rest"],
                     "mag_disturbed": out["dist"], "acc_correction_rad_s": out["acc_rate"],
                     "mag_gain": out["k_mag"], "hard_iron": out["hi"],
                     "acc_skipped": (f & 1) != 0,
                     "mag_skipped": (f & 2) != 0, "gap": (f & 4) != 0},
        )


def _normalise(q):
    return q / np.linalg.norm(q)
