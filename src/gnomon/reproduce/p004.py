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

import dataclasses
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


@dataclasses.dataclass(frozen=True)
class _Setup:
    """The paper's disturbance at the sampling rate used: a pulse of acceleration ``a``
    (``A g`` for ``tau`` s from ``t_on``) and a constant gyro drift ``wd`` (rad/s)."""

    progress: bool
    fs: float
    dt: float
    g: float
    A: float
    tau: float
    t_on: float
    wd: float
    duration: float
    t: np.ndarray
    a: np.ndarray
    zero: np.ndarray

    @classmethod
    def make(cls, quick: bool, progress: bool) -> _Setup:
        c = CONFIG
        fs = c["fs_hz_quick"] if quick else c["fs_hz"]
        dt = 1.0 / fs
        g, A = c["gravity_m_s2"], c["a_over_g"]
        tau, t_on, wd = c["tau_s"], c["t_on_s"], c["drift_rad_s"]
        duration = t_on + 8.0 * max(c["T_s"])
        t = np.arange(0.0, duration + 0.5 * dt, dt)
        a = sim.pulse_profile(t, t_on, tau, A * g)
        return cls(progress, fs, dt, g, A, tau, t_on, wd, duration, t, a, np.zeros_like(t))

    @property
    def T1(self) -> float:
        """The shorter first-order time constant (s): the bandwidth of the comparisons."""
        return min(CONFIG["T_s"])

    def say(self, msg: str) -> None:
        _say(self.progress, msg)


def run(out_dir: pathlib.Path | None = None, quick: bool = False, progress: bool = False) -> dict:
    """Run the seed-004 reproduction, in the paper's order, then its "next step"; see the
    module docstring. Returns the metrics dict."""
    s = _Setup.make(quick, progress)
    traces: dict = {"t": s.t}
    out: dict = {"paper": "004"}
    out["first_order"] = first_order_filter(s, "linear", traces)
    out["first_order_true_geometry"] = first_order_filter(s, "true", traces)
    out["second_order"], gains = second_order_variants(s, traces)
    out["tilt_cf_3d"], incl3d = tilt_filter_in_3d(s, out["first_order_true_geometry"], gains)
    # one noise stream: the speed-compensated runs, then the general profile
    rng = np.random.default_rng(CONFIG["seed"])
    comp = acceleration_compensation(s, rng, incl3d)
    comp["general_profile"], general = general_profile_with_a_turn(s, rng)
    out["compensated"] = comp
    out["targets"] = _targets(out, s)
    out["config"] = {**{k: (list(v) if isinstance(v, tuple) else v) for k, v in CONFIG.items()},
                     "quick": quick, "fs_used_hz": s.fs, "duration_s": s.duration}
    if out_dir is not None:
        out_dir = pathlib.Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        s.say(f"figures -> {out_dir}")
        _figure_first_order(out_dir, out, traces)
        _figure_second_order(out_dir, traces, gains, s.t_on)
        _figure_bode(out_dir, gains, s.T1)
        _figure_compensated(out_dir, out, traces["t"], s.t_on, incl3d, general)
        (out_dir / "metrics.json").write_text(json.dumps(out, indent=2) + "\n")
    return out


def first_order_filter(s: _Setup, model: str, traces: dict) -> dict:
    """The paper's Figs. 3-4: the first-order filter, T = 100 s and 200 s, one axis, in
    the paper's linear model (``a/g``) or the true geometry (``arctan(a/g)``): peak
    acceleration error and drift error, simulated and analytic, and their sum."""
    e_a = float(an.accel_tilt_error_rad(s.A, model))
    res = {}
    for T in CONFIG["T_s"]:
        s.say(f"first order, {model} model, T = {T:g} s")
        w_acc, phi_acc = sim.one_axis_inputs(s.a, 0.0, model, s.g)
        w_dr, _ = sim.one_axis_inputs(s.zero, s.wd, model, s.g)
        y_acc = cf.first_order_filter(w_acc, phi_acc, s.dt, T, phi0_rad=0.0)
        y_dr = cf.first_order_filter(w_dr, s.zero, s.dt, T, phi0_rad=0.0)
        y_sum = cf.first_order_filter(w_dr, phi_acc, s.dt, T, phi0_rad=0.0)
        peak = float(np.max(np.abs(y_acc)))
        drift = float(y_dr[-1])
        ana_peak = an.first_order_peak_accel_error(T, s.tau, e_a)
        ana_drift = an.first_order_steady_drift_error(T, s.wd)
        res[f"T{T:g}"] = {
            "peak_accel_error_deg": _deg(peak),
            "drift_error_deg": _deg(drift),
            "analytic_peak_accel_error_deg": _deg(ana_peak),
            "analytic_peak_accel_error_small_tau_deg": _deg(
                an.first_order_peak_accel_error_small_tau(T, s.tau, e_a)),
            "analytic_drift_error_deg": _deg(ana_drift),
            "peak_sum_error_deg": _deg(np.max(np.abs(y_sum))),
            "peak_accel_error_rel_diff_pct": _pct(peak, ana_peak),
            "drift_error_rel_diff_pct": _pct(drift, ana_drift),
        }
        traces[(model, T)] = (y_dr, y_acc, y_sum,
                              an.first_order_drift_error(s.t, T, s.wd),
                              an.first_order_accel_error(s.t - s.t_on, T, s.tau, e_a))
    return res


