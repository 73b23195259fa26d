"""Run a scenario: orbit -> environment (field, Sun, shadow) -> attitude dynamics -> sensors.

(A ``kind: imu`` scenario goes to ``simulate_imu`` instead: ``gnomon.simulation.ahrs``.)

The output :class:`gnomon.recording.Recording` (frames ``{"reference": "o", "body": "b"}``):

* ``gyro`` (N, 3) rad/s: measured ``w_ib_b``; ``mag`` (N, 3) nT in b; ``sun`` (N, 3)
  unit vectors in b with ``sun_valid``; ``accel`` when enabled.
* ``q_true`` (N, 4): ``q_ob`` (orbital from body), [w, x, y, z].
* ``extra`` (all (N, ...)): ``w_ob_b``, ``w_ib_b`` (truth, rad/s), ``w_io_o`` (rate of o
  relative to i, in o, rad/s), ``b_o_nT`` (true field in o), ``b_o_model_nT`` (field in
  o from the on-board model, with the scenario's field-model error), ``b_b_nT`` (true
  field in b), ``s_o``, ``s_b`` (true Sun unit vectors), ``eclipse`` (illumination
  fraction, 1 = sunlit), ``gyro_bias_rad_s`` (bias truth), ``q_io``, ``r_i_m``,
  ``v_i_m``, ``h_wheel_b_Nms``, ``hdot_wheel_b_Nm``, ``m_dipole_b_Am2``,
  ``torque_ctrl_b_Nm`` (magnetorquer torque), ``torque_dist_b_Nm``,
  ``inertia_kg_m2`` and ``inertia_model_kg_m2`` (N, 3, 3; the model one carries the
  scenario's inertia error), ``time_orbits``.
* With ``sensors.star_tracker.enabled``, also in ``extra``: ``st_q_ib`` (N, 4) the
  measured inertial attitude ``q̂_ib`` [w, x, y, z] (NaN rows where there is no
  measurement), ``st_valid`` (N,) bool, ``st_flags`` (N,) uint8 (why a due sample has
  none: ``gnomon.sensors.STAR_TRACKER_FLAGS``), ``st_boresight_b`` (N, 3) the unit
  boresight in b (:func:`gnomon.sensors.star_tracker_model`; the truth ``q_ib`` is
  ``q_io ⊗ q_true``). No Moon exclusion: the environment has no Moon ephemeris.

The truth (orbit, environment, attitude dynamics) does not depend on the seed: only
the sensors, the on-board field model's error and the inertia error draw random
numbers. It is computed once per process for each distinct orbit / environment /
spacecraft / controller / initial state and kept (:func:`truth_of`, the last
:data:`TRUTH_CACHE_SIZE`), so the runs of a campaign that varies only sensors, seeds
or model errors simulate their sensors alone; each recording gets its own copies.

Random draws: ``numpy.random.SeedSequence(seed).spawn(7)`` -> gyro, magnetometer,
sun sensor, accelerometer, field-model error, inertia error, star tracker (the first
six are the children ``spawn(6)`` gave before the star tracker existed); each sensor
has its own generator so changing one sensor's noise leaves the others' draws unchanged.
"""

from __future__ import annotations

import collections
import json
import types

import numpy as np

from gnomon.dynamics import integrate_attitude
from gnomon.environment.magnetic import field_i_nT, field_model
from gnomon.environment.orbit import (
    R_EARTH,
    KeplerOrbit,
    TLEOrbit,
    raan_from_ltan,
    sun_synchronous_inclination,
)
from gnomon.environment.sun import illumination_fraction, sun_position_i
from gnomon.frames import orbital_frame_dcm, parse_epoch, w_io_o_of_orbit
from gnomon.recording import Recording
from gnomon.rotation import quat_conj, quat_from_dcm, quat_from_euler, quat_mul, quat_rotate
from gnomon.sensors import (
    accelerometer_model,
    boresight_frame,
    gyro_model,
    magnetometer_model,
    star_tracker_model,
    sun_sensor_model,
)

