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
  ``rest_th_gyro_deg_s`` / ``rest_th_acc_m_s2`` for ``rest_min_s`` and the low-passed
  rate is within ``bias_clip_deg_s``. A steady rate farther than ``rest_th_rate_deg_s``
  from the bias estimate (measured on the bias-corrected rate, so a large but estimated
  bias does not prevent a rest) is either a large bias not yet estimated or a slow
  rotation: it counts as rest only after ``rest_min_large_bias_s``, and only when the
  gyro (minus the bias) says the accelerometer or the magnetometer direction would have
  turned by at least twice ``rest_th_turn_deg`` in the body frame meanwhile. A rest
  ends, and a rest candidacy begins anew, whenever the low-passed accelerometer or
  magnetometer direction turns by more than ``rest_th_turn_deg`` from where it was when
  the candidacy began: a steady turn (a turntable, a drone yawing, a car on a
  roundabout) has a constant gyro and, about the vertical, a constant accelerometer,
  but its magnetometer turns, so it is not rest and the bias does not absorb its rate
  (``tests/test_steady_turn.py``). A turn about the field and gravity both (no
  magnetometer sample, a turn about the vertical) cannot be told from a bias: no rest.
* **First-rest reset** (``rest_reset``): until the first rest the gyro bias is unknown
  and the estimate drifts; the running means of the start-up (accelerometer in I,
  heading) keep that drift for seconds (the heading for about ``tau_mag_s``). The
  first rest while the heading is still starting (its first ``tau_mag_s``; without a
  magnetometer, the first rest) restarts the accelerometer low-pass in I settled at
  the rest's low-passed specific force (the inclination follows at once) and sets the
  heading to the rest's low-passed field (hard-iron offset removed) seen in frame 6.
  A later first rest changes nothing: after the start-up the heading trusts the field
  only through ``tau_mag_s`` and the disturbance tests, which a reset would bypass.
* **Gyro bias** (3-state Kalman filter, rad/s): at rest the measurement is the
  low-passed gyro (``H = I``, std ``bias_sigma_rest_deg_s``); in motion
  (``motion_bias``) the inclination correction is the measurement of the
  horizontal components of ``R_6b b`` (both sides low-passed like the
  accelerometer), std ``bias_sigma_motion_deg_s``, with Huber weights beyond
  ``bias_huber_deg_s`` (a larger innovation pulls like one of that size, and the
  covariance shrinks less, so a large initial bias still converges); the vertical
  component is only weakly pulled to zero (``bias_vertical_forgetting``). The
  covariance grows so that the uncertainty reaches 0.1 deg/s after
  ``bias_forgetting_s``. The estimate is bounded by ``bias_clip_deg_s`` (15 deg/s:
  uncalibrated phone gyros reach 6 deg/s; VQF's 2 deg/s would hold such a bias at the
  bound); ``bias_at_limit`` says when it is there.
* **Heading** (``tau_mag_s``): the magnetometer, seen in frame 6, gives the
  heading disagreement ``atan2(m_E, m_N) - δ``; ``δ`` follows it with a
  first-order filter. The magnetometer never touches the inclination. During
  the first ``tau_mag_s`` seconds the gain is at least ``1/k`` (running mean).
