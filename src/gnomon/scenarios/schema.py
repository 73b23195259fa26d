"""The scenario schema: every key a scenario file may hold, its default, type and unit.

A scenario is a nested mapping; ``validate(user_dict)`` merges it over the
defaults, rejecting unknown keys by their dotted name (``sensors.gyro.bias_deg``,
with a "did you mean" for a near miss) and checking every leaf's type and range, then
the cross-field rules (step divides duration, orbit above the atmosphere, inertia
symmetric, positive definite, obeying the triangle inequality and in kg m^2, TLE
well-formed with valid checksums and near the scenario's epoch). Every error is one
``InputError`` naming the key and the value, raised before any simulation.

Two schemas, chosen by the top-level ``kind``: ``SCHEMA`` for a spacecraft in orbit
(the default) and ``IMU_SCHEMA`` for an IMU on the ground (``kind: imu``).
"""

from __future__ import annotations

import copy
import datetime
import difflib
import math
import numbers
from typing import Any

import numpy as np

from gnomon.errors import InputError
from gnomon.frames import parse_epoch

__all__ = ["SCHEMA", "IMU_SCHEMA", "KINDS", "schema_of", "defaults", "validate", "flatten",
           "set_dotted", "get_dotted"]


class Leaf:
    """One scenario value: ``kind`` in
    float/int/bool/str/vec3/inertia/enum/number_or/opt_float/windows, a default, a unit and
    a one-line description."""

    def __init__(self, kind: str, default: Any, unit: str = "", doc: str = "", *,
                 choices: tuple = (), min: float | None = None, min_open: bool = False):
        self.kind = kind
        self.default = default
        self.unit = unit
        self.doc = doc
        self.choices = choices
        self.min = min
        self.min_open = min_open

    def check(self, key: str, v: Any) -> Any:
        k = self.kind
        bad = InputError
        if k in ("float", "opt_float", "number_or"):
            if v is None and k == "opt_float":
                return None
            if k == "number_or" and isinstance(v, str):
                if v not in self.choices:
                    raise bad(f"expected a number or one of {list(self.choices)}, got {v!r}",
                              field=key)
                return v
            if isinstance(v, str):          # PyYAML reads '1.0e4' (no exponent sign) as text
                try:
                    v = float(v)
                except ValueError:
                    raise bad(f"expected a number, got {v!r}", field=key) from None
            if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
                raise bad(f"expected a number, got {v!r}", field=key)
            v = float(v)
        elif k == "int":
            if isinstance(v, bool) or not isinstance(v, numbers.Integral):
                raise bad(f"expected an integer, got {v!r}", field=key)
            v = int(v)
        elif k == "bool":
            if not isinstance(v, bool):
                raise bad(f"expected true or false, got {v!r}", field=key)
        elif k == "epoch":                  # YAML turns an unquoted ISO time into a datetime
            if not isinstance(v, str | datetime.date):
                raise bad(f"expected an ISO-8601 UTC time, got {v!r}", field=key)
            try:
                return parse_epoch(v).isoformat().replace("+00:00", "Z")
            except InputError as err:
                raise bad(err.message, field=key) from None
        elif k == "str":
            if not isinstance(v, str):
                raise bad(f"expected a string, got {v!r}", field=key)
        elif k == "enum":
            if v not in self.choices:
                raise bad(f"expected one of {list(self.choices)}, got {v!r}", field=key)
        elif k == "vec3":                   # 3 numbers, or one number for all three axes
            a = np.asarray(v, dtype=object)
            if a.shape == ():
                a = np.array([v, v, v], dtype=object)
            if a.shape != (3,) or not all(isinstance(x, numbers.Real) and not isinstance(x, bool)
                                          and math.isfinite(x) for x in a):
                raise bad(f"expected 3 numbers (or one for all axes), got {v!r}", field=key)
            return [float(x) for x in a]
        elif k == "windows":                # a list of [start, end] pairs, start < end
            ok = isinstance(v, list | tuple) and all(
                isinstance(w, list | tuple) and len(w) == 2 and all(
                    isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x)
                    for x in w) and w[0] < w[1] for w in v)
            if not ok:
                raise bad(f"expected a list of [start, end] pairs with start < end, got {v!r}",
                          field=key)
            return [[float(a), float(b)] for a, b in v]
        elif k == "inertia":
            from gnomon.dynamics import check_inertia

            try:
                arr = np.asarray(v, dtype=float)
            except (TypeError, ValueError):
                raise bad(f"expected 3 numbers or a 3x3 matrix, got {v!r}", field=key) from None
            return check_inertia(arr, field=key).tolist()
        if self.min is not None and isinstance(v, int | float) and not isinstance(v, bool):
            if v < self.min or (self.min_open and v == self.min):
                op = ">" if self.min_open else ">="
                raise bad(f"must be {op} {self.min:g}, got {v!r}", field=key)
        return v


