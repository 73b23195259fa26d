"""A user's own motion-capture recording, scored in one command (issue 33's contract):
``gnomon inspect FILE --write-map MAP.yaml`` with no edit, then ``gnomon benchmark DIR
--map MAP.yaml --align auto --anchors vqf --json``.

The file has the layout of a public mocap data set: ``Timestamp`` in ms, gyro in rad/s,
accelerometer in g, magnetometer in gauss, the optical quaternion as ``cam_qx, cam_qy,
cam_qz, cam_qw`` (scalar last) in a y-up world with a 40° heading, on a marker turned
75° from the sensor, 37 ms late, and an ``isTracked`` column (the untracked rows hold
the identity). The independent check: every method's error against the true attitude
(known by construction, ``test_alignment._motion``) equals its error against the truth
that ``--align auto`` fitted, within 0.1°.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from test_alignment import _mocap, _motion

from gnomon.benchmark.scoring import score_trial
from gnomon.cli import main
from gnomon.estimators import registry
from gnomon.io import read

G = 9.80665


def _write_take(path, seconds, seed):
    t, q_rs, gyro, accel, mag = _motion(seconds, seed=seed)
    q = _mocap(t, q_rs)
    tracked = np.all(np.isfinite(q), axis=1)
    q[~tracked] = [1.0, 0.0, 0.0, 0.0]  # a capture writes a placeholder when it loses track
    head = ["Timestamp", *(f"gyro_{a}" for a in "xyz"), *(f"acc_{a}" for a in "xyz"),
            *(f"mag_{a}" for a in "xyz"), "cam_qx", "cam_qy", "cam_qz", "cam_qw", "isTracked"]
    cols = np.column_stack([np.round(1000.0 * (t + 1234.5), 3), gyro, accel / G, mag / 100.0,
                            q[:, 1:], q[:, :1], tracked.astype(int)])
    np.savetxt(path, cols, delimiter=",", header=",".join(head), comments="", fmt="%.8g")
    return q_rs


def _json(capsys, *args):
    assert main([str(a) for a in args]) == 0
    return json.loads(capsys.readouterr().out)


def test_a_mocap_csv_is_mapped_aligned_and_scored_like_the_true_attitude(tmp_path, capsys):
    takes = tmp_path / "takes"
    takes.mkdir()
    truth = {f"take{k}": _write_take(takes / f"take{k}.csv", 30.0, seed) for k, seed in
             enumerate((3, 5))}
    assert main(["inspect", str(takes / "take0.csv"), "--write-map",
                 str(tmp_path / "map.yaml")]) == 0
    capsys.readouterr()
    res = _json(capsys, "benchmark", takes, "--map", tmp_path / "map.yaml", "--align", "auto",
                "--anchors", "vqf", "--filters", "robust-ahrs,mahony", "--json")
    assert sorted(a["trial"] for a in res["alignment"]) == ["take0", "take1"]
    for a in res["alignment"]:
        assert a["applied"] == ["lag", "body", "world"]
        assert a["lag_s"] == pytest.approx(0.037, abs=2e-3)
        assert np.allclose(a["world_up_in_world"], [0.0, 1.0, 0.0], atol=0.01)
    for m in ("robust-ahrs", "mahony"):
        assert set(res["mean"][m]) >= {"total_deg", "heading_deg", "inclination_deg"}
    try:
        import vqf  # noqa: F401
    except ImportError:
        pass
    else:
        assert res["mean"]["vqf"]["total_deg"] < 5.0
    rows = {(r["trial"], r["method"]): r for r in res["trials"]}
    for name, q_rs in truth.items():  # against the true attitude, where the capture tracked
        rec = read(takes / f"{name}.csv", map=tmp_path / "map.yaml")
        oracle = np.where(np.all(np.isfinite(rec.q_true), axis=1)[:, None], q_rs, np.nan)
        for m in ("robust-ahrs", "mahony"):
            est = registry.create(m, {}).run(rec)
            true = score_trial(dataclasses.replace(rec, q_true=oracle), est.q)
            assert rows[(name, m)]["total_deg"] == pytest.approx(true["total_deg"], abs=0.1)
            assert rows[(name, m)]["total_deg"] < 5.0
