"""The C twins of robust-ahrs and tilt-cf (``gnomon export c``) beyond the shared checks of
``tests/test_export.py``: the coefficients ``gnomon_robust_ahrs_init`` derives in C from the
parameters and the sample times, and its fresh state, equal the kernel's bit for bit; the
library called sample by sample as a board calls it (each sensor at its own rate, several
accelerometer samples per gyro sample, a gap) equals gnomon's ``run``; parameters other than
the defaults; tilt-cf's speed compensation is refused (the C leaves it out)."""

import dataclasses
import shutil
import subprocess

import numpy as np
import pytest

import gnomon
from gnomon.datasets import bundled
from gnomon.errors import InputError
from gnomon.export import export_c
from gnomon.recording import Recording

pytestmark = pytest.mark.skipif(shutil.which("cc") is None or shutil.which("make") is None,
                                reason="no C compiler (cc) or make: the C exports NOT tested")

STRICT = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic"]
#: parameters off the defaults: every branch the defaults leave alone
RA_VARIANTS = [
    {},
    {"mag_every": 1, "bias_every": 1, "heading_kf": False, "hard_iron_tau_s": 0.0,
     "mag_bias_gain_per_s": 0.02, "mag_soft_norm": 0.2, "mag_soft_dip_deg": 5.0,
     "rest_reset": False},
    {"mag_rejection": False, "motion_bias": False, "heading_bias_ref_deg_s": 0.0,
     "tau_mag_s": 0.0, "mag_every": 3, "bias_every": 2, "mag_current_tau_s": 0.0},
]
TC_VARIANTS = [{}, {"accel_rejection_rel": 0.0, "bias_gain_1_s2": 0.0, "init_samples": 1},
               {"time_constant_s": 0.5, "bias_gain_1_s2": 0.05, "init_samples": 3}]


def _angle(q1, q2):
    sign = np.where(np.sum(q1 * q2, axis=-1) < 0.0, -1.0, 1.0)[..., None]
    chord = np.linalg.norm(q1 - sign * q2, axis=-1)
    return 4.0 * np.arcsin(np.clip(0.5 * chord, 0.0, 1.0))


def _export(tmp_path, name, params=None, precision="double"):
    d = tmp_path / f"{name}-{precision}-{abs(hash(str(params))) % 10**8}"
    export_c(name, d, precision, params)
    p = subprocess.run(["make", "-s", "-C", str(d)], capture_output=True, text=True)
    assert p.returncode == 0, p.stdout + p.stderr
    return d


def _compile(d, name, source):
    (d / f"{name}.c").write_text(source)
    lib = next(d.glob("libgnomon_*.a"))
    p = subprocess.run(["cc", *STRICT, "-o", str(d / name), str(d / f"{name}.c"), str(lib),
                        "-lm"], capture_output=True, text=True, cwd=d)
    assert p.returncode == 0, p.stdout + p.stderr
    return d / name


# ---------------------------------------------------------------- coefficients and state
def _flat_record_fields(dtype, prefix):
    """C expressions (row-major, as the C structs lay the kernel's arrays out) of every
    number in a structured dtype, in numpy's order."""
    out = []
    for name in dtype.names:
        sub = dtype.fields[name][0]
        if sub.names:
            out += _flat_record_fields(sub, f"{prefix}{name}.")
        elif sub.shape:
            out += [f"{prefix}{name}[{k}]" for k in range(int(np.prod(sub.shape)))]
        else:
            out.append(prefix + name)
    return out


def _flat_values(x):
    if isinstance(x, np.void):
        return [v for name in x.dtype.names for v in _flat_values(x[name])]
    return [float(v) for v in np.ravel(x)]


@pytest.mark.parametrize("variant", range(len(RA_VARIANTS)))
def test_the_c_coefficients_and_fresh_state_are_the_kernels(tmp_path, variant):
    from gnomon.kernels.robust_ahrs import STATE, coefficients, new_state

    params = RA_VARIANTS[variant]
    d = _export(tmp_path, "robust-ahrs", params)
    p = gnomon.make_filter("robust-ahrs", params).params
    c0 = coefficients(p, 0.01)
    exprs = []
    for field, value in zip(c0._fields, c0, strict=True):
        if hasattr(value, "_fields"):
            exprs += [f"c.{field}.{sub}" for sub in value._fields]
        else:
            exprs.append(f"c.{field}")
    state = _flat_record_fields(STATE, "s.")
    prints = "\n".join(f'    printf("%.17g\\n", (double)({e}));' for e in exprs + state)
    exe = _compile(d, "coeffs", f"""#include <stdio.h>
#include <stdlib.h>
#include "robust_ahrs.h"
#include "robust_ahrs_params.h"
int main(int argc, char **argv)
{{
    gnomon_robust_ahrs_state s;
    gnomon_robust_ahrs_coefficients c;
    (void)argc;
    gnomon_robust_ahrs_init(&s, &c, &GNOMON_ROBUST_AHRS_PARAMS, strtod(argv[1], 0),
                            strtod(argv[2], 0), strtod(argv[3], 0));
{prints}
    return 0;
}}
""")
    for ts in [(0.0035, 0.0035, 0.0035), (0.004888000000001114, 0.00977, 0.02),
               (0.005035400000000578, 0.005035400000000578, 0.020141601999998926),
               (0.01, 0.0, 0.0)]:
        out = subprocess.run([str(exe), *map(repr, ts)], capture_output=True, text=True,
                             check=True).stdout.split()
        got = np.array([float(v) for v in out])
        ref_c = coefficients(p, ts[0], ts[1] or None, ts[2] or None)
        want = [float(sub) for v in ref_c for sub in (v if hasattr(v, "_fields") else (v,))]
        want += _flat_values(new_state(p)[0])
        names = exprs + state
        assert len(got) == len(want)
        bad = [(n, g, w) for n, g, w in zip(names, got, want, strict=True) if g != w]
        assert not bad, (ts, bad)


