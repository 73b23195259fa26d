"""The ``gnomon`` command line: parse, call the library, print. No logic of its own.

Every command is one library call a user could make from Python (named in
each command's help). Bad input ends with one line ``gnomon: error: ...``
naming the file, field and row, and exit status 2 — never a traceback.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from gnomon import __version__
from gnomon.errors import InputError


def _json_default(o):
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")


def _clean(o):
    """NaN/inf -> None so the output is strict JSON."""
    if isinstance(o, float) and not math.isfinite(o):
        return None
    if isinstance(o, dict):
        return {k: _clean(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_clean(v) for v in o]
    return o


def print_json(obj) -> None:
    print(json.dumps(_clean(json.loads(json.dumps(obj, default=_json_default))), indent=2))


def _params(pairs: list[str], option: str = "--param", typed: bool = False) -> dict:
    """``KEY=VALUE`` strings to a dict; ``typed`` parses values as YAML scalars (1.5, true)."""
    out = {}
    for p in pairs or []:
        if "=" not in p:
            raise InputError(f"expected KEY=VALUE, got {p!r}", field=option)
        k, v = p.split("=", 1)
        if typed:
            import yaml

            v = yaml.safe_load(v)
        out[k.strip()] = v.strip() if isinstance(v, str) else v
    return out


# ------------------------------------------------------------------ commands
def cmd_filters(args) -> int:
    """``gnomon.describe_filters()``: names, parameters, defaults, units."""
    from gnomon.estimators import registry

    table = registry.describe()
    if args.json:
        print_json(table)
        return 0
    for f in table:
        print(f"{f['name']}: {f['summary']}  (needs {', '.join(f['needs'])})")
        for p in f["params"]:
            unit = f" [{p['unit']}]" if p["unit"] else ""
            print(f"    {p['name']} = {p['default']!r}{unit}  {p['doc']}")
    return 0


#: phone exports with an OS-calibrated and a raw magnetometer (``mag=`` of their reader)
_PHONE_FORMATS = ("tyrex", "sensorlogger")


def _raw_phone_mag(args, why: str) -> None:
    """``--phone-mag raw`` when not given and the input is a phone export: a magnetometer
    calibration is fitted to (and corrects) the raw magnetometer, never the one the OS
    already corrected. Says so on stderr."""
    from gnomon.io import detect_format

    if getattr(args, "phone_mag", None) is not None:
        return
    try:
        fmt = getattr(args, "format", "auto")
        fmt = detect_format(args.input) if fmt == "auto" else fmt
    except InputError:
        return  # the reader will say what is wrong with the input
    if fmt in _PHONE_FORMATS:
        args.phone_mag = "raw"
        print(f"note: {why}: the phone's raw magnetometer (--phone-mag raw; "
              f"--phone-mag calibrated for the OS-calibrated one)", file=sys.stderr)


def _read_input(args):
    from gnomon.io import read

    csv_opts = {}
    if args.columns:
        csv_opts["columns"] = _params(args.columns.split(","), option="--columns")
    for opt in ("gyro_unit", "accel_unit", "mag_unit", "time_unit"):
        if getattr(args, opt, None):
            csv_opts[opt] = getattr(args, opt)
    if getattr(args, "phone_mag", None):  # phone exports: which magnetometer file
        csv_opts["mag"] = args.phone_mag
    return read(args.input, format=args.format, **csv_opts, **_log_options(args))


def _log_options(args) -> dict:
    """``--topic``/``--instance`` (and ``--mag-topic``) as reader options, when given."""
    out = {}
    for opt in ("topic", "mag_topic", "instance"):
        if getattr(args, opt, None) is not None:
            out[opt] = getattr(args, opt)
    return out


def cmd_inspect(args) -> int:
    """``gnomon.io.inspect(path, format, topic=, instance=)``: what a log holds."""
    from gnomon.io import inspect

    info = inspect(args.input, format=args.format, **_log_options(args))
    if args.json:
        print_json(info)
        return 0
    print(f"{info['file']}: {info['format']}, {info['source']}; {info['duration_s']:.2f} s; "
          f"frames {info['frames']['reference']}/{info['frames']['body']}")
    for s in info["sensors"]:
        gaps = f", {s['gaps']} gaps (longest {s['longest_gap_s']:.3f} s)" if s["gaps"] else ""
        origin = f"  [{s['from']}]" if s["from"] else ""
        print(f"  {s['name']:5s} {s['rate_hz']:9.2f} Hz {s['samples']:9d} samples  "
              f"{s['unit']}{gaps}{origin}")
    for key, label in (("onboard", "own estimate"), ("truth", "truth")):
        if info[key]:
            o = info[key]
            print(f"  {label}: {o['what']} ({o['coverage']:.0%} of gyro samples)")
    if info.get("truncated"):
        c = info["truncated"]
        print(f"  truncated: the file ends inside a message at byte {c['at_byte']} "
              f"({c['bytes_present']} of {c['message_bytes']} bytes); data up to "
              f"t = {c['data_up_to_s']:.3f} s")
    if info.get("available"):
        print(f"  available: {json.dumps(info['available'], default=str)}")
    for line in info["assumed"]:
        print(f"  assumed: {line}")
    return 0


def cmd_convert(args) -> int:
    """``gnomon.io.write(out, gnomon.io.read(path, format, topic=, instance=))``."""
    from gnomon.io import read, write

    rec = read(args.input, format=args.format, **_log_options(args))
    write(args.out, rec)
    summary = {"input": str(args.input), "out": str(args.out), "samples": len(rec),
               "format_version": 2}
    if args.json:
        print_json(summary)
    else:
        print(f"wrote {args.out}: {len(rec)} gyro samples from {args.input}")
    return 0


def _estimate_filter(name: str | None, offline: bool, rec) -> tuple[str, str | None]:
    """The filter ``gnomon estimate`` runs, and why when it chose it: ``name``, or with
    ``offline`` its ``-offline`` form; without a name the first of the registry's
    default order that runs on ``rec`` (``registry.default_for``)."""
    from gnomon.estimators import registry

    if name is None:
        return registry.default_for(rec, offline)
    if not offline or getattr(registry.get(name), "offline", False):
        return name, None
    if f"{name}-offline" in registry.names():
        return f"{name}-offline", None
    raise InputError(f"{name!r} has no offline form; offline filters: "
                     f"{', '.join(registry.names(offline=True))}", field="--filter")


def cmd_estimate(args) -> int:
    """``registry.create(name, params).run(gnomon.io.read(path))`` and ``metrics.score``."""
    from gnomon.estimators import registry
    from gnomon.metrics import score

    if args.mag_calibration:
        _raw_phone_mag(args, "--mag-calibration corrects")
    rec = _read_input(args)
    cal_summary = None
    if args.mag_calibration:
        rec, cal_summary = _apply_mag_calibration(rec, args.mag_calibration)
    args.filter, chosen = _estimate_filter(args.filter, args.offline, rec)
    est = registry.create(args.filter, _params(args.param)).run(rec)
    summary = {"input": str(args.input), "filter": args.filter, "samples": len(rec),
               **({"filter_chosen_because": chosen} if chosen else {}),
               "params": est.params,
               "warnings": _limit_warnings(est, getattr(registry.get(args.filter), "limits",
                                                        {}))}
    if cal_summary is not None:
        summary["mag_calibration"] = cal_summary
    if rec.q_true is not None:
        summary["errors"] = score(rec.q_true, est.q, rec.score_mask)
    matched = None
    if args.compare == "onboard":
        from gnomon.metrics import compare_onboard

        summary["onboard"], matched = compare_onboard(rec, est.q)
    if args.out:
        from gnomon.io.estimate import write_estimate

        write_estimate(args.out, est)
        summary["out"] = str(args.out)
    if args.plot:
        from gnomon.report.figures import plot_estimate

        plot_estimate(rec, est, args.plot,
                      compare=None if matched is None else ("device's own", matched))
        summary["plot"] = str(args.plot)
    if args.json:
        print_json(summary)
        return 0
    print(f"{args.filter} on {args.input}: {len(rec)} samples")
    if chosen:
        print(f"  (default filter: {chosen}; --filter NAME to choose)")
    if cal_summary is not None:
        print(f"  magnetometer calibration ({cal_summary['from']}): {cal_summary['model']}, "
              f"offset {[round(v, 2) for v in cal_summary['offset_uT']]} uT, coverage "
              f"{cal_summary['coverage']:.2f}, residual {cal_summary['residual_uT']:.2f} uT")
    for w in summary["warnings"]:
        print(f"  warning: {w['message']}")
    if "errors" in summary:
        e = summary["errors"]
        print(f"  RMS error over {e['samples']} scored samples: total {e['total_deg']:.3f} deg, "
              f"heading {e['heading_deg']:.3f} deg, inclination {e['inclination_deg']:.3f} deg")
        print(f"  per axis: roll {e['roll_deg']:.3f}, pitch {e['pitch_deg']:.3f}, "
              f"yaw {e['yaw_deg']:.3f} deg; max {e['max_deg']:.3f} deg")
    else:
        print("  (no truth in the input: no error summary)")
    if "onboard" in summary:
        o = summary["onboard"]
        print(f"  vs the device's own estimate over {o['samples']} samples: total "
              f"{o['total_deg']:.3f} deg, heading {o['heading_deg']:.3f} deg, inclination "
              f"{o['inclination_deg']:.3f} deg ({o['heading_reference']})")
    for key in ("out", "plot"):
        if key in summary:
            print(f"  wrote {summary[key]}")
    return 0


def _apply_mag_calibration(rec, which: str):
    """``gnomon.calibration.apply_mag_calibration(rec, cal)`` with ``cal`` from a JSON
    file (``gnomon calibrate mag --out``) or, for ``self``, ``calibrate_mag(rec,
    require_ok=True)``: (the corrected recording, the calibration's report)."""
    from gnomon.calibration import apply_mag_calibration, calibrate_mag, load_mag_calibration

    if which == "self":
        cal = calibrate_mag(rec, require_ok=True)
    else:
        cal = load_mag_calibration(which)
    return apply_mag_calibration(rec, cal), {"from": which, **cal.to_dict()}


def cmd_calibrate_mag(args) -> int:
    """``gnomon.calibration.calibrate_mag(gnomon.io.read(path), field_uT=, location=,
    model=)``, ``save_mag_calibration(out, cal)``, ``plot_mag_calibration(...)``. Exit
    status 1 when the calibration is refused (the report says why). ``--orbit``:
    :func:`_calibrate_mag_orbit` (TWOSTEP against the recording's field model)."""
    from gnomon.calibration import (
        calibrate_mag,
        mag_uT_of,
        plot_mag_calibration,
        save_mag_calibration,
    )

    _raw_phone_mag(args, "calibrating")
    rec = _read_input(args)
    if args.orbit:
        return _calibrate_mag_orbit(args, rec)
    if args.noise_nT is not None:
        raise InputError("--noise-nT goes with --orbit", field="--noise-nT")
    location = None
    if args.location:
        parts = args.location.split(",")
        try:
            values = [float(v) for v in parts]
        except ValueError:
            raise InputError(f"expected LAT,LON[,ALT_M] in degrees and m, got "
                             f"{args.location!r}", field="--location") from None
        if len(values) not in (2, 3):
            raise InputError(f"expected LAT,LON[,ALT_M], got {args.location!r}",
                             field="--location")
        if not args.date:
            raise InputError("--location needs --date YYYY-MM-DD (the field changes with "
                             "time)", field="--date")
        location = {"latitude_deg": values[0], "longitude_deg": values[1],
                    "altitude_m": values[2] if len(values) == 3 else 0.0, "date": args.date}
    elif args.date:
        raise InputError("--date goes with --location", field="--date")
    cal = calibrate_mag(rec, field_uT=args.field_uT, location=location, model=args.model,
                        gyro=not args.no_gyro)
    report = {**cal.to_dict(), "input": str(args.input)}
    if args.out:
        save_mag_calibration(args.out, cal)
        report["out"] = str(args.out)
    if args.plot:
        plot_mag_calibration(mag_uT_of(rec), cal, args.plot, title=str(args.input))
        report["plot"] = str(args.plot)
    if args.json:
        print_json(report)
    else:
        o = ", ".join(f"{v:.2f}" for v in cal.offset_uT)
        print(f"magnetometer calibration of {args.input}: {cal.n_samples} samples, "
              f"{cal.model} model, {'ok' if cal.ok else 'REFUSED'}")
        if not cal.ok:
            print(f"  reason: {cal.reason}")
        print(f"  offset_uT [{o}]")
        print("  soft_iron " + "\n            ".join(
            "[" + ", ".join(f"{v:8.5f}" for v in row) + "]" for row in cal.soft_iron))
        print(f"  field {cal.field_uT:.2f} uT ({cal.field_source}); residual "
              f"{cal.residual_uT:.2f} uT (raw spread {cal.raw_residual_uT:.2f} uT); coverage "
              f"{cal.coverage:.2f}; condition {cal.condition:.3g}")
        for key in ("out", "plot"):
            if key in report:
                print(f"  wrote {report[key]}")
    return 0 if cal.ok else 1


def _calibrate_mag_orbit(args, rec) -> int:
    """``gnomon calibrate mag REC --orbit``: ``gnomon.twostep.calibrate_mag_orbit(rec,
    noise_nT)`` (TWOSTEP against the recording's field model). ``--json`` prints
    ``TwostepResult.to_dict()`` (``bias_nT``, ``std_nT``, ``cov_nT2``, ``centred_bias_nT``,
    ``centred_std_nT``, ``iterations``, ``converged``, ``residual_nT``,
    ``raw_residual_nT``, ``noise_nT``, ``noise_source``, ``condition``, ``n_samples``,
    ``mean_field_nT``, ``coverage``, ``field_source``, ``source``) plus ``input``,
    ``mag_unit``, ``bias_in_mag_unit``, ``std_in_mag_unit`` and ``out``. ``--out`` writes
    the bias as a calibration JSON (``gnomon estimate --mag-calibration``). Exit status 1
    when Gauss-Newton did not converge."""
    from gnomon.calibration import save_mag_calibration
    from gnomon.recording import MAG_UNITS_TO_TESLA
    from gnomon.twostep import calibrate_mag_orbit

    for opt in ("field_uT", "location", "date", "plot"):
        if getattr(args, opt, None):
            raise InputError(f"--orbit uses the recording's field model; "
                             f"--{opt.replace('_', '-')} does not apply",
                             field=f"--{opt.replace('_', '-')}")
    if args.model != "auto":
        raise InputError("--orbit estimates the bias alone; --model does not apply",
                         field="--model")
    res = calibrate_mag_orbit(rec, noise_nT=args.noise_nT)
    per_unit = 1e-9 / MAG_UNITS_TO_TESLA[rec.mag_unit]
    report = {**res.to_dict(), "input": str(args.input), "mag_unit": rec.mag_unit,
              "bias_in_mag_unit": [float(v) * per_unit for v in res.bias_nT],
              "std_in_mag_unit": [float(v) * per_unit for v in res.std_nT]}
    if args.out:
        save_mag_calibration(args.out, res.calibration())
        report["out"] = str(args.out)
    if args.json:
        print_json(report)
    else:
        print(f"TWOSTEP magnetometer bias of {args.input}: {res.n_samples} samples against "
              f"{res.field_source}, {res.iterations} iterations, "
              f"{'converged' if res.converged else 'NOT CONVERGED'}")
        print("  bias_nT [" + ", ".join(f"{v:.1f}" for v in res.bias_nT) + "] +- ["
              + ", ".join(f"{v:.1f}" for v in res.std_nT) + "] (1 sigma)")
        if rec.mag_unit != "nT":
            print(f"  bias_{rec.mag_unit} [" + ", ".join(
                f"{v:.6g}" for v in report["bias_in_mag_unit"]) + "]")
        print(f"  residual ||B - b| - |H|| {res.residual_nT:.1f} nT RMS (raw "
              f"{res.raw_residual_nT:.1f} nT); noise {res.noise_nT:.1f} nT "
              f"({res.noise_source}); condition {res.condition:.3g}")
        if "out" in report:
            print(f"  wrote {report['out']}")
    return 0 if res.converged else 1


def _limit_warnings(est, limits: dict) -> list[dict]:
    """One entry per boolean signal ``<quantity>_at_limit`` of ``est`` that is ever true:
    the bound (``limits``: signal -> (parameter, unit, what), a filter class attribute),
    when it was first reached (s after the first sample) and for how long (s)."""
    import numpy as np

    out = []
    t = np.asarray(est.t, float)
    for name, flag in est.signals.items():
        flag = np.asarray(flag)
        if not name.endswith("_at_limit") or flag.dtype != bool or not flag.any():
            continue
        param, unit, what = limits.get(name, (None, "", name[:-len("_at_limit")]))
        bound = est.params.get(param) if param else None
        first = int(np.argmax(flag))
        held = float(np.diff(t, append=t[-1])[flag].sum())  # each row until the next one
        where = "its bound"
        if bound is not None:
            deg = f" = {math.degrees(bound):.3g} deg/s" if unit == "rad/s" else ""
            where = f"±{bound:g} {unit}{deg} ({param})"
        out.append({"signal": name, "parameter": param, "limit": bound, "unit": unit,
                    "first_s": float(t[first] - t[0]), "duration_s": held,
                    "fraction": float(flag.mean()),
                    "message": f"{what} at its limit {where} from {t[first] - t[0]:.2f} s "
                               f"for {held:.2f} s ({100 * flag.mean():.1f} % of samples); "
                               f"the true value may lie beyond it"})
    return out


def cmd_benchmark(args) -> int:
    """``gnomon.benchmark.run_broad`` / ``run_tyrex`` (``--data DIR``) or ``run_benchmark(DIR)``
    (any folder of recordings with a truth)."""
    from gnomon.benchmark import BENCHMARKS, default_filters, run_benchmark, run_broad, run_tyrex

    filters = args.filters.split(",") if args.filters else list(default_filters())
    anchors = None if args.anchors is None else (
        [] if args.anchors in ("", "none") else args.anchors.split(","))
    progress = _progress(args)
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
                            align=args.align or (), progress=progress)
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
    print(f"\n{'method':<16}{'total':>9}{'heading':>9}{'inclin.':>9}{'trials':>8}   "
          "(mean over trials of the RMSE, deg)")
    for m in methods:
        v = res["mean"][m]
        print(f"{m:<16}{v['total_deg']:>9.2f}{v['heading_deg']:>9.2f}"
              f"{v['inclination_deg']:>9.2f}{v['trials']:>8}")
    from gnomon.benchmark import group_kinds

    for kind in group_kinds(res):
        values = sorted({g.partition(":")[2] for m in res["groups"] for g in res["groups"][m]
                         if g.startswith(kind + ":")})
        w = max(10, *(len(v) + 2 for v in values))
        print(f"\nper {kind}: mean total RMSE (deg)")
        print(f"{'method':<16}" + "".join(f"{v:>{w}}" for v in values))
        for m in methods:
            row = res["groups"].get(m, {})
            print(f"{m:<16}" + "".join(
                f"{row.get(f'{kind}:{v}', {}).get('total_deg', math.nan):>{w}.2f}"
                for v in values))
    if res.get("alignment"):
        print("\nalignment of the truth per trial (fitted from the gyro against the "
              "reference's rate; applied: " + (",".join(res["align"]) or "none") + ")")
        width = max(len(a["trial"]) for a in res["alignment"])
        print(f"{'trial':<{width}}{'lag ms':>9}{'corr':>7}{'misalign deg':>14}"
              f"{'rate rms deg/s':>17}")
        for a in res["alignment"]:
            print(f"{a['trial']:<{width}}{1000 * a['lag_s']:>9.1f}{a['lag_correlation']:>7.3f}"
                  f"{a['misalignment_deg']:>14.2f}"
                  f"{a['rate_rms_deg_s_before']:>9.1f} ->{a['rate_rms_deg_s']:>5.1f}")
    for s in res.get("skipped", []):
        print(f"skipped: {s['trial']}: {s['reason']}")


