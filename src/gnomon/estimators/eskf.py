"""Error-state quaternion KF for a strapdown AHRS, full (r = 6) and reduced (r = 3) measurement.

After Bilous & Nesterenko, "Simplification of the measurement model in the
algorithm of a strapdown attitude and heading reference system based on the
quaternion Kalman filter" (seed 002; ``docs/estimators/eskf.md``).

Frames and conventions (``shared/spec/conventions.md``):

* navigation frame n = East-North-Up: a resting accelerometer reads
  ``g_n = [0, 0, +g]``, the Earth field is ``m_n = [0, H, -Z]``, ``tan I = Z/H``;
* the estimate is ``q = q_nb`` (ENU from body), Hamilton, ``[w, x, y, z]``;
* error state ``X = [δe; δb]`` (n = 6): ``δe`` the vector part of the body-frame
  error quaternion ``δq = conj(q̂) ⊗ q`` (true = estimate ⊗ error, so
  ``δe ≈ θ/2`` for a small rotation θ in the body frame) and ``δb = b - b̂``
  the gyro bias error (rad/s). With ``ω̂ = ω̃ - b̂``:
  ``δė = -[ω̂×] δe - ½ δb - ½ w_g``, ``δḃ = w_b``, i.e. the paper's
  ``F = [-[ω×]  -½I; 0  0]``;
* the nominal quaternion and bias live outside the covariance; after every
  update ``q̂ ← normalise(q̂ ⊗ [1, δe])``, ``b̂ ← b̂ + δb`` and the error is reset.

Measurement models (magnetometer normalised by the reference field magnitude
``|B0|`` measured at initialisation, so ``H² + Z² = 1``):

* ``r6``: ``y = [a - Ĉ_bn g_n; m - Ĉ_bn m_n]``, ``D = [2[â×] 0; 2[m̂×] 0]``
  (``â = Ĉ_bn g_n``, ``m̂ = Ĉ_bn m_n``);
* ``r3``: ``y = [ã_x/g, ã_y/g, m̃_x/H]`` with ``ã = Ĉ_nb a``, ``m̃ = Ĉ_nb m`` (the
  readings projected into the *computed* navigation frame; predicted value 0),
  ``D = [D_n Ĉ_nb  0]``, ``D_n = [[0, -2, 0], [2, 0, 0], [0, 2 tan I, 2]]``.
  The paper's constant matrix is ``-D_n`` (its error is defined in the
  navigation frame with the opposite sense); with gnomon's body-frame error the
  reduced ``D`` is the constant matrix times the estimated rotation.

Both ``D`` are checked against finite differences of the measurement functions
in ``tests/test_eskf.py``. The update is the Joseph form, symmetrised.

Two twins of one filter, on the same ``STATE`` record: the compiled kernel
``gnomon.kernels.eskf`` runs ``update(dt_s, gyro_rad_s, accel_m_s2, mag_uT)`` (one sample,
``eskf_sample``), ``update_many`` (a buffer) and ``run`` (a recording), so any split of a
recording into such calls gives ``run``'s result; ``update_reference`` (same arguments)
runs the readable functions of ``gnomon.estimators.eskf_model`` (numpy matrices,
re-exported here) in the kernel's phases — prediction, gates and reference field,
accelerometer low-pass, measurement, correction — and the tests compare the two sample
by sample. The operation counts of the paper's comparison (``count_gain_operations``,
``count_update_operations``) run the kernel's correction source on ``Traced`` numbers.

Beyond the paper (which assumes no linear acceleration, an undisturbed field
and known H, Z), for real data — all can be switched off by parameters:

* the inclination is estimated from the data, ``-Z ≈ mean(a·m)/(g|m|)``
  (rotation invariant; ``dip_tau``), unless ``inclination_known``;
* the accelerometer is low-pass filtered in the computed navigation frame,
  where gravity is constant and linear accelerations average out
  (``accel_lowpass_tau``, default 3 s; 0 = the paper's raw accelerometer);
* measurement variances are inflated by ``1 + (dev/gate)²`` when ``| |a| - g |``
  (``accel_gate``) or the field magnitude / dip deviates (``mag_gate``);
* the low-pass follows the corrections (``accel_lowpass_follow``): a tilt error once
  corrected is not measured again for ``accel_lowpass_tau`` (that repeated measurement,
  under sustained motion, drove the bias estimate to 14-19 °/s on walking and swinging
  phone data whose bias is below 1 °/s);
* optionally (``bias_gate`` > 0; off by default), while the RMS of ``| |a| - g |`` over
  ``bias_gate_tau`` exceeds ``bias_gate`` (walking, running), corrections leave the bias
  and its covariance alone (a Schmidt update: the attitude part is the optimal one, the
  covariance stays consistent); on the phones it held a wrong early bias through whole
  running trials, so it is off;
* each component of the bias estimate stays within ``bias_limit`` (signal
  ``bias_at_limit``).

The noise levels were chosen on the 15 BROAD trials shipped with the project, so the
BROAD score is not a held-out result; ``accel_lowpass_follow`` and ``bias_gate`` with
BROAD and the tyrex phones held apart (``benchmarks/defaults_tuning.py``, both
directions in ``docs/estimators/eskf.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gnomon.errors import InputError
from gnomon.estimators.base import CompiledIMUUpdate, Estimate, Estimator, Params, imu_buffer, param
from gnomon.estimators.eskf_model import (
    MAX_ABS_DIP,
    accel_lowpass,
    continuous_matrix,
    gate_factor,
    measurement_function_r3,
    measurement_function_r6,
    measurement_matrix_r3_nav,
    measurement_r3,
    measurement_r6,
    process_noise,
    propagate,
    reference_field,
    transition_matrix,
    update,
    update_dip,
)
from gnomon.estimators.initial import initial_attitude
from gnomon.recording import MAG_UNITS_TO_TESLA, Recording
from gnomon.rotation import dcm_from_quat

__all__ = [
    "EskfParams", "EskfR6Params", "EskfR3Params", "Eskf", "EskfR6", "EskfR3",
    "transition_matrix", "process_noise", "propagate", "measurement_r6", "measurement_r3",
    "measurement_function_r6", "measurement_function_r3", "measurement_matrix_r3_nav",
    "update", "update_dip", "accel_lowpass", "reference_field",
    "count_gain_operations", "count_update_operations", "paper_gain_operations",
    "trace_update", "UpdateTrace", "OpTape", "Traced", "continuous_matrix",
]


# ---------------------------------------------------------------- parameters & class
@dataclass(frozen=True)
class EskfParams(Params):
    """Tuning of the error-state AHRS filter (SI units)."""

    measurement: str = param("r6", "", "measurement model: 'r6' (accel + mag residuals) "
                             "or 'r3' (a_x/g, a_y/g, m_x/H in the computed ENU frame)")
    gyro_noise: float = param(1e-3, "rad/s/√Hz", "gyro white-noise density")
    bias_rw: float = param(1e-5, "rad/s/√s", "gyro bias random walk")
    accel_noise: float = param(0.3, "m/s²", "accelerometer noise std per sample "
                               "(includes unmodelled linear acceleration)")
    mag_noise: float = param(0.1, "1 (of |B0|)", "magnetometer noise std per sample, as a "
                             "fraction of the reference field magnitude")
    init_att_std: float = param(0.1, "rad", "initial attitude error std (per axis)")
    init_bias_std: float = param(0.02, "rad/s", "initial gyro bias std (per axis)")
    gravity: float = param(9.81, "m/s²", "gravity magnitude")
    init_time: float = param(0.1, "s", "averaging window of the first samples for the "
                             "TRIAD initialisation and the reference field")
    accel_gate: float = param(1.0, "m/s²", "| |a| - g | at which the accelerometer variance "
                              "is doubled (1 + (dev/gate)²); 0 disables")
    mag_gate: float = param(0.1, "1 (of |B0|)", "deviation of |m|/|B0| from 1 or of "
                            "a·m/(g|m|) from its running mean at which the magnetometer "
                            "variance is doubled; 0 disables")
    dip_tau: float = param(30.0, "s", "time constant of the running estimate of the "
                           "inclination from the angle between a and m; 0: fixed at init")
    accel_lowpass_tau: float = param(3.0, "s", "time constant of a low-pass of the "
                                     "accelerometer in the computed navigation frame "
                                     "(rejects linear acceleration); 0: off, as in the paper")
    accel_lowpass_follow: float = param(0.4, "1", "fraction of each correction of the "
                                        "attitude that the accelerometer low-pass follows "
                                        "(1: the corrected tilt leaves the average at once; "
                                        "0: it is measured again for accel_lowpass_tau, "
                                        "which drives the bias away under sustained motion)")
    bias_gate: float = param(0.0, "m/s²", "RMS of | |a| - g | (over bias_gate_tau) above "
                             "which corrections leave the bias and its covariance alone "
                             "(strong sustained linear acceleration: walking, running); "
                             "0 disables")
    bias_gate_tau: float = param(3.0, "s", "time constant of that RMS")
    bias_limit: float = param(0.2, "rad/s", "bound on each component of the bias estimate "
                              "(11.5 deg/s; signal bias_at_limit when reached)")
    inclination_known: bool = param(False, "", "use the given inclination instead of "
                                    "estimating it (the paper's assumption: H, Z known)")
    inclination: float = param(1.0, "rad", "magnetic inclination I (tan I = Z/H, positive "
                               "downward), used when inclination_known")

    def validate(self) -> None:
        self._require("measurement", self.measurement in ("r6", "r3"), "must be 'r6' or 'r3'")
        for name in ("gyro_noise", "bias_rw", "init_att_std", "init_bias_std"):
            self._require(name, getattr(self, name) >= 0.0, "must be >= 0")
        for name in ("accel_noise", "mag_noise", "gravity", "bias_gate_tau", "bias_limit"):
            self._require(name, getattr(self, name) > 0.0, "must be > 0")
        for name in ("init_time", "accel_gate", "mag_gate", "dip_tau", "accel_lowpass_tau",
                     "bias_gate"):
            self._require(name, getattr(self, name) >= 0.0, "must be >= 0")
        self._require("accel_lowpass_follow", 0.0 <= self.accel_lowpass_follow <= 1.0,
                      "must be in [0, 1]")


@dataclass(frozen=True)
class EskfR6Params(EskfParams):
    """``EskfParams`` of ``eskf-r6``: the full 6-component measurement, fixed."""

    measurement: str = param("r6", "", "measurement model, fixed at 'r6' for eskf-r6 "
                             "(the reduced model is eskf-r3)")

    def validate(self) -> None:
        super().validate()
        self._require("measurement", self.measurement == "r6",
                      "eskf-r6 runs the full model 'r6' (the reduced 'r3' is eskf-r3)")


@dataclass(frozen=True)
class EskfR3Params(EskfParams):
    """``EskfParams`` of ``eskf-r3``: the paper's reduced 3-component measurement, fixed."""

    measurement: str = param("r3", "", "measurement model, fixed at 'r3' for eskf-r3 "
                             "(the full model is eskf-r6)")

    def validate(self) -> None:
        super().validate()
        self._require("measurement", self.measurement == "r3",
                      "eskf-r3 runs the reduced model 'r3' (the full 'r6' is eskf-r6)")


