"""The IMU's noise from a static log (``gnomon calibrate imu``): the Allan deviation of the
gyro and the accelerometer per axis, the IEEE Std 952 noise terms read off it
(:mod:`gnomon.calibration.allan`), the rest biases, and the report's JSON form.

Input: a ``Recording`` (any reader; its gyro in rad/s, accelerometer in m/s², sensor axes
b) of a device at rest, ideally for hours on a steady table after it has warmed up.

Output (:func:`imu_noise`): ``(report, curves)``. ``report`` is a JSON-able dict (the
contract of ``gnomon calibrate imu --json``):

* ``gyro``: ``noise_density_rad_s_sqrt_hz`` N (angle random walk), ``bias_instability_rad_s``
  B, ``rate_random_walk_rad_s2_sqrt_hz`` K, ``bias_rad_s`` (the mean rate), each a list
  of 3 (x, y, z; None where the curve does not show the term, with the sentence why in
  ``why_none``), and the same in the datasheet units ``angle_random_walk_deg_sqrt_h``
  (N·180/π·60), ``bias_instability_deg_h``; ``bias_instability_fit_rad_s`` B from the
  fitted model, ``bias_instability_bound_rad_s`` the bound when B is None, ``read_at_tau_s``
  where each term was read, ``model`` the fitted model's coefficients;
* ``accel``: ``noise_density_m_s2_sqrt_hz`` N (velocity random walk),
  ``bias_instability_m_s2`` B, ``random_walk_m_s3_sqrt_hz`` K, ``mean_m_s2`` and the one
  observable part of its bias, ``bias_along_gravity_m_s2 = |mean| - g`` (``bias_note``
  says why only that part; None when the log has no accelerometer);
* ``duration_s`` (the gyro's time span), ``static`` (the check of rest), ``notes``
  (gaps, the reader's assumptions, what the terms could not show), ``method``.

``curves``: ``{"gyro": (tau_s (M,), adev (M, 3)), "accel": ...}`` for the plot.

**Rest biases.** The gyro's mean rate is its bias plus the Earth's rotation seen by each
axis (7.29e-5 rad/s in all, 15 deg/h: not negligible for a tactical-grade gyro; it
cannot be told apart without knowing the heading and latitude). From one static pose
only the accelerometer's bias along gravity is observable: the mean specific force is
``g u + b``, ``u`` the unknown up direction, and any ``b`` across ``u`` is a tilt
(``|mean| - g`` is the bias along ``u``; g is standard gravity unless given). A
multi-pose (six-face) calibration separates the components.

**Refused when not static** (:func:`check_static`): the standard deviation of the
1-s means of any gyro axis above ``MAX_GYRO_STD_RAD_S`` or of any accelerometer axis
above ``MAX_ACCEL_STD_M_S2``, or a mean rate above ``MAX_GYRO_MEAN_RAD_S`` (a steady
turn). One-second means are used so that a noisy sensor at a
high rate is not mistaken for motion (its white noise falls by the square root of the
samples averaged); a turn, a tilt, a hand-held device all exceed the thresholds.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from gnomon.calibration.allan import (
    BIAS_INSTABILITY_FACTOR,
    MIN_CLUSTERS,
    allan_deviation,
    read_noise_terms,
)
from gnomon.errors import InputError
from gnomon.recording import Recording

__all__ = ["imu_noise", "check_static", "save_imu_noise", "load_imu_noise",
           "MAX_GYRO_STD_RAD_S", "MAX_GYRO_MEAN_RAD_S", "MAX_ACCEL_STD_M_S2",
           "STATIC_WINDOW_S", "G0_M_S2", "MIN_DURATION_S", "FORMAT", "EARTH_RATE_RAD_S"]

#: the 1-s means of a gyro axis of a device at rest vary less than this (std, rad/s;
#: 2.9 deg/s)
MAX_GYRO_STD_RAD_S = 0.05
#: a static gyro's mean rate (its bias and the Earth's rotation) is below this (rad/s;
#: 11.5 deg/s): a larger steady rate is a turn
MAX_GYRO_MEAN_RAD_S = 0.2
#: the 1-s means of an accelerometer axis at rest vary less than this (std, m/s²; a tilt
#: of 1.2 deg moves a horizontal axis by 0.2 m/s²)
MAX_ACCEL_STD_M_S2 = 0.2
#: the averaging window of the check of rest (s)
STATIC_WINDOW_S = 1.0
#: shorter logs are refused: the Allan deviation needs ``MIN_CLUSTERS`` clusters of a few
#: cluster times (s)
MIN_DURATION_S = 10.0
#: standard gravity (m/s²), the default g of the bias along gravity
G0_M_S2 = 9.80665
#: the Earth's rotation rate (rad/s): part of a static gyro's mean
EARTH_RATE_RAD_S = 7.2921150e-5
#: the ``format`` of the saved report (``gnomon calibrate imu --out``)
FORMAT = "gnomon-imu-noise"
#: time steps longer than this many nominal steps count as gaps
GAP_FACTOR = 1.5

_AXES = ("x", "y", "z")
#: (sensor, unit, JSON keys of N, B, K)
_KEYS = {
    "gyro": ("rad/s", "noise_density_rad_s_sqrt_hz", "bias_instability_rad_s",
             "rate_random_walk_rad_s2_sqrt_hz"),
    "accel": ("m/s^2", "noise_density_m_s2_sqrt_hz", "bias_instability_m_s2",
              "random_walk_m_s3_sqrt_hz"),
}


def _block_means(t: np.ndarray, y: np.ndarray, window_s: float) -> np.ndarray:
    """Means (K, 3) of ``y`` (N, 3) over consecutive windows of ``window_s`` of ``t``."""
    k = np.floor((t - t[0]) / window_s).astype(np.int64)
    _, idx, counts = np.unique(k, return_inverse=True, return_counts=True)
    sums = np.zeros((counts.size, y.shape[1]))
    np.add.at(sums, idx, y)
    return sums / counts[:, None]


def check_static(t, y, sensor: str, limit: float, unit: str,
                 window_s: float = STATIC_WINDOW_S) -> list[float]:
    """The std (3,) of the ``window_s`` means of each axis of ``y`` (N, 3; ``unit``) at
    the times ``t`` (N,) s; raises ``InputError`` naming the sensor, the axis, the value
    and the threshold ``limit`` when any exceeds it (the device moved)."""
    means = _block_means(np.asarray(t, float), np.asarray(y, float), window_s)
    std = means.std(axis=0) if len(means) > 1 else np.zeros(3)
    worst = int(np.argmax(std))
    if std[worst] > limit:
        raise InputError(
            f"not a static log: the {window_s:g}-s means of the {sensor}'s {_AXES[worst]} "
            f"axis vary by {std[worst]:.3g} {unit} (std) > {limit:g} {unit}; an Allan "
            f"analysis needs the device at rest (hours on a steady table, after warm-up)",
            field=sensor)
    return [float(v) for v in std]


def _rate_and_gaps(t: np.ndarray, sensor: str) -> tuple[float, list[str]]:
    """The nominal rate (Hz, from the median step) and a sentence on the gaps."""
    dt = np.diff(t)
    step = float(np.median(dt))
    gaps = dt > GAP_FACTOR * step
    notes = []
    if gaps.any():
        missing = float(dt[gaps].sum()) - int(gaps.sum()) * step
        notes.append(f"{sensor}: {int(gaps.sum())} time steps longer than {GAP_FACTOR}x the "
                     f"nominal {step:.4g} s (largest {float(dt.max()):.3g} s, {missing:.3g} s "
                     f"missing in all): the Allan deviation takes the samples as uniformly "
                     f"spaced")
    return 1.0 / step, notes


def _terms(y: np.ndarray, rate_hz: float, sensor: str):
    """Allan curves and the terms of the three axes of one sensor: ``(section, curves,
    notes)``; ``section`` holds the contract's three keys and the read-off details."""
    unit, kn, kb, kk = _KEYS[sensor]
    tau, adev = allan_deviation(y, rate_hz)
    terms = [read_noise_terms(tau, adev[:, k], len(y), rate_hz, unit) for k in range(3)]
    names = {"white": kn, "bias_instability": kb, "random_walk": kk}
    section = {kn: [a.white for a in terms], kb: [a.bias_instability for a in terms],
               kk: [a.random_walk for a in terms]}
    section["bias_instability_bound" + kb[len("bias_instability"):]] = [
        a.bias_instability_bound for a in terms]
    section["bias_instability_fit" + kb[len("bias_instability"):]] = [
        a.bias_instability_fit for a in terms]
    section["read_at_tau_s"] = {
        kn: [a.white_tau_s for a in terms], kb: [a.bias_instability_tau_s for a in terms],
        kk: [a.random_walk_tau_s for a in terms]}
    section["max_tau_s"] = [a.max_tau_s for a in terms]
    section["model"] = [list(a.model) for a in terms]
    why: dict[str, dict] = {}
    notes = []
    for axis, a in zip(_AXES, terms, strict=True):
        for term, reason in a.reasons.items():
            why.setdefault(names[term], {})[axis] = reason
    for key, per_axis in why.items():
        notes.append(f"{sensor} {key} not read on axis "
                     f"{', '.join(per_axis)}: {next(iter(per_axis.values()))}")
    section["why_none"] = why
    return section, (tau, adev), notes