def cmd_scenarios(args) -> int:
    """``gnomon.scenarios.list_presets()`` and each preset's description."""
    from gnomon.scenarios import list_presets, load_scenario

    rows = [{"name": n, "description": load_scenario(n).config.get("description", "")}
            for n in list_presets()]
    if args.json:
        print_json(rows)
    else:
        for r in rows:
            print(f"{r['name']}: {' '.join(str(r['description']).split())}")
    return 0


def cmd_simulate(args) -> int:
    """``gnomon.io.write(out, gnomon.scenarios.simulate(load_scenario(name), rng_seed))``."""
    from gnomon.io import write
    from gnomon.scenarios import load_scenario, simulate

    scenario = load_scenario(args.scenario)
    if args.set:
        scenario = scenario.replace(_params(args.set, option="--set", typed=True))
    rec = simulate(scenario, rng_seed=args.seed)
    write(args.out, rec)
    summary = {"scenario": args.scenario, "out": str(args.out), "samples": len(rec),
               "duration_s": float(rec.t[-1] - rec.t[0]), "frames": rec.frames}
    if args.json:
        print_json(summary)
    else:
        print(f"simulated {args.scenario}: {len(rec)} samples over "
              f"{summary['duration_s']:.0f} s; wrote {args.out}")
    return 0


