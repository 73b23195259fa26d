"""Store, or compare against, every registered filter's output on fixed inputs.

A refactoring that must not change behaviour is checked with it:

    python tools/behaviour_snapshot.py save    SNAPSHOT_DIR   # before
    python tools/behaviour_snapshot.py compare SNAPSHOT_DIR   # after: exit 1 on a change

``--what`` chooses what is stored (default ``filters``; ``all`` for every part):

- ``filters``: every registered filter's output on fixed inputs (below);
- ``reproduce``: ``gnomon.reproduce.run_all(quick=True)``, every number of its JSON;
- ``benchmark``: ``run_broad`` and ``run_tyrex`` on the full data sets where present
  (``../shared/data``), ``run_benchmark`` on the bundled BROAD excerpts, every number;
- ``cli``: the help text of ``gnomon`` and of every command (compared as text).

Inputs: the BROAD excerpts in ``gnomon/data/broad`` (package data), the full BROAD trials in
``../shared/data/broad`` where present, and short simulated runs of every scenario
preset (seeded). Every registered filter runs on every input that holds the
sensors it needs; its attitude ``q`` and all its numeric signals are stored. ``compare``
reports, per filter and input, the largest attitude difference (rad) and the largest
signal difference, and fails above ``--tol`` (default 1e-9 rad for the attitude, the
same relative to a signal's scale).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SIM_DURATION_S = {"imu-handheld": 30.0, "seed000": 3000.0, "seed001": 1500.0}


def inputs():
    from gnomon.datasets import bundled
    from gnomon.io import read
    from gnomon.scenarios import list_presets, load_scenario, simulate

    for path in sorted(bundled("broad").glob("*_excerpt.*")):
        yield path.stem, read(path)
    full = ROOT.parent / "shared/data/broad"  # the full trials, where present
    for path in sorted(full.glob("*.hdf5")) + sorted(full.glob("*.mat")):
        yield f"broad-{path.stem}", read(path)
    for name in list_presets():
        sc = load_scenario(name)
        sc = sc.replace({"duration_s": SIM_DURATION_S.get(name, 600.0)})
        yield f"sim-{name}", simulate(sc, rng_seed=7)


def outputs() -> dict[str, np.ndarray]:
    from gnomon.errors import InputError
    from gnomon.estimators import registry

    out = {}
    for label, rec in inputs():
        for name in registry.names():
            f = registry.create(name)
            try:
                f.check_inputs(rec)
                est = f.run(rec)
            except InputError as err:
                print(f"  {name} on {label}: not run ({err})")
                continue
            out[f"{label}|{name}|q"] = np.asarray(est.q, float)
            for key, val in est.signals.items():
                a = np.asarray(val)
                if a.dtype.kind in "fbiu":
                    out[f"{label}|{name}|{key}"] = a.astype(float)
            print(f"  {name} on {label}: {len(rec)} samples")
    return out


#: words of a key naming a measured time or speed (they differ per run: not compared)
_TIMING_WORDS = ("elapsed", "runtime", "run_time", "seconds_per", "samples_per_s", "speed",
                 "timing", "traceback", "time_s", "ms_per", "time_per", "time_us")


def _compared(key: str) -> bool:
    """Whether a stored path is compared: not a timing, not a folder's path."""
    parts = key.split("/")
    return not any(any(w in part for w in _TIMING_WORDS) for part in parts)


