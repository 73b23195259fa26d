"""Spacecraft environment against independent references: ppigrf, WMM2025 (pygeomag),
Skyfield (DE421), closed-form orbit mechanics, sgp4's own test vector."""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest

from gnomon.environment.magnetic import (
    field_e_nT,
    field_i_nT,
    field_model,
    igrf_coefficients,
)
from gnomon.environment.orbit import (
    J2_EARTH,
    MU_EARTH,
    R_EARTH,
    KeplerOrbit,
    TLEOrbit,
    nodal_rate,
    sun_synchronous_inclination,
)
from gnomon.environment.sun import (
    AU_M,
    illumination_fraction,
    sun_direction_i,
    sun_direction_j2000,
)
from gnomon.frames import (
    dcm_ei,
    gmst_rad,
    julian_date,
    orbital_frame_dcm,
    quat_io,
    w_io_o,
)
from gnomon.rotation import quat_conj, quat_mul, rotvec_from_quat

DEG = np.pi / 180.0
ARCSEC = DEG / 3600.0
WGS84_A = 6378137.0
WGS84_E2 = 6.69437999014e-3


def _angle_deg(a, b):
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, -1)))


def _geodetic_to_ecef(lat, lon, h):
    n = WGS84_A / np.sqrt(1 - WGS84_E2 * np.sin(lat) ** 2)
    return np.array([(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon),
                     (n * (1 - WGS84_E2) + h) * np.sin(lat)])


# ------------------------------------------------------------------ time and frames
def test_gmst_vallado_example_3_5():
    # Vallado, Fundamentals of Astrodynamics, example 3-5: 1992-08-20 12:14 UT1
    jd, fr = julian_date(dt.datetime(1992, 8, 20, 12, 14, 0))
    assert np.degrees(gmst_rad(jd, fr)) == pytest.approx(152.578787810, abs=1e-6)


def test_gmst_against_skyfield():
    import warnings

    import skyfield_data
    from skyfield.api import Loader

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ts = Loader(skyfield_data.get_skyfield_data_path()).timescale(builtin=True)
    epoch = dt.datetime(2026, 5, 3, 7, 11, 5, tzinfo=dt.UTC)
    t_s = np.linspace(0, 200 * 86400, 17)
    jd, fr = julian_date(epoch, t_s)
    t = ts.ut1_jd(jd + fr)                      # UT1 = UTC in gnomon's world
    diff = np.mod(gmst_rad(jd, fr) - t.gmst * 15 * DEG + np.pi, 2 * np.pi) - np.pi
    assert np.max(np.abs(diff)) < 0.01 * ARCSEC * 15


def test_orbital_frame_axes_and_rate():
    orb = KeplerOrbit(R_EARTH + 600e3, 0.0, 97.8 * DEG, 1.0, 0.0, 0.3, "2026-01-01T00:00:00Z",
                      j2=False)
    t = np.arange(0.0, 600.0, 10.0)
    r, v = orb.propagate(t)
    R = orbital_frame_dcm(r, v)
    np.testing.assert_allclose(R[..., :, 2], -r / np.linalg.norm(r, axis=1)[:, None],
                               atol=1e-15)
    h = np.cross(r, v)
    np.testing.assert_allclose(R[..., :, 1], -h / np.linalg.norm(h, axis=1)[:, None],
                               atol=1e-15)
    assert np.all(np.sum(R[..., :, 0] * v, axis=1) / np.linalg.norm(v, axis=1) > 1 - 1e-12)
    np.testing.assert_allclose(w_io_o(r, v), np.tile([0, -orb.n, 0], (len(t), 1)), atol=1e-15)
    # kinematics: q_io(t+dt) = q_io(t) ⊗ exp(w_io_o dt) (constant rate on a circular orbit)
    q = quat_io(r, v)
    dq = quat_mul(quat_conj(q[:-1]), q[1:])
    np.testing.assert_allclose(rotvec_from_quat(dq), w_io_o(r, v)[:-1] * 10.0, atol=1e-12)


