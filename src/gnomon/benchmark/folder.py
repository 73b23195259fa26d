"""The benchmark of any folder (``gnomon benchmark DIR``): every recording gnomon reads
under ``DIR`` (any format, any depth up to 4) that holds a truth; no groups, no alignment
unless asked; with a map (``map=``, ``--map MAP.yaml``) every file of the map's kind
(:mod:`gnomon.io.mapping`) read with it. Its JSON has BROAD's keys
(:mod:`gnomon.benchmark.broad`; rows with ``samples``) plus ``benchmark`` (``"dir"``),
``align``, ``alignment`` and ``alignment_stats`` (when aligned), ``skipped`` and ``map``
(with a map).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from gnomon.alignment import align_names
from gnomon.benchmark.methods import default_anchors, default_filters, make_methods, method_names
from gnomon.benchmark.scoring import alignment_stats, means, score_trial, speed
from gnomon.benchmark.trials import parse_align, run_trials
from gnomon.errors import InputError

__all__ = ["run_benchmark", "DEFAULT_ALIGN"]

#: the truth as recorded
DEFAULT_ALIGN: tuple[str, ...] = ()


def _recordings(root: Path, depth: int = 4) -> tuple[list[tuple[str, Path, str]], list]:
    """Every file or folder under ``root`` that gnomon recognises: ``[(name, path,
    format)]`` and ``[{"trial", "reason"}]`` for what it skipped."""
    from gnomon.io import detect_format

    found, skipped = [], []

    def visit(folder: Path, level: int):
        for p in sorted(folder.iterdir()):
            if p.name.startswith("."):
                continue
            try:
                fmt = detect_format(p)
            except InputError as err:
                if p.is_dir() and level < depth:
                    visit(p, level + 1)
                elif p.is_file() and p.suffix.lower() not in (".json", ".md", ".txt"):
                    skipped.append({"trial": str(p.relative_to(root)), "reason": err.message})
                continue
            found.append((str(p.relative_to(root).with_suffix("")) if p.is_file()
                          else str(p.relative_to(root)), p, fmt))

    visit(root, 0)
    return found, skipped


def _mapped(root: Path, kind: str, depth: int = 4) -> list[tuple[str, Path, str]]:
    """Every file under ``root`` whose suffix is one of a map's ``kind``
    (:data:`gnomon.io.mapping.KIND_SUFFIXES`): ``[(name, path, "map")]``."""
    from gnomon.io.mapping import KIND_SUFFIXES

    found = []

    def visit(folder: Path, level: int):
        for p in sorted(folder.iterdir()):
            if p.name.startswith("."):
                continue
            if p.is_dir() and level < depth:
                visit(p, level + 1)
            elif p.is_file() and p.suffix.lower() in KIND_SUFFIXES[kind]:
                found.append((str(p.relative_to(root).with_suffix("")), p, "map"))

    visit(root, 0)
    return found


def _with_truth(root: Path, skipped: list, map_file=None, strict: bool = False) -> list:
    """``[(name, rec)]`` of the recordings under ``root`` that hold a truth; the others
    (and what cannot be read, with ``strict`` a non-finite sample too) go to
    ``skipped``. With ``map_file``, the files of its kind,
    each read with it."""
    from gnomon.io import read

    if map_file is None:
        found, more = _recordings(root)
        skipped.extend(more)
    else:
        from gnomon.io.mapping import load_map

        found = _mapped(root, load_map(map_file)["kind"])
    recs = []
    for name, path, fmt in found:
        try:
            rec = (read(path, format=fmt, strict=strict) if map_file is None
                   else read(path, map=map_file, strict=strict))
        except InputError as err:
            skipped.append({"trial": name, "reason": f"{fmt}: {err.message}"})
            continue
        if rec.q_true is None:
            skipped.append({"trial": name, "reason": f"{fmt}: no truth (q_true)"})
            continue
        recs.append((name, rec))
    if not recs:
        raise InputError("no recording with a truth (q_true) found", file=str(root))
    return recs


def run_benchmark(data_dir, filters: Sequence[str] | None = None,
                  anchors: Sequence[str] | None = None, align: Sequence[str] | str = (),
                  progress: bool = False, map=None, strict: bool = False) -> dict:
    """Every recording under ``data_dir`` that gnomon reads (any format, any depth up to
    4; with ``map``, a map's YAML path or dict, every file of the map's kind read with it:
    :mod:`gnomon.io.mapping`) and that holds a truth (``q_true``): ``filters`` (default
    every IMU filter),
    ``anchors`` (default every installed causal library, ``vqf-offline`` and ``onboard``,
    the device's own estimate, where the recording has one), ``align`` (default none).
    Recordings without a truth, and files gnomon cannot read (``strict``: nor those with a
    non-finite sample, else dropped from its sensor), are listed in ``skipped``.
    Returns the JSON object of the module docstring."""
    root = Path(data_dir)
    if not root.is_dir():
        raise InputError("no such directory", file=str(root))
    align = parse_align(align)
    skipped: list = []
    recs = _with_truth(root, skipped, map, strict)
    if anchors is None:
        anchors = default_anchors() + ["onboard"]
    methods = make_methods(default_filters() if filters is None else filters, anchors)
    names = method_names(methods)
    rows, errors, timing, alignment = run_trials(
        [(n, lambda r=r: r) for n, r in recs], methods, n_trials=len(recs), align=align,
        scorer=score_trial, desc=root.name, progress=progress)
    out = {"metric": "broad", "benchmark": "dir", "data": str(root), "align": align_names(align),
           **({"map": "given as a dict" if isinstance(map, dict) else str(map)}
              if map is not None else {}),
           "trials": rows, "mean": means(rows, names), "groups": {},
           "skipped": sorted(skipped, key=lambda s: s["trial"]),
           "samples_per_s": speed(timing), "errors": errors}
    if align:
        out["alignment"] = alignment
        out["alignment_stats"] = alignment_stats(alignment, {})
    return out
