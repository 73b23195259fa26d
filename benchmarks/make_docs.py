"""Regenerate the measured tables of the docs and the README from the commands themselves.

    python benchmarks/make_docs.py [--broad DIR] [--quick] [--speed]

Runs ``gnomon benchmark broad --json`` (the full BROAD trials when found, see
``gnomon.datasets.broad_dir``; the bundled excerpt otherwise),
``gnomon benchmark tyrex --json`` with ``--mag calibrated`` and ``--mag raw`` (when the
tyrex data set is found, ``gnomon.datasets.tyrex_dir``; the section is kept as it is
otherwise) and ``gnomon bench --json``, then writes ``docs/benchmarks.md`` and replaces the
speed and accuracy tables in ``README.md`` between the markers
``<!-- bench:start/end -->`` and ``<!-- broad:start/end -->``. Nothing in those
tables is typed by hand.

``tyrex_section(calibrated, raw, data_name)`` renders the smartphone section from the two
JSON results (between ``<!-- tyrex:start -->`` and ``<!-- tyrex:end -->``). The ESKF page
(``docs/estimators/eskf.md``) gets its results (``eskf-results``: BROAD per trial, tyrex
means) from the same runs and its tuning table (``eskf-tuning``) from
``docs/figures/defaults_tuning.json`` (``benchmarks/defaults_tuning.py``). With the tyrex
data set, ``docs/calibration.md`` gets its table (``calibration-tyrex``) from the same
benchmark with ``--mag raw --mag-calibration recording|self``. The spacecraft MEKF's
page (``docs/estimators/mekf.md``, ``mekf-targets``) gets its tables from
``benchmarks/mekf_targets.py`` (simulations, no data set).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def gnomon_json(*args: str) -> dict:
    out = subprocess.run([sys.executable, "-m", "gnomon.cli", *args, "--json"],
                         capture_output=True, text=True, check=True, cwd=ROOT)
    return json.loads(out.stdout)


def broad_tables(res: dict) -> str:
    methods = list(res["mean"])
    lines = ["| method | total (deg) | heading (deg) | inclination (deg) | trials |",
             "| --- | ---: | ---: | ---: | ---: |"]
    for m in sorted(methods, key=lambda m: res["mean"][m]["total_deg"]):
        v = res["mean"][m]
        lines.append(f"| {m} | {v['total_deg']:.3f} | {v['heading_deg']:.3f} | "
                     f"{v['inclination_deg']:.3f} | {v['trials']} |")
    trials = sorted({r["trial"] for r in res["trials"]})
    cell = {(r["trial"], r["method"]): r["total_deg"] for r in res["trials"]}
    lines += ["", "Per trial, total RMSE (deg):", "",
              "| trial | " + " | ".join(methods) + " |",
              "| --- |" + " ---: |" * len(methods)]
    for t in trials:
        lines.append(f"| {t} | " + " | ".join(
            f"{cell.get((t, m), float('nan')):.3f}" for m in methods) + " |")
    if res.get("groups"):
        groups = sorted({g for m in res["groups"] for g in res["groups"][m]})
        lines += ["", "Per BROAD group, mean total RMSE (deg):", "",
                  "| group | " + " | ".join(methods) + " |",
                  "| --- |" + " ---: |" * len(methods)]
        for g in groups:
            lines.append(f"| {g} | " + " | ".join(
                f"{res['groups'].get(m, {}).get(g, {}).get('total_deg', float('nan')):.3f}"
                for m in methods) + " |")
    return "\n".join(lines)


def readers_section() -> str:
    """The "Reading logs" section from the committed ``docs/figures/readers_speed.json``
    (``benchmarks/bench_readers.py`` measures it; too long to run here)."""
    path = ROOT / "docs" / "figures" / "readers_speed.json"
    if not path.exists():
        return ""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_readers import markdown_section

    return "\n" + markdown_section(json.loads(path.read_text()))


def _mean_table(res: dict) -> list[str]:
    lines = ["| method | total (deg) | heading (deg) | inclination (deg) | trials |",
             "| --- | ---: | ---: | ---: | ---: |"]
    for m in sorted(res["mean"], key=lambda m: res["mean"][m]["total_deg"]):
        v = res["mean"][m]
        lines.append(f"| {m} | {v['total_deg']:.2f} | {v['heading_deg']:.2f} | "
                     f"{v['inclination_deg']:.2f} | {v['trials']} |")
    return lines


def _group_table(res: dict, kind: str, key: str = "total_deg") -> list[str]:
    values = sorted({g.split(":", 1)[1] for m in res["groups"] for g in res["groups"][m]
                     if g.startswith(kind + ":")})
    methods = sorted(res["mean"], key=lambda m: res["mean"][m]["total_deg"])
    lines = [f"| method | {' | '.join(values)} |", "| --- |" + " ---: |" * len(values)]
    for m in methods:
        row = res["groups"].get(m, {})
        lines.append(f"| {m} | " + " | ".join(
            f"{row.get(f'{kind}:{v}', {}).get(key, float('nan')):.2f}" for v in values) + " |")
    return lines


def tyrex_section(cal: dict, raw: dict | None, data_name: str) -> str:
    """The "Smartphones (tyrex)" section from ``gnomon benchmark tyrex --json`` results
    (``--mag calibrated`` and, optionally, ``--mag raw``)."""
    n = len({r["trial"] for r in cal["trials"]})
    st = cal["alignment_stats"]

    def rng(d, scale="{:.1f}"):
        return (f"{scale.format(d['min'])} to {scale.format(d['max'])} (median "
                f"{scale.format(d['median'])})")

    lines = [
        "## Smartphones (tyrex)",
        "",
        "Michel, Genevès, Fourati, Layaïda, *Pervasive and Mobile Computing* 46, 2018 (the",
        "\"benchmarks-attitude-smartphones\" data set, CeCILL 2.1): one user, a Nexus 5 and an",
        f"iPhone 5, {n} trials of about 2 minutes (8 motions, with and without magnetic",
        "disturbance), optical motion capture as the truth. Run it:",
        "",
        "```bash",
        f"gnomon benchmark tyrex --data {data_name} [--mag calibrated|raw] "
        "[--align body,lag|lag|body|none] [--json] [--plot tyrex.png]",
        "gnomon benchmark DIR      # any folder of recordings that hold a truth",
        "```",
        "",
        "Every method runs on each phone's own sensor rates (gyro, accelerometer and",
        "magnetometer each at its own rate; no sample invented: see `gnomon.anchors`), with",
        "default parameters, from the trial's first sample; the metric is BROAD's (RMSE of",
        "the total, heading and inclination error per trial over 5-120 s of the capture's",
        "clock, mean over trials). The truth is the phone's attitude in ENU with y to",
        "**magnetic** north (the capture's true north turned by the declination,",
        f"{cal['truth']['declination_deg']:+.3f} deg): the north a magnetometer sees. No "
        "heading offset",
        "is removed from any method. `phone` is the phone's own estimate (Android rotation",
        "vector, iOS CoreMotion attitude). Names ending in `-offline` see the whole log",
        "(forward and backward passes; `gnomon estimate --offline`): compare them with",
        "`vqf-offline`, VQF's acausal variant, not with the causal filters.",
        "",
        "Two properties of the phones' data weigh on the iPhone 5 columns (`docs/logs.md`):",
        "its gyro is the raw one, with the bias in the table below (VQF's default bias",
        "estimate is clipped at 2 deg/s), and its OS-calibrated magnetometer keeps one",
        "magnitude between jumps, following CoreMotion's own heading: a model output more",
        "than a measurement. `--mag raw` is uncalibrated (hard iron of 300-430 µT) on both.",
        "",
        "**Alignment** (`--align`, default `body,lag`; `gnomon.metrics.align_truth`), fitted",
        "once per trial from the gyro against the truth's own angular rate and applied to the",
        "truth before any method is scored, identical for every method: `lag` shifts the",
        "truth in time by the lag that maximises the correlation of the two rate magnitudes",
        "(sub-sample), the residual of the data set's 10 ms clock alignment; `body` turns it",
        "by the constant rotation between the phone's sensor axes and its marker body (least",
        "squares on the rate vectors, gyro bias removed). Over the trials (rate RMS: the gyro",
        "against the truth's body rate, nothing corrected, then after the fit):",
        "",
        "| phone | lag (ms) | misalignment (deg) | gyro bias (deg/s) | rate RMS before "
        "(deg/s) | after |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for key, label in (("phone:Nexus5", "Nexus 5"), ("phone:iPhone5", "iPhone 5"),
                       ("all", "all")):
        if key in st:
            d = st[key]
            lines.append(f"| {label} | {rng(d['lag_ms'])} | "
                         f"{rng(d['misalignment_deg'], '{:.2f}')} | "
                         f"{rng(d['gyro_bias_deg_s'], '{:.2f}')} | "
                         f"{d['rate_rms_deg_s_before']['median']:.1f} (median) | "
                         f"{d['rate_rms_deg_s']['median']:.1f} (median) |")
    lines += ["", "### OS-calibrated magnetometer (`--mag calibrated`, the default)", ""]
    lines += _mean_table(cal)
    for kind, title in (("phone", "Per phone"), ("disturbance", "Per magnetic disturbance"),
                        ("motion", "Per motion")):
        lines += ["", f"{title}, mean total RMSE (deg):", ""] + _group_table(cal, kind)
    lines += ["", "Per phone, mean inclination RMSE (deg):", ""]
    lines += _group_table(cal, "phone", "inclination_deg")
    if raw is not None:
        lines += ["", "### Raw magnetometer (`--mag raw`)", "",
                  "The uncalibrated field: heading from it is wrong for every filter (`phone`",
                  "is the phone's own estimate, the same as above); the inclination remains",
                  "comparable.", ""]
        lines += _mean_table(raw)
        lines += ["", "Per phone, mean total RMSE (deg):", ""] + _group_table(raw, "phone")
    lines += ["", "How each library is fed the multi-rate phone data:", ""]
    for k, v in cal["anchor_inputs"].items():
        lines.append(f"* `{k}`: {v}")
    return "\n".join(lines)


def eskf_results(broad: dict, tyrex: dict | None) -> str:
    """The ESKF page's results: per BROAD trial and mean for eskf-r6 / eskf-r3 (VQF for
    scale), and their tyrex means and worst trials."""
    ms = [m for m in ("eskf-r6", "eskf-r3", "vqf") if m in broad["mean"]]
    cell = {(r["trial"], r["method"]): r["total_deg"] for r in broad["trials"]}
    lines = ["| BROAD trial | " + " | ".join(f"{m} total RMSE, deg" for m in ms) + " |",
             "| --- |" + " ---: |" * len(ms)]
    for t in sorted({r["trial"] for r in broad["trials"]}):
        lines.append(f"| {t} | " + " | ".join(f"{cell.get((t, m), float('nan')):.2f}"
                                             for m in ms) + " |")
    lines.append("| **mean** | " + " | ".join(f"**{broad['mean'][m]['total_deg']:.2f}**"
                                            for m in ms) + " |")
    if tyrex is not None:
        ms = [m for m in ("eskf-r6", "eskf-r3", "vqf", "vqf-offline") if m in tyrex["mean"]]
        worst = {m: max((r for r in tyrex["trials"] if r["method"] == m),
                        key=lambda r: r["total_deg"]) for m in ms}
        lines += ["", f"tyrex ({tyrex['mean'][ms[0]]['trials']} trials, OS-calibrated "
                  "magnetometer), mean total / heading / inclination RMSE and the worst trial "
                  "(deg):", "", "| method | total | heading | inclination | worst trial |",
                  "| --- | ---: | ---: | ---: | --- |"]
        for m in ms:
            v, w = tyrex["mean"][m], worst[m]
            lines.append(f"| {m} | {v['total_deg']:.2f} | {v['heading_deg']:.2f} | "
                         f"{v['inclination_deg']:.2f} | {w['total_deg']:.1f} ({w['trial']}) |")
    return "\n".join(lines)


def calibration_section(runs: dict[str, dict]) -> str:
    """The tyrex table of ``docs/calibration.md``: mean total RMSE per magnetometer
    (``runs``: label -> ``gnomon benchmark tyrex --json``) and what the calibrations
    were (models, coverage, residual)."""
    ms = [m for m in ("robust-ahrs", "eskf-r3", "eskf-r6", "mahony", "vqf", "vqf-offline")
          if all(m in r["mean"] for r in runs.values())]
    n = len({r["trial"] for r in next(iter(runs.values()))["trials"]})
    lines = [f"Mean over the {n} trials of the total RMSE (deg):", "",
             "| magnetometer | " + " | ".join(ms) + " |", "| --- |" + " ---: |" * len(ms)]
    for label, r in runs.items():
        lines.append(f"| {label} | " + " | ".join(f"{r['mean'][m]['total_deg']:.2f}"
                                                 for m in ms) + " |")
    for label, r in runs.items():
        cals = r.get("calibrations")
        if not cals:
            continue
        models: dict[str, int] = {}
        for c in cals:
            models[c["model"]] = models.get(c["model"], 0) + 1
        cov = [c["coverage"] for c in cals]
        res = [c["residual_uT"] for c in cals]
        lines += ["", f"{label}: model " + ", ".join(f"{k} on {v}" for k, v in models.items())
                  + f" trials; applied on {sum(bool(c['applied']) for c in cals)} of "
                  f"{len(cals)}; coverage {min(cov):.2f}-{max(cov):.2f}; residual "
                  f"{min(res):.2f}-{max(res):.2f} µT."]
    return "\n".join(lines)


def offline_section(broad: dict, tyrex: dict | None) -> str:
    """The offline page's table: mean total RMSE of the offline estimators, the causal
    filters they start from and VQF's two forms, on BROAD and (when run) the phones."""
    ms = ["eskf-offline", "robust-ahrs-offline", "vqf-offline", "eskf-r3", "robust-ahrs",
          "vqf"]
    runs = {"BROAD": broad, **({"tyrex (OS-calibrated magnetometer)": tyrex} if tyrex
                                else {})}
    lines = ["| method | " + " | ".join(f"{k}, {len({r['trial'] for r in v['trials']})} "
                                         f"trials" for k, v in runs.items()) + " |",
             "| --- |" + " ---: |" * len(runs)]
    for m in ms:
        cells = [f"{v['mean'][m]['total_deg']:.3f}" if m in v["mean"] else "–"
                 for v in runs.values()]
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    lines += ["", "Honesty of the per-axis uncertainty `att_std_rad` on the same trials: NEES "
              "(normalised estimation error squared, 3 dof; 3 for an honest band), mean and "
              "median over the trials of each trial's mean:", "",
              "| method | " + " | ".join(runs) + " |", "| --- |" + " ---: |" * len(runs)]
    for m in ("eskf-offline", "robust-ahrs-offline"):
        cells = []
        for v in runs.values():
            nees = [r["nees"] for r in v["trials"] if r["method"] == m and "nees" in r]
            cells.append(f"{np.mean(nees):.1f} / {np.median(nees):.1f}" if nees else "–")
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def replace_section(text: str, name: str, body: str) -> str:
    """``text`` with what lies between ``<!-- name:start -->`` and ``<!-- name:end -->``
    replaced by ``body`` (unchanged when the markers are missing)."""
    start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    if start not in text or end not in text:
        return text
    head, rest = text.split(start, 1)
    _, tail = rest.split(end, 1)
    return f"{head}{start}\n{body}\n{end}{tail}"


