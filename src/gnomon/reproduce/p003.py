"""Reproduce seed 003: pitch of an aerial vehicle from a camera strip and gyros.

``run(out_dir=None, quick=False, progress=False) -> dict`` returns the issue's JSON
contract::

    {"paper": "003",
     "per_frame": {"max_error_deg", "conversion": {"atan", "linear", "resampled"}},
     "cases": [{"gyro", "strip_px", "scene", "mode", "duration_s", "max_pitch_error_deg",
                "rms_pitch_error_deg", "sins_max_pitch_error_deg", "autonomy_s"}, ...],
     "autonomy_formula": [{"strip_px", "gyro", "scene", "predicted_s", "simulated_s"}, ...],
     "methods": {"ssd", "ssd_subpixel", "phase_correlation", "ecc": {"rmse_px", "time_us"}}}

plus extra keys (``setup``, ``yaw_only_sweep``, ``targets``). Scenes: the real cube map
``meadow_cube.jpg`` seen at two headings and the real aerial photos ``aero1.jpg`` /
``aero3.jpg`` warped by rotation homographies (full run; quick: one of each kind,
60-s flights), and in the full run an ideal azimuth-invariant horizon as a best
case. Camera 640x480, 60° horizontal field of view, frames at 2 Hz, gyros at 100 Hz,
harmonic roll/pitch/yaw (4°, 5° about a 2° mean, 3°; periods 23, 37, 29 s).
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
import time

import numpy as np

from gnomon.report.values import display_path
from gnomon.vision.camera import PinholeCamera, rpy_dcm
from gnomon.vision.compare import compare_methods
from gnomon.vision.images import find_image, load_cube_faces, load_gray
from gnomon.vision.render import CubeMapScene, HorizonScene, PhotoScene
from gnomon.vision.sins import (
    GYRO_CLASSES,
    HarmonicFlight,
    autonomy_time_s,
    pitch_error_summary,
    run_flight,
)

PAPER_CASES = (("mems", 11, "open_loop"), ("medium", 5, "open_loop"), ("mems", 6, "open_loop"),
               ("mems", 11, "closed_loop"))
PAPER_CLAIMS_S = {("mems", 6): 30.0, ("medium", 5): 600.0, ("mems", 11): 600.0}
#: how each claim is stated: "about" 30 s, "longer than" 10 min
PAPER_CLAIM_KIND = {("mems", 6): "about", ("medium", 5): "longer_than", ("mems", 11): "longer_than"}


def paper_claims_implied_scale() -> list[dict]:
    """Camera scale ``C_px / A_hfov`` (px/rad) each of the paper's claims implies via formula (3).

    ``T = w A / (b_z C)`` gives ``C / A = w / (b_z T)``: equal to it for "about T",
    at most it for "longer than T". Inconsistent values mean the claims cannot all follow
    from formula (3) with one camera.
    """
    out = []
    for (gyro, w), T in PAPER_CLAIMS_S.items():
        bz = GYRO_CLASSES[gyro]["bias_rad_s"][2]
        kind = PAPER_CLAIM_KIND[(gyro, w)]
        out.append({"gyro": gyro, "strip_px": w, "claim_s": T, "claim": kind,
                    "implied_px_per_rad": w / (bz * T),
                    "relation": "=" if kind == "about" else "<="})
    return out


def make_camera() -> PinholeCamera:
    """The simulated camera: 640x480 px, 60° horizontal field of view, no distortion."""
    return PinholeCamera.from_fov(640, 480, math.radians(60.0))


def make_scene(name: str, camera: PinholeCamera, face_px: int = 1024):
    """Scene by name: ``meadow`` / ``meadow_<deg>`` (cube map at a heading), ``aero1``,
    ``aero3`` (photos as seen by ``camera`` at zero attitude) or ``horizon`` (ideal)."""
    if name.startswith("meadow"):
        heading = float(name.split("_")[1]) if "_" in name else 0.0
        return CubeMapScene(load_cube_faces(face_px), math.radians(heading), name)
    if name in ("aero1", "aero3"):
        return PhotoScene(load_gray(f"{name}.jpg"), camera, np.eye(3), name)
    if name == "horizon":
        return HorizonScene()
    raise ValueError(f"unknown scene {name!r}")


def offcentre_strip_bias(scene, cam: PinholeCamera, offsets_px=(0, 100, 200),
                         roll_error_deg: float = 1.0, n_frames: int = 12,
                         rng: np.random.Generator | None = None) -> list[dict]:
    """Mean visual pitch error when the de-roll is off by ``roll_error_deg``, for vertical
    strips ``offsets_px`` right of the principal point, beside the small-angle prediction
    ``atan(x·δφ/f)`` (a de-roll by too much, ``φ̂ = φ + δφ``, samples a right-hand strip
    ``x·δφ/f`` higher up: the pitch reads high)."""
    from gnomon.vision.render import SimulatedFrame
    from gnomon.vision.strip import StripMatcher

    rng = np.random.default_rng(0) if rng is None else rng
    r0 = np.array([0.0, math.radians(2.0), 0.0])
    ref = SimulatedFrame(scene, cam, rpy_dcm(*r0), 0.004, 1)
    truths = r0 + np.radians(rng.uniform(-3, 3, (n_frames, 3)))
    out = []
    for x in offsets_px:
        sm = StripMatcher(ref, r0, strip_px=11, column_offset_px=x)
        errs = []
        for i, tr in enumerate(truths):
            fr = SimulatedFrame(scene, cam, rpy_dcm(*tr), 0.004, 10 + i)
            p, _ = sm.pitch(fr, tr + np.array([math.radians(roll_error_deg), 0.0, 0.0]))
            errs.append(p - tr[1])
        dphi = math.radians(roll_error_deg)
        out.append({"offset_px": int(x), "roll_error_deg": roll_error_deg,
                    "mean_pitch_error_deg": float(np.degrees(np.mean(errs))),
                    "predicted_deg": float(np.degrees(np.arctan(x * dphi / cam.f_px)))})
    return out


def _progress_cb(progress, label):
    if not progress:
        return None
    state = {"t": time.time()}

    def cb(i, n):
        if i == n - 1 or time.time() - state["t"] > 5:
            state["t"] = time.time()
            print(f"  {label}: frame {i + 1}/{n}", flush=True)

    return cb


@dataclasses.dataclass(frozen=True)
class _Plan:
    """The camera, scenes, flight and length of one reproduction (``quick`` or full)."""

    quick: bool
    progress: bool
    t_start: float
    cam: PinholeCamera
    duration: float
    scenes: list
    flight: HarmonicFlight

    @classmethod
    def make(cls, quick: bool, progress: bool) -> _Plan:
        scenes = (["meadow", "aero1"] if quick
                  else ["meadow", "meadow_120", "aero1", "aero3", "horizon"])
        return cls(quick, progress, time.time(), make_camera(), 60.0 if quick else 600.0,
                   scenes, HarmonicFlight())

    @property
    def real_scenes(self) -> list:
        return [s for s in self.scenes if s != "horizon"]

    def log(self, msg: str) -> None:
        if self.progress:
            print(f"[p003 {time.time() - self.t_start:6.1f} s] {msg}", flush=True)


def run(out_dir: pathlib.Path | None = None, quick: bool = False, progress: bool = False) -> dict:
    """Run the seed-003 reproduction, experiment by experiment; see the module docstring
    for the returned dict."""
    plan = _Plan.make(quick, progress)
    cam = plan.cam
    per_frame, per_frame_runs = per_frame_pitch_conversions(plan)
    cases, formula, runs = the_papers_cases(plan)
    sweep = autonomy_vs_strip_width(plan)
    # why the strip stays at the principal-point column: residual roll -> pitch bias
    offc = offcentre_strip_bias(make_scene(plan.real_scenes[0], cam), cam,
                                offsets_px=(0, 100, 200), roll_error_deg=1.0,
                                n_frames=4 if quick else 12, rng=np.random.default_rng(9))
    methods, methods_aero = shift_estimators(plan)
    result = {
        "paper": "003",
        "per_frame": per_frame,
        "cases": cases,
        "autonomy_formula": formula,
        "methods": {k: {"rmse_px": v["rmse_px"], "time_us": v["time_us"],
                        **{kk: vv for kk, vv in v.items() if kk not in ("rmse_px", "time_us")}}
                    for k, v in methods.items()},
        "methods_aero1": methods_aero,
        "yaw_only_sweep": sweep,
        "paper_claims": paper_claims_implied_scale(),
        "offcentre_strip": offc,
        "camera_px_per_rad": cam.width / cam.hfov_rad,
        "targets": _targets(per_frame, cases, methods),
        "setup": _setup(plan),
    }
    result["setup"]["elapsed_s"] = time.time() - plan.t_start
    if out_dir is not None:
        out_dir = pathlib.Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        _figure_pitch(out_dir, runs, plan.scenes)
        _figure_pitch_errors(out_dir, runs, plan.scenes)
        _figure_conversions(out_dir, per_frame_runs)
        _figure_reference_frames(out_dir, runs, plan.scenes)
        _figure_autonomy(out_dir, sweep, formula)
        (out_dir / "metrics.json").write_text(json.dumps(_jsonable(result), indent=2))
    plan.log("done")
    return _jsonable(result)


def per_frame_pitch_conversions(plan: _Plan) -> tuple[dict, dict]:
    """Per frame: the true roll and yaw used for the de-rotation, the three conversions of
    the shift to a pitch (``per_frame``); also the runs (for the figure)."""
    pf_scenes = plan.real_scenes[:1] if plan.quick else plan.real_scenes[:2]
    conv_err = {"resampled": 0.0, "atan": 0.0, "linear": 0.0}
    per_frame_runs = {}
    for k, sname in enumerate(pf_scenes):
        plan.log(f"per-frame accuracy on {sname}")
        r = run_flight(make_scene(sname, plan.cam), plan.cam, "mems", 11, plan.duration,
                       "open_loop", flight=plan.flight,
                       conversions=("resampled", "atan", "linear"), derotation="truth",
                       rng=np.random.default_rng(100 + k),
                       progress=_progress_cb(plan.progress, sname))
        per_frame_runs[sname] = r
        for c in conv_err:
            e = np.degrees(np.abs(r["visual_pitch"][c] - r["truth"][:, 1]))
            conv_err[c] = max(conv_err[c], float(e.max()))
    return {"max_error_deg": conv_err["resampled"], "conversion": dict(conv_err)}, per_frame_runs


def the_papers_cases(plan: _Plan) -> tuple[list, list, dict]:
    """The paper's cases (MEMS gyros with 11 and 6 px strips, medium gyros with 5 px) open
    loop, and the loop closed, on every scene: ``cases``, the ``autonomy_formula`` rows of
    the open-loop cases (formula (3) beside the simulated autonomy) and the runs."""
    cases, formula, runs = [], [], {}
    for k, sname in enumerate(plan.scenes):
        scene = make_scene(sname, plan.cam)
        for j, (gyro, w, mode) in enumerate(PAPER_CASES):
            plan.log(f"{sname}: {gyro} gyros, {w} px strip, {mode}")
            r = run_flight(scene, plan.cam, gyro, w, plan.duration, mode, flight=plan.flight,
                           rng=np.random.default_rng(1000 * k + j),
                           progress=_progress_cb(plan.progress, f"{sname} {gyro} {w} {mode}"))
            runs[(sname, gyro, w, mode)] = r
            case = _case_row(r, sname, gyro, w, mode)
            if mode != "closed_loop":
                bz = GYRO_CLASSES[gyro]["bias_rad_s"][2]
                formula.append({"strip_px": w, "gyro": gyro, "scene": sname,
                                "predicted_s": autonomy_time_s(w, bz, plan.cam.hfov_rad,
                                                               plan.cam.width),
                                "simulated_s": case["autonomy_s"],
                                "paper_claim_s": PAPER_CLAIMS_S.get((gyro, w))})
            cases.append(case)
    return cases, formula, runs


def _case_row(r: dict, sname: str, gyro: str, w: int, mode: str) -> dict:
    """One case's row: pitch errors, autonomy, and the closed loop's roll/yaw errors,
    acceptance and bias estimate (or the open-loop SINS's final roll/yaw errors)."""
    mx, rms, smx, aut = pitch_error_summary(r)
    case = {"gyro": gyro, "strip_px": w, "scene": sname, "mode": mode,
            "duration_s": r["duration_s"], "max_pitch_error_deg": mx,
            "rms_pitch_error_deg": rms, "sins_max_pitch_error_deg": smx,
            "autonomy_s": aut, "real_scene": sname != "horizon",
            "accepted_fraction": float(np.mean(r["ok"])),
            "visual_available_fraction": float(np.mean(r["available"]))}
    if mode == "closed_loop":
        est, tru = r["estimate"], r["truth"]
        case["max_roll_error_deg"] = float(np.degrees(np.abs(est[:, 0] - tru[:, 0])).max())
        d_yaw = (est[:, 2] - tru[:, 2] + np.pi) % (2 * np.pi) - np.pi
        case["max_yaw_error_deg"] = float(np.degrees(np.abs(d_yaw)).max())
        case["accepted"] = dict(r["accepted"])
        case["bias_estimate_rad_s"] = [float(b) for b in r["bias_estimate"]]
    else:
        e_open = r["sins_open"] - r["truth"]
        case["sins_final_roll_error_deg"] = float(np.degrees(abs(e_open[-1, 0])))
        d_yaw = (e_open[-1, 2] + np.pi) % (2 * np.pi) - np.pi
        case["sins_final_yaw_error_deg"] = float(np.degrees(abs(d_yaw)))
    return case


def autonomy_vs_strip_width(plan: _Plan) -> list:
    """Formula (3) in isolation: the yaw-gyro bias only, the strip width swept; the
    simulated autonomy beside the predicted one (``yaw_only_sweep``)."""
    sweep = []
    widths = (5, 21) if plan.quick else (3, 5, 11, 21, 41)
    sweep_scenes = plan.real_scenes[:1] if plan.quick else [plan.real_scenes[0], "aero1"]
    bz = GYRO_CLASSES["mems"]["bias_rad_s"][2]
    for k, sname in enumerate(sweep_scenes):
        scene = make_scene(sname, plan.cam)
        for w in widths:
            plan.log(f"yaw-only sweep {sname} {w} px")
            r = run_flight(scene, plan.cam, "mems", w, 60.0 if plan.quick else 120.0,
                           "open_loop", flight=plan.flight, gyro_bias_rad_s=(0.0, 0.0, bz),
                           rng=np.random.default_rng(5000 + 10 * k + w))
            _, _, _, aut = pitch_error_summary(r)
            t = r["t"]
            yaw_err = np.degrees(np.abs(r["sins_open"][:, 2] - r["truth"][:, 2]))
            bad = np.nonzero(np.degrees(np.abs(r["visual_pitch"]["resampled"]
                                               - r["truth"][:, 1])) > 0.5)[0]
            sweep.append({"scene": sname, "strip_px": w, "yaw_bias_rad_s": bz,
                          "predicted_s": autonomy_time_s(w, bz, plan.cam.hfov_rad,
                                                         plan.cam.width),
                          "simulated_s": aut,
                          "yaw_error_at_failure_deg": float(yaw_err[bad[0]]) if bad.size
                          else None,
                          "duration_s": float(t[-1])})
    return sweep


def shift_estimators(plan: _Plan) -> tuple[dict, dict]:
    """What the project adds: the SSD strip shift (integer and sub-pixel) against OpenCV's
    phase correlation and ECC on the same frames, on the first real scene and on aero1."""
    plan.log("shift estimators (SSD strip vs OpenCV)")
    quick = plan.quick
    methods = compare_methods(make_scene(plan.real_scenes[0], plan.cam), plan.cam,
                              rpy_dcm(0.0, math.radians(2.0), 0.0),
                              n_trials=8 if quick else 40, rng=np.random.default_rng(7),
                              repeat=2 if quick else 3)
    methods_aero = compare_methods(make_scene("aero1", plan.cam), plan.cam, np.eye(3),
                                   n_trials=6 if quick else 40, rng=np.random.default_rng(8),
                                   repeat=1 if quick else 3)
    return methods, methods_aero


def _targets(per_frame: dict, cases: list, methods: dict) -> dict:
    closed_real = [c for c in cases if c["mode"] == "closed_loop" and c["real_scene"]]
    pc = methods["phase_correlation"]["time_us"]
    ss = methods["ssd_subpixel"]["time_us"]
    return {
        "per_frame_resampled_le_0.1deg": per_frame["max_error_deg"] <= 0.1,
        "closed_loop_mems_lt_0.5deg_scenes": sum(c["max_pitch_error_deg"] < 0.5
                                                 for c in closed_real),
        "ssd_subpixel_rmse_le_0.05px": methods["ssd_subpixel"]["rmse_px"] <= 0.05,
        "ssd_speedup_vs_phase_correlation": (pc / ss) if np.isfinite(pc) else None,
    }


def _setup(plan: _Plan) -> dict:
    cam, flight = plan.cam, plan.flight
    # where each image came from, without the machine's absolute prefix
    images = {n: {"path": display_path(find_image(n)[0]), "full_size": find_image(n)[1]}
              for n in ("meadow_cube.jpg", "aero1.jpg", "aero3.jpg")}
    return {"quick": plan.quick, "duration_s": plan.duration, "scenes": plan.scenes,
            "camera": {"width": cam.width, "height": cam.height,
                       "hfov_deg": math.degrees(cam.hfov_rad),
                       "vfov_deg": math.degrees(cam.vfov_rad), "f_px": cam.f_px},
            "frame_hz": 2.0, "gyro_hz": 100.0,
            "flight": {"mean_deg": [math.degrees(a) for a in flight.mean_rad],
                       "amp_deg": [math.degrees(a) for a in flight.amp_rad],
                       "period_s": list(flight.period_s)},
            "gyros": {k: {"bias_rad_s": list(v["bias_rad_s"]),
                          "noise_rad_s_sqrt_hz": v["noise_rad_s_sqrt_hz"]}
                      for k, v in GYRO_CLASSES.items()},
            "images": images, "elapsed_s": None}


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.bool_ | bool):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, float | np.floating):
        v = float(x)
        return v if math.isfinite(v) else None
    return x




