"""Regenerate the measured tables of the docs and the README from the commands themselves.

    python benchmarks/make_docs.py [--broad DIR] [--quick]

Runs ``gnomon benchmark broad --json`` (the full BROAD trials when found, see
``gnomon.datasets.broad_dir``; the bundled excerpt otherwise) and
``gnomon bench --json``, then writes ``docs/benchmarks.md`` and replaces the
speed and accuracy tables in ``README.md`` between the markers
``<!-- bench:start/end -->`` and ``<!-- broad:start/end -->``. Nothing in those
tables is typed by hand.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import subprocess
import sys
from pathlib import Path

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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--broad", help="BROAD directory (default: gnomon.datasets.broad_dir())")
    ap.add_argument("--quick", action="store_true", help="quick speed benchmark")
    args = ap.parse_args()
    from gnomon.datasets import broad_dir
    from gnomon.speed import markdown_table

    data = args.broad or broad_dir() or ROOT / "tests" / "data" / "broad"
    broad = gnomon_json("benchmark", "broad", "--data", str(data))
    bench = gnomon_json("bench", *(["--quick"] if args.quick else []))
    today = dt.date.today().isoformat()
    n_trials = len({r["trial"] for r in broad["trials"]})
    speed = markdown_table(bench)
    page = f"""# Benchmarks

Generated on {today} by `python benchmarks/make_docs.py` from the JSON of
`gnomon benchmark broad --data {Path(data).name} --json` and `gnomon bench --json`.

## Accuracy on BROAD

BROAD (Laidig, Caruso, Cereatti, Seel, *Data* 6(7):72, 2021): {n_trials}
trials, every method with its default parameters, causal, the benchmark's own metric
(RMSE over the movement phases with a valid truth; no alignment).

{broad_tables(broad)}

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
    for name, text in (("bench", speed), ("broad", summary)):
        start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
        if start in readme and end in readme:
            head, rest = readme.split(start, 1)
            _, tail = rest.split(end, 1)
            readme = f"{head}{start}\n{text}\n{end}{tail}"
    (ROOT / "README.md").write_text(readme)
    print(f"wrote docs/benchmarks.md ({data})")


if __name__ == "__main__":
    main()