* **Heading Kalman gain** (``heading_kf``, ``heading_rate_noise_s``, gnomon's
  addition): ``δ`` has a scalar variance that grows at rate 1/s plus
  ``heading_rate_noise_s² |ω|²`` and is reduced by each heading update with
  measurement variance ``tau_mag_s² / T`` (steady gain = the first-order gain of
  ``tau_mag_s`` at rest). While the field is rejected the variance grows, so the
  heading recovers fast afterwards; fast rotation raises the gain too. The rate-1
  growth is multiplied by ``1 + σ_v² / heading_bias_ref_deg_s²``, ``σ_v² = uᵀ P u`` the
  variance of the bias estimate about the vertical (``u`` = up in body, ``P`` the bias
  filter's covariance): an unknown bias turns the heading, so where the bias is known
  only to its prior (no rest phase yet) the heading follows the magnetometer faster,
  and after a rest with ``tau_mag_s``.
* **Online hard-iron offset** (``hard_iron_tau_s``, gnomon's addition): with a
  magnet fixed to the sensor, ``R_6b m = h + R_6b o`` with ``h`` fixed in frame 6.
  Exponentially weighted sums (window ``hard_iron_tau_s``) give the least-squares
  ``o`` in closed form, ``(w²(1+reg) I - SᵀS) o = w Σm - Sᵀ Σ R m`` (``S = Σ R``,
  prior ``hard_iron_reg``; every sum over the samples, each with its own ``R_6b``).
  ``o`` is subtracted from the magnetometer only while it explains the field
  (residual energy below ``hard_iron_gate`` of the residual without an offset); a
  field that varies in space is not explained by a body-fixed offset and leaves
  ``o = 0``.
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
  reference exists yet) becomes the reference. A field inside the bounds whose
  heading disagrees with the estimate by more than ``mag_heading_dis_deg`` is a
  disturbance too (gnomon's addition; after the heading's start-up): a disturbed
  field can pass the norm and dip tests while it points elsewhere (a room whose
  field turns by tens of degrees, or a field back in the bounds but turned away),
  and the heading gain is high after a long rejection. The gyro drifts far less
  than that while a rejection lasts, so the test holds the field back for at most
  ``mag_max_reject_s``.

Filter coefficients use nominal sample times ``ts`` = (gyro, accelerometer,
magnetometer): for ``run`` the median of the first 100 regular intervals of each
sensor of the first recording run (every sensor at its own rate: a row without a new
sample of a sensor skips its phase; ``prepare(rec)`` sets the same times); for
``update`` and ``update_many`` the first sample's ``dt`` (> 0) or
``start(ts_s, accel_ts_s, mag_ts_s)``. The gyro is integrated over the actual intervals.
Intervals longer than ``max_dt_s`` are gaps (gyro only). Streaming
``update(dt_s, gyro_rad_s, accel_m_s2=None, mag_uT=None)`` (one sample) and
``update_many`` (a buffer of them), both compiled, on the filter's own state: ``None``
(or a zero vector, as in a recording, or one with a non-finite component) is no new
sample of that sensor and skips its phase; a non-finite gyro sample raises and changes
nothing. ``prepare(rec)`` sets the sample times ``run(rec)`` would, so that the rows of
``rec`` fed through ``update``/``update_many`` in any split give ``run``'s result.

Signals of ``run``: ``bias_rad_s`` (N, 3), ``bias_at_limit`` (bool: a component of the
bias estimate is at ``bias_clip_deg_s``; the true bias may be larger, ``gnomon estimate``
warns), ``rest`` (bool), ``mag_disturbed``
(bool), ``acc_correction_rad_s`` (inclination correction rate: sine of the
correction angle / ts), ``hard_iron`` (N, 3) offset in use (magnetometer unit),
``mag_gain``
(heading gain used, 0 while rejected), ``acc_skipped``, ``mag_skipped``, ``gap``.

Design: the coefficients (``Coefficients``, a named tuple from
``coefficients(params, ts)``) and the state (one record of the structured dtype
``STATE``, fresh from ``new_state(params)``; low-pass filters and hard-iron sums are
nested records) are defined in the kernel module ``gnomon.kernels.robust_ahrs``, which
knows nothing of this one. The filter holds the state as ``self.state``, an array of one
record (``record`` is its attribute view; ``get_state``/``set_state`` save and restore
it with ``ts`` and ``t_last``). The readable per-sample ``update_reference`` is the
reference: it runs the kernel's phases (rest detection, strapdown, inclination, bias
Kalman filter, magnetometer: hard iron, disturbance, heading) written with numpy, below,
on the same record; ``update``, ``update_many`` and ``run`` use the compiled kernel
(tested sample by sample against it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from gnomon.errors import InputError
from gnomon.estimators.base import (
    CompiledIMUUpdate,
    Estimate,
    Estimator,
    Params,
    imu_buffer,
    param,
)
from gnomon.kernels.entry import BAD_GYRO, record
from gnomon.kernels.robust_ahrs import (
    ACC_SKIPPED,
    BIAS_AT_LIMIT,
    GAP,
    MAG_SKIPPED,
    Coefficients,
    butter2,
    coefficients,
    new_state,
)
from gnomon.recording import Recording
from gnomon.rotation import dcm_from_quat, quat_from_rotvec, quat_mul

__all__ = ["RobustAHRSParams", "RobustAHRS", "coefficients", "butter2", "new_state"]


@dataclass(frozen=True)
class RobustAHRSParams(Params):
    renamed: ClassVar[dict[str, str]] = {"mag_return_dis_deg": "mag_heading_dis_deg"}

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
    heading_bias_ref_deg_s: float = param(0.05, "deg/s", "heading KF: its random walk is "
                                          "multiplied by 1 + (sigma_bv / this)^2, sigma_bv "
                                          "the std of the bias estimate about the vertical "
                                          "(an unknown bias turns the heading; 0: off)")
    mag_bias_gain_per_s: float = param(0.0, "1/s", "heading-rate bias loop: integral gain "
                                       "of the heading disagreement into the vertical bias "
                                       "(0: off)")
    bias_sigma_init_deg_s: float = param(0.5, "deg/s", "initial bias uncertainty (std)")
    bias_forgetting_s: float = param(100.0, "s", "time for the bias uncertainty to grow by "
                                     "0.1 deg/s")
    bias_clip_deg_s: float = param(15.0, "deg/s", "bound on the bias estimate (signal "
                                   "bias_at_limit when reached) and on the low-passed rate "
                                   "of a rest phase")
    bias_huber_deg_s: float = param(2.0, "deg/s", "bias filter in motion: an innovation "
                                    "component beyond this has its variance scaled by "
                                    "|e|/this (Huber weight: its pull is that of this bound, "
                                    "the covariance shrinks less)")
    bias_sigma_motion_deg_s: float = param(0.1, "deg/s", "bias measurement std in motion")
    bias_vertical_forgetting: float = param(1e-4, "", "vertical bias in motion: weight "
                                            "relative to the horizontal components")
    bias_sigma_rest_deg_s: float = param(0.03, "deg/s", "bias measurement std at rest")
    rest_min_s: float = param(1.5, "s", "minimum duration of a rest phase")
    rest_tau_s: float = param(0.5, "s", "low-pass time constant of the rest detection")
    rest_th_gyro_deg_s: float = param(2.0, "deg/s", "rest threshold on the gyro deviation")
    rest_th_rate_deg_s: float = param(2.0, "deg/s", "a steady low-passed rate farther than "
                                      "this from the bias estimate (a large bias not yet "
                                      "estimated, or a slow rotation) needs "
                                      "rest_min_large_bias_s to count as rest")
    rest_min_large_bias_s: float = param(5.0, "s", "minimum duration of such a rest phase, "
                                         "which counts only when the gyro says the "
                                         "accelerometer or magnetometer would have turned by "
                                         "at least twice rest_th_turn_deg meanwhile")
    rest_th_turn_deg: float = param(2.0, "deg", "a rest ends (and does not begin) when the "
                                    "low-passed accelerometer or magnetometer direction turns "
                                    "by more than this in the body frame: a steady turn is "
                                    "not rest (0: off)")
    rest_th_acc_m_s2: float = param(0.5, "m/s^2", "rest threshold on the accelerometer "
                                    "deviation")
    rest_reset: bool = param(True, "", "the first rest, while the heading is still starting "
                             "(its first tau_mag_s), sets the inclination and the heading "
                             "from the rest's low-passed accelerometer and magnetometer: "
                             "before it the gyro bias was unknown and the estimate drifted")
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
    mag_heading_dis_deg: float = param(60.0, "deg", "a field within the norm and dip bounds "
                                       "whose heading disagrees with the estimate by more "
                                       "than this (after the start-up) is a disturbance too: "
                                       "a field that turns, or one back in the bounds turned "
                                       "away; up to mag_max_reject_s (0: off)")
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
                     "bias_clip_deg_s", "bias_huber_deg_s",
                     "bias_sigma_motion_deg_s", "bias_sigma_rest_deg_s",
                     "max_dt_s", "mag_reject_factor", "bias_vertical_forgetting"):
            self._require(name, getattr(self, name) > 0, "must be > 0")
        for name in ("tau_mag_s", "heading_bias_ref_deg_s", "rest_min_s", "rest_th_gyro_deg_s",
                     "rest_th_rate_deg_s", "rest_min_large_bias_s", "rest_th_turn_deg",
                     "rest_th_acc_m_s2", "mag_current_tau_s", "mag_ref_tau_s", "mag_norm_th",
                     "mag_dip_th_deg", "mag_new_s", "mag_new_first_s", "mag_soft_norm",
                     "mag_soft_dip_deg",
                     "mag_new_min_gyro_deg_s", "mag_min_undisturbed_s", "mag_max_reject_s"):
            self._require(name, getattr(self, name) >= 0, "must be >= 0")
        self._require("mag_heading_dis_deg", 0 <= self.mag_heading_dis_deg <= 180,
                      "must be in [0, 180] (0: off)")



