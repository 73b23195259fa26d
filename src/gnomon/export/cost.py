"""What an exported filter costs, measured: ``cost.json`` beside its sources.

``build_and_measure(out_dir, spec)`` builds the export (``make``: the strict flags of the
Makefile), then measures on a recording the filter runs on (the bundled BROAD excerpt for
the IMU filters, a simulated orbit for the spacecraft ones; written as ``bench.csv``):

* ``state_bytes``: ``sizeof`` the filter's state struct (and ``params_bytes``;
  ``tail_bytes``: storage the caller gives the filter besides, where a runner reports it);
* ``code_bytes``: ``size`` of the library's objects (text + data), on this machine and,
  when ``arm-none-eabi-gcc`` is there, for a Cortex-M4F (``code_bytes_cortex_m4f``;
  ``null`` with the reason where it is not);
* ``ns_per_update``: ``gnomon_run --bench`` (the fastest of several passes over the
  recording; one update = one row: its accelerometer and magnetometer samples and its
  gyro step);
* ``ops_per_update``: ``gnomon_count`` (the same source compiled as C++ with a counting
  number type: additions, multiplications, divisions, square roots, trigonometric and
  other functions, per row, as written in the source).
* ``phases`` (filters whose adapter has them, ``FilterSpec.phases``): ``gnomon_run
  --phases`` and ``gnomon_count --phases``, ns and operations of each phase of the step
  (the adapter says which phases and on which rows).

Nothing is typed in: every number comes from running the tools on this machine.
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
from pathlib import Path

from gnomon.errors import InputError

__all__ = ["build_and_measure", "bench_recording", "make"]


def make(out_dir, *targets: str, env_cc: str | None = None) -> str:
    """``make -C out_dir TARGETS``; raises ``InputError`` with the compiler's output when it
    fails. Returns make's output."""
    cc = env_cc or os.environ.get("CC") or "cc"
    if shutil.which("make") is None or shutil.which(cc.split()[0]) is None:
        raise InputError(f"building the C export needs make and a C compiler ({cc})",
                         field="make")
    cmd = ["make", "-s", "-C", str(out_dir), *targets]
    if env_cc:
        cmd.append(f"CC={env_cc}")
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        raise InputError(f"make {' '.join(targets) or 'all'} failed:\n{p.stdout}{p.stderr}",
                         field="make")
    return p.stdout


def bench_recording(kind: str):
    """The recording the costs are measured on: the bundled BROAD excerpt (IMU) or 600 s of
    the seed001 scenario with a star tracker (spacecraft)."""
    from gnomon.datasets import bundled
    from gnomon.io import read

    if kind == "imu":
        return read(sorted(bundled("broad").glob("*.hdf5"))[0])
    from gnomon.scenarios import load_scenario, simulate

    sc = load_scenario("smallsat-star-tracker").replace({"duration_s": 600.0})
    return simulate(sc, rng_seed=1)


def _sizes(objects: list[Path], size_tool: str = "size") -> int | None:
    if shutil.which(size_tool) is None or not objects:
        return None
    p = subprocess.run([size_tool, *map(str, objects)], capture_output=True, text=True)
    if p.returncode != 0:
        return None
    total = 0
    for line in p.stdout.splitlines()[1:]:
        parts = line.split()
        total += int(parts[0]) + int(parts[1])  # text + data
    return total


def build_and_measure(out_dir, spec, rec=None) -> dict:
    """Build the export in ``out_dir`` and write ``out_dir/cost.json`` (module docstring);
    returns its content."""
    from gnomon.io import write

    out = Path(out_dir)
    make(out)
    rec = bench_recording(spec.kind) if rec is None else rec
    csv = out / "bench.csv"
    write(csv, rec)

    def run(exe: str, *args: str) -> dict:
        with open(csv) as fh:
            p = subprocess.run([str(out / exe), *args], stdin=fh, capture_output=True,
                               text=True)
        if p.returncode != 0:
            raise InputError(f"{exe} failed: {p.stderr.strip()}", field="make")
        return json.loads(p.stdout)

    bench = run("gnomon_run", "--bench")
    cost = {"filter": spec.filter, "machine": platform.machine(),
            "state_bytes": bench.get("state_bytes"), "params_bytes": bench.get("params_bytes"),
            "code_bytes": _sizes([out / s.replace(".c", ".o") for s in spec.sources]),
            "ns_per_update": bench["ns_per_update"], "rows": bench["rows"],
            "recording": rec.source or "bench.csv"}
    if "tail_bytes" in bench:  # memory the caller provides besides the state (mekf's tail)
        cost["tail_bytes"] = bench["tail_bytes"]
    try:
        make(out, "count")
        cost["ops_per_update"] = run("gnomon_count")["ops_per_update"]
    except InputError as err:
        cost["ops_per_update"] = None
        cost["ops_per_update_why_not"] = str(err).splitlines()[0]
    if spec.phases:
        cost["phases"] = run("gnomon_run", "--phases")
        if cost["ops_per_update"] is not None:
            cost["phases"]["ops"] = run("gnomon_count", "--phases")["ops"]
        cost["phases"].pop("sink", None)
    if shutil.which("arm-none-eabi-gcc"):
        try:
            make(out, "m4")
            cost["code_bytes_cortex_m4f"] = _sizes(
                [out / "m4" / s.replace(".c", ".o") for s in spec.sources],
                "arm-none-eabi-size" if shutil.which("arm-none-eabi-size") else "size")
        except InputError as err:
            cost["code_bytes_cortex_m4f"] = None
            cost["code_bytes_cortex_m4f_why_not"] = str(err).splitlines()[0]
    else:
        cost["code_bytes_cortex_m4f"] = None
        cost["code_bytes_cortex_m4f_why_not"] = ("arm-none-eabi-gcc is not installed "
                                                 "(Debian: apt-get install gcc-arm-none-eabi)")
    (out / "cost.json").write_text(json.dumps(cost, indent=2) + "\n")
    return cost