# ------------------------------------------------------------------ figures
def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: pathlib.Path, dpi: int = 110) -> None:
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    _pyplot().close(fig)


def _figure_pitch(out_dir, runs, scenes) -> None:
    """Pitch: truth, SINS, visual open loop, closed loop (first scene and aero1)."""
    d = np.degrees
    shown = [s for s in scenes if s in ("meadow", "aero1")] or scenes[:1]
    fig, axes = _pyplot().subplots(len(shown), 1, figsize=(10, 3.6 * len(shown)),
                                   squeeze=False)
    for ax, s in zip(axes[:, 0], shown, strict=True):
        ro = runs[(s, "mems", 11, "open_loop")]
        rc = runs[(s, "mems", 11, "closed_loop")]
        t = ro["t"]
        ax.plot(t, d(ro["truth"][:, 1]), "k", lw=1.5, label="truth")
        ax.plot(t, d(ro["sins_open"][:, 1]), "C3", lw=1, label="SINS (MEMS gyros only)")
        ax.plot(t, d(ro["visual_pitch"]["resampled"]), "C1", lw=0.8,
                label="visual, open loop (11 px)")
        ax.plot(rc["t"], d(rc["estimate"][:, 1]), "C0--", lw=1, label="visual, closed loop")
        ax.set_ylim(-15, 20)
        ax.set_ylabel("pitch, deg")
        ax.set_title(f"scene {s}: pitch from SINS vs visual vs truth")
        ax.legend(loc="upper left", fontsize=8, ncol=2)
    axes[-1, 0].set_xlabel("time, s")
    _save(fig, out_dir / "pitch_sins_visual_truth.png")


