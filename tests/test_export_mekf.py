"""The C twin of the spacecraft MEKF equals the Python: ``mekf`` (and its presets
``mekf-delayed``, ``mekf-spacecraft``) exported, compiled with the strict flags and run by
its ``gnomon_run`` (``runner_spacecraft.c``) on the CSV that ``gnomon convert`` writes of
simulated spacecraft recordings (seed001; smallsat-star-tracker), with the magnetometer
only, with the sun sensors, with the star tracker, with the star tracker alone, and on a
hard case (an eclipse the delayed pair bridges, field dropouts, a gap, wrong star matches
the gate rejects, tracker outages): in double precision within 1e-6 rad of
``gnomon.make_filter(name).run(rec)`` at every sample, for the default configuration and
for each option of the form (magnetometer bias with its magnitude row, gyro scale factors,
relinearised vectors, star-tracker latency, first-order forms, the current gyro sample,
the delayed pair); in float within 0.05 deg RMS."""

import ctypes
import dataclasses
import json
import re
import shutil
import subprocess

import numpy as np
import pytest

import gnomon
from gnomon.export import SPECS, export_c
from gnomon.rotation import quat_mul
from gnomon.scenarios import load_scenario, simulate

pytestmark = pytest.mark.skipif(shutil.which("cc") is None or shutil.which("make") is None,
                                reason="no C compiler (cc) or make: the C exports NOT tested")

STRICT = "-std=c99 -O2 -Wall -Wextra -Werror -pedantic"


def _angle(q1, q2):
    sign = np.where(np.sum(q1 * q2, axis=-1) < 0.0, -1.0, 1.0)[..., None]
    chord = np.linalg.norm(q1 - sign * q2, axis=-1)
    return 4.0 * np.arcsin(np.clip(0.5 * chord, 0.0, 1.0))


def _hard(rec):
    """``rec`` (5 Hz, star tracker) made hard: the sun invalid over rows 200-699 (NaN in
    300-399), the field zero (dropouts) in rows 50-59 and 800-805, a 15 s gap before row
    1000, the tracker's attitude 2 deg off in rows 400-401 (gated out) and missing in
    rows 600-650."""
    t = rec.t.copy()
    t[1000:] += 15.0
    sun, valid = rec.sun.copy(), rec.sun_valid.copy()
    valid[200:700] = False
    sun[300:400] = np.nan
    mag = rec.mag.copy()
    mag[50:60] = 0.0
    mag[800:806] = 0.0
    extra = dict(rec.extra)
    st, st_valid = extra["st_q_ib"].copy(), extra["st_valid"].copy()
    a = np.radians(2.0)
    st[400:402] = quat_mul(st[400:402], [np.cos(a / 2), np.sin(a / 2), 0.0, 0.0])
    st[600:651] = np.nan
    st_valid[600:651] = False
    extra.update(st_q_ib=st, st_valid=st_valid)
    return dataclasses.replace(rec, t=t, sun=sun, sun_valid=valid, mag=mag, extra=extra)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """label -> (recording, its CSV): seed001 (200 s, 1 Hz) and smallsat-star-tracker (300 s,
    5 Hz) simulated, written as .h5, read back and converted by ``gnomon convert``; their
    sensor subsets and the hard case written by the same writer (``gnomon.write``)."""
    from gnomon.cli import main

    d = tmp_path_factory.mktemp("recordings")
    out = {}
    for label, preset, duration in (("seed001", "seed001", 200.0),
                                    ("star", "smallsat-star-tracker", 300.0)):
        h5, csv = d / f"{label}.h5", d / f"{label}.csv"
        gnomon.write(h5, simulate(load_scenario(preset).replace({"duration_s": duration}),
                                  rng_seed=1))
        assert main(["convert", str(h5), str(csv)]) == 0
        out[label] = (gnomon.read(h5), csv)
    seed001, star = out["seed001"][0], out["star"][0]
    no_tracker = {k: v for k, v in star.extra.items() if not k.startswith("st_")}
    derived = {
        "seed001-mag": dataclasses.replace(seed001, sun=None, sun_valid=None),
        "star-mag": dataclasses.replace(star, sun=None, sun_valid=None, extra=no_tracker),
        "star-only": dataclasses.replace(star, mag=None, sun=None, sun_valid=None),
        "hard": _hard(star),
    }
    for label, rec in derived.items():
        csv = d / f"{label}.csv"
        gnomon.write(csv, rec)
        out[label] = (rec, csv)
    return out


