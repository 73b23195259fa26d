"""Filter names -> estimator classes, for the command line, benchmarks and campaigns.

Classes are imported lazily (``import gnomon`` stays light). To add a filter, add
one line to ``_ENTRIES``; everything else (``gnomon filters``, the benchmarks, the
speed table, campaigns, the docs' filter tables) finds it here and reads what it
needs from the class: ``name``, ``summary``, ``paper``, ``kind`` (``"imu"`` or
``"spacecraft"``), ``needs`` and ``Params``.
"""

from __future__ import annotations

import importlib

from gnomon.errors import InputError

__all__ = ["names", "get", "create", "describe", "KINDS"]

KINDS = ("imu", "spacecraft")

_ENTRIES: dict[str, str] = {
    "mahony": "gnomon.estimators.mahony:Mahony",
    "tilt-cf": "gnomon.estimators.complementary:TiltComplementaryFilter",
    "eskf-r6": "gnomon.estimators.eskf:EskfR6",
    "eskf-r3": "gnomon.estimators.eskf:EskfR3",
    "ecf-spacecraft": "gnomon.estimators.ecf_spacecraft:ExplicitSpacecraftCF",
    "qcf": "gnomon.estimators.qcf:QuaternionCF",
    "mekf-delayed": "gnomon.estimators.mekf_spacecraft:MagGyroMEKF",
    "ekf-spacecraft": "gnomon.estimators.ekf_spacecraft:EKFSpacecraft",
    "mekf-spacecraft": "gnomon.estimators.mekf_spacecraft:MEKFSpacecraft",
    "robust-ahrs": "gnomon.estimators.robust_ahrs:RobustAHRS",
    "eskf-offline": "gnomon.estimators.eskf_offline:EskfOffline",
    "robust-ahrs-offline": "gnomon.estimators.robust_ahrs_offline:RobustAHRSOffline",
}


def names(kind: str | None = None, offline: bool | None = None) -> list[str]:
    """Registered filter names, sorted; ``kind`` ``"imu"`` or ``"spacecraft"`` selects one
    family; ``offline`` True / False only the filters that need the whole log (names
    ending in ``-offline``: forward-backward over a recording) / only the causal ones."""
    if kind is not None and kind not in KINDS:
        raise InputError(f"expected one of {', '.join(KINDS)}, got {kind!r}", field="kind")
    return [n for n in sorted(_ENTRIES)
            if (kind is None or get(n).kind == kind)
            and (offline is None or bool(getattr(get(n), "offline", False)) == offline)]


def get(name: str):
    """The estimator class registered as ``name``; unknown names raise ``InputError``."""
    try:
        target = _ENTRIES[name]
    except KeyError:
        raise InputError(f"unknown filter {name!r}; known: {', '.join(names())}",
                         field="filter") from None
    module, attr = target.split(":")
    return getattr(importlib.import_module(module), attr)


def create(name: str, params: dict | None = None, **overrides):
    """An instance of filter ``name`` with parameters from a mapping and/or keywords
    (``create("mahony", kp_acc_rad_s=0.5)``; unknown names raise ``InputError``)."""
    cls = get(name)
    return cls(cls.Params.from_dict({**(params or {}), **overrides}))


def describe(kind: str | None = None) -> list[dict]:
    """One row per filter: ``name``, ``summary``, ``paper``, ``kind``, ``needs`` and its
    parameters (``Params.describe()``)."""
    rows = []
    for name in names(kind):
        cls = get(name)
        rows.append({"name": name, "summary": cls.summary, "paper": cls.paper,
                     "kind": cls.kind, "needs": list(cls.needs),
                     "params": cls.Params.describe()})
    return rows
