"""Accuracy on data sets with a reference: gnomon's filters and the reference libraries,
side by side, one metric.

The metric is BROAD's (Laidig, Caruso, Cereatti, Seel, Data 6(7):72, 2021): for every
scored sample (``Recording.score_mask``: ``mask`` and a valid truth)
``q_err = q_est ⊗ conj(q_true)``; total ``2·acos(|w|)``, heading ``2·atan(|z/w|)``,
inclination ``2·acos(sqrt(w²+z²))`` (``gnomon.metrics.broad_errors_rad``); RMSE per trial
in degrees; a method's score is the mean over trials. Every estimate must be
sensor-to-ENU from the first sample on.

Three entry points, one loop (``_run``):

* ``run_benchmark(DIR)`` (``gnomon benchmark DIR``): every recording gnomon reads under
  ``DIR`` (any format, any depth) that holds a truth; no groups, no alignment unless
  asked.
* ``run_broad`` (``gnomon benchmark broad --data DIR``): the BROAD trials, BROAD's groups,
  no alignment (BROAD's own protocol). Its JSON::

    {"metric": "broad", "data",
     "trials": [{"trial", "method", "total_deg", "heading_deg", "inclination_deg"}, ...],
     "mean": {METHOD: {"total_deg", "heading_deg", "inclination_deg", "trials"}},
     "groups": {METHOD: {GROUP: {"total_deg", "heading_deg", "inclination_deg", "trials"}}},
     "samples_per_s": {METHOD: float}, "errors": [...]}

* ``run_tyrex`` (``gnomon benchmark tyrex --data DIR``): the smartphone trials of Michel
  et al. 2018 (:mod:`gnomon.io.tyrex`), truth on magnetic north, groups by phone, motion
  and magnetic disturbance, and by default the truth aligned to each phone
  (``--align body,lag``). Its JSON has BROAD's keys (rows also carry ``samples``,
  ``lag_s``, ``misalignment_deg``, ``phone``, ``motion``, ``disturbance``) plus
  ``benchmark``, ``mag``, ``align``, ``truth``, ``alignment`` (one entry per trial: the
  fit of ``gnomon.metrics.align_truth``), ``alignment_stats``, ``anchor_inputs`` and
  ``skipped``; with ``mag_calibration`` (raw magnetometer only) also ``mag_calibration``
  (the mode) and ``calibrations`` (one entry per trial: where its calibration came from,
  whether it was applied, and the report of :class:`gnomon.calibration.MagCalibration`).

**Magnetometer calibration** (``mag_calibration``, tyrex with ``mag="raw"``):
``"recording"`` corrects each trial's raw magnetometer with the calibration fitted
(:func:`gnomon.calibration.fit_mag`, field magnitude the IGRF value at the data set's
place and date) to the data set's own calibration recording of that phone and day,
``TYREX_MAG_CALIBRATION``; ``"self"`` with the calibration fitted to the trial's own raw
samples (all of them, before the filters run: a batch calibration of the log). A trial
whose calibration is refused (``ok`` false) keeps its raw magnetometer and says so
(``applied: false``); the filters' own online estimates (robust-ahrs's hard iron) stay on
in every case.

**Alignment** (``align``, ``gnomon.metrics.align_truth``): fitted once per trial from the
gyro against the reference's own angular rate, applied to the truth before any method
is scored, so every method is scored against the same corrected truth: ``lag`` shifts
the truth in time (the residual clock offset), ``body`` turns it onto the sensor's axes
(the constant rotation between the sensor and the motion-capture marker body). Nothing
is fitted to any estimate; no heading offset is removed.

**Rows that are not gnomon filters** (``gnomon.anchors``): ``vqf``, ``imufusion``,
``ahrs-madgwick`` (causal libraries, default parameters), ``vqf-offline`` (VQF's
acausal batch variant), ``phone`` (tyrex) / ``onboard`` (generic): the device's own
estimate ``q_onboard``, scored over the rows where it exists (``samples`` says how many).
A method that fails on a trial is recorded in ``errors`` and the run goes on.

**Uncertainty** (estimators that carry ``att_std_rad``, the offline ones): their rows and
means also have ``nees``, the mean normalised estimation error squared over the scored
samples (3 for an honest per-axis standard deviation; ``_nees``).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

import numpy as np

from gnomon import anchors as anchors_mod
from gnomon.errors import InputError
from gnomon.estimators import registry
from gnomon.estimators.base import Estimate
from gnomon.metrics import (
    ALIGN_OPTIONS,
    align_truth,
    body_axis_errors_rad,
    broad_errors_rad,
    rms_deg,
    score_broad,
)
from gnomon.progress import Progress
from gnomon.recording import Recording

__all__ = ["run_broad", "run_tyrex", "run_benchmark", "default_filters", "parse_align",
           "TYREX_ANCHORS", "BENCHMARKS", "plot_benchmark", "group_kinds",
           "TYREX_MAG_CALIBRATION", "MAG_CALIBRATION_MODES"]


def default_filters() -> tuple[str, ...]:
    """The gnomon filters run by default: every registered IMU filter (``kind = "imu"``),
    the causal ones and the offline ones (``-offline``: they see the whole log; compare
    them with the ``vqf-offline`` row)."""
    return tuple(registry.names("imu"))


_KEYS = ("total", "heading", "inclination")
#: the anchor rows of the tyrex benchmark (``phone``: the phone's own estimate)
TYREX_ANCHORS = ("vqf", "vqf-offline", "phone", "ahrs-madgwick", "imufusion")
#: row name -> anchor (the device's own estimate has its data set's name)
_ALIASES = {"phone": "onboard"}
#: named benchmarks: default alignment
BENCHMARKS = {"broad": (), "tyrex": ("body", "lag")}
#: ``run_tyrex(mag_calibration=...)``: the trial's own samples or the data set's
#: calibration recording
MAG_CALIBRATION_MODES = ("self", "recording")
_N5D2, _N5D3, _N5D4 = (f"android/calib_mag_Nexus5_d{d}" for d in (2, 3, 4))
_I5D3 = "ios/calib_mag_iPhone5_d3"
#: the magnetometer calibration recording of each tyrex trial (folder under
#: ``datasets/``), as the data set's own benchmark pairs them: the last argument of each
#: ``loadTest(...)`` in ``src/Benchmark/AttitudeBenchmarks.m`` (``'i5d3'``, ``'N5d2'``,
#: ...) names the calibration of ``loadCalibration`` (``calib_mag_<phone>_d<day>``). The
#: iPhone 5 trials all use day 3; the Nexus 5's disturbed trials day 3, its undisturbed
#: ones day 2 except the two running trials, day 4. ``calib_mag_Nexus5_d1`` and
#: ``calib_mag_iPhone5_d4`` belong to no trial shipped here.
TYREX_MAG_CALIBRATION = {
    **{f"Guillaume_iPhone5_{d}_{m}": _I5D3 for d, ms in (
        ("Dist", ("AR", "BackPocket", "FrontPocket", "Phoning", "Swinging", "Texting")),
        ("NoDist", ("AR", "BackPocket", "FrontPocket", "Phoning", "RunningHand",
                    "RunningPocket", "Swinging", "Texting"))) for m in ms},
    **{f"Guillaume_Nexus5_Dist_{m}": _N5D3
       for m in ("AR", "BackPocket", "FrontPocket", "Phoning", "Swinging", "Texting")},
    **{f"Guillaume_Nexus5_NoDist_{m}": _N5D2
       for m in ("AR", "BackPocket", "FrontPocket", "Phoning", "Swinging", "Texting")},
    **{f"Guillaume_Nexus5_NoDist_{m}": _N5D4 for m in ("RunningHand", "RunningPocket")},
}


def parse_align(text: str | Sequence[str] | None) -> tuple[str, ...]:
    """``"body,lag"`` / ``"none"`` / ``""`` / a sequence -> a tuple of ``ALIGN_OPTIONS``."""
    if text is None:
        return ()
    items = text.split(",") if isinstance(text, str) else list(text)
    items = [s.strip() for s in items if s.strip() and s.strip() != "none"]
    bad = [s for s in items if s not in ALIGN_OPTIONS]
    if bad:
        raise InputError(f"unknown alignment {', '.join(bad)}; use body, lag, body,lag or "
                         "none", field="align")
    return tuple(dict.fromkeys(items))


# ------------------------------------------------------------------ methods
# (name, q = fn(rec), applies(rec) -> bool): a method that does not apply to a recording
# (the device's own estimate where there is none) is left out of it without an error
_Method = tuple[str, Callable[[Recording], np.ndarray], Callable[[Recording], bool]]


def _always(rec: Recording) -> bool:
    return True


def _has_onboard(rec: Recording) -> bool:
    return rec.q_onboard is not None


def _methods(filters: Sequence[str], anchors: Sequence[str] | None) -> list[_Method]:
    methods: list[_Method] = []
    for name in filters:
        registry.get(name)  # unknown names fail before any trial runs

        def run_filter(rec, name=name):
            return registry.create(name).run(rec)

        methods.append((name, run_filter, _always))
    if anchors is None:  # the causal libraries and VQF's offline form, where installed
        anchors = anchors_mod.available() + [a for a in ("vqf-offline",)
                                             if anchors_mod.installed(a)]
    names = list(anchors)
    known = [*anchors_mod.ANCHORS, *anchors_mod.EXTRA_ANCHORS, *_ALIASES]
    for name in names:
        target = _ALIASES.get(name, name)
        if target not in anchors_mod.ANCHORS and target not in anchors_mod.EXTRA_ANCHORS:
            raise InputError(f"unknown reference library {name!r}; known: "
                             f"{', '.join(known)}", field="anchors")
        applies = _has_onboard if target == "onboard" else _always
        methods.append((name, lambda rec, t=target: anchors_mod.run_anchor(t, rec), applies))
    return methods


def _nees(rec: Recording, q_est, std) -> float:
    """Mean normalised estimation error squared of an estimate that carries its per-axis
    1-sigma ``std`` (N, 3) rad (``att_std_rad``): ``Σ_i (ε_i / σ_i)²`` averaged over the
    scored samples, ``ε`` the body-axis error (``metrics.body_axis_errors_rad``). An honest
    uncertainty gives 3; larger means the band is too narrow for this data."""
    q = np.asarray(q_est, dtype=float)
    std = np.asarray(std, dtype=float)
    m = rec.score_mask & np.all(np.isfinite(q), axis=1) & np.all(std > 0, axis=1)
    if not m.any():
        return float("nan")
    eps = body_axis_errors_rad(rec.q_true[m], q[m])
    return float(np.mean(np.sum((eps / std[m]) ** 2, axis=1)))


def _score(rec: Recording, q_est) -> dict:
    """BROAD's RMSE (deg) over ``rec.score_mask`` and the rows where ``q_est`` exists (all
    rows for a filter; the device's own estimate may lack some): also ``samples``."""
    q = np.asarray(q_est, dtype=float)
    m = rec.score_mask & np.all(np.isfinite(q), axis=1)
    if not m.any():
        raise InputError("no sample with a valid truth and an estimate to score",
                         file=rec.source or None, field="q_true")
    e = broad_errors_rad(rec.q_true[m], q[m])
    return {**{f"{k}_deg": rms_deg(e[k]) for k in _KEYS}, "samples": int(m.sum())}


