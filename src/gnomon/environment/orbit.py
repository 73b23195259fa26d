"""Orbits: a Keplerian propagator with J2 secular drift, and SGP4 from a TLE.

Both give position ``r_i`` (m) and velocity ``v_i`` (m/s) in the inertial frame
``i`` (see :mod:`gnomon.frames`) at times ``t_s`` seconds after the orbit's UTC
epoch, vectorised over ``t_s``.

The J2 propagator keeps the osculating-looking elements ``a, e, i`` fixed and
lets the node, the argument of perigee and the mean anomaly drift at the first-order
secular rates (Vallado, *Fundamentals of Astrodynamics*, 4th ed., eqs. 9-41):

    dΩ/dt = -3/2 n J2 (R/p)^2 cos i
    dω/dt =  3/4 n J2 (R/p)^2 (5 cos^2 i - 1)
    dM/dt =  n [1 + 3/4 J2 (R/p)^2 sqrt(1-e^2) (3 cos^2 i - 1)]

This is the model used by mission analysis for sun-synchronous design; the
short-periodic J2 terms (km level) are left out on purpose: the attitude
problem needs a smooth, exactly known orbital frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gnomon.errors import InputError
from gnomon.frames import julian_date, parse_epoch

__all__ = [
    "MU_EARTH",
    "R_EARTH",
    "J2_EARTH",
    "KeplerOrbit",
    "TLEOrbit",
    "sun_synchronous_inclination",
    "raan_from_ltan",
    "mean_motion",
    "nodal_rate",
]

MU_EARTH = 3.986004418e14     # m^3/s^2 (WGS-84 / EGM-96)
R_EARTH = 6378137.0           # m, equatorial radius (WGS-84)
J2_EARTH = 1.08262668e-3      # (EGM-96)
#: Mean rate of the Sun in right ascension (one revolution per tropical year), rad/s.
SUN_MEAN_RATE = 2.0 * np.pi / (365.2421897 * 86400.0)
MIN_ALTITUDE_M = 150e3


def mean_motion(a_m: float) -> float:
    """Keplerian mean motion ``sqrt(mu/a^3)``, rad/s."""
    return float(np.sqrt(MU_EARTH / a_m**3))


def nodal_rate(a_m: float, e: float, inc_rad: float) -> float:
    """J2 secular node rate ``dΩ/dt = -3/2 n J2 (R/p)^2 cos i``, rad/s."""
    p = a_m * (1.0 - e * e)
    return float(-1.5 * mean_motion(a_m) * J2_EARTH * (R_EARTH / p) ** 2 * np.cos(inc_rad))


def sun_synchronous_inclination(a_m: float, e: float = 0.0) -> float:
    """Inclination (rad) at which the J2 node rate equals the Sun's mean rate."""
    p = a_m * (1.0 - e * e)
    c = -SUN_MEAN_RATE / (1.5 * mean_motion(a_m) * J2_EARTH * (R_EARTH / p) ** 2)
    if abs(c) > 1.0:
        raise InputError(f"no sun-synchronous inclination for a = {a_m / 1e3:.0f} km",
                         field="orbit.inclination_deg")
    return float(np.arccos(c))


def raan_from_ltan(epoch, ltan_h: float) -> float:
    """RAAN (rad, in ``i``) giving local time of the ascending node ``ltan_h`` hours at ``epoch``.

    Uses the apparent Sun's right ascension (:func:`gnomon.environment.sun.sun_direction_i`):
    ``Ω = α_sun + (LTAN - 12 h) * 15 deg/h``.
    """
    from gnomon.environment.sun import sun_direction_i

    s = sun_direction_i(epoch, 0.0)
    alpha = np.arctan2(s[1], s[0])
    return float(np.mod(alpha + (ltan_h - 12.0) * np.pi / 12.0, 2.0 * np.pi))


def _solve_kepler(M, e, tol=1e-13):
    E = np.array(M, dtype=float, copy=True)
    if e == 0.0:
        return E
    for _ in range(30):
        dE = (E - e * np.sin(E) - M) / (1.0 - e * np.cos(E))
        E -= dE
        if np.max(np.abs(dE)) < tol:
            break
    return E


