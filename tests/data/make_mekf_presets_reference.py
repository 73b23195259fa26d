"""Make tests/data/mekf_presets_before_merge.npz (not run by tests).

The outputs of the two spacecraft MEKFs as they were before issue 22 merged them into
one ``mekf`` (``gnomon.estimators.mekf_spacecraft.MagGyroMEKF`` and ``MEKFSpacecraft``
at commit a7ed4d5), so that ``tests/test_mekf.py`` can hold their presets
``mekf-delayed`` and ``mekf-spacecraft`` to the same results. Written once, at that
commit plus the new module, with::

    python tests/data/make_mekf_presets_reference.py

Cases: ``seed000`` (first 4000 s: sunlit, sun-sensor losses), ``seed001`` (first 2000 s,
with a 10 % tilted field model so that the updates are large), default parameters;
every 4th sample of ``q`` (q_ob) and ``bias`` (rad/s).
"""

from pathlib import Path

import numpy as np
from gnomon.estimators.mekf_spacecraft import MagGyroMEKF, MEKFSpacecraft

from gnomon.scenarios import load_scenario, simulate

CASES = {
    "seed000": ("seed000", {"duration_s": 4000.0}, MagGyroMEKF),
    "seed001": ("seed001", {"duration_s": 2000.0, "environment.field_error.kind": "tilt",
                            "environment.field_error.level_pct": 10.0}, MEKFSpacecraft),
}

if __name__ == "__main__":
    out = {}
    for key, (name, changes, cls) in CASES.items():
        rec = simulate(load_scenario(name).replace(changes))
        est = cls().run(rec)
        out[f"{key}_q"] = est.q[::4]
        out[f"{key}_bias"] = est.signals["bias_rad_s"][::4]
    np.savez_compressed(Path(__file__).with_name("mekf_presets_before_merge.npz"), **out)
