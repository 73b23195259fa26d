"""``gnomon compile``: compile filters for this machine now, before their first use."""

from __future__ import annotations

import sys

from gnomon.cli.common import print_json


def add_parser(sub) -> None:
    s = sub.add_parser(
        "compile", help="compile filters for this machine now (a container image, a CI cache, "
                        "a cluster before its workers), in parallel processes")
    s.add_argument("targets", nargs="*", metavar="TARGET",
                   help="filter names, 'simulation', 'scoring' (default: all)")
    s.add_argument("--workers", type=int, default=None,
                   help="processes compiling side by side (default: the CPU count)")
    s.add_argument("--json", action="store_true", help="print the JSON result")
    s.set_defaults(func=run)


def run(args) -> int:
    """``gnomon.precompile.precompile(targets, workers)``; exit 1 if a target failed."""
    from gnomon.precompile import precompile

    def say(name, seconds, error):
        if not args.json:
            print(f"{name}: {'failed: ' + error if error else f'{seconds:.1f} s'}",
                  file=sys.stderr if error else sys.stdout, flush=True)

    res = precompile(args.targets or None, workers=args.workers, progress=say)
    if args.json:
        print_json(res)
    else:
        print(f"{len(res['targets'])} targets in {res['wall_s']:.1f} s on {res['workers']} "
              f"processes (later runs load them from the cache)")
    return 1 if any(t["error"] for t in res["targets"].values()) else 0