def second_order_variants(s: _Setup, traces: dict) -> tuple[dict, tuple[float, float]]:
    """The paper's Fig. 7: both second-order variants with ``r₁, r₂`` of the T = 100 s
    bandwidth, on the same disturbance, against the closed forms; variant 2 also with its
    own gains for the same bandwidth of ``1 − W``. Also ``(r₁, r₂)``."""
    T1 = s.T1
    gains = an.second_order_gains(1.0 / T1, CONFIG["zeta"])
    r1, r2 = gains.r1, gains.r2
    w_acc, phi_acc = sim.one_axis_inputs(s.a, 0.0, "linear", s.g)
    w_dr, _ = sim.one_axis_inputs(s.zero, s.wd, "linear", s.g)
    so = {}
    for v in an.VARIANTS:
        s.say(f"second order, variant {v}")
        y_acc = cf.second_order_filter(w_acc, phi_acc, s.dt, r1, r2, v, phi0_rad=0.0)
        y_dr = cf.second_order_filter(w_dr, s.zero, s.dt, r1, r2, v, phi0_rad=0.0)
        y_sum = cf.second_order_filter(w_dr, phi_acc, s.dt, r1, r2, v, phi0_rad=0.0)
        ana_peak, t_peak = an.second_order_peak_accel_error(r1, r2, v, s.tau, s.A)
        _, tf_1mw = an.second_order_tf(r1, r2, v)
        so[f"variant{v}"] = {
            "peak_accel_error_deg": _deg(np.max(np.abs(y_acc))),
            "steady_drift_error_deg": _deg(y_dr[-1]),
            "analytic_steady_drift_error_deg": _deg(
                an.second_order_steady_drift_error(r1, r2, v, s.wd)),
            "analytic_peak_accel_error_deg": _deg(ana_peak),
            "analytic_peak_time_after_onset_s": t_peak,
            "max_drift_error_deg": _deg(np.max(np.abs(y_dr))),
            "peak_sum_error_deg": _deg(np.max(np.abs(y_sum))),
            "bandwidth_1mW_rad_s": an.bandwidth_rad_s(tf_1mw),
        }
        traces[("so", v)] = (y_dr, y_acc, y_sum)
    # variant 2 with its own gains for the same -3 dB bandwidth of 1 - W
    g2 = an.second_order_gains(1.0 / T1, CONFIG["zeta"], variant=2)
    y2 = cf.second_order_filter(w_acc, phi_acc, s.dt, g2.r1, g2.r2, 2, phi0_rad=0.0)
    so["variant2_same_bandwidth"] = {
        "r1_1_s": g2.r1,
        "r2_1_s2": g2.r2,
        "peak_accel_error_deg": _deg(np.max(np.abs(y2))),
        "analytic_peak_accel_error_deg": _deg(
            an.second_order_peak_accel_error(g2.r1, g2.r2, 2, s.tau, s.A)[0]),
        "steady_drift_error_deg": _deg(
            cf.second_order_filter(w_dr, s.zero, s.dt, g2.r1, g2.r2, 2, phi0_rad=0.0)[-1]),
        "analytic_steady_drift_error_deg": _deg(
            an.second_order_steady_drift_error(g2.r1, g2.r2, 2, s.wd)),
    }
    so["r1_1_s"] = r1
    so["r2_1_s2"] = r2
    so["zeta"] = gains.zeta
    so["omega_n_rad_s"] = gains.omega_n_rad_s
    so["variant1_attenuates_accel_better"] = bool(
        so["variant1"]["peak_accel_error_deg"] < so["variant2"]["peak_accel_error_deg"]
        and so["variant1"]["peak_accel_error_deg"]
        < so["variant2_same_bandwidth"]["peak_accel_error_deg"])
    return so, (r1, r2)


