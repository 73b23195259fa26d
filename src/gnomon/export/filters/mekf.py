"""The C twin of ``mekf`` and of its presets ``mekf-delayed`` and ``mekf-spacecraft`` (one
filter, three parameter sets; ``gnomon/export/c/mekf.c``, run by ``runner_spacecraft.c`` on
the CSV of a spacecraft recording). Its parameter struct is ``MEKFParams`` field by field,
the four options of the numerical form as the kernel's ``Coefficients`` hold them
(``substitute``, ``previous_gyro``, ``exponential``, ``exp_correction``)."""

from gnomon.export.spec import FilterSpec

PARAMS = ("sigma_mag_rad", "mag_noise_nT", "sigma_sun_rad", "arw_rad_rt_s", "bias_rw_rad_s_rt_s",
          "sigma0_att_rad", "sigma0_bias_rad_s", "estimate_mag_bias", "sigma0_mag_bias_nT",
          "mag_bias_rw_nT_rt_s", "sigma_mag_norm_nT", "estimate_gyro_scale",
          "sigma0_gyro_scale", "gyro_scale_rw_rt_s", "use_sun", "substitute", "delay_samples",
          "swing_gain", "use_star_tracker", "st_sigma_cross_rad", "st_sigma_about_rad",
          "st_latency_s", "st_gate_chi2", "previous_gyro", "exponential", "relinearise",
          "exp_correction", "orbital_rate_rad_s", "max_dt_s")


def values(p) -> dict:
    """The C fields computed from ``MEKFParams`` (``gnomon.kernels.mekf.coefficients``)."""
    from gnomon.kernels.spacecraft_cf import SUBSTITUTES

    return {"substitute": SUBSTITUTES[p.sun_substitute],
            "previous_gyro": p.gyro_sample == "previous",
            "exponential": p.transition == "exponential",
            "exp_correction": p.correction == "exponential"}


SPECS = tuple(FilterSpec(
    filter=name, prefix="mekf", sources=("mekf.c",), headers=("mekf.h",),
    adapter="adapter_mekf.h", runner="runner_spacecraft.c", params=PARAMS, values=values,
    kind="spacecraft") for name in ("mekf", "mekf-delayed", "mekf-spacecraft"))
