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
"""

from __future__ import annotations

import importlib.util

import numpy as np

from gnomon.recording import Recording
from gnomon.rotation import quat_mul

__all__ = ["ANCHORS", "available", "run_anchor", "Q_ENU_NWU", "G_STANDARD"]

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


def run_vqf(rec: Recording) -> np.ndarray:
    """VQF (Laidig & Seel 2023), ``VQF(Ts).updateBatch(gyr, acc, mag)['quat9D']``."""
    import vqf

    _require_enu(rec)
    gyr, acc, mag = _arrays(rec)
    return np.asarray(vqf.VQF(1.0 / rec.sample_rate_hz).updateBatch(gyr, acc, mag)["quat9D"])


def run_imufusion(rec: Recording) -> np.ndarray:
    """imufusion ``Ahrs`` with default settings but the sample rate, one ``update`` per sample."""
    import imufusion

    _require_enu(rec)
    gyr, acc, mag = _arrays(rec)
    fs = rec.sample_rate_hz
    ahrs = imufusion.Ahrs()
    ahrs.set_settings(imufusion.AhrsSettings(sample_rate=fs))
    ahrs.set_sample_period(1.0 / fs)
    gyr_deg = np.degrees(gyr)
    acc_g = acc / G_STANDARD
    out = np.empty((len(rec), 4))
    for i in range(len(rec)):
        ahrs.update(gyr_deg[i], acc_g[i], mag[i])
        out[i] = ahrs.get_quaternion()
    return quat_mul(Q_ENU_NWU, out)


def run_ahrs_madgwick(rec: Recording) -> np.ndarray:
    """ahrs' ``Madgwick(gyr=, acc=, mag=, frequency=fs).Q`` (default gain), NWU -> ENU."""
    from ahrs.filters import Madgwick

    _require_enu(rec)
    gyr, acc, mag = _arrays(rec)
    q = Madgwick(gyr=gyr, acc=acc, mag=mag, frequency=rec.sample_rate_hz).Q
    return quat_mul(Q_ENU_NWU, np.asarray(q, dtype=float))


#: method name (as in the benchmark's JSON) -> (python module it needs, adapter)
ANCHORS = {
    "vqf": ("vqf", run_vqf),
    "imufusion": ("imufusion", run_imufusion),
    "ahrs-madgwick": ("ahrs", run_ahrs_madgwick),
}


def available() -> list[str]:
    """Names of the anchors whose library is installed."""
    return [name for name, (module, _) in ANCHORS.items()
            if importlib.util.find_spec(module) is not None]


def run_anchor(name: str, rec: Recording) -> np.ndarray:
    """Run anchor ``name`` on ``rec``; returns ``q_nb`` (N, 4), ENU from sensor."""
    if name not in ANCHORS:
        raise ValueError(f"unknown anchor {name!r}; known: {', '.join(ANCHORS)}")
    return ANCHORS[name][1](rec)