# ---------------------------------------------------------------- readable twin
# The phases of ``gnomon.kernels.robust_ahrs.robust_ahrs_step`` written with numpy, on the
# same state record (``s``: ``state.view(np.recarray)[0]``, fields by name) and the same
# ``Coefficients`` ``c``. Vectors are (3,) arrays in the frame their name says.
def _lowpass(f, x, lp):
    """``LowPass`` ``lp`` of ``x`` (array), state ``f`` (a ``LOWPASS_*`` record): for the
    first ``tau_s`` the running mean, which then becomes the filter's steady state."""
    if f.n >= 0:
        n = f.n + 1
        f.z0 += x  # the running sum
        y = f.z0 / n
        f.n = n
        if n * lp.ts_s >= lp.tau_s:
            _settle(f, y, lp)
        return y
    y = lp.b0 * x + f.z0
    f.z0, f.z1 = lp.b1 * x - lp.a1 * y + f.z1, lp.b2 * x - lp.a2 * y
    return y


def _settle(f, y, lp):
    """The low-pass state ``f`` set to its steady state for a constant input ``y`` (the
    start-up's running mean over)."""
    f.z0, f.z1, f.n = y * (1.0 - lp.b0), y * (lp.b2 - lp.a2), -1


def _set_heading(s, d):
    """``delta`` (rad) and the half-angle cosine and sine the estimate is built from."""
    s.delta, s.cos_half_delta, s.sin_half_delta = d, math.cos(0.5 * d), math.sin(0.5 * d)


def _wrap(a):
    return a - 2 * math.pi if a > math.pi else (a + 2 * math.pi if a < -math.pi else a)


def _dcm6(s) -> np.ndarray:
    """``R_6b`` (3, 3): body to the inclination-corrected frame 6."""
    return dcm_from_quat(quat_mul(s.q_acc, s.q_gyr))


def _rest_gyro(s, c, g):
    """Rest detection, gyro part: low-pass ``g`` (rad/s) into ``s.gyro_lp``; a large
    deviation (or a low-passed rate beyond the bias bound) ends a rest phase."""
    s.gyro_lp = g_lp = _lowpass(s.rest_gyro_lp, g, c.rest_lp)
    dev = g - g_lp
    if dev @ dev >= c.rest_th_gyro2 or np.max(np.abs(g_lp)) > c.bias_clip:
        s.rest_t, s.rest = 0.0, False


def _strapdown(s, dt, g):
    """``q_gyr <- q_gyr ⊗ exp((g - b) dt)``; ``rot2 += |g - b|² dt``."""
    if dt > 0.0:
        r = (g - s.bias) * dt
        s.rot2 += (r @ r) / dt
        if r @ r > 0.0:
            s.q_gyr = _normalise(quat_mul(s.q_gyr, quat_from_rotvec(r)))


def _chord2(u, v) -> float:
    """Squared distance between the directions of two non-zero 3-vectors."""
    d = u / np.linalg.norm(u) - v / np.linalg.norm(v)
    return float(d @ d)


