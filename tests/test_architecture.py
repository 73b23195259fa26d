"""The package's import graph: no cycle inside ``src/gnomon``, and lower layers never
import higher ones (``docs/architecture.md``). Read from the source with ``ast``: every
``import`` statement counts, also the ones inside functions (a lazy import that
closes a cycle is still a cycle for the reader)."""

import ast
import functools
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"


def _modules() -> dict[str, Path]:
    mods = {}
    for path in (SRC / "gnomon").rglob("*.py"):
        parts = list(path.relative_to(SRC).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        mods[".".join(parts)] = path
    return mods


def _imports(path: Path, name: str, known: set[str]) -> set[str]:
    """gnomon modules imported anywhere in the module ``name`` at ``path``."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parent + ([base] if base else []))
            # ``from gnomon.kernels import quat`` imports the module gnomon.kernels.quat
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base
                       for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in known:  # ``import gnomon.io.csv as x`` -> gnomon.io.csv
                t = t.rpartition(".")[0]
            if t and t != name:
                out.add(t)
    return out


@functools.cache  # one parse of the package for every test here
def _graph() -> dict[str, set[str]]:
    mods = _modules()
    known = set(mods)
    return {name: _imports(path, name, known) for name, path in mods.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle_inside_gnomon():
    cycles = _cycles(_graph())
    assert not cycles, "import cycles: " + "; ".join(" <-> ".join(c) for c in cycles)


# layer -> the gnomon packages/modules it must never import (anywhere in its code)
FORBIDDEN = {
    "gnomon.kernels": ("gnomon.estimators", "gnomon.campaign", "gnomon.cli", "gnomon.report",
                       "gnomon.reproduce", "gnomon.io", "gnomon.scenarios"),
    "gnomon.rotation": ("gnomon.",),
    "gnomon.errors": ("gnomon.",),
    "gnomon.recording": ("gnomon.estimators", "gnomon.io", "gnomon.cli", "gnomon.campaign"),
    "gnomon.estimators": ("gnomon.cli", "gnomon.campaign", "gnomon.report", "gnomon.reproduce"),
    "gnomon.metrics": ("gnomon.estimators", "gnomon.cli", "gnomon.campaign"),
    "gnomon.io": ("gnomon.estimators", "gnomon.cli", "gnomon.campaign", "gnomon.report"),
}
ALLOWED = {"gnomon.rotation": ("gnomon.errors",), "gnomon.recording": ()}


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_lower_layers_do_not_import_higher_ones(layer):
    bad = []
    for mod, deps in _graph().items():
        if mod != layer and not mod.startswith(layer + "."):
            continue
        for d in deps:
            if d in ALLOWED.get(layer, ()) or d == layer or d.startswith(layer + "."):
                continue
            if any(d == f or d.startswith(f if f.endswith(".") else f + ".")
                   for f in FORBIDDEN[layer]):
                bad.append(f"{mod} imports {d}")
    assert not bad, "; ".join(sorted(bad))