__all__ = ["build_orbit", "simulate", "simulate_imu", "truth_of",
           "TRUTH_CACHE_SIZE"]

_D2R = np.pi / 180.0
_AS2R = _D2R / 3600.0


def build_orbit(cfg: dict):
    """The orbit object (``KeplerOrbit`` or ``TLEOrbit``) of a validated scenario config."""
    o = cfg["orbit"]
    epoch = parse_epoch(cfg["epoch"])
    if o["kind"] == "tle":
        return TLEOrbit(o["tle_line1"], o["tle_line2"], epoch=epoch)
    a = R_EARTH + o["altitude_km"] * 1e3
    e = o["eccentricity"]
    inc = (sun_synchronous_inclination(a, e) if o["inclination_deg"] == "sun_synchronous"
           else o["inclination_deg"] * _D2R)
    raan = o["raan_deg"] * _D2R if o["raan_deg"] is not None else raan_from_ltan(epoch,
                                                                                o["ltan_h"])
    argp = o["arg_perigee_deg"] * _D2R
    m0 = o["arg_latitude_deg"] * _D2R - argp
    return KeplerOrbit(a, e, inc, raan, argp, m0, epoch, j2=o["j2"])


def _inertia_model(J, pct, rng):
    if pct == 0.0:
        return J.copy()
    d = np.sqrt(np.maximum(1.0 + pct / 100.0 * rng.standard_normal(3), 0.05))
    return d[:, None] * J * d[None, :]


#: how many distinct truths :func:`truth_of` keeps per process
TRUTH_CACHE_SIZE = 4
_TRUTHS: collections.OrderedDict = collections.OrderedDict()
#: the config keys the truth of a spacecraft scenario depends on (field_error and
#: spacecraft.inertia_error_pct are removed from them: they only change the on-board models)
_TRUTH_KEYS = ("epoch", "duration_s", "step_s", "orbit", "environment", "spacecraft",
               "initial", "controller")


def _truth_key(cfg: dict) -> str:
    d = {k: cfg[k] for k in _TRUTH_KEYS}
    d["environment"] = {k: v for k, v in d["environment"].items() if k != "field_error"}
    d["spacecraft"] = {k: v for k, v in d["spacecraft"].items() if k != "inertia_error_pct"}
    return json.dumps(d, sort_keys=True, default=str)


def truth_of(cfg: dict) -> types.SimpleNamespace:
    """The seed-independent part of a validated spacecraft scenario config: time base,
    orbit, environment and attitude dynamics (arrays read-only; cached per process,
    see the module docstring). Fields: ``t`` (N,) s, ``orbit``, ``epoch``, ``r_i``,
    ``v_i`` (N, 3) m, m/s, ``b_i`` (N, 3) nT, ``R_io`` (N, 3, 3), ``q_io`` (N, 4),
    ``wio`` (N, 3) rad/s (``w_io_o``), ``hist`` (``AttitudeHistory``), ``q_ob`` (N, 4),
    ``w_ob`` (N, 3) rad/s, ``b_o``, ``b_b`` (N, 3) nT, ``s_i``, ``s_o``, ``s_b`` (N, 3)
    unit, ``illum`` (N,), ``torque_ctrl`` (N, 3) N m."""
    key = _truth_key(cfg)
    hit = _TRUTHS.get(key)
    if hit is not None:
        _TRUTHS.move_to_end(key)
        return hit
    truth = _compute_truth(cfg)
    for v in vars(truth).values():
        if isinstance(v, np.ndarray):
            v.flags.writeable = False
    for v in vars(truth.hist).values():
        v.flags.writeable = False
    _TRUTHS[key] = truth
    while len(_TRUTHS) > TRUTH_CACHE_SIZE:
        _TRUTHS.popitem(last=False)
    return truth