@dataclass(frozen=True)
class KeplerOrbit:
    """Keplerian elements at ``epoch`` (UTC), propagated with J2 secular rates when ``j2``.

    ``a_m`` semi-major axis (m), ``e`` eccentricity, angles in rad: inclination
    ``inc``, right ascension of the ascending node ``raan``, argument of perigee
    ``argp``, mean anomaly ``m0`` at epoch.
    """

    a_m: float
    e: float
    inc: float
    raan: float
    argp: float
    m0: float
    epoch: object
    j2: bool = True

    def __post_init__(self):
        if not (0.0 <= self.e < 1.0):
            raise InputError(f"eccentricity must be in [0, 1), got {self.e}",
                             field="orbit.eccentricity")
        perigee_alt = self.a_m * (1.0 - self.e) - R_EARTH
        if perigee_alt < MIN_ALTITUDE_M:
            raise InputError(
                f"perigee altitude {perigee_alt / 1e3:.1f} km is inside the atmosphere "
                f"(minimum {MIN_ALTITUDE_M / 1e3:.0f} km)", field="orbit.altitude_km")
        object.__setattr__(self, "epoch", parse_epoch(self.epoch))

    @property
    def n(self) -> float:
        """Keplerian mean motion, rad/s."""
        return mean_motion(self.a_m)

    def rates(self) -> tuple[float, float, float]:
        """Secular rates ``(dΩ/dt, dω/dt, dM/dt)``, rad/s."""
        n = self.n
        if not self.j2:
            return 0.0, 0.0, n
        p = self.a_m * (1.0 - self.e**2)
        k = J2_EARTH * (R_EARTH / p) ** 2
        ci = np.cos(self.inc)
        draan = -1.5 * n * k * ci
        dargp = 0.75 * n * k * (5.0 * ci**2 - 1.0)
        dm = n * (1.0 + 0.75 * k * np.sqrt(1.0 - self.e**2) * (3.0 * ci**2 - 1.0))
        return float(draan), float(dargp), float(dm)

    @property
    def period_s(self) -> float:
        """Anomalistic period ``2 pi / (dM/dt)`` (J2-corrected when ``j2``), s."""
        return float(2.0 * np.pi / self.rates()[2])

    def propagate(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and velocity (m/s) in ``i`` at ``t_s`` s after epoch; shapes (..., 3)."""
        t = np.asarray(t_s, dtype=float)
        draan, dargp, dm = self.rates()
        raan = self.raan + draan * t
        argp = self.argp + dargp * t
        M = self.m0 + dm * t
        e = self.e
        E = _solve_kepler(np.mod(M, 2.0 * np.pi), e)
        cE, sE = np.cos(E), np.sin(E)
        sq = np.sqrt(1.0 - e * e)
        a = self.a_m
        # perifocal position / velocity (velocity uses the secular mean motion dm so that
        # the orbital frame rotates consistently with the propagated position)
        xp = a * (cE - e)
        yp = a * sq * sE
        rr = a * (1.0 - e * cE)
        Edot = dm / (1.0 - e * cE)
        vxp = -a * sE * Edot
        vyp = a * sq * cE * Edot
        # add the apsidal rotation rate to the in-plane velocity (dω/dt)
        vxp, vyp = vxp - dargp * yp, vyp + dargp * xp
        cO, sO = np.cos(raan), np.sin(raan)
        cw, sw = np.cos(argp), np.sin(argp)
        ci, si = np.cos(self.inc), np.sin(self.inc)
        # columns P and Q of the perifocal-to-inertial matrix
        P = np.stack([cO * cw - sO * sw * ci, sO * cw + cO * sw * ci, sw * si], -1)
        Q = np.stack([-cO * sw - sO * cw * ci, -sO * sw + cO * cw * ci, cw * si], -1)
        r = xp[..., None] * P + yp[..., None] * Q
        v = vxp[..., None] * P + vyp[..., None] * Q
        # node regression: v += dΩ/dt * (z x r)
        if draan != 0.0:
            v = v + draan * np.stack([-r[..., 1], r[..., 0], np.zeros_like(rr)], -1)
        return r, v


class TLEOrbit:
    """SGP4 propagation of a two-line element set (``sgp4`` package, WGS-72 constants).

    Output frame is TEME, used as ``i`` (differs from the MOD frame by nutation only).
    ``epoch`` defaults to the TLE epoch; ``t_s`` counts from ``epoch``.
    """

    def __init__(self, line1: str, line2: str, epoch=None):
        from sgp4.api import Satrec

        self.satrec = Satrec.twoline2rv(line1, line2)
        if self.satrec.error != 0:
            raise InputError(f"SGP4 could not read the TLE (error {self.satrec.error})",
                             field="orbit.tle")
        if epoch is None:
            from sgp4.conveniences import sat_epoch_datetime

            epoch = sat_epoch_datetime(self.satrec)
        self.epoch = parse_epoch(epoch)
        perigee_alt = self.satrec.altp * self.satrec.radiusearthkm * 1e3
        if perigee_alt < MIN_ALTITUDE_M:
            raise InputError(f"perigee altitude {perigee_alt / 1e3:.1f} km is inside the "
                             f"atmosphere (minimum {MIN_ALTITUDE_M / 1e3:.0f} km)",
                             field="orbit.tle")

    @property
    def period_s(self) -> float:
        """Period from the Kozai mean motion, s."""
        return float(2.0 * np.pi / (self.satrec.no_kozai / 60.0))

    def propagate(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and velocity (m/s) in TEME at ``t_s`` s after epoch; shapes (..., 3)."""
        t = np.asarray(t_s, dtype=float)
        jd, fr = julian_date(self.epoch, t.ravel())
        err, r, v = self.satrec.sgp4_array(jd, fr)
        if np.any(err != 0):
            k = int(np.flatnonzero(err)[0])
            raise InputError(f"SGP4 failed (error {int(err[k])}) at t = {t.ravel()[k]} s",
                             field="orbit.tle")
        return (r * 1e3).reshape(t.shape + (3,)), (v * 1e3).reshape(t.shape + (3,))
