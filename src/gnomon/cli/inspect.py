"""``gnomon inspect`` (what a log holds) and ``gnomon convert`` (a log to a gnomon HDF5
recording)."""

from __future__ import annotations

import json
import sys

from gnomon.cli.common import (
    add_format_option,
    add_log_options,
    add_map_option,
    log_options,
    print_json,
)
from gnomon.errors import InputError


def add_parser(sub) -> None:
    s = sub.add_parser("inspect", help="what a log holds: sensors, rates, gaps, units, the "
                                       "device's own estimate, topics/instances")
    s.add_argument("input", help="log file or folder (ULog, DataFlash, ROS bag, phone, ...)")
    add_format_option(s)
    add_log_options(s)
    s.add_argument("--json", action="store_true", help="machine-readable output")
    s.add_argument("--write-map", metavar="MAP.yaml",
                   help="propose a map for a table of any layout (CSV/TSV, .mat, .npz, "
                        "Parquet: time, gyro, accelerometer, magnetometer, reference "
                        "quaternion, units, with the evidence) and write it (exit 2 when no "
                        "time, gyro or accelerometer is found); proposed anyway when the "
                        "file's layout is not one gnomon knows")
    add_map_option(s)
    s.set_defaults(func=run_inspect)

    s = sub.add_parser("convert", help="read a log and write it as a gnomon HDF5 recording "
                                       "(or a gnomon CSV)")
    s.add_argument("input", help="log file or folder")
    s.add_argument("out", help="recording file to write (.h5; .csv: one row per gyro sample, "
                               "SI units and uT, the other sensors in their arrival rows, "
                               "as an exported filter's gnomon_run reads it)")
    add_format_option(s)
    add_log_options(s)
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=run_convert)


def run_inspect(args) -> int:
    """``gnomon.io.inspect(path, format, topic=, instance=)``: what a log holds. A table of
    a layout no reader knows (or ``--write-map``): ``gnomon.io.mapping.propose_map(path)``,
    ``write_map``, and what the file holds read with it (``--map``: read with that one)."""
    from gnomon.io import inspect

    if args.map:
        from gnomon.io.mapping import read_mapped
        from gnomon.io.summary import summarise

        if args.write_map:
            raise InputError("--map reads with a map, --write-map proposes one: give one",
                             field="--write-map")
        info = {**summarise(read_mapped(args.input, args.map), str(args.input), "map"),
                "proposed_map": None}
    elif args.write_map:
        return _propose(args, None)
    else:
        try:
            info = inspect(args.input, format=args.format, **log_options(args))
        except InputError as err:
            if not (_layout_unknown(err) and _mappable(args)):
                raise
            return _propose(args, err)
        info["proposed_map"] = None
    if args.json:
        print_json(info)
        return 0
    _print_info(info)
    return 0


#: the readers' messages that mean "not a layout I know" (not a damaged file)
_LAYOUT_MESSAGES = ("missing column", "no gyro variable", "no accelerometer variable",
                    "no time (", "cannot tell the format", "a zip file, but not")


def _layout_unknown(err: InputError) -> bool:
    """Whether a reader refused the file for its layout (names it does not know), not for
    bad values (those keep their error, naming the row)."""
    header_wrong = "cells, header has" in err.message and (err.row or 0) <= 2  # metadata
    return err.message.startswith(_LAYOUT_MESSAGES) or header_wrong


def _mappable(args) -> bool:
    """Whether a file the readers refused is a table a map may read (CSV/TSV text, .mat,
    .npz, Parquet; not a log format, not a folder)."""
    from gnomon.io import detect_format
    from gnomon.io.table import table_kind

    if args.format not in ("auto", "csv", "mat") or log_options(args):
        return False
    try:
        table_kind(args.input)
    except InputError:
        return False
    try:
        return detect_format(args.input) in ("csv", "mat")
    except InputError:
        return True  # .npz, Parquet: no reader knows them


