"""The tyrex smartphone data set (Michel, Genevès, Fourati, Layaïda, "Attitude estimation
for indoor navigation and augmented reality with smartphones", *Pervasive and Mobile
Computing* 46, 2018; CeCILL 2.1): its trials, their groups and their reference.

Layout (kept from the data set's repository)::

    datasets/android/<user>_Nexus5_<Dist|NoDist>_<Motion>/     phone files (gnomon.io.phone)
    datasets/ios/<user>_iPhone5_<Dist|NoDist>_<Motion>/
    datasets/qualisys/<trial>.mat                               QTM export (gnomon.io.qualisys)
    datasets/*/calib_mag_*                                      magnetometer calibration
                                                                recordings, no reference

The reference of a trial (:func:`reference_on`), as the data set defines it and as
checked on the data (``docs/logs.md``):

* **Attitude.** The QTM rigid body's ``R_global_body``; the global frame is ENU with y
  to *true* north. gnomon's truth is ``q_ENU_body`` with y to **magnetic north**
  (``q_true = Rz(D) ⊗ q_ENUtrue_body``, declination ``D = DECLINATION_DEG`` east): the
  filters take heading from the magnetometer, and both phones' own estimates refer to
  magnetic north, so every method is scored against the north it can observe.
* **Time.** The phone's clock is put on the capture's clock by ``timeAlignment.txt``
  (the data set's offset, found by matching the accelerometer norm with the second
  derivative of the body position in 10 ms steps; iOS also ``- BootTime``); a residual
  of a few tens of ms remains, fitted per trial by ``gnomon.metrics.align_truth``.
* **Missing truth.** NaN on the gyro rows between two capture frames of which one was
  not tracked, and inside the intervals the authors marked as bad by hand
  (``BAD_INTERVALS_S``, capture clock).
* **Scored samples.** ``mask``: ``5 s <= t <= 120 s`` on the capture's clock, as in the
  data set's own benchmark (the first 5 s let the filters converge).

The facts below (declination, bad intervals, scoring window) are data, cited from the
data set's MATLAB sources (``src/Benchmark/AttitudeBenchmarks.m``,
``createContextFromLocationAndDate.m``, ``getAttitudeErrors.m``); no code of theirs is
used here.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from gnomon.io._common import onboard_on
from gnomon.io.qualisys import MocapReference, read_qtm
from gnomon.rotation import quat_from_rotvec, quat_mul

__all__ = ["DECLINATION_DEG", "BAD_INTERVALS_S", "SCORE_WINDOW_S", "LOCATION", "PHONES",
           "MOTIONS", "trial_info", "trial_groups", "reference_path", "reference_on",
           "tyrex_trials", "datasets_dir"]

#: where and when the data set was recorded (``AttitudeBenchmarks.m``): Grenoble,
#: 2016-05-31
LOCATION = {"latitude_deg": 45.187778, "longitude_deg": 5.726945, "altitude_m": 200.0,
            "date": "2016-05-31"}
#: magnetic declination (deg, east positive) there and then: IGRF-14 (ppigrf) gives
#: 1.505 deg; the data set's own code uses the WMM of MATLAB's wrldmagm (about 1.5 deg E)
DECLINATION_DEG = 1.505
#: samples scored: 5 s <= t <= 120 s on the capture's clock (``getAttitudeErrors.m``
#: keeps 0-120 s; its benchmark averages from 5 s on)
SCORE_WINDOW_S = (5.0, 120.0)
#: reference intervals the authors marked bad by hand (s, capture clock), per trial;
#: ``AttitudeBenchmarks.m`` (the trials of user Guillaume shipped here)
BAD_INTERVALS_S: dict[str, tuple[tuple[float, float], ...]] = {
    "Guillaume_iPhone5_Dist_FrontPocket": ((65.6, 67.2), (100.4, 102.0)),
    "Guillaume_iPhone5_Dist_Swinging": ((103.5, 104.5),),
    "Guillaume_iPhone5_NoDist_BackPocket": ((5.7, 6.1), (7.9, 8.5), (9.1, 9.6), (24.7, 25.3),
                                            (26.0, 26.5), (76.4, 77.3)),
    "Guillaume_Nexus5_Dist_FrontPocket": ((21.2, 21.6),),
    "Guillaume_Nexus5_Dist_Phoning": ((40.5, 40.8),),
    "Guillaume_Nexus5_Dist_Swinging": ((59.7, 60.5), (73.1, 73.5)),
    "Guillaume_Nexus5_NoDist_AR": ((64.0, 120.0),),
}
PHONES = ("Nexus5", "iPhone5")
MOTIONS = ("Texting", "Phoning", "Swinging", "FrontPocket", "BackPocket", "AR", "RunningHand",
           "RunningPocket")
_NAME = re.compile(r"^(?P<user>[A-Za-z]+)_(?P<phone>[A-Za-z0-9]+)_(?P<dist>Dist|NoDist)_"
                   r"(?P<motion>[A-Za-z]+)")


def trial_info(name: str) -> dict | None:
    """``{"trial", "user", "phone", "disturbance", "motion"}`` from a trial's folder name
    (``Guillaume_Nexus5_Dist_AR``; a suffix such as ``_excerpt`` is allowed), else None.
    ``trial`` is the data set's name of the trial (without the suffix)."""
    m = _NAME.match(name)
    if m is None:
        return None
    d = m.groupdict()
    return {"trial": f"{d['user']}_{d['phone']}_{d['dist']}_{d['motion']}", "user": d["user"],
            "phone": d["phone"], "disturbance": d["dist"], "motion": d["motion"]}


