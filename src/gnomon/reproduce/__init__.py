"""One module per paper: ``p000`` ... ``p004``, each with ``run(out_dir, quick, progress) -> dict``.

``run(paper)`` runs one; ``run_all`` runs every available paper (a failure in
one is recorded and the others still run) and writes the HTML report.
"""

from __future__ import annotations

import importlib
import importlib.util
import json
import traceback
from pathlib import Path

PAPERS = ("000", "001", "002", "003", "004")

__all__ = ["PAPERS", "available", "run", "run_all"]


def available() -> list[str]:
    """Papers whose reproduction module exists."""
    return [p for p in PAPERS if importlib.util.find_spec(f"gnomon.reproduce.p{p}") is not None]


def run(paper: str, out_dir: Path | None = None, quick: bool = False,
        progress: bool = False) -> dict:
    """Reproduce one paper; returns its JSON-contract dict (and writes figures to ``out_dir``)."""
    if paper not in available():
        from gnomon.errors import InputError

        raise InputError(f"no reproduction for paper {paper!r}; available: "
                         f"{', '.join(available())}", field="paper")
    module = importlib.import_module(f"gnomon.reproduce.p{paper}")
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
    res = module.run(out_dir=None if out_dir is None else Path(out_dir), quick=quick,
                     progress=progress)
    if out_dir is not None:
        (Path(out_dir) / "metrics.json").write_text(json.dumps(res, indent=2, default=float))
    return res


def run_all(out_dir: Path | None = None, quick: bool = False, progress: bool = False) -> dict:
    """Every available paper into ``out_dir/pNNN``.

    Returns ``{paper: result}``, with ``{"error": ...}`` for a paper that failed.
    ``progress``: a bar over the papers (rate, time left; :mod:`gnomon.progress`) and each
    paper's own progress.
    """
    from gnomon.progress import Progress

    results = {}
    papers = available()
    with Progress(len(papers), "reproduce", unit="paper", enabled=progress) as bar:
        for paper in papers:
            bar.note(f"paper {paper}")
            sub = None if out_dir is None else Path(out_dir) / f"p{paper}"
            try:
                results[paper] = run(paper, sub, quick=quick, progress=progress)
            except Exception as exc:  # one paper failing must not lose the others
                results[paper] = {"paper": paper, "error": f"{type(exc).__name__}: {exc}",
                                  "traceback": traceback.format_exc()}
            bar.update(1)
    if out_dir is not None:
        try:
            from gnomon.report.html import build_report
        except ImportError:
            pass
        else:
            build_report(Path(out_dir), results, quick=quick)
    return results
