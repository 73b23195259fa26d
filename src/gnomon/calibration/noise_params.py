"""A filter's noise parameters from an IMU noise report (``gnomon estimate --noise
noise.json``, the report of ``gnomon calibrate imu --out``).

:func:`noise_params` maps the Allan terms (gyro white noise N in rad/s/√Hz and rate
random walk K in rad/s²/√Hz, accelerometer white noise N in m/s²/√Hz) onto the
parameters a filter has, by parameter name, so a filter added later with the same
parameter names is served too. Each filter takes one value for its three axes: the RMS
of the axes that have the term (the same variance in total).

================================  ===================  ======================================
parameter (filters)               from                 conversion
================================  ===================  ======================================
``gyro_noise`` (eskf-r3, eskf-r6,  gyro N               none: a continuous density (the filter's
eskf-offline)                                          process noise is ¼ N² dt)
``arw_rad_rt_s`` (mekf,            gyro N               none (rad/√s = rad/s/√Hz; process
mekf-delayed, mekf-spacecraft)                         noise N² dt)
``bias_rw`` (eskf-*)               gyro K               none (rad/s/√s = rad/s²/√Hz)
``bias_rw_rad_s_rt_s`` (mekf-*)    gyro K               none
``bias_forgetting_s`` (robust-     gyro K               (0.1 deg/s)² / K²: the time in which
ahrs, robust-ahrs-offline)                             the bias variance grows by (0.1 deg/s)²
``accel_noise`` (eskf-*)           accelerometer N      per-sample std N √f_s (f_s the log's
                                                       accelerometer rate), used only when it
                                                       exceeds the filter's default: the
                                                       parameter also covers linear
                                                       acceleration, which a static log
                                                       does not show
================================  ===================  ======================================

The Allan K of a static log is a lower bound of a gyro's bias drift in use (temperature
changes add to it); filters with gains rather than noise parameters (mahony, qcf,
tilt-cf, ecf-spacecraft) or without a gyro (ekf-spacecraft) take nothing, and say so.
"""

from __future__ import annotations

import dataclasses
import math

__all__ = ["noise_params", "NOISE_PARAMETERS"]

_D2R = math.pi / 180.0

#: filter parameter -> (sensor, report key, what it is)
NOISE_PARAMETERS = {
    "gyro_noise": ("gyro", "noise_density_rad_s_sqrt_hz", "the gyro's white-noise density N"),
    "arw_rad_rt_s": ("gyro", "noise_density_rad_s_sqrt_hz",
                     "the gyro's angle random walk N"),
    "bias_rw": ("gyro", "rate_random_walk_rad_s2_sqrt_hz", "the gyro's rate random walk K"),
    "bias_rw_rad_s_rt_s": ("gyro", "rate_random_walk_rad_s2_sqrt_hz",
                           "the gyro's rate random walk K"),
    "bias_forgetting_s": ("gyro", "rate_random_walk_rad_s2_sqrt_hz",
                          "the gyro's rate random walk K"),
    "accel_noise": ("accel", "noise_density_m_s2_sqrt_hz",
                    "the accelerometer's white-noise density N"),
}


def _rms(values) -> tuple[float | None, list[str]]:
    """RMS of the non-null values and the axes they are of."""
    have = [(a, float(v)) for a, v in zip("xyz", values, strict=True) if v is not None]
    if not have:
        return None, []
    return math.sqrt(sum(v * v for _, v in have) / len(have)), [a for a, _ in have]


def noise_params(noise: dict, filter_name: str, rate_hz: float | None
                 ) -> tuple[dict, list[str]]:
    """``(params, notes)``: the parameters of filter ``filter_name`` (registry name) that
    the noise report ``noise`` (:func:`gnomon.calibration.imu_noise.load_imu_noise`)
    determines, by name to value in the filter's units, and one sentence per parameter
    saying which term it came from (or why it was not set). ``rate_hz``: the
    accelerometer's sample rate (Hz) of the log the filter will run on (the per-sample
    noise of ``accel_noise``; None: not set). A filter with no noise parameter returns
    ``({}, [the sentence saying so])``."""
    from gnomon.estimators import registry

    cls = registry.get(filter_name)
    fields = {f.name: f for f in dataclasses.fields(cls.Params)}
    params: dict[str, float] = {}
    notes: list[str] = []
    for name, (sensor, key, what) in NOISE_PARAMETERS.items():
        if name not in fields:
            continue
        unit = fields[name].metadata.get("unit", "")
        value, axes = _rms(((noise.get(sensor) or {}).get(key)) or [None] * 3)
        if value is None:
            why = ((noise.get(sensor) or {}).get("why_none", {}).get(key, {}) or {})
            reason = next(iter(why.values()), f"the noise file has no {sensor} {key}")
            notes.append(f"{name} not set ({what} is not in the noise file: {reason})")
            continue
        of = f"RMS of axes {', '.join(axes)}" if len(axes) > 1 else f"axis {axes[0]}"
        if name == "bias_forgetting_s":
            if value <= 0:
                notes.append(f"{name} not set ({what} is 0)")
                continue
            params[name] = (0.1 * _D2R) ** 2 / value**2
            notes.append(f"{name} = {params[name]:.4g} s from {what} = {value:.3g} rad/s^2/"
                         f"sqrt(Hz) ({of}): the time in which its bias variance grows by "
                         f"(0.1 deg/s)^2, (0.1 deg/s)^2 / K^2; a static log's K is a lower "
                         f"bound of the drift in use (temperature adds to it)")
        elif name == "accel_noise":
            if rate_hz is None or not rate_hz > 0:
                notes.append(f"{name} not set (no accelerometer rate to make the per-sample "
                             f"noise of {what})")
                continue
            sigma = value * math.sqrt(rate_hz)
            default = fields[name].default
            if sigma > default:
                params[name] = sigma
                notes.append(f"{name} = {sigma:.4g} {unit} from {what} = {value:.3g} "
                             f"m/s^2/sqrt(Hz) ({of}): the per-sample std N sqrt(f_s) at "
                             f"f_s = {rate_hz:.4g} Hz")
            else:
                notes.append(f"{name} kept at its default {default:g} {unit}: the "
                             f"sensor's own per-sample noise, {what} = {value:.3g} "
                             f"m/s^2/sqrt(Hz) times sqrt({rate_hz:.4g} Hz) = {sigma:.3g} "
                             f"{unit}, is below it and the parameter also covers linear "
                             f"acceleration (--param {name}={sigma:.3g} to use the "
                             f"sensor's alone)")
        else:
            params[name] = value
            how = ("a continuous density as the filter takes it (process noise N^2 dt)"
                   if key.startswith("noise_density") else
                   "a continuous random-walk intensity as the filter takes it (the bias "
                   "variance grows by K^2 dt)")
            notes.append(f"{name} = {value:.4g} {unit} from {what} ({of}), {how}")
    if not any(n in fields for n in NOISE_PARAMETERS):
        takers = [n for n in registry.names()
                  if any(p in {f.name for f in dataclasses.fields(registry.get(n).Params)}
                         for p in NOISE_PARAMETERS)]
        notes.append(f"{filter_name} has no parameter an IMU noise report sets (a gyro "
                     f"noise density or bias random walk, an accelerometer noise; its "
                     f"tuning is {', '.join(list(fields)[:4])}"
                     f"{', ...' if len(fields) > 4 else ''}): the noise file sets nothing; "
                     f"filters that take it: {', '.join(takers)}")
    return params, notes
