"""The self-contained HTML report of ``gnomon reproduce all --out DIR``.

``DIR/index.html`` is the front page: per paper the targets met, its first rows
and thumbnails of its figures, linking to the paper's page (``DIR/pNNN.html``); then
the benchmark tables and the speed table when their JSON is beside the report
(``DIR/benchmark-NAME.json`` from ``gnomon benchmark NAME --json``, ``DIR/bench.json``
from ``gnomon bench --json``; ``gnomon report DIR`` builds the pages again). Each paper's
page has the system in two sentences, the scenario's parameters (those the paper left
out marked as chosen, when the reproduction says so), a table "paper's reported value |
gnomon's value | target | met?", how targets the work found ill-posed are stated, every
figure the reproduction wrote into ``DIR/pNNN/`` and the full metrics JSON. Numbers are
shown to 4 (tables) or 6 (JSON) significant digits, paths without the machine's
absolute prefix (:mod:`gnomon.report.values`).

gnomon's values are read from the same result dictionaries the ``--json``
outputs print; nothing here is typed in except the papers' own reported
numbers (quoted from ``shared/spec``) and the targets of the issues.
"""

from __future__ import annotations

import html
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from gnomon.report.values import display_path, sig, text, tidy

__all__ = ["build_report", "rebuild_report", "CHECKS", "evaluate", "page"]


@dataclass(frozen=True)
class Check:
    label: str
    paper: str  # the paper's reported value, as the paper states it
    value: Callable[[dict], float]  # gnomon's value from the result dict
    target: str  # the target in words
    met: Callable[[dict], bool] | None = None  # None: reported, no target
    unit: str = "deg"


def _get(d: dict, *path):
    for key in path:
        d = d[key]
    return d


def _autonomy(r: dict, gyro: str, px: int):
    """Open-loop autonomy (s) of paper 003 over the real scenes, as "min-max" text."""
    v = [c["autonomy_s"] for c in r["cases"] if c["mode"] == "open_loop" and c["gyro"] == gyro
         and c["strip_px"] == px and c["scene"] != "horizon"]
    return f"{min(v):.4g}-{max(v):.4g}" if v else math.nan


def _ratio(a, b):
    return a / b if b else math.nan


def _c_ops(r: dict, phase: str) -> str:
    """Paper 002's C flight code: a phase's counted operations, r = 6 → r = 3, as
    "mul+div/add → mul+div/add" text."""
    c = r["c_flight_code"]
    return " → ".join(f"{c[k]['ops'][phase]['mul']:g}/{c[k]['ops'][phase]['add']:g}"
                      for k in ("r6", "r3"))


def _c_ops_are_traced(r: dict) -> bool:
    """The C's counted gain and update are the Python kernel's traced operations."""
    c = r["c_flight_code"]
    return all(c[k]["ops"][ph]["mul"] == c["python_traced"][k][ph]["mul_div"]
               and c[k]["ops"][ph]["add"] == c["python_traced"][k][ph]["add"]
               for k in ("r6", "r3") for ph in ("gain", "kalman_update"))


SUMMARY = {
    "000": "A microsatellite estimates its attitude from a magnetometer, a sun sensor and MEMS "
           "gyros with complementary filters: Mahony's explicit filter on vector pairs versus a "
           "filter driven by a quaternion measured by least squares (Gauss-Newton, QUEST...). "
           "The paper also replaces a lost sun sensor by the magnetometer delayed by M samples.",
    "001": "A microsatellite estimates body rate and attitude with an extended Kalman filter "
           "built on the rigid-body dynamics, from a magnetometer and a sun sensor only. The "
           "paper studies errors in the inertia, the field model and the sun sensor, and eclipse.",
    "002": "A strapdown AHRS (gyro, accelerometer, magnetometer) uses an error-state quaternion "
           "Kalman filter; the paper reduces the measurement vector from 6 to 3 components and "
           "claims the same information at lower cost, with full observability.",
    "003": "An aerial vehicle measures its pitch from a fixed camera: a narrow vertical strip of "
           "the current image is matched against a reference image by a one-parameter "
           "least-squares shift, correcting gyro-only attitude.",
    "004": "First- and second-order complementary filters fuse a gyro with an accelerometer; the "
           "paper computes the errors caused by a constant gyro drift and a long linear "
           "acceleration, and proposes compensating the acceleration from speed information.",
}