L = Leaf
SCHEMA: dict = {
    "kind": L("enum", "spacecraft", choices=("spacecraft",),
              doc="what is simulated: a spacecraft in orbit (or imu: see IMU_SCHEMA)"),
    "name": L("str", "", doc="scenario name"),
    "description": L("str", "", doc="free text"),
    "epoch": L("epoch", "2026-03-20T00:00:00Z", "UTC", "start time, ISO-8601 UTC"),
    "duration_s": L("float", 5900.0, "s", "length of the run", min=0, min_open=True),
    "step_s": L("float", 1.0, "s", "sampling = integration step", min=0, min_open=True),
    "seed": L("int", 0, doc="root seed (numpy SeedSequence) of every random draw", min=0),
    "orbit": {
        "kind": L("enum", "circular", choices=("circular", "kepler", "tle"),
                  doc="circular/kepler: own propagator with J2 secular drift; tle: SGP4"),
        "altitude_km": L("float", 650.0, "km", "circular: altitude; kepler: a - R_earth"),
        "eccentricity": L("float", 0.0, "", "kepler only", min=0),
        "inclination_deg": L("number_or", "sun_synchronous", "deg",
                             "inclination or 'sun_synchronous'", choices=("sun_synchronous",)),
        "raan_deg": L("opt_float", None, "deg", "RAAN in i; null: from ltan_h"),
        "ltan_h": L("float", 18.0, "h", "local time of the ascending node (when raan_deg null)"),
        "arg_perigee_deg": L("float", 0.0, "deg", "argument of perigee"),
        "arg_latitude_deg": L("float", 0.0, "deg", "argument of latitude (argp + M) at epoch"),
        "j2": L("bool", True, doc="J2 secular drift of node, perigee, mean anomaly"),
        "tle_line1": L("str", "", doc="TLE line 1 (kind: tle)"),
        "tle_line2": L("str", "", doc="TLE line 2 (kind: tle)"),
    },
    "environment": {
        "field_model": L("enum", "igrf", choices=("igrf", "dipole"),
                         doc="truth field: IGRF-14 or its tilted dipole (degree 1)"),
        "field_degree": L("int", 13, doc="IGRF truncation degree (igrf only)", min=1),
        "field_error": {
            "kind": L("enum", "none", choices=("none", "scale", "tilt", "component", "gauss"),
                      doc="error of the on-board field model (extra b_o_model_nT)"),
            "level_pct": L("float", 0.0, "%", "error level", min=0),
        },
        "sun_model": L("enum", "almanac", choices=("almanac", "orbit_normal"),
                       doc="almanac: real Sun; orbit_normal: Sun fixed along the orbit "
                       "normal (-y_o)"),
        "shadow": L("enum", "conical", choices=("conical", "none"),
                    doc="Earth shadow model (illumination fraction)"),
    },
    "spacecraft": {
        "mass_kg": L("float", 30.0, "kg", "mass (informational)", min=0, min_open=True),
        "inertia_kg_m2": L("inertia", [[0.62, 0.01, -0.005], [0.01, 0.58, 0.008],
                                       [-0.005, 0.008, 0.45]], "kg m^2",
                           "3 principal moments or a full 3x3 tensor"),
        "inertia_error_pct": L("float", 0.0, "%",
                               "error of the inertia given to estimators (extra "
                               "inertia_model_kg_m2)", min=0),
        "residual_dipole_A_m2": L("vec3", [0.0, 0.0, 0.0], "A m^2", "residual magnetic dipole"),
        "gravity_gradient": L("bool", True, doc="gravity-gradient torque on"),
        "wheels": {
            "momentum_Nms": L("vec3", [0.0, 0.0, 0.0], "N m s", "initial wheel momentum in b"),
            "max_momentum_Nms": L("float", 0.02, "N m s", "per wheel", min=0),
            "max_torque_Nm": L("float", 0.002, "N m", "per wheel", min=0),
        },
        "magnetorquers": {
            "max_dipole_A_m2": L("float", 0.5, "A m^2", "per axis", min=0),
        },
    },
    "initial": {
        "attitude_euler_deg": L("vec3", [0.0, 0.0, 0.0], "deg",
                                "q_ob at t=0 as [roll, pitch, yaw] (z-y'-x'')"),
        "rate_ob_deg_s": L("vec3", [0.0, 0.0, 0.0], "deg/s", "w_ob_b at t=0"),
    },
    "controller": {
        "mode": L("enum", "magnetic_pd",
                  choices=("none", "bdot", "magnetic_pd", "bdot_then_pd", "wheel_pd"),
                  doc="attitude control law (gnomon.dynamics)"),
        "k_bdot": L("float", 1.0e6, "A m^2 s/T", "B-dot gain", min=0),
        "kp_Nm": L("float", 5e-6, "N m", "pointing gain", min=0),
        "kd_Nms": L("float", 2.5e-3, "N m s", "rate damping gain", min=0),
        "switch_rate_deg_s": L("float", 0.2, "deg/s", "B-dot -> pointing hand-over", min=0),
        "k_dump_1_s": L("float", 1e-3, "1/s", "wheel momentum dumping gain", min=0),
    },
    "sensors": {
        "gyro": {
            "arw_deg_rt_h": L("float", 0.0, "deg/sqrt(h)", "angle random walk", min=0),
            "bias_deg_s": L("vec3", [0.0, 0.0, 0.0], "deg/s", "constant bias"),
            "bias_rw_deg_s_rt_s": L("float", 0.0, "deg/s/sqrt(s)", "bias random walk", min=0),
            "step_deg_s": L("vec3", [0.0, 0.0, 0.0], "deg/s", "drift step (Heaviside)"),
            "step_time_orbits": L("opt_float", None, "orbits", "time of the step in orbits"),
            "step_time_s": L("opt_float", None, "s", "time of the step in seconds"),
        },
        "magnetometer": {
            "noise_nT": L("float", 0.0, "nT", "white noise sigma per axis", min=0),
            "bias_nT": L("vec3", [0.0, 0.0, 0.0], "nT", "constant bias"),
            "scale_pct": L("float", 0.0, "%", "scale-factor sigma (drawn once)", min=0),
            "misalignment_deg": L("float", 0.0, "deg", "misalignment sigma (drawn once)", min=0),
        },
        "sun_sensor": {
            "noise_deg": L("float", 0.0, "deg", "angular noise sigma per axis", min=0),
            "boresight_b": L("vec3", [0.0, 1.0, 0.0], "", "boresight direction in b"),
            "fov_half_angle_deg": L("float", 90.0, "deg", "field-of-view cone half angle",
                                    min=0),
            "min_illumination": L("float", 0.5, "", "valid when illumination >= this", min=0),
        },
        "accelerometer": {
            "enabled": L("bool", False, doc="record an accelerometer"),
            "noise_m_s2": L("float", 0.0, "m/s^2", "white noise sigma", min=0),
            "bias_m_s2": L("vec3", [0.0, 0.0, 0.0], "m/s^2", "constant bias"),
        },
        "star_tracker": {
            "enabled": L("bool", False, doc="record a star tracker (extra st_q_ib, st_valid)"),
            "boresight_b": L("vec3", [0.0, 0.0, -1.0], "",
                             "boresight direction in b (default: zenith when b = o)"),
            "noise_cross_arcsec": L("float", 10.0, "arcsec",
                                    "noise sigma about each axis across the boresight", min=0),
            "noise_about_arcsec": L("float", 60.0, "arcsec",
                                    "noise sigma about the boresight", min=0),
            "rate_hz": L("float", 1.0, "Hz", "update rate (at most 1 / step_s)", min=0,
                         min_open=True),
            "latency_s": L("float", 0.0, "s",
                           "a measurement at t describes the attitude at t - latency", min=0),
            "sun_exclusion_deg": L("float", 30.0, "deg",
                                   "no measurement with the Sun closer to the boresight",
                                   min=0),
            "earth_limb_exclusion_deg": L("float", 20.0, "deg",
                                          "no measurement with the Earth's limb closer to "
                                          "the boresight", min=0),
            "outage_rate_per_h": L("float", 0.0, "1/h",
                                   "random outages: start rate while available", min=0),
            "outage_mean_s": L("float", 0.0, "s", "random outages: mean duration "
                               "(exponential)", min=0),
            "outage_windows_s": L("windows", [], "s",
                                  "scheduled outages: list of [start, end) from the start"),
        },
    },
}


