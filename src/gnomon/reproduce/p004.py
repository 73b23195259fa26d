"""Reproduction of seed 004: first- vs second-order complementary filters under gyro drift
and long linear accelerations, and the paper's "next step" (acceleration compensation from a
speed sensor).

Scenario (the paper's numbers): a level vehicle, a forward acceleration ``a = g``
(``a/g = 1``) for ``τ = 5 s`` starting at ``t_on = 10 s``, a constant gyro drift
``ω_d = 5·10⁻⁵ rad/s`` from ``t = 0``; first-order filters with ``T = 100 s`` and
``200 s``; second-order variants with ``r₁, r₂`` from ``second_order_gains(1/100 s)``
(variant 1's ``1 − W`` has the −3 dB bandwidth of the ``T = 100 s`` filter, ζ = 1/√2; both
variants use the same ``r₁, r₂``, as in the paper's comparison of ``|1 − W|``).

Every filter gets the same data: one-axis filters the angle ``φ_a`` (``a/g`` in the
paper's linear model, ``arctan(a/g)`` for a real accelerometer) and the drift; the 3D
``tilt-cf`` filter the simulated IMU (``simulation.linear_accel``). Errors are measured
in three runs: acceleration only (peak error), drift only (steady error at the end of the
run, ``8·200 s`` after the start), and both (the sum, as in the paper's Figs. 3, 4, 7).

``run(out_dir=None, quick=False, progress=False) -> dict`` returns the issue's JSON
contract (plus extra keys) and writes ``metrics.json`` and PNG figures into ``out_dir``.
"""

from __future__ import annotations

import json
import math
import pathlib
import sys

import numpy as np

from gnomon.analysis import complementary as an
from gnomon.estimators import complementary as cf
from gnomon.metrics import broad_errors_rad
from gnomon.simulation import linear_accel as sim

__all__ = ["run", "CONFIG"]

CONFIG = {
    "a_over_g": 1.0,
    "tau_s": 5.0,
    "t_on_s": 10.0,
    "drift_rad_s": 5e-5,
    "T_s": (100.0, 200.0),
    "gravity_m_s2": sim.G0_M_S2,
    "fs_hz": 100.0,
    "fs_hz_quick": 20.0,
    "zeta": 1.0 / math.sqrt(2.0),
    # speed sensor of the compensated case: GNSS-speed-like
    "speed_rate_hz": 10.0,
    "speed_noise_m_s": 0.1,
    "speed_scale_error": 0.005,
    "seed": 4004,
}


def _deg(x) -> float:
    return float(np.degrees(x))


def _say(progress: bool, msg: str) -> None:
    if progress:
        print(f"[p004] {msg}", file=sys.stderr, flush=True)


def _pct(sim_v: float, ana_v: float) -> float:
    return float(abs(sim_v - ana_v) / abs(ana_v) * 100.0)