# ------------------------------------------------------------------ the loop
def _run(trials: Iterable[tuple[str, Callable[[], Recording]]], methods: list[_Method], *,
         n_trials: int, align: tuple[str, ...] = (), fit_alignment: bool = False,
         scorer=score_broad, desc: str = "benchmark", progress: bool = False,
         trial_extra: Callable[[str], dict] | None = None, named_by_source: bool = False):
    """Score every method on every trial: ``(rows, errors, timing, alignment)``. A trial
    is ``(name, load)``; with ``named_by_source`` its rows are named by the recording's
    ``source`` (BROAD's trial name) once it is read."""
    rows, errors, timing, alignment = [], [], {}, []
    bar = Progress(n_trials * len(methods), desc, unit="run", enabled=progress, leave=False)
    warmed: set[str] = set()
    for name, load in trials:
        try:
            rec = load()
            name = (rec.source or name) if named_by_source else name
            fit = {}
            if align or fit_alignment:
                q_al, info = align_truth(rec, align)
                rec = dataclasses.replace(rec, q_true=q_al)
                fit = {"lag_s": info["lag_s"] if "lag" in align else 0.0,
                       "misalignment_deg": info["misalignment_deg"] if "body" in align
                       else 0.0}
                alignment.append({"trial": name, **info})
        except Exception as exc:  # a trial that cannot be read or aligned: the others go on
            errors.append({"trial": name, "method": None,
                           "error": f"{type(exc).__name__}: {exc}"})
            bar.update(len(methods))
            continue
        extra = trial_extra(name) if trial_extra else {}
        for method, fn, applies in methods:
            bar.note(f"{name[:24]} {method}")
            if not applies(rec):
                bar.update(1)
                continue
            try:
                if method not in warmed:  # compile / load compiled code outside the timing
                    fn(rec.slice(0, min(len(rec), 200)))
                    warmed.add(method)
                t0 = time.perf_counter()
                out = fn(rec)
                timing.setdefault(method, []).append((len(rec), time.perf_counter() - t0))
                q = out.q if isinstance(out, Estimate) else out
                row = {"trial": name, "method": method, **scorer(rec, q), **fit, **extra}
                if isinstance(out, Estimate) and "att_std_rad" in out.signals:
                    row["nees"] = _nees(rec, q, out.signals["att_std_rad"])
                rows.append(row)
            except Exception as exc:  # one failure must not lose the other trials
                errors.append({"trial": name, "method": method,
                               "error": f"{type(exc).__name__}: {exc}"})
            bar.update(1)
    bar.close()
    return rows, errors, timing, alignment