def _rest_begin(s, a_lp):
    """A rest candidacy begins: keep the low-passed accelerometer (unit) and magnetometer
    and start the gyro's rotation ``rest_q`` at the identity."""
    s.rest_a0 = a_lp / np.linalg.norm(a_lp)
    s.rest_m0 = s.mag_body_lp
    s.rest_m0_ok = s.mag_body_ok
    s.rest_q = np.array([1.0, 0.0, 0.0, 0.0])


def _rest_turn(s, dt, g):
    """During a candidacy: ``rest_q <- rest_q ⊗ exp((g - b) dt)`` (body then <- body now)."""
    if s.rest_t > 0.0 and dt > 0.0:
        s.rest_q = _normalise(quat_mul(s.rest_q, quat_from_rotvec((g - s.bias) * dt)))


def _gyro_says_turned(s, c) -> bool:
    """The gyro's rotation since the candidacy began would have turned the accelerometer's
    or the magnetometer's (hard-iron offset removed) direction by twice ``rest_th_turn``."""
    Rt = dcm_from_quat(s.rest_q).T  # body then -> body now
    big = 4.0 * c.rest_th_turn2
    if _chord2(Rt @ s.rest_a0, s.rest_a0) >= big:
        return True
    m = s.rest_m0 - s.hard_iron.o
    return bool(s.rest_m0_ok and m @ m > 0.0 and _chord2(Rt @ m, m) >= big)


def _first_rest_reset(s, c, a_lp):
    """The first rest, while the heading is still starting (``k_mag_init`` not 0): the
    accelerometer low-pass in frame I restarts settled at the rest's low-passed specific
    force ``a_lp`` (body), and the next magnetometer sample sets the heading."""
    s.reset_done = True
    if s.k_mag_init == 0.0:
        return
    _settle(s.acc_lp, dcm_from_quat(s.q_gyr) @ a_lp, c.acc_lp)
    s.heading_reset = True


def _heading_reset(s):
    """``delta`` set to the heading, in frame 6, of the low-passed magnetometer (hard-iron
    offset removed): the heading of the first rest."""
    s.heading_reset = False
    m6 = _dcm6(s) @ (s.mag_body_lp - s.hard_iron.o)
    if m6[0] * m6[0] + m6[1] * m6[1] > 0.0:
        _set_heading(s, math.atan2(m6[0], m6[1]))


def _rest_acc(s, c, a):
    """Rest detection, accelerometer part: rest after ``rest_min_s`` within the threshold
    of the low-passed specific force ``a`` (m/s²) while its direction stays within
    ``rest_th_turn`` of the candidacy's first (else a new candidacy); after
    ``rest_min_large_s``, and only if the gyro says the accelerometer or magnetometer
    would have turned by twice that, when the low-passed rate is farther than
    ``rest_th_rate`` from the bias estimate."""
    a_lp = _lowpass(s.rest_acc_lp, a, c.rest_acc_lp)
    dev = a - a_lp
    if dev @ dev >= c.rest_th_acc2:
        s.rest_t, s.rest = 0.0, False
        return
    if s.rest_t == 0.0:
        _rest_begin(s, a_lp)
    elif c.rest_th_turn2 > 0.0 and _chord2(a_lp, s.rest_a0) >= c.rest_th_turn2:
        s.rest_t, s.rest = 0.0, False
        _rest_begin(s, a_lp)
    s.rest_t += c.ts_acc_s
    far = np.max(np.abs(s.gyro_lp - s.bias))
    if s.rest_t >= c.rest_min_s and not s.rest and (far <= c.rest_th_rate or (
            s.rest_t >= c.rest_min_large_s and (c.rest_th_turn2 == 0.0
                                                or _gyro_says_turned(s, c)))):
        s.rest = True
        if c.rest_reset and not s.reset_done:
            _first_rest_reset(s, c, a_lp)


def _rest_mag(s, c, m):
    """Rest detection, magnetometer part: low-pass the field in the body frame; a direction
    farther than ``rest_th_turn`` from the candidacy's first ends the rest and the
    candidacy."""
    s.mag_body_lp = m_lp = _lowpass(s.rest_mag_lp, m, c.rest_mag_lp)
    s.mag_body_ok = True
    if (s.rest_t > 0.0 and s.rest_m0_ok and c.rest_th_turn2 > 0.0
            and _chord2(m_lp, s.rest_m0) >= c.rest_th_turn2):
        s.rest_t, s.rest = 0.0, False


def _inclination(s, c, a):
    """Low-pass the specific force in frame I, see it in frame 6 (``f``, normalised) and
    turn ``q_acc`` by the rotation taking ``f`` to up. Returns ``f`` (None if zero)."""
    f = dcm_from_quat(s.q_acc) @ _lowpass(s.acc_lp, dcm_from_quat(s.q_gyr) @ a, c.acc_lp)
    nf = np.linalg.norm(f)
    if not nf > 0.0:
        return None
    f = f / nf
    cw = math.sqrt(max(0.5 * (f[2] + 1.0), 0.0))
    corr = (np.array([cw, 0.5 * f[1] / cw, -0.5 * f[0] / cw, 0.0]) if cw > 1e-6
            else np.array([0.0, 1.0, 0.0, 0.0]))
    s.q_acc = _normalise(quat_mul(corr, s.q_acc))
    s.acc_rate = math.hypot(f[0], f[1]) / c.ts_acc_s  # sin(correction angle) / ts
    return f


