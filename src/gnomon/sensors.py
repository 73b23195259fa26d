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
* Star tracker: the inertial attitude ``q_ib`` at its own rate and latency, with a
  small rotation of noise about and across the boresight, no measurement where the
  Sun, the Earth's limb or the Moon is too close to the boresight or during an outage
  (:func:`star_tracker_model`).
* Accelerometer: free fall, so the specific force is the (tiny) non-gravitational
  acceleration, taken as zero, plus bias and white noise.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from gnomon.environment.orbit import R_EARTH
from gnomon.errors import InputError
from gnomon.rotation import quat_from_rotvec, quat_mul, quat_rotate, quat_slerp

__all__ = ["gyro_model", "magnetometer_model", "sun_sensor_model", "accelerometer_model",
           "star_tracker_model", "boresight_frame", "STAR_TRACKER_FLAGS", "allan_deviation"]


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


#: why a star-tracker sample that was due holds no measurement: bits of the ``flags``
#: output of :func:`star_tracker_model` (0 on a valid sample and on samples not due)
STAR_TRACKER_FLAGS = {"sun": 1, "earth": 2, "moon": 4, "outage": 8, "no_history": 16}


def _unit3(v, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InputError(f"expected 3 finite numbers, got {v!r}", field=name)
    norm = float(np.linalg.norm(a))
    if norm == 0.0:
        raise InputError("must be a non-zero vector, got [0, 0, 0]", field=name)
    return a / norm


def _non_negative(value, name: str) -> float:
    if not isinstance(value, numbers.Real) or isinstance(value, bool) \
            or not math.isfinite(value) or value < 0:
        raise InputError(f"must be a finite number >= 0, got {value!r}", field=name)
    return float(value)


def _directions(v, n: int, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.shape == (3,):
        a = np.broadcast_to(a, (n, 3))
    if a.shape != (n, 3) or not np.all(np.isfinite(a)):
        raise InputError(f"expected finite values of shape ({n}, 3) or (3,), got {a.shape}",
                         field=name)
    norm = np.linalg.norm(a, axis=1)
    if np.any(norm == 0.0):
        raise InputError("zero vector", field=name, row=int(np.flatnonzero(norm == 0.0)[0]))
    return a / norm[:, None]


def _angle(u, v) -> np.ndarray:
    """Angle (rad) between unit vectors, row by row (atan2: accurate near 0 and π)."""
    return np.arctan2(np.linalg.norm(np.cross(u, v), axis=1), np.sum(u * v, axis=1))


def boresight_frame(boresight_b) -> np.ndarray:
    """The star-tracker frame s of a boresight: ``R_bs`` (3, 3), ``v_b = R_bs @ v_s``.

    ``boresight_b`` (3,): boresight direction in body axes (any length but zero).
    The columns of ``R_bs`` are ``x_s, y_s, z_s`` in b: ``z_s`` the unit boresight,
    ``x_s = unit(e_k × z_s)`` with ``e_k`` the body axis least aligned with the boresight
    (the first one on a tie), ``y_s = z_s × x_s``. Raises ``InputError`` (field
    ``boresight_b``) for a zero or non-finite vector.
    """
    z = _unit3(boresight_b, "boresight_b")
    e = np.zeros(3)
    e[int(np.argmin(np.abs(z)))] = 1.0
    x = np.cross(e, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def _due_rows(t: np.ndarray, rate_hz) -> np.ndarray:
    if rate_hz is None:
        return np.ones(t.size, bool)
    if isinstance(rate_hz, bool) or not isinstance(rate_hz, numbers.Real) \
            or not math.isfinite(rate_hz) or rate_hz <= 0:
        raise InputError(f"must be a finite number > 0, got {rate_hz!r}", field="rate_hz")
    ticks = np.floor((t - t[0]) * rate_hz + 1e-9)     # tracker clock ticks up to each sample
    step = np.diff(ticks)
    if np.any(step > 1):
        row = int(np.flatnonzero(step > 1)[0]) + 1
        raise InputError(f"{rate_hz:g} Hz gives more than one measurement between samples "
                         f"{row - 1} and {row} (the tracker cannot be faster than the time "
                         f"base)", field="rate_hz", row=row)
    return np.concatenate([[True], step > 0])


def _exposure_attitude(t: np.ndarray, q_ib: np.ndarray, latency_s: float):
    """``q_ib`` at ``t - latency_s`` (slerp between samples) and where that time is known."""
    if latency_s == 0.0:
        return q_ib.copy(), np.ones(t.size, bool)
    te = t - latency_s
    known = te >= t[0]
    q = q_ib.copy()
    if t.size > 1 and np.any(known):
        j = np.clip(np.searchsorted(t, te[known], side="right") - 1, 0, t.size - 2)
        frac = (te[known] - t[j]) / (t[j + 1] - t[j])
        q[known] = quat_slerp(q_ib[j], q_ib[j + 1], frac)
    return q, known


def _outages(t, rng, rate_hz: float, mean_s: float, windows) -> np.ndarray:
    out = np.zeros(t.size, bool)
    for start, end in windows:
        out |= (t >= start) & (t < end)
    if rate_hz > 0.0 and mean_s > 0.0:
        span = t[-1] - t[0]
        chunk = int(1.2 * span / (1.0 / rate_hz + mean_s)) + 16
        pos, starts, ends = t[0], [], []
        while pos <= t[-1]:
            up = rng.exponential(1.0 / rate_hz, chunk)
            down = rng.exponential(mean_s, chunk)
            a = pos + np.cumsum(up + down) - down       # outage starts
            starts.append(a)
            ends.append(a + down)
            pos = ends[-1][-1]
        a = np.searchsorted(t, np.concatenate(starts), side="left")
        b = np.searchsorted(t, np.concatenate(ends), side="left")
        count = np.zeros(t.size + 1)
        np.add.at(count, a, 1.0)
        np.add.at(count, b, -1.0)
        out |= np.cumsum(count[:-1]) > 0
    return out


def star_tracker_model(t, q_ib, rng: np.random.Generator, *, boresight_b=(0.0, 0.0, 1.0),
                       noise_cross_rad=0.0, noise_about_rad=0.0, rate_hz=None, latency_s=0.0,
                       sun_i=None, sun_exclusion_rad=0.0, r_i_m=None,
                       earth_limb_exclusion_rad=0.0, earth_radius_m=R_EARTH, moon_i=None,
                       moon_exclusion_rad=0.0, outage_rate_hz=0.0, outage_mean_s=0.0,
                       outage_windows_s=()):
    """Star tracker: measured inertial attitude ``q̂_ib`` with NaN rows where there is none.

    Parameters (frames: ``i`` inertial, ``b`` body, ``s`` tracker frame of
    :func:`boresight_frame`, z_s = boresight)

    t : (N,) s, increasing: the time base; a measurement is stamped at a sample of it.
    q_ib : (N, 4) true attitude, inertial from body, ``[w, x, y, z]``.
    rng : the tracker's own generator.
    boresight_b : (3,) boresight direction in b (normalised here; not zero).
    noise_cross_rad, noise_about_rad : 1-sigma noise angle (rad) about each of the two
        axes across the boresight (x_s, y_s) and about the boresight (z_s).
    rate_hz : update rate; the tracker's clock ticks at ``t[0] + k / rate_hz`` and a
        measurement is stamped at the first sample at or after each tick (at most one
        per sample interval, else ``InputError``). ``None``: every sample.
    latency_s : the measurement stamped at ``t`` describes the attitude at
        ``t - latency_s`` (slerp between the two samples around it); none while
        ``t - latency_s < t[0]`` (flag ``no_history``).
    sun_i : (N, 3) or (3,) direction from the spacecraft to the Sun in i (any length),
        or ``None`` (no Sun exclusion). No measurement while the angle between the
        boresight and the Sun is below ``sun_exclusion_rad`` (also in eclipse:
        conservative).
    r_i_m : (N, 3) spacecraft position in i (m), or ``None`` (no Earth exclusion). No
        measurement while the boresight is within ``earth_limb_exclusion_rad`` of the
        Earth's disk: angle to the nadir ``-r`` below ``asin(earth_radius_m / |r|) +
        earth_limb_exclusion_rad`` (a sphere of radius ``earth_radius_m``, m).
    moon_i, moon_exclusion_rad : the same for the Moon (``None``: no Moon exclusion).
    outage_rate_hz, outage_mean_s : random outages: while available, an outage starts
        at rate ``outage_rate_hz`` (exponential waiting time) and lasts an exponential
        time of mean ``outage_mean_s``; starting available at ``t[0]``, the long-run
        fraction of time in outage is ``λμ / (1 + λμ)``. Either zero: none.
    outage_windows_s : (K, 2) scheduled outages ``[start, end)`` in the time of ``t``.

    Model: ``q̂_ib = q_ib(t - L) ⊗ exp(δθ_b)`` (the error on the right, in body axes),
    ``δθ_b = R_bs δθ_s``, ``δθ_s = [σ_cross n1, σ_cross n2, σ_about n3]``, ``n``
    standard normal. So ``rotvec(conj(q_ib) ⊗ q̂_ib)`` expressed in s has the standard
    deviations ``(σ_cross, σ_cross, σ_about)``. The exclusion geometry uses the exposure
    attitude ``q_ib(t - L)`` and the Sun, Moon and position at ``t``.

    Draws: the noise ``(N, 3)`` for every sample first (so a change of the noise level
    leaves the outage draws unchanged), then the random outages.

    Returns ``(q_meas (N, 4), valid (N,) bool, flags (N,) uint8)``: NaN rows where
    ``valid`` is false; ``flags`` says why a due sample has no measurement (bits of
    :data:`STAR_TRACKER_FLAGS`; 0 on valid samples and on samples not due).
    """
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size < 1 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise InputError("expected finite, strictly increasing times of shape (N,)", field="t")
    n = t.size
    q_ib = np.asarray(q_ib, dtype=float)
    if q_ib.shape != (n, 4) or not np.all(np.isfinite(q_ib)):
        raise InputError(f"expected finite values of shape ({n}, 4), got {q_ib.shape}",
                         field="q_ib")
    R_bs = boresight_frame(boresight_b)
    sig = np.array([_non_negative(noise_cross_rad, "noise_cross_rad")] * 2
                   + [_non_negative(noise_about_rad, "noise_about_rad")])
    latency_s = _non_negative(latency_s, "latency_s")
    excl = {name: _non_negative(v, name) for name, v in (
        ("sun_exclusion_rad", sun_exclusion_rad),
        ("earth_limb_exclusion_rad", earth_limb_exclusion_rad),
        ("moon_exclusion_rad", moon_exclusion_rad))}
    outage_rate_hz = _non_negative(outage_rate_hz, "outage_rate_hz")
    outage_mean_s = _non_negative(outage_mean_s, "outage_mean_s")
    windows = np.asarray(outage_windows_s, dtype=float).reshape(-1, 2) if len(
        outage_windows_s) else np.zeros((0, 2))
    if not np.all(np.isfinite(windows)) or np.any(windows[:, 1] <= windows[:, 0]):
        raise InputError(f"expected [start, end] pairs with start < end, got "
                         f"{np.asarray(outage_windows_s).tolist()}", field="outage_windows_s")
    due = _due_rows(t, rate_hz)

    q_exp, known = _exposure_attitude(t, q_ib, latency_s)
    bs_i = quat_rotate(q_exp, R_bs[:, 2])
    flags = np.zeros(n, np.int64)
    if sun_i is not None:
        sun = _directions(sun_i, n, "sun_i")
        flags |= STAR_TRACKER_FLAGS["sun"] * (_angle(bs_i, sun) < excl["sun_exclusion_rad"])
    if moon_i is not None:
        moon = _directions(moon_i, n, "moon_i")
        flags |= STAR_TRACKER_FLAGS["moon"] * (_angle(bs_i, moon) < excl["moon_exclusion_rad"])
    if r_i_m is not None:
        r = np.asarray(r_i_m, dtype=float)
        if r.shape != (n, 3) or not np.all(np.isfinite(r)):
            raise InputError(f"expected finite values of shape ({n}, 3), got {r.shape}",
                             field="r_i_m")
        dist = np.linalg.norm(r, axis=1)
        if np.any(dist <= earth_radius_m):
            raise InputError("position inside the Earth", field="r_i_m",
                             row=int(np.flatnonzero(dist <= earth_radius_m)[0]))
        limb = np.arcsin(earth_radius_m / dist) + excl["earth_limb_exclusion_rad"]
        flags |= STAR_TRACKER_FLAGS["earth"] * (_angle(bs_i, -r / dist[:, None]) < limb)

    noise = rng.standard_normal((n, 3)) * sig
    outage = _outages(t, rng, outage_rate_hz, outage_mean_s, windows)
    flags |= STAR_TRACKER_FLAGS["outage"] * outage
    flags |= STAR_TRACKER_FLAGS["no_history"] * ~known
    flags[~due] = 0
    valid = due & (flags == 0)

    q_meas = quat_mul(q_exp, quat_from_rotvec(noise @ R_bs.T)) if np.any(sig) else q_exp
    q_meas[~valid] = np.nan
    return q_meas, valid, flags.astype(np.uint8)


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
