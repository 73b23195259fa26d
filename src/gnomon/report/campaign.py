"""The HTML report of a Monte Carlo campaign (``gnomon campaign ... --report``,
``gnomon report CAMPAIGN_DIR``).

One page, ``CAMPAIGN_DIR/report.html``, its figures beside it in ``CAMPAIGN_DIR/report/``
(PNG, linked by relative paths, so the directory can be moved or served as it is):

* the campaign: scenario, runs, failures, root seed, varied parameters, filters;
* the error distribution of every filter: empirical CDFs over the runs;
* the attitude-knowledge budget of every filter: per body axis and total, 3σ and p99,
  over all samples, sunlit and in eclipse (how each is computed:
  :mod:`gnomon.campaign.budget`, stated on the page);
* the worst runs, each with the exact command that re-runs it alone
  (:mod:`gnomon.campaign.rerun`);
* the sensitivity of each error to every varied parameter (Spearman ρ,
  :mod:`gnomon.campaign.sensitivity`) and scatter plots of the strongest pairs;
* run time and failures.

Everything is read from ``results.parquet`` and ``campaign.json``; no absolute path of
the machine appears on the page.
"""

from __future__ import annotations

import html
import math
from collections import Counter
from pathlib import Path

import numpy as np

from gnomon.report.html import page
from gnomon.report.values import sig

__all__ = ["build_campaign_report", "REPORT_HTML", "REPORT_FIGURES", "HEADLINE_METRICS"]

REPORT_HTML = "report.html"
REPORT_FIGURES = "report"
#: the metrics (per filter, without ``F.``) whose sensitivity is ranked, when present
HEADLINE_METRICS = ("rms_deg", "max_deg", "sunlit_rms_deg", "eclipse_rms_deg",
                    "eclipse_max_deg", "heading_rms_deg", "inclination_rms_deg",
                    "x_rms_deg", "y_rms_deg", "z_rms_deg")
#: worst runs listed per filter; scatter plots drawn
_WORST = 3
_SCATTERS = 4
_DPI = 80


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _esc(x) -> str:
    return html.escape(str(x))


def _num(v, digits: int = 3) -> str:
    return _esc(sig(v, digits)) if isinstance(v, float | int | np.floating) else _esc(v)


def _table(head: list[str] | None, rows: list[list[str]]) -> str:
    """An HTML table (no header row when ``head`` is None); cells are HTML already."""
    th = "<tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>" if head else ""
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table>{th}{body}</table>"


def _figure(src: str, caption: str) -> str:
    return (f"<figure><img src='{_esc(src)}' alt='{_esc(caption)}'>"
            f"<figcaption>{_esc(caption)}</figcaption></figure>")


# ------------------------------------------------------------------ figures
def _cdf_figure(ok, filters: list[str], path: Path) -> list[str]:
    """Empirical CDFs over the runs of the RMS error and the peak error (and the eclipse
    peak, with a sun sensor), one line per filter. Returns the metrics drawn."""
    plt = _plt()
    from matplotlib.ticker import FuncFormatter, NullFormatter

    metrics = [m for m in ("rms_deg", "max_deg", "eclipse_max_deg")
               if any(f"{f}.{m}" in ok for f in filters)]
    fig, axes = plt.subplots(1, len(metrics), figsize=(4.2 * len(metrics), 3.4), squeeze=False)
    for ax, m in zip(axes[0], metrics, strict=True):
        for f in filters:
            if f"{f}.{m}" not in ok:
                continue
            v = np.sort(ok[f"{f}.{m}"].to_numpy(float))
            v = v[np.isfinite(v)]
            if v.size:
                ax.step(v, np.arange(1, v.size + 1) / v.size, where="post", lw=1.2, label=f)
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel(f"per-run {m.replace('_deg', '').replace('_', ' ')} (deg)")
        ax.set_ylabel("fraction of runs ≤ x")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=_DPI)
    plt.close(fig)
    return metrics


def _scatter_figure(ok, corr, path: Path) -> None:
    plt = _plt()
    x = ok[corr.param].to_numpy(float)
    y = ok[corr.metric].to_numpy(float)
    fig, ax = plt.subplots(figsize=(4.2, 3.2))
    ax.plot(x, y, ".", ms=3, alpha=0.6)
    ax.set_xlabel(corr.param.removeprefix("param."))
    ax.set_ylabel(corr.metric)
    ax.set_title(f"Spearman ρ = {corr.rho:+.2f} over {corr.runs} runs", fontsize=9)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=_DPI)
    plt.close(fig)


