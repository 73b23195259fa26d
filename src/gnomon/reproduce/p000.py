"""Seed 000: microsatellite attitude by complementary filtering — reproduce and go beyond.

Paper: "Estimating the attitude of a microsatellite with a complementary
filter" (``shared/spec/000-microsat-complementary.md``). Scenario: the
``seed000`` preset (30 kg microsatellite, 650 km dawn-dusk SSO, magnetic
stabilisation close to the orbital frame, magnetometer noise 300 nT, gyro
drift step 0.02°/s in all axes at 1.7 orbits, 1 s sampling).

Monte Carlo: each run is the preset with its noise seed and initial
conditions drawn from ``numpy.random.default_rng(seed)``: initial attitude =
preset + U(−2°, 2°) per Euler angle, initial rate = preset + U(−0.005, 0.005)°/s
per axis. Tuning seeds and reporting seeds are disjoint. All RMS values are of
the total error angle over ``t >= 600 s`` (initial convergence excluded)
unless stated, averaged over the reporting seeds.

Experiments (keys of the returned dict, the issue's JSON contract):

* ``tuned``: each filter (explicit ECF, quaternion-driven QCF with the paper's
  Gauss-Newton q_mes) tuned on a (K_P, K_I) grid to its best mean RMS over the
  tuning seeds, then run on the reporting seeds. ``drift_step``: RMS over the
  600 s after the step.
* ``same_gain``: both filters at one high gain (K_P = 0.85 s⁻¹, K_I = 0.01 s⁻²)
  with magnetometer noise 1000 nT — the paper's situation; per-axis error
  RMS about b, s⊥ and c = b × s (body frame, true directions) shows why.
* ``sun_loss``: the sun sensor lost for the whole run (drift step inside),
  the paper's delayed-field substitute (M = 500) in the QCF with gains tuned on
  the tuning seeds, versus gnomon's magnetometer + gyro MEKF (bias estimated
  from the turning field). RMS over ``t >= 1000 s``; ``max_abs_error_deg``:
  mean over seeds of the per-seed maximum (``..._worst``: the worst seed).
* ``solvers``: RMS error of q_mes itself from each Wahba solver.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from gnomon.estimators.ecf_spacecraft import ExplicitSpacecraftCF, initial_q_ob, vector_pairs
from gnomon.estimators.mekf import MEKFDelayed
from gnomon.estimators.qcf import QuaternionCF, measured_quaternions
from gnomon.metrics import axis_errors_rad, error_angle_rad
from gnomon.rotation import quat_conj, quat_mul, quat_rotate, rotvec_from_quat

__all__ = ["run", "simulate_seed", "axis_errors_bsc_rad", "benchmark_speed"]

CONVERGE_S = 600.0
SUN_LOSS_CONVERGE_S = 1000.0
DRIFT_WINDOW_S = 600.0
SAME_GAIN = {"kp": 0.85, "ki": 0.01, "mag_noise_nT": 1000.0}
# log-spaced grids (factor ~1.4); the quaternion filter's grid is the explicit one's x 2
# (its small-error gain is K_P / 2 against K_P about b and s)
ECF_GRID = {"kp": [float(x) for x in np.round(0.01 * np.sqrt(2) ** np.arange(11), 5)],
            "ki": [float(x) for x in np.round(1e-5 * 2.0 ** np.arange(9), 8)]}
QCF_GRID = {k: [2 * v for v in vals] for k, vals in ECF_GRID.items()}
SUN_LOSS_GRID = {"kp": [0.005, 0.01, 0.02, 0.05, 0.1], "ki": [1e-6, 1e-5, 1e-4]}
MEKF_GRID = {"sigma_mag_rad": [0.01, 0.03], "arw_rad_rt_s": [2e-5, 2e-4],
             "bias_rw_rad_s_rt_s": [3e-7, 1e-6, 3e-6]}
MEKF_SUN_GRID = {"sigma_mag_rad": [0.003, 0.01, 0.03], "sigma_sun_rad": [0.001, 0.005],
                 "bias_rw_rad_s_rt_s": [1e-6, 3e-6, 1e-5]}
HYBRID_GRID = {**MEKF_GRID, "swing_gain": [2.0, 4.0, 8.0]}
MOTION_SCALES = (0.0, 0.5, 1.0, 2.0, 4.0)
SOLVER_NAMES = ("gauss-newton", "quest", "davenport", "svd", "triad")


def simulate_seed(seed: int, duration_s: float | None = None, mag_noise_nT: float | None = None,
                  motion_scale: float = 1.0):
    """The ``seed000`` preset with the Monte Carlo draw of ``seed`` (see module docstring).

    ``motion_scale`` scales the initial attitude and rate (preset and draw) and the
    residual magnetic dipole, which set the amplitude of the satellite's swing about
    the orbital frame (measured mean of the per-seed maxima, roll/pitch/yaw: 0: about
    ±3/2/6°; 1, the preset: about ±4/2/12°; 2: ±8/4/21°; 4: ±17/10/41°).
    """
    from gnomon.scenarios import load_scenario, simulate

    sc = load_scenario("seed000")
    rng = np.random.default_rng(seed)
    euler = np.asarray(sc.get("initial.attitude_euler_deg"), float) + rng.uniform(-2, 2, 3)
    rate = np.asarray(sc.get("initial.rate_ob_deg_s"), float) + rng.uniform(-0.005, 0.005, 3)
    dipole = np.asarray(sc.get("spacecraft.residual_dipole_A_m2"), float)
    over = {"seed": int(seed), "initial.attitude_euler_deg": (motion_scale * euler).tolist(),
            "initial.rate_ob_deg_s": (motion_scale * rate).tolist()}
    if motion_scale != 1.0:
        over["spacecraft.residual_dipole_A_m2"] = (motion_scale * dipole).tolist()
    if duration_s is not None:
        over["duration_s"] = float(duration_s)
    if mag_noise_nT is not None:
        over["sensors.magnetometer.noise_nT"] = float(mag_noise_nT)
    return simulate(sc.replace(over))


def _step_time(rec) -> float:
    b = rec.extra["gyro_bias_rad_s"]
    moved = np.flatnonzero(np.any(np.abs(b - b[0]) > 0, axis=1))
    return float(rec.t[moved[0]]) if moved.size else float("nan")


def _rms_deg(x_rad, mask) -> float:
    """RMS in degrees that passes a NaN through (``metrics.rms_deg`` raises on one): a
    grid point whose filter diverged scores NaN, and ``_tune`` ranks it last."""
    return float(np.degrees(np.sqrt(np.mean(np.asarray(x_rad)[mask] ** 2))))


def axis_errors_bsc_rad(rec, q_est) -> np.ndarray:
    """Error rotation vector (body frame, rad) projected on b, s⊥ and c = b × s (N, 3).

    ``θ = rotvec(conj(q_true) ⊗ q_est)``; b, s are the TRUE field and sun
    directions in the body; ``s⊥`` is s made orthogonal to b, ``c = b × s⊥``.
    """
    q_bo = quat_conj(rec.q_true)
    b = quat_rotate(q_bo, rec.extra["b_o_nT"])
    s = quat_rotate(q_bo, rec.extra["s_o"])
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    s = s - np.sum(s * b, axis=1, keepdims=True) * b
    s = s / np.linalg.norm(s, axis=1, keepdims=True)
    c = np.cross(b, s)
    th = rotvec_from_quat(quat_mul(quat_conj(rec.q_true), q_est))
    return np.stack([np.sum(th * b, 1), np.sum(th * s, 1), np.sum(th * c, 1)], axis=1)


class _Case:
    """One simulated run with the filters' preprocessed inputs cached."""

    def __init__(self, rec, sun_lost: bool = False):
        if sun_lost:
            rec = dataclasses.replace(rec, sun_valid=np.zeros(len(rec), bool))
        self.rec = rec
        self.mask = rec.t >= (SUN_LOSS_CONVERGE_S if sun_lost else CONVERGE_S)
        self.t_step = _step_time(rec)
        self.drift = (rec.t >= self.t_step) & (rec.t < self.t_step + DRIFT_WINDOW_S)
        self.q0 = None
        self._measured = {}

    def measured(self, solver="gauss-newton", substitute="delayed"):
        key = (solver, substitute)
        if key not in self._measured:
            pairs = vector_pairs(self.rec, substitute, 500)
            if self.q0 is None:  # TRIAD on the first sample with a real sun vector
                self.q0 = initial_q_ob(vector_pairs(self.rec, "none", 1))
            q_mes, ok = measured_quaternions(pairs, solver, self.q0)
            self._measured[key] = (pairs, q_mes, ok)
        return self._measured[key]

    def run(self, kind, **params):
        if kind == "qcf":
            meas = self.measured(params.get("solver", "gauss-newton"),
                                 params.get("sun_substitute", "delayed"))
            return QuaternionCF(**params).run(self.rec, q0=self.q0, measured=meas).q
        self.measured()
        cls = {"ecf": ExplicitSpacecraftCF, "mekf": MEKFDelayed}[kind]
        return cls(**params).run(self.rec, q0=self.q0).q

    def score(self, q):
        return _rms_deg(error_angle_rad(self.rec.q_true, q), self.mask)