def cmd_campaign(args) -> int:
    """``gnomon.campaign.run_campaign(scenario, runs, out, vary, ...).summary()``; with
    ``--report`` then ``gnomon.report.campaign.build_campaign_report(out, elapsed_s)``."""
    from gnomon.campaign import run_campaign

    if args.report and (args.out is None or args.only is not None):
        raise InputError("a report is of a whole campaign: give --out DIR (and no --only)",
                         field="--report")
    summary = run_campaign(args.scenario, args.runs, args.out, args.vary or [],
                           root_seed=args.seed, executor=args.executor,
                           scheduler=args.scheduler, workers=args.workers, resume=args.resume,
                           only=args.only, filters=args.filter,
                           progress=_progress(args)).summary()
    report = None
    if args.report:
        from gnomon.report.campaign import build_campaign_report

        report = build_campaign_report(args.out, elapsed_s=summary.elapsed_s)
    if args.json:
        print_json(summary.to_dict())
    else:
        _print_campaign(args.scenario, summary)
        if report is not None:
            print(f"  report: {report}")
    return 0


def cmd_report(args) -> int:
    """``gnomon.report.campaign.build_campaign_report(DIR)`` for a campaign directory,
    ``gnomon.report.html.rebuild_report(DIR)`` for a reproduction's."""
    if (Path(args.directory) / "campaign.json").is_file():
        from gnomon.report.campaign import build_campaign_report

        path = build_campaign_report(args.directory)
    else:
        from gnomon.report.html import rebuild_report

        path = rebuild_report(args.directory)
    print(f"wrote {path}")
    return 0


