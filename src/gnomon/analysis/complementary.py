"""Analysis of first- and second-order complementary filters (seed 004).

Source: "Complementary filter for determining the orientation of moving
objects" (seed 004, ``shared/seeds/004_c0fcf3e556c4470f.txt``). One axis, the
filtration scheme of the paper's Fig. 1::

    φ̂ = W(s) · (ω / s) + (1 − W(s)) · φ_a

with ``ω`` the gyro rate (rad/s) and ``φ_a`` the angle (rad) computed from the
accelerometer. With ``ω = sφ + ω_d`` (a gyro drift ``ω_d``) and
``φ_a = φ + e_a`` (an accelerometer angle error ``e_a``, e.g. ``a/g`` during a
linear acceleration ``a``) the filter's error is::

    δ = φ̂ − φ = (1 − W(s)) · e_a  +  W(s) · ω_d / s²

(a constant drift is a step ``ω_d / s`` in the rate, a ramp ``ω_d / s²`` in the
integrated angle). The filters compared by the paper:

===========  ==============================  ==============================
filter       W(s)                            1 − W(s)
===========  ==============================  ==============================
first order  Ts / (Ts + 1)                   1 / (Ts + 1)
variant 1    (s² + r₁s) / (s² + r₁s + r₂)    r₂ / (s² + r₁s + r₂)
variant 2    s² / (s² + r₁s + r₂)            (r₁s + r₂) / (s² + r₁s + r₂)
===========  ==============================  ==============================

Closed forms derived here (final-value theorem on ``W(s) ω_d / s²``):

* first order: steady drift error ``T ω_d``; acceleration error of a pulse
  ``A = a/g`` lasting ``τ``: ``δ(t) = A(1 − e^{−t/T}) − A(1 − e^{−(t−τ)/T})·1(t ≥ τ)``,
  peak at ``t = τ``: ``A(1 − e^{−τ/T})`` exactly, ``≈ (τ/T) A`` for ``τ ≪ T``
  (the paper's formula; 2.87° for ``A = 1, τ = 5 s, T = 100 s``).
* variant 1: steady drift error ``r₁ ω_d / r₂`` (not zero);
  variant 2: steady drift error ``0`` (its W has a double zero at s = 0, so it
  rejects a ramp). The paper's statement that both variants treat the drift
  alike "because W(0) = 0" holds for a constant angle offset, not for the
  ramp that a constant drift produces.
* a real accelerometer sees the tilt ``arctan(a/g)`` (45° for ``a = g``), not
  ``a/g`` (1 rad): the "true geometry" errors scale by ``arctan(A)/A``.

Angles in rad, times in s, rates in rad/s throughout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize, signal

__all__ = [
    "SecondOrderGains",
    "first_order_tf",
    "second_order_tf",
    "second_order_gains",
    "bandwidth_rad_s",
    "bode",
    "first_order_accel_error",
    "first_order_drift_error",
    "first_order_peak_accel_error",
    "first_order_peak_accel_error_small_tau",
    "first_order_steady_drift_error",
    "second_order_step_response",
    "second_order_impulse_response",
    "second_order_accel_error",
    "second_order_drift_error",
    "second_order_steady_drift_error",
    "second_order_peak_accel_error",
    "accel_tilt_error_rad",
]

VARIANTS = (1, 2)


# ---------------------------------------------------------------- transfer functions
def first_order_tf(T_s: float) -> tuple[signal.TransferFunction, signal.TransferFunction]:
    """``(W, 1 − W)`` of the first-order filter with time constant ``T_s`` (s).

    ``W = Ts/(Ts + 1)`` acts on the gyro-integrated angle, ``1 − W = 1/(Ts + 1)``
    on the accelerometer angle (paper, eq. 6).
    """
    _positive("T_s", T_s)
    return (signal.TransferFunction([T_s, 0.0], [T_s, 1.0]),
            signal.TransferFunction([1.0], [T_s, 1.0]))


def second_order_tf(r1: float, r2: float, variant: int
                    ) -> tuple[signal.TransferFunction, signal.TransferFunction]:
    """``(W, 1 − W)`` of the second-order filter, ``variant`` 1 or 2 (paper, Figs. 5–6).

    Variant 1: ``W = (s² + r₁s)/D``, ``1 − W = r₂/D``; variant 2: ``W = s²/D``,
    ``1 − W = (r₁s + r₂)/D``; ``D = s² + r₁s + r₂``; ``r₁`` in 1/s, ``r₂`` in 1/s².
    """
    _positive("r1", r1)
    _positive("r2", r2)
    den = [1.0, r1, r2]
    if variant == 1:
        return (signal.TransferFunction([1.0, r1, 0.0], den),
                signal.TransferFunction([r2], den))
    if variant == 2:
        return (signal.TransferFunction([1.0, 0.0, 0.0], den),
                signal.TransferFunction([r1, r2], den))
    raise ValueError(f"variant must be 1 or 2, got {variant!r}")


@dataclass(frozen=True)
class SecondOrderGains:
    """``r1`` (1/s), ``r2`` (1/s²) and the natural frequency / damping they mean."""

    r1: float
    r2: float
    omega_n_rad_s: float
    zeta: float


def second_order_gains(bandwidth_rad_s: float, zeta: float = 1.0 / math.sqrt(2.0),
                       variant: int = 1) -> SecondOrderGains:
    """``r₁ = 2ζω_n``, ``r₂ = ω_n²`` so that ``1 − W`` of ``variant`` has its −3 dB point at
    ``bandwidth_rad_s`` (rad/s) — the bandwidth of a first-order filter with
    ``T = 1/bandwidth_rad_s``.

    With ``x = ω/ω_n`` at −3 dB: variant 1 (``ω_n²/D``)
    ``x² = 1 − 2ζ² + sqrt(4ζ⁴ − 4ζ² + 2)`` (``x = 1`` for ``ζ = 1/√2``);
    variant 2 (``(2ζω_n s + ω_n²)/D``) ``x² = 1 + 2ζ² + sqrt((1 + 2ζ²)² + 1)``.
    """
    _positive("bandwidth_rad_s", bandwidth_rad_s)
    _positive("zeta", zeta)
    z2 = zeta * zeta
    if variant == 1:
        x2 = 1.0 - 2.0 * z2 + math.sqrt(4.0 * z2 * z2 - 4.0 * z2 + 2.0)
    elif variant == 2:
        x2 = 1.0 + 2.0 * z2 + math.sqrt((1.0 + 2.0 * z2) ** 2 + 1.0)
    else:
        raise ValueError(f"variant must be 1 or 2, got {variant!r}")
    wn = bandwidth_rad_s / math.sqrt(x2)
    return SecondOrderGains(r1=2.0 * zeta * wn, r2=wn * wn, omega_n_rad_s=wn, zeta=zeta)


def bandwidth_rad_s(tf: signal.TransferFunction, w_max: float = 1e3) -> float:
    """Frequency (rad/s) where a low-pass ``|tf(iω)|`` falls below ``|tf(0)|/√2`` (−3 dB) for good.

    The last downward crossing on a log grid from 1e-8 to ``w_max``, refined by ``brentq``.
    """
    def excess(logw):
        return abs(_freqresp(tf, 10.0**logw)) - abs(_freqresp(tf, 0.0)) / math.sqrt(2.0)

    grid = np.linspace(-8.0, math.log10(w_max), 2000)
    vals = np.array([excess(g) for g in grid])
    down = np.flatnonzero((vals[:-1] > 0) & (vals[1:] <= 0))
    if down.size == 0:
        raise ValueError("no -3 dB crossing found below w_max")
    i = int(down[-1])
    return float(10.0 ** optimize.brentq(excess, grid[i], grid[i + 1], xtol=1e-14))


def _freqresp(tf: signal.TransferFunction, w: float) -> complex:
    s = 1j * w
    return complex(np.polyval(tf.num, s) / np.polyval(tf.den, s))


def bode(tf: signal.TransferFunction, w_rad_s) -> tuple[np.ndarray, np.ndarray]:
    """Magnitude (dB) and phase (deg) of ``tf`` at ``w_rad_s`` (rad/s) (``scipy.signal.bode``)."""
    _, mag, phase = signal.bode(tf, w=np.asarray(w_rad_s, dtype=float))
    return mag, phase


# ---------------------------------------------------------------- accelerometer geometry
def accel_tilt_error_rad(a_over_g, model: str = "linear") -> np.ndarray:
    """Angle error (rad) of the accelerometer's tilt during a horizontal acceleration ``a``.

    ``model="linear"``: the paper's small-angle ``a/g``; ``model="true"``: the
    real geometry ``arctan(a/g)`` (specific force ``[a, 0, g]`` read as a tilt).
    """
    x = np.asarray(a_over_g, dtype=float)
    if model == "linear":
        return x
    if model == "true":
        return np.arctan(x)
    raise ValueError(f"model must be 'linear' or 'true', got {model!r}")


# ---------------------------------------------------------------- first order, closed form
def first_order_accel_error(t_s, T_s: float, tau_s: float, accel_error_rad: float) -> np.ndarray:
    """Error (rad) of the first-order filter for an accelerometer angle error pulse.

    ``e_a = accel_error_rad`` for ``0 ≤ t < tau_s``, zero otherwise (acceleration
    switched on at ``t = 0``, off at ``τ``); paper eq. (2):
    ``δ(t) = A(1 − e^{−t/T}) − A(1 − e^{−(t−τ)/T})·1(t ≥ τ)``, zero for ``t < 0``.
    """
    _positive("T_s", T_s)
    t = np.asarray(t_s, dtype=float)
    on = np.where(t >= 0.0, 1.0 - np.exp(-np.maximum(t, 0.0) / T_s), 0.0)
    off = np.where(t >= tau_s, 1.0 - np.exp(-np.maximum(t - tau_s, 0.0) / T_s), 0.0)
    return accel_error_rad * (on - off)


def first_order_peak_accel_error(T_s: float, tau_s: float, accel_error_rad: float) -> float:
    """Exact peak (rad) of ``first_order_accel_error``: ``A(1 − e^{−τ/T})``, at ``t = τ``."""
    _positive("T_s", T_s)
    return float(accel_error_rad * -math.expm1(-tau_s / T_s))


def first_order_peak_accel_error_small_tau(T_s: float, tau_s: float,
                                           accel_error_rad: float) -> float:
    """The paper's approximation ``(τ/T)·A`` (rad) of the peak, valid for ``τ ≪ T`` (eq. 7)."""
    _positive("T_s", T_s)
    return float(tau_s / T_s * accel_error_rad)