# ------------------------------------------------------------------ orbit
def test_kepler_period_and_closure():
    a = R_EARTH + 700e3
    orb = KeplerOrbit(a, 0.01, 51.6 * DEG, 0.4, 1.0, 2.0, "2026-01-01T00:00:00Z", j2=False)
    period = 2 * np.pi * np.sqrt(a**3 / MU_EARTH)
    assert orb.period_s == pytest.approx(period, rel=1e-14)
    r, v = orb.propagate(np.array([0.0, period]))
    np.testing.assert_allclose(r[1], r[0], atol=1e-6)
    # vis-viva and the velocity being dr/dt
    t = np.array([100.0 - 1e-2, 100.0, 100.0 + 1e-2])
    r, v = orb.propagate(t)
    np.testing.assert_allclose((r[2] - r[0]) / 2e-2, v[1], rtol=1e-7)
    rn = np.linalg.norm(r[1])
    assert np.linalg.norm(v[1]) ** 2 == pytest.approx(MU_EARTH * (2 / rn - 1 / a), rel=1e-12)


def test_j2_nodal_rate_and_sun_synchronism():
    a = R_EARTH + 650e3
    inc = sun_synchronous_inclination(a)
    assert np.degrees(inc) == pytest.approx(97.99, abs=0.02)   # textbook SSO at 650 km
    orb = KeplerOrbit(a, 0.0, inc, 0.5, 0.0, 0.0, "2026-01-01T00:00:00Z", j2=True)
    draan, dargp, dm = orb.rates()
    period_u = 2 * np.pi / (dargp + dm)              # draconic period: back at the node
    t = np.array([0.0, np.round(10 * 86400.0 / period_u) * period_u])
    r, v = orb.propagate(t)
    assert abs(r[1, 2]) < 1e-3                       # at the ascending node again
    h = np.cross(r, v)
    node = np.arctan2(h[:, 0], -h[:, 1])       # RAAN from the orbit normal
    rate = (node[1] - node[0]) / t[1]
    closed = -1.5 * np.sqrt(MU_EARTH / a**3) * J2_EARTH * (R_EARTH / a) ** 2 * np.cos(inc)
    assert rate == pytest.approx(closed, rel=1e-9)
    assert rate == pytest.approx(nodal_rate(a, 0.0, inc), rel=1e-12)
    assert np.degrees(rate) * 86400 * 365.2422 == pytest.approx(360.0, rel=1e-6)


def test_sgp4_wrapper_reproduces_test_vector():
    # sgp4 / Vallado "Revisiting Spacetrack Report #3" test case 00005 (tcppver.out)
    line1 = "1 00005U 58002B   00179.78495062  .00000023  00000-0  28098-4 0  4753"
    line2 = "2 00005  34.2682 348.7242 1859667 331.7664  19.3264 10.82419157413667"
    orb = TLEOrbit(line1, line2)
    r, v = orb.propagate(np.array([0.0, 360 * 60.0]))
    np.testing.assert_allclose(r[0] / 1e3, [7022.46529266, -1400.08296755, 0.03995155],
                               atol=1e-3)
    np.testing.assert_allclose(v[0] / 1e3, [1.893841015, 6.405893759, 4.534807250], atol=1e-6)
    np.testing.assert_allclose(r[1] / 1e3, [-7154.03120202, -3783.17682504, -3536.19412294],
                               atol=1e-3)
    np.testing.assert_allclose(v[1] / 1e3, [4.741887409, -4.151817765, -2.093935425],
                               atol=1e-6)


# ------------------------------------------------------------------ geomagnetic field
@pytest.mark.parametrize("date, tol_nT", [(dt.datetime(2025, 1, 1), 0.01),
                                           (dt.datetime(2027, 1, 1), 0.5)])
