"""Reproduce seed 002: full (r = 6) vs reduced (r = 3) measurement model of the AHRS error-state KF.

Bilous & Nesterenko, "Simplification of the measurement model in the algorithm
of a strapdown AHRS based on the quaternion Kalman filter". The paper's claims
and how they are checked here:

* operation counts of one gain computation, ``M = n²r + 2nr² + r³``,
  ``A = n²r + 2nr² - 2nr + r³`` (864/792 for r = 6, 243/207 for r = 3), next
  to the count of what gnomon's gain actually executes (traced);
* observability rank 6 of ``(F, D)`` for both models;
* "the same information at lower cost": both filters on identical simulated
  MEMS data (``gnomon.simulation.ahrs``), attitude and bias RMS, as a function
  of the accelerometer noise, and on the real BROAD trials;
* measured time per step and per update of the compiled batch kernel.

``run`` returns the issue's JSON contract (plus extra keys) and, with
``out_dir``, writes ``metrics.json`` and the figures ``p002_attitude.png``,
``p002_bias.png``, ``p002_cost_accuracy.png``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from gnomon.analysis.observability import observability
from gnomon.estimators.eskf import (
    EskfParams,
    EskfR3,
    EskfR6,
    continuous_matrix,
    count_gain_operations,
    count_update_operations,
    measurement_r3,
    measurement_r6,
    paper_gain_operations,
)
from gnomon.metrics import axis_errors_rad, broad_errors_rad, error_angle_rad, rms_deg
from gnomon.simulation.ahrs import AhrsSimParams, simulate_ahrs

__all__ = ["run", "SETTLE_S", "filter_params_for", "broad_directory", "load_broad_trials"]

#: convergence time excluded from the simulated RMS, s
SETTLE_S = 30.0


def filter_params_for(sim: AhrsSimParams, inclination_known: bool = True) -> dict:
    """Filter tuning matched to a simulation scenario (noise levels of the sensors it draws).

    ``inclination_known``: the paper's assumption (H and Z known); otherwise the
    filter estimates the inclination from the data (its default).
    """
    return {
        "gyro_noise": sim.gyro_noise, "bias_rw": max(sim.bias_rw, 1e-6),
        "accel_noise": max(sim.accel_noise, 1e-3) if sim.linear_accel_rms == 0
        else float(np.hypot(sim.accel_noise, sim.linear_accel_rms)),
        "mag_noise": sim.mag_noise_uT / sim.field_uT, "init_bias_std": 2 * sim.gyro_bias_std,
        "init_att_std": 0.1, "gravity": sim.gravity, "accel_gate": 0.0, "mag_gate": 0.0,
        "inclination_known": inclination_known, "accel_lowpass_tau": 0.0,
        "inclination": float(np.radians(sim.inclination_deg)),
    }


def _jsonable(d: dict) -> dict:
    """Scenario values for JSON: tuples as lists, infinities as the string 'inf'."""
    def conv(v):
        if isinstance(v, tuple | list):
            return [conv(x) for x in v]
        if isinstance(v, float) and not np.isfinite(v):
            return str(v)
        return v
    return {k: conv(v) for k, v in d.items()}


def _score_sim(rec, est) -> dict:
    m = rec.t >= SETTLE_S
    e = error_angle_rad(rec.q_true, est.q)
    db = est.signals["bias_rad_s"] - rec.extra["gyro_bias_rad_s"]
    return {"attitude_rms_deg": rms_deg(e, m),
            "bias_rms_deg_s": rms_deg(np.linalg.norm(db, axis=1), m)}


def _simulate_pair(sim: AhrsSimParams, seeds, inclination_known=True, **overrides):
    """RMS over seeds (root of the mean square) for both filters; also the last run.

    ``overrides``: filter parameters replacing those of ``filter_params_for``.
    """
    acc = {"r6": [], "r3": []}
    last = None
    for seed in seeds:
        rec = simulate_ahrs(sim, np.random.default_rng(seed))
        fp = {**filter_params_for(sim, inclination_known), **overrides}
        ests = {"r6": EskfR6(**fp).run(rec), "r3": EskfR3(**fp).run(rec)}
        for k, est in ests.items():
            acc[k].append(_score_sim(rec, est))
        last = (rec, ests)
    out = {}
    for k, runs in acc.items():
        out[k] = {key: float(np.sqrt(np.mean([r[key] ** 2 for r in runs])))
                  for key in ("attitude_rms_deg", "bias_rms_deg_s")}
    return out, last


# ---------------------------------------------------------------- observability
def observability_case(measurement: str, w_b=(0.2, -0.1, 0.3), inclination_deg=60.0,
                       rng: np.random.Generator | None = None, tol: float = 1e-9):
    """``observability(F, D)`` at a random attitude (ENU from body) with body rate ``w_b``
    (rad/s), field inclination ``inclination_deg`` and the normalised field."""
    from gnomon.rotation import quat_normalize

    rng = rng or np.random.default_rng(0)
    q = quat_normalize(rng.normal(size=4))
    inc = np.radians(inclination_deg)
    h, z = np.cos(inc), np.sin(inc)
    F = continuous_matrix(np.asarray(w_b, float))
    if measurement == "r6":
        _, D = measurement_r6(q, np.zeros(3), np.zeros(3), 9.81, h, z)
        D = D / np.array([9.81] * 3 + [1.0] * 3)[:, None]   # accel rows in units of g
    elif measurement == "r3":
        _, D = measurement_r3(q, np.zeros(3), np.zeros(3), 9.81, h, z)
    elif measurement == "accel":
        _, D = measurement_r6(q, np.zeros(3), np.zeros(3), 9.81, h, z)
        D = D[:3] / 9.81
    else:
        raise ValueError(measurement)
    return observability(F, D, tol=tol)


# ---------------------------------------------------------------- timing
def _time_kernel(n_steps: int, repeats: int = 5) -> dict:
    """Min-of-repeats ns per step of the batch kernel for predict-only, r6 and r3."""
    from gnomon.kernels import eskf as kern

    sim = AhrsSimParams(duration_s=60.0, rate_hz=100.0)
    rec = simulate_ahrs(sim, np.random.default_rng(1))
    reps = int(np.ceil(n_steps / len(rec)))
    inputs = kern.Inputs(
        np.ascontiguousarray(np.tile(rec.gyro, (reps, 1))[:n_steps]),
        np.ascontiguousarray(np.tile(rec.accel, (reps, 1))[:n_steps]),
        np.ascontiguousarray(np.tile(rec.mag / sim.field_uT, (reps, 1))[:n_steps]),
        np.full(n_steps, 1.0 / sim.rate_hz))
    out = kern.new_outputs(n_steps)
    tuning = EskfParams(gyro_noise=sim.gyro_noise, bias_rw=1e-5, accel_noise=sim.accel_noise,
                        mag_noise=0.006, gravity=9.81, dip_tau=30.0, accel_lowpass_tau=0.0,
                        accel_gate=1.0, mag_gate=0.3)
    coefs = {"predict": kern.coefficients(tuning, predict_only=True),
             "r6": kern.coefficients(tuning),
             "r3": kern.coefficients(tuning.replace(measurement="r3"))}
    best = {}
    for _ in range(repeats):
        for name, c in coefs.items():
            state = kern.new_state(rec.q_true[0], np.zeros(3), np.diag([1e-3] * 3 + [1e-4] * 3),
                                   -np.sin(np.radians(60.0)), 10.0)
            t0 = time.perf_counter()
            kern.run_batch(inputs, state, c, out)
            ns = (time.perf_counter() - t0) / n_steps * 1e9
            best[name] = min(best.get(name, np.inf), ns)
    return best


# ---------------------------------------------------------------- BROAD
def broad_directory() -> Path | None:
    """The full BROAD trials (:func:`gnomon.datasets.broad_dir`: ``$GNOMON_BROAD_DIR``,
    ``../shared/data/broad`` beside the repository or the fetched copy), else the BROAD
    excerpts shipped in the package data (``None`` when neither holds a trial)."""
    from gnomon.datasets import broad_dir, bundled

    for c in (broad_dir(), bundled("broad")):
        if c is not None and (any(c.glob("*.mat")) or any(c.glob("*.hdf5"))):
            return c
    return None


def _read_broad_private(path: Path):
    """Minimal BROAD reader (used only when ``gnomon.io.broad`` is not available)."""
    from gnomon.recording import Recording

    if path.suffix == ".mat":
        import scipy.io

        d = scipy.io.loadmat(path)
        fs = float(np.ravel(d["sampling_rate"])[0])

        def get(k):
            return np.asarray(d[k], float)
    else:
        import h5py

        f = h5py.File(path, "r")
        fs = float(np.ravel(f.attrs["sampling_rate"])[0])

        def get(k):
            return np.asarray(f[k], float)
    gyr = get("imu_gyr")
    q = get("opt_quat")
    q = np.where(np.all(np.isfinite(q), axis=1, keepdims=True), q, np.nan)
    return Recording(t=np.arange(len(gyr)) / fs, gyro=gyr, accel=get("imu_acc"),
                     mag=get("imu_mag"), mag_unit="uT", q_true=q,
                     mask=get("movement").ravel() > 0.5,
                     frames={"reference": "ENU", "body": "sensor"}, source=str(path))


def load_broad_trials(directory: Path) -> list:
    """Recordings of every BROAD trial in ``directory`` (``gnomon.io.broad`` if present)."""
    try:
        from gnomon.io.broad import broad_trials, read_broad
    except ImportError:
        files = sorted(p for p in Path(directory).iterdir() if p.suffix in (".mat", ".hdf5"))
        return [_read_broad_private(p) for p in files]
    return [read_broad(p) for p in broad_trials(directory)]


def _broad_scores(recs) -> dict:
    out = {}
    for key, cls in (("r6", EskfR6), ("r3", EskfR3)):
        vals = []
        for rec in recs:
            est = cls().run(rec)
            m = rec.score_mask
            vals.append(rms_deg(broad_errors_rad(rec.q_true[m], est.q[m])["total"]))
        out[key] = vals
    return out


# ---------------------------------------------------------------- run
def run(out_dir: Path | None = None, quick: bool = False, progress: bool = False) -> dict:
    """Run the seed-002 reproduction, claim by claim; returns the JSON-contract dict (see
    the module docstring).

    quick: fewer seeds / noise levels and a shorter timing run (< ~30 s).
    """
    def say(msg):
        if progress:
            print(f"[p002] {msg}", flush=True)

    seeds = range(2) if quick else range(6)
    duration = 90.0 if quick else 180.0
    say("operation counts")
    res: dict = {"paper": "002", "op_counts": operation_counts()}
    say("observability")
    res.update(observability_ranks())
    say("simulation: paper setting (accel noise 0.02 m/s², inclination known)")
    accuracy, (rec_fig, ests_fig) = accuracy_on_the_same_data(seeds, duration)
    res.update(accuracy)
    res["accel_noise_sweep"] = accuracy_vs_accel_noise(seeds, duration, quick, say)
    say("simulation with linear accelerations and a magnetic disturbance")
    res.update(accuracy_with_disturbances(seeds, duration))
    say("timing")
    res.update(time_per_step(quick))
    res.update(broad_real_data(say))
    if out_dir is not None:
        import json

        _figures(Path(out_dir), res, rec_fig, ests_fig)
        (Path(out_dir) / "metrics.json").write_text(json.dumps(res, indent=2, default=float))
    return res


def operation_counts() -> dict:
    """The paper's counts of one gain computation (``M``, ``A``) for r = 6 and r = 3, next
    to what gnomon's gain and whole update execute (traced)."""
    out = {}
    for r in (6, 3):
        paper = paper_gain_operations(6, r)
        impl = count_gain_operations(r)
        whole = count_update_operations(r)
        out[f"r{r}"] = {
            "mul": paper["mul"], "add": paper["add"],
            "mul_implemented": impl["mul_div"], "add_implemented": impl["add"],
            "div_implemented": impl["div"],
            "update_mul_implemented": whole["mul_div"],
            "update_add_implemented": whole["add"],
        }
    return out