def first_order_drift_error(t_s, T_s: float, drift_rad_s: float) -> np.ndarray:
    """Error (rad) of the first-order filter under a gyro drift starting at ``t = 0``.

    ``W ω_d/s² = T ω_d/(s(Ts + 1))`` → ``T ω_d (1 − e^{−t/T})``.
    """
    _positive("T_s", T_s)
    t = np.asarray(t_s, dtype=float)
    return np.where(t >= 0.0, T_s * drift_rad_s * -np.expm1(-np.maximum(t, 0.0) / T_s), 0.0)


def first_order_steady_drift_error(T_s: float, drift_rad_s: float) -> float:
    """Steady error (rad) under a constant gyro drift: ``T ω_d`` (paper, eq. 7)."""
    _positive("T_s", T_s)
    return float(T_s * drift_rad_s)


# ---------------------------------------------------------------- second order, closed form
def _poles(r1: float, r2: float):
    disc = complex(r1 * r1 - 4.0 * r2)
    root = np.sqrt(disc)
    return (-r1 + root) / 2.0, (-r1 - root) / 2.0


def _critical(r1: float, r2: float) -> bool:
    return abs(r1 * r1 - 4.0 * r2) <= 1e-12 * max(r1 * r1, 4.0 * r2)


def _step_lowpass(t: np.ndarray, r1: float, r2: float) -> np.ndarray:
    """Step response of ``r₂/(s² + r₁s + r₂)`` for ``t ≥ 0``."""
    if _critical(r1, r2):
        p = -r1 / 2.0
        return 1.0 - np.exp(p * t) * (1.0 - p * t)
    p1, p2 = _poles(r1, r2)
    y = 1.0 + r2 * (np.exp(p1 * t) / (p1 * (p1 - p2)) + np.exp(p2 * t) / (p2 * (p2 - p1)))
    return y.real


