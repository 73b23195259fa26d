"""The BROAD benchmark (``gnomon benchmark broad --data DIR``): the BROAD trials
(Laidig et al. 2021), BROAD's groups, no alignment (BROAD's own protocol). Its JSON::

    {"metric": "broad", "data",
     "trials": [{"trial", "method", "total_deg", "heading_deg", "inclination_deg"}, ...],
     "mean": {METHOD: {"total_deg", "heading_deg", "inclination_deg", "trials"}},
     "groups": {METHOD: {GROUP: {"total_deg", "heading_deg", "inclination_deg", "trials"}}},
     "samples_per_s": {METHOD: float}, "errors": [...]}
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from gnomon.alignment import align_names
from gnomon.benchmark.methods import default_filters, make_methods, method_names
from gnomon.benchmark.scoring import group_means, means, speed
from gnomon.benchmark.trials import parse_align, run_trials
from gnomon.errors import InputError

__all__ = ["run_broad", "DEFAULT_ALIGN"]

#: BROAD's protocol: the truth as recorded
DEFAULT_ALIGN: tuple[str, ...] = ()


def run_broad(data_dir, filters: Sequence[str] | None = None,
              anchors: Sequence[str] | None = None, progress: bool = False,
              align: Sequence[str] = ()) -> dict:
    """Run ``filters`` (registry names) and ``anchors`` (None: every installed causal
    library and ``vqf-offline``) on every BROAD trial in ``data_dir`` (``.hdf5`` and
    ``.mat``); returns the JSON object of the module docstring. ``align`` (default none,
    BROAD's protocol; :mod:`gnomon.benchmark.trials`): when given, rows carry
    ``lag_s``/``misalignment_deg`` and ``align``, ``alignment`` are added."""
    from gnomon.io import read
    from gnomon.io.broad import broad_groups, broad_trials

    align = parse_align(align)
    paths = broad_trials(data_dir)
    if not paths:
        raise InputError("no BROAD trial (.hdf5 or .mat) found", file=str(data_dir))
    methods = make_methods(default_filters() if filters is None else filters, anchors)
    names = method_names(methods)
    groups_of = broad_groups(data_dir)
    trials = [(Path(p).stem, lambda p=p: read(p, format="broad")) for p in paths]
    rows, errors, timing, alignment = run_trials(trials, methods, n_trials=len(paths),
                                                 align=align, desc="BROAD", progress=progress,
                                                 named_by_source=True)
    out = {"metric": "broad", "data": str(data_dir), "trials": rows,
           "mean": means(rows, names), "groups": group_means(rows, groups_of, names),
           "samples_per_s": speed(timing), "errors": errors}
    if align:
        out["align"] = align_names(align)
        out["alignment"] = alignment
    return out
