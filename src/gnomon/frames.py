"""Reference frames of the spacecraft world: time scales, Earth rotation, the orbital frame.

Frames (``shared/spec/conventions.md``):

* ``i`` -- Earth-centred inertial. In the simulated world ``i`` is the **mean
  equator and equinox of the scenario epoch** (MOD at epoch): a fixed inertial
  frame over a run (precession over hours is ~1e-6 rad), in which the Earth
  rotates by the Greenwich mean sidereal angle. It differs from J2000/GCRF by
  the precession since 2000 (about 0.37 deg in 2026); :func:`precession_j2000_to_mod`
  gives that rotation. SGP4 positions (TEME) are used as ``i`` directly: TEME
  and MOD differ by nutation only (< 0.005 deg).
* ``e`` -- Earth-fixed (ECEF): ``r_e = R_ei @ r_i`` with ``R_ei = Rz(GMST)``
  (polar motion and nutation neglected, < 0.005 deg; UT1 taken equal to UTC,
  |UT1-UTC| < 0.9 s, i.e. < 0.004 deg).
* ``o`` -- orbital frame: ``z_o`` towards nadir (``-r/|r|``), ``y_o`` along the
  negative orbit normal (``-h/|h|``, ``h = r x v``), ``x_o = y_o x z_o``
  (along the velocity on a circular orbit). Its rate relative to ``i``,
  in ``o``, is ``[0, -n, 0]`` on a circular orbit of mean motion ``n``.

Epochs are UTC ``datetime`` objects (timezone-aware or naive-as-UTC) or ISO
strings; Julian dates are split as ``(jd, fraction)`` where precision matters.
"""

from __future__ import annotations

import datetime as _dt

import numpy as np

from gnomon.errors import InputError
from gnomon.rotation import quat_from_dcm

__all__ = [
    "parse_epoch",
    "julian_date",
    "gmst_rad",
    "dcm_ei",
    "orbital_frame_dcm",
    "quat_io",
    "w_io_o",
    "w_io_o_of_orbit",
    "precession_j2000_to_mod",
    "TT_MINUS_UTC_S",
]

#: TT - UTC in seconds (32.184 s + 37 leap seconds, valid since 2017).
TT_MINUS_UTC_S = 69.184

_J2000_JD = 2451545.0


def parse_epoch(epoch) -> _dt.datetime:
    """A UTC ``datetime`` (tz-aware) from a ``datetime`` or an ISO-8601 string ('...Z' allowed)."""
    if isinstance(epoch, _dt.datetime):
        d = epoch
    elif isinstance(epoch, _dt.date):
        d = _dt.datetime(epoch.year, epoch.month, epoch.day)
    elif isinstance(epoch, str):
        try:
            d = _dt.datetime.fromisoformat(epoch.strip().replace("Z", "+00:00"))
        except ValueError:
            raise InputError(f"not an ISO-8601 UTC time: {epoch!r}", field="epoch") from None
    else:
        raise InputError(f"expected an ISO-8601 UTC time, got {epoch!r}", field="epoch")
    if d.tzinfo is None:
        d = d.replace(tzinfo=_dt.UTC)
    return d.astimezone(_dt.UTC)


def julian_date(epoch, t_s=0.0) -> tuple[np.ndarray, np.ndarray]:
    """Julian date (UTC) of ``epoch + t_s`` as ``(jd_whole, fraction)``; ``t_s`` any shape, s."""
    d = parse_epoch(epoch)
    d0 = _dt.datetime(d.year, d.month, d.day, tzinfo=_dt.UTC)
    # JD at 0h UTC of that day (Fliegel & Van Flandern via ordinal: JD of 0001-01-01 0h = 1721425.5)
    jd0 = d0.toordinal() + 1721424.5
    sec = (d - d0).total_seconds() + np.asarray(t_s, dtype=float)
    return np.full(np.shape(sec), jd0), sec / 86400.0


def gmst_rad(jd_whole, fraction) -> np.ndarray:
    """Greenwich mean sidereal angle (IAU 1982, Vallado eq. 3-47), rad in [0, 2 pi); UT1 = UTC."""
    jd = np.asarray(jd_whole, float) + np.asarray(fraction, float)
    tu = (jd - _J2000_JD) / 36525.0
    sec = (67310.54841 + (876600.0 * 3600.0 + 8640184.812866) * tu
           + 0.093104 * tu**2 - 6.2e-6 * tu**3)
    # the big linear term is evaluated split to keep precision
    return np.mod(sec % 86400.0 / 240.0 * np.pi / 180.0, 2.0 * np.pi)