#: tesla per µT (the streaming ``update`` takes µT; the state keeps |B0| in tesla, as ``run``)
_TESLA_PER_UT = MAG_UNITS_TO_TESLA["uT"]


def _new(v):
    """A sample, or None for none (None or a non-finite component: no new sample)."""
    return None if v is None or not np.all(np.isfinite(v)) else v


class Eskf(CompiledIMUUpdate, Estimator):
    """Error-state quaternion KF AHRS (seed 002); see the module docstring.

    The evolving state is one ``gnomon.kernels.eskf.STATE`` record (``state``, an array of
    one element: ``q`` = ``q_nb``, ``bias`` rad/s, ``P`` (6, 6), the inclination estimate
    and the accelerometer low-pass), with the reference magnitude ``b0_mag`` (tesla) and
    ``t_last``. ``run(rec)``, ``update_many(...)`` (a buffer) and ``update(...)`` (one
    sample) continue it with the compiled kernel; ``update_reference(...)`` with the
    readable reference of the same phases. ``run`` starts a fresh filter from the first
    ``init_time`` of its recording (``prepare``), ``update``/``update_many`` from their
    first sample (TRIAD). ``flags``: what the last ``update`` did (``update_skipped``,
    ``bias_at_limit``, as the signals); ``innovation`` its measurement.
    Signals: ``bias_rad_s`` (N, 3), ``bias_at_limit`` (N,) (a component of the bias
    estimate at ``bias_limit``: the true bias may be larger, or the estimate ran into the
    bound; ``gnomon estimate`` warns), ``innovation`` (N, r), ``cov_diag`` (N, 6)
    (attitude part in rad² of ``δe`` = half-angles, bias part in (rad/s)²),
    ``update_skipped`` (N,) (not both sensors had a usable sample: prediction only, or
    the one sensor's rows of the model).
    """

    name = "eskf"
    summary = "error-state quaternion KF AHRS, full or reduced measurement (seed 002)"
    paper = "seed 002 (Bilous & Nesterenko)"
    Params = EskfParams
    needs = ("gyro", "accel", "mag")
    multi_rate = True
    kind = "imu"
    reference_frame = "ENU"
    state_fields = ("state", "b0_mag", "t_last")
    #: Signals ``*_at_limit`` -> (parameter of the bound, its unit, what reached it): read
    #: by ``gnomon estimate`` for its warnings.
    limits = {"bias_at_limit": ("bias_limit", "rad/s", "gyro bias estimate")}
    flag_bits = {"update_skipped": 1, "bias_at_limit": 2}  # kernels.eskf_sample's bits

    def reset(self) -> None:
        self.state = None       # gnomon.kernels.eskf.STATE array of one element, once started
        self.b0_mag = None      # reference field magnitude, tesla
        self.t_last = None      # s, last sample processed by ``run``
        self._reset_sample_path()

    @property
    def b0_mag(self) -> float | None:
        """Reference field magnitude (tesla) that the magnetometer is normalised by."""
        return self._b0_mag

    @b0_mag.setter
    def b0_mag(self, value: float | None) -> None:
        # ``update``'s record holds the magnetometer's scale: built again at the next call
        self._b0_mag = value
        self._sample = self._record = None

    def _reset_sample_path(self) -> None:
        super()._reset_sample_path()
        self._record = None

    def _sample_record(self) -> np.ndarray:
        """``update``'s coefficients and work arrays (``gnomon.kernels.eskf_sample``)."""
        if self._record is None:
            from gnomon.kernels.eskf import coefficients
            from gnomon.kernels.eskf_sample import sample_record

            self._record = sample_record(coefficients(self.params), self.b0_mag,
                                         _TESLA_PER_UT)
        return self._record

    def _sample_kernel(self, dt_s, accel, mag):
        """``update``'s kernel (``CompiledIMUUpdate``): ``eskf_sample``; a fresh filter
        starts from this first sample (``_start``)."""
        from gnomon.kernels.eskf_sample import eskf_sample

        if self.state is None:
            self._start(accel, mag)
        return eskf_sample, self._sample_record()

    def _start(self, accel_m_s2, mag_uT) -> None:
        """Initialise from one sample (m/s², µT; None or NaN: none, as a dropout)."""
        a, m = _new(accel_m_s2), _new(mag_uT)
        self._init_state(np.zeros(3) if a is None else a,
                         np.zeros(3) if m is None else m * _TESLA_PER_UT)

    @property
    def innovation(self) -> np.ndarray | None:
        """The measurement ``y`` (r,) of the last ``update`` or ``update_reference``: zeros
        when not both sensors had a usable sample (prediction only, or one sensor's rows);
        None before either."""
        from gnomon.kernels.eskf_sample import SAMPLE_Y

        if self._record is None or self.state is None:
            return None
        r = 6 if self.params.measurement == "r6" else 3
        if self._flags & 1:
            return np.zeros(r)
        return self._record["work"][0, SAMPLE_Y:SAMPLE_Y + r].copy()

    # ------------------------------------------------------------ state views
    @property
    def _s(self):
        """The state record, read and written by field name (as the kernel's ``s``)."""
        return self.state.view(np.recarray)[0]

    @property
    def q(self) -> np.ndarray | None:
        """``q_nb`` (4,): ENU from body, ``[w, x, y, z]`` (None before the first sample)."""
        return None if self.state is None else self.state["q"][0].copy()

    @property
    def bias(self) -> np.ndarray | None:
        """Gyro bias estimate (3,), rad/s, body frame."""
        return None if self.state is None else self.state["bias"][0].copy()

    @property
    def P(self) -> np.ndarray | None:
        """Covariance (6, 6) of the error state ``[δe; δb]``."""
        return None if self.state is None else self.state["P"][0].copy()

    @property
    def field(self) -> tuple[float, float]:
        """Current normalised reference field ``(H, Z)`` (``H² + Z² = 1``)."""
        s = float(self.state["dip_s"][0])
        return float(np.sqrt(1.0 - s * s)), float(-s)

    def _init_state(self, accel_b, mag_T):
        """Initialise from windows ``accel_b`` (m/s²), ``mag_T`` (tesla) (k, 3) of the first
        samples.

        Rows with a zero accelerometer or magnetometer vector (dropouts) are left
        out; without any usable row the attitude starts at the identity with a
        reference field of inclination 60° until the data say otherwise.
        """
        from gnomon.kernels.eskf import new_state

        p = self.params
        a = np.atleast_2d(np.asarray(accel_b, float))
        m = np.atleast_2d(np.asarray(mag_T, float))
        na, nm = np.linalg.norm(a, axis=1), np.linalg.norm(m, axis=1)
        ok = (na > 0) & (nm > 0)
        q = initial_attitude(a[ok], m[ok], samples=len(a)) if ok.any() else \
            np.array([1.0, 0.0, 0.0, 0.0])
        self.b0_mag = float(nm[nm > 0].mean()) if (nm > 0).any() else 1.0
        cos = np.sum(a[ok] * m[ok], 1) / (p.gravity * nm[ok])
        dip = ((float(cos.mean()), float(len(cos))) if ok.any()
               else (-float(np.sin(np.radians(60.0))), 1.0))
        if p.inclination_known:
            dip = (-float(np.sin(p.inclination)), float(max(len(cos), 1)))
        if abs(dip[0]) > MAX_ABS_DIP:  # field along gravity: heading unobservable for now;
            # keep the filter running (H > 0) and let the running mean learn the real dip
            dip = (float(np.clip(dip[0], -MAX_ABS_DIP, MAX_ABS_DIP)), dip[1])
        P = np.diag([(0.5 * p.init_att_std) ** 2] * 3 + [p.init_bias_std**2] * 3)
        self.state = new_state(q, np.zeros(3), P, dip[0], dip[1])

    # ------------------------------------------------------------ readable twin
    def update_reference(self, dt_s: float, gyro_rad_s=None, accel_m_s2=None, mag_uT=None):
        """The readable twin of ``update`` (numpy, one sample; the tests hold the compiled
        paths to it sample by sample): same arguments and result, same ``flags`` and
        ``innovation``; ``gyro_rad_s`` None also allowed: no prediction.

        ``dt_s`` s since the previous sample (0 at the first); gyro rad/s, accelerometer
        m/s², magnetometer µT, body frame. ``None`` (or a non-finite component) = no new
        sample of that sensor (as a zero-vector dropout); with only one of the
        accelerometer and the magnetometer, that sensor's rows of the measurement model
        correct the state (``_one_sensor``; each sensor at its own rate). Phases as the
        kernel's ``step_row``: ``propagate`` (gyro), ``_reference_and_gates``,
        ``_bias_gate``, ``_accel_lowpass``, ``measurement_r6`` / ``_r3``, ``_correct``
        (``update``, the bias held while the gate is shut, the low-pass following).
        """
        p = self.params
        if gyro_rad_s is not None and not np.all(np.isfinite(gyro_rad_s)):
            raise InputError(f"non-finite value {np.asarray(gyro_rad_s).tolist()} (the "
                             "sample was not used)", field="gyro_rad_s")
        a, m = _new(accel_m_s2), _new(mag_uT)
        a = None if a is None else np.asarray(a, float)
        m = None if m is None else np.asarray(m, float) * _TESLA_PER_UT
        if self.state is None:
            self._init_state(np.zeros(3) if a is None else a, np.zeros(3) if m is None else m)
        s = self._s
        if gyro_rad_s is not None:
            s.q, s.P = propagate(s.q, s.bias, s.P, gyro_rad_s, dt_s, p.gyro_noise, p.bias_rw)
        s.since_acc_s += dt_s
        if m is not None:
            m = m / self.b0_mag
        na = float(np.linalg.norm(a)) if a is not None else 0.0
        nm = float(np.linalg.norm(m)) if m is not None else 0.0
        if not (na > 0 or nm > 0):  # no usable sample: prediction only
            return self._done(s, None)
        if not (na > 0 and nm > 0):  # one sensor alone: its rows of the model
            self._one_sensor(s, a if na > 0 else None, m if nm > 0 else None, na, nm)
            return self._done(s, None)
        fa, fm, h, z = self._reference_and_gates(s, a, m, na, nm, dt_s)
        hold = self._bias_gate(s, na, s.since_acc_s)
        if p.accel_lowpass_tau > 0.0:
            a = self._accel_lowpass(s, a, s.since_acc_s)
        s.since_acc_s = 0.0
        meas = measurement_r6 if p.measurement == "r6" else measurement_r3
        y, D = meas(s.q, a, m, p.gravity, h, z)
        self._correct(s, y, D, self._R(fa, fm, h), hold,
                      a if p.accel_lowpass_tau > 0.0 else None)
        return self._done(s, y)

    def _done(self, s, y):
        """The end of ``update_reference``: ``flags`` and ``innovation`` as the kernel sets
        them (``y``: the full measurement, None when not both sensors corrected)."""
        from gnomon.kernels.eskf_sample import SAMPLE_Y

        at_limit = bool(np.any(np.abs(s.bias) >= self.params.bias_limit))
        self._flags = (1 if y is None else 0) | (2 if at_limit else 0)
        if y is not None:
            self._sample_record()["work"][0, SAMPLE_Y:SAMPLE_Y + len(y)] = y
        return s.q.copy()

    def _bias_gate(self, s, na: float, dt: float) -> bool:
        """The kernel's ``bias_gate``: the mean of ``(| |a| - g |)²`` (weight
        ``min(1, dt / bias_gate_tau)``); True (hold the bias) above ``bias_gate²``."""
        p = self.params
        if p.bias_gate <= 0.0:  # off: the mean is not kept
            return False
        s.acc_dev2 += min(1.0, dt / p.bias_gate_tau) * ((na - p.gravity) ** 2 - s.acc_dev2)
        return self._bias_held(s)

    def _bias_held(self, s) -> bool:
        p = self.params
        return p.bias_gate > 0.0 and s.acc_dev2 > p.bias_gate**2

    def _correct(self, s, y, D, R, hold: bool, a_body) -> None:
        """``update`` of the record (bias within ``bias_limit``); with ``hold`` the bias and
        its covariance block are put back (the Schmidt update: ``hold_bias`` in the
        kernel); then the accelerometer low-pass follows ``accel_lowpass_follow`` of the
        correction (``a_body``: the filtered reading before it; None: nothing to follow)."""
        p = self.params
        b, Pbb = s.bias.copy(), s.P[3:, 3:].copy()
        s.q, s.bias, s.P, _ = update(s.q, s.bias, s.P, y, D, R, p.bias_limit)
        if hold:
            s.bias = b
            s.P[3:, 3:] = Pbb
        if a_body is not None and p.accel_lowpass_follow > 0.0:
            s.acc_lp += p.accel_lowpass_follow * (dcm_from_quat(s.q) @ a_body - s.acc_lp)

    def _one_sensor(self, s, a, m, na: float, nm: float) -> None:
        """The correction by the accelerometer alone (``m`` None) or the magnetometer alone
        (``a`` None): that sensor's rows of the measurement model (r6: three each; r3: the
        two tilt rows or the heading row). The magnetometer's gate reads the field's
        vertical through the attitude estimate; the inclination estimate does not move."""
        p = self.params
        h, z = float(np.sqrt(1.0 - s.dip_s**2)), float(-s.dip_s)
        accel_alone = a is not None
        hold = self._bias_gate(s, na, s.since_acc_s) if accel_alone else self._bias_held(s)
        if accel_alone:
            fa, fm = gate_factor(abs(na - p.gravity), p.accel_gate), 1.0
            if p.accel_lowpass_tau > 0.0:
                a = self._accel_lowpass(s, a, s.since_acc_s)
            s.since_acc_s = 0.0
            m = np.zeros(3)
        else:
            up = (dcm_from_quat(s.q) @ m)[2] / nm
            fa, fm = 1.0, gate_factor(max(abs(nm - 1.0), abs(up - s.dip_s)), p.mag_gate)
            a = np.zeros(3)
        meas = measurement_r6 if p.measurement == "r6" else measurement_r3
        y, D = meas(s.q, a, m, p.gravity, h, z)
        R = self._R(fa, fm, h)
        if p.measurement == "r6":
            rows = slice(0, 3) if accel_alone else slice(3, 6)
        else:
            rows = slice(0, 2) if accel_alone else slice(2, 3)
        follow = p.accel_lowpass_tau > 0.0 and s.acc_lp_started
        self._correct(s, y[rows], D[rows], R[rows, rows], hold,
                      dcm_from_quat(s.q).T @ s.acc_lp if follow else None)

    def _reference_and_gates(self, s, a, m, na: float, nm: float, dt: float):
        """Variance gates ``fa``, ``fm`` and the reference field ``(H, Z)`` after updating
        the inclination estimate ``s.dip_s`` (``update_dip``; frozen while a gate is at 2
        or more). ``na``, ``nm``: norms of ``a`` (m/s²) and the normalised ``m``."""
        p = self.params
        fa = gate_factor(abs(na - p.gravity), p.accel_gate)
        cos_am = (a @ m) / (p.gravity * nm)
        fm = gate_factor(max(abs(nm - 1.0), abs(cos_am - s.dip_s)), p.mag_gate)
        tau = 0.0 if (p.inclination_known or fa >= 2.0 or fm >= 2.0) else p.dip_tau
        s.dip_s, s.dip_count = update_dip(s.dip_s, s.dip_count, a, m, dt, tau, p.gravity)
        return fa, fm, float(np.sqrt(1.0 - s.dip_s**2)), float(-s.dip_s)

    def _accel_lowpass(self, s, a, dt: float):
        """``accel_lowpass`` on the record's low-pass state; the filtered reading (body);
        ``dt``: the time since the accelerometer's previous sample."""
        tau = self.params.accel_lowpass_tau
        w = min(1.0, dt / tau) if s.acc_lp_started else 1.0
        a, s.acc_lp = accel_lowpass(s.q, a, s.acc_lp if s.acc_lp_started else None, w)
        s.acc_lp_started = True
        return a

    def _R(self, fa: float, fm: float, h: float) -> np.ndarray:
        """Measurement covariance with the gates' inflation ``fa``, ``fm``; ``h`` = H."""
        p = self.params
        if p.measurement == "r6":
            return np.diag([p.accel_noise**2 * fa] * 3 + [p.mag_noise**2 * fm] * 3)
        ra = p.accel_noise**2 * fa / p.gravity**2
        return np.diag([ra, ra, p.mag_noise**2 * fm / h**2])

    # ------------------------------------------------------------ compiled batch
    def prepare(self, rec: Recording) -> None:
        """Start as ``run`` starts a fresh filter: TRIAD on the mean accelerometer and
        magnetometer over the first ``init_time`` seconds of ``rec`` (at least one sample),
        the reference field ``[0, H, -Z]`` and ``|B0|`` from the same samples."""
        t0 = rec.t[0] + self.params.init_time
        n_acc = max(1, int(np.searchsorted(rec.times("accel"), t0, side="right")))
        n_mag = max(1, int(np.searchsorted(rec.times("mag"), t0, side="right")))
        n = min(n_acc, n_mag)  # the first samples of each (pairs for the TRIAD)
        self._init_state(rec.accel[:n], rec.mag[:n] * MAG_UNITS_TO_TESLA[rec.mag_unit])

    def buffer_inputs(self, rec: Recording):
        """``rec`` as ``update_many`` takes it (the IMU form, the magnetometer in µT)."""
        (dt, gyro, acc, mag), kwargs = super().buffer_inputs(rec)
        if rec.mag_unit != "uT":
            mag = mag * (MAG_UNITS_TO_TESLA[rec.mag_unit] / _TESLA_PER_UT)
        return (dt, gyro, acc, mag), kwargs

    def _kernel_inputs(self, rec: Recording):
        """The compiled kernel's ``Inputs`` for ``rec`` (checked), the filter started when
        fresh (``prepare``): the gyro, each other sensor on the gyro's time base (NaN rows:
        no new sample), the magnetometer normalised by ``|B0|``, the intervals. Shared
        with the offline smoother (``gnomon.estimators.eskf_offline``)."""
        from gnomon.kernels import eskf as kern

        self.check_inputs(rec)
        dt = np.empty(len(rec))
        dt[0] = self.first_dt(rec)
        dt[1:] = np.diff(rec.t)
        if self.state is None:
            self.prepare(rec)
        # each sensor at its own rate: a correction needs a new accelerometer and a new
        # magnetometer sample in the same row (the model and its gates use both); other
        # rows only predict
        mag = rec.on_time_base("mag") * MAG_UNITS_TO_TESLA[rec.mag_unit]  # a new array
        mag /= self.b0_mag
        return kern.Inputs(np.ascontiguousarray(rec.gyro, float),
                           np.ascontiguousarray(rec.on_time_base("accel"), float),
                           np.ascontiguousarray(mag), dt)

    def update_many(self, dt_s, gyro_rad_s, accel_m_s2=None, mag_uT=None, *,
                    t_s=None) -> Estimate:
        """A buffer of N samples through the compiled kernel, as N calls of ``update``:
        ``dt_s`` (N,) s (each since the previous sample), ``gyro_rad_s`` (N, 3) rad/s,
        ``accel_m_s2`` (N, 3) m/s², ``mag_uT`` (N, 3) µT, body frame, with NaN rows where
        that sensor has no new sample (None: none at all). ``t_s`` (N,) the samples' times
        for the returned ``Estimate`` (default: the running sum of ``dt_s``); its signals
        as ``run``'s. A fresh filter starts from the first row (as ``update``)."""
        from gnomon.kernels import eskf as kern

        dt, gyro, acc, mag = imu_buffer(dt_s, gyro_rad_s, accel_m_s2, mag_uT)
        if self.state is None:
            self._start(acc[0] if len(dt) else None, mag[0] if len(dt) else None)
        mag = mag * _TESLA_PER_UT  # a new array: scaled in place below, as ``run``'s
        mag /= self.b0_mag
        inputs = kern.Inputs(np.ascontiguousarray(gyro), np.ascontiguousarray(acc),
                             np.ascontiguousarray(mag), np.ascontiguousarray(dt))
        return self._batch(inputs, np.cumsum(dt) if t_s is None else np.asarray(t_s, float),
                           "sensor")

    def _batch(self, inputs, t: np.ndarray, body: str) -> Estimate:
        """``run_batch`` over ``inputs`` (checked, normalised) from the current state."""
        from gnomon.kernels import eskf as kern

        p = self.params
        out = kern.new_outputs(len(inputs.dt))
        kern.run_batch(inputs, self.state, kern.coefficients(p), out)
        r = 6 if p.measurement == "r6" else 3
        return Estimate(
            t=t, q=out.q, estimator=self.name, params=p.as_dict(),
            frames={"reference": "ENU", "body": body},
            signals={"bias_rad_s": out.bias,
                     "bias_at_limit": out.at_limit,
                     "innovation": out.innovation[:, :r],
                     "cov_diag": out.cov_diag, "update_skipped": out.skipped},
        )

    def run(self, rec: Recording) -> Estimate:
        """Filter a whole recording (compiled kernel), continuing from the current state
        (a fresh or reset filter starts anew: ``prepare``)."""
        inputs = self._kernel_inputs(rec)
        est = self._batch(inputs, rec.t.copy(), rec.frames.get("body", "sensor"))
        self.t_last = float(rec.t[-1])
        return est


