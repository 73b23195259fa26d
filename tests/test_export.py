"""The C flight code equals the Python: every export compiled with the strict flags and run
on real and simulated recordings (a BROAD trial, a phone trial, a PX4 log); in double
precision within 1e-6 rad of the compiled Python kernel at every sample, in float within
0.05 deg RMS, with a BROAD error within 1 % of the double's."""

import json
import shutil
import subprocess

import numpy as np
import pytest

import gnomon
from gnomon.datasets import bundled
from gnomon.export import SPECS, export_c

pytestmark = pytest.mark.skipif(shutil.which("cc") is None or shutil.which("make") is None,
                                reason="no C compiler (cc) or make: the C exports NOT tested")

STRICT = "-std=c99 -O2 -Wall -Wextra -Werror -pedantic"
IMU_EXPORTS = sorted(n for n, s in SPECS.items() if s.kind == "imu")


def _angle(q1, q2):
    sign = np.where(np.sum(q1 * q2, axis=-1) < 0.0, -1.0, 1.0)[..., None]
    chord = np.linalg.norm(q1 - sign * q2, axis=-1)
    return 4.0 * np.arcsin(np.clip(0.5 * chord, 0.0, 1.0))


def _recordings():
    """A BROAD trial, a phone trial (Nexus 5, tyrex) and a PX4 flight log (bundled)."""
    broad = gnomon.read(sorted(bundled("broad").glob("*.hdf5"))[0])
    phone = gnomon.read(next(bundled("logs").glob("tyrex/android/*")))
    px4 = gnomon.read(bundled("logs") / "px4" / "sample_log_small_imu.ulg")
    return {"broad": broad, "phone": phone, "px4": px4}


@pytest.fixture(scope="module")
def recordings():
    return _recordings()


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """Every IMU export, double and float, written and built (make: the strict flags)."""
    out = {}
    for name in IMU_EXPORTS:
        for precision in ("double", "float"):
            d = tmp_path_factory.mktemp(f"{name}-{precision}")
            export_c(name, d, precision)
            p = subprocess.run(["make", "-s", "-C", str(d)], capture_output=True, text=True)
            assert p.returncode == 0, p.stdout + p.stderr
            assert STRICT in (d / "Makefile").read_text()
            out[name, precision] = d
    return out


