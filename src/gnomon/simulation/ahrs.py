"""Strapdown AHRS simulation: smooth random rotations and MEMS gyro / accelerometer / magnetometer.

Produces a ``Recording`` in the seed-002 frames: navigation frame ENU (a
resting accelerometer reads ``[0, 0, +g]``, the Earth field is ``[0, H, -Z]``),
truth ``q_true = q_nb`` (ENU from body). Used by ``gnomon.reproduce.p002`` to
compare the full and the reduced measurement model on identical data.

Truth: the body rate ``w_b(t)`` (rad/s, body) is a sum of sinusoids per axis
with random frequencies and phases (smooth, band-limited, scaled to a given
RMS); the attitude is integrated from it with ``substeps`` 4th-order Magnus steps
per sample interval (each the exponential of ``h/2 (w_a + w_b) + √3/12 h² w_a × w_b``
from the rates at the substep's two Gauss-Legendre points; one step per 10 ms sample
is within 3e-7 deg of the exact attitude after 120 s of the default rotation, where 8
midpoint steps were 7e-5 deg off). Sensors (per sample k, interval
``[t_{k-1}, t_k]``):

* gyro: ``w_b`` at the interval midpoint + bias + white noise
  (density ``gyro_noise`` rad/s/√Hz → std ``gyro_noise·√fs``); the bias is a
  constant drawn with std ``gyro_bias_std`` per axis plus a random walk
  (``bias_rw`` rad/s/√s);
* accelerometer: ``C_bn (g_n + a_lin_n) + noise`` (std ``accel_noise`` m/s²
  per sample); ``a_lin_n`` optional smooth linear acceleration of RMS
  ``linear_accel_rms`` per axis;
* magnetometer (µT): ``C_bn (m_n + d_n) + noise`` (std ``mag_noise_uT``), field
  magnitude ``field_uT`` and inclination ``inclination_deg``; ``d_n`` an optional
  disturbance of magnitude ``mag_disturbance_uT`` (smooth, random direction),
  active between ``disturbance_window_s``.

The true bias is returned in ``extra['gyro_bias_rad_s']`` (N, 3) and the true
rate in ``extra['w_true_rad_s']``.

Two implementations of the same model: :func:`simulate_ahrs_batch` (and
:func:`simulate_ahrs`, one run of it) draws each run's random numbers with its own
generator and computes the rest in one compiled call for all runs
(:func:`gnomon.kernels.simulate.ahrs_batch`); :func:`simulate_ahrs_reference` is the
readable numpy version it is tested against. Both draw the same numbers in the same
order from ``rng``, so a seed gives the same samples from either, to rounding (they
differ by about 1e-13 of each value: sines evaluated by rotation, see the kernel). Two
orders exist (``draw_order``):

* ``"by-sensor"`` (the default; the order of every release so far): rotation profile
  (frequencies, phases, amplitudes), initial attitude, constant bias, bias random walk
  (N, 3), gyro noise (N, 3), [linear acceleration profile], accelerometer noise (N, 3),
  [disturbance profile], magnetometer noise (N, 3);
* ``"by-sample"``: rotation profile, initial attitude, constant bias, [linear
  acceleration profile], [disturbance profile], then the noise as
  ``rng.standard_normal((N, 12))``: per sample the bias step, gyro, accelerometer and
  magnetometer noise (three each). Drawn by a compiled loop
  (:func:`gnomon.kernels.simulate.normals_by_sample`, numpy's algorithm on ``rng``), so
  a campaign's simulation is not waiting on numpy's fill; the ``kind: imu`` scenarios use
  this order with an SFC64 generator (``gnomon.scenarios.simulator.imu_rng``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gnomon.errors import InputError
from gnomon.recording import Recording
from gnomon.rotation import dcm_from_quat, quat_from_euler, quat_from_rotvec, quat_mul

__all__ = ["AhrsSimParams", "DRAW_ORDERS", "SHARED_IN_BATCH", "batch_key", "simulate_ahrs",
           "simulate_ahrs_batch", "simulate_ahrs_reference", "smooth_random_signal"]


#: the orders in which a run's random numbers are drawn (module docstring)
DRAW_ORDERS = ("by-sensor", "by-sample")


def _check_draw_order(draw_order: str) -> None:
    if draw_order not in DRAW_ORDERS:
        raise InputError(f"unknown draw order {draw_order!r}; known: {', '.join(DRAW_ORDERS)}",
                         field="draw_order")


@dataclass(frozen=True)
class AhrsSimParams:
    """Scenario of ``simulate_ahrs`` (SI units; MEMS-grade defaults)."""

    duration_s: float = 120.0          # s
    rate_hz: float = 100.0             # Hz
    rate_rms: float = 0.5              # rad/s, RMS body rate per axis
    rate_band_hz: tuple = (0.02, 0.3)  # Hz, frequency band of the rotation
    n_harmonics: int = 6               # sinusoids per axis
    rest_s: float = 0.0                # s at rest at the start
    substeps: int = 1                  # truth integration steps per sample (4th order)
    gyro_noise: float = 3e-4           # rad/s/√Hz (0.017 °/s/√Hz)
    gyro_bias_std: float = 0.01        # rad/s, constant bias per axis (0.57 °/s)
    bias_rw: float = 2e-5              # rad/s/√s
    accel_noise: float = 0.02          # m/s² per sample
    mag_noise_uT: float = 0.3          # µT per sample
    gravity: float = 9.81              # m/s²
    field_uT: float = 50.0             # µT
    inclination_deg: float = 60.0      # deg, tan I = Z/H
    linear_accel_rms: float = 0.0      # m/s² per axis (0: none)
    mag_disturbance_uT: float = 0.0    # µT (0: none)
    disturbance_window_s: tuple = (0.0, float("inf"))  # s, when the disturbances act

    def validate(self) -> None:
        for name in ("duration_s", "rate_hz", "gravity", "field_uT"):
            if not getattr(self, name) > 0:
                raise InputError(f"must be > 0, got {getattr(self, name)!r}", field=name)
        for name in ("rate_rms", "rest_s", "gyro_noise", "gyro_bias_std", "bias_rw",
                     "accel_noise", "mag_noise_uT", "linear_accel_rms", "mag_disturbance_uT"):
            if not getattr(self, name) >= 0:
                raise InputError(f"must be >= 0, got {getattr(self, name)!r}", field=name)
        if not 0 <= self.inclination_deg < 90:
            raise InputError(f"must be in [0, 90), got {self.inclination_deg!r}",
                             field="inclination_deg")
        if self.substeps < 1 or self.n_harmonics < 1:
            raise InputError("must be >= 1", field="substeps/n_harmonics")


def smooth_random_signal(t, rms, band_hz, n_harmonics, rng: np.random.Generator, dim=3):
    """Sum of ``n_harmonics`` sinusoids per component, frequencies uniform in ``band_hz``,
    random phases, scaled to the given RMS; returns a callable ``f(t) -> (len(t), dim)``
    and its value at ``t``."""
    f = rng.uniform(band_hz[0], band_hz[1], (n_harmonics, dim))
    ph = rng.uniform(0, 2 * np.pi, (n_harmonics, dim))
    amp = rng.uniform(0.5, 1.0, (n_harmonics, dim))
    amp *= rms * np.sqrt(2.0) / np.sqrt((amp**2).sum(0))

    def fun(tt):
        tt = np.asarray(tt, float)[:, None, None]
        return (amp * np.sin(2 * np.pi * f * tt + ph)).sum(1)

    return fun, fun(t)


def _harmonics(rng: np.random.Generator, rms, band_hz, n_harmonics):
    """The draws of :func:`smooth_random_signal`: frequencies (Hz), phases (rad) and
    amplitudes, each (n_harmonics, 3)."""
    f = rng.uniform(band_hz[0], band_hz[1], (n_harmonics, 3))
    ph = rng.uniform(0, 2 * np.pi, (n_harmonics, 3))
    amp = rng.uniform(0.5, 1.0, (n_harmonics, 3))
    amp *= rms * np.sqrt(2.0) / np.sqrt((amp**2).sum(0))
    return f, ph, amp


def simulate_ahrs(params: AhrsSimParams | None, rng: np.random.Generator,
                  draw_order: str = "by-sensor") -> Recording:
    """Simulate a strapdown AHRS run (see the module docstring); ``params`` None: defaults.

    All randomness (rotation profile, initial attitude, biases, noise, disturbances)
    comes from ``rng`` in ``draw_order`` (module docstring), so ``(params, seed)``
    describes a run completely. One run of :func:`simulate_ahrs_batch`.
    """
    return simulate_ahrs_batch(params, [rng], draw_order)[0]


#: the parameters the runs of one simulate_ahrs_batch call must share (the time base,
#: the truth integration, and which optional terms exist); the others may differ per run
SHARED_IN_BATCH = ("duration_s", "rate_hz", "substeps", "rest_s", "n_harmonics",
                   "disturbance_window_s")


def batch_key(p: AhrsSimParams) -> tuple:
    """Runs whose parameters have the same key can be simulated in one
    :func:`simulate_ahrs_batch` call."""
    return (*(getattr(p, k) for k in SHARED_IN_BATCH), p.linear_accel_rms > 0,
            p.mag_disturbance_uT > 0)


def simulate_ahrs_batch(params, rngs: list[np.random.Generator],
                        draw_order: str = "by-sensor") -> list[Recording]:
    """R runs, one generator each (drawn from in ``draw_order``, module docstring): a
    ``Recording`` per run.

    ``params``: one ``AhrsSimParams`` (None: defaults) for every run, or one per run, all
    with the same :func:`batch_key` (the time base, the substeps, the rest and the
    disturbance window, the number of harmonics and which optional terms exist; noise
    levels, biases, rates, the field and the amplitudes may differ). Run ``r`` equals
    ``simulate_ahrs(params[r], rngs[r])`` and, to rounding,
    ``simulate_ahrs_reference(params[r], rngs[r])`` (same draws from the same
    generator). Each run's random numbers are drawn in bulk by its generator; the truth
    attitude and the sensors of all runs are one compiled call
    (:func:`gnomon.kernels.simulate.ahrs_batch`). The recordings' arrays are views into
    shared (R, N, 3) / (R, N, 4) arrays (each C-contiguous).
    """
    from gnomon.kernels.simulate import ahrs_batch, normals_by_sample

    rngs = list(rngs)
    if not rngs:
        return []
    if params is None or isinstance(params, AhrsSimParams):
        ps = [params or AhrsSimParams()] * len(rngs)
    else:
        ps = [q or AhrsSimParams() for q in params]
        if len(ps) != len(rngs):
            raise InputError(f"{len(ps)} parameter sets for {len(rngs)} generators",
                             field="params")
    for q in set(ps):
        q.validate()
    if len({batch_key(q) for q in ps}) > 1:
        raise InputError(f"runs of one batch must share {', '.join(SHARED_IN_BATCH)} "
                         "and which of linear_accel_rms, mag_disturbance_uT are > 0",
                         field="params")
    if not all(isinstance(g, np.random.Generator) for g in rngs):
        raise TypeError("rng must be a numpy.random.Generator")
    _check_draw_order(draw_order)
    by_sensor = draw_order == "by-sensor"
    p = ps[0]
    fs = p.rate_hz
    n = int(round(p.duration_s * fs)) + 1
    t = np.arange(n) / fs
    dt = 1.0 / fs
    runs = len(rngs)
    n_lin = 4 if p.linear_accel_rms > 0 else 0
    n_dist = 3 if p.mag_disturbance_uT > 0 else 0
    rate = np.empty((3, runs, p.n_harmonics, 3))
    lin = np.zeros((3, runs, n_lin, 3))
    dist = np.zeros((3, runs, n_dist, 3))
    rpy0 = np.empty((runs, 3))
    bias0 = np.empty((runs, 3))
    acc_n = np.zeros((runs, 3))
    m_n = np.empty((runs, 3))
    dist_uT = np.empty(runs)
    sigma = np.empty((runs, 4))
    # standard normal draws, turned into the samples in place by the kernel
    gyro, bias, accel, mag = (np.empty((runs, n, 3)) for _ in range(4))
    for r, (rng, q) in enumerate(zip(rngs, ps, strict=True)):
        # the draws of simulate_ahrs_reference, in its order
        rate[:, r] = _harmonics(rng, q.rate_rms, q.rate_band_hz, q.n_harmonics)
        rpy0[r] = rng.uniform([-0.3, -0.3, -np.pi], [0.3, 0.3, np.pi])
        bias0[r] = rng.normal(0, q.gyro_bias_std, 3)
        if by_sensor:
            rng.standard_normal(out=bias[r])
            rng.standard_normal(out=gyro[r])
        if n_lin:
            lin[:, r] = _harmonics(rng, q.linear_accel_rms, (0.1, 1.0), n_lin)
        if by_sensor:
            rng.standard_normal(out=accel[r])
        if n_dist:
            dist[:, r] = _harmonics(rng, 1.0, (0.01, 0.1), n_dist)
        if by_sensor:
            rng.standard_normal(out=mag[r])
        else:
            normals_by_sample(rng, bias[r], gyro[r], accel[r], mag[r])
        inc = np.radians(q.inclination_deg)
        m_n[r] = [0.0, q.field_uT * np.cos(inc), -q.field_uT * np.sin(inc)]
        acc_n[r, 2] = q.gravity
        dist_uT[r] = q.mag_disturbance_uT
        sigma[r] = [q.bias_rw * np.sqrt(dt), q.gyro_noise * np.sqrt(fs), q.accel_noise,
                    q.mag_noise_uT]
    q0 = np.ascontiguousarray(quat_from_euler(rpy0))
    q_nb = np.empty((runs, n, 4))
    w_true = np.empty((runs, n, 3))
    ahrs_batch(t, dt, int(p.substeps), float(p.rest_s),
               np.array(p.disturbance_window_s, dtype=float), rate[0], rate[1], rate[2], q0,
               acc_n, lin[0], lin[1], lin[2], m_n, dist_uT, dist[0], dist[1], dist[2],
               bias0, sigma, gyro, bias, accel, mag, q_nb, w_true)
    return [Recording(t=t, gyro=gyro[r], accel=accel[r], mag=mag[r], mag_unit="uT",
                      q_true=q_nb[r], frames={"reference": "ENU", "body": "body"},
                      source="gnomon.simulation.ahrs",
                      extra={"gyro_bias_rad_s": bias[r], "w_true_rad_s": w_true[r]})
            for r in range(runs)]


def simulate_ahrs_reference(params: AhrsSimParams | None, rng: np.random.Generator,
                            draw_order: str = "by-sensor") -> Recording:
    """The readable (slow) numpy version of :func:`simulate_ahrs`: the same model and the
    same draws, so the same samples to rounding; the tests compare the two."""
    from gnomon.kernels.quat import chain_products

    p = params or AhrsSimParams()
    p.validate()
    if not isinstance(rng, np.random.Generator):
        raise TypeError("rng must be a numpy.random.Generator")
    _check_draw_order(draw_order)
    fs = p.rate_hz
    n = int(round(p.duration_s * fs)) + 1
    t = np.arange(n) / fs
    dt = 1.0 / fs
    rate_fun, _ = smooth_random_signal(t, p.rate_rms, p.rate_band_hz, p.n_harmonics, rng)
    gate = (t >= p.rest_s).astype(float)

    def w_of(tt):
        return rate_fun(tt) * (np.asarray(tt) >= p.rest_s)[:, None]

    # truth attitude
    q0 = quat_from_euler(rng.uniform([-0.3, -0.3, -np.pi], [0.3, 0.3, np.pi]))
    h = dt / p.substeps
    c = np.sqrt(3.0) / 6.0                                  # Gauss-Legendre points h (1/2 ∓ c)
    mid = t[:-1, None] + (np.arange(p.substeps) + 0.5)[None, :] * h
    w_a = w_of((mid - c * h).ravel()).reshape(n - 1, p.substeps, 3)
    w_b = w_of((mid + c * h).ravel()).reshape(n - 1, p.substeps, 3)
    # 4th-order Magnus: exp(h/2 (w_a + w_b) + √3/12 h² w_a × w_b) per substep
    dq = quat_from_rotvec(0.5 * h * (w_a + w_b)
                          + np.sqrt(3.0) / 12.0 * h * h * np.cross(w_a, w_b))
    step = dq[:, 0]
    for s in range(1, p.substeps):
        step = quat_mul(step, dq[:, s])
    q = np.empty((n, 4))
    chain_products(q0, np.ascontiguousarray(step), q)  # compiled: q[k+1] = q[k] ⊗ step[k]
    C_bn = np.swapaxes(dcm_from_quat(q), -1, -2)

    # the random draws, in draw_order: standard normal noise z (n, 12), columns the bias
    # step, gyro, accelerometer and magnetometer noise
    bias0 = rng.normal(0, p.gyro_bias_std, 3)
    z = np.empty((n, 12))
    if draw_order == "by-sensor":
        z[:, 0:3] = rng.standard_normal((n, 3))
        z[:, 3:6] = rng.standard_normal((n, 3))
    if p.linear_accel_rms > 0:
        _, a_lin = smooth_random_signal(t, p.linear_accel_rms, (0.1, 1.0), 4, rng)
    if draw_order == "by-sensor":
        z[:, 6:9] = rng.standard_normal((n, 3))
    if p.mag_disturbance_uT > 0:
        _, d = smooth_random_signal(t, 1.0, (0.01, 0.1), 3, rng)
    if draw_order == "by-sensor":
        z[:, 9:12] = rng.standard_normal((n, 3))
    else:
        z = rng.standard_normal((n, 12))

    # gyro: midpoint rate of the preceding interval (first sample: rate at t0)
    t_mid = np.concatenate([[t[0]], t[1:] - 0.5 * dt])
    w_true = w_of(t_mid)
    bias = bias0 + np.cumsum(p.bias_rw * np.sqrt(dt) * z[:, 0:3], 0)
    gyro = w_true + bias + p.gyro_noise * np.sqrt(fs) * z[:, 3:6]

    active = ((t >= p.disturbance_window_s[0]) & (t < p.disturbance_window_s[1]))[:, None]
    g_n = np.array([0.0, 0.0, p.gravity])
    acc_n = np.broadcast_to(g_n, (n, 3)).copy()
    if p.linear_accel_rms > 0:
        acc_n += a_lin * active * gate[:, None]
    accel = np.einsum("nij,nj->ni", C_bn, acc_n) + p.accel_noise * z[:, 6:9]

    inc = np.radians(p.inclination_deg)
    m_n = np.broadcast_to([0.0, p.field_uT * np.cos(inc), -p.field_uT * np.sin(inc)],
                          (n, 3)).copy()
    if p.mag_disturbance_uT > 0:
        d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        m_n += p.mag_disturbance_uT * d * active
    mag = np.einsum("nij,nj->ni", C_bn, m_n) + p.mag_noise_uT * z[:, 9:12]

    return Recording(
        t=t, gyro=gyro, accel=accel, mag=mag, mag_unit="uT", q_true=q,
        frames={"reference": "ENU", "body": "body"}, source="gnomon.simulation.ahrs",
        extra={"gyro_bias_rad_s": bias, "w_true_rad_s": w_true},
    )
