"""On-orbit magnetometer bias by TWOSTEP (Alonso & Shuster 2002): moved to
:mod:`gnomon.calibration.orbit`, which documents it; this module re-exports its names so
that ``gnomon.twostep`` keeps working.

Patching a value here (``NOISE_MEAN_S2``, say) does not reach the code that runs: patch
:mod:`gnomon.calibration.orbit`.
"""

from gnomon.calibration.orbit import (
    FIELD_KEYS,
    MAX_CONDITION,
    MIN_SAMPLES,
    NOISE_MEAN_S2,
    TwostepResult,
    calibrate_mag_orbit,
    twostep,
)

__all__ = ["TwostepResult", "twostep", "calibrate_mag_orbit", "MIN_SAMPLES",
           "MAX_CONDITION", "NOISE_MEAN_S2", "FIELD_KEYS"]
