"""Speed of the spacecraft world: one orbit of simulation, and the field at 100,000 points.

Run: ``PYTHONPATH=src python benchmarks/bench_world.py``. Prints measured times
(best of several runs, after a warm-up that compiles the numba kernels).
"""

from __future__ import annotations

import time

import numpy as np

from gnomon.environment.magnetic import field_i_nT, field_model
from gnomon.environment.orbit import R_EARTH, KeplerOrbit
from gnomon.scenarios import load_scenario, simulate


def best_of(fn, repeat=5):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times), float(np.median(times))


def main() -> None:
    t0 = time.perf_counter()
    sc = load_scenario("seed000")
    orbit = sc.replace({"duration_s": 5900.0})
    simulate(orbit.replace({"duration_s": 10.0}))
    print(f"warm-up (numba compile or cache load, scenario load): {time.perf_counter() - t0:.2f} s")
    b, m = best_of(lambda: simulate(orbit))
    print(f"one orbit, 5,900 s at 1 s (orbit + IGRF on the half-step grid + Sun + shadow + "
          f"RK4 dynamics + sensors): best {b * 1e3:.1f} ms, median {m * 1e3:.1f} ms")

    model = field_model("igrf")
    orb = KeplerOrbit(R_EARTH + 650e3, 0.0, np.radians(98.0), 0.0, 0.0, 0.0,
                      "2026-06-01T00:00:00Z")
    t = np.linspace(0.0, 86400.0 * 2, 100_000)
    r, _ = orb.propagate(t)
    field_i_nT(model, orb.epoch, t[:10], r[:10])
    b, m = best_of(lambda: field_i_nT(model, orb.epoch, t, r))
    print(f"IGRF-14 (degree 13) field in i at 100,000 trajectory points (2 epoch days): "
          f"best {b * 1e3:.1f} ms, median {m * 1e3:.1f} ms")
    dip = field_model("dipole")
    b, m = best_of(lambda: field_i_nT(dip, orb.epoch, t, r))
    print(f"tilted dipole at 100,000 points: best {b * 1e3:.1f} ms, median {m * 1e3:.1f} ms")
    b, m = best_of(lambda: orb.propagate(t))
    print(f"J2 orbit propagation at 100,000 points: best {b * 1e3:.1f} ms")


if __name__ == "__main__":
    main()
