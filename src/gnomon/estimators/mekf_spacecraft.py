"""The two spacecraft multiplicative EKFs: ``mekf-delayed`` (seed 000) and ``mekf-spacecraft``
(seed 001), side by side.

Both are Lefferts, Markley & Shuster's MEKF ("Kalman filtering for spacecraft attitude
estimation", JGCD 5(5), 1982; Markley & Crassidis 2014, ch. 6): estimate ``q_ob``
(orbital from body), error state ``[θ, δb]`` with ``q = q̂ ⊗ exp(θ)`` (body frame),
the gyro ``ω_ib_b`` drives the prediction, unit vectors (field, sun) the update. They
come from two papers and differ in details (first-order or exponential transition,
sequential or joint update, noise as an angle or per component, which gyro sample
propagates, ...): the table in ``gnomon.kernels.mekf_spacecraft`` lists them for the
merge of issue #22. Compiled loops: ``gnomon.kernels.mekf_spacecraft`` (``delayed_*``,
``spacecraft_*``).

Streaming, both (``None`` = no new sample of that input)::

    update(dt_s, gyro_rad_s=None, *, mag_b=None, mag_ref_o=None, sun_b=None,
           sun_ref_o=None, w_io_o_rad_s=None) -> q_ob (4,)

``dt_s`` s since the previous sample; ``gyro_rad_s`` (3,) ``ω_ib_b`` rad/s; ``mag_b`` (3,)
the measured field in b and ``mag_ref_o`` (3,) the field model in o (any one unit: only
directions are used); ``sun_b`` (3,) the sun direction measured in b and ``sun_ref_o`` (3,)
the sun model in o (None: eclipse); ``w_io_o_rad_s`` (3,) the orbital frame's rate
(default ``[0, −n, 0]`` from the params).

``mekf-delayed`` — gnomon's answer to seed 000's sun-sensor loss: instead of
substituting the sun pair by the magnetometer pair delayed by M samples (the
paper), keep using the one real pair and let the filter's covariance carry the
information of past field directions. The field direction turns in the
orbital frame (about twice per orbit on a polar orbit), so attitude and gyro
bias — including a drift step during the outage — stay observable from the
magnetometer alone (Psiaki, Martel & Pal, "Three-axis attitude determination via
Kalman filtering of magnetometer data", JGCD 13(3), 1990)::

    q̂ ← q̂ ⊗ exp((ω_ib − b̂ − R̂_bo ω_io_o) dt)
    Φ = I + [[−[(ω_ib − b̂)×], −I], [0, 0]] dt,   P ← Φ P Φᵀ + diag(σ_v² dt I, σ_u² dt I)
    per unit vector pair (v_b, v_o):  m̂ = R̂_bo v_o,  H = [[m̂×], 0],
        K = P Hᵀ (H P Hᵀ + σ² I)⁻¹,  [θ; δb] = K (v_b − m̂),  P ← (I − K H) P

The sun pair is used where valid (``sigma_sun_rad``); the magnetometer always
(``sigma_mag_rad`` ≈ noise / |B|). Where the sun is invalid and
``sun_substitute="delayed"``, the paper's substitute (the magnetometer pair of
``delay_samples`` ago) is used as well, with the noise
``sqrt(σ_mag² + (swing_gain·Δ)²)``, Δ the filter's own attitude change over those
samples: exact for a satellite that keeps its attitude in the orbital frame
(small swing, where it beats the magnetometer alone), ignored when it swings.
Bad input as in the complementary filters (unusable vectors skipped and
flagged, gaps propagate only, never a NaN). ``step`` is the readable twin of the kernel
``delayed_step`` (tested sample by sample); ``update`` makes the second pair from the
filter's tail as ``run`` does.

``mekf-spacecraft`` — the remedy seed 001 stops short of: the gyro instead of the
dynamics model of ``ekf-spacecraft``, with the same unit-vector measurements (joint
update of the magnetometer and sun rows, Joseph form). Its readable twin is the
kernel's ``.py_func`` (``run(rec, compiled=False)``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gnomon.estimators.base import Estimate, Estimator, Params, param
from gnomon.estimators.ecf_spacecraft import VectorPairFilter, _correct, _unit
from gnomon.estimators.ekf_spacecraft import _first_q, _initial_q, _vector, reference_inputs
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_rotate, skew

__all__ = ["MagGyroMEKFParams", "MagGyroMEKF", "MEKFSpacecraftParams", "MEKFSpacecraft"]


# ================================================================ seed 000: mekf-delayed
@dataclass(frozen=True)
class MagGyroMEKFParams(Params):
    sigma_mag_rad: float = param(0.03, "rad", "direction noise of the magnetometer pair "
                                 "(noise/|B| plus field-model error)")
    sigma_sun_rad: float = param(0.005, "rad", "direction noise of the sun pair")
    arw_rad_rt_s: float = param(2e-5, "rad/sqrt(s)", "gyro angle random walk (process noise)")
    bias_rw_rad_s_rt_s: float = param(1e-6, "rad/s/sqrt(s)", "gyro bias random walk "
                                      "(lets the filter follow drift steps)")
    sigma0_att_rad: float = param(0.2, "rad", "initial attitude standard deviation")
    sigma0_bias_rad_s: float = param(1e-3, "rad/s", "initial bias standard deviation")
    use_sun: bool = param(True, "", "use the sun pair where it is valid")
    sun_substitute: str = param("delayed", "", "where the sun is invalid: none (magnetometer "
                                "alone) | delayed (also the paper's delayed pair, weighted "
                                "by the estimated swing)")
    delay_samples: int = param(500, "samples", "M of the delayed magnetometer pair")
    swing_gain: float = param(8.0, "", "the delayed pair's noise grows by this times the "
                              "estimated attitude change over M samples (rad)")
    orbital_rate_rad_s: float = param(0.0, "rad/s", "mean motion n if the recording has no "
                                      "extra['w_io_o']")
    max_dt_s: float = param(10.0, "s", "longer sample intervals are gaps: propagation only")

    def validate(self):
        for name in ("sigma_mag_rad", "sigma_sun_rad", "sigma0_att_rad", "sigma0_bias_rad_s"):
            self._require(name, getattr(self, name) > 0, "must be > 0")
        for name in ("arw_rad_rt_s", "bias_rw_rad_s_rt_s", "orbital_rate_rad_s"):
            self._require(name, getattr(self, name) >= 0, "must be >= 0")
        self._require("max_dt_s", self.max_dt_s > 0, "must be > 0")
        self._require("sun_substitute", self.sun_substitute in ("none", "delayed"),
                      "must be none or delayed")
        self._require("delay_samples", self.delay_samples >= 1, "must be >= 1")
        self._require("swing_gain", self.swing_gain >= 0, "must be >= 0")


def _propagate_covariance(P, w, dt, p):
    """``Φ P Φᵀ + Q`` (readable twin of ``delayed_propagate_covariance``); ``w`` = ω − b̂."""
    F = np.zeros((6, 6))
    F[:3, :3] = -skew(w)
    F[:3, 3:] = -np.eye(3)
    Phi = np.eye(6) + F * dt
    Q = np.diag([p.arw_rad_rt_s ** 2 * dt] * 3 + [p.bias_rw_rad_s_rt_s ** 2 * dt] * 3)
    return Phi @ P @ Phi.T + Q


class MagGyroMEKF(VectorPairFilter):
    """Magnetometer(+sun)+gyro MEKF with bias; survives sun loss on the turning field; q_ob."""

    name = "mekf-delayed"
    summary = ("Multiplicative EKF (Lefferts-Markley-Shuster) on mag (+ sun where valid) + gyro "
               "with bias; orbital frame; keeps attitude and drift through sun outages")
    paper = "seed 000 (remedy: Lefferts, Markley & Shuster 1982)"
    Params = MagGyroMEKFParams

    def reset(self, q0_ob=None) -> None:
        self.history = []  # past estimates (for the delayed pair's weight)
        super().reset(q0_ob)

    def _new_state(self) -> np.ndarray:
        from gnomon.kernels.mekf_spacecraft import DELAYED_STATE

        p = self.params
        state = np.zeros(1, DELAYED_STATE)
        state["q"][0] = [1.0, 0.0, 0.0, 0.0]
        state["P"][0] = np.diag([p.sigma0_att_rad ** 2] * 3 + [p.sigma0_bias_rad_s ** 2] * 3)
        return state

    @property
    def P(self):
        """Covariance (6, 6) of ``[θ (rad), δb (rad/s)]`` now (a copy), None before starting."""
        return None if self.state is None else self.state["P"][0].copy()

    def update(self, dt_s, gyro_rad_s=None, *, mag_b=None, mag_ref_o=None, sun_b=None,
               sun_ref_o=None, w_io_o_rad_s=None) -> np.ndarray:
        """One raw sample (streaming; arguments in the module docstring). Returns ``q_ob``
        (4,); ``self.flags`` says what was used."""
        x = self.stream_pairs(dt_s, gyro_rad_s, mag_b, mag_ref_o, sun_b, sun_ref_o,
                              w_io_o_rad_s)
        valid = x["sec_valid"] and self.params.use_sun
        return self.step(dt_s, x["gyro"], x["w_io_o"], x["mag_b"], x["mag_o"], x["sec_b"],
                         x["sec_o"], valid, x["substituted"])

    def step(self, dt_s, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid,
             substituted=False) -> np.ndarray:
        """One sample given the kernel's inputs (readable twin of ``delayed_step``). Returns
        ``q_ob`` (4,). ``substituted``: the second pair is the paper's delayed magnetometer
        pair."""
        q = self._step(dt_s, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid, substituted)
        self.history.append(q.copy())
        if len(self.history) > self.params.delay_samples:
            self.history.pop(0)
        return q

    def _step(self, dt_s, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid, substituted):
        p = self.params
        s = self.record()
        # -- gyro prediction: attitude, then covariance
        ok_g = self._predict_phase(s, dt_s, gyro, w_io_o, "sun_unusable")
        if ok_g is None:
            return self.q
        w = np.asarray(gyro, float) - s.bias if ok_g else np.zeros(3)
        s.P[:] = _propagate_covariance(s.P, w, dt_s, p)
        if self._gap(dt_s):
            return self.q
        # -- magnetometer
        ok_m = self._vector_update(s, mag_b, mag_o, p.sigma_mag_rad)
        # -- sun, or the delayed magnetometer pair weighted by the swing since M samples
        sigma = self._second_sigma(s.q, sec_valid, substituted)
        ok_s = sigma is not None and self._vector_update(s, sec_b, sec_o, sigma)
        self.flags.update(mag_unusable=not ok_m, sun_unusable=not ok_s,
                          coast=self.flags["coast"] or not (ok_m or ok_s))
        return self.q

    def _second_sigma(self, q, sec_valid, substituted):
        """Noise (rad) of the second pair, None when it is not used (readable twin of
        ``delayed_second_sigma``)."""
        p = self.params
        if not sec_valid:
            return None
        if not substituted:
            return p.sigma_sun_rad
        if len(self.history) < p.delay_samples:
            return None
        old = self.history[-p.delay_samples]
        swing = 2.0 * np.arccos(min(1.0, abs(float(old @ q))))
        return np.sqrt(p.sigma_mag_rad ** 2 + (p.swing_gain * swing) ** 2)

    @staticmethod
    def _vector_update(s, vb, vo, sigma) -> bool:
        """One unit-vector measurement into the record ``s`` (readable twin of
        ``delayed_vector_update``); False if either vector is unusable."""
        ub, ok_b = _unit(vb)
        uo, ok_o = _unit(vo)
        if not (ok_b and ok_o):
            return False
        m = quat_rotate(quat_conj(s.q), uo)
        H = np.zeros((3, 6))
        H[:, :3] = skew(m)
        S = H @ s.P @ H.T + sigma ** 2 * np.eye(3)
        K = s.P @ H.T @ np.linalg.inv(S)
        dx = K @ (ub - m)
        P = s.P - K @ (H @ s.P)
        s.P[:] = 0.5 * (P + P.T)
        s.q[:] = _correct(s.q, dx[:3])
        s.bias[:] = s.bias + dx[3:]
        return True

    def run(self, rec: Recording, q0=None) -> Estimate:
        """Whole recording (compiled). ``q0``: initial ``q_ob`` (default: TRIAD, else identity)."""
        from gnomon.kernels.mekf_spacecraft import delayed_batch, delayed_coefficients

        self.check_inputs(rec)
        pairs = self.pairs(rec)
        if not self.params.use_sun:
            pairs["sec_valid"] = np.zeros(len(rec), bool)
        self._start(pairs, q0)
        q_out, b_out, flags = self._outputs(len(rec))
        delayed_batch(delayed_coefficients(self.params), self.state, pairs["dt"],
                      pairs["gyro"], pairs["w_io_o"], pairs["mag_b"], pairs["mag_o"],
                      pairs["sec_b"], pairs["sec_o"], pairs["sec_valid"],
                      pairs["substituted"], q_out, b_out, flags)
        return self._finish(rec, pairs, q_out, b_out, flags,
                            ("mag_unusable", "sun_unusable", "gap", "coast"))


# ================================================================ seed 001: mekf-spacecraft
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


class MEKFSpacecraft(Estimator):
    """Gyro-aided multiplicative EKF (attitude error + gyro bias), magnetometer + sun sensor.

    Streaming: ``update(dt_s, gyro_rad_s, *, mag_b, mag_ref_o, sun_b, sun_ref_o,
    w_io_o_rad_s)`` (module docstring); batch: ``run(rec)``."""

    name = "mekf-spacecraft"
    summary = "Multiplicative EKF [dtheta, gyro bias] with gyro, magnetometer + sun sensor"
    paper = "seed 001 (remedy: Lefferts, Markley & Shuster 1982)"
    kind = "spacecraft"
    reference_frame = "o"
    needs = ("gyro", "mag", "sun", "extra.b_o_nT", "extra.s_o")

    Params = MEKFSpacecraftParams

    state_fields = ("state", "t_last")

    def reset(self) -> None:
        self.state = None  # the kernel's SPACECRAFT_STATE record once started
        self.t_last = None

    def _new_state(self, q0) -> np.ndarray:
        from gnomon.kernels.mekf_spacecraft import SPACECRAFT_STATE

        p = self.params
        state = np.zeros(1, SPACECRAFT_STATE)
        state["q"][0] = q0
        state["P"][0] = np.diag([p.p0_att_rad**2] * 3 + [p.p0_bias_rad_s**2] * 3)
        return state

    @property
    def q(self):
        """``q_ob`` (4,) now (a copy), None before the first sample."""
        return None if self.state is None else self.state["q"][0].copy()

    @property
    def bias(self) -> np.ndarray:
        """Gyro-bias estimate (3,) rad/s now (a copy)."""
        return np.zeros(3) if self.state is None else self.state["bias"][0].copy()

    @property
    def P(self):
        """Covariance (6, 6) of ``[δθ, δb]`` now (a copy), None before the first sample."""
        return None if self.state is None else self.state["P"][0].copy()

    def update(self, dt_s: float, gyro_rad_s=None, *, mag_b=None, mag_ref_o=None, sun_b=None,
               sun_ref_o=None, w_io_o_rad_s=None) -> np.ndarray:
        """One sample (streaming; arguments in the module docstring); returns ``q_ob`` (4,).

        The gyro sample propagates to the next sample, as in ``run`` (None: the last one
        keeps propagating). The first call initialises (TRIAD) and ``dt_s`` is ignored.
        """
        from gnomon.kernels.mekf_spacecraft import (
            spacecraft_coefficients,
            spacecraft_hold,
            spacecraft_step,
        )

        p = self.params
        mag_u, bo_u = _vector(mag_b), _vector(mag_ref_o)
        sun_ok = sun_b is not None and sun_ref_o is not None and p.use_sun
        sun_u = _vector(sun_b) if sun_ok else np.zeros(3)
        so_u = _vector(sun_ref_o) if sun_ok else np.zeros(3)
        w_io = (np.array([0.0, -p.orbit_rate_rad_s, 0.0]) if w_io_o_rad_s is None
                else np.asarray(w_io_o_rad_s, float))
        if self.state is None:
            self.state = self._new_state(_first_q(mag_u, bo_u, sun_u, so_u, sun_ok))
        else:
            spacecraft_step(spacecraft_coefficients(p), self.state[0], float(dt_s), mag_u,
                            bo_u, sun_u, so_u, sun_ok, np.empty(2))
        s = self.state[0]
        gyro = s["gyro_b"].copy() if gyro_rad_s is None else np.asarray(gyro_rad_s, float)
        spacecraft_hold(s, gyro, w_io)
        return self.q

    def run(self, rec: Recording, compiled: bool = True) -> Estimate:
        """Whole recording; ``compiled=False`` runs the interpreted twin of the kernel."""
        from gnomon.kernels.mekf_spacecraft import spacecraft_batch, spacecraft_coefficients

        self.check_inputs(rec)
        p = self.params
        inp = reference_inputs(rec, p.orbit_rate_rad_s)
        first = 1 if self.state is None else 0  # a fresh filter starts at row 0
        if first:
            self.state = self._new_state(_initial_q(rec, inp))
        else:
            inp["dt"][0] = self.first_dt(rec)
        n = len(rec)
        q, b, pd, innov = np.empty((n, 4)), np.empty((n, 3)), np.empty((n, 6)), np.empty((n, 2))
        fn, state = spacecraft_batch, self.state
        if not compiled:
            fn, state = getattr(fn, "py_func", fn), state.view(np.recarray)
        fn(spacecraft_coefficients(p), state, first, inp["dt"], np.ascontiguousarray(rec.gyro),
           inp["mag_u"], inp["sun_u"], inp["sun_valid"], inp["b_o_u"], inp["s_o_u"],
           inp["w_io_o"], q, b, pd, innov)
        self.t_last = float(rec.t[-1])
        return Estimate(
            t=rec.t, q=q, estimator=self.name, params=self.params.as_dict(),
            frames={"reference": rec.frames.get("reference", "o"),
                    "body": rec.frames.get("body", "b")},
            signals={"bias_rad_s": b, "p_diag": pd, "innovation_mag": innov[:, 0],
                     "innovation_sun": innov[:, 1]},
        )

