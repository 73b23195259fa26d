"""The ESKF over a whole recorded log: forward filter, then an error-state RTS smoother.

Issue 20 ("Offline: the most accurate attitude from a recorded log"). The forward pass is
``eskf-r3`` itself (``gnomon.estimators.eskf``, unchanged: the same input handling,
initialisation, multi-rate rows, gates, low-pass and bias bound); it keeps, per sample,
the updated attitude ``q⁺``, bias ``b⁺`` and covariance ``P⁺`` of the error
``[δe; δb]``. The backward pass is the Rauch-Tung-Striebel recursion on that error state
(Rauch, Tung & Striebel, AIAA J. 3(8), 1965): at each sample the smoothed state of the
next one, expressed as an error of the filter's prediction of it, is carried back
through the gain ``C = P⁺ Φᵀ (P⁻)⁻¹`` and injected into ``q⁺``, ``b⁺`` as the filter
injects its corrections. Equations, memory and speed: ``gnomon.kernels.eskf_smoother``.

Frames and units (``docs/conventions.md``): ``q = q_nb`` ENU from body, ``[w, x, y, z]``;
bias rad/s, body; ``att_std_rad`` the 1-sigma rotation angle (rad) of the smoothed
error per body axis (``δe`` is a half-angle: ``2 sqrt(P_ii)``).

What the smoother assumes is the filter's own model: where the forward pass inflates or
gates measurements (linear acceleration, magnetic disturbance) or holds the bias, the
stored ``P⁺`` already says so and the smoother follows it; it does not revisit those
decisions with the future's knowledge (``robust-ahrs-offline`` does, heuristically).
The covariance is the linearised model's: consistent (NEES within its chi-square band)
when the noise parameters describe the sensors, as on the simulations of the tests.

On real data they rarely do (a hand swinging a phone is not white accelerometer noise),
and the model's band is then far too narrow. ``att_std_rad`` is therefore widened where
the log itself shows the model to be overconfident (``std_consistency_window_s``, on by
default): for a consistent smoother the difference between the causal and the smoothed
estimate has covariance ``P_f - P_s`` (Rauch, Tung & Striebel; the "covariance matching"
check of adaptive filtering, Mehra, IEEE TAC 17(5), 1972), so the ratio
``λ = mean(|d|²) / mean(tr(P_f - P_s))`` over a centred window (``d`` the rotation vector
between the two attitudes, ``P`` their attitude blocks, rad²) is about 1 where the model
holds; the standard deviations are multiplied by ``sqrt(max(1, λ))`` (signal
``std_scale``). It never narrows the band. Measured (``docs/estimators/offline.md``): on
simulations whose noise the parameters describe, NEES 2.8 → 2.3 (slightly conservative);
on BROAD and the phones it brings the NEES from hundreds down to tens: errors that the
future samples do not reveal (a constant field distortion) stay invisible to it.
``smooth(rec, attitude_cov=True)`` with ``std_consistency_window_s=0`` is the model's
covariance as is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d

from gnomon.errors import InputError
from gnomon.estimators.base import Estimate, param
from gnomon.estimators.eskf import EskfR3, EskfR3Params, process_noise, transition_matrix
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_from_rotvec, quat_mul

__all__ = ["EskfOffline", "EskfOfflineParams", "rts_reference"]


@dataclass(frozen=True)
class EskfOfflineParams(EskfR3Params):
    """``eskf-r3``'s parameters and the widening of the band (module docstring)."""

    std_consistency_window_s: float = param(
        30.0, "s", "window of the consistency ratio of causal vs smoothed attitude that "
        "widens att_std_rad where the model is overconfident; 0: the model's covariance")

    def validate(self) -> None:
        super().validate()
        self._require("std_consistency_window_s", self.std_consistency_window_s >= 0.0,
                      "must be >= 0")