def _bias_kf(s, c, f):
    """Gyro-bias Kalman filter on every ``bias_every``-th accelerometer sample: at rest
    ``H = I`` with the low-passed gyro; in motion the inclination correction ``f`` (frame 6)
    measures the horizontal ``R_6b b`` (both sides low-passed, vertical pulled to 0)."""
    run = s.bias_count == 0
    s.bias_count = (s.bias_count + 1) % c.bias_every
    if not (run and (c.rest_bias or c.motion_bias)):
        return
    R = _dcm6(s)
    rb = (R @ s.bias)[:2]
    H = _lowpass(s.bias_R_lp, R, c.bias_lp)
    rb_lp = _lowpass(s.bias_Rb_lp, rb, c.bias_lp)
    P = s.P  # a view
    P[np.diag_indices(3)] += np.where(np.diag(P) < c.bias_p0, c.bias_v, 0.0)
    if c.rest_bias and s.rest:
        _bias_update(s, c, np.eye(3), s.gyro_lp - s.bias, np.full(3, c.w_rest), c.bias_clip)
    elif c.motion_bias and f is not None:
        y = np.array([-f[1] / c.ts_acc_s + rb_lp[0], f[0] / c.ts_acc_s + rb_lp[1], 0.0])
        _bias_update(s, c, H, y - H @ s.bias, np.array([c.w_motion, c.w_motion,
                                                        c.w_vertical]), c.huber)


def _bias_update(s, c, H, e, w, ei):
    """Kalman update of the bias with the innovation ``e``, measurement matrix ``H`` and
    variances ``w``, each multiplied by ``|e_i| / ei`` where ``|e_i| > ei`` (Huber weights);
    the bias stays within ``bias_clip``."""
    lim = c.bias_clip
    w = w * np.maximum(np.abs(e) / ei, 1.0)
    P = s.P.copy()
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + np.diag(w))
    s.bias = np.clip(s.bias + K @ e, -lim, lim)
    s.bias_at_limit = bool(np.any(np.abs(s.bias) >= lim))
    P -= K @ H @ P
    s.P = 0.5 * (P + P.T)  # symmetric against rounding over long runs


def _magnetometer(s, c, m):
    """Heading from the magnetometer ``m`` (body): accumulate the field in frame 6; on a
    complete block update the hard-iron offset, test for disturbances and turn ``delta``
    towards the field's heading (and optionally feed the vertical bias)."""
    R, hi = _dcm6(s), s.hard_iron
    if c.hi_lambda > 0.0:  # block sums of the raw field, each sample with its own R
        hi.block_m += m
        hi.block_mm += m @ m
        hi.block_S += R
        hi.block_rm += R @ m
        m = m - hi.o
    s.mag_sum += R @ m
    s.mag_count += 1
    if not (s.mag_count >= c.mag_every or s.k_mag_init == 1.0):
        return  # accumulating: the heading filter runs on every mag_every-th sample
    cnt = s.mag_count
    m6 = s.mag_sum * (1.0 / cnt)  # the mean field in frame 6
    if c.hi_lambda > 0.0:
        _hard_iron(s, c, cnt)
    s.mag_sum, s.mag_count = 0.0, 0
    soft = 1.0
    if c.mag_rejection:
        nm = np.linalg.norm(m6)
        cur = _mag_disturbance(s, c, nm, -math.asin(min(max(m6[2] / nm, -1.0), 1.0)))
        soft = _new_field(s, c, cur)
    dis = _wrap(math.atan2(m6[0], m6[1]) - s.delta)
    s.mag_dis = dis
    if (c.mag_heading_dis > 0.0 and not s.mag_disturbed and s.k_mag_init == 0.0
            and abs(dis) > c.mag_heading_dis and s.mag_reject_t <= c.mag_max_reject_s):
        s.mag_disturbed, s.mag_undisturbed_t = True, 0.0  # in the bounds, turned away
    s.k_mag_used = k = _heading_gain(s, c, soft, R[2] @ s.P @ R[2])  # R[2]: up in b
    _set_heading(s, _wrap(s.delta + k * dis))
    if c.k_mag_bias > 0.0 and k > 0.0 and s.k_mag_init == 0.0:  # heading-rate bias loop
        db = -c.k_mag_bias * (k / c.k_mag) * dis * c.ts_mag  # dis < 0: bias along up too small
        s.bias = np.clip(s.bias + db * R[2], -c.bias_clip, c.bias_clip)  # R[2]: up in b
        s.bias_at_limit = bool(np.any(np.abs(s.bias) >= c.bias_clip))


