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
* measured time per step and per update of the compiled batch kernel;
* the same comparison in C (``c_flight_code_cost``): both filters exported as flight code
  (``gnomon export c``), their measurement update timed (ns) and counted (operations) on
  this machine, beside the paper's 864/792 -> 243/207.

``run`` returns the issue's JSON contract (plus extra keys) and, with
``out_dir``, writes ``metrics.json`` and the figures ``p002_attitude.png``,
``p002_bias.png``, ``p002_cost_accuracy.png`` (and ``p002_c_cost.png`` when a C compiler
was there).
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
    say("C flight code: the measurement update timed and counted")
    res.update(c_flight_code_cost(quick))
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


def c_flight_code_cost(quick: bool = False) -> dict:
    """Seed 002 in C: ``eskf-r6`` and ``eskf-r3`` exported as flight code (``gnomon export
    c``, double precision), built with the strict flags, and their phases measured on the
    bundled BROAD excerpt (every row has both sensors: a full correction):
    ``gnomon_run --phases`` times them (ns, the fastest of many passes over up to 1024
    captured rows, each phase alone on the states the filter had there) and
    ``gnomon_count --phases`` counts their operations (the same source as C++ on a
    counting number type; ``gn_ops`` read around each call of a phase).

    Phases: ``gain`` (the Kalman gain alone, the paper's unit: counted; its time
    ``gain_loops`` is of the loop form, which the filter does not run for its full
    measurement), ``kalman_update`` (gain + Joseph covariance + ``dx``: the straight-line
    function the filter runs, the measurement update whose size r decides),
    ``measurement_update`` (the whole row after the prediction: gates, inclination,
    low-pass, measurement model, Kalman update, injection), ``predict``. Operations:
    ``mul`` = multiplications + divisions (the paper's M), ``add`` = additions and
    subtractions (its A). ``quick``: no whole-row ``--bench``. Without ``cc``, ``c++`` and
    ``make``: ``{"c_flight_code": {"skipped": why}}``."""
    import platform
    import shutil
    import subprocess
    import tempfile

    from gnomon.errors import InputError

    if shutil.which("cc") is None or shutil.which("make") is None or shutil.which("c++") is None:
        return {"c_flight_code": {"skipped": "no C and C++ compiler (cc, c++) or make on "
                                             "this machine: the C export was not measured"}}
    from gnomon.export import export_c
    from gnomon.export.cost import bench_recording, make
    from gnomon.io import write

    rec = bench_recording("imu")
    res: dict = {"recording": rec.source or "BROAD excerpt", "rows": len(rec),
                 "precision": "double", "machine": platform.machine(),
                 "compiler": subprocess.run(["cc", "--version"], capture_output=True,
                                            text=True).stdout.splitlines()[0]}
    try:
        with tempfile.TemporaryDirectory(prefix="gnomon-p002-c-") as tmp:
            csv = write(Path(tmp) / "rec.csv", rec)
            for r in (6, 3):
                out = Path(tmp) / f"eskf-r{r}"
                export_c(f"eskf-r{r}", out, "double")
                make(out)
                make(out, "count")
                ns = _run_c_json(out / "gnomon_run", csv, "--phases")
                ops = _run_c_json(out / "gnomon_count", csv, "--phases")["ops"]
                row = {"ns": ns["ns"], "updates": ns["updates"], "timed": ns["timed"],
                       "ops": {k: {"mul": round(v["mul"] + v["div"], 2), "add": v["add"],
                                   "total": v["total"]} for k, v in ops.items()}}
                if not quick:
                    bench = _run_c_json(out / "gnomon_run", csv, "--bench")
                    row["ns_per_row"] = bench["ns_per_update"]
                    row["state_bytes"] = bench["state_bytes"]
                res[f"r{r}"] = row
    except (InputError, OSError, KeyError, ValueError) as err:
        return {"c_flight_code": {"skipped": f"the C export failed: {err}"}}
    paper = {f"r{r}": paper_gain_operations(6, r) for r in (6, 3)}
    res["paper_gain"] = paper
    res["python_traced"] = {f"r{r}": {"gain": count_gain_operations(r),
                                      "kalman_update": count_update_operations(r)}
                            for r in (6, 3)}
    r6, r3 = res["r6"], res["r3"]
    res["ratio_r6_r3"] = {
        "paper_mul": paper["r6"]["mul"] / paper["r3"]["mul"],
        "paper_add": paper["r6"]["add"] / paper["r3"]["add"],
        **{f"{ph}_{kind}": r6["ops"][ph][kind] / r3["ops"][ph][kind]
           for ph in ("gain", "kalman_update", "measurement_update") for kind in ("mul", "add")},
        **{f"{ph}_ns": r6["ns"][ph] / r3["ns"][ph]
           for ph in ("kalman_update", "measurement_update")},
    }
    return {"c_flight_code": res}


def _run_c_json(exe: Path, csv: Path, *args: str) -> dict:
    """``exe ARGS < csv``'s JSON (gnomon_run, gnomon_count)."""
    import json
    import subprocess

    with open(csv) as fh:
        p = subprocess.run([str(exe), *args], stdin=fh, capture_output=True, text=True)
    if p.returncode != 0:
        raise ValueError(f"{exe.name} {' '.join(args)}: {p.stderr.strip()}")
    return json.loads(p.stdout)


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
    c = res.get("c_flight_code", {})
    if "r6" in c and "r3" in c:
        _figure_c_cost(out, c, plt)


def _figure_c_cost(out: Path, c: dict, plt) -> None:
    """``p002_c_cost.png``: the C flight code's measurement update, r = 6 against r = 3, in
    counted operations beside the paper's gain counts and in ns on this machine."""
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
    x = np.arange(2)
    groups = [("paper: gain M", [c["paper_gain"][k]["mul"] for k in ("r6", "r3")]),
              ("paper: gain A", [c["paper_gain"][k]["add"] for k in ("r6", "r3")])]
    for ph, label in (("gain", "gain"), ("kalman_update", "gain + Joseph"),
                      ("measurement_update", "whole correction")):
        groups.append((f"C: {label}, mul+div", [c[k]["ops"][ph]["mul"] for k in ("r6", "r3")]))
        groups.append((f"C: {label}, add", [c[k]["ops"][ph]["add"] for k in ("r6", "r3")]))
    w = 0.8 / len(groups)
    for i, (label, vals) in enumerate(groups):
        a1.bar(x + (i - len(groups) / 2 + 0.5) * w, vals, w, label=label,
               hatch="//" if label.startswith("paper") else None)
    a1.set_xticks(x, ["r = 6", "r = 3"])
    a1.set_ylabel("operations per update (counted)")
    a1.set_title("measurement update: operations")
    a1.legend(fontsize=7)
    a1.grid(alpha=0.3, axis="y")
    phases = [("kalman_update", "gain + Joseph"), ("measurement_update", "whole correction"),
              ("predict", "prediction (gyro)")]
    w = 0.8 / len(phases)
    for i, (ph, label) in enumerate(phases):
        vals = [c[k]["ns"][ph] for k in ("r6", "r3")]
        bars = a2.bar(x + (i - len(phases) / 2 + 0.5) * w, vals, w, label=label)
        a2.bar_label(bars, fmt="%.0f", fontsize=7)
    a2.set_xticks(x, ["r = 6", "r = 3"])
    a2.set_ylabel(f"ns per update ({c['machine']}, {c['precision']})")
    a2.set_title("measurement update: time (C flight code)")
    a2.legend(fontsize=7)
    a2.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    fig.savefig(out / "p002_c_cost.png", dpi=110)
    plt.close(fig)