def _numbers(obj, prefix: str, out: dict) -> None:
    """Every number (and string) of a JSON-like result under its path, as ``out[path]``;
    timings (keys naming seconds of run time or speed) and absolute paths (where the tree
    is) are left out: they differ per run."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            if not _compared(str(k)):
                continue
            _numbers(v, f"{prefix}/{k}", out)
    elif isinstance(obj, list | tuple):
        for i, v in enumerate(obj):
            _numbers(v, f"{prefix}/{i}", out)
    elif isinstance(obj, str) and obj.startswith("/"):
        return  # a path: where the tree is, not what it computed
    elif isinstance(obj, bool) or obj is None or isinstance(obj, str):
        out[prefix] = np.array(str(obj))
    elif isinstance(obj, int | float | np.generic):
        out[prefix] = np.array(float(obj))
    elif isinstance(obj, np.ndarray):
        if obj.dtype.kind in "fbiu":
            out[prefix] = obj.astype(float)


def reproduce_outputs() -> dict[str, np.ndarray]:
    from gnomon.reproduce import run_all

    out = {}
    _numbers(run_all(out_dir=None, quick=True), "reproduce", out)
    return out


def benchmark_outputs() -> dict[str, np.ndarray]:
    from gnomon.benchmark import run_benchmark, run_broad, run_tyrex
    from gnomon.datasets import bundled

    out = {}
    _numbers(run_benchmark(bundled("broad"), anchors=[]), "benchmark-dir", out)
    broad = ROOT.parent / "shared/data/broad"
    if broad.is_dir():
        _numbers(run_broad(broad, anchors=[]), "benchmark-broad", out)
    tyrex = ROOT.parent / "shared/data/tyrex"
    if tyrex.is_dir():
        _numbers(run_tyrex(tyrex, anchors=["phone"]), "benchmark-tyrex", out)
    return out


def cli_outputs() -> dict[str, np.ndarray]:
    import contextlib
    import io

    from gnomon.cli import build_parser

    out = {}
    parser = build_parser()
    out["cli|gnomon"] = np.array(parser.format_help())

    def walk(p, path):
        for action in p._actions:
            if getattr(action, "choices", None) and hasattr(action, "_name_parser_map"):
                for name, sub in action._name_parser_map.items():
                    out[f"cli|{path} {name}"] = np.array(sub.format_help())
                    walk(sub, f"{path} {name}")

    with contextlib.redirect_stdout(io.StringIO()):
        walk(parser, "gnomon")
    return out


PARTS = {"filters": lambda: outputs(), "reproduce": reproduce_outputs,
         "benchmark": benchmark_outputs, "cli": cli_outputs}


def angle(q1, q2):
    """Rotation angle between unit quaternions (rad), accurate near zero: the chord
    ``|q1 - q2| = 2 sin(θ/4)`` of the nearer sign."""
    sign = np.where(np.sum(q1 * q2, axis=-1) < 0.0, -1.0, 1.0)[..., None]
    chord = np.linalg.norm(q1 - sign * q2, axis=-1)
    return 4.0 * np.arcsin(np.clip(0.5 * chord, 0.0, 1.0))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("action", choices=("save", "compare"))
    ap.add_argument("dir", type=Path)
    ap.add_argument("--tol", type=float, default=1e-9)
    ap.add_argument("--what", default="filters",
                    help="comma-separated parts: " + ", ".join(PARTS) + ", or all")
    args = ap.parse_args(argv)
    parts = list(PARTS) if args.what == "all" else args.what.split(",")
    code = 0
    for part in parts:
        code = max(code, _one(part, args))
    return code


def _one(part: str, args) -> int:
    file = args.dir / f"{part}.npz"
    now = PARTS[part]()
    if args.action == "save":
        args.dir.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(file, **now)
        print(f"saved {len(now)} arrays to {file}")
        return 0
    before = {k: v for k, v in np.load(file).items()
              if part in ("filters", "cli") or (_compared(k) and not str(v).startswith("/"))}
    worst, failed = 0.0, []
    for key in sorted(set(before) | set(now)):
        if key not in now or key not in before:
            failed.append(f"{key}: {'missing now' if key not in now else 'new'}")
            continue
        a, b = before[key], now[key]
        if a.dtype.kind == "U" or b.dtype.kind == "U":
            if str(a) != str(b):
                failed.append(f"{key}: text changed")
            continue
        if a.shape != b.shape:
            failed.append(f"{key}: shape {a.shape} -> {b.shape}")
            continue
        if key.endswith("|q"):
            d = float(np.nanmax(angle(a, b))) if a.size else 0.0
        else:
            scale = max(1.0, float(np.nanmax(np.abs(a))) if a.size else 1.0)
            same_nan = np.array_equal(np.isnan(a), np.isnan(b))
            d = float(np.nanmax(np.abs(a - b))) / scale if a.size else 0.0
            if not same_nan:
                d = np.inf
        worst = max(worst, d) if key.endswith("|q") else worst
        if d > 0.0:
            print(f"{d:10.3e}  {key}")
        if not d <= args.tol:
            failed.append(f"{key}: {d:.3e}")
    print(f"{part}: largest attitude difference {worst:.3e} rad over {len(now)} arrays "
          "(nonzero differences listed above)")
    if failed:
        print("CHANGED:\n  " + "\n  ".join(failed))
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
