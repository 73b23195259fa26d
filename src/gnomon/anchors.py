"""Adapters to the orientation libraries users compare against: VQF, imufusion, ahrs.

The only place (besides ``gnomon.io``) that knows other libraries' conventions.
Each adapter takes a gnomon ``Recording`` whose reference frame is ENU
(gyro rad/s, accelerometer m/s², magnetometer in ``rec.mag_unit``) and returns
``q_nb`` (N, 4) ``[w, x, y, z]``, ENU from sensor — gnomon's convention — using
each library with its default parameters (only the sampling rate set):

=================  ==========================  ==================================
library            its output                  conversion here
=================  ==========================  ==================================
``vqf``            ``quat9D`` ``[w,x,y,z]``    none (already sensor-to-ENU)
                   earth (ENU) from sensor
``imufusion``      ``[w,x,y,z]`` NWU from      gyro to deg/s, accelerometer to g;
                   sensor (default             ``q_ENU_NWU ⊗ q``
                   convention NWU)
``ahrs`` Madgwick  ``[w,x,y,z]`` NWU from      ``q_ENU_NWU ⊗ q``
                   sensor
=================  ==========================  ==================================

``q_ENU_NWU`` is a +90° rotation about the common up axis (NWU's x = north is
ENU's y). The libraries are optional (``pip install gnomon[anchors]``);
``available()`` says which are installed.

Two more rows for benchmarks that have them (not in ``available()``, named explicitly):
``vqf-offline`` (VQF's acausal ``offlineVQF(gyr, acc, mag, Ts)``, ``quat9D``; an upper
bound, not a causal filter) and ``onboard`` (the recording's ``q_onboard``: the device's
own estimate — phone OS, autopilot — scored like any method).

**Each sensor at its own rate** (a recording that is not ``single_rate``, e.g. a phone):
no sample is invented for a library that can be told "no new sample". Every library is
fed on the gyro's time base, the accelerometer and magnetometer rows of
``Recording.on_time_base`` (the sample in the row where it arrives, NaN elsewhere), the
same rows gnomon's own filters take:

* ``vqf``: ``VQF(gyrTs, accTs, magTs)`` with each sensor's nominal interval, then
  ``updateBatch`` with zero rows where no sample arrived: VQF's ``updateAcc`` and
  ``updateMag`` return at once on ``[0, 0, 0]``, so this is ``updateGyr`` every row and
  ``updateAcc``/``updateMag`` only in a row where a sample arrived (VQF's documented
  multi-rate use; ``run_vqf_per_row`` writes it out and equals it).
* ``imufusion``: ``update(gyr, acc, mag)`` with a zero vector where none arrived (Fusion
  ignores a zero accelerometer or magnetometer), the sample period set to each row's
  interval.
* ``ahrs-madgwick``: ``updateMARG(q, gyr, acc, mag, dt)`` per row with zero vectors
  where none arrived (ahrs falls back to ``updateIMU`` for a zero magnetometer and to the
  gyro alone for a zero accelerometer), ``dt`` each row's interval; started like its
  batch form, from ``ecompass`` of the first accelerometer and magnetometer samples,
  with the batch form's MARG gain. Its MARG step needs an accelerometer sample in the
  same call (it skips the whole correction without one), so a magnetometer sample is
  passed with the next accelerometer sample (a delay of at most one accelerometer
  interval; still used once).

For the two per-row libraries a magnetometer at a quarter of the gyro's rate corrects
heading in a quarter of the rows: their heading gain is that much lower than at one
rate — the cost of not repeating samples (VQF takes each sensor's rate as a parameter).
* ``vqf-offline`` cannot be told "no sample" (it needs one sampling grid: a zero row
  would be taken as a measurement): each row gets the latest accelerometer and
  magnetometer sample at or before it (zero-order hold: samples repeated, none
  interpolated), ``Ts`` the gyro's nominal interval. Said in ``MULTI_RATE_INPUT``.

A single-rate recording is fed exactly as before (batch calls, the table above).
"""

from __future__ import annotations

import importlib.util

import numpy as np

from gnomon.recording import Recording
from gnomon.rotation import quat_mul

__all__ = ["ANCHORS", "EXTRA_ANCHORS", "available", "installed", "run_anchor", "Q_ENU_NWU",
           "G_STANDARD",
           "MULTI_RATE_INPUT"]

G_STANDARD = 9.80665  # m/s² per g
#: ENU from NWU: rotation of +90 deg about z (x_NWU = north = y_ENU)
Q_ENU_NWU = np.array([np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)])


def _require_enu(rec: Recording) -> None:
    ref = rec.frames.get("reference", "ENU")
    if ref != "ENU":
        raise ValueError(f"anchors need an ENU recording, got reference frame {ref!r}")