def _impulse_lowpass(t: np.ndarray, r1: float, r2: float) -> np.ndarray:
    """Impulse response (1/s) of ``r₂/(s² + r₁s + r₂)`` for ``t ≥ 0``."""
    if _critical(r1, r2):
        p = -r1 / 2.0
        return r2 * t * np.exp(p * t)
    p1, p2 = _poles(r1, r2)
    return (r2 * (np.exp(p1 * t) - np.exp(p2 * t)) / (p1 - p2)).real


def second_order_step_response(t_s, r1: float, r2: float, variant: int) -> np.ndarray:
    """Closed-form unit-step response of ``1 − W`` (zero for ``t < 0``).

    Variant 1: ``y₁`` = step response of ``r₂/D`` (partial fractions over the
    poles of D; the critically damped case separately). Variant 2:
    ``(r₁s + r₂)/D = r₂/D + (r₁/r₂)·s·r₂/D`` → ``y₁ + (r₁/r₂)·h₁`` with ``h₁`` the
    impulse response of ``r₂/D``.
    """
    _positive("r1", r1)
    _positive("r2", r2)
    t = np.asarray(t_s, dtype=float)
    tp = np.maximum(t, 0.0)
    y = _step_lowpass(tp, r1, r2)
    if variant == 2:
        y = y + r1 / r2 * _impulse_lowpass(tp, r1, r2)
    elif variant != 1:
        raise ValueError(f"variant must be 1 or 2, got {variant!r}")
    return np.where(t >= 0.0, y, 0.0)