# A hand-held or vehicle IMU (gyro + accelerometer + magnetometer) on the ground,
# simulated by ``gnomon.simulation.ahrs`` (``kind: imu``; navigation frame ENU).
IMU_SCHEMA: dict = {
    "kind": L("enum", "imu", choices=("imu",), doc="what is simulated: an IMU on the ground"),
    "name": L("str", "", doc="scenario name"),
    "description": L("str", "", doc="free text"),
    "duration_s": L("float", 120.0, "s", "length of the run", min=0, min_open=True),
    "seed": L("int", 0, doc="root seed of every random draw", min=0),
    "settle_s": L("float", 10.0, "s", "campaign scores start this long after the start",
                  min=0),
    "imu": {
        "rate_hz": L("float", 100.0, "Hz", "sampling rate", min=0, min_open=True),
        "rate_rms_rad_s": L("float", 0.5, "rad/s", "RMS body rate per axis", min=0),
        "rate_band_low_hz": L("float", 0.02, "Hz", "lowest frequency of the rotation", min=0,
                              min_open=True),
        "rate_band_high_hz": L("float", 0.3, "Hz", "highest frequency of the rotation", min=0,
                               min_open=True),
        "rest_s": L("float", 0.0, "s", "at rest at the start", min=0),
        "gyro_noise_rad_s_rt_hz": L("float", 3e-4, "rad/s/sqrt(Hz)", "gyro white noise",
                                    min=0),
        "gyro_bias_std_rad_s": L("float", 0.01, "rad/s", "constant gyro bias, sigma per axis",
                                 min=0),
        "gyro_bias_rw_rad_s_rt_s": L("float", 2e-5, "rad/s/sqrt(s)", "gyro bias random walk",
                                     min=0),
        "accel_noise_m_s2": L("float", 0.02, "m/s^2", "accelerometer noise per sample", min=0),
        "mag_noise_uT": L("float", 0.3, "uT", "magnetometer noise per sample", min=0),
        "field_uT": L("float", 50.0, "uT", "magnitude of the Earth's field", min=0,
                      min_open=True),
        "inclination_deg": L("float", 60.0, "deg", "magnetic inclination (tan I = Z/H)",
                             min=0),
        "linear_accel_rms_m_s2": L("float", 0.0, "m/s^2", "linear acceleration per axis",
                                   min=0),
        "mag_disturbance_uT": L("float", 0.0, "uT", "magnetic disturbance", min=0),
    },
}
KINDS = {"spacecraft": SCHEMA, "imu": IMU_SCHEMA}

