"""Spacecraft attitude from magnetometer + sun sensor without a gyro: the seed-001 EKF.

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

Its gyro-aided remedy is the one spacecraft MEKF, :mod:`gnomon.estimators.mekf`
(``mekf``; ``mekf-spacecraft`` is its seed-001 preset).

``run`` (``prepare``: the coefficients and the initial state of a recording, then its
rows) and ``update_many`` (a buffer of rows) call the kernel
``gnomon.kernels.ekf_spacecraft.ekf_batch``, ``update`` (one row) ``ekf_sample``, both one
``ekf_row`` per sample (coefficients ``coefficients(params, J, gg)``, state record
``STATE`` holding ``z``, ``P`` and the known inputs of the last sample): any split of a
recording into ``update``/``update_many`` calls gives ``run``'s result. The readable twin
is the kernel's ``.py_func`` (``run(rec, compiled=False)``; ``update_reference`` runs
``ekf_row.py_func`` per sample). Streaming::

    update(dt_s, gyro_rad_s=None, *, mag_b=None, mag_ref_o=None, sun_b=None,
           sun_ref_o=None, w_io_o_rad_s=None, h_b_Nms=None, hdot_b_Nm=None,
           tau_b_Nm=None, inertia_kg_m2=None) -> q_ob (4,)

``gyro_rad_s`` is ignored (the filter has no gyro: the rate is a state); ``mag_b``/``sun_b``
(3,) measured in b and ``mag_ref_o``/``sun_ref_o`` (3,) models in o (any one unit, only
directions are used; None, zero or non-finite = no sample, e.g. eclipse; a vector
without its model is not used); ``w_io_o_rad_s`` (3,) rad/s
(default ``[0, −orbit_rate, 0]``); the wheel momentum ``h_b_Nms``, its rate ``hdot_b_Nm``
and the known external torque ``tau_b_Nm`` (e.g. magnetorquer ``m × B``) at this sample
(None: zero) drive the prediction to the next sample, as in ``run``.

Unit-vector measurements make the filters insensitive to a pure magnitude error
of the field model (an observation the campaign of seed 001 confirms).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gnomon.errors import InputError
from gnomon.estimators.base import Estimate, Estimator, Params, param
from gnomon.estimators.spacecraft_update import CompiledSampleUpdate, buffer, vec
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_from_dcm, quat_rotate

__all__ = ["EKFSpacecraft", "EKFSpacecraftParams", "triad_q_ob", "reference_inputs"]

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


class EKFSpacecraft(CompiledSampleUpdate, Estimator):
    """The seed-001 EKF: state (body rate, quaternion), dynamics in the prediction, no gyro."""

    name = "ekf-spacecraft"
    summary = ("Gyro-less EKF [w_ib_b, q_ob] with rigid-body dynamics, magnetometer + sun "
               "sensor (seed 001)")
    paper = "seed 001"
    kind = "spacecraft"
    reference_frame = "o"
    needs = ("mag", "sun", "extra.b_o_nT", "extra.s_o")

    Params = EKFSpacecraftParams

    state_fields = ("state", "t_last", "_coef")

    def reset(self) -> None:
        self.state = None  # the kernel's STATE record once started
        self.t_last = None
        self._coef = None  # the kernel's coefficients (``prepare``, or the first update)
        self._w_io0 = np.array([0.0, -self.params.orbit_rate_rad_s, 0.0])
        self._reset_sample_path()

    @property
    def z(self):
        """``[w_ib_b (rad/s), q_ob]`` (7,) now (a copy), None before the first sample."""
        return None if self.state is None else self.state["z"][0].copy()

    @property
    def P(self):
        """Covariance (7, 7) now (a copy), None before the first sample."""
        return None if self.state is None else self.state["P"][0].copy()

    def _new_state(self, z0) -> np.ndarray:
        """A fresh state at ``z0``: its first sample is the initial state (no step)."""
        from gnomon.kernels.ekf_spacecraft import STATE

        p = self.params
        state = np.zeros(1, STATE)
        state["z"][0] = z0
        state["P"][0] = np.diag([p.p0_rate_rad_s**2] * 3 + [p.p0_quat**2] * 4)
        state["pending"][0] = True
        return state

    # ---------------------------------------------------------------- streaming
    def _start_from_sample(self, mag_b, mag_o, sun_b, sun_o, w_io, inertia_kg_m2) -> None:
        """A streamed start: the coefficients (the inertia ``inertia_kg_m2`` (3, 3), else the
        params' diagonal tensor; the gravity gradient from this sample's ``|w_io_o|``) if
        there are none, the state (TRIAD of this sample, the orbit-fixed rate) if none."""
        from gnomon.kernels.ekf_spacecraft import coefficients

        p = self.params
        if self._coef is None:
            J = self.inertia if inertia_kg_m2 is None else np.asarray(inertia_kg_m2, float)
            gg = 3.0 * float(np.linalg.norm(w_io)) ** 2 if p.gravity_gradient else 0.0
            self._coef = coefficients(p, J, gg)
        if self.state is None:
            sun_ok = p.use_sun and bool(np.all(np.isfinite(sun_b)) and np.all(np.isfinite(sun_o)))
            q0 = _first_q(*(_vector(v) for v in (mag_b, mag_o, sun_b, sun_o)), sun_ok)
            self.state = self._new_state(np.concatenate([quat_rotate(quat_conj(q0), w_io), q0]))

    def _sample_kernel(self):
        """``update``'s kernel (``CompiledSampleUpdate``): ``ekf_sample`` with the filter's
        ``Coefficients`` (a named tuple: the batch's compiled phases serve it as they are)."""
        from gnomon.kernels.ekf_spacecraft import ekf_sample

        return ekf_sample, self._coef

    def _inputs(self, mag_b, mag_ref_o, sun_b, sun_ref_o, w_io_o_rad_s, h_b_Nms, hdot_b_Nm,
                tau_b_Nm):
        """A streamed sample's vectors for the kernel (None: none; the inputs: zero)."""
        if sun_b is None or sun_ref_o is None:
            sun_b = sun_ref_o = None
        zero = _ZERO3
        return (vec(mag_b, "mag_b"), vec(mag_ref_o, "mag_ref_o"), vec(sun_b, "sun_b"),
                vec(sun_ref_o, "sun_ref_o"),
                self._w_io0 if w_io_o_rad_s is None else vec(w_io_o_rad_s, "w_io_o_rad_s"),
                zero if h_b_Nms is None else vec(h_b_Nms, "h_b_Nms"),
                zero if hdot_b_Nm is None else vec(hdot_b_Nm, "hdot_b_Nm"),
                zero if tau_b_Nm is None else vec(tau_b_Nm, "tau_b_Nm"))

    def update(self, dt_s: float, gyro_rad_s=None, *, mag_b=None, mag_ref_o=None, sun_b=None,
               sun_ref_o=None, w_io_o_rad_s=None, h_b_Nms=None, hdot_b_Nm=None,
               tau_b_Nm=None, inertia_kg_m2=None) -> np.ndarray:
        """One sample through the compiled kernel (the arithmetic of ``run``; arguments in
        the module docstring); returns ``q_ob`` (4,). ``update_reference`` is the readable
        twin.

        The first call of a fresh filter initialises (TRIAD) and ``dt_s`` is ignored; the
        inertia (``inertia_kg_m2`` (3, 3), else the params' diagonal tensor) and the
        gravity-gradient coefficient (from ``|w_io_o|``) are taken at the first streamed
        sample (after ``prepare``/``run``: those of the recording).
        """
        x = self._inputs(mag_b, mag_ref_o, sun_b, sun_ref_o, w_io_o_rad_s, h_b_Nms,
                         hdot_b_Nm, tau_b_Nm)
        if self._coef is None or self.state is None:
            self._start_from_sample(*x[:5], inertia_kg_m2)
        return self._call(float(dt_s), *x, self.state)

    def update_reference(self, dt_s: float, gyro_rad_s=None, *, mag_b=None, mag_ref_o=None,
                         sun_b=None, sun_ref_o=None, w_io_o_rad_s=None, h_b_Nms=None,
                         hdot_b_Nm=None, tau_b_Nm=None, inertia_kg_m2=None) -> np.ndarray:
        """The readable twin of ``update``: ``ekf_row.py_func`` (the kernel's row interpreted,
        its phases as compiled) on the same state. Same arguments and result."""
        from gnomon.kernels.ekf_spacecraft import ekf_row, workspace

        x = self._inputs(mag_b, mag_ref_o, sun_b, sun_ref_o, w_io_o_rad_s, h_b_Nms,
                         hdot_b_Nm, tau_b_Nm)
        if self._coef is None or self.state is None:
            self._start_from_sample(*x[:5], inertia_kg_m2)
        ekf_row.py_func(self._coef, self.state.view(np.recarray)[0], float(dt_s), *x[:4],
                        True, *x[4:], np.empty(2), workspace.py_func())
        return self.state["z"][0, 3:7].copy()

    def update_many(self, dt_s, gyro_rad_s=None, *, mag_b=None, mag_ref_o=None, sun_b=None,
                    sun_ref_o=None, w_io_o_rad_s=None, h_b_Nms=None, hdot_b_Nm=None,
                    tau_b_Nm=None, inertia_kg_m2=None, t_s=None) -> Estimate:
        """A buffer of N samples through the compiled kernel, as N calls of ``update``:
        ``dt_s`` (N,) s, the keyword inputs (N, 3) with NaN rows where there is no sample
        (None: none at all; the orbital rate ``[0, −orbit_rate, 0]``, the known inputs
        zero); ``gyro_rad_s`` ignored. ``t_s`` (N,) the samples' times (default: the
        running sum of ``dt_s``)."""
        zero = np.zeros(3)
        dt, _, x = buffer(dt_s, None, mag_b=(mag_b, 3, None), b_o=(mag_ref_o, 3, None),
                          sun_b=(sun_b, 3, None), s_o=(sun_ref_o, 3, None),
                          w_io_o=(w_io_o_rad_s, 3, self._w_io0), h=(h_b_Nms, 3, zero),
                          hdot=(hdot_b_Nm, 3, zero), tau=(tau_b_Nm, 3, zero))
        x["dt"] = dt
        x["sun_valid"] = np.ones(len(dt), bool)
        if (self._coef is None or self.state is None) and len(dt):
            self._start_from_sample(*(x[k][0] for k in ("mag_b", "b_o", "sun_b", "s_o",
                                                        "w_io_o")), inertia_kg_m2)
        return self._batch(x, np.cumsum(dt) if t_s is None else t_s)

    @property
    def inertia(self) -> np.ndarray:
        p = self.params
        return np.diag([p.inertia_x_kg_m2, p.inertia_y_kg_m2, p.inertia_z_kg_m2])

    # ---------------------------------------------------------------- a recording
    def _rows(self, rec: Recording, first_dt: float = 0.0) -> dict:
        """The kernel inputs of ``rec``'s rows: ``dt`` (N,) s (``first_dt`` at row 0), the
        measured ``mag_b``, ``sun_b`` (b) with ``sun_valid``, their models ``b_o`` (the
        on-board field model ``extra['b_o_model_nT']``, else the true ``b_o_nT``), ``s_o``
        (o), ``w_io_o`` (``extra['w_io_o']``, else ``[0, −orbit_rate, 0]``), the known
        inputs ``h``, ``hdot`` (the wheels) and ``tau`` (the magnetorquer's ``m × B``),
        zero without ``control_inputs``."""
        p = self.params
        n = len(rec)
        dt = np.empty(n)
        dt[0] = first_dt
        dt[1:] = np.diff(rec.t)

        def series(name):
            v = _series(rec, name)
            return v if p.control_inputs else np.zeros_like(v)

        c = np.ascontiguousarray
        b_o = rec.extra.get("b_o_model_nT")
        w_io = rec.extra.get("w_io_o")
        return {"dt": dt, "mag_b": c(rec.mag, float),
                "b_o": c(rec.extra["b_o_nT"] if b_o is None else b_o, float),
                "sun_b": c(rec.sun, float), "s_o": c(rec.extra["s_o"], float),
                "sun_valid": c(rec.sun_valid, bool),
                "w_io_o": (np.tile(self._w_io0, (n, 1)) if w_io is None
                           else c(np.asarray(w_io, float).reshape(n, 3))),
                "h": series("h_wheel_b_Nms"), "hdot": series("hdot_wheel_b_Nm"),
                "tau": c(np.cross(series("m_dipole_b_Am2"), rec.mag_tesla))}

    def buffer_inputs(self, rec: Recording):
        """``rec`` as ``update_many`` takes it: ``((dt, gyro), {mag_b, mag_ref_o, sun_b (NaN
        where not valid), sun_ref_o, w_io_o_rad_s, h_b_Nms, hdot_b_Nm, tau_b_Nm})``."""
        x = self._rows(rec)
        return (x["dt"], rec.gyro), {
            "mag_b": x["mag_b"], "mag_ref_o": x["b_o"],
            "sun_b": np.where(x["sun_valid"][:, None], x["sun_b"], np.nan),
            "sun_ref_o": x["s_o"], "w_io_o_rad_s": x["w_io_o"], "h_b_Nms": x["h"],
            "hdot_b_Nm": x["hdot"], "tau_b_Nm": x["tau"]}

    def sample_inputs(self, rec: Recording):
        """The rows of ``rec`` as ``update`` takes them (the sun None where not valid)."""
        args, kwargs = self.buffer_inputs(rec)
        for k in range(len(args[0])):
            kw = {key: v[k] for key, v in kwargs.items()}
            if not np.all(np.isfinite(kw["sun_b"])):
                kw["sun_b"] = kw["sun_ref_o"] = None
            yield (args[0][k], args[1][k]), kw

    def prepare(self, rec: Recording, inertia=None) -> None:
        """What ``run(rec)`` does before its first sample: the coefficients of ``rec`` (the
        inertia ``inertia`` (3, 3), else the on-board model ``extra.inertia_model_kg_m2``
        when ``inertia_from_recording``, else the params'; the gravity gradient from the
        mean ``|w_io_o|``) and, for a fresh filter, the initial state (TRIAD at the first
        usable sample, the orbit-fixed rate)."""
        self._prepare(rec, self._rows(rec), inertia)

    def _prepare(self, rec: Recording, x: dict, inertia) -> None:
        from gnomon.kernels.ekf_spacecraft import coefficients

        p = self.params
        if inertia is not None:
            J = np.asarray(inertia, float)
        elif p.inertia_from_recording and "inertia_model_kg_m2" in rec.extra:
            J = np.asarray(rec.extra["inertia_model_kg_m2"][0], float)
        else:
            J = self.inertia
        n_orb = float(np.mean(np.linalg.norm(x["w_io_o"], axis=1)))
        self._coef = coefficients(p, J, 3.0 * n_orb**2 if p.gravity_gradient else 0.0)
        self._reset_sample_path()  # the sample kernel takes the new coefficients
        if self.state is None:
            inp = reference_inputs(rec, p.orbit_rate_rad_s)
            q0 = _initial_q(rec, inp)
            w0 = quat_rotate(quat_conj(q0), inp["w_io_o"][0])  # orbit-fixed rate: first guess
            self.state = self._new_state(np.concatenate([w0, q0]))

    def _batch(self, x: dict, t, compiled: bool = True) -> Estimate:
        """The rows ``x`` (``_rows``) through ``ekf_batch`` (or its ``py_func``),
        continuing the state."""
        from gnomon.kernels.ekf_spacecraft import ekf_batch

        n = len(x["dt"])
        z, pd, innov = np.empty((n, 7)), np.empty((n, 7)), np.empty((n, 2))
        fn, state = ekf_batch, self.state
        if not compiled:
            fn, state = getattr(fn, "py_func", fn), state.view(np.recarray)
        fn(self._coef, state, *(x[k] for k in ("dt", "mag_b", "b_o", "sun_b", "s_o",
                                               "sun_valid", "w_io_o", "h", "hdot", "tau")),
           z, pd, innov)
        return Estimate(
            t=np.asarray(t, float), q=z[:, 3:7], estimator=self.name,
            params=self.params.as_dict(), frames={"reference": "o", "body": "b"},
            signals={"w_ib_b_rad_s": z[:, 0:3], "p_diag": pd, "innovation_mag": innov[:, 0],
                     "innovation_sun": innov[:, 1]},
        )

    def run(self, rec: Recording, compiled: bool = True, inertia=None) -> Estimate:
        """Whole recording (``prepare``, then its rows as ``update_many`` takes them).
        ``inertia`` (3, 3) overrides the params' diagonal tensor (used by the uncertainty
        campaigns); ``compiled=False`` runs the interpreted twin."""
        self.check_inputs(rec)
        x = self._rows(rec, self.first_dt(rec))
        self._prepare(rec, x, inertia)
        est = self._batch(x, rec.t, compiled)
        self.t_last = float(rec.t[-1])
        est.frames = {"reference": rec.frames.get("reference", "o"),
                      "body": rec.frames.get("body", "b")}
        return est


_ZERO3 = np.zeros(3)  # a known input not given: zero (never written)


def _vector(v) -> np.ndarray:
    """A streamed direction (3,) as a unit vector; None, zero or non-finite as zero (none)."""
    return np.zeros(3) if v is None else _unit_or_zero(np.asarray(v, float).reshape(1, 3))[0]


def _first_q(mag_u, bo_u, sun_u, so_u, sun_ok) -> np.ndarray:
    """``q_ob`` of a first streamed sample: TRIAD (sun primary) if the sun is seen, else the
    field and nadir; the identity without a usable field or for a parallel pair."""
    if not (np.any(mag_u != 0.0) and np.any(bo_u != 0.0)):
        return np.array([1.0, 0.0, 0.0, 0.0])
    try:
        if sun_ok and np.any(sun_u != 0.0) and np.any(so_u != 0.0):
            return triad_q_ob(sun_u, mag_u, so_u, bo_u)
        return triad_q_ob(mag_u, [0.0, 0.0, 1.0], bo_u, [0.0, 0.0, 1.0])
    except InputError:
        return np.array([1.0, 0.0, 0.0, 0.0])
