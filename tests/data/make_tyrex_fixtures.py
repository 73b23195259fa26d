"""Make the motion-capture excerpts in src/gnomon/data/logs/tyrex/qualisys (see README.md there).

Run once by hand (the tests never run it): ``python tests/data/make_tyrex_fixtures.py``.
It reads ``$GNOMON_TYREX_DIR`` (default ``../shared/data/tyrex``) through
``gnomon.datasets``. For each phone excerpt in ``logs/tyrex/{android,ios}`` (made by
``make_log_fixtures.py``) it cuts the trial's QTM export to the frames covering the
excerpt's gyro samples (0.5 s margin), keeps QTM's layout (one struct named after the
measurement: ``File``, ``Timestamp``, ``StartFrame``, ``Frames``, ``FrameRate``,
``RigidBodies`` with ``Bodies``, ``Name``, ``Positions``, ``Rotations``, ``RPYs``,
``Residual``; the marker ``Trajectories`` are dropped), sets ``StartFrame`` to the first
kept frame's number (so the capture's clock is kept) and writes it compressed, with a
header text that starts with ``QTM_ver`` as QTM's own does. No value is altered.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import scipy.io

from gnomon.datasets import tyrex_dir
from gnomon.io.phone import read_tyrex

HERE = Path(__file__).resolve().parents[2] / "src" / "gnomon" / "data" / "logs" / "tyrex"


def qtm_excerpt(src: Path, dst: Path, t0: float, t1: float) -> None:
    d = scipy.io.loadmat(src, squeeze_me=False, struct_as_record=False)
    name = next(k for k in d if not k.startswith("__"))
    s = d[name][0, 0]
    rate = float(s.FrameRate[0, 0])
    first = float(s.StartFrame[0, 0])
    t = (first - 1 + np.arange(int(s.Frames[0, 0]))) / rate
    keep = np.flatnonzero((t >= t0) & (t <= t1))
    a, b = int(keep[0]), int(keep[-1]) + 1
    rb = s.RigidBodies[0, 0]
    names = np.empty((1, rb.Name.shape[1]), dtype=object)
    for i in range(rb.Name.shape[1]):
        names[0, i] = str(np.asarray(rb.Name[0, i]).reshape(-1)[0])
    out = {
        "File": str(s.File[0]), "Timestamp": str(s.Timestamp[0]),
        "StartFrame": np.array([[first + a]]), "Frames": np.array([[float(b - a)]]),
        "FrameRate": np.array([[rate]]),
        "RigidBodies": {"Bodies": rb.Bodies, "Name": names,
                        "Positions": rb.Positions[:, :, a:b], "Rotations": rb.Rotations[:, :, a:b],
                        "RPYs": rb.RPYs[:, :, a:b], "Residual": rb.Residual[:, :, a:b]},
    }
    dst.parent.mkdir(parents=True, exist_ok=True)
    scipy.io.savemat(dst, {dst.stem: out}, do_compression=True, oned_as="column")
    with open(src, "rb") as fh:
        qtm_text = fh.read(116).rstrip(b"\x00 ")
    text = (qtm_text + b"; excerpt by gnomon tests/data/make_tyrex_fixtures.py")[:116]
    with open(dst, "r+b") as fh:
        fh.write(text.ljust(116, b" "))
    print(f"{dst.name}: frames {first + a:.0f}-{first + b - 1:.0f} ({(b - a) / rate:.2f} s), "
          f"{dst.stat().st_size / 1024:.0f} kB")


def main() -> int:
    tyrex = tyrex_dir()
    if tyrex is None:
        print("full data not found: set GNOMON_TYREX_DIR")
        return 1
    for platform in ("android", "ios"):
        for excerpt in sorted((HERE / platform).iterdir()):
            trial = excerpt.name.removesuffix("_excerpt")
            rec = read_tyrex(excerpt, reference=False)
            qtm_excerpt(tyrex / "datasets" / "qualisys" / f"{trial}.mat",
                        HERE / "qualisys" / f"{excerpt.name}.mat",
                        float(rec.t[0]) - 0.5, float(rec.t[-1]) + 0.5)
    return 0


if __name__ == "__main__":
    sys.exit(main())