def _speed(timing: dict) -> dict:
    return {m: sum(n for n, _ in v) / max(sum(s for _, s in v), 1e-12)
            for m, v in timing.items()}


def _mean_of(rows) -> dict:
    out = {**{f"{k}_deg": float(np.mean([r[f"{k}_deg"] for r in rows])) for k in _KEYS},
           "trials": len(rows)}
    if all("nees" in r for r in rows):  # estimates with an uncertainty: its honesty
        out["nees"] = float(np.nanmean([r["nees"] for r in rows]))
    return out


def _means(rows, methods) -> dict:
    return {m: _mean_of(sel) for m in methods if (sel := [r for r in rows if r["method"] == m])}


def _group_means(rows, groups_of: dict, methods) -> dict:
    if not groups_of:
        return {}
    out = {}
    for m in methods:
        per_group: dict[str, list] = {}
        for r in rows:
            if r["method"] == m:
                for g in groups_of.get(r["trial"], []):
                    per_group.setdefault(g, []).append(r)
        if per_group:
            out[m] = {g: _mean_of(sel) for g, sel in sorted(per_group.items())}
    return out


def _stats(values) -> dict:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if not v.size:
        return {"min": None, "median": None, "max": None, "n": 0}
    return {"min": float(v.min()), "median": float(np.median(v)), "max": float(v.max()),
            "n": int(v.size)}


