"""The C twin of ``robust-ahrs`` (``gnomon/export/c/robust_ahrs.c``): its parameter struct
is ``RobustAHRSParams`` field by field; the coefficients (``gnomon.kernels.robust_ahrs.
Coefficients``) are derived in C by ``gnomon_robust_ahrs_init`` from the parameters and the
nominal sample times, so that a board can run it at its own rates."""

from gnomon.export.spec import FilterSpec

SPECS = (FilterSpec(
    filter="robust-ahrs", prefix="robust_ahrs", sources=("robust_ahrs.c",),
    headers=("robust_ahrs.h",), adapter="adapter_robust_ahrs.h",
    params=("tau_acc_s", "tau_mag_s", "rest_bias", "motion_bias", "mag_rejection", "heading_kf",
            "heading_rate_noise_s", "heading_bias_ref_deg_s", "mag_bias_gain_per_s",
            "bias_sigma_init_deg_s", "bias_forgetting_s", "bias_clip_deg_s", "bias_huber_deg_s",
            "bias_sigma_motion_deg_s", "bias_vertical_forgetting", "bias_sigma_rest_deg_s",
            "rest_min_s", "rest_tau_s", "rest_th_gyro_deg_s", "rest_th_rate_deg_s",
            "rest_min_large_bias_s", "rest_th_turn_deg",
            "rest_th_acc_m_s2", "rest_reset", "mag_current_tau_s", "mag_ref_tau_s",
            "mag_norm_th", "mag_dip_th_deg", "mag_new_s", "mag_new_first_s",
            "mag_new_min_gyro_deg_s", "mag_min_undisturbed_s", "mag_max_reject_s",
            "mag_reject_factor", "mag_heading_dis_deg", "max_dt_s", "mag_soft_norm",
            "mag_soft_dip_deg",
            "hard_iron_tau_s", "hard_iron_reg", "hard_iron_gate", "mag_every", "bias_every"),
    signals=(("bias_rad_s", 3, "float"), ("bias_at_limit", 1, "bool"), ("rest", 1, "bool"),
             ("mag_disturbed", 1, "bool"), ("acc_correction_rad_s", 1, "float"),
             ("mag_gain", 1, "float"), ("hard_iron", 3, "float"), ("acc_skipped", 1, "bool"),
             ("mag_skipped", 1, "bool"), ("gap", 1, "bool")),
    streams=True),)
