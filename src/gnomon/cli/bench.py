"""``gnomon bench``: the speed of gnomon's filters against the reference libraries."""

from __future__ import annotations

from gnomon.cli.common import add_quiet_option, print_json, progress_wanted


def add_parser(sub) -> None:
    s = sub.add_parser("bench", help="speed of gnomon's filters vs the reference libraries")
    s.add_argument("--samples", type=int, default=1_000_000, help="samples in the recording")
    s.add_argument("--repeats", type=int, default=5, help="interleaved repetitions (median)")
    s.add_argument("--runs", type=int, default=1000, help="runs of the batch-over-runs kernel")
    s.add_argument("--quick", action="store_true", help="200,000 samples, 3 repeats")
    s.add_argument("--json", action="store_true", help="print the JSON result")
    add_quiet_option(s)
    s.set_defaults(func=run)


def run(args) -> int:
    """``gnomon.speed.run_bench(samples, repeats, runs, quick)``."""
    from gnomon.speed import markdown_table, per_sample_table, run_bench, simulation_line

    res = run_bench(samples=args.samples, repeats=args.repeats, runs=args.runs, quick=args.quick,
                    progress=progress_wanted(args))
    if args.json:
        print_json(res)
    else:
        print(markdown_table(res))
        print()
        print(per_sample_table(res))
        print()
        print(simulation_line(res))
    return 0
