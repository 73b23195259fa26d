"""Issue 22's targets for the spacecraft MEKF ``mekf``, measured (T1, T2).

Nothing here is typed in: every number is computed from simulated recordings.

T1 -- magnetometer bias. Scenario: ``seed001`` with another epoch and orbit than the
presets (``T1_OVERRIDES``: epoch 2026-11-05T06:00Z, 600 km, LTAN 09:00, still
sun-synchronous with eclipses), one orbit (6000 s; ``--quick``: 3000 s) at 1 s, seeds
1..N (16 by default). Cases:

* (a) no magnetometer bias, ``mekf`` defaults;
* (b) bias (200, -150, 100) nT, ``mekf`` defaults;
* (c) the same bias, ``mekf`` with ``estimate_mag_bias=True`` (other parameters default);
* (d) no bias, ``estimate_mag_bias=True``: what estimating the bias costs by itself;
* and, for a look at the tuning, (c) again with the field's direction only
  (``sigma_mag_norm_nT=0``: no magnitude row), other ``sigma_mag_norm_nT``,
  ``sigma0_mag_bias_nT`` and ``mag_bias_rw_nT_rt_s`` (``T1_TUNINGS``).

Measured per run: the RMS of the attitude error angle after ``T1_SETTLE_S`` (the first
600 s excluded), the RMS after ``T1_LATE_S`` = 3600 s (past the first eclipse, once the
bias estimate has settled) and the eclipse peak (largest error after the settle time where
``extra.eclipse < 0.5`` or the sun sensor is invalid); reported as means over the runs,
with the ratio RMS(c)/RMS(a) (target <= 1.3; both for the 600 s and 3600 s settle) and
the bias estimate at the end vs truth.

T2 -- star tracker with a MEMS gyro. Scenario ``smallsat-star-tracker`` (star tracker 10"
across / 60" about the boresight, 5 Hz, latency 0.2 s, outage [3000, 3600) s, MEMS gyro,
one orbit at 0.2 s), seeds 1..N (100 by default; ``--quick``: 1800 s runs with the
10-minute outage moved to [900, 1500) s). ``mekf`` is tuned from the scenario's datasheet values
(``t2_params``): ARW and bias random walk of the gyro, the star tracker's noise and
latency, sun sensor 1 deg, magnetometer 150 nT over |B| per sample, the filter's
``mag_noise_nT`` (``--t2-mag-sigma min|mean``: a constant 150 nT
/ min or mean |B| instead; the mean makes the filter overconfident in the outage).
Measured:

* outside the outage and after ``T2_SETTLE_S``: the RMS of the error components about
  two cross-boresight axes and about the boresight (frame built from
  ``extra.st_boresight_b``), vs 10" and 60";
* NEES ``θᵀ C⁻¹ θ`` with ``C = att_cov_rad2``, averaged over the runs at each time (ANEES)
  after the settle time; the fraction of times inside the two-sided 95 % chi-square band
  ``chi2(3 N)/N`` and the overall mean (3 if consistent), outside and inside the outage;
* through the outage: the drift bound, (i) from the filter's own covariance,
  ``3 sqrt(tr C(t))``, and (ii) from the gyro physics,
  ``3 sqrt(tr C(t0) + 3 (ARW² τ + σ_b² τ² + q_b² τ³ / 3))`` with ``τ = t - t0``, ``σ_b`` the
  filter's bias standard deviation at the outage start (rms over axes), ``q_b`` the bias
  random walk; the error must stay within each in every run (the worst ratio error/bound
  is reported); plus the star-tracker samples gated out (``star_unused``) after the outage.

Usage::

    python benchmarks/mekf_targets.py [--runs N] [--quick] [--json PATH] [--doc PAGE]
                                      [--only t1|t2]
                                      [--t2-mag-sigma per-sample|min|mean]

``--runs`` sets both run counts (default 16 for T1, 100 for T2).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from scipy.stats import chi2

from gnomon.estimators.mekf import MEKF, MEKFParams
from gnomon.rotation import error_angle, quat_conj, quat_mul, rotvec_from_quat
from gnomon.scenarios import load_scenario, simulate
from gnomon.sensors import boresight_frame

DEG = np.pi / 180.0
ARCSEC = DEG / 3600.0

T1_OVERRIDES = {"epoch": "2026-11-05T06:00:00Z", "orbit.altitude_km": 600.0,
                "orbit.ltan_h": 9.0}
T1_BIAS_NT = [200.0, -150.0, 100.0]
T1_SETTLE_S = 600.0
T1_LATE_S = 3600.0  # after the first eclipse (about 1500-3400 s) and the bias convergence
T1_TUNINGS = ({"sigma_mag_norm_nT": 0.0}, {"sigma_mag_norm_nT": 300.0},
              {"sigma_mag_norm_nT": 1000.0}, {"sigma0_mag_bias_nT": 300.0},
              {"mag_bias_rw_nT_rt_s": 0.1})  # the first: the field's direction only
T2_SETTLE_S = 300.0
T2_QUICK = {"duration_s": 1800.0, "sensors.star_tracker.outage_windows_s": [[900.0, 1500.0]]}


# ----------------------------------------------------------------------------- T1
def t1_scenario(seed: int, bias_nT, duration_s: float | None = None):
    over = {**T1_OVERRIDES, "seed": int(seed), "sensors.magnetometer.bias_nT": list(bias_nT)}
    if duration_s is not None:
        over["duration_s"] = float(duration_s)
    return load_scenario("seed001").replace(over)


def t1_run(rec, params: MEKFParams, settle_s: float = T1_SETTLE_S) -> dict:
    """RMS and eclipse peak (deg) of one run after ``settle_s``; final bias estimate."""
    est = MEKF(params).run(rec, keep_covariance=False)
    err = np.degrees(error_angle(rec.q_true, est.q))
    t = rec.t - rec.t[0]
    late = t >= settle_s
    dark = (np.asarray(rec.extra["eclipse"]) < 0.5) | ~np.asarray(rec.sun_valid, bool)
    after = t >= T1_LATE_S
    out = {"rms_deg": float(np.sqrt(np.mean(err[late] ** 2))),
           "rms_late_deg": float(np.sqrt(np.mean(err[after] ** 2))) if np.any(after)
           else float("nan"),
           "eclipse_peak_deg": float(err[late & dark].max()) if np.any(late & dark)
           else float("nan")}
    if "mag_bias_nT" in est.signals:
        out["mag_bias_end_nT"] = est.signals["mag_bias_nT"][-1].tolist()
    return out


def _eclipse_span(rec):
    t = rec.t - rec.t[0]
    dark = np.asarray(rec.extra["eclipse"]) < 0.5
    return [float(t[dark].min()), float(t[dark].max())] if dark.any() else None


def measure_t1(runs: int = 16, duration_s: float | None = None,
               settle_s: float = T1_SETTLE_S, tunings=T1_TUNINGS) -> dict:
    cases = {"a_no_bias": ({}, [0.0, 0.0, 0.0]),
             "b_bias_defaults": ({}, T1_BIAS_NT),
             "c_bias_estimated": ({"estimate_mag_bias": True}, T1_BIAS_NT),
             "d_no_bias_estimated": ({"estimate_mag_bias": True}, [0.0, 0.0, 0.0])}
    for i, tun in enumerate(tunings):
        cases[f"c{i + 1}_" + "_".join(f"{k}={v}" for k, v in tun.items())] = (
            {"estimate_mag_bias": True, **tun}, T1_BIAS_NT)
    recs = {}
    res = {k: [] for k in cases}
    t0 = time.perf_counter()
    for seed in range(1, runs + 1):
        for bias in ([0.0, 0.0, 0.0], T1_BIAS_NT):
            recs[tuple(bias)] = simulate(t1_scenario(seed, bias, duration_s))
        for name, (kw, bias) in cases.items():
            res[name].append(t1_run(recs[tuple(bias)], MEKFParams(**kw), settle_s))
    out = {"scenario": {"preset": "seed001", **T1_OVERRIDES,
                        "eclipse_s": _eclipse_span(recs[(0.0, 0.0, 0.0)]),
                        "duration_s": duration_s, "bias_nT": T1_BIAS_NT},
           "runs": runs, "settle_s": settle_s, "cases": {}}
    for name, rs in res.items():
        c = {"rms_deg_mean": float(np.mean([r["rms_deg"] for r in rs])),
             "eclipse_peak_deg_mean": float(np.nanmean([r["eclipse_peak_deg"] for r in rs])),
             "rms_late_deg_mean": float(np.mean([r["rms_late_deg"] for r in rs])),
             "rms_deg_runs": [r["rms_deg"] for r in rs]}
        if "mag_bias_end_nT" in rs[0]:
            m = np.array([r["mag_bias_end_nT"] for r in rs])
            c["mag_bias_end_nT_mean"] = m.mean(0).tolist()
            c["mag_bias_end_nT_std"] = m.std(0).tolist()
            truth = np.array(cases[name][1])
            c["mag_bias_end_err_nT_mean"] = (m.mean(0) - truth).tolist()
            c["mag_bias_end_err_nT_rms"] = float(np.sqrt(np.mean(np.sum((m - truth) ** 2, 1))))
        out["cases"][name] = c
    a = out["cases"]["a_no_bias"]["rms_deg_mean"]
    out["ratio_c_over_a"] = out["cases"]["c_bias_estimated"]["rms_deg_mean"] / a
    out["ratio_late_c_over_a"] = (out["cases"]["c_bias_estimated"]["rms_late_deg_mean"]
                                  / out["cases"]["a_no_bias"]["rms_late_deg_mean"])
    out["ratio_b_over_a"] = out["cases"]["b_bias_defaults"]["rms_deg_mean"] / a
    out["ratios_tunings_over_a"] = {k: v["rms_deg_mean"] / a for k, v in out["cases"].items()
                                    if k.startswith("c") and k[1].isdigit()}
    out["wall_s"] = time.perf_counter() - t0
    return out


# ----------------------------------------------------------------------------- T2
def t2_scenario(seed: int, quick: bool = False):
    over = {"seed": int(seed)}
    if quick:
        over.update(T2_QUICK)
    return load_scenario("smallsat-star-tracker").replace(over)


def t2_params(scenario, rec, mag_sigma: str = "per-sample") -> MEKFParams:
    """``mekf`` from the scenario's datasheet values. The magnetometer's direction noise is
    its noise over the field magnitude: per sample (``mag_sigma="per-sample"``, the
    filter's ``mag_noise_nT``, with a floor ``sigma_mag_rad`` of 1e-4 rad: this scenario's
    field model is exact), or a constant from the on-board model's field, the smallest
    over the recording (``"min"``: covers the whole orbit) or the mean (``"mean"``:
    overconfident where the field is weak)."""
    g = scenario.config["sensors"]["gyro"]
    st = scenario.config["sensors"]["star_tracker"]
    mag_nT = scenario.get("sensors.magnetometer.noise_nT")
    b_abs = np.linalg.norm(rec.extra["b_o_model_nT"], axis=1)
    b_mean = float(b_abs.min() if mag_sigma == "min" else b_abs.mean())
    mag = ({"sigma_mag_rad": 1e-4, "mag_noise_nT": mag_nT} if mag_sigma == "per-sample"
           else {"sigma_mag_rad": mag_nT / b_mean})
    return MEKFParams(arw_rad_rt_s=g["arw_deg_rt_h"] * DEG / 60.0,
                      bias_rw_rad_s_rt_s=g["bias_rw_deg_s_rt_s"] * DEG,
                      sigma_sun_rad=scenario.get("sensors.sun_sensor.noise_deg") * DEG,
                      **mag,
                      st_sigma_cross_rad=st["noise_cross_arcsec"] * ARCSEC,
                      st_sigma_about_rad=st["noise_about_arcsec"] * ARCSEC,
                      st_latency_s=st["latency_s"])


def t2_run(rec, params: MEKFParams) -> dict:
    """Per-sample error θ (body axes, rad), NEES, covariance trace and bias std."""
    est = MEKF(params).run(rec)
    dq = quat_mul(quat_conj(est.q), rec.q_true)  # q_true = q_est ⊗ exp(θ)
    theta = rotvec_from_quat(dq)
    C = est.signals["att_cov_rad2"]
    nees = np.einsum("ni,ni->n", theta, np.linalg.solve(C, theta[..., None])[..., 0])
    R_bs = boresight_frame(rec.extra["st_boresight_b"][0])  # columns: x_s, y_s, z_s in b
    return {"theta": theta, "theta_bore": theta @ R_bs,
            "nees": nees, "trace": np.trace(C, axis1=1, axis2=2),
            "bias_std": np.sqrt(est.signals["p_diag"][:, 3:6]),
            "bias_err": rec.extra["gyro_bias_rad_s"] - est.signals["bias_rad_s"],
            "star_unused": np.asarray(est.signals["star_unused"], bool),
            "st_valid": np.asarray(rec.extra["st_valid"], bool)}


def measure_t2(runs: int = 100, quick: bool = False, settle_s: float = T2_SETTLE_S,
               mag_sigma: str = "per-sample") -> dict:
    t0 = time.perf_counter()
    sc0 = t2_scenario(1, quick)
    (w0, w1), = sc0.get("sensors.star_tracker.outage_windows_s")
    g = sc0.config["sensors"]["gyro"]
    arw, q_b = g["arw_deg_rt_h"] * DEG / 60.0, g["bias_rw_deg_s_rt_s"] * DEG
    nees, sq_bore, n_bore = None, None, 0
    worst_cov, worst_phys, drift_end, unused_after, valid_after = [], [], [], [], []
    bound_phys_end, bound_cov_end, bias_std0, bias_err0 = [], [], [], []
    t_sim = t_filt = 0.0
    for seed in range(1, runs + 1):
        ts = time.perf_counter()
        sc = t2_scenario(seed, quick)
        rec = simulate(sc)
        tf = time.perf_counter()
        params = t2_params(sc, rec, mag_sigma)
        r = t2_run(rec, params)
        t_filt += time.perf_counter() - tf
        t_sim += tf - ts
        t = rec.t - rec.t[0]
        out_ = (t >= w0) & (t < w1)
        ok = (t >= settle_s) & ~out_
        nees = r["nees"] if nees is None else nees + r["nees"]
        sq = np.sum(r["theta_bore"][ok] ** 2, 0)
        sq_bore = sq if sq_bore is None else sq_bore + sq
        n_bore += int(ok.sum())
        # outage drift
        k0 = int(np.argmax(t >= w0))
        tau = t[out_] - t[k0]
        err = np.linalg.norm(r["theta"][out_], axis=1)
        b_cov = 3.0 * np.sqrt(r["trace"][out_])
        sb = float(np.sqrt(np.mean(r["bias_std"][k0] ** 2)))
        b_phys = 3.0 * np.sqrt(r["trace"][k0] + 3.0 * (arw ** 2 * tau + sb ** 2 * tau ** 2
                                                       + q_b ** 2 * tau ** 3 / 3.0))
        worst_cov.append(float(np.max(err / b_cov)))
        worst_phys.append(float(np.max(err / b_phys)))
        drift_end.append(float(err[-1]))
        bound_phys_end.append(float(b_phys[-1]))
        bound_cov_end.append(float(b_cov[-1]))
        bias_std0.append(sb)
        bias_err0.append(float(np.linalg.norm(r["bias_err"][k0])))
        after = (t >= w1) & (t < w1 + 60.0)
        unused_after.append(int(np.sum(r["star_unused"][after])))
        valid_after.append(int(np.sum(r["st_valid"][after])))
    anees = nees / runs
    lo, hi = chi2.ppf([0.025, 0.975], 3 * runs) / runs
    late = t >= settle_s
    in_band = (anees >= lo) & (anees <= hi)
    rms = np.sqrt(sq_bore / n_bore) / ARCSEC
    return {
        "scenario": {"preset": "smallsat-star-tracker", "quick": quick,
                     "duration_s": float(sc0.get("duration_s")), "outage_s": [w0, w1]},
        "runs": runs, "settle_s": settle_s, "mag_sigma_from": mag_sigma,
        "params": {k: getattr(params, k) for k in
                   ("arw_rad_rt_s", "bias_rw_rad_s_rt_s", "sigma_sun_rad", "sigma_mag_rad",
                    "mag_noise_nT", "st_sigma_cross_rad", "st_sigma_about_rad", "st_latency_s")},
        "rms_arcsec": {"cross1": float(rms[0]), "cross2": float(rms[1]),
                       "about_boresight": float(rms[2])},
        "st_noise_arcsec": {"cross": params.st_sigma_cross_rad / ARCSEC,
                            "about": params.st_sigma_about_rad / ARCSEC},
        "nees": {"band": [float(lo), float(hi)],
                 "fraction_in_band_outside_outage": float(np.mean(in_band[late & ~out_])),
                 "fraction_in_band_outage": float(np.mean(in_band[out_])),
                 "fraction_in_band_all": float(np.mean(in_band[late])),
                 "mean_outside_outage": float(np.mean(anees[late & ~out_])),
                 "mean_outage": float(np.mean(anees[out_])),
                 "mean_all": float(np.mean(anees[late]))},
        "outage": {"length_s": w1 - w0,
                   "worst_error_over_cov_bound": float(np.max(worst_cov)),
                   "worst_error_over_phys_bound": float(np.max(worst_phys)),
                   "all_within_cov_bound": bool(np.max(worst_cov) <= 1.0),
                   "runs_over_cov_bound": int(np.sum(np.array(worst_cov) > 1.0)),
                   "runs_over_phys_bound": int(np.sum(np.array(worst_phys) > 1.0)),
                   "all_within_phys_bound": bool(np.max(worst_phys) <= 1.0),
                   "error_end_arcsec_mean": float(np.mean(drift_end)) / ARCSEC,
                   "error_end_arcsec_max": float(np.max(drift_end)) / ARCSEC,
                   "cov_bound_end_arcsec_mean": float(np.mean(bound_cov_end)) / ARCSEC,
                   "phys_bound_end_arcsec_mean": float(np.mean(bound_phys_end)) / ARCSEC,
                   "bias_std_start_deg_h_mean": float(np.mean(bias_std0)) / DEG * 3600,
                   "bias_err_start_deg_h_rms": float(np.sqrt(np.mean(np.square(bias_err0))))
                   / DEG * 3600,
                   "star_unused_60s_after": int(np.sum(unused_after)),
                   "star_valid_60s_after": int(np.sum(valid_after))},
        "wall_s": {"total": time.perf_counter() - t0, "simulate": t_sim, "filter": t_filt},
    }


def markdown(out: dict) -> str:
    """The measured targets as the tables of ``docs/estimators/mekf.md``."""
    lines = []
    if "t1" in out:
        t1, c = out["t1"], out["t1"]["cases"]
        sc = t1["scenario"]
        lines += [f"**Magnetometer bias** ({t1['runs']} runs of `seed001` with epoch "
                  f"{sc['epoch']}, {sc['orbit.altitude_km']:g} km, LTAN "
                  f"{sc['orbit.ltan_h']:g} h; bias {sc['bias_nT']} nT; RMS after "
                  f"{t1['settle_s']:g} s, means over the runs):", "",
                  "| case | RMS (°) | eclipse peak (°) |", "| --- | ---: | ---: |"]
        names = {"a_no_bias": "no bias", "b_bias_defaults": "bias, not estimated",
                 "c_bias_estimated": "bias, `estimate_mag_bias`",
                 "d_no_bias_estimated": "no bias, `estimate_mag_bias`"}
        for k, label in names.items():
            lines.append(f"| {label} | {c[k]['rms_deg_mean']:.3f} | "
                         f"{c[k]['eclipse_peak_deg_mean']:.3f} |")
        e = c["c_bias_estimated"]
        lines += ["", f"RMS ratio, bias estimated over no bias: **{t1['ratio_c_over_a']:.2f}** "
                  f"(target ≤ 1.3); bias not estimated: {t1['ratio_b_over_a']:.2f}. The bias "
                  f"estimate at the end: RMS error {e['mag_bias_end_err_nT_rms']:.1f} nT over "
                  f"the runs. With the field's direction only (`sigma_mag_norm_nT=0`): "
                  f"{t1['ratios_tunings_over_a']['c1_sigma_mag_norm_nT=0.0']:.2f}.", ""]
    if "t2" in out:
        t2 = out["t2"]
        r, nees, o = t2["rms_arcsec"], t2["nees"], t2["outage"]
        lines += [f"**Star tracker** ({t2['runs']} runs of `smallsat-star-tracker`, "
                  f"{t2['scenario']['duration_s']:g} s at 0.2 s, tracker 10″ across / 60″ "
                  f"about the boresight at 5 Hz with 0.2 s latency, MEMS gyro; `mekf` set "
                  "from the datasheet values):", "",
                  "| measure | value | target |", "| --- | ---: | --- |",
                  f"| RMS about the two cross-boresight axes | {r['cross1']:.1f}″, "
                  f"{r['cross2']:.1f}″ | < 10″ |",
                  f"| RMS about the boresight | {r['about_boresight']:.1f}″ | < 60″ |",
                  f"| mean NEES outside the outage | {nees['mean_outside_outage']:.2f} | 3 |",
                  f"| times with the {t2['runs']}-run NEES in its 95 % band "
                  f"[{nees['band'][0]:.2f}, {nees['band'][1]:.2f}] | "
                  f"{100 * nees['fraction_in_band_all']:.1f} % | 95 % |",
                  f"| 10-min outage: worst error / gyro drift bound | "
                  f"{o['worst_error_over_phys_bound']:.2f} | ≤ 1 in every run |",
                  f"| 10-min outage: error at its end, mean / max | "
                  f"{o['error_end_arcsec_mean']:.0f}″ / {o['error_end_arcsec_max']:.0f}″ | |",
                  f"| tracker attitudes gated out in the minute after the outage | "
                  f"{o['star_unused_60s_after']} of {o['star_valid_60s_after']} | 0 |", "",
                  "The drift bound: 3 √(tr C(t₀) + 3 (ARW² τ + σ_b² τ² + q_b² τ³/3)), τ the "
                  "time into the outage, σ_b the filter's bias standard deviation at its start "
                  f"({o['bias_std_start_deg_h_mean']:.2f} °/h), ARW and the bias random walk "
                  "q_b from the datasheet; at the outage's end "
                  f"{o['phys_bound_end_arcsec_mean']:.0f}″ on average. The filter's own "
                  "3 √(tr C) was crossed in "
                  f"{o['runs_over_cov_bound']} run(s) of {t2['runs']} (worst ratio "
                  f"{o['worst_error_over_cov_bound']:.2f}).", ""]
    return "\n".join(lines)


def write_doc(out: dict, page) -> None:
    """Replace the ``mekf-targets`` section of ``page`` with :func:`markdown`."""
    from pathlib import Path

    page = Path(page)
    start, end = "<!-- mekf-targets:start -->", "<!-- mekf-targets:end -->"
    text = page.read_text()
    head, rest = text.split(start, 1)
    _, tail = rest.split(end, 1)
    page.write_text(f"{head}{start}\n{markdown(out)}\n{end}{tail}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=None, help="runs for T1 and T2 "
                    "(default 16 and 100)")
    ap.add_argument("--quick", action="store_true", help="short runs (T1 3000 s, T2 1800 s "
                    "with the outage at 900-1500 s)")
    ap.add_argument("--t2-mag-sigma", choices=("per-sample", "min", "mean"),
                    default="per-sample",
                    help="magnetometer direction noise: 150 nT over |B| per sample, or over "
                    "the min or mean |B|")
    ap.add_argument("--only", choices=("t1", "t2"), default=None)
    ap.add_argument("--json", default=None, help="write the numbers to this file")
    ap.add_argument("--doc", default=None, help="write the tables into this page's "
                    "mekf-targets section (docs/estimators/mekf.md)")
    a = ap.parse_args(argv)
    out = {}
    if a.only in (None, "t1"):
        out["t1"] = measure_t1(a.runs or 16, duration_s=3000.0 if a.quick else None)
        print(json.dumps(out["t1"], indent=1, default=float))
    if a.only in (None, "t2"):
        out["t2"] = measure_t2(a.runs or 100, quick=a.quick, mag_sigma=a.t2_mag_sigma)
        print(json.dumps(out["t2"], indent=1, default=float))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1, default=float)
    if a.doc:
        write_doc(out, a.doc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