# ------------------------------------------------------------------ sections
def _overview(manifest: dict, table, ok, filters, elapsed_s) -> str:
    from gnomon.campaign.rerun import scenario_argument

    scenario = scenario_argument(manifest) or "(a scenario given as a dict; see campaign.json)"
    vary = manifest.get("vary") or {}
    rows = [["scenario", _esc(scenario)], ["runs", f"{len(table)} of {manifest.get('runs')}"],
            ["successful", str(len(ok))], ["failed", str(len(table) - len(ok))],
            ["root seed", _esc(manifest.get("root_seed", 0))],
            ["varied", "<br>".join(f"<code>{_esc(k)}={_esc(v)}</code>" for k, v in vary.items())
             or "nothing (only the noise seeds differ)"],
            ["filters", _esc(", ".join(filters))]]
    if elapsed_s is not None:
        rows.append(["wall time of the campaign", f"{sig(elapsed_s, 3)} s"])
    return "<h2>Campaign</h2>" + _table(None, rows)


def _budget_section(ok, filters) -> str:
    from gnomon.campaign.budget import AXES, budget

    parts = ["<h2>Attitude-knowledge budget</h2>",
             "<p>Per body axis (the rotation vector of conj(q_true) ⊗ q_est, in the true "
             "body axes) and total (the error angle), over the samples after the settling "
             "time: all of them, the sunlit ones and those in eclipse. "
             "<b>3σ</b> = 3 · √(mean over runs of the run's RMS²): 3 × the RMS of all "
             "samples pooled, every run weighing the same; an RMS, so a bias counts in it "
             "(for zero-mean Gaussian errors, exactly 3σ). <b>p99</b> = the 99th "
             "percentile over runs of each run's 99th percentile of |error|: 99 % of the "
             "runs keep 99 % of their samples within it. Degrees; successful runs only.</p>"]
    head = ["phase", "runs"] + [f"{a} 3σ" for a in AXES] + [f"{a} p99" for a in AXES]
    for f in filters:
        rows = budget(ok, f)
        if not rows:
            continue
        cells = [[_esc(r["phase"]), str(r["runs"])]
                 + [_num(r[f"{a}_3sigma_deg"]) for a in AXES]
                 + [_num(r[f"{a}_p99_deg"]) for a in AXES] for r in rows]
        parts.append(f"<h3>{_esc(f)}</h3>" + _table(head, cells))
    return "".join(parts)


def _worst_section(ok, filters, manifest, campaign_dir_name) -> str:
    from gnomon.campaign.rerun import rerun_command, rerun_python

    params = [c for c in ok.columns if c.startswith("param.")]
    rows = []
    for f in filters:
        col = f"{f}.rms_deg"
        worst = ok.sort_values(col, ascending=False, na_position="last").head(_WORST)
        for _, r in worst.iterrows():
            idx = int(r["index"])
            cmd = rerun_command(manifest, idx) or rerun_python(manifest, idx, campaign_dir_name)
            drawn = ", ".join(f"{p.removeprefix('param.')}={_num(r[p])}" for p in params)
            rows.append([_esc(f), str(idx), _num(r[col]), _num(r.get(f"{f}.max_deg", math.nan)),
                         drawn or "—", f"<code>{_esc(cmd)}</code>"])
    return ("<h2>Worst runs</h2><p>The runs of largest RMS error of each filter, and the "
            "command that re-runs one alone (same seed, same drawn parameters: the same "
            "metrics).</p>"
            + _table(["filter", "run", "RMS (deg)", "max (deg)", "drawn parameters",
                      "re-run it alone"], rows))


def _rho_cell(c, noise: float) -> str:
    """ρ to 2 digits: grey below the no-dependence level, bold from 0.5."""
    if c is None or not math.isfinite(c.rho):
        return "—"
    cls = "na" if abs(c.rho) < noise else ("strong" if abs(c.rho) >= 0.5 else "")
    text = _num(c.rho, 2)
    return f"<span class='{cls}'>{text}</span>" if cls else text


def _sensitivity_section(ok, filters, fig_dir: Path, rel: str) -> str:
    from gnomon.campaign.sensitivity import sensitivity, varied_parameters

    out = ["<h2>Sensitivity: which parameter drives which error</h2>"]
    if not varied_parameters(ok):
        out.append("<p>No parameter was varied (<code>--vary KEY=DIST</code>): only the "
                   "noise seeds differ between runs, so there is nothing to rank.</p>")
        return "".join(out)
    metrics = [f"{f}.{m}" for f in filters for m in HEADLINE_METRICS if f"{f}.{m}" in ok]
    s = sensitivity(ok, metrics)
    n = len(ok)
    noise = 2.0 / math.sqrt(n) if n else math.nan
    out.append("<p>Spearman rank correlation ρ of each error metric with each varied "
               "parameter over the successful runs (+1: the error grows with the parameter "
               f"monotonically; over {n} runs, |ρ| below about {sig(noise, 2)} is "
               "indistinguishable from no dependence: grey; |ρ| ≥ 0.5 in bold).</p>")
    params = varied_parameters(ok)
    ranked = [p for p in params if p not in s.skipped]
    cell = {(c.param, c.metric): c for c in s.correlations}
    for f in filters:
        mets = [m for m in metrics if m.startswith(f + ".")]
        rows = [[_esc(m.removeprefix(f + "."))] + [
            _rho_cell(cell.get((p, m)), noise) for p in ranked] for m in mets]
        if ranked:
            out.append(f"<h3>{_esc(f)}</h3>" + _table(
                ["metric"] + [_esc(p.removeprefix("param.")) for p in ranked], rows))
    for p, why in s.skipped.items():
        out.append(f"<p><code>{_esc(p.removeprefix('param.'))}</code>: {_esc(why)}.</p>")
    strongest = s.strongest(_SCATTERS, min_abs_rho=noise if math.isfinite(noise) else 0.0)
    if strongest:
        out.append("<h3>The strongest dependencies</h3>")
        for k, c in enumerate(strongest, 1):
            name = f"scatter-{k}.png"
            _scatter_figure(ok, c, fig_dir / name)
            out.append(_figure(f"{rel}/{name}", f"{c.metric} against "
                               f"{c.param.removeprefix('param.')}: ρ = {c.rho:+.2f}"))
    return "".join(out)


