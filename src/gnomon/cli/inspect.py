"""``gnomon inspect`` (what a log holds) and ``gnomon convert`` (a log to a gnomon HDF5
recording)."""

from __future__ import annotations

import json

from gnomon.cli.common import add_format_option, add_log_options, log_options, print_json


def add_parser(sub) -> None:
    s = sub.add_parser("inspect", help="what a log holds: sensors, rates, gaps, units, the "
                                       "device's own estimate, topics/instances")
    s.add_argument("input", help="log file or folder (ULog, DataFlash, ROS bag, phone, ...)")
    add_format_option(s)
    add_log_options(s)
    s.add_argument("--json", action="store_true", help="machine-readable output")
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
    """``gnomon.io.inspect(path, format, topic=, instance=)``: what a log holds."""
    from gnomon.io import inspect

    info = inspect(args.input, format=args.format, **log_options(args))
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
    return 0


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
