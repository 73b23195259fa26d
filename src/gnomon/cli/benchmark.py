"""``gnomon benchmark broad|tyrex|DIR``: score filters and reference libraries on a data set
with a reference, and print the tables."""

from __future__ import annotations

import math
import sys
from pathlib import Path

from gnomon.cli.common import (
    add_map_option,
    add_quiet_option,
    add_strict_option,
    print_json,
    progress_wanted,
)
from gnomon.errors import InputError


def add_parser(sub) -> None:
    s = sub.add_parser(
        "benchmark", help="score filters on a benchmark data set or a folder of recordings",
        description="gnomon benchmark broad --data DIR | gnomon benchmark tyrex --data DIR | "
                    "gnomon benchmark DIR (every recording under DIR that holds a truth)")
    s.add_argument("dataset", metavar="broad|tyrex|DIR",
                   help="a named benchmark (with --data) or a folder of recordings with truth")
    s.add_argument("--data", help="directory of the named benchmark's data set")
    s.add_argument("--filters", help="comma-separated gnomon filters (default: every IMU filter)")
    s.add_argument("--anchors", help="reference rows: vqf,vqf-offline,imufusion,ahrs-madgwick "
                                     "and, where the data has them, phone (tyrex) or onboard "
                                     "(default: broad the installed libraries and "
                                     "vqf-offline; tyrex vqf,vqf-offline,phone,ahrs-madgwick,"
                                     "imufusion; DIR the libraries, vqf-offline and onboard; "
                                     "'none' for none)")
    s.add_argument("--align", metavar="auto|world,body,lag|none|FILE.json",
                   help="correct the truth before scoring, fitted per trial from the gyro "
                        "(and accelerometer, magnetometer) against it: 'lag' (time offset), "
                        "'body' (sensor-to-marker rotation), 'world' (the reference's world "
                        "to ENU: any up axis, heading to magnetic north), a comma-separated "
                        "list of them, 'auto' (what each trial's motion determines), "
                        "'none' or a FILE.json of --save-alignment (default: tyrex body,lag; "
                        "broad and DIR none)")
    s.add_argument("--save-alignment", metavar="FILE.json",
                   help="write each trial's fitted alignment for reuse (--align FILE.json)")
    s.add_argument("--mag", choices=["calibrated", "raw"],
                   help="tyrex: the OS-calibrated magnetometer (default) or the raw one")
    s.add_argument("--mag-calibration", choices=["self", "recording"],
                   help="tyrex, raw magnetometer: correct it by gnomon's calibration (gnomon "
                        "calibrate mag) fitted to each trial's own samples (self) or to the "
                        "data set's calibration recording of that phone and day (recording)")
    add_map_option(s)
    s.add_argument("--plot", help="write a bar chart, e.g. broad.png (tyrex, DIR: per group)")
    s.add_argument("--json", action="store_true", help="print the JSON result")
    add_strict_option(s)
    add_quiet_option(s)
    s.set_defaults(func=run)


def run(args) -> int:
    """``gnomon.benchmark.run_broad`` / ``run_tyrex`` (``--data DIR``) or ``run_benchmark(DIR)``
    (any folder of recordings with a truth)."""
    from gnomon.benchmark import BENCHMARKS, default_filters, run_benchmark, run_broad, run_tyrex

    filters = args.filters.split(",") if args.filters else list(default_filters())
    anchors = None if args.anchors is None else (
        [] if args.anchors in ("", "none") else args.anchors.split(","))
    progress = progress_wanted(args)
    named = args.dataset in BENCHMARKS
    if named and not args.data:
        from gnomon.datasets import dataset, dataset_dir

        found = dataset_dir(args.dataset)
        if found is None:
            raise InputError(f"no {args.dataset} data set here: fetch it with `gnomon datasets "
                             f"fetch {args.dataset}`, or give --data DIR, or set "
                             f"{dataset(args.dataset).env}", field="--data")
        args.data = str(found)
    if not named and args.data:
        raise InputError("--data is for a named benchmark (broad, tyrex); give the folder "
                         "itself: gnomon benchmark DIR", field="--data")
    if args.strict and named:
        raise InputError("--strict applies to benchmark DIR", field="--strict")
    if args.map is not None and named:
        raise InputError("--map reads a folder of tables of one layout: gnomon benchmark DIR "
                         "--map MAP.yaml", field="--map")
    if args.mag is not None and args.dataset != "tyrex":
        raise InputError("--mag applies to the tyrex benchmark", field="--mag")
    if args.mag_calibration is not None and args.dataset != "tyrex":
        raise InputError("--mag-calibration applies to the tyrex benchmark",
                         field="--mag-calibration")
    if args.mag_calibration is not None and args.mag == "calibrated":
        raise InputError("--mag-calibration corrects the raw magnetometer: use --mag raw",
                         field="--mag-calibration")
    if args.dataset == "broad":
        res = run_broad(args.data, filters=filters, anchors=anchors, progress=progress,
                        align=args.align or ())
    elif args.dataset == "tyrex":
        res = run_tyrex(args.data, filters=filters, anchors=anchors, align=args.align,
                        mag=args.mag or ("raw" if args.mag_calibration else "calibrated"),
                        progress=progress, mag_calibration=args.mag_calibration)
    else:
        res = run_benchmark(args.dataset, filters=filters, anchors=anchors,
                            align=args.align or (), progress=progress, strict=args.strict,
                            map=args.map)
    if args.save_alignment:
        if not res.get("alignment"):
            raise InputError("nothing aligned to save: give --align", field="--save-alignment")
        from gnomon.alignment import save_alignment

        save_alignment(args.save_alignment,
                       {"trials": {a["trial"]: a for a in res["alignment"]}})
        res["alignment_saved"] = str(args.save_alignment)
    if args.plot:
        if args.dataset == "broad":
            from gnomon.report.figures import plot_broad

            plot_broad(res, args.plot)
        else:
            from gnomon.benchmark import plot_benchmark

            title = (f"tyrex smartphone benchmark (magnetometer {res['mag']})"
                     if args.dataset == "tyrex" else f"benchmark {Path(args.dataset).name}")
            plot_benchmark(res, args.plot, f"{title}: mean total RMSE per group (deg)")
    if args.json:
        print_json(res)
        return 0
    if args.dataset == "broad":
        _print_broad(res, args)
    else:
        _print_benchmark(res, args)
    for e in res["errors"]:
        print(f"failed: {e['trial']} {e['method']}: {e['error']}", file=sys.stderr)
    if args.plot:
        print(f"wrote {args.plot}")
    return 0


