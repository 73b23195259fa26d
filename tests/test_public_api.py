"""The public face: every name ``import gnomon`` offers resolves to the documented
object, and the README's example runs through it alone."""

import importlib
import subprocess
import sys
from pathlib import Path

import numpy as np

import gnomon
from gnomon.datasets import bundled


def test_every_exported_name_resolves_to_its_module_attribute():
    for name, target in gnomon._EXPORTS.items():
        module, attr = target.split(":")
        assert getattr(gnomon, name) is getattr(importlib.import_module(module), attr), name
    assert set(gnomon.__all__) == {"__version__", *gnomon._EXPORTS}
    assert "read" in dir(gnomon)


def test_an_unknown_name_raises_attribute_error():
    try:
        gnomon.no_such_thing  # noqa: B018
    except AttributeError as err:
        assert "no_such_thing" in str(err)
    else:
        raise AssertionError("no AttributeError")


def test_import_gnomon_does_not_import_numba_or_the_filters():
    code = ("import sys, gnomon; "
            "print(int('numba' in sys.modules), int('gnomon.estimators' in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["0", "0"]


def test_readme_example_through_the_facade(tmp_path):
    rec = gnomon.read(bundled("broad", "01_undisturbed_slow_rotation_A_excerpt.mat"))
    est = gnomon.make_filter("mahony", kp_acc_rad_s=0.6).run(rec)
    s = gnomon.score(rec.q_true, est.q, rec.score_mask)
    e = gnomon.error_angle_rad(rec.q_true, est.q)
    valid = rec.score_mask & np.all(np.isfinite(rec.q_true), axis=1)
    # the summary's total RMS is the RMS of the per-sample error angle
    assert abs(s["total_deg"] - np.degrees(np.sqrt(np.mean(e[valid] ** 2)))) < 1e-9
    assert "mahony" in gnomon.list_filters()
    path = gnomon.plot_estimate(rec, est, tmp_path / "est.png")
    assert Path(path).stat().st_size > 10_000