def _arrays(rec: Recording):
    return (np.ascontiguousarray(rec.gyro, dtype=float),
            np.ascontiguousarray(rec.accel, dtype=float),
            np.ascontiguousarray(rec.mag, dtype=float))


def _on_time_base(rec: Recording):
    """Gyro (N, 3), and accelerometer and magnetometer on the gyro's rows (N, 3) with zero
    rows where no new sample arrived, and the masks of the rows with a sample."""
    gyr = np.ascontiguousarray(rec.gyro, dtype=float)
    out = []
    for name in ("accel", "mag"):
        v = rec.on_time_base(name)
        if v is None:
            raise ValueError(f"anchors need a {name} (the recording has none)")
        new = np.all(np.isfinite(v), axis=1)
        out += [np.ascontiguousarray(np.where(new[:, None], v, 0.0)), new]
    return gyr, out[0], out[2], out[1], out[3]


def _held(values: np.ndarray, new: np.ndarray) -> np.ndarray:
    """Rows of ``values`` (zero where not ``new``) with the last new sample repeated up to
    the next one (zero before the first)."""
    idx = np.where(new, np.arange(new.size), -1)
    np.maximum.accumulate(idx, out=idx)
    out = np.where((idx >= 0)[:, None], values[np.maximum(idx, 0)], 0.0)
    return np.ascontiguousarray(out)


def _dt_rows(rec: Recording) -> np.ndarray:
    """Each row's interval (s); the first row gets the nominal gyro interval."""
    dt0 = rec.nominal_dt_s("gyro")
    return np.diff(rec.t, prepend=rec.t[0] - dt0)


def run_vqf(rec: Recording) -> np.ndarray:
    """VQF (Laidig & Seel 2023), ``VQF(Ts).updateBatch(gyr, acc, mag)['quat9D']``; a
    multi-rate recording per row (module docstring)."""
    import vqf

    _require_enu(rec)
    if rec.single_rate:
        gyr, acc, mag = _arrays(rec)
        return np.asarray(vqf.VQF(1.0 / rec.sample_rate_hz).updateBatch(gyr, acc, mag)[
            "quat9D"])
    gyr, acc, mag, _, _ = _on_time_base(rec)
    f = vqf.VQF(rec.nominal_dt_s("gyro"), rec.nominal_dt_s("accel"), rec.nominal_dt_s("mag"))
    return np.asarray(f.updateBatch(gyr, acc, mag)["quat9D"])  # zero rows: no sample


def run_vqf_per_row(rec: Recording) -> np.ndarray:
    """``run_vqf`` of a multi-rate recording written out with VQF's per-sample calls
    (``updateGyr``; ``updateAcc``/``updateMag`` only when a sample arrived): the readable
    twin of the batch call, equal to it (``tests/test_benchmark_tyrex.py``)."""
    import vqf

    gyr, acc, mag, acc_new, mag_new = _on_time_base(rec)
    f = vqf.VQF(rec.nominal_dt_s("gyro"), rec.nominal_dt_s("accel"), rec.nominal_dt_s("mag"))
    out = np.empty((len(rec), 4))
    for i in range(len(rec)):
        f.updateGyr(gyr[i])
        if acc_new[i]:
            f.updateAcc(acc[i])
        if mag_new[i]:
            f.updateMag(mag[i])
        out[i] = f.getQuat9D()
    return out


def run_vqf_offline(rec: Recording) -> np.ndarray:
    """VQF's offline (acausal) variant, ``offlineVQF(gyr, acc, mag, Ts)['quat9D']``; a
    multi-rate recording with the latest sample held per row (module docstring)."""
    import vqf

    _require_enu(rec)
    if rec.single_rate:
        gyr, acc, mag = _arrays(rec)
        ts = 1.0 / rec.sample_rate_hz
    else:
        gyr, acc, mag, acc_new, mag_new = _on_time_base(rec)
        acc, mag = _held(acc, acc_new), _held(mag, mag_new)
        ts = rec.nominal_dt_s("gyro")
    return np.asarray(vqf.offlineVQF(gyr, acc, mag, ts)["quat9D"])


def run_onboard(rec: Recording) -> np.ndarray:
    """The recording's own attitude estimate ``q_onboard`` (NaN rows where it has none)."""
    if rec.q_onboard is None:
        raise ValueError("the recording has no estimate of the device's own (q_onboard)")
    return np.array(rec.q_onboard, dtype=float)