#: more simulation steps than this are refused (a typo in ``step_s``, not a simulation)
MAX_STEPS = 1e9


#: a scenario epoch further than this from the TLE's epoch is refused (SGP4 has drifted
#: by tens to hundreds of km by then: the TLE is not of this time)
MAX_TLE_AGE_DAYS = 30.0
#: a magnetometer noise above this is not a magnetometer (the field in LEO is < 6e4 nT)
MAX_MAG_NOISE_NT = 1e5
#: a radius of gyration sqrt(J_max / mass) above this is an inertia in the wrong unit
MAX_GYRATION_RADIUS_M = 100.0


def _check_tle_epoch(tle_epoch: datetime.datetime, epoch: str) -> None:
    """``InputError`` on ``epoch`` if it is more than ``MAX_TLE_AGE_DAYS`` from the TLE's."""
    days = (parse_epoch(epoch) - tle_epoch).total_seconds() / 86400.0
    if abs(days) > MAX_TLE_AGE_DAYS:
        raise InputError(f"{epoch} is {days:+.1f} days from the TLE's epoch "
                         f"{tle_epoch.isoformat().replace('+00:00', 'Z')} (at most "
                         f"{MAX_TLE_AGE_DAYS:g}): set epoch to the TLE's, or use a newer TLE",
                         field="epoch")


