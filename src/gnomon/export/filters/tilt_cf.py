"""The C twin of ``tilt-cf`` (``gnomon/export/c/tilt_cf.c``): its parameter struct is
``TiltCFParams`` field by field but ``speed_compensation``, which the C leaves out (the
export refuses it)."""

from gnomon.errors import InputError
from gnomon.export.spec import FilterSpec


def _values(p) -> dict:
    """No computed fields; refuses what the C does not do."""
    if p.speed_compensation:
        raise InputError("the C export of tilt-cf has no speed compensation (the vehicle's "
                         "acceleration from extra['speed_m_s']); export it with "
                         "speed_compensation=false", field="--param")
    return {}


SPECS = (FilterSpec(
    filter="tilt-cf", prefix="tilt_cf", sources=("tilt_cf.c",), headers=("tilt_cf.h",),
    adapter="adapter_tilt_cf.h",
    params=("time_constant_s", "bias_gain_1_s2", "accel_rejection_rel", "gravity_m_s2",
            "init_samples"),
    values=_values, signals=(("acc_rejected", 1, "bool"), ("bias_rad_s", 3, "float"))),)