def _print_campaign(scenario: str, s) -> None:
    """A ``CampaignSummary`` as text: counts, then a table of the metrics (one run's values
    with ``--only``; mean / p95 / max over the successful runs otherwise). The per-axis
    metrics a budget is built from are left to ``--json`` and ``--report``."""
    from gnomon.campaign.budget import is_budget_metric

    def fmt(v):
        return "n/a" if v is None else f"{v:.4g}" if isinstance(v, float) else str(v)

    if s.row is not None:
        r = s.row
        print(f"campaign {scenario}: run {r['index']} of {s.runs} alone (seed {r['seed']}): "
              f"{r['status']}" + (f", {r['error']}" if r["status"] != "ok" else ""))
        names = [k for k in r if k.startswith("param.")] + [
            m for m in s.metrics if not is_budget_metric(m)]
        width = max(map(len, names), default=0)
        for name in names:
            print(f"  {name:<{width}}  {fmt(r[name])}")
    else:
        print(f"campaign {scenario}: {s.rows} of {s.runs} runs in the table "
              f"({s.ran} ran now, {s.failed_total} failed), {s.runs_per_s:.2f} runs/s")
        if s.metrics:
            head = f"over {s.rows - s.failed_total} successful runs"
            shown = {k: v for k, v in s.metrics.items() if not is_budget_metric(k)}
            width = max(len(head), *map(len, shown))
            print(f"  {head:<{width}}  {'mean':>9}  {'p95':>9}  {'max':>9}")
            for name, m in shown.items():
                print(f"  {name:<{width}}  {fmt(m['mean']):>9}  {fmt(m['p95']):>9}  "
                      f"{fmt(m['max']):>9}")
        if s.failed_total and s.path:
            print("  failed runs and their errors: the 'status' and 'error' columns of the table")
    if s.path:
        print(f"  results: {s.path}")