def observability_ranks() -> dict:
    """Rank 6 of ``(F, D)`` for both models, and the degenerate cases (no rotation, the
    accelerometer alone, tan I → ∞ near the magnetic pole)."""
    return {
        "observability_rank": {k: observability_case(k).rank for k in ("r6", "r3")},
        "observability_condition": {k: observability_case(k).condition for k in ("r6", "r3")},
        "observability_degenerate": {
            "r3_no_rotation": observability_case("r3", w_b=(0, 0, 0)).rank,
            "accel_only_no_rotation": observability_case("accel", w_b=(0, 0, 0)).rank,
            "accel_only_rotating": observability_case("accel").rank,
            "r3_tanI_1e3_condition": observability_case("r3", inclination_deg=89.9427).condition,
            "r3_tanI_1e12_rank": observability_case("r3", inclination_deg=90 - 5.7e-11).rank,
        },
    }


def accuracy_on_the_same_data(seeds, duration: float) -> tuple[dict, tuple]:
    """The paper's "same information at lower cost": both filters on identical simulated MEMS
    data in the paper's setting (accelerometer noise 0.02 m/s², inclination known). Also the
    last run (for the figures)."""
    base = AhrsSimParams(duration_s=duration)
    acc, last = _simulate_pair(base, seeds)
    return {"accuracy": acc,
            "accuracy_setting": {"sim": _jsonable(base.__dict__), "seeds": list(seeds),
                                 "settle_s": SETTLE_S, "inclination_known": True}}, last