def run(out_dir: pathlib.Path | None = None, quick: bool = False, progress: bool = False) -> dict:
    """Run the seed-004 reproduction; see the module docstring. Returns the metrics dict."""
    c = CONFIG
    fs = c["fs_hz_quick"] if quick else c["fs_hz"]
    dt = 1.0 / fs
    g = c["gravity_m_s2"]
    A = c["a_over_g"]
    tau, t_on, wd = c["tau_s"], c["t_on_s"], c["drift_rad_s"]
    duration = t_on + 8.0 * max(c["T_s"])
    t = np.arange(0.0, duration + 0.5 * dt, dt)
    a = sim.pulse_profile(t, t_on, tau, A * g)
    zero = np.zeros_like(t)
    traces: dict = {"t": t}

    # ---------------------------------------------------------------- first order, one axis
    out: dict = {"paper": "004"}
    for model, key in (("linear", "first_order"), ("true", "first_order_true_geometry")):
        e_a = float(an.accel_tilt_error_rad(A, model))
        res = {}
        for T in c["T_s"]:
            _say(progress, f"first order, {model} model, T = {T:g} s")
            w_acc, phi_acc = sim.one_axis_inputs(a, 0.0, model, g)
            w_dr, _ = sim.one_axis_inputs(zero, wd, model, g)
            y_acc = cf.first_order_filter(w_acc, phi_acc, dt, T, phi0_rad=0.0)
            y_dr = cf.first_order_filter(w_dr, zero, dt, T, phi0_rad=0.0)
            y_sum = cf.first_order_filter(w_dr, phi_acc, dt, T, phi0_rad=0.0)
            peak = float(np.max(np.abs(y_acc)))
            drift = float(y_dr[-1])
            ana_peak = an.first_order_peak_accel_error(T, tau, e_a)
            ana_drift = an.first_order_steady_drift_error(T, wd)
            res[f"T{T:g}"] = {
                "peak_accel_error_deg": _deg(peak),
                "drift_error_deg": _deg(drift),
                "analytic_peak_accel_error_deg": _deg(ana_peak),
                "analytic_peak_accel_error_small_tau_deg": _deg(
                    an.first_order_peak_accel_error_small_tau(T, tau, e_a)),
                "analytic_drift_error_deg": _deg(ana_drift),
                "peak_sum_error_deg": _deg(np.max(np.abs(y_sum))),
                "peak_accel_error_rel_diff_pct": _pct(peak, ana_peak),
                "drift_error_rel_diff_pct": _pct(drift, ana_drift),
            }
            traces[(model, T)] = (y_dr, y_acc, y_sum,
                                  an.first_order_drift_error(t, T, wd),
                                  an.first_order_accel_error(t - t_on, T, tau, e_a))
        out[key] = res

    # ---------------------------------------------------------------- second order, one axis
    T1 = min(c["T_s"])
    gains = an.second_order_gains(1.0 / T1, c["zeta"])
    r1, r2 = gains.r1, gains.r2
    w_acc, phi_acc = sim.one_axis_inputs(a, 0.0, "linear", g)
    w_dr, _ = sim.one_axis_inputs(zero, wd, "linear", g)
    so = {}
    for v in an.VARIANTS:
        _say(progress, f"second order, variant {v}")
        y_acc = cf.second_order_filter(w_acc, phi_acc, dt, r1, r2, v, phi0_rad=0.0)
        y_dr = cf.second_order_filter(w_dr, zero, dt, r1, r2, v, phi0_rad=0.0)
        y_sum = cf.second_order_filter(w_dr, phi_acc, dt, r1, r2, v, phi0_rad=0.0)
        ana_peak, t_peak = an.second_order_peak_accel_error(r1, r2, v, tau, A)
        _, tf_1mw = an.second_order_tf(r1, r2, v)
        so[f"variant{v}"] = {
            "peak_accel_error_deg": _deg(np.max(np.abs(y_acc))),
            "steady_drift_error_deg": _deg(y_dr[-1]),
            "analytic_steady_drift_error_deg": _deg(
                an.second_order_steady_drift_error(r1, r2, v, wd)),
            "analytic_peak_accel_error_deg": _deg(ana_peak),
            "analytic_peak_time_after_onset_s": t_peak,
            "max_drift_error_deg": _deg(np.max(np.abs(y_dr))),
            "peak_sum_error_deg": _deg(np.max(np.abs(y_sum))),
            "bandwidth_1mW_rad_s": an.bandwidth_rad_s(tf_1mw),
        }
        traces[("so", v)] = (y_dr, y_acc, y_sum)
    # variant 2 with its own gains for the same -3 dB bandwidth of 1 - W
    g2 = an.second_order_gains(1.0 / T1, c["zeta"], variant=2)
    y2 = cf.second_order_filter(w_acc, phi_acc, dt, g2.r1, g2.r2, 2, phi0_rad=0.0)
    so["variant2_same_bandwidth"] = {
        "r1_1_s": g2.r1,
        "r2_1_s2": g2.r2,
        "peak_accel_error_deg": _deg(np.max(np.abs(y2))),
        "analytic_peak_accel_error_deg": _deg(
            an.second_order_peak_accel_error(g2.r1, g2.r2, 2, tau, A)[0]),
        "steady_drift_error_deg": _deg(
            cf.second_order_filter(w_dr, zero, dt, g2.r1, g2.r2, 2, phi0_rad=0.0)[-1]),
        "analytic_steady_drift_error_deg": _deg(
            an.second_order_steady_drift_error(g2.r1, g2.r2, 2, wd)),
    }
    so["r1_1_s"] = r1
    so["r2_1_s2"] = r2
    so["zeta"] = gains.zeta
    so["omega_n_rad_s"] = gains.omega_n_rad_s
    so["variant1_attenuates_accel_better"] = bool(
        so["variant1"]["peak_accel_error_deg"] < so["variant2"]["peak_accel_error_deg"]
        and so["variant1"]["peak_accel_error_deg"]
        < so["variant2_same_bandwidth"]["peak_accel_error_deg"])
    out["second_order"] = so

    # ---------------------------------------------------------------- 3D tilt filter
    _say(progress, "3D tilt-cf (true geometry)")
    bias = (0.0, -wd, 0.0)

    def incl(rec, **kw):
        kw = {"bias_gain_1_s2": 0.0, "accel_rejection_rel": 0.0, **kw}
        est = cf.TiltComplementaryFilter(time_constant_s=T1, init_samples=1, **kw).run(rec)
        return broad_errors_rad(rec.q_true, est.q)["inclination"]

    rec_acc = sim.vehicle_recording(t, a, gyro_bias_rad_s=(0.0, 0.0, 0.0), gravity_m_s2=g)
    rec_dr = sim.vehicle_recording(t, zero, gyro_bias_rad_s=bias, gravity_m_s2=g)
    rec_sum = sim.vehicle_recording(t, a, gyro_bias_rad_s=bias, gravity_m_s2=g)
    i_acc, i_dr, i_sum = incl(rec_acc), incl(rec_dr), incl(rec_sum)
    tg = out["first_order_true_geometry"][f"T{T1:g}"]
    out["tilt_cf_3d"] = {
        "T_s": T1,
        "peak_accel_error_deg": _deg(i_acc.max()),
        "drift_error_deg": _deg(i_dr[-1]),
        "peak_sum_error_deg": _deg(i_sum.max()),
        "analytic_peak_accel_error_deg": tg["analytic_peak_accel_error_deg"],
        "analytic_drift_error_deg": tg["analytic_drift_error_deg"],
    }
    # variant 2 in 3D: the same filter with a gyro-bias integral (r1 = 1/T, r2 from the gains)
    i_dr_b = incl(rec_dr, bias_gain_1_s2=r2)
    out["tilt_cf_3d"]["with_bias_integral"] = {
        "bias_gain_1_s2": r2,
        "drift_error_deg": _deg(i_dr_b[-1]),
        "max_drift_error_deg": _deg(i_dr_b.max()),
    }

    # ---------------------------------------------------------------- compensation
    _say(progress, "acceleration compensation from a speed sensor")
    rng = np.random.default_rng(c["seed"])
    spd = {"speed_rate_hz": c["speed_rate_hz"], "speed_noise_m_s": c["speed_noise_m_s"],
           "speed_scale_error": c["speed_scale_error"]}
    rec_c = sim.vehicle_recording(t, a, gyro_bias_rad_s=(0.0, 0.0, 0.0), gravity_m_s2=g,
                                  rng=rng, **spd)
    i_c = incl(rec_c, speed_compensation=True)
    rec_cs = sim.vehicle_recording(t, a, gyro_bias_rad_s=bias, gravity_m_s2=g, rng=rng, **spd)
    i_cs = incl(rec_cs, speed_compensation=True)
    comp = {
        "peak_accel_error_deg": _deg(i_c.max()),
        "uncompensated_peak_accel_error_deg": _deg(i_acc.max()),
        "removed_fraction": float(1.0 - i_c.max() / i_acc.max()),
        "peak_sum_error_deg": _deg(i_cs.max()),
        "T_s": T1,
        **spd,
    }

    # a general profile: accelerate, turn, brake (smooth edges), T = 100 s
    _say(progress, "general profile with a turn")
    tg_t = np.arange(0.0, 200.0, dt)
    a_gen = (sim.pulse_profile(tg_t, 10.0, 10.0, 3.0, edge_s=1.0)
             + sim.pulse_profile(tg_t, 70.0, 6.0, -5.0, edge_s=1.0))
    r_gen = sim.pulse_profile(tg_t, 40.0, 15.0, 0.2, edge_s=2.0)
    rec_g = sim.vehicle_recording(tg_t, a_gen, r_gen, gyro_bias_rad_s=(0.0, 0.0, 0.0),
                                  gravity_m_s2=g, rng=rng, **spd)
    i_g0, i_g1 = incl(rec_g), incl(rec_g, speed_compensation=True)
    comp["general_profile"] = {
        "uncompensated_peak_error_deg": _deg(i_g0.max()),
        "compensated_peak_error_deg": _deg(i_g1.max()),
        "removed_fraction": float(1.0 - i_g1.max() / i_g0.max()),
        "max_centripetal_m_s2": float(np.max(np.abs(rec_g.accel[:, 1]))),
    }
    out["compensated"] = comp

    # ---------------------------------------------------------------- targets
    fo = [out["first_order"][k] for k in out["first_order"]]
    out["targets"] = {
        "first_order_within_5pct": bool(all(
            r["peak_accel_error_rel_diff_pct"] < 5.0 and r["drift_error_rel_diff_pct"] < 5.0
            for r in fo)),
        "second_order_drift_matches_derivation": bool(all(
            abs(so[f"variant{v}"]["steady_drift_error_deg"]
                - so[f"variant{v}"]["analytic_steady_drift_error_deg"])
            < 0.01 * _deg(an.first_order_steady_drift_error(T1, wd)) for v in an.VARIANTS)),
        "variant1_attenuates_accel_better": so["variant1_attenuates_accel_better"],
        "compensation_removes_80pct": bool(comp["removed_fraction"] >= 0.8),
    }
    out["config"] = {**{k: (list(v) if isinstance(v, tuple) else v) for k, v in c.items()},
                     "quick": quick, "fs_used_hz": fs, "duration_s": duration}

    if out_dir is not None:
        out_dir = pathlib.Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        _say(progress, f"figures -> {out_dir}")
        _figures(out_dir, out, traces, (r1, r2), t_on,
                 {"acc": i_acc, "dr": i_dr, "sum": i_sum, "comp": i_c, "comp_sum": i_cs},
                 (tg_t, i_g0, i_g1))
        (out_dir / "metrics.json").write_text(json.dumps(out, indent=2) + "\n")
    return out