def _check_inertia_units(sc: dict) -> None:
    """``InputError`` if the inertia, with the mass, is far too large for kg m^2 (a tensor
    in kg mm^2 or g cm^2 is 1e6 or 1e7 times too large)."""
    j_max = float(np.max(np.linalg.eigvalsh(np.asarray(sc["inertia_kg_m2"]))))
    radius = math.sqrt(j_max / sc["mass_kg"])
    if radius > MAX_GYRATION_RADIUS_M:
        raise InputError(f"largest moment {j_max:.4g} kg m^2 with mass_kg {sc['mass_kg']:g} "
                         f"is a radius of gyration of {radius:.3g} m: given in kg mm^2 or "
                         "g cm^2? (kg m^2 expected)", field="spacecraft.inertia_kg_m2")


def schema_of(config: dict | None) -> dict:
    """The schema of a scenario mapping: by its ``kind`` (no kind: a spacecraft)."""
    kind = (config or {}).get("kind", "spacecraft") if isinstance(config, dict) else "spacecraft"
    if kind not in KINDS:
        raise InputError(f"expected one of {sorted(KINDS)}, got {kind!r}", field="kind")
    return KINDS[kind]

def defaults(schema: dict = SCHEMA) -> dict:
    """The default scenario as a nested dict."""
    return {k: (defaults(v) if isinstance(v, dict) else copy.deepcopy(v.default))
            for k, v in schema.items()}


def flatten(d: dict, prefix: str = "") -> dict:
    """Nested dict -> {dotted key: value}."""
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, key + "."))
        else:
            out[key] = v
    return out


def _leaf(key: str, schema: dict = SCHEMA):
    node: Any = schema
    parts = key.split(".")
    for i, p in enumerate(parts):
        if not isinstance(node, dict) or p not in node:
            where = ".".join(parts[: i + 1])
            known = sorted(node) if isinstance(node, dict) else []
            raise InputError(f"unknown scenario key {where!r}" + _did_you_mean(where, schema) +
                             (f"; known here: {', '.join(known)}" if known else ""), field=where)
        node = node[p]
    return node


def get_dotted(d: dict, key: str):
    node = d
    for p in key.split("."):
        node = node[p]
    return node


