"""Filter names -> estimator classes, for the command line and the benchmarks.

Classes are imported lazily (``import gnomon`` stays light). To add a filter,
add one line to ``_ENTRIES``.
"""

from __future__ import annotations

import importlib

from gnomon.errors import InputError

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
}


def names() -> list[str]:
    """Registered filter names, sorted."""
    return sorted(_ENTRIES)


def get(name: str):
    """The estimator class registered as ``name``; unknown names raise ``InputError``."""
    try:
        target = _ENTRIES[name]
    except KeyError:
        raise InputError(f"unknown filter {name!r}; known: {', '.join(names())}",
                         field="filter") from None
    module, attr = target.split(":")
    return getattr(importlib.import_module(module), attr)


def create(name: str, params: dict | None = None):
    """An instance of filter ``name`` with parameters from a mapping (unknown keys raise)."""
    cls = get(name)
    return cls(cls.Params.from_dict(params or {}))
