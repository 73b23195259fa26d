"""Accuracy on data sets with a reference: gnomon's filters and the reference libraries,
side by side, one metric.

The metric is BROAD's (Laidig, Caruso, Cereatti, Seel, Data 6(7):72, 2021; see
:mod:`~gnomon.benchmark.scoring`): for every scored sample (``Recording.score_mask``:
``mask`` and a valid truth) the total, heading and inclination error angles; RMSE per
trial in degrees; a method's score is the mean over trials. Every estimate must be
sensor-to-ENU from the first sample on.

One entry, :func:`run` (``gnomon benchmark broad|tyrex|DIR``), and one room per kind of
data, all three on the same loop:

* :mod:`~gnomon.benchmark.broad`: :func:`run_broad`, the BROAD trials, BROAD's groups,
  no alignment (BROAD's own protocol); its JSON contract is in that module.
* :mod:`~gnomon.benchmark.tyrex`: :func:`run_tyrex`, the smartphone trials of Michel et
  al. 2018, groups by phone, motion and disturbance, the truth aligned to each phone by
  default, the magnetometer calibrations.
* :mod:`~gnomon.benchmark.folder`: :func:`run_benchmark`, every recording gnomon reads
  under a folder that holds a truth.

The shared machinery, one job per module:

* :mod:`~gnomon.benchmark.methods`: the rows, gnomon's filters and the anchors (the
  reference libraries, the device's own estimate).
* :mod:`~gnomon.benchmark.trials`: the run loop over trials and methods, the alignment of
  the truth (:func:`parse_align`), failures kept as errors.
* :mod:`~gnomon.benchmark.scoring`: a trial's score, the means over trials and groups,
  speed, NEES, the alignment statistics.
* :mod:`~gnomon.benchmark.plot`: :func:`plot_benchmark`, :func:`group_kinds`.
"""

from __future__ import annotations

from collections.abc import Sequence

from gnomon.benchmark import broad, folder, tyrex
from gnomon.benchmark.broad import run_broad
from gnomon.benchmark.folder import run_benchmark
from gnomon.benchmark.methods import default_filters
from gnomon.benchmark.plot import group_kinds, plot_benchmark
from gnomon.benchmark.scoring import score_trial as _score  # noqa: F401 (benchmarks/ use it)
from gnomon.benchmark.trials import parse_align
from gnomon.benchmark.tyrex import (
    MAG_CALIBRATION_MODES,
    TYREX_ANCHORS,
    TYREX_MAG_CALIBRATION,
    run_tyrex,
)
from gnomon.errors import InputError

__all__ = ["run", "run_broad", "run_tyrex", "run_benchmark", "default_filters", "parse_align",
           "TYREX_ANCHORS", "BENCHMARKS", "plot_benchmark", "group_kinds",
           "TYREX_MAG_CALIBRATION", "MAG_CALIBRATION_MODES"]

#: named benchmarks: default alignment
BENCHMARKS = {"broad": broad.DEFAULT_ALIGN, "tyrex": tyrex.DEFAULT_ALIGN}


def run(what: str, data_dir=None, *, filters: Sequence[str] | None = None,
        anchors: Sequence[str] | None = None, align: Sequence[str] | str | None = None,
        progress: bool = False, mag: str | None = None,
        mag_calibration: str | None = None) -> dict:
    """The benchmark ``what``: a named one (:data:`BENCHMARKS`: ``"broad"``, ``"tyrex"``)
    on ``data_dir`` (None: the data set :func:`gnomon.datasets.dataset_dir` finds), or any
    folder of recordings (``what`` the folder, no ``data_dir``).

    ``filters``, ``anchors``: the rows (defaults: each kind's); ``align``: None for the
    kind's default (:data:`BENCHMARKS`; a folder: none); ``mag``, ``mag_calibration``:
    tyrex only (``mag`` default ``"raw"`` with a calibration, else ``"calibrated"``).
    Returns the kind's JSON object (:func:`run_broad`, :func:`run_tyrex`,
    :func:`run_benchmark`)."""
    if what not in BENCHMARKS:
        if data_dir is not None:
            raise InputError("data_dir is for a named benchmark (broad, tyrex); give the "
                             "folder itself as the benchmark", field="data_dir")
    elif data_dir is None:
        data_dir = _dataset_dir(what)
    if what != "tyrex" and (mag is not None or mag_calibration is not None):
        raise InputError("mag and mag_calibration apply to the tyrex benchmark",
                         field="mag" if mag is not None else "mag_calibration")
    if what == "broad":
        return run_broad(data_dir, filters, anchors, progress=progress, align=align)
    if what == "tyrex":
        return run_tyrex(data_dir, filters, anchors, align=align,
                         mag=mag or ("raw" if mag_calibration else "calibrated"),
                         progress=progress, mag_calibration=mag_calibration)
    return folder.run_benchmark(what, filters, anchors, align=align, progress=progress)


def _dataset_dir(name: str):
    from gnomon.datasets import dataset, dataset_dir

    found = dataset_dir(name)
    if found is None:
        raise InputError(f"no {name} data set here: fetch it with `gnomon datasets fetch "
                         f"{name}`, or give its folder, or set {dataset(name).env}",
                         field="data_dir")
    return found