def _run(d, rec, tmp_path):
    csv = tmp_path / "rec.csv"
    gnomon.write(csv, rec)
    with open(csv) as fh:
        p = subprocess.run([str(d / "gnomon_run")], stdin=fh, capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    data = np.loadtxt(p.stdout.splitlines()[1:], delimiter=",")
    assert p.stdout.splitlines()[0] == "t,q_w,q_x,q_y,q_z"
    return data[:, 0], data[:, 1:]


@pytest.mark.slow(reason="8 s (2 cores): builds and runs the C export")
@pytest.mark.parametrize("name", IMU_EXPORTS)
def test_double_equals_the_compiled_python_at_every_sample(built, recordings, name,
                                                           tmp_path):
    for label, rec in recordings.items():
        ref = gnomon.make_filter(name).run(rec)
        t, q = _run(built[name, "double"], rec, tmp_path)
        np.testing.assert_array_equal(t, rec.t)
        err = _angle(q, ref.q)
        assert err.max() < 1e-6, (label, err.max(), int(err.argmax()))


@pytest.mark.parametrize("name", IMU_EXPORTS)
def test_float_within_five_hundredths_of_a_degree(built, recordings, name, tmp_path):
    for label, rec in recordings.items():
        ref = gnomon.make_filter(name).run(rec)
        _, q = _run(built[name, "float"], rec, tmp_path)
        rms = np.degrees(np.sqrt(np.mean(_angle(q, ref.q) ** 2)))
        assert rms < 0.05, (label, rms)
    broad = recordings["broad"]
    _, q_double = _run(built[name, "double"], broad, tmp_path)
    _, q_float = _run(built[name, "float"], broad, tmp_path)
    e_double = gnomon.score(broad.q_true, q_double, broad.score_mask)["total_deg"]
    e_float = gnomon.score(broad.q_true, q_float, broad.score_mask)["total_deg"]
    assert abs(e_float - e_double) <= 0.01 * e_double, (e_double, e_float)


def test_the_library_uses_no_heap_globals_or_io(built):
    """Only math.h, stdint.h and stdbool.h in the library's sources; no malloc, no stdio,
    no file-scope variables but constants."""
    import re

    for (name, _), d in built.items():
        spec = SPECS[name]
        for fname in spec.sources + spec.headers + ("gnomon_real.h", "gnomon_quat.h"):
            text = (d / fname).read_text()
            includes = set(re.findall(r'#include [<"]([^>"]+)[>"]', text))
            assert includes <= {"math.h", "stdint.h", "stdbool.h", "gnomon_config.h",
                                "gnomon_count.hpp", "gnomon_real.h", "gnomon_quat.h",
                                *spec.headers}, (fname, includes)
            for word in ("malloc", "printf", "FILE", "fopen"):
                assert word not in text, (fname, word)
        nm = subprocess.run(["nm", str(d / spec.sources[0].replace(".c", ".o"))],
                            capture_output=True, text=True).stdout
        assert not re.search(r" [BbDdCc] ", nm), f"{name}: a global variable\n{nm}"


def test_cost_json_is_measured(tmp_path):
    from gnomon.cli import main

    out = tmp_path / "mahony"
    assert main(["export", "c", "--filter", "mahony", "--out", out]) == 0
    cost = json.loads((out / "cost.json").read_text())
    assert cost["state_bytes"] > 0 and cost["code_bytes"] > 0 and cost["ns_per_update"] > 0
    ops = cost["ops_per_update"]
    assert ops["total"] == pytest.approx(sum(ops[k] for k in ("add", "mul", "div", "sqrt",
                                                              "trig", "other")))
    assert ops["mul"] > 20  # a quaternion step and two vector errors at the least


def test_backend_c_equals_the_python_on_a_log(tmp_path, monkeypatch):
    from gnomon.export.backend import run_c

    monkeypatch.setenv("GNOMON_DATA_DIR", str(tmp_path))  # builds into a cache of its own
    rec = gnomon.read(bundled("logs") / "px4" / "sample_log_small_imu.ulg")
    for name in IMU_EXPORTS:
        ref = gnomon.make_filter(name).run(rec).q
        assert _angle(run_c(name, rec).q, ref).max() < 1e-6


def test_backend_c_reports_the_python_signals(recordings, tmp_path, monkeypatch):
    """The exports that name their signals (``FilterSpec.signals``) return each of the
    Python ``run``'s: flags equal at every sample, numbers within 1e-9 of theirs."""
    from gnomon.export.backend import run_c

    monkeypatch.setenv("GNOMON_DATA_DIR", str(tmp_path))
    named = [n for n in IMU_EXPORTS if SPECS[n].signals]
    assert {"robust-ahrs", "mahony", "tilt-cf", "eskf-r3", "eskf-r6"} <= set(named)
    seen = set()
    for name in named:
        for which, rec in recordings.items():
            ref = gnomon.make_filter(name).run(rec).signals
            if name == "robust-ahrs":
                seen |= {(k, bool(v)) for k in ("rest", "mag_disturbed") for v in ref[k]}
            got = run_c(name, rec).signals
            assert sorted(got) == sorted(ref), (name, which)
            for key, want in ref.items():
                assert got[key].shape == want.shape, (name, which, key)
                if want.dtype == bool:
                    assert np.array_equal(got[key], want), (name, which, key)
                else:
                    np.testing.assert_allclose(got[key], want, rtol=0, atol=1e-9,
                                               err_msg=f"{name} {which} {key}")
    assert len(seen) == 4  # rest and motion, disturbed and clean fields: both compared
    # eskf's bias at its limit (never reached on these logs with the default 0.2 rad/s):
    # a bound of 2e-4 rad/s, both flag values compared
    rec = recordings["broad"]
    ref = gnomon.make_filter("eskf-r3", {"bias_limit": 2e-4}).run(rec).signals
    got = run_c("eskf-r3", rec, params={"bias_limit": 2e-4}).signals
    assert 0 < ref["bias_at_limit"].sum() < len(rec)
    assert np.array_equal(got["bias_at_limit"], ref["bias_at_limit"])
    np.testing.assert_allclose(got["bias_rad_s"], ref["bias_rad_s"], rtol=0, atol=1e-9)


@pytest.mark.slow(reason="about a minute: full phone and BROAD trials through every C export")
def test_held_out_trials_match_in_double_and_float(built, full_tyrex, full_broad, tmp_path):
    """Recordings the twins were not written on: full tyrex phone trials (each sensor on
    its own clock, samples stamped before the first gyro sample) and full BROAD trials;
    double within 1e-6 rad at every sample, float within 0.05 deg RMS."""
    trials = sorted((full_tyrex / "datasets" / "ios").glob("*_NoDist_AR"))[:1] + \
        sorted((full_tyrex / "datasets" / "android").glob("*_Dist_AR"))[:1] + \
        sorted(full_broad.glob("*.hdf5"))[:2]
    assert trials
    for path in trials:
        rec = gnomon.read(path)
        for name in IMU_EXPORTS:
            ref = gnomon.make_filter(name).run(rec).q
            _, q = _run(built[name, "double"], rec, tmp_path)
            assert _angle(q, ref).max() < 1e-6, (path.name, name, _angle(q, ref).max())
            _, q = _run(built[name, "float"], rec, tmp_path)
            rms = np.degrees(np.sqrt(np.mean(_angle(q, ref) ** 2)))
            assert rms < 0.05, (path.name, name, rms)


def test_auto_backend_leaves_parameters_the_c_does_not_take_to_python(tmp_path, monkeypatch,
                                                                       capsys):
    """tilt-cf's C has no speed compensation: under ``--backend auto`` the estimate runs the
    numba kernels and says why (stderr and ``backend_because``); ``--backend c`` refuses it
    naming the parameter. Without the parameter, auto runs the C with its signals."""
    import argparse
    import dataclasses

    from gnomon.cli.estimate import _run_filter
    from gnomon.errors import InputError
    from gnomon.simulation.ahrs import AhrsSimParams, simulate_ahrs

    monkeypatch.setenv("GNOMON_DATA_DIR", str(tmp_path))
    rec = simulate_ahrs(AhrsSimParams(duration_s=5.0), np.random.default_rng(3))
    rec = dataclasses.replace(rec, extra={**rec.extra, "speed_m_s": np.zeros(len(rec))})
    args = argparse.Namespace(filter="tilt-cf", backend="auto", precision="double")
    est, backend, why = _run_filter(args, rec, {"speed_compensation": True})
    assert backend == "python" and "does not take these parameters" in why, why
    assert "running the numba kernels instead" in capsys.readouterr().err
    ref = gnomon.make_filter("tilt-cf").run(rec)     # speed 0: nothing to compensate
    assert _angle(est.q, ref.q).max() < 1e-9
    with pytest.raises(InputError, match="speed compensation") as err:
        _run_filter(argparse.Namespace(filter="tilt-cf", backend="c", precision="double"),
                    rec, {"speed_compensation": True})
    assert err.value.field == "--param"
    est, backend, _ = _run_filter(args, rec, {})
    assert backend == "c (double)" and set(est.signals) == {"acc_rejected", "bias_rad_s"}