def imu_noise(rec: Recording, gravity_m_s2: float | None = None) -> tuple[dict, dict]:
    """The noise report of a static log (module docstring): ``(report, curves)``.
    ``gravity_m_s2``: the local g for the accelerometer's bias along gravity (default
    standard gravity ``G0_M_S2``). Raises ``InputError`` when the log is shorter than
    ``MIN_DURATION_S`` or not static (:func:`check_static`)."""
    g = G0_M_S2 if gravity_m_s2 is None else float(gravity_m_s2)
    if not (g > 0 and math.isfinite(g)):
        raise InputError(f"must be > 0, got {gravity_m_s2!r}", field="gravity_m_s2")
    t = np.asarray(rec.t, float)
    duration = float(t[-1] - t[0])
    if duration < MIN_DURATION_S:
        raise InputError(f"the log lasts {duration:.3g} s: an Allan analysis needs at least "
                         f"{MIN_DURATION_S:g} s (hours for the bias instability and the "
                         f"random walk)", field="duration_s")
    static = {"window_s": STATIC_WINDOW_S,
              "gyro_std_rad_s": check_static(t, rec.gyro, "gyro", MAX_GYRO_STD_RAD_S, "rad/s"),
              "gyro_limit_rad_s": MAX_GYRO_STD_RAD_S}
    notes = [f"reader: {s}" for s in rec.meta.get("assumed", [])]
    if rec.accel is not None:
        ta = rec.times("accel")
        static["accel_std_m_s2"] = check_static(ta, rec.accel, "accel", MAX_ACCEL_STD_M_S2,
                                                "m/s^2")
        static["accel_limit_m_s2"] = MAX_ACCEL_STD_M_S2
    mean_rate = float(np.linalg.norm(rec.gyro.mean(axis=0)))
    if mean_rate > MAX_GYRO_MEAN_RAD_S:
        raise InputError(f"not a static log: the gyro's mean rate is {mean_rate:.3g} rad/s "
                         f"> {MAX_GYRO_MEAN_RAD_S:g} rad/s (a steady turn, not a rest "
                         f"bias)", field="gyro")

    rate_g, gap_notes = _rate_and_gaps(t, "gyro")
    notes += gap_notes
    gyro, curves_g, term_notes = _terms(rec.gyro, rate_g, "gyro")
    notes += term_notes
    d2r = math.pi / 180.0
    gyro["bias_rad_s"] = [float(v) for v in rec.gyro.mean(axis=0)]
    gyro["angle_random_walk_deg_sqrt_h"] = [
        None if v is None else v / d2r * 60.0 for v in gyro["noise_density_rad_s_sqrt_hz"]]
    gyro["bias_instability_deg_h"] = [
        None if v is None else v / d2r * 3600.0 for v in gyro["bias_instability_rad_s"]]
    gyro["bias_note"] = (f"the mean rate: the bias plus the Earth's rotation seen by each "
                         f"axis ({EARTH_RATE_RAD_S:.3g} rad/s in all, 15 deg/h)")
    gyro.update(rate_hz=rate_g, samples=int(len(t)))
    report = {"format": FORMAT, "version": 1, "duration_s": duration, "gyro": gyro,
              "accel": None, "static": static}
    curves = {"gyro": curves_g}

    if rec.accel is not None:
        rate_a, gap_notes = _rate_and_gaps(ta, "accel")
        notes += gap_notes
        accel, curves_a, term_notes = _terms(rec.accel, rate_a, "accel")
        notes += term_notes
        mean = rec.accel.mean(axis=0)
        norm = float(np.linalg.norm(mean))
        accel["mean_m_s2"] = [float(v) for v in mean]
        accel["gravity_m_s2"] = g
        accel["gravity_source"] = "given" if gravity_m_s2 is not None else "standard gravity"
        accel["up_b"] = [float(v) / norm for v in mean] if norm > 0 else None
        accel["bias_along_gravity_m_s2"] = norm - g
        accel["bias_note"] = (
            "from one static pose only the bias along gravity is observable: |mean| - g "
            "along up_b (a bias across gravity reads as a tilt); a multi-pose (six-face) "
            "calibration separates the three components")
        accel["velocity_random_walk_m_s_sqrt_h"] = [
            None if v is None else v * 60.0 for v in accel["noise_density_m_s2_sqrt_hz"]]
        accel.update(rate_hz=rate_a, samples=int(len(ta)))
        report["accel"] = accel
        curves["accel"] = curves_a
    else:
        notes.append("no accelerometer in the log: the gyro alone")
    report["notes"] = notes
    report["method"] = (
        f"overlapping Allan deviation (NIST SP 1065 eq. 12) per axis; N from the -1/2 "
        f"slope at 1 s, B = flat minimum / {BIAS_INSTABILITY_FACTOR:.3f}, K from the +1/2 "
        f"slope at 3 s of the fitted IEEE Std 952 model (annex C; AN5087); cluster times "
        f"with >= {MIN_CLUSTERS} clusters")
    return report, curves