def _hard_iron(s, c, cnt):
    """Fold a block of ``cnt`` samples into the weighted sums and solve for the hard-iron
    offset ``o`` (body).

    Least squares of ``R_6b m = h + R_6b o`` over the window (``h`` fixed in frame 6)
    with the prior ``reg·w·|o|²``: ``(w²(1+reg) I - SᵀS) o = w Σm - Sᵀ Σ R m`` with
    ``S = Σ R``, ``w = Σ 1``. Used only if it leaves less than ``hard_iron_gate`` of the
    residual energy without an offset (``h`` = the mean of ``R m``); else zero.
    """
    hi, lam = s.hard_iron, c.hi_lambda
    hi.w = lam * hi.w + cnt
    hi.S = lam * hi.S + hi.block_S  # Σ R, each sample with its own R
    hi.rm = lam * hi.rm + hi.block_rm  # Σ R m of the raw field
    hi.m = lam * hi.m + hi.block_m
    hi.mm = lam * hi.mm + hi.block_mm
    hi.block_m, hi.block_mm, hi.block_S, hi.block_rm = 0.0, 0.0, 0.0, 0.0
    w, S, rm = hi.w, hi.S, hi.rm
    A = w * w * (1.0 + c.hi_reg) * np.eye(3) - S.T @ S
    if np.linalg.det(A) <= 0.0:
        return
    o = np.linalg.solve(A, w * hi.m - S.T @ rm)
    h = (rm - S @ o) / w
    e0 = hi.mm - rm @ rm / w
    e1 = hi.mm - h @ rm - o @ hi.m
    hi.o = o if e1 < c.hi_gate * e0 else 0.0


def _mag_disturbance(s, c, nm, dip):
    """Norm/dip test of the field against the learned reference (disturbed outside the
    thresholds, undisturbed after ``mag_min_undisturbed_s`` within them). Returns the
    low-passed ``(norm, dip)``."""
    cur = _lowpass(s.mag_lp, np.array([nm, dip]), c.mag_lp)
    ref_n = s.mag_ref_norm
    if abs(cur[0] - ref_n) < c.mag_norm_th * ref_n and abs(cur[1] - s.mag_ref_dip) < c.mag_dip_th:
        s.mag_undisturbed_t += c.ts_mag
        if s.mag_undisturbed_t >= c.mag_min_undisturbed_s:
            s.mag_disturbed = False
            s.mag_ref_norm += c.k_mag_ref * (cur[0] - ref_n)
            s.mag_ref_dip += c.k_mag_ref * (cur[1] - s.mag_ref_dip)
    else:
        s.mag_undisturbed_t, s.mag_disturbed = 0.0, True
    return cur


def _new_field(s, c, cur):
    """A steady new field (``cur`` = low-passed norm, dip) becomes the reference after
    ``mag_new_s`` of motion in it. Returns the soft de-weighting factor
    ``1 + soft_norm (Δnorm/norm)² + soft_dip Δdip²``."""
    cand_n = s.cand_norm
    if abs(cur[0] - cand_n) < c.mag_norm_th * cand_n and abs(cur[1] - s.cand_dip) < c.mag_dip_th:
        if s.gyro_lp @ s.gyro_lp >= c.mag_new_min_gyro2:
            s.cand_t += c.ts_mag
        s.cand_norm += c.k_mag_ref * (cur[0] - cand_n)
        s.cand_dip += c.k_mag_ref * (cur[1] - s.cand_dip)
        if s.mag_disturbed and (s.cand_t >= c.mag_new_s or (
                s.mag_ref_norm == 0.0 and s.cand_t >= c.mag_new_first_s)):
            s.mag_ref_norm, s.mag_ref_dip = s.cand_norm, s.cand_dip
            s.mag_disturbed, s.mag_undisturbed_t = False, c.mag_min_undisturbed_s
    else:
        s.cand_t, s.cand_norm, s.cand_dip = 0.0, cur[0], cur[1]
    if s.mag_ref_norm > 0.0:
        dn = (cur[0] - s.mag_ref_norm) / s.mag_ref_norm
        dd = cur[1] - s.mag_ref_dip
        return 1.0 + c.soft_norm * dn * dn + c.soft_dip * dd * dd
    return 1.0


def _heading_gain(s, c, soft, p_bv):
    """This update's heading gain: ``k_mag`` or the heading KF's (random walk raised by
    the vertical bias variance ``p_bv``), 0 while a disturbance is rejected (divided after
    ``mag_max_reject_s``), divided by the de-weighting ``soft``, at least the running-mean
    gain at start."""
    k, r_head = c.k_mag, c.r_head  # r_head: the heading measurement variance
    if c.heading_kf:
        s.p_head += c.q_head * (1.0 + p_bv * c.inv_bias_ref2) + c.q_rate * s.rot2
    s.rot2 = 0.0
    if c.mag_rejection:
        if s.mag_disturbed:
            if s.mag_reject_t <= c.mag_max_reject_s:
                s.mag_reject_t += c.ts_mag
                k, r_head = 0.0, 0.0
            else:
                k /= c.mag_reject_factor
                r_head = c.r_head * c.mag_reject_factor * c.mag_reject_factor
        else:
            s.mag_reject_t = max(s.mag_reject_t - c.mag_reject_factor * c.ts_mag, 0.0)
    k /= soft
    r_head *= soft
    if c.heading_kf and r_head > 0.0:
        k = s.p_head / (s.p_head + r_head)
        s.p_head *= 1.0 - k
    ki = s.k_mag_init
    if ki != 0.0:  # running mean at start: gain at least 1/count
        if k < ki:
            k = ki
            s.p_head = ki * c.r_head
        ki = ki / (ki + 1.0)
        s.k_mag_init = 0.0 if ki * c.tau_mag_s < c.ts_mag else ki
    return k


def _sample(v, name):
    """A sensor sample as a float array (3,), or None for no new sample (None, zero, or a
    non-finite component)."""
    if v is None:
        return None
    a = np.asarray(v, dtype=float)
    if a.shape != (3,):
        raise InputError(f"expected a 3-vector, got shape {a.shape}", field=name)
    return a if np.all(np.isfinite(a)) and a @ a > 0.0 else None


