"""The C twin of ``mahony`` (``gnomon/export/c/mahony.c``): its parameter struct is
``MahonyParams`` field by field."""

from gnomon.export.spec import FilterSpec

SPECS = (FilterSpec(
    filter="mahony", prefix="mahony", sources=("mahony.c",), headers=("mahony.h",),
    adapter="adapter_mahony.h",
    params=("kp_acc_rad_s", "kp_mag_rad_s", "ki_rad_s2", "mag_heading_only", "init_samples",
            "max_dt_s"),
    signals=(("bias_rad_s", 3, "float"), ("acc_skipped", 1, "bool"), ("mag_skipped", 1, "bool"),
             ("gap", 1, "bool"))),)
