"""An experiment, not a feature: robust-ahrs with its attitude reset at its first rest.

    python benchmarks/first_rest_reset.py [--broad DIR]

On short, clean trials that begin at rest (``sim-tstick`` of ``defaults_loo.py``: 40 s,
the first 5 s at rest) most of robust-ahrs' error is made in the first seconds: the gyro
bias is unknown until the first rest is confirmed (``rest_min_s``), the attitude drifts
meanwhile, and the heading then decays with ``tau_mag_s``. This script measures what a
reset would gain: robust-ahrs streamed sample by sample (``update``, the kernel of
``run``), and when its ``rest`` flag first rises, its state set (``RobustAHRS.record``:
the heading into ``delta``, the tilt into ``q_acc``, ``q_gyr`` kept) to the attitude of
the mean accelerometer and magnetometer of the last ``rest_min_s`` seconds
(``attitude_from_acc_mag``). Mean total RMSE (BROAD's metric, ``gnomon.benchmark``),
as shipped and with the reset, and VQF's beside them; the development and held-out
halves as ``defaults_loo.py`` splits them.

Single-rate recordings only (the stream here hands every row to ``update``): the
simulated clean lab, and BROAD with ``--broad``. The tyrex phone trials never rest
(robust-ahrs' ``rest`` signal is never set there), so a first-rest reset cannot move
them. Measured 2026-12-07: sim-tstick 0.131 -> 0.095° (development), 0.103 -> 0.092°
(held out; VQF 0.104°); BROAD unchanged to 0.001° (the reset fires on every trial, at
1.5 s). Not in the filter: the numba kernel, its readable twin and the C twin would
need the same step and a guard for a disturbed or uncalibrated field at that rest.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _normalised(q):
    return q / np.linalg.norm(q)


def with_reset(rec) -> np.ndarray:
    """``q_nb`` (N, 4) of robust-ahrs (defaults) streamed over ``rec`` with the first-rest
    reset (module docstring)."""
    from gnomon.estimators import registry
    from gnomon.estimators.initial import attitude_from_acc_mag
    from gnomon.rotation import quat_conj, quat_mul

    f = registry.create("robust-ahrs", {})
    t = rec.t
    dt = np.diff(t, prepend=t[0] - (t[1] - t[0]))
    window_s = f.params.rest_min_s
    q = np.empty((len(rec), 4))
    done = False
    for k in range(len(rec)):
        q[k] = f.update(dt[k], rec.gyro[k], rec.accel[k], rec.mag[k])
        s = f.record
        if done or not s.rest:
            continue
        done = True
        w = slice(int(np.searchsorted(t, t[k] - window_s, side="right")), k + 1)
        q_rest = attitude_from_acc_mag(rec.accel[w].mean(0), rec.mag[w].mean(0))
        # q_nb = q_z(delta) ⊗ q_acc ⊗ q_gyr: keep q_gyr, split the rest into heading and tilt
        x = _normalised(quat_mul(q_rest, quat_conj(s.q_gyr)))
        twist = _normalised(np.array([x[0], 0.0, 0.0, x[3]]))
        s.cos_half_delta, s.sin_half_delta = twist[0], twist[3]
        s.delta = 2.0 * np.arctan2(twist[3], twist[0])
        s.q_acc[:] = quat_mul(quat_conj(twist), x)
    return q


def vqf_q(rec) -> np.ndarray:
    import vqf

    dt = float(np.median(np.diff(rec.t)))
    c = np.ascontiguousarray
    return vqf.VQF(dt).updateBatch(c(rec.gyro), c(rec.accel), c(rec.mag))["quat9D"]


def main() -> None:
    from defaults_loo import halves, sim_sets

    from gnomon.benchmark import _score
    from gnomon.estimators import registry

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--broad", default=None, help="the BROAD trials' folder")
    args = ap.parse_args()
    sets = {"sim-tstick": sim_sets()["sim-tstick"]}
    if args.broad:
        from gnomon.io import read
        from gnomon.io.broad import broad_trials

        sets["broad"] = [read(p, format="broad") for p in broad_trials(args.broad)]
    print("set, half: mean total RMSE (deg) of robust-ahrs as shipped -> with the reset; VQF")
    for name, recs in sets.items():
        for half, rs in zip(("development", "held out"), halves(recs), strict=True):
            if not all(r.single_rate for r in rs):
                raise SystemExit(f"{name}: multi-rate recordings are not streamed here")
            shipped = np.mean([_score(r, registry.create("robust-ahrs", {}).run(r).q)
                               ["total_deg"] for r in rs])
            reset = np.mean([_score(r, with_reset(r))["total_deg"] for r in rs])
            v = np.mean([_score(r, vqf_q(r))["total_deg"] for r in rs])
            print(f"{name}, {half} ({len(rs)} trials): {shipped:.3f} ({shipped / v:.3f}x) -> "
                  f"{reset:.3f} ({reset / v:.3f}x); VQF {v:.3f}")


if __name__ == "__main__":
    main()
