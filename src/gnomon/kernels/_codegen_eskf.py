"""Generate ``eskf_unrolled.py``: straight-line Kalman updates for r = 3 and r = 6.

The update is traced, not re-written: the plain-Python ``gain`` and ``joseph``
of ``gnomon.kernels.eskf`` are run on symbolic numbers that print one
assignment per arithmetic operation. The generated functions therefore do
exactly the arithmetic of those two functions (and of the operation count
``count_gain_operations`` reports), with every intermediate a local scalar
that the compiler can keep in a register (arrays could alias one another and
force reloads). Regenerate after changing ``gain`` or ``joseph``::

    PYTHONPATH=src python -m gnomon.kernels._codegen_eskf

Does not import numba (only the tracing needs the two plain functions).
"""

from __future__ import annotations

import ast
import inspect
import textwrap
from pathlib import Path

import numpy as np

_TARGET = Path(__file__).with_name("eskf_unrolled.py")


class _Tracer:
    def __init__(self):
        self.lines: list[str] = []
        self.counts = {"mul": 0, "div": 0, "add": 0}
        self.n = 0

    def new(self, expr: str, kind: str) -> _Sym:
        self.n += 1
        name = f"t{self.n}"
        self.lines.append(f"{name} = {expr}")
        self.counts[kind] += 1
        return _Sym(name, self)


class _Sym:
    __slots__ = ("name", "tr")

    def __init__(self, name: str, tr: _Tracer):
        self.name = name
        self.tr = tr

    @staticmethod
    def _n(o) -> str:
        return o.name if isinstance(o, _Sym) else repr(float(o))

    def __mul__(self, o):
        return self.tr.new(f"{self.name} * {self._n(o)}", "mul")

    def __rmul__(self, o):
        return self.tr.new(f"{self._n(o)} * {self.name}", "mul")

    def __truediv__(self, o):
        return self.tr.new(f"{self.name} / {self._n(o)}", "div")

    def __rtruediv__(self, o):
        return self.tr.new(f"{self._n(o)} / {self.name}", "div")

    def __add__(self, o):
        return self.tr.new(f"{self.name} + {self._n(o)}", "add")

    def __radd__(self, o):
        return self.tr.new(f"{self._n(o)} + {self.name}", "add")

    def __sub__(self, o):
        return self.tr.new(f"{self.name} - {self._n(o)}", "add")

    def __rsub__(self, o):
        return self.tr.new(f"{self._n(o)} - {self.name}", "add")


def _plain(func):
    """The undecorated function object (the kernels module wraps it with njit)."""
    return getattr(func, "py_func", func)


def trace(r: int) -> tuple[list[str], dict, dict, dict]:
    """Trace ``gain`` + ``joseph`` for ``r`` measurements.

    Returns (lines, outputs, gain_counts, joseph_counts): ``outputs`` maps
    ``P[i][j]`` (upper triangle) and ``dx[i]`` to symbol names.
    """
    from gnomon.kernels import eskf as k

    gain = _plain(k.gain) if hasattr(k, "gain") else None
    joseph = _plain(k.joseph)
    tr = _Tracer()
    P = np.empty((6, 6), dtype=object)
    for i in range(6):
        for j in range(i, 6):
            P[i, j] = P[j, i] = _Sym(f"p{i}{j}", tr)
    D1 = np.empty((r, 3), dtype=object)
    for i in range(r):
        for j in range(3):
            D1[i, j] = _Sym(f"d{i}{j}", tr)
    Rd = np.array([_Sym(f"rd{i}", tr) for i in range(r)], dtype=object)
    y = np.array([_Sym(f"y{i}", tr) for i in range(r)], dtype=object)
    PDt = np.empty((6, r), dtype=object)
    S = np.empty((r, r), dtype=object)
    K = np.empty((6, r), dtype=object)
    L = np.empty((6, 3), dtype=object)
    M = np.empty((6, 6), dtype=object)
    G = np.empty((6, r), dtype=object)
    dx = np.empty(6, dtype=object)
    gain(P, D1, Rd, r, PDt, S, K)
    gain_counts = dict(tr.counts)
    joseph(P, D1, Rd, y, K, r, L, M, G, dx)
    jos = {key: tr.counts[key] - gain_counts[key] for key in tr.counts}
    out = {f"P{i}{j}": P[i, j].name for i in range(6) for j in range(i, 6)}
    out.update({f"dx{i}": dx[i].name for i in range(6)})
    return tr.lines, out, gain_counts, jos


def function_source(r: int) -> str:
    lines, out, gc, jc = trace(r)
    body = [f"# gain: {gc['mul']} mul, {gc['div']} div, {gc['add']} add; "
            f"joseph + dx: {jc['mul']} mul, {jc['div']} div, {jc['add']} add"]
    body += [f"p{i}{j} = P[{i}, {j}]" for i in range(6) for j in range(i, 6)]
    body += [f"d{i}{j} = D1[{i}, {j}]" for i in range(r) for j in range(3)]
    body += [f"rd{i} = Rd[{i}]" for i in range(r)]
    body += [f"y{i} = y[{i}]" for i in range(r)]
    body += lines
    for i in range(6):
        for j in range(i, 6):
            body.append(f"P[{i}, {j}] = {out[f'P{i}{j}']}")
            if j != i:
                body.append(f"P[{j}, {i}] = {out[f'P{i}{j}']}")
    body += [f"dx[{i}] = {out[f'dx{i}']}" for i in range(6)]
    doc = (f'"""Straight-line ``gain`` + ``joseph`` + mirror for r = {r} (generated; '
           f'see ``_codegen_eskf``)."""')
    src = (f'@njit(cache=True, fastmath=True, error_model="numpy")\n'
           f"def update_r{r}(P, D1, Rd, y, dx):\n    {doc}\n"
           + textwrap.indent("\n".join(body), "    ") + "\n")
    ast.parse(src)
    return src


def generate() -> str:
    from gnomon.kernels import eskf as k

    header = (
        '"""GENERATED by ``python -m gnomon.kernels._codegen_eskf`` - do not edit.\n\n'
        "Straight-line twins of ``gnomon.kernels.eskf.gain`` + ``joseph`` for r = 3 and\n"
        "r = 6 measurements (n = 6 states), traced from their source so that the\n"
        "arithmetic is identical; tested against the loop versions and the numpy\n"
        "reference in ``tests/test_eskf.py``.\n"
        f"Source hash of gain+joseph: {_source_hash(k)}\n"
        '"""\n\n'
        "from numba import njit\n\n"
        '__all__ = ["update_r3", "update_r6"]\n'
    )
    return header + "\n\n" + function_source(3) + "\n\n" + function_source(6)


def _source_hash(k) -> str:
    import hashlib

    src = inspect.getsource(_plain(k.gain)) + inspect.getsource(_plain(k.joseph))
    return hashlib.sha256(src.encode()).hexdigest()[:16]


if __name__ == "__main__":
    _TARGET.write_text(generate())
    print(f"wrote {_TARGET}")
