"""Where the full real data sets are: one setting per data set, documented in the README.

* BROAD trials: ``$GNOMON_BROAD_DIR``, else ``shared/data/broad`` beside the
  repository (``../shared/data/broad`` from the repository root, or one level
  further up for a git worktree), else none.
* Images for seed 003: ``$GNOMON_IMAGES_DIR``, else ``shared/data/images`` found the same way.
* Flight-controller sample logs (PX4 ``.ulg``, ArduPilot ``.BIN``): ``$GNOMON_LOGS_DIR``,
  else ``shared/data/logs`` found the same way.
* The tyrex smartphone data set (Michel et al. 2018): ``$GNOMON_TYREX_DIR``, else
  ``shared/data/tyrex`` found the same way.

The unit tests never need them: small excerpts ship in ``tests/data``; tests
that use the full sets skip with a message naming the setting.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["broad_dir", "images_dir", "logs_dir", "tyrex_dir", "repo_root"]


def repo_root() -> Path:
    """The source checkout's root (for an editable install; the package's parent otherwise)."""
    return Path(__file__).resolve().parents[2]


def _find(env: str, *parts: str) -> Path | None:
    value = os.environ.get(env)
    if value:
        p = Path(value)
        return p if p.is_dir() else None
    root = repo_root()
    for base in (root.parent, root.parent.parent, Path.cwd().parent):
        p = base.joinpath("shared", "data", *parts)
        if p.is_dir():
            return p
    return None


def broad_dir() -> Path | None:
    """Directory of the full BROAD trials, or None (see the module docstring)."""
    return _find("GNOMON_BROAD_DIR", "broad")


def images_dir() -> Path | None:
    """Directory of the full-size images for seed 003, or None."""
    return _find("GNOMON_IMAGES_DIR", "images")


def logs_dir() -> Path | None:
    """Directory of the sample flight logs (``px4/``, ``ardupilot/``), or None."""
    return _find("GNOMON_LOGS_DIR", "logs")


def tyrex_dir() -> Path | None:
    """Directory of the tyrex smartphone data set (``datasets/``, ``LICENCE``), or None."""
    return _find("GNOMON_TYREX_DIR", "tyrex")
