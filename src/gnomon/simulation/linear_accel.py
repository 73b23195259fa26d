"""A level vehicle with long linear accelerations and a drifting gyro (seed 004).

The vehicle moves along its body x axis on a level road (ENU reference, a
resting accelerometer reads ``[0, 0, +g]``), with a forward acceleration
profile ``a(t)`` and optionally a yaw rate ``r(t)`` (turns). Its true attitude
is the heading alone, so every tilt an estimator reports is an error. The
sensors::

    gyro_b  = [0, 0, r] + gyro_bias_rad_s (+ white noise)
    accel_b = [a, r·v, g]          (specific force: dv/dt + ω × v + R_nbᵀ[0, 0, g])
    speed   = v·(1 + scale_error) + white noise, at ``speed_rate_hz`` (NaN between samples)

The accelerometer alone reads a pitch error ``−arctan(a/g)``; the one-axis
analysis (``one_axis_inputs``) uses ``+a/g`` (the paper's linear model) or
``+arctan(a/g)``. The default gyro bias is about −y so that, in 3D as on one
axis, the drift error and the acceleration error have the same sign (the
paper adds them).
"""

from __future__ import annotations

import numpy as np

from gnomon.analysis.complementary import accel_tilt_error_rad
from gnomon.recording import Recording
from gnomon.rotation import quat_from_euler

__all__ = ["G0_M_S2", "pulse_profile", "one_axis_inputs", "vehicle_recording"]

G0_M_S2 = 9.80665


def pulse_profile(t_s, t_on_s: float, duration_s: float, accel_m_s2: float,
                  edge_s: float = 0.0) -> np.ndarray:
    """Acceleration (m/s²) that is ``accel_m_s2`` on ``[t_on, t_on + duration)``, else zero.

    ``edge_s > 0`` replaces the steps by raised-cosine ramps of that length
    (centred on the step times), a smoother and more realistic profile.
    """
    t = np.asarray(t_s, dtype=float)
    if edge_s <= 0.0:
        return np.where((t >= t_on_s) & (t < t_on_s + duration_s), accel_m_s2, 0.0)

    def smooth_step(x):
        u = np.clip((x + 0.5 * edge_s) / edge_s, 0.0, 1.0)
        return 0.5 - 0.5 * np.cos(np.pi * u)

    return accel_m_s2 * (smooth_step(t - t_on_s) - smooth_step(t - t_on_s - duration_s))


def one_axis_inputs(a_m_s2, drift_rad_s: float, model: str = "linear",
                    gravity_m_s2: float = G0_M_S2) -> tuple[np.ndarray, np.ndarray]:
    """``(ω, φ_a)`` (rad/s, rad), each (N,), for a level vehicle (true angle 0) on one axis.

    ``ω = ω_d`` (the gyro drift), ``φ_a = a/g`` (``model="linear"``) or
    ``arctan(a/g)`` (``model="true"``).
    """
    a = np.asarray(a_m_s2, dtype=float)
    return (np.full(a.shape, float(drift_rad_s)),
            accel_tilt_error_rad(a / gravity_m_s2, model))


def vehicle_recording(t_s, a_m_s2, yaw_rate_rad_s=None, *,
                      gyro_bias_rad_s=(0.0, -5e-5, 0.0), gravity_m_s2: float = G0_M_S2,
                      speed_rate_hz: float = 10.0, speed_noise_m_s: float = 0.0,
                      speed_scale_error: float = 0.0, gyro_noise_rad_s: float = 0.0,
                      accel_noise_m_s2: float = 0.0, v0_m_s: float = 0.0,
                      rng: np.random.Generator | None = None) -> Recording:
    """Simulated IMU + speed sensor of the level vehicle (module docstring); a ``Recording``.

    ``t_s`` (N,) s, ``a_m_s2`` (N,) forward acceleration, ``yaw_rate_rad_s`` (N,)
    or None. Noise values are standard deviations per sample (the speed noise per
    speed sample); ``rng`` is required when any is non-zero. ``extra`` holds
    ``speed_m_s`` (N,) (NaN between speed samples), ``speed_true_m_s``,
    ``a_fwd_m_s2``; ``q_true`` is ``q_nb`` (ENU from body).
    """
    t = np.asarray(t_s, dtype=float)
    a = np.asarray(a_m_s2, dtype=float)
    r = np.zeros_like(t) if yaw_rate_rad_s is None else np.asarray(yaw_rate_rad_s, dtype=float)
    noisy = speed_noise_m_s > 0 or gyro_noise_rad_s > 0 or accel_noise_m_s2 > 0
    if noisy and rng is None:
        raise ValueError("rng (numpy.random.Generator) is required when a noise is non-zero")
    dt = np.diff(t)
    v = v0_m_s + np.concatenate([[0.0], np.cumsum(0.5 * (a[1:] + a[:-1]) * dt)])
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (r[1:] + r[:-1]) * dt)])
    n = t.size
    gyro = np.zeros((n, 3))
    gyro[:, 2] = r
    gyro += np.asarray(gyro_bias_rad_s, dtype=float)
    accel = np.stack([a, r * v, np.full(n, gravity_m_s2)], -1)
    if gyro_noise_rad_s > 0:
        gyro += rng.normal(0.0, gyro_noise_rad_s, gyro.shape)
    if accel_noise_m_s2 > 0:
        accel += rng.normal(0.0, accel_noise_m_s2, accel.shape)
    speed = np.full(n, np.nan)
    tick = np.floor((t - t[0]) * speed_rate_hz + 1e-9)
    idx = np.flatnonzero(np.concatenate([[True], np.diff(tick) > 0]))
    speed[idx] = v[idx] * (1.0 + speed_scale_error)
    if speed_noise_m_s > 0:
        speed[idx] += rng.normal(0.0, speed_noise_m_s, idx.size)
    q_true = quat_from_euler(np.stack([np.zeros(n), np.zeros(n), yaw], -1))
    return Recording(t=t, gyro=gyro, accel=accel, q_true=q_true,
                     frames={"reference": "ENU", "body": "vehicle"},
                     source="gnomon.simulation.linear_accel",
                     extra={"speed_m_s": speed, "speed_true_m_s": v, "a_fwd_m_s2": a})