def second_order_impulse_response(t_s, r1: float, r2: float, variant: int) -> np.ndarray:
    """Closed-form impulse response (1/s) of ``1 − W`` for ``t > 0`` (zero for ``t < 0``)."""
    t = np.asarray(t_s, dtype=float)
    tp = np.maximum(t, 0.0)
    h = _impulse_lowpass(tp, r1, r2)
    if variant == 2:
        # d/dt h1 = r2·(p1 e^{p1 t} − p2 e^{p2 t})/(p1 − p2)
        if _critical(r1, r2):
            p = -r1 / 2.0
            dh = r2 * np.exp(p * tp) * (1.0 + p * tp)
        else:
            p1, p2 = _poles(r1, r2)
            dh = (r2 * (p1 * np.exp(p1 * tp) - p2 * np.exp(p2 * tp)) / (p1 - p2)).real
        h = h + r1 / r2 * dh
    elif variant != 1:
        raise ValueError(f"variant must be 1 or 2, got {variant!r}")
    return np.where(t >= 0.0, h, 0.0)


def second_order_accel_error(t_s, r1: float, r2: float, variant: int, tau_s: float,
                             accel_error_rad: float) -> np.ndarray:
    """Error (rad) of a second-order filter for an accelerometer error pulse of height
    ``accel_error_rad`` on ``[0, τ)``: ``A·(y(t) − y(t − τ))`` with ``y`` the step response of
    ``1 − W``."""
    t = np.asarray(t_s, dtype=float)
    return accel_error_rad * (second_order_step_response(t, r1, r2, variant)
                              - second_order_step_response(t - tau_s, r1, r2, variant))


def second_order_peak_accel_error(r1: float, r2: float, variant: int, tau_s: float,
                                  accel_error_rad: float) -> tuple[float, float]:
    """``(peak error (rad), time of the peak (s))`` of ``second_order_accel_error``.

    Found on the closed form: a dense grid over ten time constants, refined by
    bounded scalar minimisation.
    """
    span = tau_s + 10.0 * (r1 / r2 + 2.0 / r1 + 1.0 / math.sqrt(r2))
    t = np.linspace(0.0, span, 20001)
    e = np.abs(second_order_accel_error(t, r1, r2, variant, tau_s, accel_error_rad))
    i = int(np.argmax(e))
    lo, hi = t[max(i - 1, 0)], t[min(i + 1, t.size - 1)]
    res = optimize.minimize_scalar(
        lambda x: -abs(float(second_order_accel_error(x, r1, r2, variant, tau_s,
                                                      accel_error_rad))),
        bounds=(lo, hi), method="bounded", options={"xatol": 1e-10})
    if -res.fun >= e[i]:
        return float(-res.fun), float(res.x)
    return float(e[i]), float(t[i])


def second_order_drift_error(t_s, r1: float, r2: float, variant: int,
                             drift_rad_s: float) -> np.ndarray:
    """Error (rad) of a second-order filter under a gyro drift ``ω_d`` starting at ``t = 0``.

    ``W ω_d/s²``: variant 1 ``ω_d (s + r₁)/(sD) = ω_d (1/D + r₁/(sD))`` →
    ``ω_d (h₁ + r₁ y₁)/r₂``; variant 2 ``ω_d/D`` → ``ω_d h₁/r₂``
    (``y₁``, ``h₁``: step and impulse responses of ``r₂/D``).
    """
    t = np.asarray(t_s, dtype=float)
    tp = np.maximum(t, 0.0)
    h1 = _impulse_lowpass(tp, r1, r2)
    if variant == 1:
        e = drift_rad_s * (h1 + r1 * _step_lowpass(tp, r1, r2)) / r2
    elif variant == 2:
        e = drift_rad_s * h1 / r2
    else:
        raise ValueError(f"variant must be 1 or 2, got {variant!r}")
    return np.where(t >= 0.0, e, 0.0)


def second_order_steady_drift_error(r1: float, r2: float, variant: int,
                                    drift_rad_s: float) -> float:
    """Steady error (rad) under a constant drift, by the final-value theorem on ``W ω_d/s²``.

    Variant 1: ``lim s·(s² + r₁s)/D·ω_d/s² = r₁ ω_d / r₂``; variant 2:
    ``lim s·s²/D·ω_d/s² = 0``.
    """
    _positive("r1", r1)
    _positive("r2", r2)
    if variant == 1:
        return float(r1 * drift_rad_s / r2)
    if variant == 2:
        return 0.0
    raise ValueError(f"variant must be 1 or 2, got {variant!r}")


def _positive(name: str, value: float) -> None:
    try:
        ok = math.isfinite(float(value)) and float(value) > 0.0
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
