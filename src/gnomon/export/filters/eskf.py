"""The C twin of ``eskf-r3`` and ``eskf-r6`` (``gnomon/export/c/eskf.c``, one source; the
measurement rows r by ``GNOMON_ESKF_R`` in ``gnomon_config.h``; the straight-line update
``eskf_unrolled.h`` written by ``tools/codegen_eskf.py``): its parameter struct is
``gnomon.kernels.eskf.Coefficients`` by name (the values the compiled kernel reads,
computed by the same ``coefficients``), then the parameters of the start."""

from gnomon.export.spec import FilterSpec

#: the C parameter struct, in order: the kernel's coefficients, then the start's parameters
PARAMS = ("var_gyro", "var_bias", "var_acc", "var_mag", "gravity", "dip_tau", "acc_lp_tau",
          "acc_lp_follow", "bias_gate2", "bias_gate_rate", "bias_limit", "inv_gravity",
          "inv_gate_acc", "inv_gate_mag", "dip_rate", "acc_lp_rate", "init_att_std",
          "init_bias_std", "init_time", "inclination_known", "inclination")


def coefficient_values(params) -> dict:
    """The coefficients of ``params`` as the kernel computes them (``coefficients``)."""
    from gnomon.kernels.eskf import coefficients

    c = coefficients(params)._asdict()
    return {k: float(c[k]) for k in PARAMS if k in c}


SPECS = tuple(
    FilterSpec(filter=f"eskf-r{r}", prefix="eskf", sources=("eskf.c",),
               headers=("eskf.h", "eskf_unrolled.h"),
               adapter="adapter_eskf.h", defines=(f"#define GNOMON_ESKF_R {r}",),
               params=PARAMS, values=coefficient_values, phases=True,
               signals=(("bias_rad_s", 3, "float"), ("bias_at_limit", 1, "bool"),
                        ("innovation", r, "float"), ("cov_diag", 6, "float"),
                        ("update_skipped", 1, "bool")))
    for r in (3, 6))
