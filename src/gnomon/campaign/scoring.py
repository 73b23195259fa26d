"""The metrics of many campaign runs at once: ``score_run`` + ``score_run_budget`` of
:mod:`gnomon.metrics` for the runs of a chunk that share their time stamps.

:func:`score_runs` gives, for each run, the dict ``{**score_run(rec, q, settle),
**score_run_budget(rec, q, settle)}``: the same keys in the same order and the same
numbers to about 1e-13 of their size (one compiled pass over each run's samples,
:func:`gnomon.kernels.scores.run_scores`, whose sums run in another order than
numpy's; the tests compare them). A sun sensor's sunlit and eclipse phases are one
more pass each. Runs that do not fit (other time stamps, a NaN) are scored by the
``gnomon.metrics`` functions themselves.
"""

from __future__ import annotations

import numpy as np

from gnomon.metrics import BODY_AXES, score_run, score_run_budget

__all__ = ["score_runs"]


def _one(rec, q, settle_s: float) -> dict:
    return {**score_run(rec, q, settle_s), **score_run_budget(rec, q, settle_s)}


#: the kernel's scores, in its order (gnomon.kernels.scores.run_scores)
_KEYS = ("rms_deg", "max_deg", "mean_deg", "heading_rms_deg", "inclination_rms_deg",
         *(f"{a}_rms_deg" for a in BODY_AXES), *(f"{a}_p99_deg" for a in BODY_AXES),
         "p99_deg")
#: the budget's keys of one phase, in score_run_budget's order
_BUDGET = (*(k for a in BODY_AXES for k in (f"{a}_rms_deg", f"{a}_p99_deg")), "p99_deg")
#: the keys in the order of score_run + score_run_budget (a sun sensor's phases after them:
#: score_run's sunlit_rms_deg, eclipse_rms_deg, eclipse_max_deg before the budget, the
#: budget's sunlit_* and eclipse_* at the end)
_ORDER = ("rms_deg", "max_deg", "mean_deg", "heading_rms_deg", "inclination_rms_deg",
          "sunlit_rms_deg", "eclipse_rms_deg", "eclipse_max_deg", *_BUDGET)


def _score_together(recs, qs, settle_s: float) -> list[dict]:
    """The fast path: runs with the same ``t`` and finite ``q_true``/``q_est``; one
    compiled pass per run and phase (all samples; with a sun sensor also the sunlit and
    the eclipse ones: :func:`gnomon.kernels.scores.run_scores`)."""
    from gnomon.kernels.scores import N_SCORES, run_scores

    t = recs[0].t
    k0 = int(np.searchsorted(t - t[0] >= settle_s, True))   # keep is a suffix of t
    vertical = recs[0].frames.get("reference") in ("ENU", "NWU")
    every = np.ones(t.shape[0], dtype=bool)
    out = []
    row = np.empty(N_SCORES)
    for rec, q in zip(recs, qs, strict=True):
        qt = np.ascontiguousarray(rec.q_true, dtype=float)
        qe = np.ascontiguousarray(q, dtype=float)
        run_scores(qt, qe, k0, vertical, every, row)
        scores = dict(zip(_KEYS, row.tolist(), strict=True))
        if not vertical:
            del scores["heading_rms_deg"], scores["inclination_rms_deg"]
        phases = {}
        if rec.sun_valid is not None:
            lit = np.ascontiguousarray(rec.sun_valid, dtype=bool)
            for prefix, use in (("sunlit_", lit), ("eclipse_", ~lit)):
                run_scores(qt, qe, k0, vertical, use, row)
                phases[prefix] = dict(zip(_KEYS, row.tolist(), strict=True))
            scores.update(sunlit_rms_deg=phases["sunlit_"]["rms_deg"],
                          eclipse_rms_deg=phases["eclipse_"]["rms_deg"],
                          eclipse_max_deg=phases["eclipse_"]["max_deg"])
        ordered = {k: scores[k] for k in _ORDER if k in scores}
        for prefix, p in phases.items():
            ordered.update({prefix + k: p[k] for k in _BUDGET})
        out.append(ordered)
    return out


def score_runs(recs, qs, settle_s: float) -> list[dict]:
    """``[{**score_run(rec, q, settle_s), **score_run_budget(rec, q, settle_s)} ...]`` for
    the recordings ``recs`` and their estimates ``qs`` ((N, 4) each), computed together
    for the runs that share time stamps and frames (see the module docstring); one run
    alone takes the same compiled path."""
    recs = list(recs)
    qs = list(qs)
    if not recs:
        return []
    first = recs[0]
    fits = all(r.q_true is not None
               and r.t.shape == first.t.shape and np.array_equal(r.t, first.t)
               and r.frames.get("reference") == first.frames.get("reference")
               and np.shape(q) == r.q_true.shape
               and (r.sun_valid is None or np.shape(r.sun_valid) == r.t.shape)
               and np.isfinite(r.q_true).all() and np.isfinite(q).all()
               for r, q in zip(recs, qs, strict=True))
    if not fits:
        return [_one(r, q, settle_s) for r, q in zip(recs, qs, strict=True)]
    return _score_together(recs, qs, settle_s)
