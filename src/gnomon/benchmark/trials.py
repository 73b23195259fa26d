"""The run loop of every benchmark: each method on each trial, scored, failures kept.

**Alignment** (``align``, :func:`gnomon.alignment.align_truth`): fitted once per trial
from the gyro (and, for ``world``, the accelerometer and magnetometer) against the
reference, applied to the truth before any method is scored, so every method is scored
against the same corrected truth: ``lag`` shifts the truth in time (the residual clock
offset), ``body`` turns it onto the sensor's axes (the constant rotation between the
sensor and the motion-capture marker body), ``world`` turns the reference's world onto
ENU; ``auto`` applies those the motion determines; a saved fit (``--align FILE.json``)
is applied per trial as it is. Nothing is fitted to any estimate; no heading offset is
removed.

A method that fails on a trial is recorded in ``errors`` and the run goes on; so is a
trial that cannot be read or aligned.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterable
from typing import NamedTuple

from gnomon.alignment import align_truth, fit_for, parse_align
from gnomon.benchmark.methods import Method
from gnomon.benchmark.scoring import nees
from gnomon.estimators.base import Estimate
from gnomon.metrics import score_broad
from gnomon.progress import Progress
from gnomon.recording import Recording

__all__ = ["parse_align", "run_trials", "Scored", "Trial"]  # parse_align: gnomon.alignment

#: a trial: ``(name, load)``, ``load()`` returning its recording
Trial = tuple[str, Callable[[], Recording]]


class Scored(NamedTuple):
    """What :func:`run_trials` returns."""

    rows: list         #: one per (trial, method): the scores, the fit, the trial's extra keys
    errors: list       #: ``{"trial", "method", "error"}`` of every failure
    timing: dict       #: ``{method: [(samples, seconds), ...]}``
    alignment: list    #: ``{"trial", **align_truth's fit}`` of every aligned trial


def _aligned(rec: Recording, name: str, align, alignment: list):
    """``rec`` with its truth aligned by ``align`` and the fit of its rows; the fit goes to
    ``alignment``."""
    q_al, info = align_truth(rec, fit_for(align, name) if isinstance(align, dict) else align)
    applied = info.get("applied", ())
    fit = {"lag_s": info["lag_s"] if "lag" in applied else 0.0,
           "misalignment_deg": info["misalignment_deg"] if "body" in applied else 0.0}
    alignment.append({"trial": name, **info})
    return dataclasses.replace(rec, q_true=q_al), fit


def run_trials(trials: Iterable[Trial], methods: list[Method], *, n_trials: int,
               align: tuple[str, ...] = (), fit_alignment: bool = False, scorer=score_broad,
               desc: str = "benchmark", progress: bool = False,
               trial_extra: Callable[[str], dict] | None = None,
               named_by_source: bool = False) -> Scored:
    """Score every method on every trial. With ``named_by_source`` a trial's rows are named
    by the recording's ``source`` (BROAD's trial name) once it is read; ``fit_alignment``:
    fit (and report) the alignment even when ``align`` applies none of it;
    ``trial_extra(name)``: keys added to every row of the trial."""
    out = Scored([], [], {}, [])
    bar = Progress(n_trials * len(methods), desc, unit="run", enabled=progress, leave=False)
    warmed: set[str] = set()
    for name, load in trials:
        try:
            rec = load()
            name = (rec.source or name) if named_by_source else name
            fit = {}
            if align or fit_alignment:
                rec, fit = _aligned(rec, name, align, out.alignment)
        except Exception as exc:  # a trial that cannot be read or aligned: the others go on
            out.errors.append({"trial": name, "method": None,
                               "error": f"{type(exc).__name__}: {exc}"})
            bar.update(len(methods))
            continue
        extra = trial_extra(name) if trial_extra else {}
        for method, fn, applies in methods:
            bar.note(f"{name[:24]} {method}")
            if not applies(rec):
                bar.update(1)
                continue
            try:
                if method not in warmed:  # compile / load compiled code outside the timing
                    fn(rec.slice(0, min(len(rec), 200)))
                    warmed.add(method)
                t0 = time.perf_counter()
                res = fn(rec)
                out.timing.setdefault(method, []).append((len(rec), time.perf_counter() - t0))
                q = res.q if isinstance(res, Estimate) else res
                row = {"trial": name, "method": method, **scorer(rec, q), **fit, **extra}
                if isinstance(res, Estimate) and "att_std_rad" in res.signals:
                    row["nees"] = nees(rec, q, res.signals["att_std_rad"])
                out.rows.append(row)
            except Exception as exc:  # one failure must not lose the other trials
                out.errors.append({"trial": name, "method": method,
                                   "error": f"{type(exc).__name__}: {exc}"})
            bar.update(1)
    bar.close()
    return out