def _tune(cases, kind, grid, fixed=None, table=None):
    """Best (mean RMS over ``cases``) point of the grid: (params, mean RMS).

    ``table``: a list that receives ``(params, mean RMS, mean drift-window RMS)`` of
    every grid point.
    """
    keys = list(grid)
    best, best_val = None, np.inf
    for combo in np.array(np.meshgrid(*[grid[k] for k in keys], indexing="ij")).reshape(
            len(keys), -1).T:
        params = dict(fixed or {})
        params.update({k: float(v) for k, v in zip(keys, combo, strict=True)})
        vals, drift = [], []
        for c in cases:
            e = error_angle_rad(c.rec.q_true, c.run(kind, **params))
            vals.append(_rms_deg(e, c.mask))
            drift.append(_rms_deg(e, c.drift) if c.drift.any() else np.nan)
        val = float(np.mean(vals)) if np.all(np.isfinite(vals)) else np.inf
        if table is not None:
            table.append((params, val, float(np.mean(drift))))
        if val < best_val:
            best, best_val = params, val
    return best, best_val


def _drift_choice(table, best_val, tolerance=0.05):
    """Grid point with the smallest drift-window RMS among those within ``tolerance`` of
    the best overall RMS (a user who cares about drift steps would pick it)."""
    ok = [row for row in table if row[1] <= (1 + tolerance) * best_val]
    return min(ok, key=lambda row: row[2])[0]


