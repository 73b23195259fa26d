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
in ``tests/test_eskf.py``. The update is the Joseph form, symmetrised. The
readable functions here (numpy matrices) are the reference of the compiled
kernel ``gnomon.kernels.eskf`` that ``run`` uses.

Beyond the paper (which assumes no linear acceleration, an undisturbed field
and known H, Z), for real data — all can be switched off by parameters:

* the inclination is estimated from the data, ``-Z ≈ mean(a·m)/(g|m|)``
  (rotation invariant; ``dip_tau``), unless ``inclination_known``;
* the accelerometer is low-pass filtered in the computed navigation frame,
  where gravity is constant and linear accelerations average out
  (``accel_lowpass_tau``, default 3 s; 0 = the paper's raw accelerometer);
* measurement variances are inflated by ``1 + (dev/gate)²`` when ``| |a| - g |``
  (``accel_gate``) or the field magnitude / dip deviates (``mag_gate``).

The defaults of those and of the noise levels were chosen on the 15 BROAD
trials shipped with the project (``docs/estimators/eskf.md``), so the BROAD
score is not a held-out result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gnomon.errors import InputError
from gnomon.estimators.base import Estimate, Estimator, Params, param
from gnomon.estimators.initial import initial_attitude
from gnomon.recording import Recording
from gnomon.rotation import dcm_from_quat, quat_from_rotvec, quat_mul, skew

__all__ = [
    "EskfParams", "EskfR6Params", "EskfR3Params", "Eskf", "EskfR6", "EskfR3",
    "transition_matrix", "process_noise", "propagate", "measurement_r6", "measurement_r3",
    "measurement_function_r6", "measurement_function_r3", "measurement_matrix_r3_nav",
    "update", "update_dip", "accel_lowpass", "reference_field",
    "count_gain_operations", "paper_gain_operations", "continuous_matrix",
]


# ---------------------------------------------------------------- model (readable reference)
def transition_matrix(w_hat_b, dt: float) -> np.ndarray:
    """First-order transition ``Φ = I + F dt``, ``F = [-[ω̂×]  -½I; 0  0]`` (6x6).

    ``w_hat_b`` (3,) bias-corrected rate, rad/s, body frame; ``dt`` s.
    """
    F = continuous_matrix(w_hat_b)
    return np.eye(6) + F * dt


def continuous_matrix(w_b) -> np.ndarray:
    """The paper's ``F = [-[ω×]  -½I₃; 0₃  0₃]`` (6x6) for the rate ``w_b`` (rad/s, body)."""
    F = np.zeros((6, 6))
    F[:3, :3] = -skew(np.asarray(w_b, float))
    F[:3, 3:] = -0.5 * np.eye(3)
    return F


def process_noise(dt: float, gyro_noise: float, bias_rw: float) -> np.ndarray:
    """Discrete ``Q = diag(¼ σ_g² dt I, σ_b² dt I)``: gyro noise density σ_g (rad/s/√Hz)
    enters ``δė`` with the factor -½; bias random walk σ_b (rad/s/√s)."""
    return np.diag([0.25 * gyro_noise**2 * dt] * 3 + [bias_rw**2 * dt] * 3)


def propagate(q, b, P, gyro_b, dt, gyro_noise, bias_rw):
    """Strapdown step: ``q ← normalise(q ⊗ exp((ω̃ - b̂) dt))``, ``P ← Φ P Φᵀ + Q`` (symmetrised).

    q (4,) ``q_nb``; b (3,) bias estimate rad/s; P (6, 6); gyro_b (3,) rad/s.
    Returns new ``(q, P)``.
    """
    w = np.asarray(gyro_b, float) - b
    q = quat_mul(q, quat_from_rotvec(w * dt))
    q = q / np.linalg.norm(q)
    Phi = transition_matrix(w, dt)
    P = Phi @ P @ Phi.T + process_noise(dt, gyro_noise, bias_rw)
    return q, 0.5 * (P + P.T)


def measurement_function_r6(q, g, mag_h, mag_z) -> np.ndarray:
    """Predicted ``[Ĉ_bn g_n; Ĉ_bn m_n]`` (6,) for ``q = q_nb`` (noise-free readings in body)."""
    C_bn = dcm_from_quat(q).T
    return np.concatenate([C_bn @ [0.0, 0.0, g], C_bn @ [0.0, mag_h, -mag_z]])


def measurement_r6(q, accel_b, mag_b, g, mag_h, mag_z):
    """Full model: innovation ``y`` (6,) and ``D`` (6, 6) = ``[2[â×] 0; 2[m̂×] 0]``."""
    h = measurement_function_r6(q, g, mag_h, mag_z)
    y = np.concatenate([accel_b, mag_b]) - h
    D = np.zeros((6, 6))
    D[:3, :3] = 2.0 * skew(h[:3])
    D[3:, :3] = 2.0 * skew(h[3:])
    return y, D


def measurement_function_r3(q, accel_b, mag_b, g, mag_h) -> np.ndarray:
    """``[ã_x/g, ã_y/g, m̃_x/H]`` with ``ã = Ĉ_nb a``, ``m̃ = Ĉ_nb m`` for the estimate ``q``."""
    C_nb = dcm_from_quat(q)
    a_n = C_nb @ accel_b
    m_n = C_nb @ mag_b
    return np.array([a_n[0] / g, a_n[1] / g, m_n[0] / mag_h])


def measurement_matrix_r3_nav(tan_i: float) -> np.ndarray:
    """``D_n`` (3x3): reduced measurement vs the error rotation in the computed navigation frame.

    The paper prints ``[[0, 2, 0], [-2, 0, 0], [0, -2 tan I, -2]] = -D_n`` for its
    own error definition.
    """
    return np.array([[0.0, -2.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0 * tan_i, 2.0]])


def measurement_r3(q, accel_b, mag_b, g, mag_h, mag_z):
    """Reduced model: measurement ``y`` (3,) (predicted 0), ``D`` (3, 6) = ``[D_n Ĉ_nb 0]``."""
    y = measurement_function_r3(q, accel_b, mag_b, g, mag_h)
    D = np.zeros((3, 6))
    D[:, :3] = measurement_matrix_r3_nav(mag_z / mag_h) @ dcm_from_quat(q)
    return y, D


def update(q, b, P, y, D, R):
    """Kalman update (Joseph form, symmetrised) and injection of the error estimate.

    Returns ``(q, b, P, dx)`` with ``dx = K y`` the estimated error ``[δe; δb]``.
    """
    S = D @ P @ D.T + R
    K = np.linalg.solve(S, D @ P).T          # P Dᵀ S⁻¹ (S, P symmetric)
    dx = K @ y
    IKD = np.eye(6) - K @ D
    P = IKD @ P @ IKD.T + K @ R @ K.T
    P = 0.5 * (P + P.T)
    q = quat_mul(q, np.array([1.0, dx[0], dx[1], dx[2]]))
    q = q / np.linalg.norm(q)
    return q, b + dx[3:], P, dx


# ---------------------------------------------------------------- initialisation
def accel_lowpass(q_nb, accel_b, lp_n, w: float):
    """Low-pass of the accelerometer in the computed navigation frame.

    ``lp_n ← lp_n + w (Ĉ_nb a - lp_n)`` (``lp_n`` None or ``w = 1``: restart), returns
    ``(Ĉ_bn lp_n, lp_n)``: the filtered reading in the body frame and the new state.
    Gravity is constant in the navigation frame while a linear acceleration averages
    out there (cf. VQF's inertial-frame low-pass, Laidig & Seel, Inf. Fusion 2023).
    """
    C = dcm_from_quat(q_nb)
    a_n = C @ np.asarray(accel_b, float)
    lp = a_n.copy() if lp_n is None else lp_n + w * (a_n - lp_n)
    return C.T @ lp, lp


def update_dip(dip_s: float, count: float, accel_b, mag_b, dt: float, tau: float, g: float):
    """Running mean of ``a·m / (g |m|)`` ≈ ``cos(angle(a, m))`` = ``-Z`` of the normalised
    field (rotation invariant, so it can be averaged while the body moves; dividing by
    ``g`` rather than ``|a|`` keeps accelerometer noise from biasing it: ``E|a| > g``).

    ``count += 1``, ``w = max(1/count, dt/tau)``, ``s += w (cos - s)``; ``tau <= 0``
    leaves it unchanged. Returns ``(s, count)``; the reference is
    ``Z = -s``, ``H = sqrt(1 - s²)``.
    """
    if tau <= 0.0:
        return dip_s, count
    a = np.asarray(accel_b, float)
    m = np.asarray(mag_b, float)
    count = count + 1.0
    w = max(1.0 / count, dt / tau)
    cos = (a @ m) / (g * np.sqrt(m @ m))
    return dip_s + w * (cos - dip_s), count


def reference_field(q_nb, mag_b) -> tuple[float, float, float]:
    """``(|B0|, H, Z)``: field magnitude (input unit) and normalised horizontal / downward
    components of ``mag_b`` seen in the navigation frame of ``q_nb``."""
    m = np.asarray(mag_b, float)
    b0 = float(np.linalg.norm(m))
    m_n = dcm_from_quat(q_nb) @ (m / b0)
    return b0, float(np.hypot(m_n[0], m_n[1])), float(-m_n[2])


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
    inclination_known: bool = param(False, "", "use the given inclination instead of "
                                    "estimating it (the paper's assumption: H, Z known)")
    inclination: float = param(1.0, "rad", "magnetic inclination I (tan I = Z/H, positive "
                               "downward), used when inclination_known")

    def validate(self) -> None:
        self._require("measurement", self.measurement in ("r6", "r3"), "must be 'r6' or 'r3'")
        for name in ("gyro_noise", "bias_rw", "init_att_std", "init_bias_std"):
            self._require(name, getattr(self, name) >= 0.0, "must be >= 0")
        for name in ("accel_noise", "mag_noise", "gravity"):
            self._require(name, getattr(self, name) > 0.0, "must be > 0")
        for name in ("init_time", "accel_gate", "mag_gate", "dip_tau", "accel_lowpass_tau"):
            self._require(name, getattr(self, name) >= 0.0, "must be >= 0")


@dataclass(frozen=True)
class EskfR6Params(EskfParams):
    """``EskfParams`` with the full 6-component measurement by default."""

    measurement: str = param("r6", "", "measurement model: 'r6' or 'r3'")


@dataclass(frozen=True)
class EskfR3Params(EskfParams):
    """``EskfParams`` with the paper's reduced 3-component measurement by default."""

    measurement: str = param("r3", "", "measurement model: 'r6' or 'r3'")


class Eskf(Estimator):
    """Error-state quaternion KF AHRS (seed 002); see the module docstring.

    ``run(rec)`` uses the compiled kernel. ``update(gyro, accel, mag, dt)``
    processes one sample with the readable reference (slow; streaming use);
    the first call initialises from that sample.
    Signals: ``bias_rad_s`` (N, 3), ``innovation`` (N, r), ``cov_diag`` (N, 6)
    (attitude part in rad² of ``δe`` = half-angles, bias part in (rad/s)²).
    """

    name = "eskf"
    summary = "error-state quaternion KF AHRS, full or reduced measurement (seed 002)"
    Params = EskfParams
    needs = ("gyro", "accel", "mag")
    state_fields = ("q", "b", "P", "b0_mag", "acc_lp", "dip", "t_last")

    def reset(self) -> None:
        self.q = None
        self.b = np.zeros(3)
        self.P = None
        self.b0_mag = None   # reference field magnitude, input unit
        self.acc_lp = None   # low-passed accelerometer in the navigation frame, m/s²
        self.dip = None      # (running mean of cos(a, m) = -Z, sample count)
        self.t_last = None   # s, last sample processed by ``run``

    def _init_state(self, accel_b, mag_b):
        """Initialise from windows ``accel_b``, ``mag_b`` (k, 3) of the first samples.

        Rows with a zero accelerometer or magnetometer vector (dropouts) are left
        out; without any usable row the attitude starts at the identity with a
        reference field of inclination 60° until the data say otherwise.
        """
        p = self.params
        a = np.atleast_2d(np.asarray(accel_b, float))
        m = np.atleast_2d(np.asarray(mag_b, float))
        na, nm = np.linalg.norm(a, axis=1), np.linalg.norm(m, axis=1)
        ok = (na > 0) & (nm > 0)
        self.q = initial_attitude(a[ok], m[ok], samples=len(a)) if ok.any() else \
            np.array([1.0, 0.0, 0.0, 0.0])
        self.b = np.zeros(3)
        self.b0_mag = float(nm[nm > 0].mean()) if (nm > 0).any() else 1.0
        cos = np.sum(a[ok] * m[ok], 1) / (p.gravity * nm[ok])
        self.dip = ((float(cos.mean()), float(len(cos))) if ok.any()
                    else (-float(np.sin(np.radians(60.0))), 1.0))
        if p.inclination_known:
            self.dip = (-float(np.sin(p.inclination)), float(max(len(cos), 1)))
        if abs(self.dip[0]) >= 1.0 - 1e-9:
            raise InputError("magnetometer parallel to gravity at initialisation: "
                             "heading undefined", field="mag")
        self.P = np.diag([(0.5 * p.init_att_std) ** 2] * 3 + [p.init_bias_std**2] * 3)

    @property
    def field(self) -> tuple[float, float]:
        """Current normalised reference field ``(H, Z)`` (``H² + Z² = 1``)."""
        s = self.dip[0]
        return float(np.sqrt(1.0 - s * s)), float(-s)

    def _R(self, fa=1.0, fm=1.0):
        p = self.params
        h, _ = self.field
        if p.measurement == "r6":
            return np.diag([p.accel_noise**2 * fa] * 3 + [p.mag_noise**2 * fm] * 3)
        ra = p.accel_noise**2 * fa / p.gravity**2
        return np.diag([ra, ra, p.mag_noise**2 * fm / h**2])

    def update(self, gyro_b, accel_b, mag_b, dt: float):
        """One sample (reference implementation): gyro rad/s, accel m/s², mag any unit
        (the first call fixes the reference magnitude); returns ``q_nb`` (4,)."""
        p = self.params
        if self.q is None:
            self._init_state(accel_b, mag_b)
        m = np.asarray(mag_b, float) / self.b0_mag
        a = np.asarray(accel_b, float)
        self.q, self.P = propagate(self.q, self.b, self.P, gyro_b, dt, p.gyro_noise, p.bias_rw)
        if not (np.linalg.norm(a) > 0 and np.linalg.norm(m) > 0):  # dropout: propagate only
            self.innovation = np.zeros(6 if p.measurement == "r6" else 3)
            return self.q.copy()
        fa = _gate(abs(np.linalg.norm(a) - p.gravity), p.accel_gate)
        cos_am = (a @ m) / (p.gravity * np.linalg.norm(m))
        fm = _gate(max(abs(np.linalg.norm(m) - 1.0), abs(cos_am - self.dip[0])), p.mag_gate)
        tau = 0.0 if (p.inclination_known or fa >= 2.0 or fm >= 2.0) else p.dip_tau
        self.dip = update_dip(*self.dip, a, m, dt, tau, p.gravity)
        h, z = self.field
        if p.accel_lowpass_tau > 0.0:
            w = 1.0 if self.acc_lp is None else min(1.0, dt / p.accel_lowpass_tau)
            a, self.acc_lp = accel_lowpass(self.q, a, self.acc_lp, w)
        meas = measurement_r6 if p.measurement == "r6" else measurement_r3
        y, D = meas(self.q, a, m, p.gravity, h, z)
        self.q, self.b, self.P, _ = update(self.q, self.b, self.P, y, D, self._R(fa, fm))
        self.innovation = y
        return self.q.copy()

    def run(self, rec: Recording) -> Estimate:
        """Filter a whole recording (compiled kernel), continuing from the current state
        (a fresh or reset filter starts anew).

        Initialisation: TRIAD on the mean accelerometer and magnetometer over the
        first ``init_time`` seconds (at least one sample); the reference field
        ``[0, H, -Z]`` and ``|B0|`` are taken from the same samples.
        """
        from gnomon.kernels import eskf as kern

        self.check_inputs(rec)
        p = self.params
        mag_T = rec.mag_tesla
        dt = np.empty(len(rec))
        dt[0] = self.first_dt(rec)
        dt[1:] = np.diff(rec.t)
        if self.q is None:
            n_init = max(1, int(np.searchsorted(rec.t, rec.t[0] + p.init_time, side="right")))
            self._init_state(rec.accel[:n_init], mag_T[:n_init])
        n = len(rec)
        q_out = np.empty((n, 4))
        b_out = np.empty((n, 3))
        innov = np.zeros((n, 6))
        pdiag = np.empty((n, 6))
        P_end = np.empty((6, 6))
        state_end = np.empty(6)
        skipped = np.zeros(n, np.bool_)
        lp0 = np.zeros(3) if self.acc_lp is None else np.asarray(self.acc_lp, float)
        mode = kern.MODE_R6 if p.measurement == "r6" else kern.MODE_R3
        kern.run_batch(
            np.ascontiguousarray(rec.gyro), np.ascontiguousarray(rec.accel),
            np.ascontiguousarray(mag_T / self.b0_mag), dt, self.q.copy(), self.b.copy(),
            self.P.copy(), p.gyro_noise**2, p.bias_rw**2, p.accel_noise**2, p.mag_noise**2,
            p.gravity, self.dip[0], self.dip[1], 0.0 if p.inclination_known else p.dip_tau,
            p.accel_lowpass_tau, p.accel_gate, p.mag_gate, mode,
            q_out, b_out, innov, pdiag, P_end, lp0, self.acc_lp is not None, state_end,
            skipped)
        self.q, self.b, self.P = q_out[-1].copy(), b_out[-1].copy(), P_end
        self.dip = (float(state_end[0]), float(state_end[1]))
        self.acc_lp = state_end[2:5].copy() if state_end[5] else None
        self.t_last = float(rec.t[-1])
        r = 6 if p.measurement == "r6" else 3
        return Estimate(
            t=rec.t.copy(), q=q_out, estimator=self.name, params=p.as_dict(),
            frames={"reference": "ENU", "body": rec.frames.get("body", "sensor")},
            signals={"bias_rad_s": b_out, "innovation": innov[:, :r], "cov_diag": pdiag,
                     "update_skipped": skipped},
        )


def _gate(dev: float, gate: float) -> float:
    """Variance inflation ``1 + (dev/gate)²`` (1 when ``gate <= 0``), as the kernel."""
    if gate <= 0.0:
        return 1.0
    return 1.0 + (dev / gate) ** 2


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


class _Counted:
    """A float that counts the arithmetic done with it (shared counter dict)."""

    __slots__ = ("v", "c")

    def __init__(self, v, c):
        self.v = float(v)
        self.c = c

    def _o(self, other):
        return other.v if isinstance(other, _Counted) else float(other)

    def __mul__(self, o):
        self.c["mul"] += 1
        return _Counted(self.v * self._o(o), self.c)

    __rmul__ = __mul__

    def __truediv__(self, o):
        self.c["div"] += 1
        return _Counted(self.v / self._o(o), self.c)

    def __rtruediv__(self, o):
        self.c["div"] += 1
        return _Counted(self._o(o) / self.v, self.c)

    def __add__(self, o):
        self.c["add"] += 1
        return _Counted(self.v + self._o(o), self.c)

    __radd__ = __add__

    def __sub__(self, o):
        self.c["add"] += 1
        return _Counted(self.v - self._o(o), self.c)

    def __rsub__(self, o):
        self.c["add"] += 1
        return _Counted(self._o(o) - self.v, self.c)


def count_gain_operations(r: int, rng: np.random.Generator | None = None) -> dict[str, int]:
    """Operations the implemented gain (``gnomon.kernels.eskf.gain``, the source the
    kernel compiles) performs for ``n = 6`` states and ``r`` measurements.

    Runs that function on counting numbers. Returns ``mul`` (multiplications),
    ``div`` (divisions), ``add`` (additions and subtractions) and ``mul_div``
    (multiplications + divisions, comparable with the paper's M).
    Also checks the counted run's gain against numpy (raises if wrong).
    """
    from gnomon.kernels.eskf import gain

    rng = rng or np.random.default_rng(0)
    c = {"mul": 0, "div": 0, "add": 0}
    G = rng.normal(size=(6, 6))
    P = G @ G.T + 6 * np.eye(6)
    D1 = rng.normal(size=(r, 3))
    Rd = rng.uniform(0.5, 1.5, r)

    def wrap(a):
        out = np.empty(a.shape, dtype=object)
        for idx in np.ndindex(a.shape):
            out[idx] = _Counted(a[idx], c)
        return out

    PDt = np.empty((6, r), dtype=object)
    S = np.empty((r, r), dtype=object)
    K = np.empty((6, r), dtype=object)
    Pc, D1c, Rc = wrap(P), wrap(D1), wrap(Rd)
    c.update(mul=0, div=0, add=0)
    gain(Pc, D1c, Rc, r, PDt, S, K)
    Kv = np.array([[k.v for k in row] for row in K])
    D = np.zeros((r, 6))
    D[:, :3] = D1
    K_ref = P @ D.T @ np.linalg.inv(D @ P @ D.T + np.diag(Rd))
    if not np.allclose(Kv, K_ref, rtol=1e-9, atol=1e-12):
        raise AssertionError("counted gain disagrees with numpy")
    return {"mul": c["mul"], "div": c["div"], "add": c["add"], "mul_div": c["mul"] + c["div"]}
