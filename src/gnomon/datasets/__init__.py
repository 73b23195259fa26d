"""The data sets gnomon knows: where the full sets are, the excerpts it ships, fetching.

Full data sets, one lookup per set (the first that exists wins):

1. the setting ``$GNOMON_BROAD_DIR`` / ``$GNOMON_TYREX_DIR`` / ``$GNOMON_LOGS_DIR`` /
   ``$GNOMON_IMAGES_DIR`` (a folder in the set's layout);
2. ``shared/data/<name>`` beside the repository (``../shared/data/<name>`` from the
   repository root, or one level further up for a git worktree): for developers;
3. the copy fetched by ``gnomon datasets fetch <name>`` into the cache folder
   (:func:`gnomon.datasets.fetch.cache_dir`, moved by ``$GNOMON_DATA_DIR``), once complete.

Small excerpts ship inside the package (``gnomon/data``, with their attribution in its
``README.md``) and are found with :func:`bundled`, through ``importlib.resources``, so
the reproductions' ``--quick`` modes, the examples and the tests run from a plain wheel.

The catalogue (:data:`gnomon.datasets.catalogue.CATALOGUE`) names each set's source,
licence and files; :mod:`gnomon.datasets.fetch` downloads and verifies them.
"""

from __future__ import annotations

import importlib.resources
import os
from pathlib import Path

from gnomon.datasets.catalogue import CATALOGUE, DataSet, dataset
from gnomon.datasets.fetch import FetchError, cache_dir, fetch, fetched_dir, status

__all__ = ["broad_dir", "images_dir", "logs_dir", "tyrex_dir", "repo_root", "bundled",
           "dataset_dir", "CATALOGUE", "DataSet", "dataset", "fetch", "fetched_dir",
           "cache_dir", "status", "FetchError", "describe"]


def repo_root() -> Path:
    """The source checkout's root (for an editable install; the package's parent otherwise)."""
    return Path(__file__).resolve().parents[3]


def bundled(*parts: str) -> Path:
    """Path of a file or folder shipped in the package data ``gnomon/data`` (its root
    without arguments), e.g. ``bundled("broad", "trials.json")``.

    Found through ``importlib.resources``, so it works from a wheel as from a checkout;
    the package must be installed on a file system (not imported from a zip archive).
    Raises ``FileNotFoundError`` naming the path when nothing is there.
    """
    root = importlib.resources.files("gnomon") / "data"
    path = Path(str(root.joinpath(*parts)))
    if not path.exists():
        raise FileNotFoundError(f"gnomon's package data has no {'/'.join(parts) or 'data'} "
                                f"(looked in {path})")
    return path


def _shared(*parts: str) -> Path | None:
    """``shared/data/<parts>`` beside the repository or one level up (a worktree), or
    beside the working folder's parent: the developers' copies; None when absent."""
    root = repo_root()
    for base in (root.parent, root.parent.parent, Path.cwd().parent):
        p = base.joinpath("shared", "data", *parts)
        if p.is_dir():
            return p
    return None


def dataset_dir(name: str) -> Path | None:
    """Folder of the full data set ``name`` (see the module docstring for the order), or
    None when it is nowhere. A setting naming a missing folder gives None (it is not
    silently replaced by another copy)."""
    ds = dataset(name)
    value = os.environ.get(ds.env)
    if value:
        p = Path(value)
        return p if p.is_dir() else None
    return _shared(ds.name) or fetched_dir(ds.name)


def broad_dir() -> Path | None:
    """Directory of the full BROAD trials, or None (see the module docstring)."""
    return dataset_dir("broad")


def images_dir() -> Path | None:
    """Directory of the full-size images for seed 003, or None."""
    return dataset_dir("images")


def logs_dir() -> Path | None:
    """Directory of the sample flight logs (``px4/``, ``ardupilot/``), or None."""
    return dataset_dir("logs")


def tyrex_dir() -> Path | None:
    """Directory of the tyrex smartphone data set (``datasets/``, ``LICENCE``), or None."""
    return dataset_dir("tyrex")


def describe(name: str) -> dict:
    """What ``gnomon datasets`` prints for data set ``name``: the catalogue entry's fields
    plus ``bundled`` (path of the shipped excerpt or None), ``local`` (a copy named by the
    setting or beside the repository, or None), ``cache`` (folder), ``cached_files``,
    ``files``, ``bytes`` (the whole set) and ``state``: ``"local"``, ``"cached"``,
    ``"partly fetched"`` or ``"not fetched"``."""
    ds = dataset(name)
    value = os.environ.get(ds.env)
    if value:
        local = Path(value) if Path(value).is_dir() else None
    else:
        local = _shared(ds.name)
    st = status(ds.name)
    try:
        excerpt = bundled(ds.bundled)
    except FileNotFoundError:
        excerpt = None
    if local is not None:
        state = "local"
    elif st.complete:
        state = "cached"
    else:
        state = "partly fetched" if st.present else "not fetched"
    return {"name": ds.name, "title": ds.title, "licence": ds.licence, "source": ds.source,
            "citation": ds.citation, "scope": ds.scope, "env": ds.env,
            "bundled": None if excerpt is None else str(excerpt),
            "local": None if local is None else str(local), "cache": str(st.folder),
            "cached_files": st.present, "files": st.total, "bytes": st.bytes_total,
            "state": state}