def accuracy_vs_accel_noise(seeds, duration: float, quick: bool, say) -> list:
    """Both filters as a function of the accelerometer noise, the inclination known (the
    paper's assumption) and estimated; the r3 / r6 ratio of the attitude RMS."""
    sweep = []
    for noise in ([0.02, 0.1, 0.5] if quick else [0.005, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0]):
        say(f"simulation: accel noise {noise} m/s²")
        sim = AhrsSimParams(duration_s=duration, accel_noise=noise)
        row = {"accel_noise_m_s2": noise}
        for known in (True, False):
            acc, _ = _simulate_pair(sim, seeds, inclination_known=known)
            tag = "known_I" if known else "estimated_I"
            row[tag] = acc
            row[f"ratio_r3_r6_{tag}"] = (acc["r3"]["attitude_rms_deg"]
                                         / acc["r6"]["attitude_rms_deg"])
        sweep.append(row)
    return sweep


def accuracy_with_disturbances(seeds, duration: float) -> dict:
    """Beyond the paper's assumptions: linear accelerations and a magnetic disturbance,
    the filters with their gates and low-pass (robust) and as in the paper."""
    dist = AhrsSimParams(duration_s=duration, linear_accel_rms=0.5, mag_disturbance_uT=5.0,
                         disturbance_window_s=(60.0, 80.0))
    robust = {"accel_gate": 1.0, "mag_gate": 0.1, "accel_lowpass_tau": 3.0}
    return {
        "accuracy_disturbed": _simulate_pair(dist, seeds, inclination_known=False,
                                             **robust)[0],
        "accuracy_disturbed_paper_filter": _simulate_pair(dist, seeds,
                                                          inclination_known=False)[0],
        "accuracy_disturbed_setting": {"sim": _jsonable(dist.__dict__), "filter": robust,
                                       "settle_s": SETTLE_S},
    }


