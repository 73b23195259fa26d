"""``--vary KEY=DIST``: parsing a distribution and drawing from it.

``DIST`` is ``normal(mu, sigma)``, ``uniform(a, b)``, ``loguniform(a, b)``,
``choice(a, b, ...)`` (numbers or bare words) or a constant (``3.5``, ``tilt``,
``const(x)``, a vector ``[0.5, -0.3, 0.4]``). Invalid parameters raise ``InputError``
naming the key, before any run starts. Whether ``KEY`` exists is the runner's check
(:mod:`gnomon.campaign.runner`), not this module's.
"""

from __future__ import annotations

import ast
import dataclasses
import math
import re
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from gnomon.errors import InputError

__all__ = ["Distribution", "parse_distribution", "parse_vary"]


@dataclasses.dataclass(frozen=True)
class Distribution:
    """A parsed ``DIST``.

    ``kind``: ``normal`` (args ``(mu, sigma)``), ``uniform`` / ``loguniform`` (``(a, b)``),
    ``choice`` (the values), ``const`` (``(value,)``). ``text``: what was parsed.
    """

    kind: str
    args: tuple
    text: str = ""

    def draw(self, rng: np.random.Generator) -> Any:
        """One value: a float for the continuous kinds, one of the values for ``choice``
        and ``const`` (a number, a word or a list of floats). Uses ``rng`` once (none for
        ``const``), so the draws of a run depend only on the order of its keys."""
        k, a = self.kind, self.args
        if k == "const":
            return a[0]
        if k == "normal":
            return float(rng.normal(a[0], a[1]))
        if k == "uniform":
            return float(rng.uniform(a[0], a[1]))
        if k == "loguniform":
            return float(math.exp(rng.uniform(math.log(a[0]), math.log(a[1]))))
        return a[int(rng.integers(len(a)))]


def _literal(tok: str):
    tok = tok.strip()
    if not tok:
        raise ValueError("empty value")
    try:
        v = ast.literal_eval(tok)
    except (ValueError, SyntaxError):
        return tok  # a bare word: a string
    if isinstance(v, bool | int | float | str):
        return v
    raise ValueError(f"unsupported value {tok!r}")


_DIST_RE = re.compile(r"^\s*([a-z_]+)\s*\((.*)\)\s*$", re.S)


def parse_distribution(text: str, key: str = "vary") -> Distribution:
    """Parse ``normal(0,2)``, ``uniform(a,b)``, ``loguniform(a,b)``, ``choice(a,b,c)``,
    ``const(x)`` or a bare constant. Invalid parameters raise ``InputError`` naming ``key``."""
    m = _DIST_RE.match(str(text))
    if not m:
        try:
            v = ast.literal_eval(str(text).strip())
        except (ValueError, SyntaxError):
            v = None
        if isinstance(v, list | tuple) and v and all(
                isinstance(x, int | float) and not isinstance(x, bool) for x in v):
            return Distribution("const", ([float(x) for x in v],), str(text))  # a vector
        try:
            return Distribution("const", (_literal(str(text)),), str(text))
        except ValueError as err:
            raise InputError(f"{err}", field=key) from None
    kind, body = m.group(1), m.group(2)
    try:
        args = tuple(_literal(t) for t in body.split(",")) if body.strip() else ()
    except ValueError as err:
        raise InputError(f"{text!r}: {err}", field=key) from None
    bad = lambda msg: InputError(f"{text!r}: {msg}", field=key)  # noqa: E731
    nums = all(isinstance(v, int | float) and not isinstance(v, bool) for v in args)
    if kind in ("normal", "uniform", "loguniform"):
        if len(args) != 2 or not nums:
            raise bad(f"{kind} takes two numbers")
        a, b = (float(x) for x in args)
        if not (math.isfinite(a) and math.isfinite(b)):
            raise bad("parameters must be finite")
        if kind == "normal" and b < 0:
            raise bad("the standard deviation must be >= 0")
        if kind in ("uniform", "loguniform") and b < a:
            raise bad("needs a <= b")
        if kind == "loguniform" and a <= 0:
            raise bad("needs 0 < a")
        return Distribution(kind, (a, b), text)
    if kind == "choice":
        if not args:
            raise bad("choice needs at least one value")
        return Distribution(kind, args, text)
    if kind == "const":
        if len(args) != 1:
            raise bad("const takes one value")
        return Distribution(kind, args, text)
    raise bad("unknown distribution; use normal, uniform, loguniform, choice, const or a value")


def parse_vary(vary: Mapping[str, str] | Sequence[str] | None) -> dict[str, Distribution]:
    """``{"KEY": "DIST"}`` or ``["KEY=DIST", ...]`` -> ``{KEY: Distribution}`` (order kept)."""
    if vary is None:
        return {}
    items = []
    if isinstance(vary, Mapping):
        items = list(vary.items())
    else:
        for s in vary:
            if "=" not in s:
                raise InputError(f"expected KEY=DIST, got {s!r}", field="vary")
            k, v = s.split("=", 1)
            items.append((k.strip(), v.strip()))
    out = {}
    for k, v in items:
        if not k:
            raise InputError(f"empty key in {k}={v}", field="vary")
        if k in out:
            raise InputError("given twice", field=k)
        out[k] = v if isinstance(v, Distribution) else parse_distribution(v, key=k)
    return out