def _propose(args, why: InputError | None) -> int:
    """Propose a map (:func:`gnomon.io.mapping.propose_map`), print it with its evidence,
    write it (``--write-map``) and summarise the file read with it. Exit 2 (an InputError)
    naming what is missing when there is no time, gyro or accelerometer."""
    from gnomon.io.mapping import missing, propose_map, read_mapped, write_map
    from gnomon.io.summary import summarise

    m = propose_map(args.input)
    lack = missing(m)
    info, read_error = None, None
    if not lack:
        if args.write_map:
            write_map(args.write_map, m)
        try:
            info = summarise(read_mapped(args.input, m, map_name="the proposed map"),
                             str(args.input), "map")
        except InputError as err:
            read_error = str(err)
    if args.json:
        out = info or {"file": str(args.input), "format": "map"}
        out.update(proposed_map=m, missing=lack, known_layout_error=None if why is None
                   else str(why), map_read_error=read_error,
                   wrote_map=str(args.write_map) if args.write_map and not lack else None)
        print_json(out)
    else:
        head = "" if why is None else f"not a layout gnomon knows ({why.message}); "
        print(f"{args.input}: {head}proposed map ({m['kind']}):")
        _print_map(m)
        if args.write_map and not lack:
            print(f"wrote {args.write_map} (use it: gnomon estimate FILE --map "
                  f"{args.write_map}; edit it where the evidence is wrong)")
        elif not lack:
            print("save it with --write-map MAP.yaml")
        if info is not None:
            _print_info(info)
    if read_error is not None:
        print(f"warning: reading with the proposed map fails: {read_error}", file=sys.stderr)
    if lack:
        from gnomon.io.table import load_table

        names = load_table(args.input).names()
        raise InputError(f"no {', '.join(lack)} found (a map needs time, gyro and "
                         f"accelerometer); the file has: {', '.join(names) or 'no numbers'}",
                         file=str(args.input), field=lack[0])
    return 0


def _print_map(m: dict) -> None:
    """Each entry of a proposed map on one line, its evidence below it."""
    for key in ("time", "gyro", "accel", "mag", "truth", "mask"):
        e = m.get(key)
        if e is None and key == "mask":
            continue
        if e is None:
            print(f"  {key:6s} (not found)")
        else:
            where = (", ".join(e["columns"]) if "columns" in e else e.get("array")
                     or e.get("column") or f"rate {e.get('rate_hz'):g} Hz")
            what = [e[k] for k in ("unit", "order", "frame") if e.get(k)]
            if e.get("axes") and e["axes"] != ["x", "y", "z"]:
                what.append("axes [" + ", ".join(e["axes"]) + "]")
            if e.get("valid"):
                what.append(f"valid: {e['valid']}")
            print(f"  {key:6s} {where}" + (f"  ({'; '.join(what)})" if what else ""))
        for line in m.get("evidence", {}).get(key, []):
            print(f"         - {line}")
    for line in m.get("evidence", {}).get("unused", []):
        print(f"  {line}")


def _print_info(info: dict) -> None:
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
    if info.get("onboard_absent"):
        print(f"  own estimate: none ({info['onboard_absent']})")
    if info.get("dropped"):
        print(f"  dropped: {_counts(info['dropped'])} (samples with a non-finite value; "
              "--strict refuses them)")
    if info.get("truncated"):
        c = info["truncated"]
        print(f"  truncated: the file ends inside a message at byte {c['at_byte']} "
              f"({c['bytes_present']} of {c['message_bytes']} bytes); data up to "
              f"t = {c['data_up_to_s']:.3f} s")
    if info.get("available"):
        print(f"  available: {json.dumps(info['available'], default=str)}")
    for line in info["assumed"]:
        print(f"  assumed: {line}")


def _counts(dropped: dict) -> str:
    """``{"gyro": 2, "mag": 5}`` as ``gyro 2, mag 5``."""
    return ", ".join(f"{k} {n}" for k, n in dropped.items())


def run_convert(args) -> int:
    """``gnomon.io.write(out, gnomon.io.read(path, format, topic=, instance=))``."""
    from gnomon.io import read, write

    rec = read(args.input, format=args.format, **log_options(args))
    write(args.out, rec)
    csv = str(args.out).lower().endswith(".csv")
    summary = {"input": str(args.input), "out": str(args.out), "samples": len(rec),
               "format": "csv" if csv else "gnomon-recording",
               **({} if csv else {"format_version": 2})}
    if args.json:
        print_json(summary)
    else:
        print(f"wrote {args.out}: {len(rec)} gyro samples from {args.input}")
    return 0
