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

__all__ = ["names", "get", "create", "describe", "default_for", "KINDS", "DEFAULT_ORDER",
           "OFFLINE_DEFAULT_ORDER"]

KINDS = ("imu", "spacecraft")

_ENTRIES: dict[str, str] = {
    "mahony": "gnomon.estimators.mahony:Mahony",
    "tilt-cf": "gnomon.estimators.complementary:TiltComplementaryFilter",
    "eskf-r6": "gnomon.estimators.eskf:EskfR6",
    "eskf-r3": "gnomon.estimators.eskf:EskfR3",
    "ecf-spacecraft": "gnomon.estimators.ecf_spacecraft:ExplicitSpacecraftCF",
    "qcf": "gnomon.estimators.qcf:QuaternionCF",
    "mekf": "gnomon.estimators.mekf:MEKF",
    "mekf-delayed": "gnomon.estimators.mekf:MEKFDelayed",
    "ekf-spacecraft": "gnomon.estimators.ekf_spacecraft:EKFSpacecraft",
    "mekf-spacecraft": "gnomon.estimators.mekf:MEKFSpacecraft",
    "robust-ahrs": "gnomon.estimators.robust_ahrs:RobustAHRS",
    "eskf-offline": "gnomon.estimators.eskf_offline:EskfOffline",
    "robust-ahrs-offline": "gnomon.estimators.robust_ahrs_offline:RobustAHRSOffline",
}


#: ``default_for``: the filter run on a recording when none is named, the first of these
#: whose inputs the recording has. A spacecraft recording (a field model in the orbit
#: frame, ``extra.b_o_nT``) with a gyro: ``mekf``, which uses whatever of sun sensors and
#: star tracker it also holds; without a gyro, the gyroless EKF with the dynamics; a 9-axis
#: IMU: robust-ahrs (the benchmarks' best causal filter, docs/benchmarks.md); gyro and
#: accelerometer only: the tilt filter (no heading: the heading is the gyro's integral
#: from zero).
DEFAULT_ORDER = ("mekf", "ekf-spacecraft", "robust-ahrs", "tilt-cf")
#: the same with ``offline``: eskf-offline, the best offline estimator on BROAD and the
#: phones together relative to VQF offline (docs/estimators/offline.md), its uncertainty
#: a model's covariance; then robust-ahrs-offline
OFFLINE_DEFAULT_ORDER = ("eskf-offline", "robust-ahrs-offline")


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


def _inputs_of(rec) -> list[str]:
    """What ``rec`` holds, in the words of the filters' ``needs``."""
    have = [n for n in ("gyro", "accel", "mag", "sun") if getattr(rec, n, None) is not None]
    return have + [f"extra.{k}" for k in ("b_o_nT", "s_o") if rec.extra.get(k) is not None]


def default_for(rec, offline: bool = False) -> tuple[str, str]:
    """The filter to run on ``rec`` when none is named, and why: ``(name, reason)``. The
    first of ``DEFAULT_ORDER`` (``OFFLINE_DEFAULT_ORDER`` with ``offline``) whose
    ``check_inputs`` accepts ``rec`` (its sensors, rates and reference frame); raises
    ``InputError`` naming what the recording holds when none does."""
    order = OFFLINE_DEFAULT_ORDER if offline else DEFAULT_ORDER
    held = ", ".join(_inputs_of(rec)) or "no sensor"
    for name in order:
        try:
            create(name).check_inputs(rec)
        except InputError:
            continue
        family = get(name).kind  # name only the filters of its own family it could not run
        skipped = [n for n in order[:order.index(name)] if get(n).kind == family]
        why = f"the recording holds {held}"
        if skipped:
            why += f"; not enough for {', '.join(skipped)}"
        return name, why
    kind = "offline filter" if offline else "filter"
    needs = "; ".join(f"{n} needs {', '.join(get(n).needs)}" for n in order)
    raise InputError(f"no default {kind} runs on this recording (it holds {held}): "
                     f"{needs}" + ("; without --offline a causal filter may run"
                                   if offline else ""),
                     field="--filter", file=getattr(rec, "source", None) or None)
