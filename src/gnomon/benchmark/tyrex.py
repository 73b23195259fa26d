"""The tyrex smartphone benchmark (``gnomon benchmark tyrex --data DIR``): the trials of
Michel et al. 2018 (:mod:`gnomon.io.tyrex`), truth on magnetic north, groups by phone,
motion and magnetic disturbance, and by default the truth aligned to each phone
(``--align body,lag``; :mod:`gnomon.benchmark.trials`).

Its JSON has BROAD's keys (:mod:`gnomon.benchmark.broad`; rows also carry ``samples``,
``lag_s``, ``misalignment_deg``, ``phone``, ``motion``, ``disturbance``) plus
``benchmark``, ``mag``, ``align``, ``truth``, ``alignment`` (one entry per trial: the
fit of ``gnomon.metrics.align_truth``), ``alignment_stats``, ``anchor_inputs`` and
``skipped``; with ``mag_calibration`` (raw magnetometer only) also ``mag_calibration``
(the mode) and ``calibrations`` (one entry per trial: where its calibration came from,
whether it was applied, and the report of :class:`gnomon.calibration.MagCalibration`).

**Magnetometer calibration** (``mag_calibration``, with ``mag="raw"``):
``"recording"`` corrects each trial's raw magnetometer with the calibration fitted
(:func:`gnomon.calibration.fit_mag`, field magnitude the IGRF value at the data set's
place and date) to the data set's own calibration recording of that phone and day,
:data:`TYREX_MAG_CALIBRATION`; ``"self"`` with the calibration fitted to the trial's own
raw samples (all of them, before the filters run: a batch calibration of the log). A
trial whose calibration is refused (``ok`` false) keeps its raw magnetometer and says so
(``applied: false``); the filters' own online estimates (robust-ahrs's hard iron) stay on
in every case.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from gnomon import anchors as anchors_mod
from gnomon.alignment import align_names
from gnomon.benchmark.methods import ALIASES, default_filters, make_methods, method_names
from gnomon.benchmark.scoring import alignment_stats, group_means, means, score_trial, speed
from gnomon.benchmark.trials import parse_align, run_trials
from gnomon.errors import InputError
from gnomon.recording import Recording

__all__ = ["run_tyrex", "DEFAULT_ALIGN", "TYREX_ANCHORS", "TYREX_MAG_CALIBRATION",
           "MAG_CALIBRATION_MODES"]

#: the truth turned onto the phone's axes and shifted by the residual clock offset
DEFAULT_ALIGN: tuple[str, ...] = ("body", "lag")
#: the anchor rows of the tyrex benchmark (``phone``: the phone's own estimate)
TYREX_ANCHORS = ("vqf", "vqf-offline", "phone", "ahrs-madgwick", "imufusion")
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


def _check_mag(mag: str, mag_calibration: str | None) -> None:
    if mag not in ("calibrated", "raw"):
        raise InputError(f"expected calibrated or raw, got {mag!r}", field="mag")
    if mag_calibration is not None and mag_calibration not in MAG_CALIBRATION_MODES:
        raise InputError(f"expected self or recording, got {mag_calibration!r}",
                         field="mag_calibration")
    if mag_calibration is not None and mag != "raw":
        raise InputError("a magnetometer calibration applies to the raw magnetometer: "
                         "use mag='raw' (--mag raw)", field="mag_calibration")


def _trial_extra(name: str) -> dict:
    """The keys every row of a trial carries: its phone, motion and disturbance."""
    from gnomon.io.tyrex import trial_info

    info = trial_info(name) or {}
    return {k: info.get(k) for k in ("phone", "motion", "disturbance")}


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
    from gnomon.io.tyrex import DECLINATION_DEG, SCORE_WINDOW_S, trial_groups, tyrex_trials

    _check_mag(mag, mag_calibration)
    align = DEFAULT_ALIGN if align is None else parse_align(align)
    paths, skipped = tyrex_trials(data_dir)
    if not paths:
        raise InputError("no tyrex trial with a reference (datasets/android/<trial>, "
                         "datasets/ios/<trial> and datasets/qualisys/<trial>.mat)",
                         file=str(data_dir))
    if anchors is None:
        anchors = [a for a in TYREX_ANCHORS if anchors_mod.installed(ALIASES.get(a, a))]
    methods = make_methods(default_filters() if filters is None else filters, anchors)
    names = method_names(methods)
    groups_of = {p.name: trial_groups(p.name) for p in paths}
    calibrations: list[dict] = []
    if mag_calibration is None:
        trials = [(p.name, lambda p=p: read_tyrex(p, mag=mag)) for p in paths]
    else:
        calibrate = _tyrex_calibrator(data_dir, mag_calibration, calibrations)
        trials = [(p.name, lambda p=p: calibrate(p, read_tyrex(p, mag=mag))) for p in paths]
    rows, errors, timing, alignment = run_trials(
        trials, methods, n_trials=len(paths), align=align, fit_alignment=True,
        scorer=score_trial, desc="tyrex", progress=progress, trial_extra=_trial_extra)
    more = {} if mag_calibration is None else {"mag_calibration": mag_calibration,
                                               "calibrations": calibrations}
    return {"metric": "broad", "benchmark": "tyrex", "data": str(data_dir), "mag": mag,
            "align": align_names(align),
            "truth": {"north": "magnetic", "declination_deg": DECLINATION_DEG,
                      "score_window_s": list(SCORE_WINDOW_S),
                      "frame": "q_ENU_device (Android/iOS device axes), ENU with y to "
                               "magnetic north"},
            "trials": rows, "mean": means(rows, names),
            "groups": group_means(rows, groups_of, names),
            "alignment": alignment, "alignment_stats": alignment_stats(alignment, groups_of),
            "anchor_inputs": {m: anchors_mod.MULTI_RATE_INPUT[ALIASES.get(m, m)]
                              for m in names if ALIASES.get(m, m) in
                              anchors_mod.MULTI_RATE_INPUT},
            "skipped": [{"trial": p.name, "reason": "no reference (a calibration recording)"}
                        for p in skipped],
            "samples_per_s": speed(timing), "errors": errors, **more}


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