def benchmark_speed(rec=None, n_samples: int = 1_000_000, repeats: int = 3) -> dict:
    """Samples per second of each compiled batch loop on ``n_samples`` (a seed000 run tiled).

    Keys: ``ecf`` (explicit filter), ``gauss_newton`` (q_mes sequence), ``qcf_filter``
    (quaternion filter given q_mes), ``qcf`` (Gauss-Newton + filter), ``mekf``; best of
    ``repeats`` (compilation excluded).
    """
    from gnomon.kernels.mekf import coefficients as mekf_coefficients
    from gnomon.kernels.mekf import mekf_batch
    from gnomon.kernels.spacecraft_cf import (
        ecf_batch,
        ecf_coefficients,
        gauss_newton_coefficients,
        gn_sequence,
        qcf_batch,
        qcf_coefficients,
    )

    if rec is None:
        rec = simulate_seed(0, 6000.0)
    p1 = vector_pairs(rec, "delayed", 500)
    reps = int(np.ceil(n_samples / len(rec)))
    p = {k: np.ascontiguousarray(np.concatenate([v] * reps)[:n_samples]) for k, v in p1.items()
         if k != "tail"}
    p["dt"][0] = 0.0
    n = len(p["dt"])
    q_out, b_out, flags = np.empty((n, 4)), np.empty((n, 3)), np.zeros((n, 4), np.int8)
    ok = np.zeros(n, np.bool_)
    q_mes = np.empty((n, 4))

    def timed(fn):
        best = np.inf
        for _ in range(repeats + 1):  # the first call may compile
            t0 = time.perf_counter()
            fn()
            best = min(best, time.perf_counter() - t0)
        return best

    one = np.array([1.0, 0.0, 0.0, 0.0])
    ecf = ExplicitSpacecraftCF()
    qcf = QuaternionCF(kp_rad_s=0.1, kp_single_rad_s=0.0, ki_single_rad_s2=0.0)
    mekf = MEKFDelayed(sigma_mag_rad=0.01, bias_rw_rad_s_rt_s=3e-7, swing_gain=4.0)

    def fresh(f):
        """``f``'s kernel state, reset to the orbital frame."""
        f.reset(one)
        return f.state

    c_ecf, c_gn = ecf_coefficients(ecf.params), gauss_newton_coefficients(qcf.params)
    c_qcf, c_mekf = qcf_coefficients(qcf.params), mekf_coefficients(mekf.params)
    t_ecf = timed(lambda: ecf_batch(c_ecf, fresh(ecf), p["dt"], p["gyro"], p["w_io_o"],
                                    p["mag_b"], p["mag_o"], p["sec_b"], p["sec_o"],
                                    p["sec_valid"], q_out, b_out, flags))
    t_gn = timed(lambda: gn_sequence(c_gn, p["mag_o"], p["mag_b"], p["sec_o"], p["sec_b"],
                                     p["sec_valid"], one.copy(), q_mes, ok))
    t_qcf = timed(lambda: qcf_batch(c_qcf, fresh(qcf), p["dt"], p["gyro"], p["w_io_o"], q_mes,
                                    ok, p["mag_b"], p["mag_o"], q_out, b_out, flags))
    no_st = (np.full((n, 4), np.nan), np.zeros(n, bool), np.zeros((n, 3)))
    mekf_out = (np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 0, 0)),
                np.zeros((n, 5), np.int8), np.empty((n, 2)))
    t_mekf = timed(lambda: mekf_batch(c_mekf, fresh(mekf), p["dt"], p["gyro"], p["w_io_o"],
                                      p["mag_b"], p["mag_o"], p["sec_b"], p["sec_o"],
                                      p["sec_valid"], p["substituted"], *no_st, q_out, b_out,
                                      *mekf_out))
    return {"samples": n, "ecf": n / t_ecf, "gauss_newton": n / t_gn, "qcf_filter": n / t_qcf,
            "qcf": n / (t_gn + t_qcf), "mekf": n / t_mekf}


