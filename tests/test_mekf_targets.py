"""Issue 22's targets for ``mekf``, at small run counts (the full-size measurement is
``benchmarks/mekf_targets.py``: 16 seeds for T1, 100 runs for T2).

T1, magnetometer bias: ``seed001`` with another epoch and orbit than the presets
(2026-11-05T06:00Z, 600 km, LTAN 09:00; eclipse about 1500-3400 s), one orbit at 1 s, a
bias of (200, -150, 100) nT, seeds 1-3. RMS of the error angle after 600 s.

T2, star tracker + MEMS gyro: ``smallsat-star-tracker`` shortened to 1800 s with its
10-minute outage moved to [900, 1500) s, seeds 1-10, ``mekf`` tuned from the scenario's
datasheet values (magnetometer: ``mag_noise_nT`` 150 nT, the direction noise 150 nT / |B|
per sample). Measured after 300 s.

Truths used: the simulator's ``q_true`` and its bias; chi-square quantiles for the NEES
band; the gyro's datasheet ARW and bias random walk for the drift bound. No network.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from gnomon.estimators.mekf import MEKF, MEKFParams
from gnomon.rotation import error_angle, quat_conj, quat_mul, rotvec_from_quat
from gnomon.scenarios import load_scenario, simulate
from gnomon.sensors import boresight_frame

DEG = np.pi / 180.0
ARCSEC = DEG / 3600.0

T1_OVERRIDES = {"epoch": "2026-11-05T06:00:00Z", "orbit.altitude_km": 600.0,
                "orbit.ltan_h": 9.0}
BIAS_NT = np.array([200.0, -150.0, 100.0])
T1_SEEDS = (1, 2, 3)
T1_SETTLE_S = 600.0

T2_RUNS = 10
T2_OVERRIDES = {"duration_s": 1800.0, "sensors.star_tracker.outage_windows_s": [[900.0, 1500.0]]}
OUTAGE = (900.0, 1500.0)
T2_SETTLE_S = 300.0


# ----------------------------------------------------------------------------- T1
def _t1(seed, bias, **kw):
    sc = load_scenario("seed001").replace({**T1_OVERRIDES, "seed": seed,
                                           "sensors.magnetometer.bias_nT": list(bias)})
    rec = simulate(sc)
    est = MEKF(MEKFParams(**kw)).run(rec)
    err = error_angle(rec.q_true, est.q)
    late = rec.t - rec.t[0] >= T1_SETTLE_S
    return float(np.sqrt(np.mean(err[late] ** 2))), est


@pytest.fixture(scope="module")
def t1():
    out = {"a": [], "b": [], "c": [], "c_est": []}
    for seed in T1_SEEDS:
        out["a"].append(_t1(seed, [0.0, 0.0, 0.0])[0])
        out["b"].append(_t1(seed, BIAS_NT)[0])
        rms, est = _t1(seed, BIAS_NT, estimate_mag_bias=True)
        out["c"].append(rms)
        out["c_est"].append(est)
    return {k: (np.mean(v) if k != "c_est" else v) for k, v in out.items()}


def test_t1_estimating_the_bias_removes_most_of_its_error(t1):
    """With the bias estimated the RMS is at most 0.45 of the RMS with the bias ignored
    (measured 0.21-0.34 per seed over 16 seeds, 0.26 on their means), and estimating the
    bias costs little: RMS(c) / RMS(a) < 1.3 (per seed 0.95-1.15, 1.03 on the means).
    Tolerances: beyond the per-seed worst cases, so 3 seeds cannot miss them by chance."""
    assert t1["c"] <= 0.45 * t1["b"], (t1["c"], t1["b"])
    assert t1["c"] / t1["a"] < 1.3, (t1["c"], t1["a"])


def test_t1_bias_estimate_within_its_own_3_sigma(t1):
    """The magnetometer-bias estimate at the end (one orbit) is within 3 sigma of the
    filter's own covariance of the truth on each axis (over 16 seeds: mean error below
    1 nT, spread 4-7 nT per axis)."""
    for est in t1["c_est"]:
        sd = np.sqrt(est.signals["p_diag"][-1, 6:9])
        err = est.signals["mag_bias_nT"][-1] - BIAS_NT
        assert np.all(np.abs(err) <= 3.0 * sd), (err, sd)


def test_t1_ratio_target(t1):
    """Target (T1): RMS with a few hundred nT of bias and ``estimate_mag_bias`` within
    1.3x of the RMS without the bias (600 s settle). Measured over 16 seeds: 1.03 (the
    magnitude row; 1.44 with the field's direction only, ``sigma_mag_norm_nT=0``)."""
    assert t1["c"] / t1["a"] <= 1.3


# ----------------------------------------------------------------------------- T2
def _t2_params(sc, rec):
    g = sc.config["sensors"]["gyro"]
    st = sc.config["sensors"]["star_tracker"]
    return MEKFParams(arw_rad_rt_s=g["arw_deg_rt_h"] * DEG / 60.0,
                      bias_rw_rad_s_rt_s=g["bias_rw_deg_s_rt_s"] * DEG,
                      sigma_sun_rad=sc.config["sensors"]["sun_sensor"]["noise_deg"] * DEG,
                      sigma_mag_rad=1e-4,  # the field model is exact here: a floor
                      mag_noise_nT=sc.config["sensors"]["magnetometer"]["noise_nT"],
                      st_sigma_cross_rad=st["noise_cross_arcsec"] * ARCSEC,
                      st_sigma_about_rad=st["noise_about_arcsec"] * ARCSEC,
                      st_latency_s=st["latency_s"])


@pytest.fixture(scope="module")
def t2():
    runs = []
    for seed in range(1, T2_RUNS + 1):
        sc = load_scenario("smallsat-star-tracker").replace({**T2_OVERRIDES, "seed": seed})
        rec = simulate(sc)
        p = _t2_params(sc, rec)
        est = MEKF(p).run(rec)
        theta = rotvec_from_quat(quat_mul(quat_conj(est.q), rec.q_true))
        C = est.signals["att_cov_rad2"]
        g = sc.config["sensors"]["gyro"]
        runs.append({
            "t": rec.t - rec.t[0], "theta": theta, "C": C,
            "theta_bore": theta @ boresight_frame(rec.extra["st_boresight_b"][0]),
            "nees": np.einsum("ni,ni->n", theta, np.linalg.solve(C, theta[..., None])[..., 0]),
            "bias_std": np.sqrt(est.signals["p_diag"][:, 3:6]),
            "star_unused": np.asarray(est.signals["star_unused"], bool),
            "arw": g["arw_deg_rt_h"] * DEG / 60.0, "q_b": g["bias_rw_deg_s_rt_s"] * DEG})
    t = runs[0]["t"]
    outage = (t >= OUTAGE[0]) & (t < OUTAGE[1])
    return {"runs": runs, "t": t, "outage": outage, "ok": (t >= T2_SETTLE_S) & ~outage}


def test_t2_rms_below_star_tracker_noise(t2):
    """Outside the outage, after 300 s: the RMS of the error about each cross-boresight
    axis is below the tracker's 10" and about the boresight below its 60" (measured over
    100 full orbits: 7.0", 7.0", 15.9"; the margin is the filtering gain, far larger
    than the ~3 % sampling spread of an RMS over 10 x 6000 correlated samples)."""
    ok = t2["ok"]
    sq = np.mean([np.mean(r["theta_bore"][ok] ** 2, 0) for r in t2["runs"]], 0)
    rms = np.sqrt(sq) / ARCSEC
    assert rms[0] < 10.0 and rms[1] < 10.0, rms
    assert rms[2] < 60.0, rms


def test_t2_anees_in_band_for_10_runs(t2):
    """NEES averaged over the 10 runs at each time (ANEES), two-sided 95 % band
    chi2(30)/10 = [1.62, 4.70]: inside it at >= 90 % of the times outside the outage
    (after 300 s; 95 % expected, 90 % leaves room for the time correlation of 10 runs)
    and below its upper bound at >= 95 % of the times in the outage. Over 100 full
    orbits the 100-run band holds at 95.0 % of the times outside the outage and 94.7 %
    in it (``benchmarks/mekf_targets.py``)."""
    anees = np.mean([r["nees"] for r in t2["runs"]], 0)
    lo, hi = chi2.ppf([0.025, 0.975], 3 * T2_RUNS) / T2_RUNS
    inside = (anees >= lo) & (anees <= hi)
    assert np.mean(inside[t2["ok"]]) >= 0.9, np.mean(inside[t2["ok"]])
    assert np.mean(anees[t2["outage"]] <= hi) >= 0.95, np.mean(anees[t2["outage"]] <= hi)


def test_t2_mean_nees_consistent(t2):
    """Mean ANEES over the times outside the outage within the 100-run 95 % band
    [2.54, 3.49] (a time mean over 10 runs of ~7500 samples is at least as tight as
    the 100-run band at one time). 100 full orbits: 3.00. Before the star tracker's gain
    took out the gyro noise over its latency (in the prediction and in the carried
    measurement alike): 3.8."""
    anees = np.mean([r["nees"] for r in t2["runs"]], 0)
    assert 2.54 <= np.mean(anees[t2["ok"]]) <= 3.49


def test_t2_outage_drift_within_bounds(t2):
    """Through the 10-minute outage the error |θ(t)| stays in every run within
    (i) the filter's own 3 sqrt(tr C(t)) and (ii) the gyro physics bound
    3 sqrt(tr C(t0) + 3 (ARW² τ + σ_b² τ² + q_b² τ³/3)), τ = t - t0, σ_b the filter's bias
    standard deviation at the outage start (rms over axes), ARW and q_b from the
    datasheet: over 600 s per axis ~220" (ARW), ~340" (bias), ~300" (bias walk). Worst
    ratio error/bound over 100 full orbits: (i) 1.07, in 2 runs of 100 (a 3-sigma bound
    on a mostly one-axis error: expected to be crossed now and then), (ii) 0.88, never
    crossed; these 10 seeds stay within both."""
    out = t2["outage"]
    k0 = int(np.argmax(out))
    tau = t2["t"][out] - t2["t"][k0]
    for r in t2["runs"]:
        err = np.linalg.norm(r["theta"][out], axis=1)
        tr = np.trace(r["C"], axis1=1, axis2=2)
        sb2 = np.mean(r["bias_std"][k0] ** 2)
        phys = 3.0 * np.sqrt(tr[k0] + 3.0 * (r["arw"] ** 2 * tau + sb2 * tau ** 2
                                             + r["q_b"] ** 2 * tau ** 3 / 3.0))
        assert np.all(err <= 3.0 * np.sqrt(tr[out])), np.max(err / (3 * np.sqrt(tr[out])))
        assert np.all(err <= phys), np.max(err / phys)


def test_t2_star_tracker_used_again_after_the_outage(t2):
    """No star-tracker sample is gated out (``star_unused``) in the minute after the
    outage: the covariance grown over the outage keeps the first innovations (up to
    ~1000") within the chi-square gate. Exact: 0 over 100 full orbits."""
    t = t2["t"]
    after = (t >= OUTAGE[1]) & (t < OUTAGE[1] + 60.0)
    assert sum(int(np.sum(r["star_unused"][after])) for r in t2["runs"]) == 0
