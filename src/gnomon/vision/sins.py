"""Gyro-only attitude (the SINS) along a simulated flight, and its visual correction (seed 003).

Flight: straight and level at constant altitude with harmonic roll, pitch and yaw
(:class:`HarmonicFlight`); the camera only rotates (a distant scene), so every frame has
exact attitude truth. Gyros: the paper's constant biases, one per axis (MEMS
``1e-3, 2e-3, 3e-3`` rad/s; medium class ``1e-4, 2e-4, 3e-4`` rad/s) plus white noise.

* :func:`integrate_gyro` — the SINS attitude algorithm: ``q_{k+1} = q_k ⊗ exp(ω_k dt / 2)``
  (``q_nb``, Hamilton, scalar first).
* :func:`run_flight` — open loop (the paper: visual pitch from the drifting SINS roll and
  yaw) or closed loop (the project: pitch from the vertical strip, yaw from the horizontal
  strip, roll from the ring search, one after another, each fed back into the SINS when
  the cost curve passes the gate, plus a slow gyro-bias estimate).
* :func:`autonomy_time_s` — the paper's formula (3), reconstructed.

Frames: n = North-East-Down, b = body = camera (x forward, y right, z down);
``R_nb = Rz(ψ) Ry(θ) Rx(φ)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gnomon.errors import InputError
from gnomon.rotation import euler_from_quat, quat_from_euler
from gnomon.vision.camera import rpy_dcm
from gnomon.vision.render import SimulatedFrame
from gnomon.vision.strip import StripMatcher

__all__ = [
    "GYRO_CLASSES",
    "HarmonicFlight",
    "simulate_gyro",
    "integrate_gyro",
    "autonomy_time_s",
    "run_flight",
    "pitch_error_summary",
]

#: Gyro classes of the paper: constant bias per body axis (rad/s) and the white-noise
#: density the project adds (rad/s/√Hz).
GYRO_CLASSES = {
    "mems": {"bias_rad_s": (1e-3, 2e-3, 3e-3), "noise_rad_s_sqrt_hz": 1e-4},
    "medium": {"bias_rad_s": (1e-4, 2e-4, 3e-4), "noise_rad_s_sqrt_hz": 1e-5},
}


@dataclass(frozen=True)
class HarmonicFlight:
    """Euler angles ``a_i(t) = mean_i + amp_i sin(2π t / period_i)``; roll, pitch, yaw (rad)."""

    mean_rad: tuple[float, float, float] = (0.0, math.radians(2.0), 0.0)
    amp_rad: tuple[float, float, float] = (math.radians(4.0), math.radians(5.0),
                                           math.radians(3.0))
    period_s: tuple[float, float, float] = (23.0, 37.0, 29.0)

    def euler(self, t) -> np.ndarray:
        """``[roll, pitch, yaw]`` (rad) at times ``t``, shape ``(n, 3)``."""
        t = np.atleast_1d(np.asarray(t, dtype=float))[:, None]
        w = 2 * np.pi / np.asarray(self.period_s)
        return np.asarray(self.mean_rad) + np.asarray(self.amp_rad) * np.sin(w * t)

    def euler_rate(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, dtype=float))[:, None]
        w = 2 * np.pi / np.asarray(self.period_s)
        return np.asarray(self.amp_rad) * w * np.cos(w * t)

    def body_rate(self, t) -> np.ndarray:
        """Angular rate of b relative to n in b (rad/s), shape ``(n, 3)`` (z-y-x kinematics)."""
        e = self.euler(t)
        d = self.euler_rate(t)
        phi, th = e[:, 0], e[:, 1]
        dphi, dth, dpsi = d[:, 0], d[:, 1], d[:, 2]
        return np.stack([
            dphi - dpsi * np.sin(th),
            dth * np.cos(phi) + dpsi * np.sin(phi) * np.cos(th),
            -dth * np.sin(phi) + dpsi * np.cos(phi) * np.cos(th),
        ], -1)


def simulate_gyro(flight: HarmonicFlight, duration_s: float, rate_hz: float, bias_rad_s,
                  noise_rad_s_sqrt_hz: float, rng: np.random.Generator) -> np.ndarray:
    """Gyro samples for the intervals ``[k dt, (k+1) dt)``: true rate at the interval's middle
    + bias + white noise (``σ = density·√rate``). Shape ``(n, 3)``, rad/s."""
    n = int(round(duration_s * rate_hz))
    dt = 1.0 / rate_hz
    w = flight.body_rate((np.arange(n) + 0.5) * dt)
    noise = noise_rad_s_sqrt_hz * math.sqrt(rate_hz) * rng.standard_normal((n, 3))
    return w + np.asarray(bias_rad_s, dtype=float) + noise


def integrate_gyro(q0_nb, gyro_rad_s, dt_s: float) -> np.ndarray:
    """SINS attitude: ``q_{k+1} = q_k ⊗ exp(ω_k dt / 2)``; returns ``(n + 1, 4)`` ``q_nb``."""
    g = np.asarray(gyro_rad_s, dtype=float)
    if g.ndim != 2 or g.shape[1] != 3:
        raise InputError(f"gyro must have shape (n, 3), got {g.shape}", field="gyro")
    from gnomon.kernels.quat import integrate_rates

    out = np.empty((g.shape[0] + 1, 4))
    integrate_rates(np.asarray(q0_nb, float), np.ascontiguousarray(g), float(dt_s), out)
    return out


def autonomy_time_s(strip_px: float, yaw_bias_rad_s: float, hfov_rad: float,
                    image_cols: int) -> float:
    """Paper's formula (3), reconstructed: ``T = w · A_hfov / (b_z · C_px)``.

    Without yaw correction the SINS yaw error ``b_z t`` shifts the image horizontally by
    ``Y = b_z t C_px / A_hfov`` pixels; the strip match is assumed to fail when ``Y``
    reaches the strip width ``w``.
    """
    if yaw_bias_rad_s <= 0:
        return math.inf
    return float(strip_px) * hfov_rad / (abs(yaw_bias_rad_s) * image_cols)


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def run_flight(scene, camera, gyro_class: str = "mems", strip_px: int = 11,
               duration_s: float = 600.0, mode: str = "open_loop", frame_hz: float = 2.0,
               gyro_hz: float = 100.0, flight: HarmonicFlight | None = None,
               conversions=("resampled",), derotation: str = "sins",
               image_noise: float = 0.004, bias_gain: float = 0.05,
               rng: np.random.Generator | None = None, progress=None,
               matcher_kw: dict | None = None, gyro_bias_rad_s=None) -> dict:
    """Simulate one flight and return per-frame time series (rad) and summary numbers.

    ``mode``: ``"open_loop"`` (the paper: the SINS is never corrected, the visual pitch is
    computed from the SINS roll and yaw) or ``"closed_loop"`` (pitch, yaw, roll searches in
    sequence, each accepted measurement replaces the SINS angle; ``bias_gain`` feeds the
    corrections back into a gyro-bias estimate). ``derotation="truth"`` de-rotates with the
    true roll and yaw (the per-frame accuracy test). Rejected or impossible matches fall
    back to the SINS pitch in the output. ``gyro_bias_rad_s`` overrides the class's bias
    (e.g. a yaw-only bias to isolate formula (3)).

    Returns a dict: ``t`` (frame times, s), ``truth`` / ``sins_open`` / ``estimate``
    (``[roll, pitch, yaw]`` per frame, rad; ``estimate`` is the corrected closed-loop
    attitude, or the open-loop SINS), ``visual_pitch`` (per conversion, rad), ``ok`` (gate
    passed), ``available`` (the match had enough overlap), ``confidence``, ``accepted``
    (closed loop: accepted measurements per axis), ``bias_estimate`` (rad/s) and the
    ``matcher``.
    """
    if gyro_class not in GYRO_CLASSES:
        raise InputError(f"unknown gyro class {gyro_class!r}; known: {sorted(GYRO_CLASSES)}",
                         field="gyro")
    if mode not in ("open_loop", "closed_loop"):
        raise InputError(f"mode must be open_loop or closed_loop, got {mode!r}", field="mode")
    if derotation not in ("sins", "truth"):
        raise InputError(f"derotation must be sins or truth, got {derotation!r}",
                         field="derotation")
    rng = np.random.default_rng(0) if rng is None else rng
    flight = HarmonicFlight() if flight is None else flight
    gc = GYRO_CLASSES[gyro_class]
    bias = gc["bias_rad_s"] if gyro_bias_rad_s is None else gyro_bias_rad_s
    gyro = simulate_gyro(flight, duration_s, gyro_hz, bias,
                         gc["noise_rad_s_sqrt_hz"], rng)
    dt = 1.0 / gyro_hz
    step = int(round(gyro_hz / frame_hz))
    n_frames = gyro.shape[0] // step + 1
    t_frames = np.arange(n_frames) * step * dt
    truth = flight.euler(t_frames)
    q0 = quat_from_euler(truth[0])
    sins_q = integrate_gyro(q0, gyro, dt)[::step][:n_frames]
    sins_open = euler_from_quat(sins_q)
    seed0 = int(rng.integers(1 << 31))
    ref = SimulatedFrame(scene, camera, rpy_dcm(*truth[0]), image_noise, seed0)
    sm = StripMatcher(ref, truth[0], strip_px=strip_px, **(matcher_kw or {}))
    out = {c: np.full(n_frames, np.nan) for c in conversions}
    ok = np.zeros(n_frames, bool)
    available = np.zeros(n_frames, bool)  # the match had enough overlap to give a pitch
    conf = np.zeros(n_frames)
    est = np.array(sins_open)  # closed loop: corrected estimate at frame times
    n_acc = {"pitch": 0, "yaw": 0, "roll": 0}
    q = q0.copy()
    b_hat = np.zeros(3)
    for i in range(n_frames):
        frame = SimulatedFrame(scene, camera, rpy_dcm(*truth[i]), image_noise, seed0 + 1 + i)
        if mode == "open_loop":
            rpy = sins_open[i]
            if derotation == "truth":
                rpy = np.array([truth[i, 0], sins_open[i, 1], truth[i, 2]])
            for c in conversions:
                p, res = sm.pitch(frame, rpy, conversion=c)
                out[c][i] = p if np.isfinite(p) else sins_open[i, 1]
                if c == conversions[0]:
                    ok[i], conf[i], available[i] = res.ok, res.confidence, np.isfinite(p)
        else:
            if i > 0:
                g = gyro[(i - 1) * step:i * step] - b_hat
                q = integrate_gyro(q, g, dt)[-1]
            rpy = euler_from_quat(q)
            before = rpy.copy()
            p, rp = sm.pitch(frame, rpy)
            if rp.ok:
                rpy[1] = p
                n_acc["pitch"] += 1
            out[conversions[0]][i] = p if np.isfinite(p) else rpy[1]
            ok[i], conf[i], available[i] = rp.ok, rp.confidence, np.isfinite(p)
            y, ry = sm.yaw(frame, rpy)
            if ry.ok:
                rpy[2] = y
                n_acc["yaw"] += 1
            r, rr = sm.roll(frame, rpy)
            if rr.ok:
                rpy[0] = r
                n_acc["roll"] += 1
            if i > 0 and bias_gain > 0:
                d = _wrap(rpy - before)  # small: Euler corrections ≈ body-axis corrections
                b_hat = b_hat - bias_gain * np.array([d[0], d[1], d[2]]) / (step * dt)
            q = quat_from_euler(rpy)
            est[i] = rpy
        if progress is not None:
            progress(i, n_frames)
    return {
        "t": t_frames,
        "truth": truth,
        "sins_open": sins_open,
        "estimate": est,
        "visual_pitch": out,
        "ok": ok,
        "available": available,
        "confidence": conf,
        "accepted": n_acc,
        "bias_estimate": b_hat,
        "strip_px": strip_px,
        "gyro": gyro_class,
        "mode": mode,
        "duration_s": float(t_frames[-1]),
        "matcher": sm,
    }


def pitch_error_summary(run: dict, threshold_deg: float = 0.5, conversion: str = "resampled"):
    """``(max, rms, sins_max, autonomy_s)`` in deg/s for a :func:`run_flight` result.

    Closed loop: the error of the corrected estimate; open loop: of the visual pitch.
    ``autonomy_s``: time of the first frame whose pitch error exceeds ``threshold_deg``
    (the flight's duration if none does).
    """
    t = run["t"]
    if run["mode"] == "closed_loop":
        p = run["estimate"][:, 1]
    else:
        p = run["visual_pitch"][conversion]
    e = np.degrees(np.abs(p - run["truth"][:, 1]))
    es = np.degrees(np.abs(run["sins_open"][:, 1] - run["truth"][:, 1]))
    bad = np.nonzero(e > threshold_deg)[0]
    aut = float(t[bad[0]]) if bad.size else float(t[-1])
    return float(e.max()), float(np.sqrt(np.mean(e ** 2))), float(es.max()), aut