class EskfR6(Eskf):
    """Error-state AHRS KF with the full 6-component measurement (``eskf-r6``)."""

    name = "eskf-r6"
    summary = "error-state quaternion KF AHRS, 6-component accel+mag measurement (seed 002)"
    Params = EskfR6Params


class EskfR3(Eskf):
    """Error-state AHRS KF with the paper's reduced 3-component measurement (``eskf-r3``)."""

    name = "eskf-r3"
    summary = "error-state quaternion KF AHRS, reduced 3-component measurement (seed 002)"
    Params = EskfR3Params


# ---------------------------------------------------------------- operation counts
def paper_gain_operations(n: int, r: int) -> dict[str, int]:
    """The paper's count for one gain computation (its reference [9]):
    ``M = n²r + 2nr² + r³``, ``A = n²r + 2nr² - 2nr + r³``."""
    return {"mul": n * n * r + 2 * n * r * r + r**3,
            "add": n * n * r + 2 * n * r * r - 2 * n * r + r**3}


class OpTape:
    """The record of a computation run on ``Traced`` numbers: one line ``tN = a op b`` per
    arithmetic operation (``lines``) and their ``counts`` by kind (``mul``, ``div``, ``add``
    for additions and subtractions). The one operation tracer of the project: it counts
    the operations of the update for the paper's comparison and writes the straight-line
    kernel (``tools/codegen_eskf.py``)."""

    def __init__(self):
        self.lines: list[str] = []
        self.counts = {"mul": 0, "div": 0, "add": 0}

    def input(self, name: str, value: float) -> Traced:
        """A named input (no line: the generated code loads it)."""
        return Traced(value, name, self)

    def record(self, expr: str, kind: str, value: float) -> Traced:
        self.counts[kind] += 1
        name = f"t{len(self.lines) + 1}"
        self.lines.append(f"{name} = {expr}")
        return Traced(value, name, self)


