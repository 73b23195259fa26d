"""Complementary filters of seed 004 in discrete time: one axis (analysis) and 3D tilt (product).

Source: "Complementary filter for determining the orientation of moving
objects" (seed 004). The continuous-time analysis (transfer functions, closed
forms) is in ``gnomon.analysis.complementary``; here the same filters run on
sampled data.

One axis (pure functions over arrays, uniform sample interval ``dt_s``;
``omega_rad_s`` the gyro rate, ``phi_acc_rad`` the accelerometer angle, both (N,)):

* ``first_order_filter``: ``φ̂_k = α(φ̂_{k−1} + ω_k·dt) + (1 − α)·φ_a,k`` with
  ``α = T/(T + dt)`` — the usual embedded form of ``1/(Ts+1)``, ``Ts/(Ts+1)``;
  its steady error under a constant drift is exactly ``T ω_d``.
* ``second_order_filter``: feedback forms whose transfer functions are the
  paper's variants (``e = φ_a − φ̂``):
  variant 1 ``φ̂' = ω + c, c' = −r₁c + r₂e`` (→ ``1 − W = r₂/D``);
  variant 2 ``φ̂' = ω + r₁e + c, c' = r₂e`` (→ ``1 − W = (r₁s + r₂)/D``, a PI
  correction whose integral ``c`` is minus the gyro-drift estimate);
  integrated by semi-implicit Euler.

3D (``TiltComplementaryFilter``, registered as ``tilt-cf``): the first-order
filter in quaternion form. State ``q_nb`` (ENU from body; a resting
accelerometer reads ``[0, 0, +g]``). Per sample: propagate with the gyro,
``q ← q ⊗ exp((ω − b̂)·dt)``; then rotate the estimate by the fraction
``dt/(T + dt)`` of the rotation that takes the measured up direction
``a/|a|`` onto the predicted one ``R_nbᵀ e_z`` (rotation vector ``e``, in b,
perpendicular to the vertical so heading is untouched). About one fixed
horizontal axis this is exactly ``first_order_filter``. Optional: a gyro-bias
integral ``b̂ ← b̂ − r₂·e·dt`` (variant 2 in 3D), acceleration rejection when
``||a| − g| > accel_rejection_rel·g``, and compensation of the vehicle's
acceleration from a forward speed sensor (``compensate_accel``: subtract
``dv/dt`` and ``ω × v`` — the paper's "next step"). Heading is unobservable
and only integrates the gyro; score this filter by its inclination error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

from gnomon.errors import InputError
from gnomon.estimators.base import (
    CompiledIMUUpdate,
    Estimate,
    Estimator,
    Params,
    imu_buffer,
    param,
)
from gnomon.kernels.entry import BAD_GYRO, NO_SAMPLE, entry_point, record, vec3
from gnomon.recording import Recording
from gnomon.rotation import dcm_from_quat, quat_from_euler, quat_from_rotvec, quat_mul

__all__ = [
    "first_order_filter",
    "second_order_filter",
    "second_order_filter_reference",
    "quat_from_accel",
    "compensate_accel",
    "TiltComplementaryFilter",
    "TiltCFParams",
]

G0_M_S2 = 9.80665


# ---------------------------------------------------------------- one axis
def _one_axis_inputs(omega_rad_s, phi_acc_rad, dt_s):
    w = np.asarray(omega_rad_s, dtype=float)
    a = np.asarray(phi_acc_rad, dtype=float)
    if w.ndim != 1 or a.shape != w.shape or w.size < 1:
        raise ValueError(f"omega_rad_s and phi_acc_rad must be (N,) arrays of the same shape, "
                         f"got {w.shape} and {a.shape}")
    if not (math.isfinite(dt_s) and dt_s > 0.0):
        raise ValueError(f"dt_s must be positive, got {dt_s!r}")
    return w, a


def first_order_filter(omega_rad_s, phi_acc_rad, dt_s: float, T_s: float,
                       phi0_rad: float | None = None) -> np.ndarray:
    """First-order complementary filter on one axis; returns ``φ̂`` (N,) in rad.

    ``φ̂_0 = phi0_rad`` (default ``φ_a,0``), then for ``k ≥ 1``
    ``φ̂_k = α(φ̂_{k−1} + ω_k dt) + (1 − α)φ_a,k``, ``α = T/(T + dt)``.
    Evaluated with ``scipy.signal.lfilter`` (a linear recursion).
    """
    w, a = _one_axis_inputs(omega_rad_s, phi_acc_rad, dt_s)
    if not T_s > 0.0:
        raise ValueError(f"T_s must be positive, got {T_s!r}")
    phi0 = float(a[0]) if phi0_rad is None else float(phi0_rad)
    alpha = T_s / (T_s + dt_s)
    out = np.empty_like(w)
    out[0] = phi0
    if w.size > 1:
        u = alpha * w[1:] * dt_s + (1.0 - alpha) * a[1:]
        out[1:], _ = signal.lfilter([1.0], [1.0, -alpha], u, zi=[alpha * phi0])
    return out


def _second_order_ss(dt_s: float, r1: float, r2: float, variant: int):
    """``x_k = A x_{k−1} + B u_k`` with ``x = [φ̂, c]``, ``u = [ω, φ_a]``."""
    if variant == 1:
        lam, g = 1.0 - r1 * dt_s, 0.0
    elif variant == 2:
        lam, g = 1.0, 1.0
    else:
        raise ValueError(f"variant must be 1 or 2, got {variant!r}")
    A = np.array([[1.0 - g * r1 * dt_s - r2 * dt_s**2, lam * dt_s],
                  [-r2 * dt_s, lam]])
    B = np.array([[dt_s, g * r1 * dt_s + r2 * dt_s**2],
                  [0.0, r2 * dt_s]])
    return A, B


def second_order_filter(omega_rad_s, phi_acc_rad, dt_s: float, r1: float, r2: float,
                        variant: int, phi0_rad: float | None = None) -> np.ndarray:
    """Second-order complementary filter (paper's variant 1 or 2) on one axis; ``φ̂`` (N,) rad.

    Per sample ``k ≥ 1``, with ``e_k = φ_a,k − φ̂_{k−1}``:
    variant 1 ``c_k = (1 − r₁dt)c_{k−1} + r₂dt·e_k``, ``φ̂_k = φ̂_{k−1} + (ω_k + c_k)dt``;
    variant 2 ``c_k = c_{k−1} + r₂dt·e_k``, ``φ̂_k = φ̂_{k−1} + (ω_k + r₁e_k + c_k)dt``.
    Starts at ``φ̂_0 = phi0_rad`` (default ``φ_a,0``), ``c_0 = 0``. Evaluated as two
    ``lfilter`` passes (second-order sections) of the equivalent state-space model;
    ``second_order_filter_reference`` is the plain loop it is tested against.
    """
    w, a = _one_axis_inputs(omega_rad_s, phi_acc_rad, dt_s)
    phi0 = float(a[0]) if phi0_rad is None else float(phi0_rad)
    A, B = _second_order_ss(dt_s, r1, r2, variant)
    out = np.empty_like(w)
    out[0] = phi0
    if w.size > 1:
        # y_k = C x_k = C A x_{k-1} + C B u_k; a constant offset phi0 on φ̂ and φ_a
        # is an equilibrium, so run from zero state on (ω, φ_a − φ0).
        C = np.array([[1.0, 0.0]])
        y = np.zeros(w.size - 1)
        for i, u in enumerate((w[1:], a[1:] - phi0)):
            num, den = signal.ss2tf(A, B[:, i:i + 1], C @ A, C @ B[:, i:i + 1])
            y += signal.sosfilt(signal.tf2sos(num[0], den), u)
        out[1:] = phi0 + y
    return out


def second_order_filter_reference(omega_rad_s, phi_acc_rad, dt_s: float, r1: float,
                                  r2: float, variant: int,
                                  phi0_rad: float | None = None) -> np.ndarray:
    """Readable per-sample loop of ``second_order_filter`` (slow; for tests)."""
    w, a = _one_axis_inputs(omega_rad_s, phi_acc_rad, dt_s)
    phi = float(a[0]) if phi0_rad is None else float(phi0_rad)
    c = 0.0
    out = np.empty_like(w)
    out[0] = phi
    for k in range(1, w.size):
        e = a[k] - phi
        if variant == 1:
            c = (1.0 - r1 * dt_s) * c + r2 * dt_s * e
            phi = phi + (w[k] + c) * dt_s
        elif variant == 2:
            c = c + r2 * dt_s * e
            phi = phi + (w[k] + r1 * e + c) * dt_s
        else:
            raise ValueError(f"variant must be 1 or 2, got {variant!r}")
        out[k] = phi
    return out


# ---------------------------------------------------------------- 3D helpers
def quat_from_accel(accel_m_s2) -> np.ndarray:
    """Level attitude ``q_nb`` (ENU from body, yaw 0) from a specific force (..., 3) in b.

    Roll ``atan2(a_y, a_z)``, pitch ``atan2(−a_x, hypot(a_y, a_z))``: then
    ``R_nbᵀ e_z`` is ``a/|a|``. A zero vector gives the identity.
    """
    a = np.asarray(accel_m_s2, dtype=float)
    roll = np.arctan2(a[..., 1], a[..., 2])
    pitch = np.arctan2(-a[..., 0], np.hypot(a[..., 1], a[..., 2]))
    return quat_from_euler(np.stack([roll, pitch, np.zeros_like(roll)], -1))


def compensate_accel(t_s, accel_m_s2, gyro_rad_s, speed_m_s) -> np.ndarray:
    """Accelerometer reading with the vehicle's own acceleration removed, causally (N, 3) m/s².

    ``speed_m_s`` (N,): forward speed along body x from a speed sensor
    (odometer, GNSS speed), NaN at samples without a new measurement. At each
    new measurement ``j`` the derivative ``(v_j − v_{j−1})/(t_j − t_{j−1})`` is
    formed and held until the next one; the speed is extrapolated with it in
    between. Then ``a_lin_b = [dv/dt, 0, 0] + ω × [v, 0, 0]`` is subtracted
    (``f_b = dv_b/dt + ω × v_b + R_nbᵀ[0, 0, g]`` for a body moving along its x
    axis; Earth rate neglected). Before the second measurement nothing is
    subtracted. This is the loop of ``TiltComplementaryFilter.update``.
    """
    t = np.asarray(t_s, dtype=float)
    f = np.array(accel_m_s2, dtype=float)
    w = np.asarray(gyro_rad_s, dtype=float)
    v_meas = np.asarray(speed_m_s, dtype=float)
    st = _SpeedState()
    for k in range(t.size):
        st.step(t[k], v_meas[k])
        f[k] -= st.a_lin(w[k])
    return f


class _SpeedState:
    """Causal ``dv/dt`` and ``v`` from a sparse speed signal (see ``compensate_accel``)."""

    def __init__(self):
        self.t_last = math.nan
        self.v_last = math.nan
        self.dvdt = 0.0
        self.v = 0.0
        self.valid = False

    def step(self, t: float, v_meas: float) -> None:
        if math.isfinite(v_meas):
            if math.isfinite(self.t_last) and t > self.t_last:
                self.dvdt = (v_meas - self.v_last) / (t - self.t_last)
                self.valid = True
            self.t_last, self.v_last = t, v_meas
        if math.isfinite(self.t_last):
            self.v = self.v_last + (self.dvdt * (t - self.t_last) if self.valid else 0.0)

    def a_lin(self, w) -> np.ndarray:
        if not self.valid:
            return np.zeros(3)
        v = self.v
        # [dv/dt, 0, 0] + w × [v, 0, 0] = [dv/dt, w_z v, −w_y v]
        return np.array([self.dvdt, w[2] * v, -w[1] * v])


# ---------------------------------------------------------------- 3D estimator
@dataclass(frozen=True)
class TiltCFParams(Params):
    """Tuning of the 3D tilt complementary filter (SI units).

    Defaults are for a MEMS IMU on a hand-held or vehicle-mounted object (chosen on
    the BROAD HDF5 trials: T = 10 s, a slow bias integral, rejection at 10 % of g).
    The paper's filter is ``time_constant_s=100, bias_gain_1_s2=0,
    accel_rejection_rel=0`` (what ``reproduce.p004`` runs).
    """

    time_constant_s: float = param(10.0, "s", "T: time constant of the accelerometer correction "
                                   "(paper's first-order filter; 100 s in its example)")
    bias_gain_1_s2: float = param(0.002, "1/s^2", "r2: gain of the gyro-bias integral "
                                  "(second-order variant 2 in 3D); 0 disables it")
    accel_rejection_rel: float = param(0.1, "1", "skip the correction when ||a|-g| > this*g; "
                                       "0 disables rejection")
    gravity_m_s2: float = param(G0_M_S2, "m/s^2", "gravity magnitude for rejection")
    init_samples: int = param(10, "", "accelerometer samples averaged for the initial tilt")
    speed_compensation: bool = param(False, "", "subtract dv/dt and w x v from the accelerometer "
                                     "using extra['speed_m_s'] (forward speed, NaN = no sample)")

    def validate(self) -> None:
        self._require("time_constant_s", self.time_constant_s > 0.0, "must be > 0")
        self._require("bias_gain_1_s2", self.bias_gain_1_s2 >= 0.0, "must be >= 0")
        self._require("accel_rejection_rel", self.accel_rejection_rel >= 0.0, "must be >= 0")
        self._require("gravity_m_s2", self.gravity_m_s2 > 0.0, "must be > 0")
        self._require("init_samples", self.init_samples >= 1, "must be >= 1")


_ND = np.ndarray
_F8 = np.dtype(np.float64)
_S3 = (3,)


class TiltComplementaryFilter(CompiledIMUUpdate, Estimator):
    """3D tilt complementary filter in quaternion form (seed 004); estimate ``q_nb``, n = ENU.

    Streaming: ``update(dt_s, gyro_rad_s, accel_m_s2=None, *, speed_m_s=nan)`` per sample
    (the compiled ``gnomon.kernels.tilt_cf.tilt_cf_sample`` on the filter's own state; a
    fresh filter's first call initialises from the accelerometer, not integrating the gyro;
    ``accel_m_s2`` None, or with a non-finite component: no new accelerometer sample, gyro
    only) and ``update_many`` (a buffer, the compiled batch loop); ``update_reference`` is
    the readable twin. With ``speed_compensation`` ``update`` runs the readable twin (the
    speed bookkeeping is Python's; ``update_many`` compensates in Python, then runs the
    compiled loop). Batch: ``run(rec)`` (initial tilt from the mean of the first
    ``init_samples`` accelerometer samples, ``prepare``; then the compiled loop).
    Signals: ``acc_rejected`` (N,) bool (rejection or a zero accelerometer vector),
    ``bias_rad_s`` (N, 3). State: ``state``, a one-element ``gnomon.kernels.tilt_cf.STATE``
    array (None before the first sample); ``_t`` (s since the first sample) and ``_speed``
    are kept only with ``speed_compensation``.

    ``CompiledIMUUpdate`` gives ``flags`` and the reset of the sample path; ``update`` is
    tilt-cf's own (no magnetometer, ``speed_m_s``, the start row after ``prepare``): it
    looks its kernel up in ``_first_update``.
    """

    name = "tilt-cf"
    summary = "3D tilt complementary filter, first order (+ optional bias integral), seed 004"
    paper = "seed 004"
    kind = "imu"
    reference_frame = "ENU"
    Params = TiltCFParams
    needs = ("gyro", "accel")
    multi_rate = True
    state_fields = ("state", "t_last", "_t", "_speed")
    flag_bits = {"acc_rejected": 1}  # gnomon.kernels.tilt_cf.ACC_REJECTED

    def reset(self) -> None:
        self.state = None  # kernels.tilt_cf.STATE (1,), set by the first sample
        self.t_last = None  # s, last sample processed by ``run``
        self._t = 0.0
        self._speed = _SpeedState()
        # the state holds a start attitude (``prepare``) that the next sample outputs as it
        # is, as ``run``'s first row (not saved by ``get_state``)
        self._start_pending = False
        self._reset_sample_path()

    def set_state(self, state: dict) -> None:
        """Restore a state from ``get_state``."""
        super().set_state(state)
        self._start_pending = False
        self._reset_sample_path()

    @property
    def q(self) -> np.ndarray | None:
        """Current ``q_nb`` (4,) (None before the first sample)."""
        return None if self.state is None else self.state["q"][0].copy()

    @property
    def bias_rad_s(self) -> np.ndarray:
        """Current gyro-bias estimate (3,) rad/s."""
        return np.zeros(3) if self.state is None else self.state["bias"][0].copy()

    @property
    def acc_rejected(self) -> bool:
        """Whether the last sample's accelerometer was not used."""
        return False if self.state is None else bool(self.state["acc_rejected"][0])

    # -- one sample, compiled --
    def update(self, dt_s: float, gyro_rad_s, accel_m_s2=None, *,
               speed_m_s: float = math.nan) -> np.ndarray:
        """Process one sample through the compiled kernel (the arithmetic of ``run``);
        returns ``q_nb`` (4,). ``dt_s``: time since the previous sample (s); ``gyro_rad_s``,
        ``accel_m_s2`` (3,) body (None, or a non-finite component: no new accelerometer
        sample); ``speed_m_s`` forward speed (NaN: no new speed sample) for
        ``speed_compensation`` (then the readable twin runs). ``flags`` says whether the
        accelerometer was used. A non-finite gyro sample raises ``InputError`` and changes
        nothing."""
        g, a = gyro_rad_s, accel_m_s2
        if not (type(g) is _ND and g.dtype is _F8 and g.shape == _S3):
            g = vec3(g, "gyro_rad_s")
        if a is None:
            a = NO_SAMPLE
        elif not (type(a) is _ND and a.dtype is _F8 and a.shape == _S3):
            a = vec3(a, "accel_m_s2")
        sample = self._sample
        if sample is None:  # the first sample after reset, prepare or set_state
            return self._first_update(dt_s, g, a, speed_m_s)
        f = sample(dt_s, g, a, self.state, self._coefficients_record, False, self._q_now)
        self._flags = f
        if f & BAD_GYRO:
            raise InputError(f"non-finite value {g.tolist()} (the sample was not used)",
                             field="gyro_rad_s")
        return self._q_now.copy()

    def _first_update(self, dt_s, g, a, speed_m_s) -> np.ndarray:
        """``update`` before its kernel is looked up: a fresh filter's first sample and
        every sample with ``speed_compensation`` through the readable twin; else the
        kernel's entry point (``gnomon.kernels.entry``), then this sample through it (the
        start row after ``prepare``)."""
        if self.state is None or self.params.speed_compensation:
            return self.update_reference(dt_s, g, None if a is NO_SAMPLE else a,
                                         speed_m_s=speed_m_s)
        from gnomon.kernels.tilt_cf import coefficients, tilt_cf_sample

        self._q_now = np.zeros(4)
        self._coefficients_record = record(coefficients(self.params))
        sample = entry_point(tilt_cf_sample, 0.0, g, a, self.state,
                             self._coefficients_record, False, self._q_now)
        f = sample(dt_s, g, a, self.state, self._coefficients_record, self._start_pending,
                   self._q_now)
        self._flags = f
        if f & BAD_GYRO:
            raise InputError(f"non-finite value {g.tolist()} (the sample was not used)",
                             field="gyro_rad_s")
        self._start_pending = False
        self._sample = sample
        return self._q_now.copy()

    # -- one sample, readable (the kernels' reference) --
    def update_reference(self, dt_s: float, gyro_rad_s, accel_m_s2=None, *,
                         speed_m_s: float = math.nan) -> np.ndarray:
        """The readable twin of ``update`` (numpy, one sample; the tests hold the compiled
        paths to it sample by sample). Same arguments, result and ``flags``."""
        from gnomon.kernels.tilt_cf import new_state

        w = np.asarray(gyro_rad_s, dtype=float)
        if w.shape != (3,):
            raise InputError(f"expected shape (3,), got {w.shape}", field="gyro_rad_s")
        if not np.all(np.isfinite(w)):
            self._flags = BAD_GYRO
            raise InputError(f"non-finite value {w.tolist()} (the sample was not used)",
                             field="gyro_rad_s")
        f = None if accel_m_s2 is None else np.array(accel_m_s2, dtype=float)
        if f is not None and f.shape != (3,):
            raise InputError(f"expected shape (3,), got {f.shape}", field="accel_m_s2")
        if f is not None and not np.all(np.isfinite(f)):
            f = None  # a broken sample is no sample
        if self.state is None and f is None:
            raise InputError("the first sample needs an accelerometer reading (the "
                             "initial tilt)", field="accel_m_s2")
        if self.params.speed_compensation:
            self._t = 0.0 if self.state is None else self._t + dt_s
            self._speed.step(self._t, speed_m_s)
            if f is not None:
                f = f - self._speed.a_lin(w)
        if self.state is None:  # the first sample: the initial tilt, nothing integrated
            self.state = new_state(quat_from_accel(f))
            self.state["acc_rejected"] = not np.linalg.norm(f) > 0.0
        elif self._start_pending:  # the start row after ``prepare``: its attitude as it is
            self._start_pending = False
            self.state["acc_rejected"] = not (f is not None and f @ f > 0.0)
        else:
            tilt_step_reference(self.state.view(np.recarray)[0], self.params, dt_s, w, f)
        self._flags = 1 if self.acc_rejected else 0
        return self.q

    # -- buffers and batch --
    def _accel(self, rec: Recording) -> np.ndarray:
        """``rec``'s accelerometer on the gyro's time base (NaN rows: no new sample), with
        the vehicle's acceleration removed under ``speed_compensation``."""
        accel = rec.on_time_base("accel")  # own rate: NaN rows where no new sample arrived
        if self.params.speed_compensation:
            accel = compensate_accel(rec.t, accel, rec.gyro, self._speed_of(rec))
        return accel

    @staticmethod
    def _speed_of(rec: Recording) -> np.ndarray:
        speed = rec.extra.get("speed_m_s")
        if speed is None:
            raise InputError("speed_compensation needs extra['speed_m_s']; the recording "
                             "has none", field="extra.speed_m_s", file=rec.source or None)
        speed = np.asarray(speed, dtype=float).reshape(-1)
        if speed.shape != rec.t.shape:
            raise InputError(f"expected shape {rec.t.shape}, got {speed.shape}",
                             field="extra.speed_m_s")
        return speed

    def _start_at(self, accel) -> None:
        """The start attitude of ``run``: the tilt of the mean of the first
        ``init_samples`` accelerometer rows with a sample (``accel`` (N, 3), NaN rows: none),
        output as it is by the next row."""
        from gnomon.kernels.tilt_cf import new_state

        first = accel[np.isfinite(accel[:, 0])][:self.params.init_samples]
        self.state = new_state(quat_from_accel(np.mean(first, axis=0)))
        self._start_pending = True
        self._reset_sample_path()

    def prepare(self, rec: Recording) -> None:
        """The initial tilt as ``run`` sets it: from the mean of the first ``init_samples``
        accelerometer samples (compensated under ``speed_compensation``); the next row
        (``update``/``update_many``) outputs it as ``run``'s first row."""
        self._start_at(self._accel(rec))

    def buffer_inputs(self, rec: Recording):
        """``rec`` as ``update_many`` takes it: ``(dt_s, gyro, accel)`` (accelerometer NaN
        rows: no new sample) and, with ``speed_compensation``, ``speed_m_s``."""
        dt = np.diff(rec.t, prepend=rec.t[0])
        kwargs = {"speed_m_s": self._speed_of(rec)} if self.params.speed_compensation else {}
        return (dt, rec.gyro, rec.on_time_base("accel")), kwargs

    def sample_inputs(self, rec: Recording):
        """The rows of ``rec`` as ``update`` takes them: ``(dt_s, gyro, accel)`` (accel None
        where no new sample) and, with ``speed_compensation``, ``speed_m_s``."""
        (dt, gyro, acc), kwargs = self.buffer_inputs(rec)
        for k in range(len(dt)):
            a = None if acc[k, 0] != acc[k, 0] else acc[k]
            yield (dt[k], gyro[k], a), {key: float(v[k]) for key, v in kwargs.items()}

    def update_many(self, dt_s, gyro_rad_s, accel_m_s2=None, *, speed_m_s=None,
                    t_s=None) -> Estimate:
        """A buffer of N samples through the compiled loop, as N calls of ``update``:
        ``dt_s`` (N,) s (each since the previous sample), ``gyro_rad_s`` (N, 3),
        ``accel_m_s2`` (N, 3) m/s² body frame with NaN rows where it has no new sample
        (None: none at all); ``speed_m_s`` (N,) for ``speed_compensation`` (NaN: no new
        speed sample). ``t_s`` (N,) the samples' times for the returned ``Estimate``
        (default: the running sum of ``dt_s``)."""
        from gnomon.kernels.tilt_cf import new_state

        dt, gyro, acc, _ = imu_buffer(dt_s, gyro_rad_s, accel_m_s2)
        n = len(dt)
        fresh = self.state is None
        if fresh and n and not np.isfinite(acc[0]).all():
            raise InputError("the first sample needs an accelerometer reading (the "
                             "initial tilt)", field="accel_m_s2", row=0)
        if self.params.speed_compensation and n:
            speed = (np.full(n, np.nan) if speed_m_s is None
                     else np.asarray(speed_m_s, dtype=float).reshape(-1))
            if speed.shape != (n,):
                raise InputError(f"expected shape ({n},), got {speed.shape}",
                                 field="speed_m_s")
            acc = acc.copy()
            t = self._t
            for k in range(n):  # the readable twin's bookkeeping
                t = 0.0 if fresh and k == 0 else t + dt[k]
                self._speed.step(t, speed[k])
                acc[k] -= self._speed.a_lin(gyro[k])
            self._t = t
        start = self._start_pending
        if fresh and n:  # the first sample: its tilt is the start attitude
            self.state = new_state(quat_from_accel(acc[0]))
            start = True
        self._start_pending = self._start_pending and not n
        return self._batch(dt, gyro, acc, np.cumsum(dt) if t_s is None else t_s, start)

    def _batch(self, dt, gyro, acc, t_s, start: bool) -> Estimate:
        """``update_many`` on checked inputs (``run``'s come from a ``Recording``): the
        compiled ``tilt_cf_batch`` from ``state``; ``start``: row 0 is the start row."""
        from gnomon.kernels.tilt_cf import coefficients
        from gnomon.kernels.tilt_cf import tilt_cf_batch as kernel

        n = len(dt)
        q = np.empty((n, 4))
        bias = np.empty((n, 3))
        rej = np.zeros(n, dtype=np.bool_)
        kernel(dt, np.ascontiguousarray(gyro, dtype=float),
               np.ascontiguousarray(acc, dtype=float), self.state,
               coefficients(self.params), bool(start), q, bias, rej)
        if n:
            self._flags = 1 if rej[-1] else 0
        return Estimate(t=np.asarray(t_s, dtype=float), q=q, estimator=self.name,
                        params=self.params.as_dict(),
                        frames={"reference": "ENU", "body": "sensor"},
                        signals={"acc_rejected": rej, "bias_rad_s": bias})

    def run(self, rec: Recording) -> Estimate:
        """Whole recording through the compiled loop (``prepare`` for a fresh filter, then
        ``update_many`` over its rows; the accelerometer at its own rate, compensated under
        ``speed_compensation`` from a fresh speed state); ``rec.frames['reference']`` must
        be ENU."""
        self.check_inputs(rec)
        accel = self._accel(rec)
        if self.state is None:
            self._start_at(accel)
        dt = np.empty(len(rec))
        dt[0] = self.first_dt(rec)  # 0 for a fresh filter (its start row)
        dt[1:] = np.diff(rec.t)
        start, self._start_pending = self._start_pending, False
        est = self._batch(dt, rec.gyro, accel, rec.t, start)
        self.t_last = float(rec.t[-1])
        est.frames = {"reference": rec.frames.get("reference", "ENU"),
                      "body": rec.frames.get("body", "sensor")}
        return est


def tilt_step_reference(s, params: TiltCFParams, dt_s: float, gyro_rad_s, accel_m_s2) -> None:
    """One step of the 3D filter in place on the state record ``s`` (readable numpy twin of
    ``gnomon.kernels.tilt_cf``: ``predict`` then ``correct_accel``; ``accel_m_s2`` None skips
    the correction)."""
    # gyro: q <- q ⊗ exp((ω - b) dt)
    q = quat_mul(s.q, quat_from_rotvec((np.asarray(gyro_rad_s, float) - s.bias) * dt_s))
    s.q[:] = q / np.linalg.norm(q)
    s.acc_rejected = True
    s.since_acc_s += dt_s
    if accel_m_s2 is None:  # no new sample: no correction
        return
    dt_s, s.since_acc_s = s.since_acc_s, 0.0  # the correction covers the time since the last
    f = np.asarray(accel_m_s2, float)
    nf = float(np.linalg.norm(f))
    g, rel = params.gravity_m_s2, params.accel_rejection_rel
    if not nf > 0.0 or (rel > 0.0 and abs(nf - g) > rel * g):
        return
    s.acc_rejected = False
    m = f / nf
    u = dcm_from_quat(s.q)[2]  # the up direction in body: third row of R_nb
    c = np.cross(m, u)
    sn = float(np.linalg.norm(c))
    if sn > 0.0:
        e = math.atan2(sn, float(m @ u)) / sn * c  # rotation vector taking m onto u
        if params.bias_gain_1_s2 > 0.0:
            s.bias[:] = s.bias - params.bias_gain_1_s2 * dt_s * e
        q = quat_mul(s.q, quat_from_rotvec(dt_s / (params.time_constant_s + dt_s) * e))
        s.q[:] = q / np.linalg.norm(q)


def tilt_cf_batch(t_s, gyro_rad_s, accel_m_s2, q0, params: TiltCFParams, b0=None,
                  t_prev: float = math.nan):
    """Batch run of the 3D filter from ``q0`` at ``t_s[0]`` (numba kernel).

    Returns ``q_nb`` (N, 4), ``bias_rad_s`` (N, 3), ``acc_rejected`` (N,) bool.
    Sample 0 is ``q0`` itself (flagged rejected if its accelerometer vector is zero),
    unless ``t_prev`` (s) is given: then the filter steps from ``q0``, ``b0`` (rad/s)
    at ``t_prev`` to ``t_s[0]`` (a continued run).
    """
    from gnomon.kernels.tilt_cf import coefficients, new_state
    from gnomon.kernels.tilt_cf import tilt_cf_batch as kernel

    t = np.ascontiguousarray(t_s, dtype=float)
    n = t.size
    q = np.empty((n, 4))
    b = np.empty((n, 3))
    rej = np.zeros(n, dtype=np.bool_)
    fresh = math.isnan(t_prev)
    dt = np.empty(n)
    if n:
        dt[0] = 0.0 if fresh else t[0] - t_prev
        dt[1:] = np.diff(t)
    state = new_state(q0, np.zeros(3) if b0 is None else b0)
    kernel(dt, np.ascontiguousarray(gyro_rad_s, dtype=float),
           np.ascontiguousarray(accel_m_s2, dtype=float), state, coefficients(params), fresh,
           q, b, rej)
    return q, b, rej