def _alignment_stats(alignment: list, groups_of: dict) -> dict:
    """Lag (ms), misalignment (deg), gyro bias magnitude (deg/s) and the rate residuals
    over all trials and per phone."""
    sets = {"all": alignment}
    for a in alignment:
        for g in groups_of.get(a["trial"], []):
            if g.startswith("phone:"):
                sets.setdefault(g, []).append(a)
    return {k: {"lag_ms": _stats([1000.0 * a["lag_s"] for a in v]),
                "misalignment_deg": _stats([a["misalignment_deg"] for a in v]),
                "gyro_bias_deg_s": _stats([float(np.linalg.norm(a["gyro_bias_deg_s"]))
                                           for a in v]),
                "rate_rms_deg_s_before": _stats([a["rate_rms_deg_s_before"] for a in v]),
                "rate_rms_deg_s": _stats([a["rate_rms_deg_s"] for a in v])}
            for k, v in sets.items()}


# ------------------------------------------------------------------ BROAD
def run_broad(data_dir, filters: Sequence[str] | None = None,
              anchors: Sequence[str] | None = None, progress: bool = False,
              align: Sequence[str] = ()) -> dict:
    """Run ``filters`` (registry names) and ``anchors`` (None: every installed causal
    library and ``vqf-offline``) on every BROAD trial in ``data_dir`` (``.hdf5`` and
    ``.mat``); returns the JSON object above. ``align`` (default none, BROAD's protocol):
    module docstring; when given, rows carry ``lag_s``/``misalignment_deg`` and
    ``alignment`` is added."""
    from gnomon.io import read
    from gnomon.io.broad import broad_groups, broad_trials

    align = parse_align(align)
    paths = broad_trials(data_dir)
    if not paths:
        raise InputError("no BROAD trial (.hdf5 or .mat) found", file=str(data_dir))
    methods = _methods(default_filters() if filters is None else filters, anchors)
    groups_of = broad_groups(data_dir)
    trials = [(Path(p).stem, lambda p=p: read(p, format="broad")) for p in paths]
    rows, errors, timing, alignment = _run(trials, methods, n_trials=len(paths), align=align,
                                           desc="BROAD", progress=progress, named_by_source=True)
    out = {"metric": "broad", "data": str(data_dir), "trials": rows,
           "mean": _means(rows, [m for m, _, _ in methods]),
           "groups": _group_means(rows, groups_of, [m for m, _, _ in methods]),
           "samples_per_s": _speed(timing), "errors": errors}
    if align:
        out["align"] = list(align)
        out["alignment"] = alignment
    return out


