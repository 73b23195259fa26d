"""Numba-compiled hot loops, imported lazily by the estimators' ``run``.

Each kernel has a readable twin (the estimator's per-sample ``update``) and a
test comparing the two sample by sample. Kernels take every argument
explicitly (an omitted default costs ~37 µs per call in numba) and write into
preallocated output arrays; ``cache=True`` keeps the compiled code on disk.

numba keys a cached kernel on its own module file only: a kernel that inlines a
helper from another module (``quat.exp_mul`` in ``mahony``) would keep running
the old helper after that file changes in a source checkout (an install rewrites
every file, which numba does notice). ``drop_stale_caches`` therefore removes
this package's cache files whenever any kernel source differs from the sources
they were compiled from; it runs once, when this package is first imported.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

_STAMP = "gnomon-kernels.sources"


def drop_stale_caches(package_dir: Path) -> bool:
    """Delete ``package_dir/__pycache__/*.nbi|*.nbc`` if the ``*.py`` sources changed since
    the last call (a digest is kept beside them). Returns whether caches were dropped;
    a read-only directory is left alone."""
    digest = hashlib.sha256()
    for src in sorted(package_dir.glob("*.py")):
        digest.update(src.name.encode() + b"\0" + src.read_bytes())
    cache = package_dir / "__pycache__"
    stamp = cache / _STAMP
    try:
        if stamp.read_text() == digest.hexdigest():
            return False
    except OSError:
        pass
    try:
        for f in list(cache.glob("*.nbi")) + list(cache.glob("*.nbc")):
            f.unlink(missing_ok=True)
        cache.mkdir(exist_ok=True)
        tmp = cache / f"{_STAMP}.{os.getpid()}"
        tmp.write_text(digest.hexdigest())
        os.replace(tmp, stamp)  # atomic: a parallel worker never reads half a digest
    except OSError:
        return False
    return True


drop_stale_caches(Path(__file__).resolve().parent)
