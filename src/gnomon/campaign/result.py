"""What a campaign gives back: the table (:class:`CampaignResult`) and its summary.

Data only; the command line prints it (``gnomon.cli``), and ``--json`` prints
:meth:`CampaignSummary.to_dict`. The metrics of a table are its float columns other than
the bookkeeping ones (:func:`metric_columns`): the task's metrics and, for the default
task, ``eclipse_fraction``.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
from typing import Any

__all__ = ["CampaignResult", "CampaignSummary", "metric_columns"]

#: columns of every table that are not metrics
BOOKKEEPING = ("index", "seed", "status", "error", "elapsed_s", "cpu_s")


@dataclasses.dataclass
class CampaignResult:
    """What :func:`gnomon.campaign.run_campaign` returns: the table and counts of this call.

    ``table``: pandas DataFrame, one row per finished run (every run in ``out_dir``, not
    only this call's); ``path``: results.parquet (``only-INDEX.parquet`` or None for
    ``only``); ``ran``/``failed``: runs executed by this call / of which failed;
    ``elapsed_s``: wall time of the call (s); ``runs``: the campaign's N; ``only``: the
    index run alone, or None.
    """

    table: Any
    path: pathlib.Path | None
    ran: int
    failed: int
    elapsed_s: float
    runs: int = 0
    only: int | None = None

    @property
    def runs_per_s(self) -> float:
        return self.ran / self.elapsed_s if self.elapsed_s > 0 else float("nan")

    def summary(self) -> CampaignSummary:
        """Counts of this call and statistics of the table over its ``status == "ok"``
        rows (mean, 95th percentile by linear interpolation, max), as data."""
        df = self.table
        ok = df[df["status"] == "ok"]
        metrics = {c: {"mean": _finite(ok[c].mean()), "p95": _finite(ok[c].quantile(0.95)),
                       "max": _finite(ok[c].max())} for c in metric_columns(df) if len(ok)}
        row = None
        if self.only is not None:
            row = {}
            for k, v in df.iloc[0].to_dict().items():
                v = v.item() if hasattr(v, "item") else v
                row[k] = None if isinstance(v, float) and not math.isfinite(v) else v
        return CampaignSummary(
            runs=int(self.runs), ran=self.ran, failed_now=self.failed, rows=int(len(df)),
            failed_total=int((df["status"] != "ok").sum()), elapsed_s=self.elapsed_s,
            runs_per_s=self.runs_per_s, path=str(self.path) if self.path else None,
            metrics=metrics, row=row)


@dataclasses.dataclass(frozen=True)
class CampaignSummary:
    """Counts and per-metric statistics of a campaign's table.

    ``runs``: N; ``ran``/``failed_now``: runs of this call / of which failed; ``rows``:
    runs in the table; ``failed_total``: of which failed; ``elapsed_s``, ``runs_per_s``
    of this call; ``path``: the table's file (str) or None; ``metrics``: ``{column:
    {"mean", "p95", "max"}}`` over the successful rows (None where not finite; empty
    when no run succeeded); ``row``: with ``only``, that run's full row (else None).
    """

    runs: int
    ran: int
    failed_now: int
    rows: int
    failed_total: int
    elapsed_s: float
    runs_per_s: float
    path: str | None
    metrics: dict[str, dict[str, float | None]]
    row: dict[str, Any] | None = None

    def to_dict(self) -> dict:
        """The ``gnomon campaign --json`` object (strict JSON values): the fields in order,
        ``elapsed_s`` and ``runs_per_s`` to 3 decimals, ``row`` only with ``only``."""
        out = {"runs": self.runs, "ran": self.ran, "failed_now": self.failed_now,
               "rows": self.rows, "failed_total": self.failed_total,
               "elapsed_s": _finite(round(self.elapsed_s, 3)),
               "runs_per_s": _finite(round(self.runs_per_s, 3)), "path": self.path,
               "metrics": {k: dict(v) for k, v in self.metrics.items()}}
        if self.row is not None:
            out["row"] = dict(self.row)
        return out


def _finite(x) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None      # strict JSON: NaN -> null


def metric_columns(table) -> list[str]:
    """The metric columns of a campaign table, in table order: float columns that are
    neither bookkeeping nor ``param.KEY``."""
    return [c for c in table.columns if c not in BOOKKEEPING
            and not c.startswith("param.") and table[c].dtype.kind == "f"]
