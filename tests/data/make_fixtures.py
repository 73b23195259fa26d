"""Make the small real-data excerpts in src/gnomon/data from the BROAD data set (not run by tests).

BROAD: Laidig, Caruso, Cereatti, Seel, "BROAD — A Benchmark for Robust Inertial
Orientation Estimation", Data 6(7):72, 2021, doi:10.3390/data6070072, CC BY 4.0.

Usage (from the repository root)::

    python tests/data/make_fixtures.py [BROAD_DIR]

BROAD_DIR defaults to $GNOMON_BROAD_DIR, else ../shared/data/broad. Writes

- src/gnomon/data/broad/01_undisturbed_slow_rotation_A_excerpt.mat   (MATLAB v5, BROAD layout)
- src/gnomon/data/broad/32_disturbed_attached_magnet_1cm_excerpt.hdf5 (HDF5, BROAD layout)
- src/gnomon/data/broad/trials.json  (the two excerpts with their original trials' groups)
- src/gnomon/data/broad_01_excerpt.csv (gnomon's default CSV header + truth + mask)

Each BROAD excerpt is a contiguous window of 25 s starting 8 s before the
first sample with ``movement`` true, so it holds 8 s of the initial rest
phase (for a filter to settle) and 17 s of motion. The fields, dtypes and
shapes follow the original files exactly (``movement`` bool in HDF5,
(N, 1) uint8 in .mat; ``sampling_rate`` root attribute in HDF5, (1, 1) in .mat);
only the arrays are cut. The CSV holds 5 s of the .mat excerpt (2 s rest,
3 s motion, from 6 s into the excerpt), values written with 9 significant
digits, ``t`` restarting at 0.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import h5py
import numpy as np
import scipy.io

ROOT = Path(__file__).resolve().parents[2]
#: the package data folder the excerpts ship in (found at run time through importlib.resources)
HERE = ROOT / "src" / "gnomon" / "data"
REST_S = 8.0  # s of initial rest kept before the motion starts
LENGTH_S = 25.0  # s per excerpt
FIELDS = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "opt_pos", "movement")
TRIALS = {  # trial -> (source suffix, fixture suffix)
    "01_undisturbed_slow_rotation_A": (".mat", ".mat"),
    "32_disturbed_attached_magnet_1cm": (".hdf5", ".hdf5"),
}
CSV_START_S, CSV_LENGTH_S = 6.0, 5.0


def load(path: Path) -> tuple[dict, float, str]:
    if path.suffix == ".mat":
        d = scipy.io.loadmat(path)
        return ({k: d[k] for k in FIELDS}, float(d["sampling_rate"].item()),
                str(d["info"][0]) if "info" in d else "")
    with h5py.File(path, "r") as f:
        info = f.attrs.get("info", "")
        return ({k: f[k][()] for k in FIELDS}, float(f.attrs["sampling_rate"]),
                info.decode() if isinstance(info, bytes) else str(info))


def window(d: dict, fs: float) -> slice:
    move = np.asarray(d["movement"]).reshape(-1).astype(bool)
    first = int(np.argmax(move))
    start = max(0, first - round(REST_S * fs))
    return slice(start, start + round(LENGTH_S * fs))


def save(path: Path, d: dict, fs: float, info: str) -> None:
    if path.suffix == ".mat":
        scipy.io.savemat(path, {**d, "sampling_rate": np.array([[fs]]), "info": info},
                         do_compression=True, oned_as="column")
        return
    with h5py.File(path, "w") as f:
        f.attrs["info"] = info
        f.attrs["sampling_rate"] = fs
        for k, v in d.items():
            f.create_dataset(k, data=v, compression="gzip", compression_opts=9, shuffle=True)


def main(broad_dir: Path) -> None:
    out_dir = HERE / "broad"
    out_dir.mkdir(exist_ok=True)
    groups = json.loads((broad_dir / "trials.json").read_text())
    excerpt_groups = {"groups": groups["groups"], "trials": {}}
    for trial, (src_suffix, dst_suffix) in TRIALS.items():
        d, fs, info = load(broad_dir / f"{trial}{src_suffix}")
        s = window(d, fs)
        cut = {k: np.ascontiguousarray(v[s]) for k, v in d.items()}
        note = (f"{info}\n\nEXCERPT for gnomon's tests: samples {s.start}:{s.stop} of trial "
                f"{trial} (BROAD, Laidig et al. 2021, doi:10.3390/data6070072, CC BY 4.0).")
        name = f"{trial}_excerpt"
        save(out_dir / f"{name}{dst_suffix}", cut, fs, note)
        entry = dict(groups["trials"][trial])
        entry["description"] = f"excerpt (samples {s.start}:{s.stop}) of {trial}: " + \
            entry.get("description", "")
        excerpt_groups["trials"][name] = entry
        print(f"{name}{dst_suffix}: samples {s.start}:{s.stop} ({(s.stop - s.start) / fs:.1f} s), "
              f"movement from {np.argmax(cut['movement'].reshape(-1)) / fs:.2f} s, "
              f"NaN truth rows {int(np.isnan(cut['opt_quat']).any(axis=1).sum())}")
        if trial.startswith("01_"):
            i0, n = round(CSV_START_S * fs), round(CSV_LENGTH_S * fs)
            c = {k: v[i0:i0 + n] for k, v in cut.items()}
            table = np.column_stack([np.arange(n) / fs, c["imu_gyr"], c["imu_acc"], c["imu_mag"],
                                     c["opt_quat"], c["movement"].reshape(-1)])
            header = ("t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z,"
                      "q_w,q_x,q_y,q_z,mask")
            np.savetxt(HERE / "broad_01_excerpt.csv", table, delimiter=",", header=header,
                       comments="", fmt=["%.9g"] * 14 + ["%d"])
            print(f"broad_01_excerpt.csv: excerpt samples {i0}:{i0 + n} of {name}")
    (out_dir / "trials.json").write_text(json.dumps(excerpt_groups, indent=2) + "\n")


if __name__ == "__main__":
    default = os.environ.get("GNOMON_BROAD_DIR", str(ROOT.parent / "shared" / "data" / "broad"))
    main(Path(sys.argv[1] if len(sys.argv) > 1 else default))
