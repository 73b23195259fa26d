"""``gnomon estimate``: run a filter on a recording or log, score it against its truth,
write and plot the estimate."""

from __future__ import annotations

import math

from gnomon.cli.common import (
    add_backend_option,
    add_csv_options,
    add_format_option,
    add_log_options,
    add_phone_mag_option,
    fall_back_from_c,
    parse_pairs,
    print_json,
    raw_phone_mag,
    read_input,
)
from gnomon.errors import InputError


def add_parser(sub) -> None:
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
    s.add_argument("--noise", metavar="NOISE.json",
                   help="the filter's noise parameters from `gnomon calibrate imu --out` "
                        "(Allan deviation of a static log; --param overrides; the JSON's "
                        "noise_params says which parameter came from which term)")
    add_format_option(s)
    add_log_options(s)
    s.add_argument("--out", help="write the estimate (.csv or .h5)")
    s.add_argument("--plot", help="write a figure (attitude, errors, bias, flags), e.g. out.png")
    s.add_argument("--compare", choices=["onboard"],
                   help="onboard: the RMS difference from the device's own attitude estimate "
                        "(PX4, ArduPilot, phone OS, Xsens), heading references matched")
    s.add_argument("--align", metavar="auto|world,body,lag|none|FILE.json", default=None,
                   help="turn the truth onto the sensor before scoring, fitted from the "
                        "gyro, accelerometer and magnetometer against it: lag (clock "
                        "offset), body (sensor-to-marker rotation), world (the reference "
                        "world to ENU: any up axis, heading to magnetic north); auto: what "
                        "the motion determines; FILE.json: a saved fit (--save-alignment); "
                        "default none")
    s.add_argument("--save-alignment", metavar="FILE.json",
                   help="write the fitted alignment for reuse (--align FILE.json)")
    s.add_argument("--mag-calibration", metavar="CAL.json|self",
                   help="correct the magnetometer first: a calibration from `gnomon "
                        "calibrate mag --out` or 'self' (fitted to this log's own samples)")
    add_phone_mag_option(s)
    add_backend_option(s, "the filters whose export reports all their signals (robust-ahrs, "
                          "mahony, tilt-cf, eskf-r3, eskf-r6)")
    s.add_argument("--precision", default="double", choices=["double", "float"],
                   help="when the C runs: the C's real_t")
    s.add_argument("--json", action="store_true", help="print a JSON summary")
    add_csv_options(s)
    s.set_defaults(func=run)


def run(args) -> int:
    """``registry.create(name, params).run(gnomon.io.read(path))`` and ``metrics.score``."""
    from gnomon.estimators import registry
    from gnomon.io.summary import reader_notes
    from gnomon.metrics import score

    if args.mag_calibration:
        raw_phone_mag(args, "--mag-calibration corrects")
    rec = read_input(args)
    notes = reader_notes(rec)  # what the reader noted: dropped, truncated, assumed
    rec, alignment = _align(rec, args.align, args.save_alignment)
    cal_summary = None
    if args.mag_calibration:
        rec, cal_summary = _apply_mag_calibration(rec, args.mag_calibration)
    args.filter, chosen = _estimate_filter(args.filter, args.offline, rec)
    params, noise_summary = parse_pairs(args.param), None
    if args.noise:  # gnomon calibrate imu --out: the noise terms as filter parameters
        params, noise_summary = _noise_params(args.noise, args.filter, rec, params)
    est, backend, why = _run_filter(args, rec, params)
    summary = {"input": str(args.input), "filter": args.filter, "samples": len(rec),
               "backend": backend, **({"backend_because": why} if why else {}),
               **({"filter_chosen_because": chosen} if chosen else {}),
               "params": est.params,
               "warnings": _limit_warnings(est, getattr(registry.get(args.filter), "limits",
                                                        {})), **notes}
    if cal_summary is not None:
        summary["mag_calibration"] = cal_summary
    if alignment is not None:
        summary["alignment"] = alignment
    if noise_summary is not None:
        summary["noise_params"] = noise_summary
    if rec.q_true is not None:
        summary["errors"] = score(rec.q_true, est.q, rec.score_mask)
    matched = None
    if args.compare == "onboard" and rec.q_onboard is None:  # said, not an error
        summary.update(onboard=None, onboard_absent=rec.meta.get("onboard_absent") or
                       "the recording holds no attitude estimate of the device's own")
    elif args.compare == "onboard":
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
    else:
        _print_summary(summary)
    return 0


def _run_filter(args, rec, params: dict):
    """The estimate of ``args.filter`` on ``rec``, the backend that made it (``c
    (double|float)`` or ``python``) and, for ``--backend auto``, why
    (``gnomon.export.backend.auto_backend``; a C build that fails then falls back to
    python, said on stderr; None otherwise)."""
    from gnomon.estimators import registry

    backend, why = args.backend, None
    if backend == "auto":
        from gnomon.export.backend import auto_backend

        backend, why = auto_backend(args.filter)
    if backend == "c":  # the exported C flight code, built once into the cache
        from gnomon.export.backend import run_c

        try:
            return (run_c(args.filter, rec, args.precision, params), f"c ({args.precision})",
                    why)
        except (InputError, OSError) as e:  # the build, or a parameter the C does not take
            what = fall_back_from_c(args.backend, e)
            if what is None:
                raise
            why = f"{what}: {e}"
    return registry.create(args.filter, params).run(rec), "python", why


