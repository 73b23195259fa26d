"""The field's magnitude B a calibration scales to: the local IGRF-14 value at a place
(WGS-84 geodetic latitude and longitude in degrees, height in m) and a date, in µT."""

from __future__ import annotations

import math

import numpy as np

from gnomon.errors import InputError

__all__ = ["igrf_field_uT"]


def igrf_field_uT(latitude_deg: float, longitude_deg: float, altitude_m: float = 0.0,
                  date: str = "2025-01-01") -> float:
    """Magnitude (µT) of the IGRF-14 main field (:mod:`gnomon.environment.magnetic`) at a
    geodetic place (WGS-84 latitude and longitude in degrees, height in m) and a date
    (``YYYY-MM-DD``, or anything ``gnomon.frames.parse_epoch`` takes)."""
    import datetime as dt

    from gnomon.environment.magnetic import GeomagneticField, _decimal_year
    from gnomon.frames import parse_epoch

    lat, lon, h = (math.radians(float(latitude_deg)), math.radians(float(longitude_deg)),
                   float(altitude_m))
    if not (abs(latitude_deg) <= 90 and math.isfinite(lon) and math.isfinite(h)):
        raise InputError(f"expected latitude in [-90, 90] deg, finite longitude and height, "
                         f"got {latitude_deg}, {longitude_deg}, {altitude_m}",
                         field="location")
    a, f = 6378137.0, 1 / 298.257223563  # WGS-84
    e2 = f * (2 - f)
    n = a / math.sqrt(1 - e2 * math.sin(lat) ** 2)
    r_e = np.array([(n + h) * math.cos(lat) * math.cos(lon),
                    (n + h) * math.cos(lat) * math.sin(lon),
                    (n * (1 - e2) + h) * math.sin(lat)])
    epoch = parse_epoch(str(date))
    noon = dt.datetime(epoch.year, epoch.month, epoch.day, 12)
    b = GeomagneticField().b_e_nT(r_e, _decimal_year(noon))
    return float(np.linalg.norm(b) / 1000.0)