CHECKS: dict[str, list[Check]] = {
    "000": [
        Check("RMS error, explicit CF, same gain", "2.82", lambda r: _get(
            r, "same_gain", "ecf_rms_deg"), "reported"),
        Check("RMS error, quaternion CF, same gain", "1.05", lambda r: _get(
            r, "same_gain", "qcf_rms_deg"), "reported"),
        Check("ratio ECF / QCF, same gain", "2.69", lambda r: _get(
            r, "same_gain", "ratio_ecf_over_qcf"), ">= 2",
            lambda r: _get(r, "same_gain", "ratio_ecf_over_qcf") >= 2, ""),
        Check("ratio ECF / QCF, each tuned to its best", "—", lambda r: _get(
            r, "tuned", "ratio_ecf_over_qcf"), ">= 0.95",
            lambda r: _get(r, "tuned", "ratio_ecf_over_qcf") >= 0.95, ""),
        # restated (issue 21): the paper's claim holds at gains chosen for the step; at
        # the gains best over the whole run the ECF recovers faster (reported, no target)
        Check("QCF RMS after the drift step, gains chosen for the step (ECF's: "
              "next row)", "better", lambda r: _get(
                  r, "tuned", "drift_aware", "qcf", "drift_rms_deg"), "<= ECF's",
              lambda r: _get(r, "tuned", "drift_aware", "qcf", "drift_rms_deg")
              <= _get(r, "tuned", "drift_aware", "ecf", "drift_rms_deg")),
        Check("ECF RMS after the drift step, gains chosen for the step", "—", lambda r: _get(
            r, "tuned", "drift_aware", "ecf", "drift_rms_deg"), "reported"),
        Check("QCF / ECF RMS after the drift step, gains best over the whole run", "—",
              lambda r: _ratio(_get(r, "tuned", "drift_step", "qcf_rms_deg"),
                               _get(r, "tuned", "drift_step", "ecf_rms_deg")),
              "reported (the ECF recovers faster at these gains)", None, ""),
        Check("sun loss (M = 500): max roll error", "< 5", lambda r: _get(
            r, "sun_loss", "paper", "max_abs_error_deg", "roll"), "< 5",
            lambda r: _get(r, "sun_loss", "paper", "max_abs_error_deg", "roll") < 5),
        Check("sun loss (M = 500): max pitch error", "< 5", lambda r: _get(
            r, "sun_loss", "paper", "max_abs_error_deg", "pitch"), "< 5",
            lambda r: _get(r, "sun_loss", "paper", "max_abs_error_deg", "pitch") < 5),
        Check("sun loss (M = 500): max yaw error", "< 10", lambda r: _get(
            r, "sun_loss", "paper", "max_abs_error_deg", "yaw"), "< 10",
            lambda r: _get(r, "sun_loss", "paper", "max_abs_error_deg", "yaw") < 10),
        Check("sun loss: improved method RMS", "—", lambda r: _get(
            r, "sun_loss", "improved", "rms_deg"), "< paper's method",
            lambda r: _get(r, "sun_loss", "improved", "rms_deg")
            < _get(r, "sun_loss", "paper", "rms_deg")),
    ],
    "001": [
        Check("ideal case RMS", "0 to 0.5 (mean errors)", lambda r: _get(r, "ideal", "rms_deg"),
              "<= 0.5", lambda r: _get(r, "ideal", "rms_deg") <= 0.5),
        Check("inertia 10%: mean peak error", "hurts least", lambda r: _get(
            r, "sensitivity", "inertia", "10", "mean_peak_error_deg"), "< field and sun",
            lambda r: _get(r, "sensitivity", "inertia", "10", "mean_peak_error_deg") < min(
                _get(r, "sensitivity", "field_model", "10", "mean_peak_error_deg"),
                _get(r, "sensitivity", "sun_sensor", "10", "mean_peak_error_deg"))),
        Check("field model 10%: mean peak error", "up to 4", lambda r: _get(
            r, "sensitivity", "field_model", "10", "mean_peak_error_deg"), "reported"),
        Check("sun sensor 10%: mean peak error", "~1", lambda r: _get(
            r, "sensitivity", "sun_sensor", "10", "mean_peak_error_deg"), "reported"),
        Check("EKF eclipse peak / sunlit RMS", "degrades", lambda r: _ratio(
            _get(r, "eclipse", "ekf", "eclipse_max_deg"),
            _get(r, "eclipse", "ekf", "sunlit_rms_deg")), "> 5",
            lambda r: _get(r, "eclipse", "ekf", "eclipse_max_deg")
            > 5 * _get(r, "eclipse", "ekf", "sunlit_rms_deg"), ""),
        Check("MEKF eclipse peak (mean over seeds)", "—", lambda r: _get(
            r, "eclipse", "mekf", "eclipse_max_deg"), "<= 2",
            lambda r: _get(r, "eclipse", "mekf", "eclipse_max_deg") <= 2),
        Check("MEKF eclipse peak (worst seed)", "—", lambda r: _get(
            r, "eclipse", "mekf", "eclipse_max_worst_deg"), "<= 3",
            lambda r: _get(r, "eclipse", "mekf", "eclipse_max_worst_deg") <= 3),
        # restated (issue 21): the eclipse gap is the filters' own with the true field;
        # under a 10 % field error both carry the field-direction error (reported)
        Check("EKF / MEKF eclipse peak, exact field model", "—", lambda r: _ratio(
            _get(r, "eclipse", "ekf", "eclipse_max_deg"),
            _get(r, "eclipse", "mekf", "eclipse_max_deg")), ">= 2.5",
            lambda r: _get(r, "eclipse", "ekf", "eclipse_max_deg")
            >= 2.5 * _get(r, "eclipse", "mekf", "eclipse_max_deg"), ""),
        Check("EKF / MEKF eclipse peak, 10% field error", "—", lambda r: _ratio(
            _get(r, "eclipse", "ekf_field10", "eclipse_max_deg"),
            _get(r, "eclipse", "mekf_field10", "eclipse_max_deg")),
            "reported (both filters carry the field-direction error)", None, ""),
    ],
    "002": [
        Check("gain multiplications, r = 6", "864", lambda r: _get(r, "op_counts", "r6", "mul"),
              "= 864", lambda r: _get(r, "op_counts", "r6", "mul") == 864, ""),
        Check("gain additions, r = 6", "792", lambda r: _get(r, "op_counts", "r6", "add"),
              "= 792", lambda r: _get(r, "op_counts", "r6", "add") == 792, ""),
        Check("gain multiplications, r = 3", "243", lambda r: _get(r, "op_counts", "r3", "mul"),
              "= 243", lambda r: _get(r, "op_counts", "r3", "mul") == 243, ""),
        Check("gain additions, r = 3", "207", lambda r: _get(r, "op_counts", "r3", "add"),
              "= 207", lambda r: _get(r, "op_counts", "r3", "add") == 207, ""),
        Check("observability rank, r = 3", "6", lambda r: _get(r, "observability_rank", "r3"),
              "= 6", lambda r: _get(r, "observability_rank", "r3") == 6, ""),
        Check("attitude RMS r = 3 / r = 6", "same", lambda r: _ratio(
            _get(r, "accuracy", "r3", "attitude_rms_deg"),
            _get(r, "accuracy", "r6", "attitude_rms_deg")), "<= 1.10",
            lambda r: _get(r, "accuracy", "r3", "attitude_rms_deg")
            <= 1.1 * _get(r, "accuracy", "r6", "attitude_rms_deg"), ""),
        Check("update time r = 6 / r = 3", "3.6 (op counts)", lambda r: _ratio(
            _get(r, "time_per_update_ns", "r6"), _get(r, "time_per_update_ns", "r3")), ">= 1.8",
            lambda r: _get(r, "time_per_update_ns", "r6")
            >= 1.8 * _get(r, "time_per_update_ns", "r3"), ""),
        Check("step time r = 6 / r = 3", "—", lambda r: _ratio(
            _get(r, "time_per_step_ns", "r6"), _get(r, "time_per_step_ns", "r3")), ">= 1.4",
            lambda r: _get(r, "time_per_step_ns", "r6")
            >= 1.4 * _get(r, "time_per_step_ns", "r3"), ""),
        Check("C flight code: gain operations (mul+div/add, counted), r = 6 → r = 3",
              "864/792 → 243/207", lambda r: _c_ops(r, "gain"),
              "= the Python kernel's (traced)", _c_ops_are_traced, ""),
        Check("C flight code: measurement update operations (gain + Joseph), r = 6 → r = 3",
              "—", lambda r: _c_ops(r, "kalman_update"), "= the Python kernel's (traced)",
              _c_ops_are_traced, ""),
        Check("C flight code: measurement update time r = 6 / r = 3", "3.6 (op counts)",
              lambda r: _get(r, "c_flight_code", "ratio_r6_r3", "kalman_update_ns"), ">= 1.8",
              lambda r: _get(r, "c_flight_code", "ratio_r6_r3", "kalman_update_ns") >= 1.8, ""),
    ],
    "003": [
        Check("per-frame max pitch error (angle-resampled)", "—", lambda r: _get(
            r, "per_frame", "conversion", "resampled"), "<= 0.1",
            lambda r: _get(r, "per_frame", "conversion", "resampled") <= 0.1),
        Check("closed loop, MEMS gyros: real scenes kept within 0.5 deg for 600 s",
              "< 0.5 deg (promised)",
              lambda r: len({c["scene"] for c in r["cases"] if c["mode"] == "closed_loop"
                             and c["gyro"] == "mems" and c["scene"] != "horizon"
                             and c["max_pitch_error_deg"] < 0.5}),
              ">= 2 scenes",
              lambda r: len({c["scene"] for c in r["cases"] if c["mode"] == "closed_loop"
                             and c["gyro"] == "mems" and c["scene"] != "horizon"
                             and c["max_pitch_error_deg"] < 0.5}) >= 2, "scenes"),
        Check("closed loop, MEMS gyros: worst max pitch error on the real scenes", "< 0.5",
              lambda r: max(c["max_pitch_error_deg"] for c in r["cases"]
                            if c["mode"] == "closed_loop" and c["gyro"] == "mems"
                            and c["scene"] != "horizon"), "reported"),
        *[Check(f"open loop, {gyro} gyros, {px} px: autonomy on the real scenes (min-max)",
                claim, lambda r, gyro=gyro, px=px: _autonomy(r, gyro, px), "reported", None, "s")
          for gyro, px, claim in (("mems", 11, "> 600 s"), ("medium", 5, "> 600 s"),
                                  ("mems", 6, "about 30 s"))],
        Check("SSD + sub-pixel: shift RMSE", "—", lambda r: _get(
            r, "methods", "ssd_subpixel", "rmse_px"), "<= 0.05",
            lambda r: _get(r, "methods", "ssd_subpixel", "rmse_px") <= 0.05, "px"),
        Check("phase correlation time / SSD time", "—", lambda r: _ratio(
            _get(r, "methods", "phase_correlation", "time_us"),
            _get(r, "methods", "ssd_subpixel", "time_us")), ">= 10",
            lambda r: _get(r, "methods", "phase_correlation", "time_us")
            >= 10 * _get(r, "methods", "ssd_subpixel", "time_us"), ""),
    ],
    "004": [
        Check("T = 100 s: peak acceleration error", "2.87", lambda r: _get(
            r, "first_order", "T100", "peak_accel_error_deg"), "within 5% of analytic",
            lambda r: abs(_get(r, "first_order", "T100", "peak_accel_error_deg")
                          / _get(r, "first_order", "T100", "analytic_peak_accel_error_deg")
                          - 1) <= 0.05),
        Check("T = 100 s: drift error", "0.29", lambda r: _get(
            r, "first_order", "T100", "drift_error_deg"), "within 5% of analytic",
            lambda r: abs(_get(r, "first_order", "T100", "drift_error_deg")
                          / _get(r, "first_order", "T100", "analytic_drift_error_deg")
                          - 1) <= 0.05),
        Check("T = 200 s: peak acceleration error", "1.43", lambda r: _get(
            r, "first_order", "T200", "peak_accel_error_deg"), "within 5% of analytic",
            lambda r: abs(_get(r, "first_order", "T200", "peak_accel_error_deg")
                          / _get(r, "first_order", "T200", "analytic_peak_accel_error_deg")
                          - 1) <= 0.05),
        Check("T = 200 s: drift error", "0.57", lambda r: _get(
            r, "first_order", "T200", "drift_error_deg"), "within 5% of analytic",
            lambda r: abs(_get(r, "first_order", "T200", "drift_error_deg")
                          / _get(r, "first_order", "T200", "analytic_drift_error_deg")
                          - 1) <= 0.05),
        Check("second order: variant 1 vs 2 peak acceleration error", "variant 1 better",
              lambda r: _get(r, "second_order", "variant1", "peak_accel_error_deg"),
              "< variant 2",
              lambda r: _get(r, "second_order", "variant1", "peak_accel_error_deg")
              < _get(r, "second_order", "variant2", "peak_accel_error_deg")),
        Check("compensated peak acceleration error", "(next step)", lambda r: _get(
            r, "compensated", "peak_accel_error_deg"), "<= 20% of uncompensated (T = 100 s)",
            lambda r: _get(r, "compensated", "peak_accel_error_deg")
            <= 0.2 * _get(r, "first_order", "T100", "peak_accel_error_deg")),
    ],
}