def trial_groups(name: str) -> list[str]:
    """The benchmark groups of a trial: ``phone:<phone>``, ``motion:<motion>``,
    ``disturbance:<Dist|NoDist>`` (empty for a name that is not a trial's)."""
    info = trial_info(name)
    if info is None:
        return []
    return [f"phone:{info['phone']}", f"motion:{info['motion']}",
            f"disturbance:{info['disturbance']}"]


def reference_path(trial_dir: str | os.PathLike) -> Path:
    """Where the data set keeps a trial's reference: ``../../qualisys/<trial>.mat``."""
    p = Path(trial_dir)
    return p.parent.parent / "qualisys" / f"{p.name}.mat"


def datasets_dir(data_dir: str | os.PathLike) -> Path:
    """The folder holding ``android/``, ``ios/``, ``qualisys/``: ``data_dir/datasets`` (the
    data set's root) or ``data_dir`` itself."""
    p = Path(data_dir)
    return p / "datasets" if (p / "datasets").is_dir() else p


def tyrex_trials(data_dir: str | os.PathLike) -> tuple[list[Path], list[Path]]:
    """The trial folders of the data set at ``data_dir`` (its root or its ``datasets/``)
    that have a reference, sorted by name, and those without one (the magnetometer
    calibration recordings)."""
    base = datasets_dir(data_dir)
    with_ref, without = [], []
    for platform in ("android", "ios"):
        folder = base / platform
        if not folder.is_dir():
            continue
        for p in sorted(folder.iterdir()):
            if not (p / "accelerometer.txt").is_file():  # a phone trial folder
                continue
            (with_ref if reference_path(p).is_file() else without).append(p)
    return sorted(with_ref, key=lambda p: p.name), sorted(without, key=lambda p: p.name)


def _bad_frames(ref: MocapReference, trial: str | None) -> tuple[np.ndarray, list]:
    bad = np.zeros(ref.t.size, bool)
    intervals = list(BAD_INTERVALS_S.get(trial, ())) if trial else []
    for a, b in intervals:
        bad |= (ref.t >= a) & (ref.t <= b)
    return bad, intervals


def reference_on(t: np.ndarray, mat_path: str | os.PathLike, trial: str | None = None
                 ) -> tuple[np.ndarray, np.ndarray, list[str], dict]:
    """A trial's reference on the phone's gyro time stamps ``t`` (s, already on the
    capture's clock): ``(q_true (N, 4), mask (N,), assumed sentences, meta)``.

    ``q_true`` is ``q_ENU_body`` with y to magnetic north (module docstring), slerped
    between capture frames; NaN before the first and after the last frame, between two
    frames of which one was not tracked, and inside the trial's ``BAD_INTERVALS_S``.
    ``mask``: the samples inside ``SCORE_WINDOW_S``. ``trial``: the data set's trial name
    (for the bad intervals; default from the file name)."""
    ref = read_qtm(mat_path)
    info = trial_info(trial or Path(mat_path).stem)
    name = info["trial"] if info else None
    bad, intervals = _bad_frames(ref, name)
    valid = ref.valid & ~bad
    q = ref.q.copy()
    q[~valid] = np.nan
    q_dec = quat_from_rotvec(np.array([0.0, 0.0, np.radians(DECLINATION_DEG)]))
    q[valid] = quat_mul(q_dec, q[valid])
    # intervals longer than 1.5 frames span a frame without truth: NaN there
    q_true = onboard_on(mat_path, "RigidBodies.Rotations", ref.t[valid], q[valid],
                        np.asarray(t, dtype=float), max_gap_s=1.5 / ref.frame_rate_hz)
    lo, hi = SCORE_WINDOW_S
    mask = (t >= lo) & (t <= hi)
    covered = np.isfinite(q_true).all(axis=1)
    assumed = [
        f"Truth: {Path(mat_path).name}, rigid body {ref.body!r} ({ref.frame_rate_hz:g} Hz, "
        f"{ref.meta['tracked_fraction'] * 100:.1f} % of frames tracked); QTM's global frame "
        f"is ENU to true north; turned to magnetic north by the declination "
        f"{DECLINATION_DEG:+.3f} deg (east; IGRF-14 at Grenoble, 2016-05-31): "
        "q_true = Rz(D) * q_ENUtrue_body.",
        "Truth slerped onto the gyro time stamps between capture frames; NaN across a "
        "frame the capture lost" + (f" and inside the bad intervals {intervals} s marked by "
                                    "the data set's authors" if intervals else "") + ".",
        f"Scored samples (mask): {lo:g} s <= t <= {hi:g} s on the capture's clock, as in the "
        "data set's benchmark.",
    ]
    meta = {"file": str(mat_path), "body": ref.body, "frame_rate_hz": ref.frame_rate_hz,
            "tracked_fraction": ref.meta["tracked_fraction"],
            "north": "magnetic", "declination_deg": DECLINATION_DEG,
            "bad_intervals_s": [list(iv) for iv in intervals],
            "score_window_s": list(SCORE_WINDOW_S),
            "truth_fraction": float(covered.mean()),
            "scored_samples": int((mask & covered).sum())}
    return q_true, mask, assumed, meta