def _compute_truth(cfg: dict) -> types.SimpleNamespace:
    epoch = parse_epoch(cfg["epoch"])
    dt = cfg["step_s"]
    n = int(round(cfg["duration_s"] / dt)) + 1
    t = np.arange(n) * dt
    th = np.arange(2 * n - 1) * (dt / 2.0)           # half-step grid for RK4

    orbit = build_orbit(cfg)
    r_h, v_h = orbit.propagate(th)
    env = cfg["environment"]
    truth_field = field_model(env["field_model"],
                              nmax=env["field_degree"] if env["field_model"] == "igrf" else 1)
    b_h_i = field_i_nT(truth_field, epoch, th, r_h)
    r_i, v_i, b_i = r_h[::2], v_h[::2], b_h_i[::2]

    R_io = orbital_frame_dcm(r_i, v_i)
    q_io = quat_from_dcm(R_io)
    wio = w_io_o_of_orbit(orbit.propagate, t)

    sc = cfg["spacecraft"]
    J = np.asarray(sc["inertia_kg_m2"], float)
    ini = cfg["initial"]
    q_ob0 = quat_from_euler(np.asarray(ini["attitude_euler_deg"]) * _D2R)
    w_ob0 = np.asarray(ini["rate_ob_deg_s"]) * _D2R
    q_ib0 = quat_mul(q_io[0], q_ob0)
    w_ib0 = w_ob0 + quat_rotate(quat_conj(q_ob0), wio[0])
    ctl = cfg["controller"]
    hist = integrate_attitude(
        q_ib0, w_ib0, np.asarray(sc["wheels"]["momentum_Nms"], float), J, dt, r_h,
        b_h_i * 1e-9, q_io, wio, mode=ctl["mode"], k_bdot=ctl["k_bdot"], kp=ctl["kp_Nm"],
        kd=ctl["kd_Nms"], switch_rate=ctl["switch_rate_deg_s"] * _D2R,
        k_dump=ctl["k_dump_1_s"], max_dipole=sc["magnetorquers"]["max_dipole_A_m2"],
        max_wheel_torque=sc["wheels"]["max_torque_Nm"],
        max_wheel_momentum=sc["wheels"]["max_momentum_Nms"],
        residual_dipole=sc["residual_dipole_A_m2"], gravity_gradient=sc["gravity_gradient"])
    q_ib, w_ib = hist.q_ib, hist.w_ib_b
    q_ob = quat_mul(quat_conj(q_io), q_ib)
    w_ob = w_ib - quat_rotate(quat_conj(q_ob), wio)

    # field: truth in o and b
    q_oi = quat_conj(q_io)
    b_o = quat_rotate(q_oi, b_i)
    b_b = quat_rotate(quat_conj(q_ib), b_i)

    # Sun and shadow
    r_sun = sun_position_i(epoch, t)
    if env["sun_model"] == "orbit_normal":
        s_i = -R_io[..., :, 1]                      # -y_o = +orbit normal (dawn-dusk, LTAN 18 h)
    else:
        s_i = r_sun - r_i
        s_i /= np.linalg.norm(s_i, axis=1, keepdims=True)
    illum = (np.ones(n) if env["shadow"] == "none"
             else illumination_fraction(r_i, r_sun))
    s_o = quat_rotate(q_oi, s_i)
    s_b = quat_rotate(quat_conj(q_ib), s_i)
    torque_ctrl = np.cross(hist.m_b, b_b * 1e-9)
    return types.SimpleNamespace(
        t=t, orbit=orbit, epoch=epoch, r_i=r_i, v_i=v_i, b_i=b_i, R_io=R_io, q_io=q_io,
        wio=wio, hist=hist, q_ob=q_ob, w_ob=w_ob, b_o=b_o, b_b=b_b, s_i=s_i, s_o=s_o,
        s_b=s_b, illum=illum, torque_ctrl=torque_ctrl)