# ------------------------------------------------------------------ tyrex
def run_tyrex(data_dir, filters: Sequence[str] | None = None,
              anchors: Sequence[str] | None = None, align: Sequence[str] | str | None = None,
              mag: str = "calibrated", progress: bool = False,
              mag_calibration: str | None = None) -> dict:
    """The tyrex smartphone benchmark on the data set at ``data_dir`` (its root or its
    ``datasets/``): every trial with a reference (:func:`gnomon.io.tyrex.tyrex_trials`),
    read with ``mag`` (``"calibrated"``: the OS-calibrated magnetometer; ``"raw"``),
    ``filters`` (default every IMU filter) and ``anchors`` (default ``TYREX_ANCHORS``
    that are installed), the truth aligned by ``align`` (default ``("body", "lag")``;
    the fit is reported in every case), the raw magnetometer corrected by
    ``mag_calibration`` (None, ``"self"`` or ``"recording"``; module docstring). Returns
    the JSON object of the module docstring."""
    from gnomon.io.phone import read_tyrex
    from gnomon.io.tyrex import (
        DECLINATION_DEG,
        SCORE_WINDOW_S,
        trial_groups,
        trial_info,
        tyrex_trials,
    )

    if mag not in ("calibrated", "raw"):
        raise InputError(f"expected calibrated or raw, got {mag!r}", field="mag")
    if mag_calibration is not None and mag_calibration not in MAG_CALIBRATION_MODES:
        raise InputError(f"expected self or recording, got {mag_calibration!r}",
                         field="mag_calibration")
    if mag_calibration is not None and mag != "raw":
        raise InputError("a magnetometer calibration applies to the raw magnetometer: "
                         "use mag='raw' (--mag raw)", field="mag_calibration")
    align = BENCHMARKS["tyrex"] if align is None else parse_align(align)
    paths, skipped = tyrex_trials(data_dir)
    if not paths:
        raise InputError("no tyrex trial with a reference (datasets/android/<trial>, "
                         "datasets/ios/<trial> and datasets/qualisys/<trial>.mat)",
                         file=str(data_dir))
    if anchors is None:
        anchors = [a for a in TYREX_ANCHORS if anchors_mod.installed(_ALIASES.get(a, a))]
    methods = _methods(default_filters() if filters is None else filters, anchors)
    names = [m for m, _, _ in methods]
    groups_of = {p.name: trial_groups(p.name) for p in paths}

    def extra(name):
        info = trial_info(name) or {}
        return {k: info.get(k) for k in ("phone", "motion", "disturbance")}

    calibrations: list[dict] = []
    if mag_calibration is None:
        trials = [(p.name, lambda p=p: read_tyrex(p, mag=mag)) for p in paths]
    else:
        calibrate = _tyrex_calibrator(data_dir, mag_calibration, calibrations)
        trials = [(p.name, lambda p=p: calibrate(p, read_tyrex(p, mag=mag))) for p in paths]
    rows, errors, timing, alignment = _run(trials, methods, n_trials=len(paths), align=align,
                                           fit_alignment=True, scorer=_score, desc="tyrex",
                                           progress=progress, trial_extra=extra)
    more = {} if mag_calibration is None else {"mag_calibration": mag_calibration,
                                               "calibrations": calibrations}
    return {"metric": "broad", "benchmark": "tyrex", "data": str(data_dir), "mag": mag,
            "align": list(align),
            "truth": {"north": "magnetic", "declination_deg": DECLINATION_DEG,
                      "score_window_s": list(SCORE_WINDOW_S),
                      "frame": "q_ENU_device (Android/iOS device axes), ENU with y to "
                               "magnetic north"},
            "trials": rows, "mean": _means(rows, names),
            "groups": _group_means(rows, groups_of, names),
            "alignment": alignment, "alignment_stats": _alignment_stats(alignment, groups_of),
            "anchor_inputs": {m: anchors_mod.MULTI_RATE_INPUT[_ALIASES.get(m, m)]
                              for m in names if _ALIASES.get(m, m) in
                              anchors_mod.MULTI_RATE_INPUT},
            "skipped": [{"trial": p.name, "reason": "no reference (a calibration recording)"}
                        for p in skipped],
            "samples_per_s": _speed(timing), "errors": errors, **more}