def _print_summary(s: dict) -> None:
    """The summary of :func:`run` as text."""
    print(f"{s['filter']} on {s['input']}: {s['samples']} samples ({s['backend']})")
    if "filter_chosen_because" in s:
        print(f"  (default filter: {s['filter_chosen_because']}; --filter NAME to choose)")
    if "mag_calibration" in s:
        cal = s["mag_calibration"]
        print(f"  magnetometer calibration ({cal['from']}): {cal['model']}, "
              f"offset {[round(v, 2) for v in cal['offset_uT']]} uT, coverage "
              f"{cal['coverage']:.2f}, residual {cal['residual_uT']:.2f} uT")
    for note in s.get("noise_params", {}).get("notes", []):
        print(f"  noise ({s['noise_params']['from']}): {note}")
    for w in s["warnings"]:
        print(f"  warning: {w['message']}")
    for line in s.get("notes", []):
        print(f"  note: {line}")
    if "alignment" in s:
        _print_alignment(s["alignment"])
    if "errors" in s:
        e = s["errors"]
        print(f"  RMS error over {e['samples']} scored samples: total {e['total_deg']:.3f} deg, "
              f"heading {e['heading_deg']:.3f} deg, inclination {e['inclination_deg']:.3f} deg")
        print(f"  per axis: roll {e['roll_deg']:.3f}, pitch {e['pitch_deg']:.3f}, "
              f"yaw {e['yaw_deg']:.3f} deg; max {e['max_deg']:.3f} deg")
    else:
        print("  (no truth in the input: no error summary)")
    if s.get("onboard_absent"):
        print(f"  no comparison with the device's own estimate: {s['onboard_absent']}")
    if s.get("onboard"):
        o = s["onboard"]
        print(f"  vs the device's own estimate over {o['samples']} samples: total "
              f"{o['total_deg']:.3f} deg, heading {o['heading_deg']:.3f} deg, inclination "
              f"{o['inclination_deg']:.3f} deg ({o['heading_reference']})")
    for key in ("out", "plot"):
        if key in s:
            print(f"  wrote {s[key]}")


def _align(rec, align: str | None, save: str | None):
    """``rec`` with its truth aligned by ``--align`` (``gnomon.alignment.align_truth``)
    and the fit (None when not asked); ``save``: the fit written for reuse."""
    import dataclasses

    from gnomon.alignment import align_truth, fit_for, parse_align, save_alignment

    what = parse_align(align)
    if isinstance(what, dict):  # a saved fit; of a benchmark: this recording's trial
        from pathlib import Path

        what = fit_for(what, Path(rec.source or "").stem)
    if not what:
        if save:
            raise InputError("--save-alignment needs --align", field="--save-alignment")
        return rec, None
    if rec.q_true is None:
        raise InputError("the recording holds no truth (reference attitude) to align",
                         field="--align", file=rec.source or None)
    q, info = align_truth(rec, what)
    if save:
        save_alignment(save, info)
        info = {**info, "saved": str(save)}
    return dataclasses.replace(rec, q_true=q), info


def _print_alignment(a: dict) -> None:
    """The alignment of the truth as text lines."""
    if a.get("from_file"):
        print(f"  truth aligned by a saved fit: {', '.join(a['applied']) or 'nothing'}")
        return
    parts = []
    if "lag" in a["applied"]:
        parts.append(f"lag {1000 * a['lag_s']:+.1f} ms (rate correlation "
                     f"{a['lag_correlation']:.3f})")
    if "body" in a["applied"]:
        inv = ", the reference inverted (world to marker)" if a["reference_inverted"] else ""
        parts.append(f"sensor-to-marker rotation {a['misalignment_deg']:.2f} deg{inv}")
    if "world" in a["applied"]:
        up = ", ".join(f"{v:+.3f}" for v in a["world_up_in_world"])
        north = ("heading to magnetic north" if a["world_heading_from"] == "magnetometer"
                 else "the world's heading kept (no magnetometer)")
        parts.append(f"world up was ({up}), {north}")
    print(f"  truth aligned ({', '.join(a['applied']) or 'nothing'}): " + "; ".join(parts))
    print(f"    gyro vs reference rate: {a['rate_rms_deg_s_before']:.2f} -> "
          f"{a['rate_rms_deg_s']:.2f} deg/s RMS, correlation {a['rate_correlation']:.3f}"
          + (f"; gravity residual {a['world_gravity_residual_deg']:.2f} deg"
             if a.get("world_gravity_residual_deg") is not None else ""))
    for k, why in a["refused"].items():
        print(f"    not aligned: {k}: {why}")
    if "saved" in a:
        print(f"    wrote {a['saved']}")


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


def _noise_params(path: str, name: str, rec, params: dict) -> tuple[dict, dict]:
    """``gnomon.calibration.noise_params.noise_params(load_imu_noise(path), name,
    accelerometer rate)`` under the explicit ``params`` (``--param`` wins): (the filter's
    parameters, the JSON's ``noise_params``: ``from``, ``params`` (those set),
    ``overridden`` (by --param), ``notes``)."""
    from gnomon.calibration.imu_noise import load_imu_noise
    from gnomon.calibration.noise_params import noise_params

    rate = rec.rate_hz("accel") if rec.accel is not None else None
    from_noise, notes = noise_params(load_imu_noise(path), name, rate)
    overridden = sorted(k for k in from_noise if k in params)
    notes += [f"{k}: --param {k}={params[k]} overrides the noise file" for k in overridden]
    return {**from_noise, **params}, {"from": str(path), "params": from_noise,
                                      "overridden": overridden, "notes": notes}


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