def test_igrf_kernel_matches_ppigrf(date, tol_nT):
    # at an IGRF epoch both use the same coefficients; in between ppigrf interpolates
    # linearly in datetime, gnomon in decimal year (leap days: < 0.5 nT apart)
    from ppigrf import igrf_gc

    rng = np.random.default_rng(1)
    r = rng.uniform(6.6e6, 7.2e6, 40)
    th = rng.uniform(1.0, 179.0, 40)
    ph = rng.uniform(-180.0, 180.0, 40)
    br, bt, bp = (x[0] for x in igrf_gc(r / 1e3, th, ph, date))
    t, p = np.radians(th), np.radians(ph)
    ref = np.stack([br * np.sin(t) * np.cos(p) + bt * np.cos(t) * np.cos(p) - bp * np.sin(p),
                    br * np.sin(t) * np.sin(p) + bt * np.cos(t) * np.sin(p) + bp * np.cos(p),
                    br * np.cos(t) - bt * np.sin(t)], -1)
    xyz = r[:, None] * np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)
    ours = field_model("igrf").b_e_nT(xyz, float(date.year))
    assert np.max(np.linalg.norm(ours - ref, axis=1)) < tol_nT


def test_igrf_against_wmm2025_at_500_km():
    from pygeomag import GeoMag

    gm = GeoMag(coefficients_file="wmm/WMM_2025.COF")
    year = 2026.5
    model = field_model("igrf")
    for lat_deg, lon_deg in [(0, 0), (45, -120), (-60, 140), (80, 30), (-30, -60), (20, 100)]:
        lat, lon = lat_deg * DEG, lon_deg * DEG
        res = gm.calculate(glat=lat_deg, glon=lon_deg, alt=500.0, time=year)
        ned = np.array([res.x, res.y, res.z])
        b_e = model.b_e_nT(_geodetic_to_ecef(lat, lon, 500e3)[None], year)[0]
        north = np.array([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)])
        east = np.array([-np.sin(lon), np.cos(lon), 0.0])
        down = -np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
        ours = np.array([b_e @ north, b_e @ east, b_e @ down])
        assert _angle_deg(ours, ned) < 0.1, (lat_deg, lon_deg)
        assert abs(np.linalg.norm(ours) - np.linalg.norm(ned)) < 100.0, (lat_deg, lon_deg)


def test_dipole_is_degree_one_and_field_in_inertial_frame():
    g, h = igrf_coefficients(2026.0, 1)
    r_e = np.array([[7e6, 0.0, 0.0]])
    # dipole field on the equator in the direction x: B = (R/r)^3 * [2 g11, -h11, -g10]
    b = field_model("dipole").b_e_nT(r_e, 2026.0)[0]
    k = (6371.2e3 / 7e6) ** 3
    np.testing.assert_allclose(b, k * np.array([2 * g[1, 1], -h[1, 1], -g[1, 0]]), rtol=1e-12)
    # inertial-frame field = R_ie @ field at the rotated position
    epoch = "2026-06-01T03:00:00Z"
    t = np.array([0.0, 4000.0])
    r_i = np.array([[7e6, 1e6, 2e6], [-3e6, 5e6, 4e6]])
    jd, fr = julian_date(epoch, t)
    R = dcm_ei(gmst_rad(jd, fr))
    b_e = field_e_nT(field_model("igrf"), epoch, t, np.einsum("nij,nj->ni", R, r_i))
    np.testing.assert_allclose(field_i_nT(field_model("igrf"), epoch, t, r_i),
                               np.einsum("nji,nj->ni", R, b_e), rtol=1e-12)


