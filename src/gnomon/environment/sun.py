"""Sun position (Astronomical Almanac low-precision formula) and Earth's shadow (conical model).

Sun direction
-------------
*The Astronomical Almanac* (section C, "Low-precision formulas for the Sun"),
valid 1950-2050 with about 0.01 deg accuracy: with ``n`` days from J2000 (TT),

    L = 280.460 + 0.9856474 n          (mean longitude, deg)
    g = 357.528 + 0.9856003 n          (mean anomaly, deg)
    λ = L + 1.915 sin g + 0.020 sin 2g (ecliptic longitude)
    ε = 23.439 - 0.0000004 n           (obliquity)
    R = 1.00014 - 0.01671 cos g - 0.00014 cos 2g   (AU)

λ and ε refer to the **equator and equinox of date**, so the direction is
returned in the mean-of-date frame, which is gnomon's world frame ``i`` (see
:mod:`gnomon.frames`). :func:`sun_direction_j2000` applies the IAU 1976
precession for users who need J2000 (the two differ by ~0.37 deg in 2026).

Shadow
------
Conical umbra/penumbra model (Montenbruck & Gill, *Satellite Orbits*, 3.4.2):
the apparent disks of the Sun (radius ``a``) and the Earth (radius ``b``) seen
from the satellite, separated by ``c``; the illumination fraction is one minus
the overlapped fraction of the solar disk (limb darkening ignored).
"""

from __future__ import annotations

import numpy as np

from gnomon.frames import TT_MINUS_UTC_S, julian_date, precession_j2000_to_mod

__all__ = ["AU_M", "R_SUN_M", "sun_position_i", "sun_direction_i", "sun_direction_j2000",
           "illumination_fraction"]

AU_M = 149597870700.0
R_SUN_M = 6.957e8
R_EARTH_SHADOW_M = 6378137.0


def _almanac(n_days):
    d2r = np.pi / 180.0
    L = (280.460 + 0.9856474 * n_days) * d2r
    g = (357.528 + 0.9856003 * n_days) * d2r
    lam = L + (1.915 * np.sin(g) + 0.020 * np.sin(2 * g)) * d2r
    eps = (23.439 - 0.0000004 * n_days) * d2r
    R = 1.00014 - 0.01671 * np.cos(g) - 0.00014 * np.cos(2 * g)
    u = np.stack([np.cos(lam), np.cos(eps) * np.sin(lam), np.sin(eps) * np.sin(lam)], -1)
    return u, R * AU_M


def _n_days_tt(epoch, t_s):
    jd, fr = julian_date(epoch, t_s)
    return (jd - 2451545.0) + fr + TT_MINUS_UTC_S / 86400.0


def sun_position_i(epoch, t_s) -> np.ndarray:
    """Earth-to-Sun vector (m) in ``i`` (mean equator and equinox of date), shape (..., 3)."""
    u, R = _almanac(_n_days_tt(epoch, t_s))
    return u * R[..., None]


def sun_direction_i(epoch, t_s) -> np.ndarray:
    """Unit Earth-to-Sun direction in ``i`` (mean-of-date) at ``t_s`` s after ``epoch``."""
    return _almanac(_n_days_tt(epoch, t_s))[0]


def sun_direction_j2000(epoch, t_s) -> np.ndarray:
    """Unit Earth-to-Sun direction in J2000 (mean equator and equinox of J2000.0)."""
    n = _n_days_tt(epoch, t_s)
    u = _almanac(n)[0]
    P = precession_j2000_to_mod(2451545.0 + n)
    return np.einsum("...ji,...j->...i", P, u)          # P^T @ u


def illumination_fraction(r_sat_m, r_sun_m, r_earth_m: float = R_EARTH_SHADOW_M) -> np.ndarray:
    """Fraction of the solar disk visible from the satellite (1 sunlit, 0 umbra), shape (...).

    ``r_sat_m``: satellite position, ``r_sun_m``: Sun position, both from Earth's centre
    in the same frame (m), shape (..., 3).
    """
    rs = np.asarray(r_sat_m, float)
    d_sun = np.asarray(r_sun_m, float) - rs
    d_earth = -rs
    ls = np.linalg.norm(d_sun, axis=-1)
    le = np.linalg.norm(d_earth, axis=-1)
    a = np.arcsin(np.clip(R_SUN_M / ls, -1, 1))        # apparent Sun radius
    b = np.arcsin(np.clip(r_earth_m / le, -1, 1))      # apparent Earth radius
    cosc = np.sum(d_sun * d_earth, axis=-1) / (ls * le)
    c = np.arccos(np.clip(cosc, -1.0, 1.0))            # separation of the centres
    frac = np.ones(np.broadcast(a, b, c).shape)
    full = c <= b - a                                   # Sun disk fully behind Earth: umbra
    frac[full] = 0.0
    part = (c < a + b) & (c > np.abs(a - b))
    if np.any(part):
        aa, bb, cc = (np.broadcast_to(x, frac.shape)[part] for x in (a, b, c))
        x = (cc**2 + aa**2 - bb**2) / (2 * cc)
        y = np.sqrt(np.maximum(aa**2 - x**2, 0.0))
        area = aa**2 * np.arccos(np.clip(x / aa, -1, 1)) + bb**2 * np.arccos(
            np.clip((cc - x) / bb, -1, 1)) - cc * y
        frac[part] = 1.0 - area / (np.pi * aa**2)
    annular = c <= a - b                                # Earth inside the Sun disk (not in LEO)
    if np.any(annular):
        frac[annular] = 1.0 - (np.broadcast_to(b, frac.shape)[annular] ** 2
                               / np.broadcast_to(a, frac.shape)[annular] ** 2)
    return frac