def _tyrex_calibrator(data_dir, mode: str, log: list) -> Callable[[Path, Recording], Recording]:
    """``calibrate(trial_dir, rec)``: ``rec`` with its raw magnetometer corrected by the
    ``mode`` calibration (``self``/``recording``), appending a report to ``log``; a
    refused calibration leaves ``rec`` as it is (``applied: false``)."""
    from gnomon.calibration import apply_mag_calibration, calibrate_mag, igrf_field_uT
    from gnomon.io.phone import read_tyrex
    from gnomon.io.tyrex import LOCATION, datasets_dir

    field_uT = igrf_field_uT(LOCATION["latitude_deg"], LOCATION["longitude_deg"],
                             LOCATION["altitude_m"], LOCATION["date"])
    where = f"IGRF-14 at the data set's place and date ({LOCATION['date']})"
    cache: dict[str, object] = {}

    def calibrate(trial: Path, rec: Recording) -> Recording:
        if mode == "self":
            source = "self"
            cal = calibrate_mag(rec, field_uT=field_uT, field_source=where)
        else:
            source = TYREX_MAG_CALIBRATION.get(trial.name)
            if source is None:
                raise InputError("no calibration recording known for this trial",
                                 file=str(trial), field="mag_calibration")
            if source not in cache:
                folder = datasets_dir(data_dir) / source
                cache[source] = calibrate_mag(read_tyrex(folder, mag="raw", reference=False),
                                              field_uT=field_uT, field_source=where)
            cal = cache[source]
        log.append({"trial": trial.name, "from": source, "applied": bool(cal.ok),
                    **cal.to_dict()})
        return apply_mag_calibration(rec, cal) if cal.ok else rec

    return calibrate


# ------------------------------------------------------------------ any folder
def _recordings(root: Path, depth: int = 4) -> tuple[list[tuple[str, Path, str]], list]:
    """Every file or folder under ``root`` that gnomon recognises: ``[(name, path,
    format)]`` and ``[{"trial", "reason"}]`` for what it skipped."""
    from gnomon.io import detect_format

    found, skipped = [], []

    def visit(folder: Path, level: int):
        for p in sorted(folder.iterdir()):
            if p.name.startswith("."):
                continue
            try:
                fmt = detect_format(p)
            except InputError as err:
                if p.is_dir() and level < depth:
                    visit(p, level + 1)
                elif p.is_file() and p.suffix.lower() not in (".json", ".md", ".txt"):
                    skipped.append({"trial": str(p.relative_to(root)), "reason": err.message})
                continue
            found.append((str(p.relative_to(root).with_suffix("")) if p.is_file()
                          else str(p.relative_to(root)), p, fmt))

    visit(root, 0)
    return found, skipped


