"""``gnomon export c``: a filter as a self-contained C99 library for a microcontroller or
flight computer, with a runner, a Makefile, a README and its measured cost."""

from __future__ import annotations

from gnomon.cli.common import parse_pairs, print_json


def add_parser(sub) -> None:
    s = sub.add_parser("export", help="a filter as C flight code (a C99 library, a runner, "
                                      "its cost)")
    esub = s.add_subparsers(dest="language", metavar="LANGUAGE")
    c = esub.add_parser(
        "c", help="C99: state and parameter structs, init, one update per sensor, getters",
        description="Write the filter's C twin into DIR: <filter>.h/.c (no heap, no globals, "
                    "no I/O; only math.h, stdint.h, stdbool.h), the chosen parameters baked "
                    "into <filter>_params.h, gnomon_run (a gnomon CSV on stdin, the attitude "
                    "on stdout; --bench), a Makefile and a README; then build it and write "
                    "DIR/cost.json (state and code bytes, ns and operations per update).")
    from gnomon.export import PRECISIONS, SPECS

    c.add_argument("--filter", required=True, choices=sorted(SPECS), help="the filter")
    c.add_argument("--precision", default="double", choices=list(PRECISIONS),
                   help="real_t: double (default) or float (single precision FPUs)")
    c.add_argument("--param", action="append", metavar="KEY=VALUE",
                   help="filter parameter (see `gnomon filters`)")
    c.add_argument("--out", required=True, metavar="DIR", help="folder to write")
    c.add_argument("--no-build", action="store_true",
                   help="only write the sources (no make, no cost.json)")
    c.add_argument("--json", action="store_true", help="print the summary as JSON")
    c.set_defaults(func=run_c)


def run_c(args) -> int:
    """``gnomon.export.export_c(filter, out, precision, params, build=not --no-build)``."""
    from gnomon.export import export_c

    summary = export_c(args.filter, args.out, args.precision, parse_pairs(args.param),
                       build=not args.no_build)
    if args.json:
        print_json(summary)
        return 0
    print(f"{summary['filter']} ({summary['precision']}) written to {summary['out']}: "
          f"{', '.join(summary['files'])}")
    cost = summary.get("cost")
    if cost:
        ops = cost.get("ops_per_update") or {}
        m4 = cost.get("code_bytes_cortex_m4f")
        print(f"  built: {cost['ns_per_update']:.1f} ns per update on this machine, state "
              f"{cost['state_bytes']} bytes, code {cost['code_bytes']} bytes"
              + (f" ({m4} on a Cortex-M4F)" if m4 else "")
              + (f", {ops['total']:.0f} operations per update" if ops else ""))
        print(f"  cost: {summary['out']}/cost.json; run: make -C {summary['out']} && "
              f"{summary['out']}/gnomon_run < rec.csv")
    return 0