def _inclination_error(rec, **kw) -> np.ndarray:
    """Inclination error (rad) of ``tilt-cf`` with T = 100 s, no bias estimate and no
    acceleration rejection unless ``kw`` says otherwise."""
    kw = {"bias_gain_1_s2": 0.0, "accel_rejection_rel": 0.0, **kw}
    est = cf.TiltComplementaryFilter(time_constant_s=min(CONFIG["T_s"]), init_samples=1,
                                     **kw).run(rec)
    return broad_errors_rad(rec.q_true, est.q)["inclination"]


def tilt_filter_in_3d(s: _Setup, true_geometry: dict, gains) -> tuple[dict, dict]:
    """The filter in discrete time, in 3D (``tilt-cf`` on the simulated IMU, the true
    geometry): acceleration, drift and both, against the one-axis closed forms; variant 2
    in 3D (a gyro-bias integral). Also the inclination errors (for what follows)."""
    s.say("3D tilt-cf (true geometry)")
    T1 = s.T1
    bias = (0.0, -s.wd, 0.0)
    rec_acc = sim.vehicle_recording(s.t, s.a, gyro_bias_rad_s=(0.0, 0.0, 0.0), gravity_m_s2=s.g)
    rec_dr = sim.vehicle_recording(s.t, s.zero, gyro_bias_rad_s=bias, gravity_m_s2=s.g)
    rec_sum = sim.vehicle_recording(s.t, s.a, gyro_bias_rad_s=bias, gravity_m_s2=s.g)
    i_acc, i_dr, i_sum = (_inclination_error(rec_acc), _inclination_error(rec_dr),
                          _inclination_error(rec_sum))
    tg = true_geometry[f"T{T1:g}"]
    out = {
        "T_s": T1,
        "peak_accel_error_deg": _deg(i_acc.max()),
        "drift_error_deg": _deg(i_dr[-1]),
        "peak_sum_error_deg": _deg(i_sum.max()),
        "analytic_peak_accel_error_deg": tg["analytic_peak_accel_error_deg"],
        "analytic_drift_error_deg": tg["analytic_drift_error_deg"],
    }
    # variant 2 in 3D: the same filter with a gyro-bias integral (r1 = 1/T, r2 from the gains)
    r2 = gains[1]
    i_dr_b = _inclination_error(rec_dr, bias_gain_1_s2=r2)
    out["with_bias_integral"] = {
        "bias_gain_1_s2": r2,
        "drift_error_deg": _deg(i_dr_b[-1]),
        "max_drift_error_deg": _deg(i_dr_b.max()),
    }
    return out, {"acc": i_acc, "dr": i_dr, "sum": i_sum}


def _speed_sensor() -> dict:
    return {k: CONFIG[k] for k in ("speed_rate_hz", "speed_noise_m_s", "speed_scale_error")}


def acceleration_compensation(s: _Setup, rng: np.random.Generator, incl3d: dict) -> dict:
    """The paper's "next step": the acceleration compensated from a speed sensor, on the
    paper's disturbance without and with the drift (``compensated``); adds the
    inclination errors to ``incl3d`` (``comp``, ``comp_sum``)."""
    s.say("acceleration compensation from a speed sensor")
    spd = _speed_sensor()
    bias = (0.0, -s.wd, 0.0)
    rec_c = sim.vehicle_recording(s.t, s.a, gyro_bias_rad_s=(0.0, 0.0, 0.0), gravity_m_s2=s.g,
                                  rng=rng, **spd)
    i_c = _inclination_error(rec_c, speed_compensation=True)
    rec_cs = sim.vehicle_recording(s.t, s.a, gyro_bias_rad_s=bias, gravity_m_s2=s.g, rng=rng,
                                   **spd)
    i_cs = _inclination_error(rec_cs, speed_compensation=True)
    i_acc = incl3d["acc"]
    incl3d.update({"comp": i_c, "comp_sum": i_cs})
    return {
        "peak_accel_error_deg": _deg(i_c.max()),
        "uncompensated_peak_accel_error_deg": _deg(i_acc.max()),
        "removed_fraction": float(1.0 - i_c.max() / i_acc.max()),
        "peak_sum_error_deg": _deg(i_cs.max()),
        "T_s": s.T1,
        **spd,
    }