def time_per_step(quick: bool) -> dict:
    """The measured time per step and per update of the compiled batch kernel (ns), and
    the reduced model's speed-up."""
    t = _time_kernel(200_000 if quick else 2_000_000, repeats=3 if quick else 7)
    return {
        "time_per_step_ns": {"r6": t["r6"], "r3": t["r3"]},
        "time_per_update_ns": {"r6": t["r6"] - t["predict"], "r3": t["r3"] - t["predict"]},
        "time_per_predict_ns": t["predict"],
        "speedup_r3": {"step": t["r6"] / t["r3"],
                       "update": (t["r6"] - t["predict"]) / (t["r3"] - t["predict"])},
    }


def broad_real_data(say) -> dict:
    """Both filters on the real BROAD trials (or the shipped excerpts): the mean total
    RMSE and each trial's."""
    d = broad_directory()
    if d is None:
        return {"broad_dev_mean_total_deg": {"r6": float("nan"), "r3": float("nan")},
                "broad_note": "no BROAD data found (gnomon datasets fetch broad)"}
    say(f"BROAD trials in {d}")
    recs = load_broad_trials(d)
    scores = _broad_scores(recs)
    return {"broad_dev_mean_total_deg": {k: float(np.mean(v)) for k, v in scores.items()},
            "broad_trials": {"dir": str(d), "n": len(recs),
                             "files": [Path(r.source).name for r in recs],
                             "total_deg": scores}}