def _print_broad(res, args) -> None:
    trials = sorted({r["trial"] for r in res["trials"]})
    methods = list(res["mean"])
    width = max(len(t) for t in trials) if trials else 10
    print(f"BROAD benchmark: {len(trials)} trials in {args.data}; RMSE total (deg)")
    print(" " * width + "".join(f"{m:>15}" for m in methods))
    cell = {(r["trial"], r["method"]): r["total_deg"] for r in res["trials"]}
    for t in trials:
        print(f"{t:<{width}}" + "".join(f"{cell.get((t, m), float('nan')):>15.3f}"
                                         for m in methods))
    for k in ("total", "heading", "inclination"):
        print(f"{'mean ' + k:<{width}}" + "".join(
            f"{res['mean'][m][k + '_deg']:>15.3f}" for m in methods))
    if res.get("groups"):
        print("\nper group (mean total RMSE, deg)")
        groups = sorted({g for m in res["groups"] for g in res["groups"][m]})
        for g in groups:
            print(f"{g:<{width}}" + "".join(
                f"{res['groups'].get(m, {}).get(g, {}).get('total_deg', float('nan')):>15.3f}"
                for m in methods))


def _print_benchmark(res, args) -> None:
    """Text tables of a ``run_tyrex`` / ``run_benchmark`` result."""
    methods = sorted(res["mean"], key=lambda m: res["mean"][m]["total_deg"])
    trials = sorted({r["trial"] for r in res["trials"]})
    where = args.data or args.dataset
    what = "tyrex smartphone benchmark" if res.get("benchmark") == "tyrex" else "benchmark"
    extra = f", magnetometer {res['mag']}" if "mag" in res else ""
    print(f"{what}: {len(trials)} trials in {where}{extra}; alignment of the truth: "
          f"{','.join(res['align']) or 'none'}")
    if "truth" in res:
        tr = res["truth"]
        print(f"truth: {tr['frame']} (declination {tr['declination_deg']:+.3f} deg applied); "
              f"scored {tr['score_window_s'][0]:g}-{tr['score_window_s'][1]:g} s")
    mw = max(16, *(len(m) + 2 for m in methods))  # the method column
    print(f"\n{'method':<{mw}}{'total':>9}{'heading':>9}{'inclin.':>9}{'trials':>8}   "
          "(mean over trials of the RMSE, deg)")
    for m in methods:
        v = res["mean"][m]
        print(f"{m:<{mw}}{v['total_deg']:>9.2f}{v['heading_deg']:>9.2f}"
              f"{v['inclination_deg']:>9.2f}{v['trials']:>8}")
    from gnomon.benchmark import group_kinds

    for kind in group_kinds(res):
        values = sorted({g.partition(":")[2] for m in res["groups"] for g in res["groups"][m]
                         if g.startswith(kind + ":")})
        w = max(10, *(len(v) + 2 for v in values))
        print(f"\nper {kind}: mean total RMSE (deg)")
        print(f"{'method':<{mw}}" + "".join(f"{v:>{w}}" for v in values))
        for m in methods:
            row = res["groups"].get(m, {})
            print(f"{m:<{mw}}" + "".join(
                f"{row.get(f'{kind}:{v}', {}).get('total_deg', math.nan):>{w}.2f}"
                for v in values))
    if res.get("alignment"):
        print("\nalignment of the truth per trial (fitted from the gyro against the "
              "reference's rate; applied: " + (",".join(res["align"]) or "none") + ")")
        width = max(len(a["trial"]) for a in res["alignment"])
        print(f"{'trial':<{width}}{'lag ms':>9}{'corr':>7}{'misalign deg':>14}"
              f"{'rate rms deg/s':>17}{'world up':>22}  applied")
        for a in res["alignment"]:
            up = a.get("world_up_in_world")
            up = "(" + ",".join(f"{v:+.2f}" for v in up) + ")" if up else "-"
            print(f"{a['trial']:<{width}}{1000 * a['lag_s']:>9.1f}{a['lag_correlation']:>7.3f}"
                  f"{a['misalignment_deg']:>14.2f}"
                  f"{a['rate_rms_deg_s_before']:>9.1f} ->{a['rate_rms_deg_s']:>5.1f}"
                  f"{up:>22}  {','.join(a.get('applied', [])) or 'none'}")
            for k, why in a.get("refused", {}).items():
                print(f"{'':<{width}}  not aligned: {k}: {why}")
    for s in res.get("skipped", []):
        print(f"skipped: {s['trial']}: {s['reason']}")