def cmd_datasets(args) -> int:
    """``gnomon.datasets.describe`` for every data set, or ``gnomon.datasets.fetch(NAME)``."""
    from gnomon import datasets

    if args.action == "fetch":
        if not args.name:
            raise InputError(f"gnomon datasets fetch needs a NAME: {', '.join(datasets.CATALOGUE)}",
                             field="NAME")
        folder = datasets.fetch(args.name, progress=_progress(args))
        if args.json:
            print_json(datasets.describe(args.name))
        else:
            print(f"{args.name}: complete in {folder}")
        return 0
    rows = [datasets.describe(name) for name in datasets.CATALOGUE]
    if args.json:
        print_json({"cache": str(datasets.cache_dir()), "datasets": rows})
        return 0
    print(f"cache folder: {datasets.cache_dir()} (setting GNOMON_DATA_DIR)")
    for r in rows:
        where = {"local": f"local copy in {r['local']}",
                 "cached": f"fetched into {r['cache']}",
                 "partly fetched": f"{r['cached_files']} of {r['files']} files fetched into "
                                   f"{r['cache']}: gnomon datasets fetch {r['name']}",
                 "not fetched": f"not fetched ({r['bytes'] / 1e6:.1f} MB): "
                                f"gnomon datasets fetch {r['name']}"}[r["state"]]
        print(f"\n{r['name']}: {r['title']}")
        print(f"  licence: {r['licence']}; credit: {r['citation']}")
        print(f"  source:  {r['source']} ({r['scope']})")
        print(f"  bundled: {'excerpt in ' + r['bundled'] if r['bundled'] else 'no'}")
        print(f"  full:    {where}")
    return 0