def _notes_000(r: dict) -> str:
    d = r["tuned"]["drift_aware"]
    w = r["tuned"]["drift_step"]
    return ("The paper's \"quaternion filter no worse after the drift step\" holds at gains "
            "chosen for the step (within 5% of each filter's best overall RMS, the one with "
            f"the smallest RMS after the step): {d['qcf']['drift_rms_deg']:.3f}° against "
            f"{d['ecf']['drift_rms_deg']:.3f}°, the target above. At the gains best over the "
            "whole run the explicit filter recovers faster "
            f"({w['qcf_rms_deg']:.3f}° against {w['ecf_rms_deg']:.3f}°): its integral term "
            "acts with 2 K_I about c = b × s. The advantage at the step is a matter of gains, "
            "not of structure (docs/estimators/spacecraft-complementary.md).")


def _notes_001(r: dict) -> str:
    e = r["eclipse"]
    ratio = _ratio(e["ekf"]["eclipse_max_deg"], e["mekf"]["eclipse_max_deg"])
    ratio10 = _ratio(e["ekf_field10"]["eclipse_max_deg"], e["mekf_field10"]["eclipse_max_deg"])
    return ("The eclipse gap between the EKF and the MEKF is stated with the exact field "
            f"model: {e['ekf']['eclipse_max_deg']:.2f}° against "
            f"{e['mekf']['eclipse_max_deg']:.2f}°, a ratio of {ratio:.1f} (target >= 2.5). "
            "With a 10% field-model error both filters already carry a sunlit error from the "
            f"wrong field direction (EKF {e['ekf_field10']['sunlit_rms_deg']:.2f}° RMS, MEKF "
            f"{e['mekf_field10']['sunlit_rms_deg']:.2f}°); that floor sets both eclipse peaks "
            f"({e['ekf_field10']['eclipse_max_deg']:.2f}° and "
            f"{e['mekf_field10']['eclipse_max_deg']:.2f}°, a ratio of {ratio10:.1f}), so no "
            "eclipse strategy opens a 2.5x gap there: that ratio is reported, without a "
            "target.")


