"""The metrics of many campaign runs at once: ``score_run`` + ``score_run_budget`` of
:mod:`gnomon.metrics` for the runs of a chunk that share their time stamps.

:func:`score_runs` gives, for each run, the dict ``{**score_run(rec, q, settle),
**score_run_budget(rec, q, settle)}``: the same keys in the same order and the same
numbers to about 1e-13 of their size (one compiled pass over each run's samples,
:func:`gnomon.kernels.scores.run_scores`, whose sums run in another order than
numpy's; the tests compare them). Runs that do not fit (other time stamps, a sun
sensor, a NaN) are scored by the ``gnomon.metrics`` functions themselves.
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
#: the keys in the order of score_run + score_run_budget
_ORDER = ("rms_deg", "max_deg", "mean_deg", "heading_rms_deg", "inclination_rms_deg",
          *(k for a in BODY_AXES for k in (f"{a}_rms_deg", f"{a}_p99_deg")), "p99_deg")


def _score_together(recs, qs, settle_s: float) -> list[dict]:
    """The fast path: runs with the same ``t``, finite ``q_true``/``q_est``, no sun sensor;
    one compiled pass per run (:func:`gnomon.kernels.scores.run_scores`)."""
    from gnomon.kernels.scores import N_SCORES, run_scores

    t = recs[0].t
    k0 = int(np.searchsorted(t - t[0] >= settle_s, True))   # keep is a suffix of t
    vertical = recs[0].frames.get("reference") in ("ENU", "NWU")
    out = []
    row = np.empty(N_SCORES)
    for rec, q in zip(recs, qs, strict=True):
        run_scores(np.ascontiguousarray(rec.q_true, dtype=float),
                   np.ascontiguousarray(q, dtype=float), k0, vertical, row)
        scores = dict(zip(_KEYS, row.tolist(), strict=True))
        if not vertical:
            del scores["heading_rms_deg"], scores["inclination_rms_deg"]
        out.append({k: scores[k] for k in _ORDER if k in scores})
    return out


def score_runs(recs, qs, settle_s: float) -> list[dict]:
    """``[{**score_run(rec, q, settle_s), **score_run_budget(rec, q, settle_s)} ...]`` for
    the recordings ``recs`` and their estimates ``qs`` ((N, 4) each), computed together
    for the runs that share time stamps and frames (see the module docstring)."""
    recs = list(recs)
    qs = list(qs)
    if len(recs) < 2:
        return [_one(r, q, settle_s) for r, q in zip(recs, qs, strict=True)]
    first = recs[0]
    fits = all(r.sun_valid is None and r.q_true is not None
               and r.t.shape == first.t.shape and np.array_equal(r.t, first.t)
               and r.frames.get("reference") == first.frames.get("reference")
               and np.shape(q) == r.q_true.shape
               and np.isfinite(r.q_true).all() and np.isfinite(q).all()
               for r, q in zip(recs, qs, strict=True))
    if not fits:
        return [_one(r, q, settle_s) for r, q in zip(recs, qs, strict=True)]
    return _score_together(recs, qs, settle_s)