def save_imu_noise(path: str | os.PathLike, report: dict) -> Path:
    """Write ``report`` (:func:`imu_noise`) as JSON (strict: NaN as null)."""
    p = Path(path)
    p.write_text(json.dumps(_strict(report), indent=2) + "\n")
    return p


def _strict(o):
    """NaN/inf -> None, tuples -> lists, numpy scalars -> floats (strict JSON)."""
    if isinstance(o, dict):
        return {k: _strict(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_strict(v) for v in o]
    if isinstance(o, np.generic):
        o = o.item()
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o


def load_imu_noise(path: str | os.PathLike) -> dict:
    """A noise report written by ``gnomon calibrate imu --out``: validated (its
    ``format``, a gyro section with three values per term)."""
    p = Path(path)
    try:
        noise = json.loads(p.read_text())
    except FileNotFoundError:
        raise InputError("no such file", field="--noise", file=str(p)) from None
    except json.JSONDecodeError as e:
        raise InputError(f"not JSON ({e.msg}, line {e.lineno})", field="--noise",
                         file=str(p)) from None
    if not isinstance(noise, dict) or noise.get("format") != FORMAT:
        raise InputError(f"not a noise file of gnomon calibrate imu --out (format "
                         f"{noise.get('format') if isinstance(noise, dict) else None!r}, "
                         f"expected {FORMAT!r})", field="format", file=str(p))
    for sensor, (_, *keys) in _KEYS.items():
        sec = noise.get(sensor)
        if sec is None and sensor == "accel":
            continue
        for key in keys:
            v = (sec or {}).get(key)
            if not (isinstance(v, list) and len(v) == 3
                    and all(x is None or isinstance(x, int | float) for x in v)):
                raise InputError(f"expected a list of 3 numbers or nulls, got {v!r}",
                                 field=f"{sensor}.{key}", file=str(p))
    return noise