@pytest.mark.parametrize("kind", ["scale", "tilt", "component", "gauss"])
def test_field_model_errors_have_their_level(kind):
    rng = np.random.default_rng(3)
    r = rng.standard_normal((400, 3))
    r *= 7e6 / np.linalg.norm(r, axis=1, keepdims=True)
    truth = field_model("igrf").b_e_nT(r, 2026.0)
    for level in (2.0, 10.0):
        bad = field_model("igrf", kind, level, np.random.default_rng(5)).b_e_nT(r, 2026.0)
        rel = np.linalg.norm(bad - truth, axis=1) / np.linalg.norm(truth, axis=1)
        if kind == "scale":
            np.testing.assert_allclose(np.linalg.norm(bad, axis=1) / np.linalg.norm(truth, axis=1),
                                       1 + level / 100, rtol=1e-12)
        elif kind == "tilt":
            # a fixed rotation by atan(L): the direction error is atan(L) sin(angle to axis)
            ang = _angle_deg(bad, truth)
            assert ang.max() <= np.degrees(np.arctan(level / 100)) + 1e-9
            assert ang.max() > 0.95 * np.degrees(np.arctan(level / 100))
            np.testing.assert_allclose(np.linalg.norm(bad, axis=1),
                                       np.linalg.norm(truth, axis=1), rtol=1e-12)
        else:   # random draws: the typical relative error is of the order of the level
            assert 0.1 * level / 100 < np.sqrt(np.mean(rel**2)) < 3 * level / 100


# ------------------------------------------------------------------ Sun and shadow
@pytest.fixture(scope="module")
def skyfield_sun():
    import warnings

    import skyfield_data
    from skyfield.api import Loader

    with warnings.catch_warnings():            # skyfield-data: expired Earth-orientation file
        warnings.simplefilter("ignore", RuntimeWarning)
        load = Loader(skyfield_data.get_skyfield_data_path())
        ts = load.timescale(builtin=True)
        eph = load("de421.bsp")
    epoch = dt.datetime(2026, 1, 1, 5, 0, 0, tzinfo=dt.UTC)
    t_s = np.arange(0, 366, 3) * 86400.0 + 3671.0
    t = ts.from_datetimes([epoch + dt.timedelta(seconds=float(x)) for x in t_s])
    gcrs = eph["earth"].at(t).observe(eph["sun"]).apparent().position.au   # (3, N)
    mod = np.einsum("ijn,jn->ni", t.P, gcrs)                              # mean of date
    return epoch, t_s, gcrs.T, mod


def test_sun_direction_against_skyfield_over_a_year(skyfield_sun):
    epoch, t_s, gcrs, mod = skyfield_sun
    assert np.max(_angle_deg(sun_direction_i(epoch, t_s), mod)) < 0.02
    assert np.max(_angle_deg(sun_direction_j2000(epoch, t_s), gcrs)) < 0.02
    # of-date and J2000 differ by the precession since 2000 (~0.37 deg in 2026)
    assert 0.3 < np.mean(_angle_deg(sun_direction_i(epoch, t_s), gcrs)) < 0.45


def test_eclipse_fraction_500_km_sun_in_orbit_plane():
    epoch = "2026-03-20T12:00:00Z"
    s = sun_direction_i(epoch, 0.0)
    p = np.cross(s, [0.0, 0.0, 1.0])
    p /= np.linalg.norm(p)
    r = R_EARTH + 500e3
    theta = np.linspace(0, 2 * np.pi, 200001)[:-1]
    r_sat = r * (np.cos(theta)[:, None] * s + np.sin(theta)[:, None] * p)
    frac = illumination_fraction(r_sat, s * AU_M)
    shadow = np.mean(1.0 - frac)
    analytic = np.arcsin(R_EARTH / r) / np.pi            # cylindrical shadow, beta = 0
    assert shadow == pytest.approx(analytic, rel=0.01)
    # penumbra: a short transition (tens of seconds), umbra in the middle
    assert frac.min() == 0.0 and frac.max() == 1.0
    n_pen = np.sum((frac > 0.0) & (frac < 1.0)) / len(theta) * 2 * np.pi * np.sqrt(r**3 / MU_EARTH)
    assert 5.0 < n_pen / 2 < 30.0
