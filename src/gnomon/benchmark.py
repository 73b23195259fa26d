"""The BROAD benchmark: gnomon's filters and the reference libraries, side by side, one metric.

BROAD (Laidig, Caruso, Cereatti, Seel, Data 6(7):72, 2021) scores causal
orientation estimates against optical motion capture: for every sample with
``movement`` true and a valid truth, ``q_err = q_est ⊗ conj(q_true)``; total
``2·acos(|w|)``, heading ``2·atan(|z/w|)``, inclination ``2·acos(sqrt(w²+z²))``
(``gnomon.metrics.broad_errors_rad``); RMSE per trial in degrees; a method's
score is the mean over trials. No alignment: every estimate must be
sensor-to-ENU from the first sample on.

``run_broad`` returns the JSON object printed by ``gnomon benchmark broad --json``::

    {"metric": "broad",
     "trials": [{"trial", "method", "total_deg", "heading_deg", "inclination_deg"}, ...],
     "mean": {METHOD: {"total_deg", "heading_deg", "inclination_deg", "trials"}},
     "groups": {METHOD: {GROUP: {"total_deg", "heading_deg", "inclination_deg", "trials"}}}}

(``groups`` is an addition: per BROAD group, when ``trials.json`` is present.)
A method that fails on a trial is recorded in ``errors`` and the run goes on.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from gnomon import anchors as anchors_mod
from gnomon.errors import InputError
from gnomon.estimators import registry
from gnomon.metrics import score_broad
from gnomon.recording import Recording

__all__ = ["run_broad", "default_filters"]


def default_filters() -> tuple[str, ...]:
    """The gnomon filters run by default: every registered IMU filter (``kind = "imu"``)."""
    return tuple(registry.names("imu"))
_KEYS = ("total", "heading", "inclination")


def _methods(filters: Sequence[str], anchors: Sequence[str] | None):
    methods: list[tuple[str, Callable[[Recording], np.ndarray]]] = []
    for name in filters:
        registry.get(name)  # unknown names fail before any trial runs

        def run_filter(rec, name=name):
            return registry.create(name).run(rec).q

        methods.append((name, run_filter))
    names = anchors_mod.available() if anchors is None else list(anchors)
    for name in names:
        if name not in anchors_mod.ANCHORS:
            raise InputError(f"unknown reference library {name!r}; known: "
                             f"{', '.join(anchors_mod.ANCHORS)}", field="anchors")
        methods.append((name, lambda rec, name=name: anchors_mod.run_anchor(name, rec)))
    return methods


def run_broad(data_dir, filters: Sequence[str] | None = None,
              anchors: Sequence[str] | None = None, progress: bool = False) -> dict:
    """Run ``filters`` (registry names) and ``anchors`` (None: every installed one) on every
    BROAD trial in ``data_dir`` (``.hdf5`` and ``.mat``); returns the JSON object above.
    """
    from gnomon.io import read
    from gnomon.io.broad import broad_groups, broad_trials

    paths = broad_trials(data_dir)
    if not paths:
        raise InputError("no BROAD trial (.hdf5 or .mat) found", file=str(data_dir))
    methods = _methods(default_filters() if filters is None else filters, anchors)
    groups_of = broad_groups(data_dir)
    rows, errors, timing = [], [], {}
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(paths) * len(methods), unit="run", desc="BROAD", leave=False)
    warmed: set[str] = set()
    for path in paths:
        rec = read(path, format="broad")
        for method, fn in methods:
            if bar is not None:
                bar.set_postfix_str(f"{Path(path).stem[:24]} {method}")
            try:
                if method not in warmed:  # compile / load compiled code outside the timing
                    fn(rec.slice(0, min(len(rec), 200)))
                    warmed.add(method)
                t0 = time.perf_counter()
                q = fn(rec)
                timing.setdefault(method, []).append((len(rec), time.perf_counter() - t0))
                rows.append({"trial": rec.source, "method": method, **score_broad(rec, q)})
            except Exception as exc:  # one failure must not lose the other trials
                errors.append({"trial": rec.source, "method": method,
                               "error": f"{type(exc).__name__}: {exc}"})
            if bar is not None:
                bar.update(1)
    if bar is not None:
        bar.close()
    out = {"metric": "broad", "data": str(data_dir), "trials": rows,
           "mean": _means(rows, [m for m, _ in methods]),
           "groups": _group_means(rows, groups_of, [m for m, _ in methods]),
           "samples_per_s": {m: sum(n for n, _ in v) / max(sum(s for _, s in v), 1e-12)
                             for m, v in timing.items()},
           "errors": errors}
    return out


def _mean_of(rows) -> dict:
    return {**{f"{k}_deg": float(np.mean([r[f"{k}_deg"] for r in rows])) for k in _KEYS},
            "trials": len(rows)}


def _means(rows, methods) -> dict:
    return {m: _mean_of(sel) for m in methods if (sel := [r for r in rows if r["method"] == m])}


def _group_means(rows, groups_of: dict, methods) -> dict:
    if not groups_of:
        return {}
    out = {}
    for m in methods:
        per_group: dict[str, list] = {}
        for r in rows:
            if r["method"] == m:
                for g in groups_of.get(r["trial"], []):
                    per_group.setdefault(g, []).append(r)
        if per_group:
            out[m] = {g: _mean_of(sel) for g, sel in sorted(per_group.items())}
    return out