# ---------------------------------------------------------------- sample by sample, own rates
def _own_rate_recording() -> Recording:
    """60 s of the imu-handheld scenario at 400 Hz (8 s at rest, linear accelerations, a
    magnetic disturbance), its gyro kept at 200 Hz, the accelerometer at 400 Hz on its own
    clock (two samples per gyro sample), the magnetometer at 50 Hz on another, a 1.5 s gap
    in every sensor."""
    from gnomon.scenarios import load_scenario, simulate

    sc = load_scenario("imu-handheld").replace({
        "duration_s": 60.0, "imu.rest_s": 8.0, "imu.linear_accel_rms_m_s2": 0.5,
        "imu.mag_disturbance_uT": 5.0, "imu.rate_hz": 400.0})
    full = simulate(sc, rng_seed=3)
    t = full.t
    keep = ~((t > 30.0) & (t < 31.5))
    ig = np.flatnonzero(keep)[::2]
    ia = np.flatnonzero(keep)
    im = np.flatnonzero(keep)[3::8]
    return Recording(t=t[ig], gyro=full.gyro[ig], accel=full.accel[ia], accel_t=t[ia] - 7e-4,
                     mag=full.mag[im], mag_t=t[im] - 3e-3, mag_unit=full.mag_unit,
                     q_true=full.q_true[ig], source="own-rate")


def _events(rec: Recording) -> str:
    """The recording as a board sees it: each sample in time order, the accelerometer and
    magnetometer samples of a row (Recording.on_time_base) before its gyro sample."""
    lines = []
    rows_a = np.searchsorted(rec.t, rec.accel_t, side="left")
    rows_m = np.searchsorted(rec.t, rec.mag_t, side="left")
    dt = np.diff(rec.t, prepend=rec.t[0])
    ia = im = 0
    for k in range(len(rec)):
        while ia < len(rows_a) and rows_a[ia] == k:
            lines.append("a " + " ".join(map(repr, map(float, rec.accel[ia]))))
            ia += 1
        while im < len(rows_m) and rows_m[im] == k:
            lines.append("m " + " ".join(map(repr, map(float, rec.mag[im]))))
            im += 1
        lines.append(f"g {float(dt[k])!r} " + " ".join(map(repr, map(float, rec.gyro[k]))))
    return "\n".join(lines) + "\n"


_LOOP = """
    char kind;
    double v[4];
    while (scanf(" %c", &kind) == 1) {
        real_t x[3];
        if (kind == 'g') {
            if (scanf("%lf %lf %lf %lf", &v[0], &v[1], &v[2], &v[3]) != 4) return 2;
            x[0] = R(v[1]); x[1] = R(v[2]); x[2] = R(v[3]);
            GYRO;
            real_t q[4];
            GETQ;
            printf("%.17g %.17g %.17g %.17g\\n", (double)q[0], (double)q[1], (double)q[2],
                   (double)q[3]);
        } else {
            if (scanf("%lf %lf %lf", &v[0], &v[1], &v[2]) != 3) return 2;
            x[0] = R(v[0]); x[1] = R(v[1]); x[2] = R(v[2]);
            if (kind == 'a') { ACC; } else { MAG; }
        }
    }
    return 0;
}
"""


