"""Magnetometer (+ sun) + gyro multiplicative EKF with gyro-bias estimation, orbital frame.

gnomon's "improved" answer to seed 000's sun-sensor loss: instead of
substituting the sun pair by the magnetometer pair delayed by M samples (the
paper), keep using the one real pair and let the filter's covariance carry the
information of past field directions. The field direction turns in the
orbital frame (about twice per orbit on a polar orbit), so attitude and gyro
bias — including a drift step during the outage — stay observable from the
magnetometer alone (Lefferts, Markley & Shuster, "Kalman filtering for
spacecraft attitude estimation", JGCD 5(5), 1982; Psiaki, Martel & Pal,
"Three-axis attitude determination via Kalman filtering of magnetometer data",
JGCD 13(3), 1990).

Estimate ``q_ob``; error state ``[θ, δb]`` with ``q = q̂ ⊗ exp(θ)`` (body frame)::

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
flagged, gaps propagate only, never a NaN).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gnomon.estimators.base import Estimate, Params, param
from gnomon.estimators.ecf_spacecraft import (
    VectorPairFilter,
    _unit,
)
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_from_rotvec, quat_mul, quat_rotate, skew

__all__ = ["MagGyroMEKFParams", "MagGyroMEKF"]


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


class MagGyroMEKF(VectorPairFilter):
    """Magnetometer(+sun)+gyro MEKF with bias; survives sun loss on the turning field; q_ob."""

    name = "mekf-delayed"
    summary = ("Multiplicative EKF (Lefferts-Markley-Shuster) on mag (+ sun where valid) + gyro "
               "with bias; orbital frame; keeps attitude and drift through sun outages")
    Params = MagGyroMEKFParams
    state_fields = ("q", "bias", "P", "t_last", "tail")

    def reset(self) -> None:
        super().reset()
        p = self.params
        self.history = []  # past estimates (for the delayed pair's weight)
        self.P = np.diag([p.sigma0_att_rad ** 2] * 3 + [p.sigma0_bias_rad_s ** 2] * 3)

    def _vector_update(self, vb, vo, sigma) -> bool:
        ub, ok_b = _unit(vb)
        uo, ok_o = _unit(vo)
        if not (ok_b and ok_o):
            return False
        m = quat_rotate(quat_conj(self.q), uo)
        H = np.zeros((3, 6))
        H[:, :3] = skew(m)
        S = H @ self.P @ H.T + sigma ** 2 * np.eye(3)
        K = self.P @ H.T @ np.linalg.inv(S)
        dx = K @ (ub - m)
        P = self.P - K @ (H @ self.P)
        self.P = 0.5 * (P + P.T)
        self.q = quat_mul(self.q, quat_from_rotvec(dx[:3]))
        self.q = self.q / np.linalg.norm(self.q)
        self.bias = self.bias + dx[3:]
        return True

    def update(self, dt_s, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid,
               substituted=False) -> np.ndarray:
        """One sample (readable reference of the kernel). Returns ``q_ob`` (4,).

        ``substituted``: the second pair is the paper's delayed magnetometer pair.
        """
        q = self._update(dt_s, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid, substituted)
        self.history.append(q.copy())
        if len(self.history) > self.params.delay_samples:
            self.history.pop(0)
        return q

    def _update(self, dt_s, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid, substituted):
        p = self.params
        ok_g = self._predict(dt_s, gyro, w_io_o, "sun_unusable")
        if ok_g is None:
            return self.q
        w = np.asarray(gyro, float) - self.bias if ok_g else np.zeros(3)
        F = np.zeros((6, 6))
        F[:3, :3] = -skew(w)
        F[:3, 3:] = -np.eye(3)
        Phi = np.eye(6) + F * dt_s
        Q = np.diag([p.arw_rad_rt_s ** 2 * dt_s] * 3 + [p.bias_rw_rad_s_rt_s ** 2 * dt_s] * 3)
        self.P = Phi @ self.P @ Phi.T + Q
        if dt_s > p.max_dt_s:
            self.flags.update(gap=True, coast=True)
            return self.q
        ok_m = self._vector_update(mag_b, mag_o, p.sigma_mag_rad)
        sigma = p.sigma_sun_rad
        use_s = bool(sec_valid)
        if use_s and substituted:
            if len(self.history) >= p.delay_samples:
                old = self.history[-p.delay_samples]
                swing = 2.0 * np.arccos(min(1.0, abs(float(old @ self.q))))
                sigma = np.sqrt(p.sigma_mag_rad ** 2 + (p.swing_gain * swing) ** 2)
            else:
                use_s = False
        ok_s = use_s and self._vector_update(sec_b, sec_o, sigma)
        self.flags.update(mag_unusable=not ok_m, sun_unusable=not ok_s,
                          coast=self.flags["coast"] or not (ok_m or ok_s))
        return self.q

    def run(self, rec: Recording, q0=None) -> Estimate:
        """Whole recording (compiled). ``q0``: initial ``q_ob`` (default: TRIAD, else identity)."""
        from gnomon.kernels.spacecraft_cf import mekf_batch

        self.check_inputs(rec)
        p = self.params
        pairs = self.pairs(rec)
        if not p.use_sun:
            pairs["sec_valid"] = np.zeros(len(rec), bool)
        self._start(pairs, q0)
        q_out, b_out, flags = self._outputs(len(rec))
        state_q = np.array(self.q, float)
        state_b = np.array(self.bias, float)
        state_P = np.array(self.P, float)
        mekf_batch(pairs["dt"], pairs["gyro"], pairs["w_io_o"], pairs["mag_b"], pairs["mag_o"],
                   pairs["sec_b"], pairs["sec_o"], pairs["sec_valid"], pairs["substituted"],
                   p.delay_samples, p.swing_gain, state_q, state_b, state_P, p.sigma_mag_rad,
                   p.sigma_sun_rad, p.arw_rad_rt_s, p.bias_rw_rad_s_rt_s, p.max_dt_s, q_out,
                   b_out, flags)
        self.P = state_P
        return self._finish(rec, pairs, q_out, b_out, flags,
                            ("mag_unusable", "sun_unusable", "gap", "coast"))