def cmd_reproduce(args) -> int:
    """``gnomon.reproduce.pNNN.run(out_dir, quick)`` (``all``: ``gnomon.reproduce.run_all``)."""
    from gnomon import reproduce

    out = Path(args.out) if args.out else None
    if args.paper == "all":
        res = reproduce.run_all(out_dir=out, quick=args.quick, progress=_progress(args))
    else:
        res = reproduce.run(args.paper, out_dir=out, quick=args.quick,
                            progress=_progress(args))
    if args.json:
        print_json(res)
    else:
        print(json.dumps(_clean(json.loads(json.dumps(res, default=_json_default))), indent=2))
        if out is not None:
            print(f"wrote {out}")
    failed = [p for p, r in res.items() if "error" in r] if args.paper == "all" else []
    if failed:  # the others ran and are in the report; say which did not, and fail
        print(f"gnomon: error: reproduction of paper(s) {', '.join(failed)} failed: "
              f"{'; '.join(res[p]['error'] for p in failed)}", file=sys.stderr)
        return 1
    return 0


def cmd_bench(args) -> int:
    """``gnomon.speed.run_bench(samples, repeats, runs, quick)``."""
    from gnomon.speed import markdown_table, run_bench

    res = run_bench(samples=args.samples, repeats=args.repeats, runs=args.runs, quick=args.quick,
                    progress=_progress(args))
    if args.json:
        print_json(res)
    else:
        print(markdown_table(res))
    return 0


# ------------------------------------------------------------------ parser
def _add_log_options(s) -> None:
    g = s.add_argument_group("log options (ULog, DataFlash, ROS bags)")
    g.add_argument("--topic", help="IMU topic (ROS: /imu/data; ULog: sensor_combined, "
                                   "vehicle_imu, sensor_gyro)")
    g.add_argument("--mag-topic", help="magnetometer topic, or none")
    g.add_argument("--instance", type=int, help="IMU instance (ULog, DataFlash; default 0)")


def _add_csv_options(s) -> None:
    g = s.add_argument_group("CSV options")
    g.add_argument("--columns", help="column map NAME=COLUMN,... (names: t, gyr_x, ..., mag_z)")
    g.add_argument("--gyro-unit", help="rad/s (default) or deg/s")
    g.add_argument("--accel-unit", help="m/s^2 (default) or g")
    g.add_argument("--mag-unit", help="uT (default), nT, mT, T or gauss")
    g.add_argument("--time-unit", help="s (default), ms, us or ns")


def _add_quiet_option(s) -> None:
    s.add_argument("--quiet", action="store_true",
                   help="no progress bar (there is none in CI, nor when stderr is not a "
                        "terminal)")


def _progress(args) -> bool:
    """Whether to show progress: ``gnomon.progress.wanted`` (a terminal, not CI), and
    neither ``--quiet`` nor ``--json``."""
    from gnomon.progress import wanted

    return wanted(quiet=getattr(args, "json", False) or getattr(args, "quiet", False))


