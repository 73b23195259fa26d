"""Which varied parameter drives which error: rank correlation over a campaign's runs.

For every numeric varied parameter (``param.KEY`` columns) and every error metric, the
Spearman rank correlation ρ (``scipy.stats.spearmanr``) over the successful runs where
both are finite, with its two-sided p-value. ρ is +1 when the error grows monotonically
with the parameter, −1 when it shrinks, near 0 when the error does not follow it (for N
independent runs, |ρ| below about 2/√N is indistinguishable from none). Categorical
parameters (``choice`` of words, vectors) and constants are not ranked: they are listed
in :attr:`Sensitivity.skipped` with the reason.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np

from gnomon.campaign.budget import ok_runs

__all__ = ["Correlation", "Sensitivity", "sensitivity", "varied_parameters"]


@dataclasses.dataclass(frozen=True)
class Correlation:
    """ρ of ``metric`` against ``param`` (a ``param.KEY`` column) over ``runs`` runs."""

    param: str
    metric: str
    rho: float
    p_value: float
    runs: int


@dataclasses.dataclass(frozen=True)
class Sensitivity:
    """``correlations``: every (parameter, metric) pair, strongest |ρ| first (NaN last);
    ``skipped``: ``{param column: why it is not ranked}``."""

    correlations: list[Correlation]
    skipped: dict[str, str]

    def strongest(self, k: int, min_abs_rho: float = 0.0) -> list[Correlation]:
        """The ``k`` pairs of largest |ρ| (at least ``min_abs_rho``), one per parameter and
        metric pair, strongest first."""
        return [c for c in self.correlations
                if math.isfinite(c.rho) and abs(c.rho) >= min_abs_rho][:k]


def varied_parameters(table) -> list[str]:
    """The ``param.KEY`` columns of a campaign table, in table order."""
    return [c for c in table.columns if c.startswith("param.")]


def sensitivity(table, metrics: list[str]) -> Sensitivity:
    """Spearman ρ of each of ``metrics`` (column names) against each varied parameter of
    ``table`` (a campaign's pandas DataFrame), over its successful runs."""
    from scipy.stats import spearmanr

    ok = ok_runs(table)
    out, skipped = [], {}
    for p in varied_parameters(table):
        try:
            x = ok[p].to_numpy(dtype=float)
        except (TypeError, ValueError):
            skipped[p] = "not a number (categorical or a vector): not ranked"
            continue
        if np.unique(x[np.isfinite(x)]).size < 2:
            skipped[p] = "takes a single value: nothing to rank"
            continue
        for m in metrics:
            y = ok[m].to_numpy(dtype=float)
            sel = np.isfinite(x) & np.isfinite(y)
            rho = pv = math.nan
            if sel.sum() >= 3 and np.ptp(y[sel]) > 0:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    res = spearmanr(x[sel], y[sel])
                rho, pv = float(res.statistic), float(res.pvalue)
            out.append(Correlation(p, m, rho, pv, int(sel.sum())))
    out.sort(key=lambda c: -abs(c.rho) if math.isfinite(c.rho) else math.inf)
    return Sensitivity(out, skipped)
