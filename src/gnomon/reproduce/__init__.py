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


#: the order in which ``run_all`` hands papers to parallel processes: the longest first
#: (``--quick`` on the 2-core machine, warm caches: 003 40 s, 001 30 s, 000 18 s, 002 18 s,
#: 004 9 s), so the last one to start is a short one
LONGEST_FIRST = ("003", "001", "000", "002", "004")


def _failed(paper: str, exc: BaseException) -> dict:
    """The result of a paper that raised ``exc`` (being handled)."""
    return {"paper": paper, "error": f"{type(exc).__name__}: {exc}",
            "traceback": traceback.format_exc()}


def _run_recorded(paper: str, sub: Path | None, quick: bool, progress: bool) -> dict:
    """``run(paper, ...)``, or ``{"paper", "error", "traceback"}`` if it raised."""
    try:
        return run(paper, sub, quick=quick, progress=progress)
    except Exception as exc:  # one paper failing must not lose the others
        return _failed(paper, exc)


def run_all(out_dir: Path | None = None, quick: bool = False, progress: bool = False,
            jobs: int = 1) -> dict:
    """Every available paper into ``out_dir/pNNN``.

    Returns ``{paper: result}`` in paper order, with ``{"error": ...}`` for a paper that
    failed. ``jobs`` > 1: that many papers at once, each in a process of its own (fresh
    interpreters; the longest first, :data:`LONGEST_FIRST`); the results are the same as
    one after the other (each paper seeds its own generators) except the speeds and times
    the papers measure, which then share the machine. ``progress``: a bar over
    the papers (rate, time left; :mod:`gnomon.progress`) and, with ``jobs`` 1, each
    paper's own progress.
    """
    from gnomon.progress import Progress

    papers = available()
    subs = {p: None if out_dir is None else Path(out_dir) / f"p{p}" for p in papers}
    done: dict = {}
    with Progress(len(papers), "reproduce", unit="paper", enabled=progress) as bar:
        if jobs <= 1 or len(papers) < 2:
            for paper in papers:
                bar.note(f"paper {paper}")
                done[paper] = _run_recorded(paper, subs[paper], quick, progress)
                bar.update(1)
        else:
            import concurrent.futures as cf
            import multiprocessing as mp

            order = sorted(papers, key=lambda p: (LONGEST_FIRST + tuple(papers)).index(p))
            with cf.ProcessPoolExecutor(max_workers=min(jobs, len(papers)),
                                        mp_context=mp.get_context("spawn")) as pool:
                futs = {pool.submit(_run_recorded, p, subs[p], quick, False): p for p in order}
                for fut in cf.as_completed(futs):
                    paper = futs[fut]
                    try:
                        done[paper] = fut.result()
                    except Exception as exc:  # noqa: BLE001 - its process died
                        done[paper] = _failed(paper, exc)
                    bar.note(f"paper {paper} done")
                    bar.update(1)
    results = {p: done[p] for p in papers}
    if out_dir is not None:
        try:
            from gnomon.report.html import build_report
        except ImportError:
            pass
        else:
            build_report(Path(out_dir), results, quick=quick)
    return results