def run_imufusion(rec: Recording) -> np.ndarray:
    """imufusion ``Ahrs`` with default settings but the sample rate, one ``update`` per sample."""
    import imufusion

    _require_enu(rec)
    single = rec.single_rate
    gyr, acc, mag = _arrays(rec) if single else _on_time_base(rec)[:3]
    fs = rec.sample_rate_hz
    ahrs = imufusion.Ahrs()
    ahrs.set_settings(imufusion.AhrsSettings(sample_rate=fs))
    ahrs.set_sample_period(1.0 / fs)
    gyr_deg = np.degrees(gyr)
    acc_g = acc / G_STANDARD
    out = np.empty((len(rec), 4))
    if single:
        for i in range(len(rec)):
            ahrs.update(gyr_deg[i], acc_g[i], mag[i])
            out[i] = ahrs.get_quaternion()
    else:
        dt = _dt_rows(rec)
        for i in range(len(rec)):
            ahrs.set_sample_period(float(dt[i]))
            ahrs.update(gyr_deg[i], acc_g[i], mag[i])
            out[i] = ahrs.get_quaternion()
    return quat_mul(Q_ENU_NWU, out)


def run_ahrs_madgwick(rec: Recording) -> np.ndarray:
    """ahrs' ``Madgwick(gyr=, acc=, mag=, frequency=fs).Q`` (default gain), NWU -> ENU."""
    from ahrs.filters import Madgwick

    _require_enu(rec)
    if rec.single_rate:
        gyr, acc, mag = _arrays(rec)
        q = Madgwick(gyr=gyr, acc=acc, mag=mag, frequency=rec.sample_rate_hz).Q
        return quat_mul(Q_ENU_NWU, np.asarray(q, dtype=float))
    from ahrs.common.orientation import ecompass

    gyr, acc, mag, acc_new, mag_new = _on_time_base(rec)
    f = Madgwick(frequency=rec.sample_rate_hz)
    f.gain = f.gain_marg  # the batch form's gain when a magnetometer is given
    dt = _dt_rows(rec)
    q = np.empty((len(rec), 4))
    q[0] = ecompass(rec.accel[0], rec.mag[0], frame="NED", representation="quaternion")
    pending = np.zeros(3)  # a magnetometer sample waiting for the next accelerometer one
    for i in range(1, len(rec)):
        if mag_new[i]:
            pending = mag[i]
        m = np.zeros(3)
        if acc_new[i]:
            m, pending = pending, np.zeros(3)
        q[i] = f.updateMARG(q[i - 1], gyr[i], acc[i], m, dt=float(dt[i]))
    return quat_mul(Q_ENU_NWU, q)


#: method name (as in the benchmark's JSON) -> (python module it needs, adapter): the
#: causal reference libraries (``available()``, BROAD's default rows)
ANCHORS = {
    "vqf": ("vqf", run_vqf),
    "imufusion": ("imufusion", run_imufusion),
    "ahrs-madgwick": ("ahrs", run_ahrs_madgwick),
}
#: rows a benchmark names explicitly (module None: nothing to install)
EXTRA_ANCHORS = {
    "vqf-offline": ("vqf", run_vqf_offline),
    "onboard": (None, run_onboard),
}
#: how each anchor is fed a recording whose sensors have their own rates
MULTI_RATE_INPUT = {
    "vqf": "VQF(gyrTs, accTs, magTs); per gyro row updateGyr, updateAcc/updateMag only "
           "when a new sample arrived (updateBatch with [0,0,0] rows, which VQF skips)",
    "imufusion": "per gyro row: update with a zero vector where no new sample arrived "
                 "(ignored by Fusion); sample period = the row's interval",
    "ahrs-madgwick": "per gyro row: updateMARG with zero vectors where no new sample "
                     "arrived (IMU update / gyro only), a magnetometer sample passed with "
                     "the next accelerometer sample; dt = the row's interval",
    "vqf-offline": "one grid (the gyro's): latest accelerometer and magnetometer sample "
                   "held per row (repeated, not interpolated); Ts = nominal gyro interval",
    "onboard": "the device's own estimate as read (slerped onto the gyro rows by the reader)",
}


def available() -> list[str]:
    """Names of the causal reference libraries (``ANCHORS``) that are installed."""
    return [name for name, (module, _) in ANCHORS.items()
            if importlib.util.find_spec(module) is not None]


def installed(name: str) -> bool:
    """Whether anchor ``name`` (``ANCHORS`` or ``EXTRA_ANCHORS``) can run here."""
    module = {**ANCHORS, **EXTRA_ANCHORS}[name][0]
    return module is None or importlib.util.find_spec(module) is not None


def run_anchor(name: str, rec: Recording) -> np.ndarray:
    """Run anchor ``name`` on ``rec``; returns ``q_nb`` (N, 4), ENU from sensor."""
    table = {**ANCHORS, **EXTRA_ANCHORS}
    if name not in table:
        raise ValueError(f"unknown anchor {name!r}; known: {', '.join(table)}")
    return table[name][1](rec)