def _add_phone_mag_option(s) -> None:
    s.add_argument("--phone-mag", choices=["calibrated", "raw"],
                   help="phone exports (tyrex, Sensor Logger): the OS-calibrated magnetometer "
                        "(the reader's default) or the raw one (the default of calibrate mag "
                        "and of estimate --mag-calibration: a calibration corrects the raw "
                        "one)")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="gnomon",
        description="Attitude determination and estimation: filters, benchmarks, reproductions. "
                    "Quaternions are Hamilton, scalar-first [w, x, y, z]; q_ab maps b to a.")
    p.add_argument("--version", action="version", version=f"gnomon {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    s = sub.add_parser("filters", help="list filters with their parameters, defaults and units")
    s.add_argument("--json", action="store_true", help="machine-readable output")
    s.set_defaults(func=cmd_filters)

    s = sub.add_parser("estimate", help="run a filter on a recording or log (CSV, BROAD, "
                                        "gnomon HDF5, PX4 ULog, ArduPilot DataFlash, ROS 1/2 "
                                        "bag, tyrex/Sensor Logger/phyphox phone export, Xsens "
                                        "text, MATLAB .mat)")
    s.add_argument("input", help="recording file or folder (format from the content; "
                                 "see --format)")
    from gnomon.estimators.registry import DEFAULT_ORDER, OFFLINE_DEFAULT_ORDER

    s.add_argument("--filter", default=None,
                   help="filter name (see `gnomon filters`; default: from the recording's "
                        "sensors, the first that runs of "
                        f"{', '.join(DEFAULT_ORDER)}; with --offline "
                        f"{', '.join(OFFLINE_DEFAULT_ORDER)})")
    s.add_argument("--offline", action="store_true",
                   help="the most accurate attitude the whole log allows: an offline filter "
                        "(forward and backward passes; --filter NAME picks NAME-offline), with "
                        "a per-axis uncertainty (drawn as a band by --plot)")
    s.add_argument("--param", action="append", metavar="KEY=VALUE", help="filter parameter")
    from gnomon.io import FORMATS

    s.add_argument("--format", default="auto", choices=list(FORMATS))
    _add_log_options(s)
    s.add_argument("--out", help="write the estimate (.csv or .h5)")
    s.add_argument("--plot", help="write a figure (attitude, errors, bias, flags), e.g. out.png")
    s.add_argument("--compare", choices=["onboard"],
                   help="onboard: the RMS difference from the device's own attitude estimate "
                        "(PX4, ArduPilot, phone OS, Xsens), heading references matched")
    s.add_argument("--mag-calibration", metavar="CAL.json|self",
                   help="correct the magnetometer first: a calibration from `gnomon "
                        "calibrate mag --out` or 'self' (fitted to this log's own samples)")
    _add_phone_mag_option(s)
    s.add_argument("--json", action="store_true", help="print a JSON summary")
    _add_csv_options(s)
    s.set_defaults(func=cmd_estimate)

    s = sub.add_parser("calibrate", help="sensor calibration from a recording or log "
                                         "(mag: hard and soft iron)")
    csub = s.add_subparsers(dest="sensor", metavar="SENSOR")
    c = csub.add_parser(
        "mag", help="magnetometer hard/soft iron by a constrained ellipsoid fit, with a "
                    "quality report; exit status 1 when refused",
        description="Fit offset (hard iron) and a symmetric soft-iron matrix to the log's "
                    "magnetometer: h = S (m - o), |h| = B. Move the device through as many "
                    "directions as you can (docs/calibration.md). Spacecraft: --orbit "
                    "estimates the bias alone by TWOSTEP against the recording's field "
                    "model, whatever the attitude.")
    c.add_argument("input", help="recording file or folder (any format gnomon reads)")
    c.add_argument("--format", default="auto", choices=list(FORMATS))
    _add_log_options(c)
    c.add_argument("--out", help="write the calibration as JSON (for gnomon estimate "
                                 "--mag-calibration)")
    c.add_argument("--plot", help="write a figure of raw and corrected samples, e.g. cal.png")
    c.add_argument("--json", action="store_true", help="print the report as JSON")
    c.add_argument("--field-uT", type=float, dest="field_uT",
                   help="the local field magnitude B in uT (default: from --location/--date, "
                        "else the data's own scale)")
    c.add_argument("--location", metavar="LAT,LON[,ALT_M]",
                   help="where the log was taken (deg, deg, m): B from IGRF-14")
    c.add_argument("--date", help="when (YYYY-MM-DD), with --location")
    c.add_argument("--model", default="auto", choices=["auto", "full", "scale", "offset"],
                   help="auto (default): the richest model the directions visited determine")
    _add_phone_mag_option(c)
    c.add_argument("--no-gyro", action="store_true",
                   help="do not use the gyro (start, gate and fallback for the offset)")
    c.add_argument("--orbit", action="store_true",
                   help="spacecraft: the bias alone by TWOSTEP against the recording's field "
                        "model (extra.b_o_model_nT or b_o_nT), attitude-independent "
                        "(docs/calibration.md, 'On orbit: TWOSTEP')")
    c.add_argument("--noise-nT", type=float, dest="noise_nT",
                   help="with --orbit: the magnetometer's noise sigma per axis in nT "
                        "(default: estimated from the data)")
    _add_csv_options(c)
    c.set_defaults(func=cmd_calibrate_mag)

    s = sub.add_parser("inspect", help="what a log holds: sensors, rates, gaps, units, the "
                                       "device's own estimate, topics/instances")
    s.add_argument("input", help="log file or folder (ULog, DataFlash, ROS bag, phone, ...)")
    s.add_argument("--format", default="auto", choices=list(FORMATS))
    _add_log_options(s)
    s.add_argument("--json", action="store_true", help="machine-readable output")
    s.set_defaults(func=cmd_inspect)

    s = sub.add_parser("convert", help="read a log and write it as a gnomon HDF5 recording")
    s.add_argument("input", help="log file or folder")
    s.add_argument("out", help="recording file to write (.h5)")
    s.add_argument("--format", default="auto", choices=list(FORMATS))
    _add_log_options(s)
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_convert)

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
    s.add_argument("--align", help="correct the truth before scoring, fitted per trial from "
                                   "the gyro: 'lag' (time offset), 'body' (sensor-to-marker "
                                   "rotation), 'body,lag' or 'none' (default: tyrex body,lag; "
                                   "broad and DIR none)")
    s.add_argument("--mag", choices=["calibrated", "raw"],
                   help="tyrex: the OS-calibrated magnetometer (default) or the raw one")
    s.add_argument("--mag-calibration", choices=["self", "recording"],
                   help="tyrex, raw magnetometer: correct it by gnomon's calibration (gnomon "
                        "calibrate mag) fitted to each trial's own samples (self) or to the "
                        "data set's calibration recording of that phone and day (recording)")
    s.add_argument("--plot", help="write a bar chart, e.g. broad.png (tyrex, DIR: per group)")
    s.add_argument("--json", action="store_true", help="print the JSON result")
    _add_quiet_option(s)
    s.set_defaults(func=cmd_benchmark)

    s = sub.add_parser("bench", help="speed of gnomon's filters vs the reference libraries")
    s.add_argument("--samples", type=int, default=1_000_000, help="samples in the recording")
    s.add_argument("--repeats", type=int, default=5, help="interleaved repetitions (median)")
    s.add_argument("--runs", type=int, default=1000, help="runs of the batch-over-runs kernel")
    s.add_argument("--quick", action="store_true", help="200,000 samples, 3 repeats")
    s.add_argument("--json", action="store_true", help="print the JSON result")
    _add_quiet_option(s)
    s.set_defaults(func=cmd_bench)

    s = sub.add_parser("scenarios", help="list the scenario presets")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_scenarios)

    s = sub.add_parser("simulate", help="simulate a scenario into a gnomon HDF5 recording")
    s.add_argument("scenario", help="preset name (see `gnomon scenarios`) or a YAML file")
    s.add_argument("--out", required=True, help="recording file to write (.h5)")
    s.add_argument("--seed", type=int, default=None, help="override the scenario's seed")
    s.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a scenario value by its dotted key")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_simulate)

    s = sub.add_parser("campaign", help="Monte Carlo campaign of a scenario (local or Dask)")
    s.add_argument("scenario", help="preset name or scenario YAML")
    s.add_argument("--runs", type=int, required=True, help="number of runs")
    s.add_argument("--out", help="directory for results.parquet and campaign.json")
    s.add_argument("--vary", action="append", metavar="KEY=DIST",
                   help="e.g. spacecraft.inertia_error_pct=normal(0,2), uniform(a,b), "
                        "choice(a,b), a constant; filter.NAME.PARAM for filter parameters")
    s.add_argument("--executor", default="local", choices=["local", "dask", "serial"])
    s.add_argument("--scheduler", help="Dask scheduler address tcp://host:port "
                                       "(default: start a LocalCluster)")
    s.add_argument("--workers", type=int, help="worker processes")
    s.add_argument("--resume", action="store_true", help="run only what is missing in --out")
    s.add_argument("--only", type=int, metavar="INDEX", help="re-run one run alone")
    s.add_argument("--seed", type=int, default=0, help="root seed (SeedSequence)")
    s.add_argument("--filter", action="append", help="filter(s) to run on each simulation")
    s.add_argument("--report", action="store_true",
                   help="then write OUT/report.html: error CDFs, the attitude-knowledge "
                        "budget (per axis, 3-sigma and p99, sunlit and eclipse), the worst "
                        "runs with their re-run command, sensitivities, run time, failures")
    s.add_argument("--json", action="store_true")
    _add_quiet_option(s)
    s.set_defaults(func=cmd_campaign)

    s = sub.add_parser("report", help="the HTML report of a campaign directory (report.html) "
                                      "or of a reproduction (index.html, built again)")
    s.add_argument("directory", help="a `gnomon campaign --out` or `gnomon reproduce --out` "
                                     "directory")
    s.set_defaults(func=cmd_report)

    s = sub.add_parser("datasets", help="the real data sets: source, licence, bundled or "
                                        "fetched; `gnomon datasets fetch NAME` downloads one")
    s.add_argument("action", nargs="?", choices=["list", "fetch"], default="list")
    s.add_argument("name", nargs="?", help="data set to fetch (broad, tyrex, logs, images)")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_datasets)

    from gnomon.reproduce import available as available_papers

    available = available_papers()
    s = sub.add_parser("reproduce", help="reproduce a paper's experiments: "
                                         + ", ".join(available + ["all"]))
    s.add_argument("paper", choices=available + ["all"])
    s.add_argument("--out", help="directory for figures, metrics.json (and the HTML report)")
    s.add_argument("--quick", action="store_true", help="short version (for CI)")
    s.add_argument("--json", action="store_true", help="print the result as JSON only")
    _add_quiet_option(s)
    s.set_defaults(func=cmd_reproduce)
    return p


def main(argv=None) -> int:
    from gnomon import kernels

    if kernels.in_source_checkout():  # kernel sources may have changed under their caches
        kernels.drop_stale_caches()
    parser = build_parser()
    args = parser.parse_args(None if argv is None else [str(a) for a in argv])
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    try:
        return args.func(args)
    except InputError as e:
        print(f"gnomon: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("gnomon: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
