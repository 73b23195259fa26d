"""Simulate the seed-001 microsatellite for 20 minutes and look at what the sensors saw.

    python examples/spacecraft_simulate.py
"""

import numpy as np

import gnomon

scenario = gnomon.load_scenario("seed001").replace({"duration_s": 1200})
rec = gnomon.simulate(scenario)
eclipse = rec.extra["eclipse"] < 1.0
angle = np.degrees(gnomon.error_angle_rad(np.tile([1.0, 0, 0, 0], (len(rec), 1)), rec.q_true))
print(f"{len(rec)} samples; sun sensor valid {rec.sun_valid.mean():.0%} of the time; "
      f"in shadow {eclipse.mean():.0%}")
print(f"attitude relative to the orbital frame: max {angle.max():.2f} deg")
print(f"field magnitude {np.linalg.norm(rec.mag, axis=1).mean():.0f} nT (mean)")