def _figure_pitch_errors(out_dir, runs, scenes) -> None:
    """The pitch error of each of the paper's cases, per scene."""
    d = np.degrees
    fig, axes = _pyplot().subplots(len(scenes), 1, figsize=(10, 2.8 * len(scenes)),
                                   squeeze=False)
    for ax, s in zip(axes[:, 0], scenes, strict=True):
        for (gyro, w, mode), st in zip(PAPER_CASES, ("C3", "C2", "C1", "C0"), strict=True):
            r = runs[(s, gyro, w, mode)]
            p = r["estimate"][:, 1] if mode == "closed_loop" else r["visual_pitch"]["resampled"]
            e = np.abs(d(p - r["truth"][:, 1]))
            ax.semilogy(r["t"], np.maximum(e, 1e-4), color=st, lw=0.8,
                        label=f"{gyro}, {w} px, {mode.replace('_', ' ')}")
        ax.axhline(0.5, color="k", ls=":", lw=1)
        ax.set_ylabel("|pitch error|, deg")
        ax.set_title(f"scene {s}")
        ax.legend(fontsize=7, loc="lower right", ncol=2)
    axes[-1, 0].set_xlabel("time, s")
    _save(fig, out_dir / "pitch_error_cases.png")


def _figure_conversions(out_dir, per_frame_runs) -> None:
    """Per frame: the errors of the three conversions of the shift to a pitch."""
    d = np.degrees
    fig, ax = _pyplot().subplots(figsize=(7, 4))
    for s, r in per_frame_runs.items():
        dp = d(r["truth"][:, 1] - r["truth"][0, 1])
        for c, st in (("resampled", "C0."), ("atan", "C1."), ("linear", "C2.")):
            ax.plot(dp, d(r["visual_pitch"][c] - r["truth"][:, 1]), st, ms=2,
                    label=f"{c} ({s})")
    ax.set_xlabel("pitch relative to the reference frame, deg")
    ax.set_ylabel("visual pitch error, deg")
    ax.set_title("true roll/yaw de-rotation: pitch conversion errors")
    ax.legend(fontsize=7)
    _save(fig, out_dir / "pitch_conversion.png")