def simulate(scenario, rng_seed: int | None = None) -> Recording:
    """Simulate a validated :class:`~gnomon.scenarios.Scenario`; ``rng_seed`` overrides its seed."""
    cfg = scenario.config
    seed = cfg["seed"] if rng_seed is None else int(rng_seed)
    if cfg["kind"] == "imu":
        return simulate_imu(cfg, seed)
    g_gyro, g_mag, g_sun, g_acc, g_field, g_inertia, g_st = (
        np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(7))
    tr = truth_of(cfg)
    t, orbit, epoch = tr.t, tr.orbit, tr.epoch
    n = t.size
    r_i, s_i, q_ib, w_ib = tr.r_i, tr.s_i, tr.hist.q_ib, tr.hist.w_ib_b
    b_b, illum = tr.b_b, tr.illum
    env = cfg["environment"]
    sc = cfg["spacecraft"]
    J = np.asarray(sc["inertia_kg_m2"], float)

    # the on-board field model (possibly in error) in o
    fe = env["field_error"]
    if fe["kind"] == "none" or fe["level_pct"] == 0.0:
        b_o_model = tr.b_o.copy()
    else:
        onboard = field_model(env["field_model"], fe["kind"], fe["level_pct"], g_field,
                              nmax=env["field_degree"] if env["field_model"] == "igrf" else 1)
        b_o_model = quat_rotate(quat_conj(tr.q_io), field_i_nT(onboard, epoch, t, r_i))

    # sensors
    gy = cfg["sensors"]["gyro"]
    period = orbit.period_s
    step_t = (gy["step_time_s"] if gy["step_time_s"] is not None else
              gy["step_time_orbits"] * period if gy["step_time_orbits"] is not None else np.inf)
    gyro, bias = gyro_model(t, w_ib, g_gyro, arw_rad_rt_s=gy["arw_deg_rt_h"] * _D2R / 60.0,
                            bias_rad_s=np.asarray(gy["bias_deg_s"]) * _D2R,
                            bias_rw_rad_s_rt_s=gy["bias_rw_deg_s_rt_s"] * _D2R,
                            step_rad_s=np.asarray(gy["step_deg_s"]) * _D2R, step_time_s=step_t)
    mg = cfg["sensors"]["magnetometer"]
    mag, _ = magnetometer_model(b_b, g_mag, mg["noise_nT"], mg["bias_nT"], mg["scale_pct"],
                                mg["misalignment_deg"])
    ss = cfg["sensors"]["sun_sensor"]
    sun, valid = sun_sensor_model(tr.s_b, illum, g_sun, ss["noise_deg"], ss["boresight_b"],
                                  ss["fov_half_angle_deg"], ss["min_illumination"])
    ac = cfg["sensors"]["accelerometer"]
    accel = (accelerometer_model(n, g_acc, ac["noise_m_s2"], ac["bias_m_s2"])
             if ac["enabled"] else None)

    J_model = _inertia_model(J, sc["inertia_error_pct"], g_inertia)
    hist = tr.hist
    extra = {
        "w_ob_b": tr.w_ob, "w_ib_b": w_ib, "w_io_o": tr.wio, "b_o_nT": tr.b_o,
        "b_o_model_nT": b_o_model, "b_b_nT": b_b, "s_o": tr.s_o, "s_b": tr.s_b,
        "eclipse": illum, "gyro_bias_rad_s": bias, "q_io": tr.q_io, "r_i_m": r_i,
        "v_i_m": tr.v_i, "h_wheel_b_Nms": hist.h_b, "hdot_wheel_b_Nm": hist.hdot_b,
        "m_dipole_b_Am2": hist.m_b, "torque_ctrl_b_Nm": tr.torque_ctrl,
        "torque_dist_b_Nm": hist.torque_dist_b,
        "inertia_kg_m2": np.broadcast_to(J, (n, 3, 3)).copy(),
        "inertia_model_kg_m2": np.broadcast_to(J_model, (n, 3, 3)).copy(),
        "time_orbits": t / period,
    }
    # each recording its own arrays (the truth's are shared and read-only)
    extra = {k: (v.copy() if not v.flags.writeable else v) for k, v in extra.items()}
    st = cfg["sensors"]["star_tracker"]
    if st["enabled"]:
        q_st, st_valid, st_flags = star_tracker_model(
            t, q_ib, g_st, boresight_b=st["boresight_b"],
            noise_cross_rad=st["noise_cross_arcsec"] * _AS2R,
            noise_about_rad=st["noise_about_arcsec"] * _AS2R, rate_hz=st["rate_hz"],
            latency_s=st["latency_s"], sun_i=s_i, sun_exclusion_rad=st["sun_exclusion_deg"] * _D2R,
            r_i_m=r_i, earth_limb_exclusion_rad=st["earth_limb_exclusion_deg"] * _D2R,
            outage_rate_hz=st["outage_rate_per_h"] / 3600.0, outage_mean_s=st["outage_mean_s"],
            outage_windows_s=st["outage_windows_s"])
        extra.update({"st_q_ib": q_st, "st_valid": st_valid, "st_flags": st_flags,
                      "st_boresight_b": np.broadcast_to(
                          boresight_frame(st["boresight_b"])[:, 2], (n, 3)).copy()})
    return Recording(t=t.copy(), gyro=gyro, accel=accel, mag=mag, mag_unit="nT", sun=sun,
                     sun_valid=valid, q_true=tr.q_ob.copy(), frames={"reference": "o", "body": "b"},
                     source=f"gnomon.simulate {cfg['name'] or scenario.source} seed={seed}",
                     extra=extra)


