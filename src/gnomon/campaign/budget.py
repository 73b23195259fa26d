"""The attitude-knowledge budget of a campaign: per body axis and total, sunlit and eclipse.

Built from the per-run metrics of the default task (:func:`gnomon.metrics.score_run`
and :func:`gnomon.metrics.score_run_budget`), over the runs with ``status == "ok"``;
a run without a value (e.g. no eclipse sample) is left out of that cell, and the cell
says how many runs it holds. All values in degrees.

* **3σ** of axis ``A`` in a phase: ``3 · sqrt(mean over runs of rms_A²)``, where
  ``rms_A`` is the run's RMS of the body-axis error over the phase's samples (after the
  settling time). Every run weighs the same; with runs of equal length this is 3 × the
  RMS of all their samples pooled. σ is an RMS, so a bias is included in it: for
  zero-mean Gaussian errors of standard deviation σ it is 3σ. The total's 3σ is the same
  of the run's RMS of the error angle (``sqrt(σx² + σy² + σz²)`` for independent axes).
* **p99** of axis ``A``: the 99th percentile over runs of each run's 99th percentile of
  ``|e_A|``: 99 % of the runs keep 99 % of their samples within it (for Gaussian
  errors, about 2.58σ). The total's p99 is the same of the error angle.

Phases: ``all`` (every sample after settling), ``sunlit``, ``eclipse`` (with a sun
sensor: the run's ``sun_valid`` samples and the others).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["PHASES", "AXES", "filters_of", "budget", "is_budget_metric", "ok_runs"]

PHASES = ("all", "sunlit", "eclipse")
AXES = ("x", "y", "z", "total")
_BUDGET_KEYS = tuple(f"{a}_{s}_deg" for a in ("x", "y", "z") for s in ("rms", "p99")) + (
    "p99_deg",)


def ok_runs(table):
    """The rows of ``table`` whose run succeeded (``status == "ok"``)."""
    return table[table["status"] == "ok"] if "status" in table else table


def filters_of(table) -> list[str]:
    """The filters scored in a campaign table: each ``F`` with an ``F.rms_deg`` column, in
    table order."""
    return [c.rsplit(".", 1)[0] for c in table.columns if c.endswith(".rms_deg")]


def is_budget_metric(column: str) -> bool:
    """Whether ``column`` is one of the per-axis / percentile metrics a budget is built
    from (``F.x_rms_deg``, ``F.sunlit_p99_deg``, ...) rather than a headline metric."""
    name = column.rsplit(".", 1)[-1]
    for prefix in ("", "sunlit_", "eclipse_"):
        if name.startswith(prefix) and name[len(prefix):] in _BUDGET_KEYS:
            return True
    return False


def _column(phase: str, axis: str, stat: str) -> str:
    """The metric (without ``F.``) of ``stat`` ("rms" or "p99") for ``axis`` in ``phase``."""
    prefix = "" if phase == "all" else f"{phase}_"
    return f"{prefix}{stat}_deg" if axis == "total" else f"{prefix}{axis}_{stat}_deg"


def _values(table, col: str) -> np.ndarray:
    if col not in table:
        return np.empty(0)
    v = table[col].to_numpy(dtype=float)
    return v[np.isfinite(v)]


def budget(table, filter_name: str) -> list[dict]:
    """The budget of ``filter_name`` in a campaign ``table`` (pandas DataFrame).

    One dict per phase present (``all``; ``sunlit`` and ``eclipse`` with a sun sensor):
    ``phase``, ``runs`` (runs with a value), and for each axis ``A`` in x, y, z, total:
    ``A_3sigma_deg`` and ``A_p99_deg`` (module docstring; NaN when no run has a value).
    """
    ok = ok_runs(table)
    rows = []
    for phase in PHASES:
        probe = f"{filter_name}.{_column(phase, 'total', 'rms')}"
        if probe not in ok:
            continue
        row = {"phase": phase, "runs": int(np.isfinite(ok[probe].to_numpy(float)).sum())}
        for axis in AXES:
            # the total's RMS is score_run's own (rms_deg, sunlit_rms_deg, eclipse_rms_deg)
            r = _values(ok, f"{filter_name}.{_column(phase, axis, 'rms')}")
            p = _values(ok, f"{filter_name}.{_column(phase, axis, 'p99')}")
            row[f"{axis}_3sigma_deg"] = (3.0 * math.sqrt(float(np.mean(r * r)))
                                         if r.size else math.nan)
            row[f"{axis}_p99_deg"] = float(np.percentile(p, 99)) if p.size else math.nan
        rows.append(row)
    return rows
