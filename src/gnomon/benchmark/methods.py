"""The rows of a benchmark: gnomon's filters and the reference libraries, as methods.

A method is ``(name, fn, applies)``: ``fn(rec)`` returns an ``Estimate`` or the attitude
``q`` (N, 4); ``applies(rec)`` says whether it runs on that recording at all (the device's
own estimate where there is none is left out without an error).

**Rows that are not gnomon filters** (``gnomon.anchors``): ``vqf``, ``imufusion``,
``ahrs-madgwick`` (causal libraries, default parameters), ``vqf-offline`` (VQF's
acausal batch variant), ``phone`` (tyrex) / ``onboard`` (generic): the device's own
estimate ``q_onboard``, scored over the rows where it exists (``samples`` says how many).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from gnomon import anchors as anchors_mod
from gnomon.errors import InputError
from gnomon.estimators import registry
from gnomon.recording import Recording

__all__ = ["Method", "ALIASES", "default_filters", "default_anchors", "make_methods",
           "method_names"]

#: row name -> anchor (the device's own estimate has its data set's name)
ALIASES = {"phone": "onboard"}

# (name, q = fn(rec), applies(rec) -> bool)
Method = tuple[str, Callable[[Recording], np.ndarray], Callable[[Recording], bool]]


def default_filters() -> tuple[str, ...]:
    """The gnomon filters run by default: every registered IMU filter (``kind = "imu"``),
    the causal ones and the offline ones (``-offline``: they see the whole log; compare
    them with the ``vqf-offline`` row)."""
    return tuple(registry.names("imu"))


def default_anchors() -> list[str]:
    """The causal libraries and VQF's offline form, where installed."""
    return anchors_mod.available() + [a for a in ("vqf-offline",) if anchors_mod.installed(a)]


def _always(rec: Recording) -> bool:
    return True


def _has_onboard(rec: Recording) -> bool:
    return rec.q_onboard is not None


def make_methods(filters: Sequence[str], anchors: Sequence[str] | None) -> list[Method]:
    """The methods of ``filters`` (registry names; an unknown name fails before any trial
    runs) and ``anchors`` (row names of ``gnomon.anchors`` or :data:`ALIASES`; None:
    :func:`default_anchors`)."""
    methods: list[Method] = []
    for name in filters:
        registry.get(name)  # unknown names fail before any trial runs

        def run_filter(rec, name=name):
            return registry.create(name).run(rec)

        methods.append((name, run_filter, _always))
    names = default_anchors() if anchors is None else list(anchors)
    known = [*anchors_mod.ANCHORS, *anchors_mod.EXTRA_ANCHORS, *ALIASES]
    for name in names:
        target = ALIASES.get(name, name)
        if target not in anchors_mod.ANCHORS and target not in anchors_mod.EXTRA_ANCHORS:
            raise InputError(f"unknown reference library {name!r}; known: "
                             f"{', '.join(known)}", field="anchors")
        applies = _has_onboard if target == "onboard" else _always
        methods.append((name, lambda rec, t=target: anchors_mod.run_anchor(t, rec), applies))
    return methods


def method_names(methods: list[Method]) -> list[str]:
    """The row names of ``methods``, in order."""
    return [m for m, _, _ in methods]