def _time_section(table, manifest, campaign_dir_name) -> str:
    from gnomon.campaign.rerun import rerun_command, rerun_python

    out = ["<h2>Run time and failures</h2>"]
    rows = []
    for col, what in (("elapsed_s", "wall time per run (s)"), ("cpu_s", "CPU time per run (s)")):
        if col in table and len(table):
            v = table[col].to_numpy(float)
            v = v[np.isfinite(v)]
            if v.size:
                rows.append([what, _num(float(v.mean())), _num(float(np.median(v))),
                             _num(float(np.percentile(v, 95))), _num(float(v.max())),
                             _num(float(v.sum()))])
    if rows:
        out.append("<p>Runs of a chunk share one batch call; each gets its share of the "
                   "chunk's time.</p>"
                   + _table(["", "mean", "median", "p95", "max", "sum"], rows))
    failed = table[table["status"] != "ok"] if "status" in table else table.iloc[:0]
    if not len(failed):
        out.append("<p>No run failed.</p>")
        return "".join(out)
    groups = Counter(str(e) for e in failed["error"])
    frows = []
    for err, count in groups.most_common():
        idx = failed[failed["error"].astype(str) == err]["index"].astype(int).tolist()
        first = idx[0]
        cmd = rerun_command(manifest, first) or rerun_python(manifest, first, campaign_dir_name)
        shown = ", ".join(map(str, idx[:10])) + (" …" if len(idx) > 10 else "")
        frows.append([str(count), _esc(err), _esc(shown), f"<code>{_esc(cmd)}</code>"])
    out.append(f"<p>{len(failed)} run(s) failed.</p>"
               + _table(["runs", "error", "run indices", "re-run the first alone"], frows))
    return "".join(out)


def build_campaign_report(campaign_dir, elapsed_s: float | None = None) -> Path:
    """Write ``report.html`` and its figures into the campaign directory ``campaign_dir``
    (one that ``gnomon campaign --out`` wrote); returns the page's path.

    ``elapsed_s``: the campaign's wall time (s), shown when given (a campaign resumed
    several times has no single one). Raises ``InputError`` when ``campaign_dir`` holds no
    campaign."""
    from gnomon.campaign import read_manifest, read_results
    from gnomon.campaign.budget import filters_of, ok_runs

    cdir = Path(campaign_dir)
    manifest = read_manifest(cdir)
    table = read_results(cdir)
    ok = ok_runs(table)
    filters = filters_of(table)
    fig_dir = cdir / REPORT_FIGURES
    fig_dir.mkdir(parents=True, exist_ok=True)
    for old in fig_dir.glob("*.png"):   # figures of an earlier report of this campaign
        old.unlink()
    name = cdir.resolve().name
    body = [f"<h1>Campaign {_esc(name)}</h1>", _overview(manifest, table, ok, filters, elapsed_s)]
    if len(ok) and filters:
        drawn = _cdf_figure(ok, filters, fig_dir / "cdf.png")
        body.append("<h2>Error distribution</h2>"
                    + _figure(f"{REPORT_FIGURES}/cdf.png", "fraction of runs whose "
                              + ", ".join(m.replace("_deg", "").replace("_", " ")
                                          for m in drawn)
                              + " error is at most x, per filter (successful runs)"))
        body.append(_budget_section(ok, filters))
        body.append(_worst_section(ok, filters, manifest, name))
        body.append(_sensitivity_section(ok, filters, fig_dir, REPORT_FIGURES))
    else:
        body.append("<p>No successful run with a filter's metrics: no distribution, budget "
                    "or sensitivity.</p>")
    body.append(_time_section(table, manifest, name))
    path = cdir / REPORT_HTML
    path.write_text(page(f"gnomon: campaign {name}", "".join(body), home=None))
    return path
