"""Spacecraft sensor models, each drawing from its own seeded ``numpy.random.Generator``.

All functions take truth time series on a uniform grid ``t`` (N,) s and return
measurements (plus the truth of the error states where there are any).

* Gyro: ``ω_meas = ω_ib_b + b(t) + n``, white noise of angle-random-walk
  density ``arw`` (rad/√s, i.e. rad/s/√Hz; per-sample σ = arw/√dt), bias
  ``b(t) = b0 + ∫ rrw dW + step · H(t - t_step)`` (bias random walk of density
  ``rrw`` in rad/s/√s, plus the Heaviside drift step of seed 000).
* Magnetometer: ``B_meas = (I + S + M) B_b + bias + n`` (scale factors S diagonal,
  misalignment M off-diagonal, both drawn once), white noise σ in nT.
* Sun sensor: ``s_meas`` = truth rotated by a small random angle (σ per axis
  perpendicular to the line of sight), valid only when the sun is inside the
  field-of-view cone around the boresight and the illumination fraction is at
  least ``min_illumination``; invalid rows are NaN.
* Accelerometer: free fall, so the specific force is the (tiny) non-gravitational
  acceleration, taken as zero, plus bias and white noise.
"""

from __future__ import annotations

import numpy as np

__all__ = ["gyro_model", "magnetometer_model", "sun_sensor_model", "accelerometer_model",
           "allan_deviation"]


def gyro_model(t, w_ib_b, rng: np.random.Generator, arw_rad_rt_s=0.0, bias_rad_s=(0, 0, 0),
               bias_rw_rad_s_rt_s=0.0, step_rad_s=(0, 0, 0), step_time_s=np.inf):
    """Gyro output (N, 3) rad/s and the bias truth (N, 3) rad/s (see module docstring)."""
    t = np.asarray(t, float)
    n = t.size
    dt = float(np.median(np.diff(t))) if n > 1 else 1.0
    bias = np.broadcast_to(np.asarray(bias_rad_s, float), (n, 3)).copy()
    if bias_rw_rad_s_rt_s > 0:
        steps = rng.standard_normal((n, 3)) * bias_rw_rad_s_rt_s * np.sqrt(dt)
        steps[0] = 0.0
        bias += np.cumsum(steps, axis=0)
    bias += (t >= step_time_s)[:, None] * np.asarray(step_rad_s, float)
    noise = rng.standard_normal((n, 3)) * (arw_rad_rt_s / np.sqrt(dt))
    return np.asarray(w_ib_b, float) + bias + noise, bias


def magnetometer_model(b_b_nT, rng: np.random.Generator, noise_nT=0.0, bias_nT=(0, 0, 0),
                       scale_pct=0.0, misalignment_deg=0.0):
    """Magnetometer output (N, 3) nT and the sensor matrix (3, 3) ``I + S + M`` used."""
    b = np.asarray(b_b_nT, float)
    A = np.eye(3)
    if scale_pct:
        A += np.diag(rng.standard_normal(3) * scale_pct / 100.0)
    if misalignment_deg:
        off = rng.standard_normal((3, 3)) * np.radians(misalignment_deg)
        A += off - np.diag(np.diag(off))
    out = b @ A.T + np.asarray(bias_nT, float)
    if noise_nT:
        out = out + rng.standard_normal(b.shape) * noise_nT
    return out, A


def sun_sensor_model(s_b, illumination, rng: np.random.Generator, noise_deg=0.0,
                     boresight_b=(0.0, 0.0, 1.0), fov_half_angle_deg=90.0,
                     min_illumination=0.5):
    """Sun sensor: unit vectors (N, 3) with NaN rows where invalid, and the validity (N,) bool."""
    s = np.asarray(s_b, float)
    s = s / np.linalg.norm(s, axis=1, keepdims=True)
    bs = np.asarray(boresight_b, float)
    bs = bs / np.linalg.norm(bs)
    valid = (s @ bs >= np.cos(np.radians(fov_half_angle_deg))) & (
        np.asarray(illumination) >= min_illumination)
    out = s.copy()
    if noise_deg:
        e = rng.standard_normal(s.shape) * np.radians(noise_deg)
        e -= np.sum(e * s, axis=1, keepdims=True) * s          # perpendicular to the sight line
        out = s + e
        out /= np.linalg.norm(out, axis=1, keepdims=True)
    out[~valid] = np.nan
    return out, valid


def accelerometer_model(n, rng: np.random.Generator, noise_m_s2=0.0, bias_m_s2=(0, 0, 0)):
    """Accelerometer output (n, 3) m/s² of a spacecraft in free fall (specific force ~ 0)."""
    return np.broadcast_to(np.asarray(bias_m_s2, float), (n, 3)) + (
        rng.standard_normal((n, 3)) * noise_m_s2)


def allan_deviation(x, dt, taus_s):
    """Overlapping Allan deviation of a rate ``x`` (N,) sampled every ``dt`` s, at ``taus_s``."""
    x = np.asarray(x, float)
    theta = np.concatenate([[0.0], np.cumsum(x) * dt])
    out = []
    for tau in taus_s:
        m = int(round(tau / dt))
        d = theta[2 * m:] - 2 * theta[m:-m] + theta[:-2 * m]
        out.append(np.sqrt(np.mean(d**2) / (2 * (m * dt) ** 2)))
    return np.array(out)