@pytest.fixture(scope="module")
def build(tmp_path_factory):
    """``build(name, precision, params)``: the export written and built (make: the strict
    flags), once per configuration."""
    cache = {}

    def get(name, precision="double", params=None):
        key = (name, precision, json.dumps(params or {}, sort_keys=True))
        if key not in cache:
            d = tmp_path_factory.mktemp(f"{name}-{precision}")
            export_c(name, d, precision, params or {})
            p = subprocess.run(["make", "-s", "-C", str(d)], capture_output=True, text=True)
            assert p.returncode == 0, p.stdout + p.stderr
            assert STRICT in (d / "Makefile").read_text()
            cache[key] = d
        return cache[key]

    return get


def _run(d, csv):
    with open(csv) as fh:
        p = subprocess.run([str(d / "gnomon_run")], stdin=fh, capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert p.stdout.splitlines()[0] == "t,q_w,q_x,q_y,q_z"
    data = np.loadtxt(p.stdout.splitlines()[1:], delimiter=",")
    return data[:, 0], data[:, 1:]


ALL = ("seed001-mag", "seed001", "star-mag", "star", "star-only", "hard")
CASES = [
    ("mekf", {}, ALL),
    ("mekf", {"estimate_mag_bias": True, "mag_noise_nT": 100.0}, ("seed001", "star", "hard")),
    ("mekf", {"estimate_gyro_scale": True}, ("seed001", "star")),
    ("mekf", {"estimate_mag_bias": True, "estimate_gyro_scale": True, "relinearise": True,
              "st_latency_s": 0.05, "sun_substitute": "delayed", "delay_samples": 100},
     ("seed001", "hard")),
    ("mekf", {"transition": "first-order", "correction": "first-order",
              "gyro_sample": "current", "st_gate_chi2": 0.0}, ("seed001", "star")),
    ("mekf", {"sun_substitute": "delayed", "delay_samples": 100}, ("hard",)),
    ("mekf", {"use_sun": False, "use_star_tracker": False}, ("star",)),
    ("mekf-delayed", {"delay_samples": 100}, ("seed001", "hard")),
    ("mekf-delayed", {"delay_samples": 100, "use_star_tracker": True}, ("hard",)),
    ("mekf-spacecraft", {}, ("seed001", "hard")),
]


@pytest.mark.slow(reason="7 s (2 cores): builds and runs the C export")
@pytest.mark.parametrize("name, params, labels", CASES,
                         ids=[f"{n}-{'-'.join(p) or 'default'}" for n, p, _ in CASES])
def test_double_equals_the_compiled_python_at_every_sample(build, recordings, name, params,
                                                           labels):
    d = build(name, "double", params)
    for label in labels:
        rec, csv = recordings[label]
        ref = gnomon.make_filter(name, **params).run(rec)
        t, q = _run(d, csv)
        np.testing.assert_array_equal(t, rec.t)
        err = _angle(q, ref.q)
        assert err.max() < 1e-6, (label, err.max(), int(err.argmax()))


@pytest.mark.parametrize("name, params, labels", [CASES[0], CASES[7]],
                         ids=["mekf", "mekf-delayed"])
def test_float_within_five_hundredths_of_a_degree(build, recordings, name, params, labels):
    d = build(name, "float", params)
    for label in labels:
        rec, csv = recordings[label]
        ref = gnomon.make_filter(name, **params).run(rec)
        _, q = _run(d, csv)
        rms = np.degrees(np.sqrt(np.mean(_angle(q, ref.q) ** 2)))
        assert rms < 0.05, (label, rms)


def test_the_hard_case_exercises_what_it_is_for(recordings):
    """The delayed pair, the dropouts, the gap and the gate all happen in it."""
    rec, _ = recordings["hard"]
    s = gnomon.make_filter("mekf-delayed", delay_samples=100, use_star_tracker=True).run(rec)
    sig = s.signals
    assert sig["sun_substituted"][200:700].all() and not sig["sun_substituted"][:200].any()
    assert sig["mag_unusable"][50:60].all() and sig["gap"][1000]
    assert sig["star_unused"][400:402].all()


def test_the_presets_are_parameter_sets_of_one_twin():
    for name in ("mekf-delayed", "mekf-spacecraft"):
        a, b = SPECS[name], SPECS["mekf"]
        assert (a.sources, a.headers, a.adapter, a.runner, a.params, a.kind) == \
               (b.sources, b.headers, b.adapter, b.runner, b.params, b.kind)
    assert SPECS["mekf"].runner == "runner_spacecraft.c" and SPECS["mekf"].kind == "spacecraft"


def test_the_csv_holds_what_the_mekf_needs(recordings):
    header = open(recordings["star"][1]).readline().strip().split(",")
    for col in ("t", "gyr_x", "mag_x", "b_o_nT_x", "b_o_model_nT_z", "sun_x", "sun_z",
                "sun_valid", "s_o_x", "w_io_o_y", "q_io_0", "q_io_3", "st_q_ib_0",
                "st_q_ib_3", "st_valid", "st_boresight_b_z"):
        assert col in header, col
    rec, csv = recordings["hard"]
    rows = np.genfromtxt(csv, delimiter=",", names=True)
    np.testing.assert_array_equal(rows["sun_valid"], rec.sun_valid.astype(float))
    np.testing.assert_array_equal(rows["sun_x"][:300], rec.sun[:300, 0])
    assert np.isnan(rows["sun_x"][300:400]).all()  # NaN: an empty cell
    np.testing.assert_array_equal(rows["st_valid"], rec.extra["st_valid"].astype(float))


def test_the_library_uses_no_heap_globals_or_io(build):
    for precision in ("double", "float"):
        d = build("mekf", precision)
        for fname in ("mekf.c", "mekf.h", "gnomon_real.h", "gnomon_quat.h"):
            text = (d / fname).read_text()
            includes = set(re.findall(r'#include [<"]([^>"]+)[>"]', text))
            assert includes <= {"math.h", "stdint.h", "stdbool.h", "gnomon_config.h",
                                "gnomon_count.hpp", "gnomon_real.h", "gnomon_quat.h",
                                "mekf.h"}, (fname, includes)
            for word in ("malloc", "printf", "FILE", "fopen"):
                assert word not in text, (fname, word)
        nm = subprocess.run(["nm", str(d / "mekf.o")], capture_output=True, text=True).stdout
        assert not re.search(r" [BbDdCc] ", nm), f"a global variable\n{nm}"


def test_the_runner_refuses_what_it_cannot_run(build, recordings, tmp_path):
    d = build("mekf")
    rec, _ = recordings["star"]
    cases = {"no attitude sensor": dataclasses.replace(rec, mag=None, sun=None, sun_valid=None,
                                                       extra={}),
             "q_io": dataclasses.replace(rec, extra={k: v for k, v in rec.extra.items()
                                                     if k != "q_io"})}
    for why, bad in cases.items():
        csv = tmp_path / "bad.csv"
        gnomon.write(csv, bad)
        with open(csv) as fh:
            p = subprocess.run([str(d / "gnomon_run")], stdin=fh, capture_output=True,
                               text=True)
        assert p.returncode == 2 and why in p.stderr, p.stderr


def test_the_runner_as_a_library_equals_the_runner(build, recordings):
    """``make shared``: ``gnomon_run_columns`` on the CSV's columns gives ``gnomon_run``'s
    attitude."""
    d = build("mekf")
    subprocess.run(["make", "-s", "-C", str(d), "shared"], check=True, capture_output=True)
    fn = ctypes.CDLL(str(d / "libgnomon_mekf_run.so")).gnomon_run_columns
    fn.restype = ctypes.c_int
    _, csv = recordings["hard"]
    table = np.genfromtxt(csv, delimiter=",", names=True)
    names = table.dtype.names
    cols = [np.ascontiguousarray(table[k], dtype=float) for k in names]
    q = np.empty((len(table), 4))
    rc = fn(ctypes.c_long(len(table)), ctypes.c_int(len(names)),
            (ctypes.c_char_p * len(names))(*[k.encode() for k in names]),
            (ctypes.c_void_p * len(cols))(*[c.ctypes.data for c in cols]),
            q.ctypes.data_as(ctypes.c_void_p))
    assert rc == 0
    _, q_run = _run(d, csv)
    np.testing.assert_array_equal(q, q_run)


@pytest.mark.slow(reason="3 s (2 cores): long runs or a first compilation")
def test_cost_json_is_measured(tmp_path):
    from gnomon.cli import main

    out = tmp_path / "mekf"
    assert main(["export", "c", "--filter", "mekf", "--out", str(out)]) == 0
    cost = json.loads((out / "cost.json").read_text())
    assert cost["filter"] == "mekf" and cost["rows"] > 1000
    assert cost["state_bytes"] > 144 * 8 and cost["code_bytes"] > 0 and cost["ns_per_update"] > 0
    assert cost["tail_bytes"] == 0  # no delayed pair: no tail (mekf-delayed: 500 records)
    ops = cost["ops_per_update"]
    assert ops["total"] == pytest.approx(sum(ops[k] for k in ("add", "mul", "div", "sqrt",
                                                              "trig", "other")))
    assert ops["mul"] > 500  # a 6-state covariance propagation at the least
    if shutil.which("arm-none-eabi-gcc"):
        assert cost["code_bytes_cortex_m4f"] > 0