class EskfOffline(EskfR3):
    """``eskf-r3`` forward, then the error-state RTS smoother backward (module docstring).

    ``run(rec)`` returns ``q`` (N, 4), the smoothed ``q_nb``, with signals
    ``bias_rad_s`` (N, 3) the smoothed gyro bias (rad/s, body), ``att_std_rad`` (N, 3)
    the per-axis 1-sigma rotation angle of the smoothed attitude error (rad, body axes
    x y z), ``forward_q`` (N, 4) the causal estimate (``eskf-r3``'s ``q``, to a few 1e-15)
    and ``bias_at_limit`` (N,) (a component of the smoothed bias at ``bias_limit``).
    ``smooth(rec, attitude_cov=True)`` adds ``att_cov_rad2`` (N, 3, 3), the covariance
    of that rotation-angle error. Needs the whole recording: no streaming ``update``.
    The filter's state (``state``, ``t_last``) is left at the log's end, as ``Eskf.run``
    leaves it.
    """

    Params = EskfOfflineParams
    name = "eskf-offline"
    summary = ("eskf-r3 forward, then an error-state Rauch-Tung-Striebel smoother backward "
               "(offline; per-axis attitude 1-sigma)")
    paper = "seed 002 (Bilous & Nesterenko) + RTS smoother (Rauch, Tung & Striebel 1965)"
    offline = True

    def update(self, dt_s, gyro_rad_s=None, accel_m_s2=None, mag_uT=None):
        """Not available: the smoother needs the whole recording (``run``); the streaming
        filter is ``eskf-r3``."""
        raise InputError("eskf-offline needs the whole recording (run); the streaming "
                         "filter is eskf-r3", field="update")

    update_reference = update

    def update_many(self, *args, **kwargs):
        """Not available either (``update``)."""
        raise InputError("eskf-offline needs the whole recording (run); the streaming "
                         "filter is eskf-r3", field="update_many")

    def run(self, rec: Recording) -> Estimate:
        """Smooth a whole recording (``smooth`` without the covariance)."""
        return self.smooth(rec)

    def smooth(self, rec: Recording, attitude_cov: bool = False) -> Estimate:
        """Forward filter and backward RTS pass over ``rec`` (compiled); ``attitude_cov``:
        also the signal ``att_cov_rad2`` (N, 3, 3), rad², body axes."""
        from gnomon.kernels import eskf as kern
        from gnomon.kernels import eskf_smoother as sm

        inputs = self._kernel_inputs(rec)
        out = sm.new_passes(len(rec), attitude_cov)
        sm.smooth(inputs, self.state, kern.coefficients(self.params), out)
        self.t_last = float(rec.t[-1])
        lim = self.params.bias_limit
        scale = self._std_scale(rec.t, out)
        signals = {"bias_rad_s": out.bias, "att_std_rad": out.att_std * scale[:, None],
                   "forward_q": out.q_fwd, "std_scale": scale,
                   "bias_at_limit": np.any(np.abs(out.bias) >= lim, axis=1)}
        if attitude_cov:
            cov = np.empty((len(rec), 3, 3))
            for m, (i, j) in enumerate(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
                cov[:, i, j] = cov[:, j, i] = out.att_cov[:, m]
            signals["att_cov_rad2"] = cov * (scale ** 2)[:, None, None]
        return Estimate(
            t=rec.t.copy(), q=out.q, estimator=self.name, params=self.params.as_dict(),
            frames={"reference": "ENU", "body": rec.frames.get("body", "sensor")},
            signals=signals)


    def _std_scale(self, t: np.ndarray, out) -> np.ndarray:
        """``sqrt(max(1, λ))`` per sample (module docstring); ones when the window is 0."""
        window = self.params.std_consistency_window_s
        if window <= 0.0 or len(t) < 2:
            return np.ones(len(t))
        from gnomon.kernels.eskf_smoother import consistency_terms

        num, den = np.empty(len(t)), np.empty(len(t))
        consistency_terms(out, num, den)
        size = int(min(max(round(window / ((t[-1] - t[0]) / (len(t) - 1))), 1), len(t)))
        num = uniform_filter1d(num, size, mode="nearest")
        den = uniform_filter1d(den, size, mode="nearest")
        ratio = np.divide(num, den, out=np.ones_like(num), where=den > 0.0)
        return np.sqrt(np.maximum(ratio, 1.0))


def rts_reference(q_fwd, b_fwd, P_fwd, gyro, dt, gyro_noise: float, bias_rw: float,
                  bias_limit: float = np.inf):
    """Readable twin of ``gnomon.kernels.eskf_smoother.backward_pass`` (numpy matrices;
    slow: for tests on short logs).

    ``q_fwd`` (N, 4) ``q⁺`` (``q_nb``), ``b_fwd`` (N, 3) ``b⁺`` rad/s, ``P_fwd`` (N, 6, 6)
    ``P⁺`` of the forward filter; ``gyro`` (N, 3) rad/s and ``dt`` (N,) s its inputs;
    noise densities as ``EskfParams``. Returns ``(q_s, b_s, P_s)``: (N, 4), (N, 3),
    (N, 6, 6).
    """
    n = len(q_fwd)
    q_s, b_s, P_s = np.empty((n, 4)), np.empty((n, 3)), np.empty((n, 6, 6))
    q_s[-1], b_s[-1], P_s[-1] = q_fwd[-1], b_fwd[-1], P_fwd[-1]
    for k in range(n - 2, -1, -1):
        w = gyro[k + 1] - b_fwd[k]
        Phi = transition_matrix(w, dt[k + 1])
        P_pred = Phi @ P_fwd[k] @ Phi.T + process_noise(dt[k + 1], gyro_noise, bias_rw)
        q_pred = quat_mul(q_fwd[k], quat_from_rotvec(w * dt[k + 1]))
        e = quat_mul(quat_conj(q_pred), q_s[k + 1])
        delta = np.concatenate([e[1:] / e[0], b_s[k + 1] - b_fwd[k]])
        C = np.linalg.solve(P_pred, Phi @ P_fwd[k]).T  # P⁺ Φᵀ (P⁻)⁻¹ (P⁻ symmetric)
        dx = C @ delta
        q = quat_mul(q_fwd[k], np.array([1.0, *dx[:3]]))
        q_s[k] = q / np.linalg.norm(q)
        b_s[k] = np.clip(b_fwd[k] + dx[3:], -bias_limit, bias_limit)
        P = P_fwd[k] + C @ (P_s[k + 1] - P_pred) @ C.T
        P_s[k] = 0.5 * (P + P.T)
    return q_s, b_s, P_s