def _figures(out: Path, res: dict, rec, ests) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    t = rec.t
    fig, axs = plt.subplots(3, 2, figsize=(11, 7), sharex=True)
    for col, key in enumerate(("r6", "r3")):
        e = np.degrees(axis_errors_rad(rec.q_true, ests[key].q))
        for i, name in enumerate(("roll", "pitch", "yaw")):
            axs[i, col].plot(t, e[:, i], lw=0.6)
            axs[i, col].set_ylim(-0.5, 0.5)
            axs[i, col].set_ylabel(f"{name} error, deg")
            axs[i, col].grid(alpha=0.3)
        axs[0, col].set_title(f"eskf-{key}: attitude error (estimate vs truth)")
        axs[2, col].set_xlabel("t, s")
    fig.tight_layout()
    fig.savefig(out / "p002_attitude.png", dpi=110)
    plt.close(fig)

    fig, axs = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    bt = np.degrees(rec.extra["gyro_bias_rad_s"])
    for i, ax in enumerate(axs):
        ax.plot(t, bt[:, i], "k", lw=1.5, label="truth")
        for key, style in (("r6", "-"), ("r3", "--")):
            ax.plot(t, np.degrees(ests[key].signals["bias_rad_s"][:, i]), style, lw=0.9,
                    label=f"eskf-{key}")
        ax.set_ylabel(f"bias {'xyz'[i]}, deg/s")
        ax.grid(alpha=0.3)
    axs[0].legend(loc="upper right")
    axs[0].set_title("gyro bias estimates vs truth (simulated MEMS)")
    axs[-1].set_xlabel("t, s")
    fig.tight_layout()
    fig.savefig(out / "p002_bias.png", dpi=110)
    plt.close(fig)

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
    ts = [res["time_per_step_ns"]["r6"], res["time_per_step_ns"]["r3"]]
    for row in res["accel_noise_sweep"]:
        acc = row["known_I"]
        a1.semilogy(ts, [acc["r6"]["attitude_rms_deg"], acc["r3"]["attitude_rms_deg"]], "-",
                    color="0.6", lw=0.8)
        a1.text(ts[1] + 3, acc["r3"]["attitude_rms_deg"], f"{row['accel_noise_m_s2']} m/s²",
                fontsize=7, va="center")
    for key, mk, i in (("r6", "o", 0), ("r3", "s", 1)):
        oc = res["op_counts"][key]
        a1.semilogy([ts[i]] * len(res["accel_noise_sweep"]),
                    [row["known_I"][key]["attitude_rms_deg"] for row in res["accel_noise_sweep"]],
                    mk, ms=7, label=f"eskf-{key}: gain {oc['mul']} mul (paper), "
                                    f"{oc['mul_implemented']} (implemented)")
    a1.set_xlabel("time per step (compiled batch), ns")
    a1.set_ylabel("attitude RMS after settling, deg")
    a1.set_title("cost vs accuracy (labels: accelerometer noise)")
    a1.legend(fontsize=8)
    a1.grid(alpha=0.3)
    sw = res["accel_noise_sweep"]
    x = [row["accel_noise_m_s2"] for row in sw]
    for tag, style in (("known_I", "-o"), ("estimated_I", "--s")):
        a2.semilogx(x, [row[f"ratio_r3_r6_{tag}"] for row in sw], style,
                    label=f"inclination {'known' if tag == 'known_I' else 'estimated'}")
    a2.axhline(1.1, color="r", lw=0.8, label="+10 %")
    a2.axhline(1.0, color="k", lw=0.5)
    a2.set_xticks(x, [f"{v:g}" for v in x])
    a2.minorticks_off()
    a2.set_xlabel("accelerometer noise, m/s² (per sample)")
    a2.set_ylabel("attitude RMS ratio r3 / r6")
    a2.set_title("reduced vs full model vs accelerometer noise")
    a2.legend(fontsize=8)
    a2.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "p002_cost_accuracy.png", dpi=110)
    plt.close(fig)