def _normalise(q):
    return q / np.linalg.norm(q)


class RobustAHRS(CompiledIMUUpdate, Estimator):
    """Decoupled 9-axis AHRS with rest/motion bias estimation and magnetic rejection (ENU).

    Streaming: ``update`` (one sample, the compiled ``robust_ahrs_sample``, see
    ``CompiledIMUUpdate``) and ``update_many`` (a buffer, the compiled batch loop) on the
    filter's own state; ``update_reference`` is the readable twin. Batch: ``run``."""

    name = "robust-ahrs"
    summary = ("Decoupled AHRS (VQF structure): inertial-frame accelerometer filter, rest and "
               "motion bias KF, heading-only magnetometer with disturbance rejection, heading "
               "Kalman gain, online hard-iron offset")
    paper = "VQF's structure (Laidig & Seel 2023) + heading KF + hard-iron"
    kind = "imu"
    reference_frame = "ENU"
    Params = RobustAHRSParams
    needs = ("gyro", "accel", "mag")
    multi_rate = True
    state_fields = ("state", "ts", "t_last")
    #: Signals ``*_at_limit`` -> (parameter of the bound, its unit, what reached it): read
    #: by ``gnomon estimate`` for its warnings.
    limits = {"bias_at_limit": ("bias_clip_deg_s", "deg/s", "gyro bias estimate")}
    flag_bits = {"acc_skipped": ACC_SKIPPED, "mag_skipped": MAG_SKIPPED, "gap": GAP,
                 "bias_at_limit": BIAS_AT_LIMIT}

    def reset(self) -> None:
        self.state = new_state(self.params)  # one STATE record (gnomon.kernels.robust_ahrs)
        self.ts = None  # s: nominal sample times (gyro, accelerometer, magnetometer)
        self.t_last = None  # s, time of the last sample processed by ``run``
        self._reset_sample_path()

    def start(self, ts_s: float, accel_ts_s: float | None = None,
              mag_ts_s: float | None = None) -> None:
        """Fix the nominal sample times (s) of the filter coefficients: the gyro's and, when
        they run at their own rates, the accelerometer's and the magnetometer's (default:
        the gyro's)."""
        times = []
        for name, v in (("ts_s", ts_s), ("accel_ts_s", accel_ts_s), ("mag_ts_s", mag_ts_s)):
            v = ts_s if v is None else v
            if not (v > 0 and math.isfinite(v)):
                raise InputError(f"sample time must be > 0, got {v!r}", field=name)
            times.append(float(v))
        self.ts = tuple(times)
        self._reset_sample_path()  # ``update``'s coefficients follow the new times

    def set_state(self, state: dict) -> None:
        """Restore a state from ``get_state`` (its nominal sample times ``ts`` too)."""
        super().set_state(state)
        self._reset_sample_path()

    def coefficients(self) -> Coefficients:
        """The kernel's coefficients for ``params`` and the nominal sample times ``ts``."""
        cached = getattr(self, "_coefficients", None)
        if cached is None or cached[0] != (self.params, self.ts):
            cached = self._coefficients = ((self.params, self.ts),
                                           coefficients(self.params, *self.ts))
        return cached[1]

    @property
    def record(self):
        """The state record with attribute access (a view: writing it changes the filter)."""
        return self.state.view(np.recarray)[0]

    @property
    def q(self) -> np.ndarray:
        """Current ``q_nb`` (ENU from body) (4,): ``q_z(delta) ⊗ q_acc ⊗ q_gyr``."""
        s = self.record
        q6 = quat_mul(s.q_acc, s.q_gyr)
        return quat_mul(np.array([s.cos_half_delta, 0.0, 0.0, s.sin_half_delta]), q6)

    @property
    def bias(self) -> np.ndarray:
        """Current gyro bias estimate (3,), rad/s, body frame."""
        return self.state["bias"][0].copy()

    def _sample_kernel(self, dt_s, accel, mag):
        """``update``'s kernel (``CompiledIMUUpdate``): ``robust_ahrs_sample``; the first
        sample without ``start`` fixes the nominal sample time from its ``dt_s``."""
        from gnomon.kernels.robust_ahrs import robust_ahrs_sample

        if self.ts is None:
            self._start_from(dt_s)
        return robust_ahrs_sample, record(self.coefficients())

    def _start_from(self, dt_s) -> None:
        """Streaming without ``start``: the first interval is the nominal sample time."""
        if not dt_s > 0:
            raise InputError("call start(ts_s) first or pass dt_s > 0", field="dt_s")
        self.start(float(dt_s))

    def update_reference(self, dt_s: float, gyro_rad_s, accel_m_s2=None,
                         mag_uT=None) -> np.ndarray:
        """The readable twin of ``update`` (numpy, one sample; the tests hold the compiled
        paths to it sample by sample): ``dt_s`` (s) since the last one, gyro (rad/s),
        accelerometer (m/s²) and magnetometer (µT, or any one unit), all (3,) in the body
        frame. ``None`` (or a zero vector, or one with a non-finite component) is no new
        sample of that sensor: its phase is skipped. Returns ``q_nb`` (ENU from body);
        ``flags`` says which phases were skipped. A non-finite gyro sample raises
        ``InputError`` and changes nothing."""
        if gyro_rad_s is None:
            raise InputError("robust-ahrs needs a gyro sample at every update",
                             field="gyro_rad_s")
        g = _sample(gyro_rad_s, "gyro_rad_s")
        if g is None:
            g = np.asarray(gyro_rad_s, dtype=float)
            if not np.all(np.isfinite(g)):
                self._flags = BAD_GYRO
                raise InputError(f"non-finite value {g.tolist()} (the sample was not used)",
                                 field="gyro_rad_s")
            g = np.zeros(3)  # a zero rate is a sample
        if self.ts is None:
            self._start_from(dt_s)
        a, m = _sample(accel_m_s2, "accel_m_s2"), _sample(mag_uT, "mag_uT")
        c, s = self.coefficients(), self.record
        flags = (ACC_SKIPPED if a is None else 0) | (MAG_SKIPPED if m is None else 0)
        if c.rest_bias or c.mag_rejection:
            _rest_gyro(s, c, g)
        _strapdown(s, dt_s, g)
        if c.rest_bias:
            _rest_turn(s, dt_s, g)
        if dt_s > c.max_dt_s:
            flags = GAP
        else:
            if a is not None:
                if c.rest_bias:
                    _rest_acc(s, c, a)
                _bias_kf(s, c, _inclination(s, c, a))
            if m is not None:
                if c.rest_bias:
                    _rest_mag(s, c, m)
                if s.heading_reset:
                    _heading_reset(s)
                _magnetometer(s, c, m)
        self._flags = flags | (BIAS_AT_LIMIT if s.bias_at_limit else 0)
        return self.q

    def prepare(self, rec: Recording) -> None:
        """The nominal sample times from ``rec`` as ``run`` sets them: the median of the
        first (up to) 100 regular intervals of each sensor (so that a run split after 100
        samples resumes exactly)."""
        self.start(*(rec.nominal_dt_s(name, self.params.max_dt_s, default=0.01)
                     for name in ("gyro", "accel", "mag")))

    def update_many(self, dt_s, gyro_rad_s, accel_m_s2=None, mag_uT=None, *,
                    t_s=None) -> Estimate:
        """A buffer of N samples through the compiled kernel, as N calls of ``update``:
        ``dt_s`` (N,) s (each since the previous sample), ``gyro_rad_s`` (N, 3),
        ``accel_m_s2`` (N, 3) m/s², ``mag_uT`` (N, 3) body frame, NaN (or zero) rows where
        that sensor has no new sample (None: none at all). ``t_s`` (N,) the samples' times
        for the returned ``Estimate`` (default: the running sum of ``dt_s``); its signals
        are those of ``run``."""
        dt, gyro, acc, mag = imu_buffer(dt_s, gyro_rad_s, accel_m_s2, mag_uT)
        if self.ts is None and len(dt):
            self._start_from(dt[0])
        return self._batch(dt, gyro, acc, mag, np.cumsum(dt) if t_s is None else t_s)

    def _batch(self, dt, gyro, acc, mag, t_s) -> Estimate:
        """``update_many`` on checked inputs (``run``'s come from a ``Recording``): the
        compiled ``robust_ahrs_batch`` from ``state``; each sensor at its own rate (NaN rows:
        no new sample, the phase skipped)."""
        from gnomon.kernels.robust_ahrs import robust_ahrs_batch

        n = len(dt)
        out = {"q": np.empty((n, 4)), "bias": np.empty((n, 3)), "rest": np.empty(n, np.bool_),
               "dist": np.empty(n, np.bool_), "acc_rate": np.empty(n), "k_mag": np.empty(n),
               "hi": np.empty((n, 3)), "flags": np.empty(n, np.uint8)}
        # strided views are fine for the kernel (no copy)
        robust_ahrs_batch(dt, gyro, acc, mag, self.state, record(self.coefficients()),
                          out["q"], out["bias"], out["rest"], out["dist"], out["acc_rate"],
                          out["k_mag"], out["hi"], out["flags"])
        f = out["flags"]
        if n:
            self._flags = int(f[-1])
        return Estimate(
            t=np.asarray(t_s, dtype=float), q=out["q"], estimator=self.name,
            params=self.params.as_dict(), frames={"reference": "ENU", "body": "sensor"},
            signals={"bias_rad_s": out["bias"],
                     "bias_at_limit": (f & BIAS_AT_LIMIT) != 0,
                     "rest": out["rest"],
                     "mag_disturbed": out["dist"], "acc_correction_rad_s": out["acc_rate"],
                     "mag_gain": out["k_mag"], "hard_iron": out["hi"],
                     "acc_skipped": (f & ACC_SKIPPED) != 0,
                     "mag_skipped": (f & MAG_SKIPPED) != 0, "gap": (f & GAP) != 0},
        )

    def run(self, rec: Recording) -> Estimate:
        """Whole recording through the compiled kernel (``prepare`` when the nominal sample
        times are not set yet, then ``update_many`` over its rows, each sensor at its own
        rate); ``rec.frames['reference']`` must be ENU."""
        self.check_inputs(rec)
        n = len(rec)
        dt = np.empty(n)
        dt[0] = self.first_dt(rec)
        dt[1:] = np.diff(rec.t)
        if self.ts is None:
            self.prepare(rec)
        est = self._batch(dt, np.asarray(rec.gyro, dtype=float),
                          np.asarray(rec.on_time_base("accel"), dtype=float),
                          np.asarray(rec.on_time_base("mag"), dtype=float), rec.t)
        self.t_last = float(rec.t[-1])
        est.frames = {"reference": rec.frames.get("reference", "ENU"), "body": "sensor"}
        return est
