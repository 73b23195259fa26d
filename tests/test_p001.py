"""Seed-001 reproduction on a small campaign (2 seeds per case, in this process)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gnomon.reproduce import p001


@pytest.mark.slow(reason="5 s (2 cores): streams through the live pipeline in real time")
def test_contract_and_targets(tmp_path):
    res = p001.run(tmp_path, seeds=2, executor="serial")
    assert res["paper"] == "001"
    assert set(res["ideal"]) >= {"rms_deg", "max_error_deg", "mean_error_deg"}
    for src in ("inertia", "field_model", "sun_sensor"):
        for lvl in ("2", "10"):
            assert set(res["sensitivity"][src][lvl]) == {"mean_peak_error_deg",
                                                         "p95_peak_error_deg", "rms_deg"}
        for m in res["error_models"][src].values():
            assert set(m) == {"level_pct", "mean_peak_error_deg", "rms_deg"}
    assert set(res["eclipse"]["mekf"]) >= {"sunlit_rms_deg", "eclipse_rms_deg",
                                           "eclipse_max_deg", "eclipse_max_worst_deg"}
    assert res["runs"] == 2 * 20
    # paper: better than 1 deg in the ideal case, mean errors 0-0.5 deg
    assert res["ideal"]["rms_deg"] < 0.5
    # inertia hurts least; a magnitude-only field error does nothing to unit-vector filters
    s10 = {k: v["10"]["mean_peak_error_deg"] for k, v in res["sensitivity"].items()}
    assert s10["inertia"] < min(s10["field_model"], s10["sun_sensor"])
    fm = res["error_models"]["field_model"]
    assert fm["magnitude"]["rms_deg"] < 1.5 * res["ideal_noisy"]["rms_deg"]
    assert fm["direction"]["mean_peak_error_deg"] > 5.0           # atan(0.1) = 5.7 deg
    # 10 % is worse than 2 % for the field model and the sun sensor (the inertia error is
    # lost in the noise for this wheel-held, nearly orbit-fixed spacecraft)
    for src in ("field_model", "sun_sensor"):
        v = res["sensitivity"][src]
        assert v["10"]["rms_deg"] > 2 * v["2"]["rms_deg"]
    assert res["sensitivity"]["inertia"]["10"]["rms_deg"] < 1.5 * res["ideal_noisy"]["rms_deg"]
    # ... but not when the spacecraft tumbles: the error grows with the level
    tb = res["inertia_tumbling"]
    assert tb["rate_ob_rms_deg_s"] > 0.4
    assert tb["10"]["rms_deg"] > 3 * tb["0"]["rms_deg"]
    assert tb["10"]["mekf_rms_deg"] < 1.5 * tb["0"]["mekf_rms_deg"]     # the gyro does not care
    e = res["eclipse"]
    assert e["ekf"]["eclipse_max_deg"] > 5 * e["ekf"]["sunlit_rms_deg"]
    assert e["mekf"]["eclipse_max_deg"] < 2.0 and e["mekf"]["eclipse_max_worst_deg"] < 3.0
    assert e["mekf_field10"]["eclipse_max_deg"] < e["ekf_field10"]["eclipse_max_deg"]
    g = res["geometry"]
    assert -35 < g["beta_deg"] < -25 and 0.25 < g["eclipse_fraction"] < 0.4
    assert 0 < g["min_sun_field_angle_deg"] < 90
    for name in ("euler_ideal.png", "error_envelopes.png", "eclipse.png"):
        assert (tmp_path / name).stat().st_size > 10_000
    assert np.isfinite(list(res["ideal"].values())).all()
    assert json.loads((tmp_path / "metrics.json").read_text())["runs"] == res["runs"]
