"""Monte Carlo campaigns: many runs of a scenario, on local processes or a Dask cluster.

A campaign is ``runs`` runs of one scenario. Run ``i`` is fully described by
``(index, seed, drawn parameters)``, so every run can be re-run alone (``only=INDEX``)
with identical results, on any machine. Each run's row (seed, parameters, status, error,
timings and the task's metrics) goes to a Parquet table as its chunk finishes; a crash
loses only unfinished chunks and ``resume=True`` runs only what is missing.

The package, one job per module:

* :mod:`~gnomon.campaign.distributions`: ``--vary KEY=DIST``: parsing, drawing.
* :mod:`~gnomon.campaign.seeds`: root seed -> the :class:`Run` ``(index, seed, params)``.
* :mod:`~gnomon.campaign.task`: the :class:`Task` type: what a run accepts and returns,
  which keys it takes, how a chunk of runs batches.
* :mod:`~gnomon.campaign.default_task`: the default task, :data:`simulate_and_score`.
* :mod:`~gnomon.campaign.worker`: one run / one chunk -> rows, failures kept as rows.
* :mod:`~gnomon.campaign.executors`: serial, local processes, Dask.
* :mod:`~gnomon.campaign.store`: the directory: part files, consolidation, resume,
  ``campaign.json``, :func:`read_results`.
* :mod:`~gnomon.campaign.runner`: :func:`run_campaign`, :func:`run_one`.
* :mod:`~gnomon.campaign.result`: :class:`CampaignResult` and its
  :class:`CampaignSummary` (data; ``gnomon campaign`` prints it).
* :mod:`~gnomon.campaign.budget`: the attitude-knowledge budget of a table (per body
  axis and total, 3σ and p99, sunlit and eclipse).
* :mod:`~gnomon.campaign.sensitivity`: Spearman ρ of each error against each varied
  parameter.
* :mod:`~gnomon.campaign.rerun`: the command that re-runs one run alone.

Scores are :func:`gnomon.metrics.score_run`'s and
:func:`gnomon.metrics.score_run_budget`'s; the report is :mod:`gnomon.report.campaign`.
``docs/campaigns.md`` is the user guide.
"""

from gnomon.campaign.default_task import (
    DEFAULT_TASK,
    accepts_filter_key,
    simulate_and_score,
    simulate_and_score_batch,
)
from gnomon.campaign.distributions import Distribution, parse_distribution, parse_vary
from gnomon.campaign.result import CampaignResult, CampaignSummary
from gnomon.campaign.runner import run_campaign, run_one
from gnomon.campaign.seeds import Run, describe_run, draw_parameters, run_seed
from gnomon.campaign.store import read_manifest, read_results
from gnomon.campaign.task import Task

__all__ = ["run_campaign", "run_one", "CampaignResult", "CampaignSummary", "read_results",
           "read_manifest", "Task", "simulate_and_score", "simulate_and_score_batch",
           "accepts_filter_key", "DEFAULT_TASK", "Distribution", "parse_distribution",
           "parse_vary", "Run", "describe_run", "run_seed", "draw_parameters"]
