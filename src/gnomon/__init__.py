"""gnomon: attitude determination and estimation.

The few things a user needs are here (imported on first use, so ``import gnomon``
stays fast)::

    import gnomon

    rec = gnomon.read("trial.hdf5")                    # a Recording (CSV, BROAD, HDF5)
    est = gnomon.make_filter("robust-ahrs").run(rec)   # est.q: (N, 4) q_ENU_sensor
    print(gnomon.score(rec.q_true, est.q, rec.score_mask))
    gnomon.plot_estimate(rec, est, "est.png")          # attitude, error, signals

    gnomon.list_filters()                              # names; gnomon.describe_filters()
    sc = gnomon.load_scenario("seed001")               # a preset or a YAML file
    sim = gnomon.simulate(sc)                          # a Recording with truth
    res = gnomon.run_campaign(sc, runs=100, out_dir="mc")

    f = gnomon.make_filter("mahony"); q = f.update(dt, gyro, accel, mag)  # live, compiled
    live = gnomon.LiveFilter(f); live.push("gyro", t, w)  # sensors as they arrive
    gnomon.calibrate_mag(rec); gnomon.export_c("mahony", "fw/")  # calibration, C code

Conventions: ``docs/conventions.md`` (Hamilton quaternions ``[w, x, y, z]``, ``q_ab``
maps b- to a-coordinates, SI units inside).
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

#: public name -> "module:attribute"
_EXPORTS = {
    "Recording": "gnomon.recording:Recording",
    "Estimate": "gnomon.estimators.base:Estimate",
    "InputError": "gnomon.errors:InputError",
    "read": "gnomon.io:read",
    "write": "gnomon.io:write",
    "make_filter": "gnomon.estimators.registry:create",
    "list_filters": "gnomon.estimators.registry:names",
    "describe_filters": "gnomon.estimators.registry:describe",
    "score": "gnomon.metrics:score",
    "error_angle_rad": "gnomon.metrics:error_angle_rad",
    "plot_estimate": "gnomon.report.figures:plot_estimate",
    "inspect": "gnomon.io:inspect",
    "load_scenario": "gnomon.scenarios:load_scenario",
    "list_scenarios": "gnomon.scenarios:list_presets",
    "simulate": "gnomon.scenarios:simulate",
    "run_campaign": "gnomon.campaign:run_campaign",
    "read_results": "gnomon.campaign:read_results",
    "calibrate_mag": "gnomon.calibration:calibrate_mag",
    "apply_mag_calibration": "gnomon.calibration:apply_mag_calibration",
    "LiveFilter": "gnomon.live.stream:LiveFilter",
    "run_live": "gnomon.live.runner:run_live",
    "open_source": "gnomon.live.sources:open_source",
    "export_c": "gnomon.export:export_c",
    "run_benchmark": "gnomon.benchmark:run",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str):
    try:
        module, attr = _EXPORTS[name].split(":")
    except KeyError:
        raise AttributeError(f"module 'gnomon' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), attr)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
