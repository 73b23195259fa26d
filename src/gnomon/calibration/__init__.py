"""Magnetometer calibration: hard iron (offset) and soft iron (a symmetric positive-definite
matrix) from the device's own samples, with a quality report and a clear refusal.

Model (units µT; ``m`` the raw reading in the sensor's axes, ``h`` the corrected one)::

    h = S (m - o),    |h| = B  for every undisturbed sample,  i.e.  m = S^-1 h + o

``o = offset_uT`` (3,), ``S = soft_iron`` (3, 3) symmetric positive definite, ``B =
field_uT`` the field's magnitude: the local IGRF value when the caller gives it (place and
date, :func:`igrf_field_uT`, or a number), else the geometric mean radius of the raw
ellipsoid (then ``det S = 1``: the correction keeps the raw readings' scale). A symmetric
``S`` fixes the rotation that a general 3x3 correction would leave free; the frame of ``h``
is the sensor's (the usual choice, Vasconcelos et al., IEEE TAES 47(2), 2011).

The package, one room per part (each module's docstring states its frames, units and
shapes); the public names below are importable from ``gnomon.calibration`` itself:

* :mod:`~gnomon.calibration.result`: :class:`MagCalibration`, the calibration and its
  quality report (residual, coverage, condition, ``ok``/``reason``), its JSON form
  (:func:`save_mag_calibration`, :func:`load_mag_calibration`) and the thresholds at
  which a model is used or the fit refused (``MODELS``, ``MIN_COVERAGE``,
  ``MAX_CONDITION``, ``MAX_ANISOTROPY``).
* :mod:`~gnomon.calibration.coverage`: the equal-area cells of the unit sphere
  (:func:`coverage_cells`, ``COVERAGE_CELLS``) and the fraction of them a set of
  directions visits (:func:`sphere_coverage`).
* :mod:`~gnomon.calibration.samples`: raw readings validated (``MIN_SAMPLES``); a
  recording's magnetometer in µT (:func:`mag_uT_of`).
* :mod:`~gnomon.calibration.field`: the field's magnitude from IGRF-14
  (:func:`igrf_field_uT`).
* :mod:`~gnomon.calibration.fit`: :func:`fit_mag`, the constrained ellipsoid fit: starts,
  geometric refinement, balance, model choice, ambiguity check.
* :mod:`~gnomon.calibration.gyro`: the offset from the gyro alone (:func:`gyro_offset_uT`,
  ``MAX_GYRO_CONDITION``).
* :mod:`~gnomon.calibration.apply`: a ``Recording``: :func:`calibrate_mag` (the fit with
  the gyro's offset as its hint and fallback), :func:`apply_mag_calibration`.
* :mod:`~gnomon.calibration.plot`: a figure of a calibration
  (:func:`plot_mag_calibration`).
* :mod:`~gnomon.calibration.orbit`: on orbit, where the field model gives ``|B|`` at every
  sample: TWOSTEP (Alonso & Shuster 2002; the bias alone, attitude-independent) returns
  the same ``MagCalibration`` (model ``"twostep"``). Its names are imported from that
  module (``gnomon.twostep`` re-exports them), not from here: its ``MIN_SAMPLES`` and
  ``MAX_CONDITION`` are its own.
* :mod:`~gnomon.calibration.allan`: the overlapping Allan deviation of a rate series
  (:func:`allan_deviation`) and the IEEE Std 952 noise terms read off its curve
  (:func:`read_noise_terms`: white noise N, bias instability B, rate random walk K).
* :mod:`~gnomon.calibration.imu_noise`: a static log's gyro and accelerometer noise and
  rest biases (:func:`imu_noise`, ``gnomon calibrate imu``), its JSON form
  (:func:`save_imu_noise`, :func:`load_imu_noise`); :mod:`~gnomon.calibration.allan_plot`
  its figure (:func:`plot_allan`).
* :mod:`~gnomon.calibration.noise_params`: a filter's noise parameters from that report
  (:func:`noise_params`, ``gnomon estimate --noise``).

Why written here rather than taken from a package (checked on PyPI, 2026): ``magcal``
(1.0.1) is an interactive serial-port tool whose fit is an unconstrained quadric least
squares with ``abs()`` applied to negative eigenvalues (no positive-definite constraint,
no geometric refinement, no coverage or refusal) and it pulls pyserial, rich, click and
questionary; ``circuitpython-mag-cal`` (1.4.1, 2023) targets CircuitPython cave-survey
instruments and fits magnetometer and accelerometer jointly with their axes aligned (it
needs both, reports no coverage); ``ctef`` is a general Cayley-transform ellipsoid fitter
for clustering; ``magcc`` is a live UDP/browser tool. None does a constrained, weighted,
quality-reported fit with a refusal, so this package uses numpy and scipy only.
"""

from gnomon.calibration.allan import allan_deviation, read_noise_terms
from gnomon.calibration.allan_plot import plot_allan
from gnomon.calibration.apply import apply_mag_calibration, calibrate_mag
from gnomon.calibration.coverage import COVERAGE_CELLS, coverage_cells, sphere_coverage
from gnomon.calibration.field import igrf_field_uT
from gnomon.calibration.fit import fit_mag
from gnomon.calibration.gyro import MAX_GYRO_CONDITION, gyro_offset_uT
from gnomon.calibration.imu_noise import imu_noise, load_imu_noise, save_imu_noise
from gnomon.calibration.noise_params import noise_params
from gnomon.calibration.plot import plot_mag_calibration
from gnomon.calibration.result import (
    MAX_ANISOTROPY,
    MAX_CONDITION,
    MIN_COVERAGE,
    MODELS,
    MagCalibration,
    load_mag_calibration,
    save_mag_calibration,
)
from gnomon.calibration.samples import MIN_SAMPLES, mag_uT_of

__all__ = ["MagCalibration", "fit_mag", "calibrate_mag", "apply_mag_calibration",
           "save_mag_calibration", "load_mag_calibration", "sphere_coverage", "coverage_cells",
           "igrf_field_uT", "gyro_offset_uT", "mag_uT_of", "plot_mag_calibration", "MODELS",
           "MIN_COVERAGE", "MAX_CONDITION", "COVERAGE_CELLS", "MIN_SAMPLES",
           "MAX_ANISOTROPY", "MAX_GYRO_CONDITION", "allan_deviation", "read_noise_terms",
           "imu_noise", "save_imu_noise", "load_imu_noise", "noise_params", "plot_allan"]