def _figures(out_dir, out, traces, gains, t_on, incl3d, general) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = traces["t"]
    deg = np.degrees
    # Figs. 3-4 of the paper: drift, acceleration and total error, T = 100 s and 200 s
    for T in out["config"]["T_s"]:
        fig, axes = plt.subplots(1, 2, figsize=(12, 4.2), sharey=True)
        for ax, model, title in ((axes[0], "linear", "linear model (a/g)"),
                                 (axes[1], "true", "true geometry (arctan a/g)")):
            y_dr, y_acc, y_sum, a_dr, a_acc = traces[(model, T)]
            ax.plot(t, deg(y_dr), "--", label="drift error (sim)")
            ax.plot(t, deg(y_acc), "-.", label="acceleration error (sim)")
            ax.plot(t, deg(y_sum), "-", label="sum (sim)")
            ax.plot(t, deg(a_dr), ":", color="k", lw=0.8, label="closed forms")
            ax.plot(t, deg(a_acc), ":", color="k", lw=0.8)
            ax.set_title(f"first order, T = {T:g} s, {title}")
            ax.set_xlabel("t (s)")
            ax.grid(alpha=0.3)
        axes[0].set_ylabel("error (deg)")
        axes[0].legend()
        fig.tight_layout()
        fig.savefig(out_dir / f"first_order_T{T:g}.png", dpi=110)
        plt.close(fig)

    # Fig. 7: second-order variants vs first order T = 100 s
    T1 = min(out["config"]["T_s"])
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    fo = traces[("linear", T1)]
    for i, name in enumerate(("drift error", "acceleration error", "sum")):
        ax = axes[i]
        ax.plot(t, deg(fo[i]), label=f"first order T = {T1:g} s")
        for v in (1, 2):
            ax.plot(t, deg(traces[("so", v)][i]), label=f"second order, variant {v}")
        ax.set_title(name)
        ax.set_xlabel("t (s)")
        ax.grid(alpha=0.3)
        if i == 1:
            ax.set_xlim(0, t_on + 6 * T1)
    axes[0].set_ylabel("error (deg)")
    axes[0].legend()
    fig.suptitle(f"r1 = {gains[0]:.4g} 1/s, r2 = {gains[1]:.4g} 1/s^2 (same bandwidth as "
                 f"T = {T1:g} s)")
    fig.tight_layout()
    fig.savefig(out_dir / "second_order.png", dpi=110)
    plt.close(fig)

    # Bode plots of W and 1 - W
    w = np.logspace(-4, 0, 400)
    tfs = {f"first order T = {T1:g} s": an.first_order_tf(T1)}
    for v in (1, 2):
        tfs[f"variant {v}"] = an.second_order_tf(*gains, v)
    fig, axes = plt.subplots(2, 2, figsize=(12, 7), sharex=True)
    for label, (W, W1) in tfs.items():
        for j, tf in enumerate((W, W1)):
            mag, ph = an.bode(tf, w)
            axes[0, j].semilogx(w, mag, label=label)
            axes[1, j].semilogx(w, ph, label=label)
    axes[0, 0].set_title("W(s) (gyro path)")
    axes[0, 1].set_title("1 - W(s) (accelerometer path)")
    axes[0, 0].set_ylabel("magnitude (dB)")
    axes[1, 0].set_ylabel("phase (deg)")
    for ax in axes.ravel():
        ax.grid(alpha=0.3, which="both")
    for ax in axes[1]:
        ax.set_xlabel("ω (rad/s)")
    axes[0, 1].axhline(-3.0, color="k", lw=0.6, ls=":")
    axes[0, 1].legend()
    fig.tight_layout()
    fig.savefig(out_dir / "bode.png", dpi=110)
    plt.close(fig)

    # compensated case (3D filter)
    tg_t, i_g0, i_g1 = general
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    ax = axes[0]
    ax.plot(t, deg(incl3d["acc"]), label="3D, uncompensated (accel only)")
    ax.plot(t, deg(incl3d["comp"]), label="3D, speed-compensated (accel only)")
    ax.plot(t, deg(incl3d["sum"]), "--", label="3D, uncompensated (accel + drift)")
    ax.plot(t, deg(incl3d["comp_sum"]), "--", label="3D, compensated (accel + drift)")
    ax.set_xlim(0, t_on + 6 * T1)
    ax.set_title(f"a/g = {out['config']['a_over_g']:g} for {out['config']['tau_s']:g} s, "
                 f"T = {T1:g} s")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("inclination error (deg)")
    ax.legend()
    ax.grid(alpha=0.3)
    ax = axes[1]
    ax.plot(tg_t, deg(i_g0), label="uncompensated")
    ax.plot(tg_t, deg(i_g1), label="speed-compensated")
    ax.set_title("general profile: accelerate, turn, brake")
    ax.set_xlabel("t (s)")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out_dir / "compensated.png", dpi=110)
    plt.close(fig)