def run(out_dir: Path | None = None, quick: bool = False, progress: bool = False) -> dict:
    """Reproduce seed 000 (see module docstring); returns the issue's JSON-contract dict."""
    t_start = time.time()
    tune_seeds = [0, 1] if quick else [0, 1, 2, 3]
    report_seeds = list(range(100, 104)) if quick else list(range(100, 124))
    duration = 11000.0 if quick else None

    def say(msg):
        if progress:
            print(f"[p000 {time.time() - t_start:6.1f}s] {msg}", flush=True)

    say("simulating")
    tune = [_Case(simulate_seed(s, duration)) for s in tune_seeds]
    report = [_Case(simulate_seed(s, duration)) for s in report_seeds]

    # ---- tuned comparison
    say("tuning ECF / QCF")
    ecf_map = {"kp": "kp_rad_s", "ki": "ki_rad_s2"}
    ecf_tab, qcf_tab = [], []
    ecf_p, ecf_best = _tune(tune, "ecf", {ecf_map[k]: v for k, v in ECF_GRID.items()},
                            table=ecf_tab)
    qcf_p, qcf_best = _tune(tune, "qcf", {ecf_map[k]: v for k, v in QCF_GRID.items()},
                            table=qcf_tab)
    say(f"ECF {ecf_p}  QCF {qcf_p}")
    t_kernel = {"ecf": 0.0, "qcf": 0.0}
    n_samples = 0
    ecf_rms, qcf_rms, ecf_drift, qcf_drift = [], [], [], []
    for c in report:
        t0 = time.perf_counter()
        qe = c.run("ecf", **ecf_p)
        t_kernel["ecf"] += time.perf_counter() - t0
        c.measured()
        t0 = time.perf_counter()
        qq = c.run("qcf", **qcf_p)
        t_kernel["qcf"] += time.perf_counter() - t0
        n_samples += len(c.rec)
        ee = error_angle_rad(c.rec.q_true, qe)
        eq = error_angle_rad(c.rec.q_true, qq)
        ecf_rms.append(_rms_deg(ee, c.mask))
        qcf_rms.append(_rms_deg(eq, c.mask))
        ecf_drift.append(_rms_deg(ee, c.drift))
        qcf_drift.append(_rms_deg(eq, c.drift))
    ecf_rms, qcf_rms = np.array(ecf_rms), np.array(qcf_rms)
    outage = [float(np.sum(np.diff(c.rec.t, prepend=c.rec.t[0])[~c.rec.sun_valid & c.mask]))
              for c in report]
    tuned = {
        "runs": len(report),
        "tuning_seeds": tune_seeds, "report_seeds": report_seeds,
        "ecf": {"kp": ecf_p["kp_rad_s"], "ki": ecf_p["ki_rad_s2"],
                "mean_rms_deg": float(ecf_rms.mean()),
                "p95_rms_deg": float(np.percentile(ecf_rms, 95))},
        "qcf": {"kp": qcf_p["kp_rad_s"], "ki": qcf_p["ki_rad_s2"],
                "mean_rms_deg": float(qcf_rms.mean()),
                "p95_rms_deg": float(np.percentile(qcf_rms, 95))},
        "ratio_ecf_over_qcf": float(ecf_rms.mean() / qcf_rms.mean()),
        "qcf_better_fraction": float(np.mean(qcf_rms < ecf_rms)),
        "drift_step": {"ecf_rms_deg": float(np.mean(ecf_drift)),
                       "qcf_rms_deg": float(np.mean(qcf_drift)),
                       "window_s": DRIFT_WINDOW_S},
        # small-error theory: the explicit filter's gain is K_P (I + c cᵀ), the
        # quaternion filter's K_P / 2, so equal bandwidth about b, s needs K_P,qcf = 2 K_P,ecf
        "kp_ratio_qcf_over_ecf": float(qcf_p["kp_rad_s"] / ecf_p["kp_rad_s"]),
        # per seed, with the seconds the sun was outside the sensor's field of view (then
        # both filters use the paper's delayed-field substitute)
        "per_seed": {"ecf_rms_deg": ecf_rms.tolist(), "qcf_rms_deg": qcf_rms.tolist(),
                     "sun_outage_s": outage},
    }
    clean = np.array(outage) == 0
    if clean.any():
        tuned["without_sun_outage"] = {
            "runs": int(clean.sum()), "ecf_mean_rms_deg": float(ecf_rms[clean].mean()),
            "qcf_mean_rms_deg": float(qcf_rms[clean].mean()),
            "ratio_ecf_over_qcf": float(ecf_rms[clean].mean() / qcf_rms[clean].mean())}

    # drift-aware choice: within 5 % of each filter's best overall RMS on the tuning seeds,
    # the gains with the smallest RMS after the drift step
    drift_tuned = {"tolerance": 0.05}
    for kind, tab, best_val in (("ecf", ecf_tab, ecf_best), ("qcf", qcf_tab, qcf_best)):
        p_d = _drift_choice(tab, best_val)
        all_, dr = [], []
        for c in report:
            e = error_angle_rad(c.rec.q_true, c.run(kind, **p_d))
            all_.append(_rms_deg(e, c.mask))
            dr.append(_rms_deg(e, c.drift))
        drift_tuned[kind] = {"kp": p_d["kp_rad_s"], "ki": p_d["ki_rad_s2"],
                             "mean_rms_deg": float(np.mean(all_)),
                             "drift_rms_deg": float(np.mean(dr))}
    tuned["drift_aware"] = drift_tuned

    # for reference: the MEKF (a Kalman filter, not complementary) tuned the same way
    mk_p, _ = _tune(tune, "mekf", MEKF_SUN_GRID)
    mk_all, mk_dr = [], []
    for c in report:
        e = error_angle_rad(c.rec.q_true, c.run("mekf", **mk_p))
        mk_all.append(_rms_deg(e, c.mask))
        mk_dr.append(_rms_deg(e, c.drift))
    tuned["mekf_reference"] = {"params": mk_p, "mean_rms_deg": float(np.mean(mk_all)),
                               "p95_rms_deg": float(np.percentile(mk_all, 95)),
                               "drift_rms_deg": float(np.mean(mk_dr)),
                               "per_seed_rms_deg": [float(v) for v in mk_all]}
    if clean.any():
        tuned["mekf_reference"]["without_sun_outage_mean_rms_deg"] = float(
            np.mean(np.array(mk_all)[clean]))

    # ---- solvers (q_mes itself)
    say("solvers")
    solvers = {}
    for name in SOLVER_NAMES:
        vals, qcf_vals = [], []
        for c in report:
            _, q_mes, ok = c.measured(name)
            m = c.mask & ok
            vals.append(_rms_deg(error_angle_rad(c.rec.q_true, q_mes), m))
            qcf_vals.append(c.score(c.run("qcf", solver=name, **qcf_p)))
        solvers[name] = {"rms_error_deg": float(np.mean(vals)),
                         "qcf_rms_deg": float(np.mean(qcf_vals))}

    # ---- same gain, the paper's situation
    say("same gain")
    sg = [_Case(simulate_seed(s, duration, SAME_GAIN["mag_noise_nT"])) for s in report_seeds]
    sg_e, sg_q, ax_e, ax_q = [], [], [], []
    for c in sg:
        qe = c.run("ecf", kp_rad_s=SAME_GAIN["kp"], ki_rad_s2=SAME_GAIN["ki"])
        qq = c.run("qcf", kp_rad_s=SAME_GAIN["kp"], ki_rad_s2=SAME_GAIN["ki"])
        sg_e.append(c.score(qe))
        sg_q.append(c.score(qq))
        ax_e.append(np.degrees(np.sqrt(np.mean(axis_errors_bsc_rad(c.rec, qe)[c.mask] ** 2, 0))))
        ax_q.append(np.degrees(np.sqrt(np.mean(axis_errors_bsc_rad(c.rec, qq)[c.mask] ** 2, 0))))
    ax_e, ax_q = np.mean(ax_e, 0), np.mean(ax_q, 0)
    kp = SAME_GAIN["kp"]
    # discrete first-order loop x+ = (1 - g) x + g n: noise variance factor g / (2 - g)
    loop = {"ecf_b": kp, "ecf_s": kp, "ecf_c": 2 * kp, "qcf": kp / 2}
    # how the ratio depends on the unknown gain and noise (K_I scaled as K_P² / 72)
    sweep = []
    for noise in ([SAME_GAIN["mag_noise_nT"]] if quick else [300.0, SAME_GAIN["mag_noise_nT"]]):
        cases = sg if noise == SAME_GAIN["mag_noise_nT"] else [
            _Case(simulate_seed(sd, duration, noise)) for sd in report_seeds[:8]]
        for kp_s in ([0.2, 0.85] if quick else [0.1, 0.2, 0.4, 0.6, 0.85, 0.95]):
            ki_s = kp_s ** 2 / 72.0
            e_ = np.mean([c.score(c.run("ecf", kp_rad_s=kp_s, ki_rad_s2=ki_s)) for c in cases])
            q_ = np.mean([c.score(c.run("qcf", kp_rad_s=kp_s, ki_rad_s2=ki_s)) for c in cases])
            sweep.append({"kp": kp_s, "ki": ki_s, "mag_noise_nT": noise, "runs": len(cases),
                          "ecf_rms_deg": float(e_), "qcf_rms_deg": float(q_),
                          "ratio_ecf_over_qcf": float(e_ / q_)})
    same_gain = {
        "sweep": sweep,
        "kp": kp, "ki": SAME_GAIN["ki"], "mag_noise_nT": SAME_GAIN["mag_noise_nT"],
        "ecf_rms_deg": float(np.mean(sg_e)), "qcf_rms_deg": float(np.mean(sg_q)),
        "ratio_ecf_over_qcf": float(np.mean(sg_e) / np.mean(sg_q)),
        "axis_rms_deg": {"ecf": dict(zip("bsc", map(float, ax_e), strict=True)),
                         "qcf": dict(zip("bsc", map(float, ax_q), strict=True))},
        "loop_gain_per_sample": loop,
        "noise_variance_factor": {k: float(g / (2 - g)) for k, g in loop.items()},
    }

    # ---- sun loss
    say("sun loss")
    tune_sl = [_Case(c.rec, sun_lost=True) for c in tune]
    report_sl = [_Case(c.rec, sun_lost=True) for c in report]
    pap_p, _ = _tune(tune_sl, "qcf", {"kp_rad_s": SUN_LOSS_GRID["kp"],
                                      "ki_rad_s2": SUN_LOSS_GRID["ki"]},
                     fixed={"sun_substitute": "delayed", "delay_samples": 500,
                            "kp_single_rad_s": 0.0, "ki_single_rad_s2": 0.0})
    mekf_p, _ = _tune(tune_sl, "mekf", HYBRID_GRID,
                      fixed={"sun_substitute": "delayed", "delay_samples": 500})
    mag_only_p, _ = _tune(tune_sl, "mekf", MEKF_GRID, fixed={"sun_substitute": "none"})
    say(f"paper {pap_p} improved {mekf_p}")

    def sun_loss_stats(kind, params, cases=None):
        rms, mx, amp = [], [], []
        for c in (report_sl if cases is None else cases):
            q = c.run(kind, **params)
            rms.append(c.score(q))
            mx.append(np.degrees(np.abs(axis_errors_rad(c.rec.q_true, q)[c.mask]).max(0)))
            amp.append(np.degrees(np.abs(axis_errors_rad(
                np.array([1.0, 0, 0, 0]), c.rec.q_true)[c.mask]).max(0)))
        mx = np.array(mx)
        return {"rms_deg": float(np.mean(rms)),
                "max_abs_error_deg": dict(zip(("roll", "pitch", "yaw"), map(float, mx.mean(0)),
                                              strict=True)),
                "max_abs_error_deg_worst": dict(zip(("roll", "pitch", "yaw"),
                                                    map(float, mx.max(0)), strict=True)),
                "rms_deg_worst": float(np.max(rms)),
                "within_paper_bound_fraction": float(np.mean(
                    (mx[:, 0] <= 5) & (mx[:, 1] <= 5) & (mx[:, 2] <= 10))),
                "params": params}, np.mean(amp, 0)

    dg_p, _ = _tune(tune_sl, "qcf", {"kp_rad_s": SUN_LOSS_GRID["kp"],
                                     "ki_rad_s2": SUN_LOSS_GRID["ki"]},
                    fixed={"sun_substitute": "delayed-gyro", "delay_samples": 500,
                           "kp_single_rad_s": 0.0, "ki_single_rad_s2": 0.0})
    dg_sl, _ = sun_loss_stats("qcf", dg_p)
    dg_sl["method"] = "qcf with the delayed field pair carried to t by the raw gyro (spec)"
    paper_sl, amp = sun_loss_stats("qcf", pap_p)
    improved_sl, _ = sun_loss_stats("mekf", mekf_p)
    improved_sl["method"] = ("mekf-delayed: magnetometer + gyro MEKF (bias from the turning "
                             "field) plus the paper's delayed pair weighted by the estimated "
                             "swing over M samples")
    mag_only_sl, _ = sun_loss_stats("mekf", mag_only_p)
    mag_only_sl["method"] = "mekf-delayed with the magnetometer pair alone"
    paper_sl["method"] = "qcf with S = B delayed by M = 500 samples (paper)"
    # how the paper's bound depends on the satellite's swing (unknown in the paper): the
    # paper's method and the hybrid MEKF retuned at each amplitude on the tuning seeds
    # (``improved_preset_gains``: the MEKF with the gains tuned on the preset)
    say("sun loss vs amplitude")
    sweep = []
    for scale in ([0.0] if quick else MOTION_SCALES):
        t_cases = [_Case(simulate_seed(sd, duration, motion_scale=scale), sun_lost=True)
                   for sd in tune_seeds]
        r_cases = [_Case(simulate_seed(sd, duration, motion_scale=scale), sun_lost=True)
                   for sd in report_seeds[:8]]
        p_s, _ = _tune(t_cases, "qcf", {"kp_rad_s": SUN_LOSS_GRID["kp"],
                                        "ki_rad_s2": SUN_LOSS_GRID["ki"]},
                       fixed={"sun_substitute": "delayed", "delay_samples": 500,
                              "kp_single_rad_s": 0.0, "ki_single_rad_s2": 0.0})
        h_s, _ = _tune(t_cases, "mekf", HYBRID_GRID,
                       fixed={"sun_substitute": "delayed", "delay_samples": 500})
        row = {"motion_scale": scale, "runs": len(r_cases)}
        for label, kind, params in (("paper", "qcf", p_s), ("improved", "mekf", h_s),
                                    ("improved_preset_gains", "mekf", mekf_p),
                                    ("mekf_mag_only", "mekf", mag_only_p)):
            st, amp_s = sun_loss_stats(kind, params, r_cases)
            row[label] = {k: st[k] for k in ("rms_deg", "max_abs_error_deg",
                                             "max_abs_error_deg_worst",
                                             "within_paper_bound_fraction")}
            row[label]["params"] = params
        row["true_attitude_amplitude_deg"] = dict(zip(("roll", "pitch", "yaw"),
                                                      map(float, amp_s), strict=True))
        sweep.append(row)
    sun_loss = {"paper": paper_sl, "improved": improved_sl, "delayed_gyro": dg_sl,
                "mekf_mag_only": mag_only_sl,
                "amplitude_sweep": sweep,
                "true_attitude_amplitude_deg": dict(zip(("roll", "pitch", "yaw"),
                                                        map(float, amp), strict=True)),
                "outage": "sun_valid false for the whole run (drift step inside)"}

    result = {"paper": "000", "quick": quick, "tuned": tuned, "same_gain": same_gain,
              "sun_loss": sun_loss, "solvers": solvers,
              "speed_samples_per_s": {k: float(v) for k, v in benchmark_speed(
                  report[0].rec, 200_000 if quick else 1_000_000).items()},
              "speed_in_run_samples_per_s": {k: float(n_samples / v)
                                             for k, v in t_kernel.items()},
              "convergence_excluded_s": CONVERGE_S,
              "elapsed_s": float(time.time() - t_start)}
    if out_dir is not None:
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        say("figures")
        _figures(out_dir, report[0], ecf_p, qcf_p, sg[0], report_sl[0], pap_p, mekf_p)
        (out_dir / "metrics.json").write_text(json.dumps(result, indent=2, default=float))
    say("done")
    return result