def run_benchmark(data_dir, filters: Sequence[str] | None = None,
                  anchors: Sequence[str] | None = None, align: Sequence[str] | str = (),
                  progress: bool = False) -> dict:
    """Every recording under ``data_dir`` that gnomon reads (any format, any depth up to
    4) and that holds a truth (``q_true``): ``filters`` (default every IMU filter),
    ``anchors`` (default every installed causal library, ``vqf-offline`` and ``onboard``,
    the device's own estimate, where the recording has one), ``align`` (default none).
    Recordings without a truth, and files gnomon cannot read, are listed in ``skipped``.
    Returns BROAD's keys
    (rows with ``samples``) plus ``benchmark``, ``align``, ``alignment`` (when aligned)
    and ``skipped``."""
    from gnomon.io import read

    root = Path(data_dir)
    if not root.is_dir():
        raise InputError("no such directory", file=str(root))
    align = parse_align(align)
    found, skipped = _recordings(root)
    recs = []
    for name, path, fmt in found:
        try:
            rec = read(path, format=fmt)
        except InputError as err:
            skipped.append({"trial": name, "reason": f"{fmt}: {err.message}"})
            continue
        if rec.q_true is None:
            skipped.append({"trial": name, "reason": f"{fmt}: no truth (q_true)"})
            continue
        recs.append((name, rec))
    if not recs:
        raise InputError("no recording with a truth (q_true) found", file=str(root))
    if anchors is None:
        anchors = anchors_mod.available() + [a for a in ("vqf-offline",)
                                             if anchors_mod.installed(a)] + ["onboard"]
    methods = _methods(default_filters() if filters is None else filters, anchors)
    names = [m for m, _, _ in methods]
    rows, errors, timing, alignment = _run([(n, lambda r=r: r) for n, r in recs], methods,
                                           n_trials=len(recs), align=align, scorer=_score,
                                           desc=root.name, progress=progress)
    out = {"metric": "broad", "benchmark": "dir", "data": str(root), "align": list(align),
           "trials": rows, "mean": _means(rows, names), "groups": {},
           "skipped": sorted(skipped, key=lambda s: s["trial"]),
           "samples_per_s": _speed(timing), "errors": errors}
    if align:
        out["alignment"] = alignment
        out["alignment_stats"] = _alignment_stats(alignment, {})
    return out


# ------------------------------------------------------------------ figure
_KIND_ORDER = ("phone", "disturbance", "motion")


def group_kinds(res: dict) -> list[str]:
    """The kinds of groups in a result (``phone``, ``disturbance``, ``motion`` first), from
    group names ``kind:value``."""
    kinds = {g.partition(":")[0] for m in res.get("groups", {}) for g in res["groups"][m]
             if ":" in g}
    return [k for k in _KIND_ORDER if k in kinds] + sorted(kinds - set(_KIND_ORDER))


def plot_benchmark(res: dict, path, title: str = "") -> Path:
    """Mean total RMSE per method for every group of a ``run_tyrex``/``run_benchmark``
    result (one panel per kind of group: ``phone``, ``motion``, ``disturbance``; one
    panel of all trials when there are no groups), log scale."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = sorted(res["mean"], key=lambda m: res["mean"][m]["total_deg"])
    kinds: dict[str, list[str]] = {}
    for m in res.get("groups", {}):
        for g in res["groups"][m]:
            kind, _, value = g.partition(":")
            if value and value not in kinds.setdefault(kind, []):
                kinds[kind].append(value)
    panels = [("all trials", ["mean"])] + [(k, sorted(kinds[k])) for k in group_kinds(res)]
    fig, axes = plt.subplots(len(panels), 1, figsize=(11, 3.2 * len(panels)), squeeze=False)
    w = 0.8 / max(len(methods), 1)
    for ax, (kind, values) in zip(axes[:, 0], panels, strict=True):
        x = np.arange(len(values))
        for j, m in enumerate(methods):
            if kind == "all trials":
                y = [res["mean"][m]["total_deg"]]
            else:
                y = [res["groups"].get(m, {}).get(f"{kind}:{v}", {}).get("total_deg", np.nan)
                     for v in values]
            ax.bar(x + j * w - 0.4 + w / 2, y, w, label=m)
        ax.set_xticks(x, values)
        ax.set_ylabel("mean total RMSE (deg)")
        ax.set_yscale("log")
        ax.set_title(kind)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", fontsize=8, ncol=min(len(methods), 6))
    if title:
        fig.suptitle(title)
    fig.tight_layout(rect=(0.0, 0.05, 1.0, 1.0))
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