def _harness(d, name):
    """A program that calls the library as a board does: `a x y z`, `m x y z` and
    `g dt x y z` lines on stdin, the estimate after each gyro sample on stdout."""
    if name == "robust-ahrs":
        head = """#include <stdio.h>
#include <stdlib.h>
#include "robust_ahrs.h"
#include "robust_ahrs_params.h"
int main(int argc, char **argv)
{
    gnomon_robust_ahrs_state s;
    gnomon_robust_ahrs_coefficients c;
    gnomon_robust_ahrs_params p = GNOMON_ROBUST_AHRS_PARAMS;
    (void)argc;
    gnomon_robust_ahrs_init(&s, &c, &p, R(strtod(argv[1], 0)), R(strtod(argv[2], 0)),
                            R(strtod(argv[3], 0)));
"""
        body = (_LOOP.replace("GYRO", "gnomon_robust_ahrs_update_gyro(&s, &c, R(v[0]), x)")
                .replace("GETQ", "gnomon_robust_ahrs_get_quat(&s, q)")
                .replace("ACC", "gnomon_robust_ahrs_update_acc(&s, x)")
                .replace("MAG", "gnomon_robust_ahrs_update_mag(&s, x)"))
    else:
        head = """#include <stdio.h>
#include <stdlib.h>
#include "tilt_cf.h"
#include "tilt_cf_params.h"
int main(int argc, char **argv)
{
    gnomon_tilt_cf_state s;
    gnomon_tilt_cf_params p = GNOMON_TILT_CF_PARAMS;
    gnomon_tilt_cf_init(&s, &p);
    if (argc == 4) {
        real_t a[3];
        a[0] = R(strtod(argv[1], 0)); a[1] = R(strtod(argv[2], 0)); a[2] = R(strtod(argv[3], 0));
        gnomon_tilt_cf_start(&s, &p, a);
    }
"""
        body = (_LOOP.replace("GYRO", "gnomon_tilt_cf_update_gyro(&s, &p, R(v[0]), x)")
                .replace("GETQ", "gnomon_tilt_cf_get_quat(&s, q)")
                .replace("ACC", "gnomon_tilt_cf_update_acc(&s, x)")
                .replace("MAG", "(void)0"))
    return _compile(d, "board", head + body)


def _board_run(name, rec, d, params):
    """The library sample by sample on ``rec`` and gnomon's run: (q_c, q_python)."""
    f = gnomon.make_filter(name, params)
    ref = f.run(rec).q
    if name == "robust-ahrs":
        args = [repr(v) for v in f.ts]  # the nominal sample times gnomon's prepare chose
    else:
        acc = rec.on_time_base("accel")
        first = acc[np.isfinite(acc[:, 0])][:f.params.init_samples]
        args = [repr(float(v)) for v in np.mean(first, axis=0)]
    p = subprocess.run([str(_harness(d, name)), *args], input=_events(rec),
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    return np.loadtxt(p.stdout.splitlines()), ref


@pytest.fixture(scope="module")
def own_rate():
    return _own_rate_recording()


@pytest.mark.slow(reason="8 s (2 cores): long runs or a first compilation")
@pytest.mark.parametrize("name, variant", [("robust-ahrs", i) for i in range(len(RA_VARIANTS))]
                         + [("tilt-cf", i) for i in range(len(TC_VARIANTS))])
def test_the_library_sample_by_sample_at_own_rates_equals_run(tmp_path, own_rate, name,
                                                               variant):
    params = (RA_VARIANTS if name == "robust-ahrs" else TC_VARIANTS)[variant]
    rec = own_rate
    assert np.max(rec.arrivals("accel")) == 2 and rec.mag_t is not None
    q, ref = _board_run(name, rec, _export(tmp_path, name, params), params)
    err = _angle(q, ref)
    assert err.max() < 1e-6, (err.max(), int(err.argmax()))
    if name == "robust-ahrs" and variant == 0:
        # the 8-s rest at the start fires the first-rest reset: the twins agree through it
        off = gnomon.make_filter(name, {"rest_reset": False}).run(rec).q
        assert _angle(off, ref).max() > 1e-3
    qf, _ = _board_run(name, rec, _export(tmp_path, name, params, "float"), params)
    rms = np.degrees(np.sqrt(np.mean(_angle(qf, ref) ** 2)))
    assert rms < 0.05, rms


@pytest.mark.parametrize("name, variant", [("robust-ahrs", 1), ("robust-ahrs", 2),
                                           ("tilt-cf", 1), ("tilt-cf", 2)])
def test_gnomon_run_with_other_parameters_equals_run(tmp_path, name, variant):
    params = (RA_VARIANTS if name == "robust-ahrs" else TC_VARIANTS)[variant]
    d = _export(tmp_path, name, params)
    for rec in (gnomon.read(sorted(bundled("broad").glob("*.hdf5"))[0]),
                gnomon.read(next(bundled("logs").glob("tyrex/android/*")))):
        csv = tmp_path / "rec.csv"
        gnomon.write(csv, rec)
        with open(csv) as fh:
            p = subprocess.run([str(d / "gnomon_run")], stdin=fh, capture_output=True,
                               text=True)
        assert p.returncode == 0, p.stderr
        q = np.loadtxt(p.stdout.splitlines()[1:], delimiter=",")[:, 1:]
        err = _angle(q, gnomon.make_filter(name, params).run(rec).q)
        assert err.max() < 1e-6, (rec.source, err.max())


def test_the_params_struct_is_the_filters_params_in_order():
    from gnomon.export import SPECS

    for name, skip in (("robust-ahrs", ()), ("tilt-cf", ("speed_compensation",))):
        fields = [f.name for f in dataclasses.fields(gnomon.make_filter(name).Params)]
        assert list(SPECS[name].params) == [f for f in fields if f not in skip]


def test_tilt_cf_speed_compensation_is_refused(tmp_path):
    with pytest.raises(InputError, match="speed compensation"):
        export_c("tilt-cf", tmp_path, params={"speed_compensation": True})
    readme = export_c("tilt-cf", tmp_path / "ok")["files"]
    assert "README.md" in readme
    assert "speed_compensation" in (tmp_path / "ok" / "tilt_cf.h").read_text()
