"""The readable twin of the spacecraft MEKF (``gnomon.estimators.mekf``), in numpy.

``update_reference`` is the readable twin of ``MEKF.update``: the second pair of the
sample from the filter's tail (``VectorPairFilter._second_pair``), then ``step``, the
twin of the kernel's ``gnomon.kernels.mekf.step`` phase by phase (gyro prediction,
magnetometer and its magnitude row, the sun or the delayed pair, the star tracker), on
the same state record. The tests hold the compiled paths to it sample by sample; the
equations are in ``gnomon.estimators.mekf``'s docstring.
"""

from __future__ import annotations

import numpy as np

from gnomon.estimators.ecf_spacecraft import _correct, _unit
from gnomon.estimators.spacecraft_update import vec
from gnomon.rotation import dcm_from_quat, quat_conj, quat_from_rotvec, quat_mul, quat_rotate, skew

__all__ = ["ReadableMEKF", "FLAG_NAMES"]

FLAG_NAMES = ("mag_unusable", "sun_unusable", "gap", "coast", "star_unused")


class ReadableMEKF:
    """The readable twin's methods, mixed into ``MEKF`` (which provides ``params``,
    ``n_states``, ``record``, ``ring``, ``flags`` and the start of a fresh filter)."""

    def update_reference(self, dt_s, gyro_rad_s=None, *, mag_b=None, mag_ref_o=None,
                         sun_b=None, sun_ref_o=None, w_io_o_rad_s=None, st_q_ob=None,
                         st_boresight_b=None) -> np.ndarray:
        """The readable twin of ``MEKF.update`` (numpy, one sample; the tests hold the
        compiled paths to it sample by sample). Same arguments and result."""
        g, w_io, m_b, m_o, s_b, s_o = self._reference_row(gyro_rad_s, w_io_o_rad_s, mag_b,
                                                          mag_ref_o, sun_b, sun_ref_o)
        st = None if st_q_ob is None else vec(st_q_ob, "st_q_ob", 4).copy()
        bore = None if st_boresight_b is None else vec(st_boresight_b, "st_boresight_b")
        if self.state is None:  # start: the tracker's attitude, else TRIAD of this sample
            self._start_from_sample(m_b, m_o, s_b, s_o, np.full(4, np.nan) if st is None else st)
            dt_s = 0.0
        s = self.record()
        k = int(s.n_seen)
        sec_b, sec_o, ok, sub, slot = self._second_pair(s, dt_s, g, w_io, m_b, m_o, s_b, s_o)
        q_old = self.ring["q"][slot].copy() if k >= self.params.delay_samples else None
        q = self.step(dt_s, g, w_io, m_b, m_o, sec_b, sec_o, ok and self.params.use_sun, sub,
                      st, bore, q_old)
        if self.params.sun_substitute != "none":  # the tail is read only for the delayed pair
            self.ring["q"][slot] = q
        return q

    def step(self, dt_s, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid,
             substituted=False, st_q_ob=None, st_boresight_b=None, q_old=None) -> np.ndarray:
        """One sample given the kernel's inputs (readable twin of ``gnomon.kernels.mekf.step``
        and of the hold in ``row``): the second pair made already (``sec_*``, whether it is
        the delayed ``substituted`` pair), ``q_old`` the estimate ``delay_samples`` samples
        before (the delayed pair's swing; None: none yet). Returns ``q_ob`` (4,)."""
        s = self.record()
        self.flags = dict.fromkeys(FLAG_NAMES, False)
        if 0.0 < dt_s < 1e300:
            self._step(s, dt_s, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, bool(sec_valid),
                       bool(substituted), st_q_ob, st_boresight_b, q_old)
        s.gyro_b[:] = gyro
        s.w_io_o[:] = w_io_o
        return self.q

    def _step(self, s, dt, gyro, w_io_o, mag_b, mag_o, sec_b, sec_o, sec_valid, substituted,
              st_q, st_bore, q_old):
        p, n = self.params, self.n_states
        P = s.P[:n, :n]
        # -- gyro prediction: attitude, then covariance
        g, w_io = ((s.gyro_b.copy(), s.w_io_o.copy()) if p.gyro_sample == "previous"
                   else (np.asarray(gyro, float), np.asarray(w_io_o, float)))
        if np.all(np.abs(g) < 1e6):
            w = g - s.bias
            if p.estimate_gyro_scale:
                w = w / (1.0 + s.scale)
            w_ob = w - quat_rotate(quat_conj(s.q), w_io)
            s.q[:] = _correct(s.q, w_ob * dt)
        else:
            w = np.zeros(3)
            self.flags["coast"] = True
        Phi = self._transition(w, dt)
        P[:] = Phi @ P @ Phi.T + self._q_noise() * dt
        if dt > p.max_dt_s:
            self.flags.update(gap=True, coast=True)
            return
        # -- magnetometer, then the sun or the delayed magnetometer pair in its place
        dx = np.zeros(n)
        ok_m = self._magnetometer(s, P, dx, mag_b, mag_o)
        sigma = self._second_sigma(s.q, sec_valid, substituted, q_old)
        ok_s = sigma is not None and self._vector(s, P, dx, sec_b, sec_o, sigma)
        if not p.relinearise and (ok_m or ok_s):
            self._apply(s, dx)
        # -- star tracker
        ok_t = False
        if st_q is not None and np.all(np.isfinite(st_q)):
            ok_t = self._star(s, P, dx, np.asarray(st_q, float), st_bore, w)
            self.flags["star_unused"] = not ok_t
        self.flags.update(mag_unusable=not ok_m, sun_unusable=not ok_s,
                          coast=self.flags["coast"] or not (ok_m or ok_s or ok_t))

    def _transition(self, w, dt):
        p, n = self.params, self.n_states
        Phi = np.eye(n)
        if p.transition == "exponential" or np.dot(w, w) * dt * dt > 0.01:  # > 0.1 rad
            Phi[:3, :3] = dcm_from_quat(quat_from_rotvec(-w * dt))
        else:
            Phi[:3, :3] -= skew(w) * dt
        Phi[:3, 3:6] = -np.eye(3) * dt
        if p.estimate_gyro_scale:
            Phi[:3, n - 3:] = -np.diag(w) * dt
        return Phi

    def _q_noise(self):
        p = self.params
        q = [p.arw_rad_rt_s ** 2] * 3 + [p.bias_rw_rad_s_rt_s ** 2] * 3
        if p.estimate_mag_bias:
            q += [p.mag_bias_rw_nT_rt_s ** 2] * 3
        if p.estimate_gyro_scale:
            q += [p.gyro_scale_rw_rt_s ** 2] * 3
        return np.diag(q)

    def _second_sigma(self, q, sec_valid, substituted, old):
        """Noise (rad) of the second pair, None when it is not used (readable twin of
        ``second_sigma``; ``old`` the estimate ``delay_samples`` before, None: none yet)."""
        p = self.params
        if not sec_valid:
            return None
        if not substituted:
            return p.sigma_sun_rad
        if old is None:
            return None
        swing = 2.0 * np.arccos(min(1.0, abs(float(old @ q))))
        return np.sqrt(p.sigma_mag_rad ** 2 + (p.swing_gain * swing) ** 2)

    @staticmethod
    def _kalman(P, dx, H, y, R):
        """``dx += K (y − H dx)``, ``P ← P − K H P`` in place; the innovation's χ², None if
        ``S`` is singular."""
        S = H @ P @ H.T + R
        if not np.linalg.det(S) > 0:
            return None
        r = y - H @ dx
        K = P @ H.T @ np.linalg.inv(S)
        dx += K @ r
        P_new = P - K @ (H @ P)
        P[:] = 0.5 * (P_new + P_new.T)
        return float(r @ np.linalg.solve(S, r))

    def _apply(self, s, dx):
        """The correction: ``q ⊗ exp(θ)``, the biases (and scales) added; ``dx`` cleared."""
        p, n = self.params, self.n_states
        if p.correction == "exponential":
            s.q[:] = _correct(s.q, dx[:3])
        else:
            q = quat_mul(s.q, np.concatenate([[1.0], 0.5 * dx[:3]]))
            s.q[:] = q / np.linalg.norm(q)
        s.bias[:] = s.bias + dx[3:6]
        if p.estimate_mag_bias:
            s.mag_bias[:] = s.mag_bias + dx[6:9]
        if p.estimate_gyro_scale:
            s.scale[:] = s.scale + dx[n - 3:]
        dx[:] = 0.0

    def _magnetometer(self, s, P, dx, mag_b, mag_o) -> bool:
        """The magnetometer (readable twin of ``magnetometer``): a zero or non-finite field is
        a dropout; its bias removed when estimated, then the magnitude row."""
        p = self.params
        if not _unit(mag_b)[1]:
            return False
        v = np.asarray(mag_b, float) - s.mag_bias
        sigma = p.sigma_mag_rad
        if p.mag_noise_nT > 0 and _unit(v)[1]:
            sigma = np.sqrt(sigma ** 2 + (p.mag_noise_nT / np.linalg.norm(v)) ** 2)
        if not self._vector(s, P, dx, v, mag_o, sigma, mag_bias=p.estimate_mag_bias):
            return False
        if p.estimate_mag_bias and p.sigma_mag_norm_nT > 0:
            u = v / np.linalg.norm(v)
            H = np.zeros((1, self.n_states))
            H[0, 6:9] = u
            y = np.array([np.linalg.norm(v) - np.linalg.norm(mag_o)])
            if self._kalman(P, dx, H, y, np.array([[p.sigma_mag_norm_nT ** 2]])) is not None \
                    and p.relinearise:
                self._apply(s, dx)
        return True

    def _vector(self, s, P, dx, vb, vo, sigma, mag_bias=False) -> bool:
        """One unit-vector measurement (readable twin of ``vector_update``); False if either
        vector is unusable."""
        ub, ok_b = _unit(vb)
        uo, ok_o = _unit(vo)
        if not (ok_b and ok_o):
            return False
        m = quat_rotate(quat_conj(s.q), uo)
        H = np.zeros((3, self.n_states))
        H[:, :3] = skew(m)
        if mag_bias:
            H[:, 6:9] = (np.eye(3) - np.outer(ub, ub)) / np.linalg.norm(vb)
        if self._kalman(P, dx, H, ub - m, sigma ** 2 * np.eye(3)) is None:
            return False
        if self.params.relinearise:
            self._apply(s, dx)
        return True

    def _star(self, s, P, dx, st_q, bore, w_ib) -> bool:
        """The star tracker (readable twin of ``star_tracker``): ``st_q`` carried over the
        latency with the inertial rate ``w_ib``; False if gated out."""
        p = self.params
        b, ok = _unit(bore)
        if not ok:
            return False
        q_m = quat_mul(st_q, quat_from_rotvec(w_ib * p.st_latency_s))
        d = quat_mul(quat_conj(s.q), q_m)
        d = -d if d[0] < 0 else d
        v = np.linalg.norm(d[1:])
        y = d[1:] * (2.0 * np.arctan2(v, d[0]) / v if v > 1e-12 else 2.0)
        H = np.zeros((3, self.n_states))
        H[:, :3] = np.eye(3)
        R = (p.st_sigma_cross_rad ** 2 * (np.eye(3) - np.outer(b, b))
             + p.st_sigma_about_rad ** 2 * np.outer(b, b))
        saved = P.copy()
        lat = p.arw_rad_rt_s ** 2 * p.st_latency_s * np.diag([1.0] * 3 + [0.0] * (len(P) - 3))
        P -= lat  # the gain of P(t − L): the gyro noise since is in both
        chi2 = self._kalman(P, dx, H, y, R)
        P += lat
        if chi2 is None or (p.st_gate_chi2 > 0 and chi2 > p.st_gate_chi2):
            P[:] = saved
            dx[:] = 0.0
            return False
        self._apply(s, dx)
        return True