#: How targets the work found ill-posed are stated, with their numbers read from the result.
NOTES = {"000": _notes_000, "001": _notes_001}


def evaluate(paper: str, result: dict) -> list[dict]:
    """Rows of the paper's table: label, paper, value, target, met (True/False/None), unit."""
    rows = []
    for c in CHECKS.get(paper, []):
        try:
            value = c.value(result)
            value = value if isinstance(value, str) else float(value)
        except (KeyError, TypeError, ValueError, StopIteration, IndexError):
            value = math.nan
        met = None
        if c.met is not None:
            try:
                met = bool(c.met(result))
            except (KeyError, TypeError, ValueError, StopIteration, IndexError):
                met = None
        rows.append({"label": c.label, "paper": c.paper, "value": value, "target": c.target,
                     "met": met, "unit": c.unit})
    return rows


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,sans-serif;max-width:1100px;margin:2em auto;
padding:0 1em;color:#222} h1,h2{font-weight:600} table{border-collapse:collapse;margin:1em 0}
td,th{border:1px solid #ccc;padding:4px 8px;text-align:left} th{background:#f3f3f3}
.ok{color:#17702b;font-weight:600} .no{color:#b00020;font-weight:600} .na{color:#777}
img{max-width:100%;border:1px solid #ddd;margin:0.5em 0} pre{background:#f7f7f7;padding:1em;
overflow:auto;font-size:12px} nav a{margin-right:1em}
img.thumb{width:180px;margin:2px} code{font-size:12px;word-break:break-all} .strong{font-weight:700}
"""


# Reports a figure that failed to load on the browser console (the browser test reads it).
_IMAGE_CHECK = ("<script>window.addEventListener('load',()=>{for(const i of document.images)"
                "{if(!i.complete||i.naturalWidth===0)console.error('missing image: '+"
                "i.getAttribute('src'))}})</script>")


def page(title: str, body: str, home: str | None = "index.html") -> str:
    """A complete HTML page: the report's style, a link to ``home`` (None: no link) and
    the check that reports an image that failed to load on the browser console."""
    nav = f"<nav><a href='{html.escape(home)}'>gnomon report</a></nav>" if home else ""
    return (f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<link rel='icon' href='data:,'>"
            f"<title>{html.escape(title)}</title><style>{_CSS}</style></head>"
            f"<body>{nav}{body}{_IMAGE_CHECK}</body></html>")


def _fmt(v) -> str:
    if isinstance(v, str):
        return html.escape(v)
    return html.escape(sig(v, 4))


def _met(m) -> str:
    return {True: "<span class='ok'>yes</span>", False: "<span class='no'>no</span>"}.get(
        m, "<span class='na'>—</span>")


def _params_table(params: dict) -> str:
    rows = "".join(f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(text(v))}</td></tr>"
                   for k, v in params.items())
    return f"<table><tr><th>parameter</th><th>value</th></tr>{rows}</table>"


#: files beside the report whose tables the front page shows (``gnomon benchmark NAME
#: --json > DIR/benchmark-NAME.json``, ``gnomon bench --json > DIR/bench.json``)
BENCHMARK_GLOB = "benchmark-*.json"
SPEED_FILE = "bench.json"


def _read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _benchmark_tables(out_dir: Path) -> str:
    """The headline table of each ``benchmark-NAME.json`` beside the report: methods by
    mean total RMSE (deg), with heading and inclination."""
    parts = []
    for path in sorted(out_dir.glob(BENCHMARK_GLOB)):
        res = _read_json(path)
        if not isinstance(res, dict) or not isinstance(res.get("mean"), dict):
            continue
        name = path.stem.removeprefix("benchmark-")
        mean = res["mean"]
        methods = sorted(mean, key=lambda m: mean[m].get("total_deg", math.inf))
        trials = len({r.get("trial") for r in res.get("trials", [])})
        rows = "".join(
            f"<tr><td>{html.escape(m)}</td>"
            + "".join(f"<td>{_fmt(mean[m].get(k))}</td>"
                      for k in ("total_deg", "heading_deg", "inclination_deg")) + "</tr>"
            for m in methods)
        parts.append(f"<h3>{html.escape(name)} ({trials} trials)</h3><table><tr><th>method"
                     "</th><th>total</th><th>heading</th><th>inclination</th></tr>"
                     f"{rows}</table>")
    if not parts:
        return ("<h2>Benchmarks</h2><p class='na'>No benchmark result beside this report: "
                "<code>gnomon benchmark broad --data DIR --json &gt; "
                "REPORT/benchmark-broad.json</code> (likewise tyrex), then <code>gnomon "
                "report REPORT</code>.</p>")
    return ("<h2>Benchmarks</h2><p>Mean over trials of the RMSE (deg), best first.</p>"
            + "".join(parts))


def _speed_table(out_dir: Path) -> str:
    res = _read_json(out_dir / SPEED_FILE)
    if not isinstance(res, dict) or not isinstance(res.get("results"), dict):
        return ("<h2>Speed</h2><p class='na'>No speed result beside this report: "
                "<code>gnomon bench --json &gt; REPORT/bench.json</code>, then <code>gnomon "
                "report REPORT</code>.</p>")
    r = res["results"]
    names = sorted(r, key=lambda n: -r[n].get("samples_per_s", 0.0))
    rows = "".join(f"<tr><td>{html.escape(n)}</td>"
                   f"<td>{_fmt(r[n].get('samples_per_s', math.nan) / 1e6)}</td>"
                   f"<td>{_fmt(r[n].get('ratio_to_vqf_batch'))}</td></tr>" for n in names)
    return (f"<h2>Speed</h2><p>{_fmt(res.get('samples'))} samples, median of "
            f"{_fmt(res.get('repeats'))} repeats.</p><table><tr><th>method</th>"
            f"<th>M samples/s</th><th>ratio to vqf-batch</th></tr>{rows}</table>")


def _thumbnails(name: str, figs: list[Path], k: int = 2) -> str:
    return "".join(f"<a href='{name}.html'><img class='thumb' src='{html.escape(name)}/"
                   f"{html.escape(f.name)}' alt='{html.escape(f.stem)}'></a>" for f in figs[:k])


def build_report(out_dir: Path, results: dict, quick: bool = False) -> Path:
    """Write ``index.html`` and one page per paper into ``out_dir``; returns the index path.

    The front page shows, per paper, the targets met, the first rows of its table and
    thumbnails of its figures; then the tables of ``benchmark-NAME.json`` and
    ``bench.json`` found in ``out_dir`` (:data:`BENCHMARK_GLOB`, :data:`SPEED_FILE`).
    Numbers are shown to 4 significant digits; no absolute path of the machine appears."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    index_rows = []
    for paper, res in sorted(results.items()):
        name = f"p{paper}"
        fig_dir = out_dir / name
        body = [f"<h1>Paper {paper}</h1><p>{html.escape(SUMMARY.get(paper, ''))}</p>"]
        if quick:
            body.append("<p><em>Quick mode: shortened runs and fewer seeds (for CI); run "
                        "without --quick for the full reproduction.</em></p>")
        headline = ""
        if "error" in res:
            body.append(f"<h2>Failed</h2><pre>{html.escape(res['error'])}</pre>")
            met_count, total = 0, 0
        else:
            rows = evaluate(paper, res)
            met_count = sum(r["met"] is True for r in rows)
            total = sum(r["met"] is not None for r in rows)
            table = "".join(
                f"<tr><td>{html.escape(r['label'])}</td><td>{html.escape(r['paper'])}</td>"
                f"<td>{_fmt(r['value'])}</td><td>{html.escape(r['unit'])}</td>"
                f"<td>{html.escape(r['target'])}</td><td>{_met(r['met'])}</td></tr>"
                for r in rows)
            body.append("<h2>Paper vs gnomon</h2><table><tr><th>quantity</th>"
                        "<th>paper's reported value</th><th>gnomon's value</th><th>unit</th>"
                        f"<th>target</th><th>within target?</th></tr>{table}</table>")
            headline = "<br>".join(
                f"{html.escape(r['label'])}: <b>{_fmt(r['value'])}</b> "
                f"{html.escape(r['unit'])} {_met(r['met'])}"
                # the targets missed first, then those met
                for r in sorted((r for r in rows if r["met"] is not None),
                                key=lambda r: r["met"])[:3])
            if paper in NOTES:
                try:
                    body.append(f"<h2>How the targets are stated</h2><p>"
                                f"{html.escape(NOTES[paper](res))}</p>")
                except (KeyError, TypeError):
                    pass
            params = res.get("scenario") or res.get("parameters") or res.get("setup")
            if isinstance(params, dict) and params:
                body.append("<h2>Scenario</h2>" + _params_table(params))
        figs = sorted(fig_dir.glob("*.png")) if fig_dir.is_dir() else []
        if figs:
            body.append("<h2>Figures</h2>")
            for f in figs:
                rel = f"{name}/{f.name}"
                body.append(f"<figure><img src='{html.escape(rel)}' alt='{html.escape(f.stem)}'>"
                            f"<figcaption>{html.escape(f.stem.replace('_', ' '))}</figcaption>"
                            "</figure>")
        clean = tidy({k: v for k, v in res.items() if k != "traceback"})
        body.append("<h2>Metrics (the JSON of <code>gnomon reproduce "
                    f"{paper} --json</code>, to 6 significant digits)</h2><pre>"
                    f"{html.escape(json.dumps(clean, indent=2, default=str))}</pre>")
        (out_dir / f"{name}.html").write_text(page(f"gnomon: paper {paper}", "".join(body)))
        status = ("<span class='no'>failed</span>" if "error" in res else
                  f"<span class='{'ok' if met_count == total else 'no'}'>{met_count} of "
                  f"{total}</span> targets met")
        system = SUMMARY.get(paper, "").split(". ")[0].rstrip(".")   # its first sentence
        index_rows.append(f"<tr><td><a href='{name}.html'>paper {paper}</a></td>"
                          f"<td>{html.escape(system)}.</td>"
                          f"<td>{status}<br><small>{headline}</small></td>"
                          f"<td>{_thumbnails(name, figs)}</td></tr>")
    index = ("<h1>gnomon: the papers reproduced</h1>"
             + ("<p><em>Quick mode (CI): shortened runs.</em></p>" if quick else "")
             + "<h2>Papers</h2><table><tr><th>paper</th><th>system</th><th>targets</th>"
             "<th>figures</th></tr>" + "".join(index_rows) + "</table>"
             + _benchmark_tables(out_dir) + _speed_table(out_dir))
    path = out_dir / "index.html"
    path.write_text(page("gnomon report", index))
    return path


def rebuild_report(out_dir: Path) -> Path:
    """The report of a ``gnomon reproduce all --out DIR`` directory built again from its
    ``DIR/pNNN/metrics.json`` files (e.g. after adding benchmark results beside it);
    returns the index path. ``InputError`` when ``out_dir`` holds no reproduction."""
    from gnomon.errors import InputError

    out_dir = Path(out_dir)
    results = {}
    for path in sorted(out_dir.glob("p[0-9][0-9][0-9]/metrics.json")):
        res = _read_json(path)
        if isinstance(res, dict):
            results[path.parent.name[1:]] = res
    if not results:
        raise InputError("holds neither a campaign (campaign.json) nor a reproduction "
                         "(pNNN/metrics.json)", file=display_path(out_dir))
    quick = (out_dir / "index.html").is_file() and "Quick mode" in (
        out_dir / "index.html").read_text()
    return build_report(out_dir, results, quick=quick)
