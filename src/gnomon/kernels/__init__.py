"""Numba-compiled hot loops: the fast twins of the estimators' readable ``update``.

Every kernel module has a readable twin (the estimator's per-sample ``update`` in
``gnomon.estimators``) and a test comparing the two sample by sample. Kernels never
import estimator modules; estimators import their kernel module (which imports
numba; ``import gnomon`` does not).

The shape of a filter's kernel (as VQF's ``Params`` → ``Coefficients`` → ``State``):

* **Coefficients**: a ``typing.NamedTuple`` of floats (and tuples of floats), built
  once from the ``Params`` and the sample time by the module's ``coefficients(...)``.
  numba passes it by value: immutable, one argument instead of dozens of positional
  numbers, and its fields are read by name (``c.k_mag``).
* **State**: a numpy structured dtype (``STATE``) whose fields are named scalars,
  vectors and matrices (``q_gyr (4,)``, ``bias (3,)``, ``P (3, 3)``, ``rest_t``). A
  filter holds it as an array of one element, ``np.zeros(1, STATE)``; the kernel
  takes ``s = state[0]``, a numba record that reads and writes the array in place
  (``s.delta += k * dis``, ``s.q_gyr[0] = w``). Why a record: numba compiles its
  fields to fixed offsets, as fast as the flat arrays with offset constants it
  replaces; ``cache=True`` works with it (numba's ``jitclass`` cannot be cached and
  compiles anew in every process); and the readable twin works on the very same
  object through ``state.view(np.recarray)[0]`` with the same field names, so a
  state saved by ``get_state`` is the one either twin continues from.
* **Step**: one function per phase (gyro prediction, accelerometer, magnetometer,
  other sensors), each short enough to read on one screen, called in order by the
  per-sample step; the batch loop over samples calls the step and writes outputs.
  Each phase is compiled as a function of its own (``cache=True``); only few-line
  helpers (``quat``, ``linalg``, a low-pass's start-up step) are ``inline="always"``.
  numba inlines at the level of its own IR and types the caller anew with every
  inlined body, so its compile time grows much faster than the code: with every phase
  inlined into the step, robust-ahrs took 58 s to compile on this project's 2-core
  machine and eskf-r3 48 s; as separate functions 8 s and 17 s, which is what a user's
  first ``gnomon estimate`` waits (``gnomon.kernels.compile_notice`` says so on stderr).
  robust-ahrs' phases, called only from compiled code, are compiled without the wrappers
  that let Python (``no_cpython_wrapper``) or a C caller (``no_cfunc_wrapper``) call
  them: 12-18 % of its compile time (6.4-6.7 -> 5.2-5.6 s on one machine, 15.2 -> 12.5-13.6
  s on a slower one; its readable twin is numpy code of its own and never calls them); the
  entry points keep their Python wrapper.
  The price is a call per phase and sample: batch loops 1.2-1.4x slower than inlined
  (``gnomon bench``: robust-ahrs 1.79x and eskf-r3 1.37x the speed of VQF's C++
  ``updateBatch``, eskf-r6 0.94x; they were 2.71x, 1.89x and 1.31x).
  The spacecraft kernels (``spacecraft_cf``, ``mekf``) and ``mahony`` keep their phases
  inlined: split, their loops ran 1.9-2.2x slower (ECF 12.1 -> 6.5, MEKF 1.38 -> 0.63
  M samples/s, ``gnomon.reproduce.p000.benchmark_speed``) and their compile times were
  already moderate. robust-ahrs'
  batch and per-sample kernels take its coefficients in the same form (a record,
  ``entry.record``), so its step is compiled once for both.

Helpers shared by all kernels live in ``quat`` (quaternion product, exponential,
rotation, normalisation) and ``linalg`` (cross products, 3x3 inverse, clipping,
symmetrising): a kernel never writes them again.

Kernels take every argument explicitly (an omitted default costs ~37 µs per call in
numba), write into preallocated output arrays, and use ``cache=True`` (compiled code
on disk). numba keys a cached kernel on its own module file only: a kernel that
inlines a helper from another module (``quat.exp_mul``) would keep running the old
helper after that file changes in a source checkout (an installed package never
changes). ``drop_stale_caches`` removes the cache files of a kernel module when its
source or that of a kernel module it imports (directly or not) differs from the
sources they were compiled from, and keeps the others: an edit of ``robust_ahrs.py``
recompiles robust-ahrs alone, one of ``quat.py`` every kernel that uses it. The test
suite and the command line call it in a source checkout (``python -m gnomon.kernels``
does it by hand). Importing this package has no side effect.
"""