def general_profile_with_a_turn(s: _Setup, rng: np.random.Generator) -> tuple[dict, tuple]:
    """The compensation on a general profile: accelerate, turn, brake (smooth edges),
    T = 100 s. Also ``(t, uncompensated, compensated inclination error)``."""
    s.say("general profile with a turn")
    tg_t = np.arange(0.0, 200.0, s.dt)
    a_gen = (sim.pulse_profile(tg_t, 10.0, 10.0, 3.0, edge_s=1.0)
             + sim.pulse_profile(tg_t, 70.0, 6.0, -5.0, edge_s=1.0))
    r_gen = sim.pulse_profile(tg_t, 40.0, 15.0, 0.2, edge_s=2.0)
    rec_g = sim.vehicle_recording(tg_t, a_gen, r_gen, gyro_bias_rad_s=(0.0, 0.0, 0.0),
                                  gravity_m_s2=s.g, rng=rng, **_speed_sensor())
    i_g0, i_g1 = _inclination_error(rec_g), _inclination_error(rec_g, speed_compensation=True)
    return {
        "uncompensated_peak_error_deg": _deg(i_g0.max()),
        "compensated_peak_error_deg": _deg(i_g1.max()),
        "removed_fraction": float(1.0 - i_g1.max() / i_g0.max()),
        "max_centripetal_m_s2": float(np.max(np.abs(rec_g.accel[:, 1]))),
    }, (tg_t, i_g0, i_g1)


def _targets(out: dict, s: _Setup) -> dict:
    so, comp = out["second_order"], out["compensated"]
    fo = [out["first_order"][k] for k in out["first_order"]]
    return {
        "first_order_within_5pct": bool(all(
            r["peak_accel_error_rel_diff_pct"] < 5.0 and r["drift_error_rel_diff_pct"] < 5.0
            for r in fo)),
        "second_order_drift_matches_derivation": bool(all(
            abs(so[f"variant{v}"]["steady_drift_error_deg"]
                - so[f"variant{v}"]["analytic_steady_drift_error_deg"])
            < 0.01 * _deg(an.first_order_steady_drift_error(s.T1, s.wd)) for v in an.VARIANTS)),
        "variant1_attenuates_accel_better": so["variant1_attenuates_accel_better"],
        "compensation_removes_80pct": bool(comp["removed_fraction"] >= 0.8),
    }


# ------------------------------------------------------------------ figures
def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: pathlib.Path) -> None:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    _pyplot().close(fig)


def _figure_first_order(out_dir, out, traces) -> None:
    """Figs. 3-4 of the paper: drift, acceleration and total error, T = 100 s and 200 s."""
    t = traces["t"]
    deg = np.degrees
    for T in out["config"]["T_s"]:
        fig, axes = _pyplot().subplots(1, 2, figsize=(12, 4.2), sharey=True)
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
        _save(fig, out_dir / f"first_order_T{T:g}.png")


def _figure_second_order(out_dir, traces, gains, t_on) -> None:
    """Fig. 7: the second-order variants against the first order, T = 100 s."""
    t = traces["t"]
    deg = np.degrees
    T1 = min(CONFIG["T_s"])
    fig, axes = _pyplot().subplots(1, 3, figsize=(15, 4.2))
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
    _save(fig, out_dir / "second_order.png")


def _figure_bode(out_dir, gains, T1) -> None:
    """Bode plots of W and 1 - W: the first order and both second-order variants."""
    w = np.logspace(-4, 0, 400)
    tfs = {f"first order T = {T1:g} s": an.first_order_tf(T1)}
    for v in (1, 2):
        tfs[f"variant {v}"] = an.second_order_tf(*gains, v)
    fig, axes = _pyplot().subplots(2, 2, figsize=(12, 7), sharex=True)
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
    _save(fig, out_dir / "bode.png")


def _figure_compensated(out_dir, out, t, t_on, incl3d, general) -> None:
    """The compensated case (3D filter) and the general profile."""
    deg = np.degrees
    T1 = min(CONFIG["T_s"])
    tg_t, i_g0, i_g1 = general
    fig, axes = _pyplot().subplots(1, 2, figsize=(12, 4.2))
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
    _save(fig, out_dir / "compensated.png")