def dcm_ei(gmst) -> np.ndarray:
    """``R_ei`` (ECEF from inertial) for Greenwich sidereal angle(s) ``gmst`` (rad), (..., 3, 3)."""
    g = np.asarray(gmst, float)
    c, s = np.cos(g), np.sin(g)
    z, o = np.zeros_like(g), np.ones_like(g)
    return np.stack([np.stack([c, s, z], -1), np.stack([-s, c, z], -1),
                     np.stack([z, z, o], -1)], -2)


def orbital_frame_dcm(r_i, v_i) -> np.ndarray:
    """``R_io`` (inertial from orbital): columns are ``x_o, y_o, z_o`` in ``i``; shape (..., 3, 3).

    ``r_i``, ``v_i``: position (m) and velocity (m/s) in ``i``, shape (..., 3).
    """
    r = np.asarray(r_i, float)
    v = np.asarray(v_i, float)
    z = -r / np.linalg.norm(r, axis=-1, keepdims=True)
    h = np.cross(r, v)
    y = -h / np.linalg.norm(h, axis=-1, keepdims=True)
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=-1)


def quat_io(r_i, v_i) -> np.ndarray:
    """Quaternion ``q_io`` (inertial from orbital), [w, x, y, z], shape (..., 4)."""
    return quat_from_dcm(orbital_frame_dcm(r_i, v_i))


def w_io_o(r_i, v_i) -> np.ndarray:
    """Rate of ``o`` relative to ``i`` in ``o`` coordinates, rad/s, shape (..., 3).

    Keplerian motion: ``[0, -|r x v| / |r|^2, 0]`` (the orbit plane's own slow
    J2 precession, ~1e-6 of this, is neglected).
    """
    r = np.asarray(r_i, float)
    v = np.asarray(v_i, float)
    rate = np.linalg.norm(np.cross(r, v), axis=-1) / np.sum(r * r, axis=-1)
    out = np.zeros(r.shape)
    out[..., 1] = -rate
    return out


def w_io_o_of_orbit(propagate, t_s, h_s: float = 0.05) -> np.ndarray:
    """Exact rate of ``o`` relative to ``i`` in ``o`` (rad/s), (N, 3), for any orbit model.

    ``propagate(t) -> (r_i, v_i)``. Central difference of ``q_io`` over ``±h_s``
    (error ~ (h ω)² ω, far below 1e-12 rad/s): includes the small out-of-plane rate
    (node regression, perturbations) that the Keplerian :func:`w_io_o` leaves out.
    """
    from gnomon.rotation import quat_conj, quat_mul, rotvec_from_quat

    t = np.asarray(t_s, float)
    qm = quat_io(*propagate(t - h_s))
    qp = quat_io(*propagate(t + h_s))
    return rotvec_from_quat(quat_mul(quat_conj(qm), qp)) / (2.0 * h_s)


def precession_j2000_to_mod(jd_tt) -> np.ndarray:
    """IAU 1976 precession matrix (Lieske): ``r_mod = P @ r_j2000`` at TT Julian date(s) ``jd_tt``.

    Shape ``(..., 3, 3)`` for ``jd_tt`` of shape ``(...)``.
    """
    t = (np.asarray(jd_tt, float) - _J2000_JD) / 36525.0
    asec = np.pi / 180.0 / 3600.0
    zeta = (2306.2181 * t + 0.30188 * t**2 + 0.017998 * t**3) * asec
    z = (2306.2181 * t + 1.09468 * t**2 + 0.018203 * t**3) * asec
    theta = (2004.3109 * t - 0.42665 * t**2 - 0.041833 * t**3) * asec

    def rz(a):
        c, s = np.cos(a), np.sin(a)
        zero, one = np.zeros_like(a), np.ones_like(a)
        return np.stack([np.stack([c, s, zero], -1), np.stack([-s, c, zero], -1),
                         np.stack([zero, zero, one], -1)], -2)

    def ry(a):
        c, s = np.cos(a), np.sin(a)
        zero, one = np.zeros_like(a), np.ones_like(a)
        return np.stack([np.stack([c, zero, -s], -1), np.stack([zero, one, zero], -1),
                         np.stack([s, zero, c], -1)], -2)

    return rz(-z) @ ry(theta) @ rz(-zeta)