from __future__ import annotations

import ast
import hashlib
import json
import os
from pathlib import Path

__all__ = ["drop_stale_caches", "module_digests", "in_source_checkout", "PACKAGE_DIR"]

_STAMP = "gnomon-kernels.sources"
PACKAGE_DIR = Path(__file__).resolve().parent


def in_source_checkout(package_dir: Path = PACKAGE_DIR) -> bool:
    """Whether gnomon runs from a git checkout (``src/gnomon/kernels`` under a work tree),
    where kernel sources can change under their compiled caches."""
    root = package_dir.parents[2]
    return (root / ".git").exists() and (root / "pyproject.toml").is_file()


def _kernel_imports(source: str, modules: set[str]) -> set[str]:
    """The kernel modules (names in ``modules``) that ``source`` imports, as
    ``from gnomon.kernels.quat import ...``, ``from gnomon.kernels import quat``,
    ``import gnomon.kernels.quat`` or relatively."""
    found = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom):
            mod = node.module or ""
            if node.level == 1:
                base = mod
            elif node.level == 0 and mod == "gnomon.kernels":
                base = ""
            elif node.level == 0 and mod.startswith("gnomon.kernels."):
                base = mod[len("gnomon.kernels."):]
            else:
                continue
            if base:
                found.add(base.split(".")[0])
            else:
                found.update(a.name for a in node.names)
        elif isinstance(node, ast.Import):
            found.update(a.name.split(".")[2] for a in node.names
                         if a.name.startswith("gnomon.kernels."))
    return found & modules


def module_digests(package_dir: Path = PACKAGE_DIR) -> dict[str, str]:
    """``{module: digest}`` of the kernel modules of ``package_dir``: each a digest of its
    own source and of the sources of every kernel module it imports, directly or through
    another (the code numba compiles into its kernels)."""
    sources = {p.stem: p.read_bytes() for p in sorted(package_dir.glob("*.py"))
               if p.stem not in ("__init__", "__main__")}
    names = set(sources)
    imports = {m: _kernel_imports(src.decode("utf-8"), names) - {m}
               for m, src in sources.items()}
    out = {}
    for m in sorted(sources):
        seen, todo = {m}, [m]
        while todo:
            for dep in imports[todo.pop()]:
                if dep not in seen:
                    seen.add(dep)
                    todo.append(dep)
        digest = hashlib.sha256()
        for dep in sorted(seen):
            digest.update(dep.encode() + b"\0" + sources[dep] + b"\0")
        out[m] = digest.hexdigest()
    return out


def drop_stale_caches(package_dir: Path = PACKAGE_DIR) -> list[str]:
    """Delete the compiled caches (``package_dir/__pycache__/MODULE.*.nbi|nbc``) of every
    kernel module whose source, or the source of a kernel module it imports (directly or
    not), changed since the last call, and those of no known module; a digest per module
    is kept beside them. Returns the modules whose caches were dropped (empty: nothing
    changed); a read-only directory is left alone.

    numba notices a change of a kernel's own file, not of a helper it inlined from
    another: after an edit of ``quat.py`` every kernel that uses it compiles anew, the
    others (and their compile time) are kept."""
    whole = hashlib.sha256()
    for src in sorted(package_dir.glob("*.py")):
        whole.update(src.name.encode() + b"\0" + src.read_bytes())
    cache = package_dir / "__pycache__"
    stamp = cache / _STAMP
    try:
        old = json.loads(stamp.read_text())
        if old.get("all") == whole.hexdigest():
            return []
        old_modules = dict(old.get("modules", {}))
    except (OSError, ValueError, AttributeError):
        old_modules = {}
    digests = module_digests(package_dir)
    stale = sorted(m for m, d in digests.items() if old_modules.get(m) != d)
    try:
        files = list(cache.glob("*.nbi")) + list(cache.glob("*.nbc"))
        dropped = set()
        for f in files:
            module = f.name.split(".", 1)[0]
            if module in stale or module not in digests:
                f.unlink(missing_ok=True)
                dropped.add(module)
        cache.mkdir(exist_ok=True)
        tmp = cache / f"{_STAMP}.{os.getpid()}"
        tmp.write_text(json.dumps({"all": whole.hexdigest(), "modules": digests}, indent=0))
        os.replace(tmp, stamp)  # atomic: a parallel worker never reads half a digest
    except OSError:
        return []
    return sorted(dropped)