def set_dotted(d: dict, key: str, value, schema: dict = SCHEMA) -> None:
    """Set ``d[a][b][c] = value`` for ``key = 'a.b.c'``; the key must name a leaf of
    ``schema``."""
    node = _leaf(key, schema)
    if isinstance(node, dict):
        raise InputError(f"{key!r} is a section, not a value", field=key)
    parts = key.split(".")
    cur = d
    for p in parts[:-1]:
        cur = cur.setdefault(p, {})
    cur[parts[-1]] = value


def _did_you_mean(key: str, root: dict) -> str:
    """``"; did you mean 'a.b.c'?"`` for an unknown dotted ``key``: the closest key of
    the same section (difflib), else the keys elsewhere with the same last name (a value
    put in the wrong section), else the closest key anywhere; ``""`` when none is close."""
    parts = key.split(".")
    node: Any = root
    for p in parts[:-1]:
        node = node.get(p) if isinstance(node, dict) else None
    names = sorted(node) if isinstance(node, dict) else []
    near = difflib.get_close_matches(parts[-1], names, n=1, cutoff=0.6)
    if near:
        cand = [".".join(parts[:-1] + near)]
    else:
        every = _all_keys(root)
        cand = [k for k in every if k.split(".")[-1] == parts[-1]]
        cand = cand or difflib.get_close_matches(key, every, n=1, cutoff=0.75)
    return f"; did you mean {' or '.join(repr(c) for c in cand)}?" if cand else ""


def _all_keys(schema: dict, prefix: str = "") -> list[str]:
    """Every dotted key of ``schema``, sections included."""
    out = []
    for k, v in schema.items():
        out.append(prefix + k)
        if isinstance(v, dict):
            out += _all_keys(v, f"{prefix}{k}.")
    return out


def _merge(user: dict, schema: dict, out: dict, prefix: str, root: dict | None = None,
           checked: set | None = None) -> None:
    """``user`` over ``out`` (the defaults), each value checked by its schema leaf; the
    dotted keys checked go into ``checked``."""
    root = schema if root is None else root
    if not isinstance(user, dict):
        raise InputError(f"expected a mapping, got {user!r}", field=prefix.rstrip(".") or None)
    for k, v in user.items():
        key = f"{prefix}{k}"
        if k not in schema:
            raise InputError(f"unknown scenario key {key!r}{_did_you_mean(key, root)}; known "
                             f"here: {', '.join(sorted(schema))}", field=key)
        if isinstance(schema[k], dict):
            _merge(v, schema[k], out[k], key + ".", root, checked)
        else:
            out[k] = schema[k].check(key, v)
            if checked is not None:
                checked.add(key)


