"""``gnomon campaign`` (Monte Carlo of a scenario, local or Dask) and ``gnomon report`` (the
HTML report of a campaign or a reproduction)."""

from __future__ import annotations

from pathlib import Path

from gnomon.cli.common import add_quiet_option, print_json, progress_wanted
from gnomon.errors import InputError


def add_parser(sub) -> None:
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
    add_quiet_option(s)
    s.set_defaults(func=run_campaign)

    s = sub.add_parser("report", help="the HTML report of a campaign directory (report.html) "
                                      "or of a reproduction (index.html, built again)")
    s.add_argument("directory", help="a `gnomon campaign --out` or `gnomon reproduce --out` "
                                     "directory")
    s.set_defaults(func=run_report)


def run_campaign(args) -> int:
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
                           progress=progress_wanted(args)).summary()
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


def run_report(args) -> int:
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