def speed_only(quick: bool) -> None:
    """``--speed``: run ``gnomon bench --json`` alone and put its table in place of the
    former one, in the README (``bench`` markers) and in docs/benchmarks.md (the same
    table, found by its text); the accuracy sections stay as measured before."""
    from gnomon.speed import markdown_table

    speed = markdown_table(gnomon_json("bench", *(["--quick"] if quick else [])))
    readme_path, page_path = ROOT / "README.md", ROOT / "docs" / "benchmarks.md"
    readme = readme_path.read_text()
    old = readme.split("<!-- bench:start -->\n", 1)[1].split("\n<!-- bench:end -->", 1)[0]
    page = page_path.read_text()
    if old not in page:
        raise SystemExit("docs/benchmarks.md does not hold the README's speed table: "
                         "run make_docs.py without --speed")
    page_path.write_text(page.replace(old, speed))
    readme_path.write_text(replace_section(readme, "bench", speed))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--broad", help="BROAD directory (default: gnomon.datasets.broad_dir())")
    ap.add_argument("--quick", action="store_true", help="quick speed benchmark")
    ap.add_argument("--speed", action="store_true",
                    help="only the speed table (gnomon bench): README and docs/benchmarks.md")
    args = ap.parse_args()
    if args.speed:
        return speed_only(args.quick)
    from gnomon.datasets import broad_dir, bundled
    from gnomon.speed import markdown_table

    data = args.broad or broad_dir() or bundled("broad")
    broad = gnomon_json("benchmark", "broad", "--data", str(data))
    from gnomon.datasets import tyrex_dir

    old_page = (ROOT / "docs" / "benchmarks.md").read_text()
    tyrex = tyrex_dir()
    if tyrex is not None:
        cal = gnomon_json("benchmark", "tyrex", "--data", str(tyrex))
        raw = gnomon_json("benchmark", "tyrex", "--data", str(tyrex), "--mag", "raw")
        tyrex_text = tyrex_section(cal, raw, tyrex.name)
        runs = {"OS-calibrated": cal, "raw (robust-ahrs: its online hard-iron estimate only)":
                raw}
        for mode, label in (("recording", "raw + gnomon, calibration recording"),
                            ("self", "raw + gnomon, self-calibration")):
            runs[label] = gnomon_json("benchmark", "tyrex", "--data", str(tyrex), "--mag",
                                      "raw", "--mag-calibration", mode)
        page = ROOT / "docs" / "calibration.md"
        page.write_text(replace_section(page.read_text(), "calibration-tyrex",
                                        calibration_section(runs)))
    elif "<!-- tyrex:start -->" in old_page:  # keep what was measured before
        tyrex_text = old_page.split("<!-- tyrex:start -->\n", 1)[1].split(
            "\n<!-- tyrex:end -->", 1)[0]
    else:
        tyrex_text = "## Smartphones (tyrex)\n\nNot run: the tyrex data set was not found."
    offline_page = ROOT / "docs" / "estimators" / "offline.md"
    offline_page.write_text(replace_section(
        offline_page.read_text(), "offline-results",
        offline_section(broad, cal if tyrex is not None else None)))
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import mekf_targets  # the spacecraft MEKF's targets (simulated; about a minute)

    mekf_targets.main(["--doc", str(ROOT / "docs" / "estimators" / "mekf.md")])
    eskf_page = ROOT / "docs" / "estimators" / "eskf.md"
    text = replace_section(eskf_page.read_text(), "eskf-results",
                           eskf_results(broad, cal if tyrex is not None else None))
    tuning = ROOT / "docs" / "figures" / "defaults_tuning.json"
    if tuning.exists():  # benchmarks/defaults_tuning.py (needs both data sets)
        sys.path.insert(0, str(ROOT / "benchmarks"))
        from robust_ahrs_doc import cross_tables

        text = replace_section(text, "eskf-tuning",
                               cross_tables(json.loads(tuning.read_text()), "eskf-r3"))
    eskf_page.write_text(text)
    bench = gnomon_json("bench", *(["--quick"] if args.quick else []))
    today = dt.date.today().isoformat()
    n_trials = len({r["trial"] for r in broad["trials"]})
    speed = markdown_table(bench)
    page = f"""# Benchmarks

Generated on {today} by `python benchmarks/make_docs.py` from the JSON of
`gnomon benchmark broad --data {Path(data).name} --json`, `gnomon benchmark tyrex --json`
(`--mag calibrated` and `--mag raw`) and `gnomon bench --json`.

## Accuracy on BROAD

BROAD (Laidig, Caruso, Cereatti, Seel, *Data* 6(7):72, 2021): {n_trials}
trials, every method with its default parameters, the benchmark's own metric (RMSE over
the movement phases with a valid truth; no alignment). Causal, except the names ending in
`-offline` (gnomon's and VQF's offline estimators: forward and backward over the whole
log; compare them with each other).

{broad_tables(broad)}

<!-- tyrex:start -->
{tyrex_text}
<!-- tyrex:end -->

## Speed

One simulated 100 Hz recording (smooth random rotation, MEMS noise), every method on
the same samples in the same process: interleaved rounds in a random order, medians,
compilation excluded, freed memory kept for reuse by every method alike (see
`gnomon.speed`). `gnomon-batch-mahony-R1000` is 1,000 Mahony filters at once
(`gnomon.estimators.mahony.run_batch`, runs innermost for SIMD, one thread), one
Monte Carlo run each. Run it yourself: `gnomon bench` (a few minutes; `--quick` for
200,000 samples).

{speed}
{readers_section()}"""
    (ROOT / "docs" / "benchmarks.md").write_text(page)
    readme = (ROOT / "README.md").read_text()
    mean_table = broad_tables(broad).split("\n\n")[0]
    summary = (f"{n_trials} trials in `{Path(data).name}`, mean RMSE in degrees "
               f"(`gnomon benchmark broad`, {today}):\n\n{mean_table}")
    sections = [("bench", speed), ("broad", summary)]
    if tyrex is not None:  # otherwise the README keeps what was measured before
        n_phone = len({r["trial"] for r in cal["trials"]})
        sections.append(("tyrex", f"{n_phone} trials in `{tyrex.name}`, OS-calibrated "
                                  f"magnetometer, truth aligned (`gnomon benchmark tyrex`, "
                                  f"{today}):\n\n" + "\n".join(_mean_table(cal))))
    for name, text in sections:
        start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
        if start in readme and end in readme:
            head, rest = readme.split(start, 1)
            _, tail = rest.split(end, 1)
            readme = f"{head}{start}\n{text}\n{end}{tail}"
    (ROOT / "README.md").write_text(readme)
    print(f"wrote docs/benchmarks.md ({data})")


if __name__ == "__main__":
    main()