def _imu_params(cfg: dict):
    """The ``AhrsSimParams`` of a validated ``kind: imu`` scenario config."""
    from gnomon.simulation.ahrs import AhrsSimParams

    m = cfg["imu"]
    return AhrsSimParams(
        duration_s=cfg["duration_s"], rate_hz=m["rate_hz"], rate_rms=m["rate_rms_rad_s"],
        rate_band_hz=(m["rate_band_low_hz"], m["rate_band_high_hz"]), rest_s=m["rest_s"],
        gyro_noise=m["gyro_noise_rad_s_rt_hz"], gyro_bias_std=m["gyro_bias_std_rad_s"],
        bias_rw=m["gyro_bias_rw_rad_s_rt_s"], accel_noise=m["accel_noise_m_s2"],
        mag_noise_uT=m["mag_noise_uT"], field_uT=m["field_uT"],
        inclination_deg=m["inclination_deg"], linear_accel_rms=m["linear_accel_rms_m_s2"],
        mag_disturbance_uT=m["mag_disturbance_uT"])


#: the draw order of the ``kind: imu`` scenarios (``gnomon.simulation.ahrs``)
IMU_DRAW_ORDER = "by-sample"


def imu_rng(seed: int) -> np.random.Generator:
    """The generator of a ``kind: imu`` run: ``numpy.random.Generator(SFC64(seed))``
    (numpy's SFC64, seeded through its ``SeedSequence``), drawn from in
    :data:`IMU_DRAW_ORDER`. Chosen for speed: numpy's normals from SFC64 are the
    fastest of its generators (a campaign draws 12 per sample)."""
    return np.random.Generator(np.random.SFC64(seed))


def simulate_imu(cfg: dict, seed: int) -> Recording:
    """A ``kind: imu`` scenario through ``gnomon.simulation.ahrs.simulate_ahrs`` (ENU,
    ``q_true`` = ``q_nb``; every draw from :func:`imu_rng` ``(seed)`` in
    :data:`IMU_DRAW_ORDER`)."""
    from gnomon.simulation.ahrs import simulate_ahrs

    return simulate_ahrs(_imu_params(cfg), imu_rng(seed), IMU_DRAW_ORDER)