class Traced:
    """A float that records each operation done with it on its ``OpTape`` (and carries its
    value, so a traced run can be checked against numpy)."""

    __slots__ = ("v", "name", "tape")

    def __init__(self, v, name: str, tape: OpTape):
        self.v = float(v)
        self.name = name
        self.tape = tape

    @staticmethod
    def _nv(o) -> tuple[str, float]:
        return (o.name, o.v) if isinstance(o, Traced) else (repr(float(o)), float(o))

    def __mul__(self, o):
        n, v = self._nv(o)
        return self.tape.record(f"{self.name} * {n}", "mul", self.v * v)

    def __rmul__(self, o):
        n, v = self._nv(o)
        return self.tape.record(f"{n} * {self.name}", "mul", v * self.v)

    def __truediv__(self, o):
        n, v = self._nv(o)
        return self.tape.record(f"{self.name} / {n}", "div", self.v / v)

    def __rtruediv__(self, o):
        n, v = self._nv(o)
        return self.tape.record(f"{n} / {self.name}", "div", v / self.v)

    def __add__(self, o):
        n, v = self._nv(o)
        return self.tape.record(f"{self.name} + {n}", "add", self.v + v)

    def __radd__(self, o):
        n, v = self._nv(o)
        return self.tape.record(f"{n} + {self.name}", "add", v + self.v)

    def __sub__(self, o):
        n, v = self._nv(o)
        return self.tape.record(f"{self.name} - {n}", "add", self.v - v)

    def __rsub__(self, o):
        n, v = self._nv(o)
        return self.tape.record(f"{n} - {self.name}", "add", v - self.v)


