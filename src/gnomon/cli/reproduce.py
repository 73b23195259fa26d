"""``gnomon reproduce NNN|all``: reproduce a paper's experiments (figures, metrics, report)."""

from __future__ import annotations

import sys
from pathlib import Path

from gnomon.cli.common import add_quiet_option, print_json, progress_wanted
from gnomon.errors import InputError


def add_parser(sub) -> None:
    from gnomon.reproduce import available as available_papers

    available = available_papers()
    s = sub.add_parser("reproduce", help="reproduce a paper's experiments: "
                                         + ", ".join(available + ["all"]))
    s.add_argument("paper", choices=available + ["all"])
    s.add_argument("--out", help="directory for figures, metrics.json (and the HTML report)")
    s.add_argument("--quick", action="store_true", help="short version (for CI)")
    s.add_argument("--json", action="store_true", help="print the result as JSON only")
    s.add_argument("--workers", type=int, default=1,
                   help="with 'all': papers reproduced side by side, each in its own "
                        "process (default 1: one after the other, with each paper's "
                        "progress; the speeds the papers measure are then not shared "
                        "with another paper's work)")
    add_quiet_option(s)
    s.set_defaults(func=run)


def run(args) -> int:
    """``gnomon.reproduce.pNNN.run(out_dir, quick)`` (``all``: ``gnomon.reproduce.run_all``)."""
    from gnomon import reproduce

    out = Path(args.out) if args.out else None
    if args.workers < 1:
        raise InputError(f"must be >= 1, got {args.workers}", field="--workers")
    if args.paper == "all":
        res = reproduce.run_all(out_dir=out, quick=args.quick, progress=progress_wanted(args),
                                jobs=args.workers)
    else:
        res = reproduce.run(args.paper, out_dir=out, quick=args.quick,
                            progress=progress_wanted(args))
    print_json(res)
    if not args.json and out is not None:
        print(f"wrote {out}")
    failed = [p for p, r in res.items() if "error" in r] if args.paper == "all" else []
    if failed:  # the others ran and are in the report; say which did not, and fail
        print(f"gnomon: error: reproduction of paper(s) {', '.join(failed)} failed: "
              f"{'; '.join(res[p]['error'] for p in failed)}", file=sys.stderr)
        return 1
    return 0
