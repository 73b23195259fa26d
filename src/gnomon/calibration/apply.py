"""Calibration of a ``Recording``'s magnetometer and its application.

:func:`calibrate_mag` runs :func:`gnomon.calibration.fit.fit_mag` on a recording's
magnetometer (any ``mag_unit``, converted to µT) with the gyro's offset
(:func:`gnomon.calibration.gyro.gyro_offset_uT`) as its hint, and that offset alone as
the result when the ellipsoid is refused (model ``"gyro-offset"``); the field magnitude
from a number or a place and date (IGRF).

Applying it: :func:`apply_mag_calibration` returns a new ``Recording``
(``dataclasses.replace``) whose ``mag`` is ``h = S (m - o)`` in µT (``mag_unit="uT"``),
sensor axes, on the magnetometer's own time stamps; nothing else changes.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from gnomon.calibration.coverage import sphere_coverage
from gnomon.calibration.field import igrf_field_uT
from gnomon.calibration.fit import fit_mag
from gnomon.calibration.gyro import gyro_offset_uT
from gnomon.calibration.result import MIN_COVERAGE, MagCalibration
from gnomon.calibration.samples import mag_uT_of
from gnomon.errors import InputError
from gnomon.recording import Recording

__all__ = ["calibrate_mag", "apply_mag_calibration"]


def calibrate_mag(rec: Recording, *, field_uT: float | None = None,
                  location: dict | None = None, gyro: bool = True, gyro_fallback: bool = True,
                  **options) -> MagCalibration:
    """:func:`fit_mag` on a recording's magnetometer (any ``mag_unit``, converted to µT).

    ``location``: ``{"latitude_deg", "longitude_deg", "altitude_m", "date"}`` sets
    ``field_uT`` to the IGRF magnitude there (when ``field_uT`` is not given). ``gyro``:
    give :func:`gyro_offset_uT` to the fit as ``offset_hint_uT`` (a start and a gate).
    ``gyro_fallback``: when the ellipsoid is refused but the gyro determines the offset,
    return the gyro's offset alone (model ``"gyro-offset"``: ``S = I·B/r``, r the median
    distance of the samples from it; the ellipsoid's refusal is kept in ``tried``); its
    ``ok`` needs the coverage of the offset model (``require_ok`` applies to the result)."""
    src = None
    if field_uT is None and location is not None:
        missing = [k for k in ("latitude_deg", "longitude_deg", "date") if k not in location]
        if missing:
            raise InputError(f"missing {', '.join(missing)}", field="location")
        field_uT = igrf_field_uT(location["latitude_deg"], location["longitude_deg"],
                                 location.get("altitude_m", 0.0), location["date"])
        src = (f"IGRF-14 at {location['latitude_deg']:.4f}, {location['longitude_deg']:.4f}"
               f" deg on {location['date']}")
    options.setdefault("source", rec.source)
    src = options.pop("field_source", None) or src
    if gyro and options.get("offset_hint_uT") is None:
        options["offset_hint_uT"] = gyro_offset_uT(rec)
    require = options.pop("require_ok", False)
    try:
        cal = fit_mag(mag_uT_of(rec), field_uT=field_uT, field_source=src, **options)
        if not cal.ok and gyro_fallback and options.get("offset_hint_uT") is not None:
            cal = _gyro_calibration(mag_uT_of(rec), cal)
        if require and not cal.ok:
            raise InputError(f"magnetometer calibration refused: {cal.reason}", field="mag")
        return cal
    except InputError as err:
        if rec.source and err.file is None:
            raise err.with_file(rec.source) from None
        raise


def _gyro_calibration(m: np.ndarray, refused: MagCalibration) -> MagCalibration:
    """The offset of ``refused.offset_hint_uT`` alone, reported like a fit."""
    o = np.asarray(refused.offset_hint_uT, dtype=float)
    r = float(np.median(np.linalg.norm(m - o, axis=1)))
    given = refused.field_source != "data"
    B = refused.field_uT if given else r
    S = np.eye(3) * (B / r)
    h = (m - o) @ S.T
    cov = sphere_coverage(h)
    ok = cov >= MIN_COVERAGE["offset"]
    tried = (*({**t, "used": False} for t in refused.tried),
             {"model": "gyro-offset", "coverage": cov, "condition": math.nan,
              "anisotropy": 1.0, "used": True,
              "why_not": "" if ok else f"coverage {cov:.2f} below {MIN_COVERAGE['offset']}"})
    return dataclasses.replace(
        refused, offset_uT=o, soft_iron=S, field_uT=B, ok=ok, model="gyro-offset",
        reason="" if ok else f"ellipsoid refused ({refused.reason}) and gyro offset "
                             f"coverage {cov:.2f} below {MIN_COVERAGE['offset']}",
        residual_uT=float(np.sqrt(np.mean((np.linalg.norm(h, axis=1) - B) ** 2))),
        coverage=cov, condition=math.nan, offset_std_uT=np.full(3, np.nan),
        soft_iron_std=math.nan, tried=tried)


def apply_mag_calibration(rec: Recording, cal: MagCalibration, *,
                          allow_refused: bool = False) -> Recording:
    """A new ``Recording`` whose ``mag`` is ``cal.correct(mag)`` in µT (``mag_unit="uT"``),
    same time stamps, everything else unchanged; ``meta["mag_calibration"]`` records the
    calibration and ``meta["assumed"]`` says so. A calibration that is not ``ok`` raises
    ``InputError`` (with its reason) unless ``allow_refused``."""
    if not cal.ok and not allow_refused:
        raise InputError(f"the magnetometer calibration was refused: {cal.reason}",
                         file=cal.source or None, field="mag_calibration")
    corrected = cal.correct(mag_uT_of(rec))
    meta = dict(rec.meta)
    meta["mag_calibration"] = cal.to_dict()
    meta["assumed"] = list(meta.get("assumed", [])) + [
        f"Magnetometer corrected by a {cal.model} calibration (offset "
        f"{np.round(cal.offset_uT, 2).tolist()} uT, coverage {cal.coverage:.2f}, residual "
        f"{cal.residual_uT:.2f} uT): h = S (m - o), in uT."]
    return dataclasses.replace(rec, mag=corrected, mag_unit="uT", meta=meta)