def _figures(out_dir, case, ecf_p, qcf_p, sg_case, sl_case, pap_p, mekf_p):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = ("roll", "pitch", "yaw")
    t_orb = case.rec.extra["time_orbits"]
    # 1. tuned filters over time with the drift step
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    for kind, params, col in (("ecf", ecf_p, "C0"), ("qcf", qcf_p, "C3")):
        err = np.degrees(axis_errors_rad(case.rec.q_true, case.run(kind, **params)))
        for k in range(3):
            lab = f"{kind.upper()} Kp={params['kp_rad_s']:g} Ki={params['ki_rad_s2']:g}"
            axes[k].plot(t_orb, err[:, k], col, lw=0.7, label=lab)
    for k in range(3):
        axes[k].axvline(np.interp(case.t_step, case.rec.t, t_orb), color="k", ls="--", lw=0.8)
        axes[k].set_ylabel(f"{names[k]} error (deg)")
        axes[k].set_ylim(-1.5, 1.5)
    axes[0].legend(fontsize=8)
    axes[0].set_title("Seed 000, tuned filters: attitude errors (dashed: gyro drift step)")
    axes[-1].set_xlabel("time (orbits)")
    fig.tight_layout()
    fig.savefig(out_dir / "p000_tuned_errors.png", dpi=110)
    plt.close(fig)

    # 2. same gain: errors about b, s, c
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    t2 = sg_case.rec.extra["time_orbits"]
    for kind, col in (("ecf", "C0"), ("qcf", "C3")):
        q = sg_case.run(kind, kp_rad_s=SAME_GAIN["kp"], ki_rad_s2=SAME_GAIN["ki"])
        err = np.degrees(axis_errors_bsc_rad(sg_case.rec, q))
        for k, lab in enumerate(("b (field)", "s⊥ (sun)", "c = b × s")):
            axes[k].plot(t2, err[:, k], col, lw=0.5, label=kind.upper())
            axes[k].set_ylabel(f"about {lab} (deg)")
    axes[0].legend(fontsize=8)
    axes[0].set_title(f"Same gain Kp={SAME_GAIN['kp']}, Ki={SAME_GAIN['ki']}, mag noise "
                      f"{SAME_GAIN['mag_noise_nT']:g} nT: ECF gain Kp(I+ccᵀ) vs QCF Kp/2")
    axes[-1].set_xlabel("time (orbits)")
    fig.tight_layout()
    fig.savefig(out_dir / "p000_same_gain_axes.png", dpi=110)
    plt.close(fig)

    # 3. sun loss
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    t3 = sl_case.rec.extra["time_orbits"]
    for kind, params, col, lab in (("qcf", pap_p, "C1", "paper: delayed field M=500"),
                                   ("mekf", mekf_p, "C2",
                                    "gnomon: MEKF, mag + swing-weighted delayed pair")):
        err = np.degrees(axis_errors_rad(sl_case.rec.q_true, sl_case.run(kind, **params)))
        for k in range(3):
            axes[k].plot(t3, err[:, k], col, lw=0.7, label=lab)
    for k, bound in enumerate((5, 5, 10)):
        axes[k].axhline(bound, color="k", ls=":", lw=0.8)
        axes[k].axhline(-bound, color="k", ls=":", lw=0.8)
        axes[k].axvline(np.interp(sl_case.t_step, sl_case.rec.t, t3), color="k", ls="--", lw=0.8)
        axes[k].set_ylabel(f"{names[k]} error (deg)")
    axes[0].legend(fontsize=8)
    axes[0].set_title("Sun sensor lost for the whole run (dotted: paper's bounds)")
    axes[-1].set_xlabel("time (orbits)")
    fig.tight_layout()
    fig.savefig(out_dir / "p000_sun_loss.png", dpi=110)
    plt.close(fig)
