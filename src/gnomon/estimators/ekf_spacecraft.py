"""Spacecraft attitude from magnetometer + sun sensor: the seed-001 EKF and a gyro-aided MEKF.

Frames (see the conventions page): ``o`` orbital (z nadir, y minus orbit normal),
``b`` body. The estimate is ``q_ob`` (orbital from body), the recording's
``q_true`` convention; ``R_ob = R(q_ob)`` and the paper's "orbital-to-body"
matrix is ``R(q)^T``.

``EKFSpacecraft`` ("ekf-spacecraft") — the paper's filter (seed 001, "Accuracy of
microsatellite attitude estimation by the Kalman method under uncertainty and
measurement noise", Fig. 1). State ``z = [w_ib_b, q_ob]`` (7). Prediction with
the dynamics model

    J ẇ = -w × (J w + h) - ḣ + m × B_b + T_d,   T_d = 3 μ/r³ ô × (J ô) (gravity gradient,
                                                   ô = R(q)^T [0, 0, 1] the nadir in b)
    q̇ = ½ q ⊗ [0, w - R(q)^T w_io_o]

integrated by RK4 over the sample period ``Ts`` with the known inputs (wheel
momentum ``h``, its rate ``ḣ``, magnetorquer dipole ``m`` times the measured
field) held; covariance with ``Φ = I + F(z_{n+1|n}) Ts``, ``F = ∂f/∂z`` (top-left
block ``J⁻¹([(Jw + h)×] - [w×] J)``, kinematic blocks from ``Ξ(q)`` and ``Ω(w_bo)``).
Measurements: unit field and sun vectors in b, ``y = R(q)^T [b̂_o; ŝ_o]``,
``H = [0 | ∂(R(q)^T v)/∂q]`` evaluated at the predicted quaternion; the
quaternion is renormalised after prediction and update. In eclipse
(``sun_valid`` false) only the magnetometer rows are used. No gyro.

``MEKFSpacecraft`` ("mekf-spacecraft") — the remedy the paper stops short of:
the multiplicative EKF (Lefferts, Markley & Shuster 1982; Markley & Crassidis
2014, ch. 6) driven by the gyro ``w_ib_b``, error state ``[δθ, δb]`` (attitude
error in b, gyro bias), the same vector measurements.

Unit-vector measurements make the filters insensitive to a pure magnitude error
of the field model (an observation the campaign of seed 001 confirms).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gnomon.errors import InputError
from gnomon.estimators.base import Estimate, Estimator, Params, param
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_from_dcm, quat_rotate

__all__ = ["EKFSpacecraft", "MEKFSpacecraft", "EKFSpacecraftParams", "MEKFSpacecraftParams",
           "triad_q_ob", "reference_inputs"]

MU_EARTH = 3.986004418e14  # m^3/s^2


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, float)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / n


def triad_q_ob(v1_b, v2_b, v1_o, v2_o) -> np.ndarray:
    """``q_ob`` by TRIAD: ``v1`` exact (primary), ``v2`` fixes the rotation about it.

    Vectors (3,) in b and o (any length). Raises ``InputError`` for parallel pairs.
    """
    def frame(a, b):
        a = _unit(a)
        c = np.cross(a, b)
        nc = np.linalg.norm(c)
        if nc < 1e-9:
            raise InputError("TRIAD: the two vectors are parallel", field="initial_attitude")
        c = c / nc
        return np.stack([a, c, np.cross(a, c)], axis=1)

    Mb = frame(np.asarray(v1_b, float), np.asarray(v2_b, float))
    Mo = frame(np.asarray(v1_o, float), np.asarray(v2_o, float))
    return quat_from_dcm(Mo @ Mb.T)


def reference_inputs(rec: Recording, orbit_rate_rad_s: float) -> dict:
    """Arrays the filters need from a recording, as contiguous float arrays.

    ``mag_u``, ``sun_u`` (N, 3) measured unit vectors in b (NaN rows of ``sun``
    replaced by zeros, ``sun_valid`` (N,)); ``b_o_u``, ``s_o_u`` (N, 3) reference unit
    vectors in o from the on-board field model ``extra['b_o_model_nT']`` (else the true
    ``extra['b_o_nT']``) and ``extra['s_o']``; ``w_io_o`` (N, 3) rad/s
    from ``extra['w_io_o']`` if present, else ``[0, -orbit_rate, 0]``; ``dt`` (N,).
    """
    n = len(rec)
    mag_u = _unit_or_zero(rec.mag)
    if rec.sun is not None:
        sun_valid = np.asarray(rec.sun_valid, bool).copy()
        sun_u = np.where(sun_valid[:, None], _unit_or_zero(np.nan_to_num(rec.sun)), 0.0)
    else:
        sun_valid = np.zeros(n, bool)
        sun_u = np.zeros((n, 3))
    b_o = rec.extra.get("b_o_model_nT")
    b_o_u = _unit_or_zero(rec.extra["b_o_nT"] if b_o is None else b_o)
    s_o_u = _unit_or_zero(np.nan_to_num(np.asarray(rec.extra["s_o"], float)))
    mag_u = np.where(np.any(b_o_u != 0.0, axis=1)[:, None], mag_u, 0.0)  # no reference: unused
    sun_valid &= np.any(s_o_u != 0.0, axis=1)
    if "w_io_o" in rec.extra:
        w_io_o = np.asarray(rec.extra["w_io_o"], float)
    else:
        w_io_o = np.tile([0.0, -orbit_rate_rad_s, 0.0], (n, 1))
    dt = np.empty(n)
    dt[0] = 0.0
    dt[1:] = np.diff(rec.t)
    c = np.ascontiguousarray
    return {"dt": dt, "mag_u": c(mag_u), "sun_u": c(sun_u), "sun_valid": sun_valid,
            "b_o_u": c(b_o_u), "s_o_u": c(np.nan_to_num(s_o_u)), "w_io_o": c(w_io_o)}


def _unit_or_zero(v) -> np.ndarray:
    """Rows of ``v`` (N, 3) normalised; zero (or non-finite) rows stay zero ("no vector")."""
    v = np.asarray(v, float)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    ok = np.isfinite(n) & (n > 0.0)
    return np.where(ok, v / np.where(ok, n, 1.0), 0.0)


def _initial_q(rec: Recording, inp: dict) -> np.ndarray:
    """``q_ob`` at the first usable sample: TRIAD (sun primary) if the sun is seen there,
    else the field and nadir; the identity (orbit-fixed) without any usable vector."""
    usable = np.flatnonzero(np.any(inp["mag_u"] != 0.0, axis=1))
    if usable.size == 0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    k = int(usable[0])
    try:
        if inp["sun_valid"][k]:
            return triad_q_ob(inp["sun_u"][k], inp["mag_u"][k], inp["s_o_u"][k],
                              inp["b_o_u"][k])
        # no sun: the field alone fixes two axes; take the attitude closest to orbit-fixed
        return triad_q_ob(inp["mag_u"][k], [0.0, 0.0, 1.0], inp["b_o_u"][k],
                          [0.0, 0.0, 1.0])
    except InputError:  # parallel pair (e.g. the field along nadir): orbit-fixed guess
        return np.array([1.0, 0.0, 0.0, 0.0])


def _continue(f, rec: Recording, args: list, per_sample, z0_at: int, P0_at: int, state,
              b0_at: int | None = None):
    """Kernel arguments that continue ``f``'s earlier run, and how many output rows to drop.

    The kernels predict sample k with the inputs of sample k-1, so a continued run
    prepends the last sample the filter saw (``f.last_row``) and starts from the state
    it ended in: the outputs after that row equal those of one uninterrupted run.
    """
    if f.last_row is None:
        return args, 0
    dt0 = f.first_dt(rec)
    for j, i in enumerate(per_sample):
        args[i] = np.ascontiguousarray(np.concatenate([f.last_row[j], args[i]]))
    args[0][1] = dt0
    args[z0_at] = np.asarray(state[0], float).copy()
    args[P0_at] = np.asarray(state[1], float).copy()
    if b0_at is not None:
        args[b0_at] = np.asarray(f.bias, float).copy()
    return args, 1


def _series(rec: Recording, name: str) -> np.ndarray:
    v = rec.extra.get(name)
    if v is None:
        return np.zeros((len(rec), 3))
    return np.ascontiguousarray(np.asarray(v, float).reshape(len(rec), 3))


@dataclass(frozen=True)
class EKFSpacecraftParams(Params):
    """Tuning of :class:`EKFSpacecraft` (SI)."""

    inertia_from_recording: bool = param(
        True, "", "use extra.inertia_model_kg_m2 (the on-board model) when the recording has it")
    inertia_x_kg_m2: float = param(0.40, "kg m^2", "filter's principal moment about x_b")
    inertia_y_kg_m2: float = param(0.58, "kg m^2", "filter's principal moment about y_b")
    inertia_z_kg_m2: float = param(0.55, "kg m^2", "filter's principal moment about z_b")
    sigma_mag: float = param(0.01, "1", "noise of the unit field vector (per component)")
    sigma_sun: float = param(0.005, "1", "noise of the unit sun vector (per component)")
    torque_noise_n_m: float = param(2e-6, "N m", "process noise: unmodelled torque")
    quat_noise_per_rt_s: float = param(1e-5, "1/sqrt(s)", "process noise on q")
    p0_rate_rad_s: float = param(0.002, "rad/s", "initial rate standard deviation")
    p0_quat: float = param(0.05, "1", "initial quaternion standard deviation")
    orbit_rate_rad_s: float = param(0.0011, "rad/s",
                                    "mean motion (used if the recording lacks extra.w_io_o)")
    gravity_gradient: bool = param(True, "", "model the gravity-gradient torque")
    control_inputs: bool = param(
        True, "", "use the recording's wheel momentum and torque and magnetorquer dipole "
        "(extra.h_wheel_b_Nms, hdot_wheel_b_Nm, m_dipole_b_Am2); false: all zero")
    use_sun: bool = param(True, "", "use the sun sensor when valid")
    substeps: int = param(1, "", "RK4 steps per sample in the prediction")

    def validate(self):
        for n in ("inertia_x_kg_m2", "inertia_y_kg_m2", "inertia_z_kg_m2", "sigma_mag",
                  "sigma_sun", "orbit_rate_rad_s"):
            self._require(n, getattr(self, n) > 0, "must be > 0")
        for n in ("torque_noise_n_m", "quat_noise_per_rt_s", "p0_rate_rad_s", "p0_quat"):
            self._require(n, getattr(self, n) >= 0, "must be >= 0")
        self._require("substeps", self.substeps >= 1, "must be >= 1")


@dataclass(frozen=True)
class MEKFSpacecraftParams(Params):
    """Tuning of :class:`MEKFSpacecraft` (SI)."""

    # 3x the magnetometer noise (300 nT in 30,000 nT): with a gyro the filter can afford to
    # lean less on the field model (seed-001 campaign: eclipse peak 0.43 vs 0.88 deg)
    sigma_mag: float = param(0.03, "1", "noise of the unit field vector (per component)")
    sigma_sun: float = param(0.005, "1", "noise of the unit sun vector (per component)")
    gyro_arw_rad_rt_s: float = param(1e-4, "rad/sqrt(s)", "gyro angle random walk")
    gyro_rrw_rad_s_rt_s: float = param(1e-6, "rad/s/sqrt(s)", "gyro bias random walk")
    p0_att_rad: float = param(0.05, "rad", "initial attitude standard deviation")
    p0_bias_rad_s: float = param(0.002, "rad/s", "initial gyro bias standard deviation")
    orbit_rate_rad_s: float = param(0.0011, "rad/s",
                                    "mean motion (used if the recording lacks extra.w_io_o)")
    use_sun: bool = param(True, "", "use the sun sensor when valid")

    def validate(self):
        for n in ("sigma_mag", "sigma_sun", "orbit_rate_rad_s"):
            self._require(n, getattr(self, n) > 0, "must be > 0")
        for n in ("gyro_arw_rad_rt_s", "gyro_rrw_rad_s_rt_s", "p0_att_rad", "p0_bias_rad_s"):
            self._require(n, getattr(self, n) >= 0, "must be >= 0")


class EKFSpacecraft(Estimator):
    """The seed-001 EKF: state (body rate, quaternion), dynamics in the prediction, no gyro."""

    name = "ekf-spacecraft"
    summary = ("Gyro-less EKF [w_ib_b, q_ob] with rigid-body dynamics, magnetometer + sun "
               "sensor (seed 001)")
    needs = ("mag", "sun", "extra.b_o_nT", "extra.s_o")

    Params = EKFSpacecraftParams

    state_fields = ("z", "P", "_prev", "last_row", "t_last")

    def reset(self) -> None:
        self.z = None
        self.P = None
        self._prev = None
        self.last_row = None  # the per-sample kernel inputs of the last sample ``run`` saw
        self.t_last = None

    def update(self, dt_s: float, mag_b, b_o, sun_b=None, s_o=None, *, w_io_o=None,
               h_b=(0.0, 0.0, 0.0), hdot_b=(0.0, 0.0, 0.0), tau_b=(0.0, 0.0, 0.0),
               inertia=None) -> np.ndarray:
        """One sample (streaming); returns ``q_ob`` (4,).

        ``mag_b`` (3,) field in b and ``b_o`` (3,) the model field in o (any one unit);
        ``sun_b``/``s_o`` (3,) sun vectors in b and o, or None (eclipse). ``w_io_o`` (3,)
        rad/s (default ``[0, -orbit_rate, 0]``), wheel momentum ``h_b`` N m s, its rate
        ``hdot_b`` N m and the known external torque ``tau_b`` N m (e.g. magnetorquer
        ``m × B``) at this sample: they drive the prediction to the next sample, as in
        ``run``. The first call initialises (TRIAD) and ``dt_s`` is ignored.
        """
        from gnomon.kernels.ekf_spacecraft import ekf_step

        p = self.params
        mag_u, bo_u = _unit(mag_b), _unit(b_o)
        sun_ok = sun_b is not None and s_o is not None and p.use_sun
        sun_u = _unit(sun_b) if sun_ok else np.zeros(3)
        so_u = _unit(s_o) if sun_ok else np.zeros(3)
        w_io = (np.array([0.0, -p.orbit_rate_rad_s, 0.0]) if w_io_o is None
                else np.asarray(w_io_o, float))
        inputs = (w_io, np.asarray(h_b, float), np.asarray(hdot_b, float),
                  np.asarray(tau_b, float))
        if self.z is None:
            J = self.inertia if inertia is None else np.asarray(inertia, float)
            q0 = (triad_q_ob(sun_u, mag_u, so_u, bo_u) if sun_ok else
                  triad_q_ob(mag_u, [0.0, 0.0, 1.0], bo_u, [0.0, 0.0, 1.0]))
            self.z = np.concatenate([quat_rotate(quat_conj(q0), w_io), q0])
            self.P = np.diag([p.p0_rate_rad_s**2] * 3 + [p.p0_quat**2] * 4)
            Jd = np.diag(J).copy()
            self._Q = np.diag(list((p.torque_noise_n_m / Jd) ** 2) +
                              [p.quat_noise_per_rt_s**2] * 4)
            self._J = (np.ascontiguousarray(J), np.ascontiguousarray(np.linalg.inv(J)))
            self._gg = 3.0 * float(np.linalg.norm(w_io)) ** 2 if p.gravity_gradient else 0.0
        else:
            wp, hp, hdp, tp = self._prev
            innov = np.empty(2)
            self.z, self.P = ekf_step(self.z, self.P, float(dt_s), mag_u, sun_u, sun_ok, bo_u,
                                      so_u, wp, self._J[0], self._J[1], hp, hdp, tp, self._gg,
                                      self._Q, p.sigma_mag**2, p.sigma_sun**2,
                                      int(p.substeps), innov)
        self._prev = inputs
        return self.z[3:7].copy()

    @property
    def inertia(self) -> np.ndarray:
        p = self.params
        return np.diag([p.inertia_x_kg_m2, p.inertia_y_kg_m2, p.inertia_z_kg_m2])

    def _setup(self, rec: Recording, inertia=None):
        p = self.params
        if inertia is not None:
            J = np.asarray(inertia, float)
        elif p.inertia_from_recording and "inertia_model_kg_m2" in rec.extra:
            J = np.asarray(rec.extra["inertia_model_kg_m2"][0], float)
        else:
            J = self.inertia
        inp = reference_inputs(rec, p.orbit_rate_rad_s)
        mag_T = rec.mag_tesla
        def series(name):
            v = _series(rec, name)
            return v if p.control_inputs else np.zeros_like(v)

        tau = np.ascontiguousarray(np.cross(series("m_dipole_b_Am2"), mag_T))
        n_orb = float(np.mean(np.linalg.norm(inp["w_io_o"], axis=1)))
        gg = 3.0 * n_orb**2 if p.gravity_gradient else 0.0
        q0 = _initial_q(rec, inp)
        w0 = quat_rotate(quat_conj(q0), inp["w_io_o"][0])  # orbit-fixed rate: first guess
        z0 = np.concatenate([w0, q0])
        P0 = np.diag([p.p0_rate_rad_s**2] * 3 + [p.p0_quat**2] * 4)
        Jd = np.diag(J).copy()
        Q = np.diag(list((p.torque_noise_n_m / Jd) ** 2) + [p.quat_noise_per_rt_s**2] * 4)
        args = (inp["dt"], inp["mag_u"], inp["sun_u"], inp["sun_valid"], inp["b_o_u"],
                inp["s_o_u"], inp["w_io_o"], np.ascontiguousarray(J),
                np.ascontiguousarray(np.linalg.inv(J)), series("h_wheel_b_Nms"),
                series("hdot_wheel_b_Nm"), tau, gg, z0, P0, Q, p.sigma_mag**2, p.sigma_sun**2,
                bool(p.use_sun), int(p.substeps))
        return args

    def run(self, rec: Recording, compiled: bool = True, inertia=None) -> Estimate:
        """Whole recording. ``inertia`` (3, 3) overrides the params' diagonal tensor (used by
        the uncertainty campaigns); ``compiled=False`` runs the interpreted twin."""
        from gnomon.kernels.ekf_spacecraft import ekf_batch

        self.check_inputs(rec)
        args = list(self._setup(rec, inertia))
        per_sample = (0, 1, 2, 3, 4, 5, 6, 9, 10, 11)  # dt, vectors, w_io_o, h, hdot, tau
        args, skip = _continue(self, rec, args, per_sample, z0_at=13, P0_at=14,
                               state=(self.z, self.P))
        fn = ekf_batch if compiled else getattr(ekf_batch, "py_func", ekf_batch)
        z, pd, innov, P_end = fn(*args)
        self.last_row = [args[i][-1:].copy() for i in per_sample]
        z, pd, innov = z[skip:], pd[skip:], innov[skip:]
        self.z, self.P, self.t_last = z[-1].copy(), P_end, float(rec.t[-1])
        return Estimate(
            t=rec.t, q=z[:, 3:7], estimator=self.name, params=self.params.as_dict(),
            frames={"reference": rec.frames.get("reference", "o"),
                    "body": rec.frames.get("body", "b")},
            signals={"w_ib_b_rad_s": z[:, 0:3], "p_diag": pd, "innovation_mag": innov[:, 0],
                     "innovation_sun": innov[:, 1]},
        )


class MEKFSpacecraft(Estimator):
    """Gyro-aided multiplicative EKF (attitude error + gyro bias), magnetometer + sun sensor."""

    name = "mekf-spacecraft"
    summary = "Multiplicative EKF [dtheta, gyro bias] with gyro, magnetometer + sun sensor"
    needs = ("gyro", "mag", "sun", "extra.b_o_nT", "extra.s_o")

    Params = MEKFSpacecraftParams

    state_fields = ("q", "bias", "P", "_prev", "last_row", "t_last")

    def reset(self) -> None:
        self.q = None
        self.bias = np.zeros(3)
        self.P = None
        self._prev = None
        self.last_row = None  # the per-sample kernel inputs of the last sample ``run`` saw
        self.t_last = None

    def update(self, dt_s: float, gyro_rad_s, mag_b, b_o, sun_b=None, s_o=None, *,
               w_io_o=None) -> np.ndarray:
        """One sample (streaming); returns ``q_ob`` (4,).

        ``gyro_rad_s`` (3,) ``w_ib_b`` of this sample (it propagates to the next one, as in
        ``run``); vectors as in :meth:`EKFSpacecraft.update`. The first call initialises
        (TRIAD) and ``dt_s`` is ignored.
        """
        from gnomon.kernels.ekf_spacecraft import mekf_step

        p = self.params
        mag_u, bo_u = _unit(mag_b), _unit(b_o)
        sun_ok = sun_b is not None and s_o is not None and p.use_sun
        sun_u = _unit(sun_b) if sun_ok else np.zeros(3)
        so_u = _unit(s_o) if sun_ok else np.zeros(3)
        w_io = (np.array([0.0, -p.orbit_rate_rad_s, 0.0]) if w_io_o is None
                else np.asarray(w_io_o, float))
        if self.q is None:
            self.q = (triad_q_ob(sun_u, mag_u, so_u, bo_u) if sun_ok else
                      triad_q_ob(mag_u, [0.0, 0.0, 1.0], bo_u, [0.0, 0.0, 1.0]))
            self.bias = np.zeros(3)
            self.P = np.diag([p.p0_att_rad**2] * 3 + [p.p0_bias_rad_s**2] * 3)
        else:
            g_prev, w_prev = self._prev
            innov = np.empty(2)
            self.q, self.bias, self.P = mekf_step(
                self.q, self.bias, self.P, float(dt_s), g_prev, mag_u, sun_u, sun_ok, bo_u,
                so_u, w_prev, p.gyro_arw_rad_rt_s**2, p.gyro_rrw_rad_s_rt_s**2,
                p.sigma_mag**2, p.sigma_sun**2, innov)
        self._prev = (np.asarray(gyro_rad_s, float), w_io)
        return self.q.copy()

    def _setup(self, rec: Recording):
        p = self.params
        inp = reference_inputs(rec, p.orbit_rate_rad_s)
        q0 = _initial_q(rec, inp)
        P0 = np.diag([p.p0_att_rad**2] * 3 + [p.p0_bias_rad_s**2] * 3)
        return (inp["dt"], np.ascontiguousarray(rec.gyro), inp["mag_u"], inp["sun_u"],
                inp["sun_valid"], inp["b_o_u"], inp["s_o_u"], inp["w_io_o"], q0,
                np.zeros(3), P0, p.gyro_arw_rad_rt_s**2, p.gyro_rrw_rad_s_rt_s**2,
                p.sigma_mag**2, p.sigma_sun**2, bool(p.use_sun))

    def run(self, rec: Recording, compiled: bool = True) -> Estimate:
        """Whole recording; ``compiled=False`` runs the interpreted twin of the kernel."""
        from gnomon.kernels.ekf_spacecraft import mekf_batch

        self.check_inputs(rec)
        per_sample = (0, 1, 2, 3, 4, 5, 6, 7)  # dt, gyro, vectors, w_io_o
        args, skip = _continue(self, rec, list(self._setup(rec)), per_sample, z0_at=8,
                               P0_at=10, state=(self.q, self.P), b0_at=9)
        fn = mekf_batch if compiled else getattr(mekf_batch, "py_func", mekf_batch)
        q, b, pd, innov, P_end = fn(*args)
        self.last_row = [args[i][-1:].copy() for i in per_sample]
        q, b, pd, innov = q[skip:], b[skip:], pd[skip:], innov[skip:]
        self.q, self.bias, self.P = q[-1].copy(), b[-1].copy(), P_end
        self.t_last = float(rec.t[-1])
        return Estimate(
            t=rec.t, q=q, estimator=self.name, params=self.params.as_dict(),
            frames={"reference": rec.frames.get("reference", "o"),
                    "body": rec.frames.get("body", "b")},
            signals={"bias_rad_s": b, "p_diag": pd, "innovation_mag": innov[:, 0],
                     "innovation_sun": innov[:, 1]},
        )