def validate(user: dict) -> dict:
    """Merge ``user`` over the defaults and validate it; returns the full nested dict."""
    from gnomon.environment.orbit import MIN_ALTITUDE_M, R_EARTH, TLEOrbit
    from gnomon.environment.tle import check_tle

    schema = schema_of(user)
    cfg = defaults(schema)
    checked: set = set()
    _merge(user or {}, schema, cfg, "", checked=checked)
    # the defaults themselves are checked too (inertia as a full matrix, etc.)
    for key, value in flatten(cfg).items():
        if key not in checked:
            set_dotted(cfg, key, _leaf(key, schema).check(key, value), schema)
    if schema is IMU_SCHEMA:
        lo, hi = cfg["imu"]["rate_band_low_hz"], cfg["imu"]["rate_band_high_hz"]
        if not lo < hi:
            raise InputError(f"must be above rate_band_low_hz ({lo:g}), got {hi:g}",
                             field="imu.rate_band_high_hz")
        if cfg["imu"]["inclination_deg"] >= 90.0:
            raise InputError(f"must be < 90, got {cfg['imu']['inclination_deg']:g}",
                             field="imu.inclination_deg")
        return cfg
    n = cfg["duration_s"] / cfg["step_s"]
    if not n <= MAX_STEPS:
        raise InputError(f"{n:.3g} steps of {cfg['step_s']:g} s over {cfg['duration_s']:g} s: "
                         f"more than {MAX_STEPS:.0e}", field="step_s")
    if abs(n - round(n)) > 1e-9 * max(1.0, n):
        raise InputError(f"step {cfg['step_s']:g} s does not divide the duration "
                         f"{cfg['duration_s']:g} s", field="step_s")
    o = cfg["orbit"]
    if o["kind"] in ("circular", "kepler"):
        perigee = (o["altitude_km"] * 1e3 + R_EARTH) * (1.0 - o["eccentricity"]) - R_EARTH
        if perigee < MIN_ALTITUDE_M:
            raise InputError(f"orbit below the atmosphere: perigee altitude "
                             f"{perigee / 1e3:.1f} km < {MIN_ALTITUDE_M / 1e3:.0f} km",
                             field="orbit.altitude_km")
        if o["kind"] == "circular" and o["eccentricity"] != 0.0:
            raise InputError("a circular orbit has eccentricity 0 (use kind: kepler)",
                             field="orbit.eccentricity")
        if o["eccentricity"] >= 1.0:
            raise InputError(f"must be < 1, got {o['eccentricity']}", field="orbit.eccentricity")
    else:
        for n_line in (1, 2):
            if not o[f"tle_line{n_line}"]:
                raise InputError("kind 'tle' needs tle_line1 and tle_line2; this one is "
                                 "missing", field=f"orbit.tle_line{n_line}")
        check_tle(o["tle_line1"], o["tle_line2"])
        _check_tle_epoch(TLEOrbit(o["tle_line1"], o["tle_line2"]).epoch, cfg["epoch"])
    if o["kind"] != "tle" and (o["tle_line1"] or o["tle_line2"]):
        raise InputError(f"TLE lines are given but orbit.kind is {o['kind']!r}, which ignores "
                         "them (set kind: tle)", field="orbit.kind")
    inc = o["inclination_deg"]
    if not isinstance(inc, str) and not 0.0 <= inc <= 180.0:
        raise InputError(f"must be in [0, 180] deg, got {inc:g}", field="orbit.inclination_deg")
    if np.linalg.norm(cfg["sensors"]["sun_sensor"]["boresight_b"]) == 0.0:
        raise InputError("must be a non-zero vector", field="sensors.sun_sensor.boresight_b")
    if cfg["sensors"]["sun_sensor"]["min_illumination"] > 1.0:
        raise InputError("must be in [0, 1]", field="sensors.sun_sensor.min_illumination")
    st = cfg["sensors"]["star_tracker"]
    if np.linalg.norm(st["boresight_b"]) == 0.0:
        raise InputError("must be a non-zero vector", field="sensors.star_tracker.boresight_b")
    if st["enabled"] and st["rate_hz"] * cfg["step_s"] > 1.0 + 1e-9:
        raise InputError(f"{st['rate_hz']:g} Hz is faster than the sampling (step_s "
                         f"{cfg['step_s']:g} s)", field="sensors.star_tracker.rate_hz")
    _check_inertia_units(cfg["spacecraft"])
    noise = cfg["sensors"]["magnetometer"]["noise_nT"]
    if noise > MAX_MAG_NOISE_NT:
        raise InputError(f"{noise:g} nT is more than the Earth's field itself (at most "
                         f"~6e4 nT in low orbit): given in pT? (nT expected)",
                         field="sensors.magnetometer.noise_nT")
    g = cfg["sensors"]["gyro"]
    if g["step_time_orbits"] is not None and g["step_time_s"] is not None:
        raise InputError("give step_time_orbits or step_time_s, not both",
                         field="sensors.gyro.step_time_s")
    if cfg["environment"]["field_degree"] > 13:
        raise InputError(f"IGRF goes to degree 13, got {cfg['environment']['field_degree']}",
                         field="environment.field_degree")
    return cfg