@dataclass(frozen=True)
class UpdateTrace:
    """``trace_update``'s result: the tape's ``lines``; ``outputs`` maps ``"P{i}{j}"``
    (upper triangle) and ``"dx{i}"`` to the names holding them; the operation counts of
    ``gain`` and of ``joseph`` (which includes ``dx = K y``)."""

    r: int
    lines: list[str]
    outputs: dict[str, str]
    gain_counts: dict[str, int]
    joseph_counts: dict[str, int]


def trace_update(r: int, rng: np.random.Generator | None = None) -> UpdateTrace:
    """Run the kernel's correction source (``gnomon.kernels.eskf.gain`` then ``joseph``)
    on ``Traced`` numbers for ``n = 6`` states and ``r`` measurements.

    The inputs are named ``p{i}{j}`` (P, symmetric: one name per pair), ``d{i}{j}`` (D1),
    ``rd{i}`` (diagonal of R), ``y{i}``, with random values (SPD ``P``); the traced gain,
    covariance and error estimate are checked against numpy (raises if wrong).
    """
    from gnomon.kernels.eskf import gain, joseph

    rng = rng or np.random.default_rng(0)
    A = rng.normal(size=(6, 6))
    P = A @ A.T + 6 * np.eye(6)
    D1 = rng.normal(size=(r, 3))
    Rd = rng.uniform(0.5, 1.5, r)
    y = rng.normal(size=r)
    tape = OpTape()
    Pt = np.empty((6, 6), dtype=object)
    for i in range(6):
        for j in range(i, 6):
            Pt[i, j] = Pt[j, i] = tape.input(f"p{i}{j}", P[i, j])
    D1t = np.array([[tape.input(f"d{i}{j}", D1[i, j]) for j in range(3)] for i in range(r)],
                   dtype=object)
    Rdt = np.array([tape.input(f"rd{i}", Rd[i]) for i in range(r)], dtype=object)
    yt = np.array([tape.input(f"y{i}", y[i]) for i in range(r)], dtype=object)
    PDt, K, G = (np.empty((6, r), dtype=object) for _ in range(3))
    S = np.empty((r, r), dtype=object)
    L = np.empty((6, 3), dtype=object)
    M = np.empty((6, 6), dtype=object)
    dx = np.empty(6, dtype=object)
    gain(Pt, D1t, Rdt, r, PDt, S, K)
    gain_counts = dict(tape.counts)
    joseph(Pt, D1t, Rdt, yt, K, r, L, M, G, dx)
    joseph_counts = {k: tape.counts[k] - gain_counts[k] for k in tape.counts}
    # the traced arithmetic against numpy: the gain, the Joseph covariance, the error
    D = np.zeros((r, 6))
    D[:, :3] = D1
    K_ref = P @ D.T @ np.linalg.inv(D @ P @ D.T + np.diag(Rd))
    IKD = np.eye(6) - K_ref @ D
    P_ref = IKD @ P @ IKD.T + K_ref @ np.diag(Rd) @ K_ref.T
    value = np.vectorize(lambda t: t.v, otypes=[float])
    upper = np.triu_indices(6)
    if not (np.allclose(value(K), K_ref, rtol=1e-9, atol=1e-12)
            and np.allclose(value(Pt)[upper], P_ref[upper], rtol=1e-9, atol=1e-12)
            and np.allclose(value(dx), K_ref @ y, rtol=1e-9, atol=1e-12)):
        raise AssertionError("traced Kalman update disagrees with numpy")
    outputs = {f"P{i}{j}": Pt[i, j].name for i in range(6) for j in range(i, 6)}
    outputs.update({f"dx{i}": dx[i].name for i in range(6)})
    return UpdateTrace(r, tape.lines, outputs, gain_counts, joseph_counts)


def _with_mul_div(c: dict[str, int]) -> dict[str, int]:
    return {"mul": c["mul"], "div": c["div"], "add": c["add"], "mul_div": c["mul"] + c["div"]}


def count_gain_operations(r: int, rng: np.random.Generator | None = None) -> dict[str, int]:
    """Operations the implemented gain (``gnomon.kernels.eskf.gain``, the source of the
    compiled kernel) performs for ``n = 6`` states and ``r`` measurements (``trace_update``).

    Returns ``mul`` (multiplications), ``div`` (divisions), ``add`` (additions and
    subtractions) and ``mul_div`` (multiplications + divisions, comparable with the
    paper's M).
    """
    return _with_mul_div(trace_update(r, rng).gain_counts)


def count_update_operations(r: int, rng: np.random.Generator | None = None) -> dict[str, int]:
    """Operations of the whole implemented correction (``gain`` + ``joseph``, i.e. gain,
    Joseph covariance and ``dx = K y``), keys as ``count_gain_operations``."""
    t = trace_update(r, rng)
    return _with_mul_div({k: t.gain_counts[k] + t.joseph_counts[k] for k in t.gain_counts})