def _figure_reference_frames(out_dir, runs, scenes) -> None:
    """The reference frames with the strips and the roll ring."""
    fig, axes = _pyplot().subplots(1, len(scenes), figsize=(4.2 * len(scenes), 3.4),
                                   squeeze=False)
    for ax, s in zip(axes[0], scenes, strict=True):
        sm = runs[(s, "mems", 11, "closed_loop")]["matcher"]
        cam = sm.cam
        ax.imshow(sm.ref.image(), cmap="gray", vmin=0, vmax=1)
        half = 0.5 * (sm.w - 1)
        ax.axvspan(cam.cx - half, cam.cx + half, color="C1", alpha=0.5, lw=0)
        ax.axhspan(cam.cy - half, cam.cy + half, color="C0", alpha=0.4, lw=0)
        r0 = cam.f_px * np.tan(sm._kappa.mean())
        ph = np.linspace(0, 2 * np.pi, 200)
        ax.plot(cam.cx + r0 * np.cos(ph), cam.cy + r0 * np.sin(ph), "C2", lw=1)
        ax.set_title(f"{s}: reference frame", fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    _save(fig, out_dir / "reference_frames.png", dpi=90)


def _figure_autonomy(out_dir, sweep, formula) -> None:
    """Autonomy: formula (3) against the simulation."""
    fig, ax = _pyplot().subplots(figsize=(7, 4.5))
    for sc_name in sorted({e["scene"] for e in sweep}):
        ee = [e for e in sweep if e["scene"] == sc_name]
        ax.plot([e["strip_px"] for e in ee], [e["simulated_s"] for e in ee], "o-",
                label=f"simulated, yaw bias only ({sc_name})")
    if sweep:
        ws = np.array(sorted({e["strip_px"] for e in sweep}))
        ax.plot(ws, [autonomy_time_s(w, sweep[0]["yaw_bias_rad_s"], math.radians(60.0), 640)
                     for w in ws], "k--", label="formula (3): w·A/(b_z·C)")
    for e in formula:
        ax.plot(e["strip_px"], e["simulated_s"], "x", color="C3" if e["gyro"] == "mems" else "C2")
    ax.plot([], [], "x", color="C3", label="simulated, all biases, MEMS")
    ax.plot([], [], "x", color="C2", label="simulated, all biases, medium")
    ax.set_xlabel("strip width, px")
    ax.set_ylabel("time to first pitch error > 0.5°, s")
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    _save(fig, out_dir / "autonomy_formula.png")
