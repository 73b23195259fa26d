"""Seeds and draws: what makes run ``index`` of a campaign the run it is.

Run ``index`` of a campaign with root seed ``R`` is fully described by
``(index, seed, parameters)`` (a :class:`Run`), computed from the child sequence
``SeedSequence(R).spawn(N)[index]`` alone (built directly as
``SeedSequence(R, spawn_key=(index,))``, the same sequence, so ``N`` does not matter):

* ``seed``: the child's first 64-bit state word; the simulation is seeded with it;
* ``parameters``: one draw per ``--vary`` key, in the order given, from a generator on
  the child's own first child (``spawn_key=(index, 0)``).

So any run can be re-run alone, on any machine, and gives the identical row.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from gnomon.campaign.distributions import Distribution

__all__ = ["Run", "describe_run", "run_seed", "draw_parameters"]


@dataclasses.dataclass(frozen=True)
class Run:
    """Run ``index``: its 64-bit ``seed`` and drawn ``params`` (``{KEY: value}``, in order)."""

    index: int
    seed: int
    params: dict[str, Any]


def describe_run(root_seed: int, index: int, dists: Mapping[str, Distribution]) -> Run:
    """The :class:`Run` ``index`` of a campaign with ``root_seed`` and distributions ``dists``."""
    child = np.random.SeedSequence(int(root_seed), spawn_key=(int(index),))
    seed = int(child.generate_state(1, np.uint64)[0])
    rng = np.random.default_rng(child.spawn(1)[0]) if dists else None
    return Run(int(index), seed, {k: d.draw(rng) for k, d in dists.items()})


def run_seed(root_seed: int, index: int) -> int:
    """The 64-bit seed of run ``index``: state of ``SeedSequence(root_seed).spawn(N)[index]``."""
    return describe_run(root_seed, index, {}).seed


def draw_parameters(root_seed: int, index: int, dists: Mapping[str, Distribution]) -> dict:
    """The parameters of run ``index`` (one draw per key, in order)."""
    return describe_run(root_seed, index, dists).params
