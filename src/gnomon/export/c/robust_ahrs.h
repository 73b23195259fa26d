/* gnomon flight code: the robust decoupled AHRS (VQF's structure, Laidig & Seel 2023, with
 * gnomon's heading Kalman gain and online hard-iron offset), 9-axis, twin of
 * gnomon.kernels.robust_ahrs (gnomon filter "robust-ahrs").
 *
 * Frames: the estimate is q_nb = q_z(delta) (x) q_acc (x) q_gyr, ENU (x east, y north,
 * z up) from the sensor (body) frame; q_gyr = q_Ib (strapdown into the almost-inertial
 * frame I), q_acc = q_6I (inclination correction, frame 6 has z up), delta the heading of
 * frame 6 in ENU. A resting accelerometer reads [0, 0, +g]. Units: gyro rad/s,
 * accelerometer m/s^2, magnetometer any one unit (gnomon uses uT), times s.
 *
 * How to call it, at any rates:
 *   gnomon_robust_ahrs_init(&s, &c, &params, ts_s, ts_acc_s, ts_mag_s);   once: the
 *       coefficients c from the parameters and the nominal sample times (s) of the gyro,
 *       the accelerometer and the magnetometer (<= 0: the gyro's), and a fresh state s
 *   then for every sample as it arrives:
 *     gnomon_robust_ahrs_update_acc(&s, acc);   an accelerometer sample
 *     gnomon_robust_ahrs_update_mag(&s, mag);   a magnetometer sample
 *     gnomon_robust_ahrs_update_gyro(&s, &c, dt_s, gyro);  a gyro sample: the step, with
 *         the accelerometer and magnetometer samples that arrived since the last gyro
 *         sample (their mean when several did); dt_s since the previous gyro sample
 *         (0 for the very first). Returns the GNOMON_ROBUST_AHRS_* flags.
 *   gnomon_robust_ahrs_get_quat(&s, q); gnomon_robust_ahrs_get_bias(&s, b);
 *
 * The step's phases (gnomon.kernels.robust_ahrs.robust_ahrs_step) in update_gyro: the gyro
 * phase (rest detection's gyro part, strapdown; a gap, dt_s > max_dt_s, ends the step
 * there), then with a new accelerometer sample the accelerometer phase (rest detection's
 * accelerometer part, inclination, the gyro-bias Kalman filter on every bias_every-th
 * sample; the first rest of the start-up restarts the low-pass in frame I at the rest's
 * force), then with a new magnetometer sample the magnetometer phase (the first rest's
 * heading, block mean of mag_every samples, hard-iron offset, disturbance detection,
 * heading gain, heading).
 * No initial attitude is needed: the low-pass filters start as running means.
 */
#ifndef GNOMON_ROBUST_AHRS_H
#define GNOMON_ROBUST_AHRS_H

#include "gnomon_real.h"

#ifdef __cplusplus
extern "C" {
#endif

/* The parameters: gnomon's RobustAHRSParams field by field (units in the names). */
typedef struct {
    real_t tau_acc_s;             /* accelerometer low-pass in frame I (inclination), s */
    real_t tau_mag_s;             /* heading correction time constant, s */
    bool rest_bias;               /* rest detection and bias estimation at rest */
    bool motion_bias;             /* bias estimation in motion */
    bool mag_rejection;           /* magnetic disturbance detection and rejection */
    bool heading_kf;              /* heading gain from a scalar Kalman filter */
    real_t heading_rate_noise_s;  /* heading KF: random walk per rotation, s */
    real_t heading_bias_ref_deg_s;  /* heading KF: vertical bias std scale, deg/s (0: off) */
    real_t mag_bias_gain_per_s;   /* heading-rate bias loop gain, 1/s (0: off) */
    real_t bias_sigma_init_deg_s;  /* initial bias std, deg/s */
    real_t bias_forgetting_s;     /* bias std grows by 0.1 deg/s in this time, s */
    real_t bias_clip_deg_s;       /* bound on the bias estimate, deg/s */
    real_t bias_huber_deg_s;      /* Huber threshold of the bias filter in motion, deg/s */
    real_t bias_sigma_motion_deg_s;  /* bias measurement std in motion, deg/s */
    real_t bias_vertical_forgetting;  /* vertical bias weight in motion (relative) */
    real_t bias_sigma_rest_deg_s;  /* bias measurement std at rest, deg/s */
    real_t rest_min_s;            /* minimum rest duration, s */
    real_t rest_tau_s;            /* rest detection low-pass, s */
    real_t rest_th_gyro_deg_s;    /* rest threshold on the gyro deviation, deg/s */
    real_t rest_th_rate_deg_s;    /* steady rate that needs rest_min_large_bias_s, deg/s */
    real_t rest_min_large_bias_s;  /* minimum duration of such a rest, s */
    real_t rest_th_turn_deg;      /* a turn of the accelerometer or magnetometer direction
                                   * beyond this ends a rest, deg (0: off) */
    real_t rest_th_acc_m_s2;      /* rest threshold on the accelerometer deviation, m/s^2 */
    bool rest_reset;              /* the first rest of the start-up sets the inclination and
                                   * the heading from the rest's accelerometer and field */
    real_t mag_current_tau_s;     /* low-pass of the field's norm and dip, s */
    real_t mag_ref_tau_s;         /* learned field reference time constant, s */
    real_t mag_norm_th;           /* relative norm deviation flagging a disturbance */
    real_t mag_dip_th_deg;        /* dip deviation flagging a disturbance, deg */
    real_t mag_new_s;             /* a steady new field accepted after this motion, s */
    real_t mag_new_first_s;       /* the same without a reference yet, s */
    real_t mag_new_min_gyro_deg_s;  /* rate counted as motion for a new field, deg/s */
    real_t mag_min_undisturbed_s;  /* undisturbed time before the field is used again, s */
    real_t mag_max_reject_s;      /* longest full rejection of a disturbed field, s */
    real_t mag_reject_factor;     /* gain divisor after that */
    real_t mag_heading_dis_deg;   /* a field in the bounds whose heading disagrees by more
                                   * than this is a disturbance too, deg (0: off) */
    real_t max_dt_s;              /* longer gyro intervals are gaps: gyro only, s */
    real_t mag_soft_norm;         /* soft de-weighting, relative norm (0: off) */
    real_t mag_soft_dip_deg;      /* soft de-weighting, dip, deg (0: off) */
    real_t hard_iron_tau_s;       /* online hard-iron window, s (0: off) */
    real_t hard_iron_reg;         /* hard-iron prior weight (relative) */
    real_t hard_iron_gate;        /* the offset is used below this residual fraction */
    int32_t mag_every;            /* heading filter on the mean of every k mag samples */
    int32_t bias_every;           /* bias filter on every k-th accelerometer sample */
} gnomon_robust_ahrs_params;

/* The number type of the low-pass filters (their coefficients and states): double in every
 * build, as VQF's C++ keeps its filters. A float second-order Butterworth whose cutoff is
 * far below its sample rate (tau_acc_s = 2.5 s at 285 Hz: 1 + a1 + a2 = 2e-6) amplifies the
 * rounding of its state by about 1 / (1 + a1 + a2): in float the inclination drifted by up
 * to 0.4 deg from the double's. -DGNOMON_ROBUST_AHRS_FLOAT_LOWPASS makes them float too in
 * a float build (no double arithmetic at all, for an FPU without double; less accurate). */
#if defined(GNOMON_COUNT_OPS) && defined(__cplusplus)
typedef real_t gnomon_robust_ahrs_lp_t;  /* counted with the rest */
#elif defined(GNOMON_FLOAT) && defined(GNOMON_ROBUST_AHRS_FLOAT_LOWPASS)
typedef float gnomon_robust_ahrs_lp_t;
#else
typedef double gnomon_robust_ahrs_lp_t;
#endif

/* A second-order Butterworth low-pass, a running mean for its first tau_s seconds
 * (gnomon.kernels.robust_ahrs.LowPass). */
typedef struct {
    gnomon_robust_ahrs_lp_t b0, b1, b2, a1, a2;
    gnomon_robust_ahrs_lp_t tau_s;  /* s */
    gnomon_robust_ahrs_lp_t ts_s;   /* its sample time, s */
} gnomon_robust_ahrs_lowpass;

/* The coefficients (gnomon.kernels.robust_ahrs.Coefficients, field by field): derived by
 * init from the parameters and the nominal sample times; constant afterwards. */
typedef struct {
    real_t ts_s;       /* nominal gyro sample time, s */
    real_t ts_acc_s;   /* nominal accelerometer sample time, s */
    real_t max_dt_s;
    bool rest_bias;
    gnomon_robust_ahrs_lowpass rest_lp;      /* the gyro (sample time ts_s) */
    gnomon_robust_ahrs_lowpass rest_acc_lp;  /* the accelerometer (ts_acc_s) */
    real_t rest_th_gyro2;   /* (rad/s)^2 */
    real_t rest_th_acc2;    /* (m/s^2)^2 */
    real_t rest_min_s;
    real_t rest_th_rate;    /* rad/s */
    real_t rest_min_large_s;
    gnomon_robust_ahrs_lowpass rest_mag_lp;  /* the magnetometer, body (its own ts) */
    real_t rest_th_turn2;   /* squared chord of rest_th_turn_deg (0: off) */
    bool rest_reset;
    gnomon_robust_ahrs_lowpass acc_lp;       /* the accelerometer in frame I */
    bool motion_bias;
    int32_t bias_every;
    gnomon_robust_ahrs_lowpass bias_lp;      /* sample time ts_acc_s * bias_every */
    real_t bias_p0;         /* (rad/s)^2 */
    real_t bias_v;          /* (rad/s)^2 per bias update */
    real_t w_rest;          /* (rad/s)^2 */
    real_t w_motion;
    real_t w_vertical;
    real_t bias_clip;       /* rad/s */
    real_t huber;           /* rad/s */
    int32_t mag_every;
    real_t ts_mag;          /* nominal magnetometer sample time * mag_every, s */
    real_t hi_lambda;
    real_t hi_reg;
    real_t hi_gate;
    bool mag_rejection;
    gnomon_robust_ahrs_lowpass mag_lp;       /* the field's norm and dip */
    real_t k_mag_ref;
    real_t mag_norm_th;
    real_t mag_dip_th;      /* rad */
    real_t mag_new_s;
    real_t mag_new_first_s;
    real_t mag_new_min_gyro2;  /* (rad/s)^2 */
    real_t mag_min_undisturbed_s;
    real_t mag_max_reject_s;
    real_t mag_reject_factor;
    real_t mag_heading_dis;  /* rad (0: off) */
    real_t soft_norm;
    real_t soft_dip;        /* 1/rad^2 */
    real_t tau_mag_s;
    real_t k_mag;
    bool heading_kf;
    real_t r_head;
    real_t q_head;
    real_t q_rate;
    real_t inv_bias_ref2;   /* 1/(rad/s)^2 */
    real_t k_mag_bias;      /* 1/s */
} gnomon_robust_ahrs_coefficients;

/* low-pass filter states (z0, z1: direct form II transposed; during the start-up z0 holds
 * the running sum; n: samples in the running mean, -1 once the filter runs) */
typedef struct {
    gnomon_robust_ahrs_lp_t z0[2], z1[2];
    int32_t n;
} gnomon_robust_ahrs_lowpass2;
typedef struct {
    gnomon_robust_ahrs_lp_t z0[3], z1[3];
    int32_t n;
} gnomon_robust_ahrs_lowpass3;
typedef struct {
    gnomon_robust_ahrs_lp_t z0[9], z1[9];  /* 3x3, row-major */
    int32_t n;
} gnomon_robust_ahrs_lowpass33;

/* exponentially weighted sums of the hard-iron fit and the offset in use (HARD_IRON) */
typedef struct {
    real_t w;           /* sum 1 */
    real_t S[9];        /* sum R_6b (3x3, row-major) */
    real_t rm[3];       /* sum R_6b m (the raw field) */
    real_t m[3];        /* sum m */
    real_t mm;          /* sum |m|^2 */
    real_t o[3];        /* the offset in use (body, magnetometer unit; 0: none) */
    real_t block_m[3];  /* sum m, sum |m|^2 over the current block of mag_every */
    real_t block_mm;
    real_t block_S[9];  /* sum R_6b, sum R_6b m (raw) over the block, each sample with */
    real_t block_rm[3]; /* its own R_6b */
} gnomon_robust_ahrs_hard_iron;

/* The state: the kernel's STATE field by field (the same names), then the samples that
 * arrived since the last gyro sample. */
typedef struct {
    real_t q_gyr[4];     /* q_Ib: strapdown of the bias-corrected gyro */
    real_t q_acc[4];     /* q_6I: inclination correction */
    real_t delta;        /* rad: heading of frame 6 in ENU */
    real_t cos_half_delta;
    real_t sin_half_delta;
    real_t bias[3];      /* rad/s, body */
    real_t P[9];         /* (rad/s)^2: bias covariance (3x3, row-major) */
    /* rest detection */
    gnomon_robust_ahrs_lowpass3 rest_gyro_lp;
    real_t gyro_lp[3];   /* rad/s: its output */
    gnomon_robust_ahrs_lowpass3 rest_acc_lp;
    real_t rest_t;       /* s within the thresholds */
    gnomon_robust_ahrs_lowpass3 rest_mag_lp;  /* the magnetometer, body frame */
    real_t mag_body_lp[3];  /* its output */
    real_t rest_a0[3];   /* unit low-passed accelerometer when the candidacy began */
    real_t rest_m0[3];   /* the low-passed magnetometer then */
    real_t rest_q[4];    /* body then <- body now: the gyro (minus bias) since */
    bool rest;
    bool bias_at_limit;  /* a component of the bias at +-bias_clip */
    bool mag_body_ok;    /* mag_body_lp holds a sample */
    bool rest_m0_ok;     /* rest_m0 was taken */
    bool reset_done;     /* the first rest came (and reset the start-up's estimate) */
    bool heading_reset;  /* the next magnetometer sample sets the heading */
    /* inclination and bias in motion */
    gnomon_robust_ahrs_lowpass3 acc_lp;  /* m/s^2, frame I */
    real_t acc_rate;     /* rad/s: sine of the last correction angle / ts */
    int32_t bias_count;  /* accelerometer samples since the last bias update, mod k */
    gnomon_robust_ahrs_lowpass33 bias_R_lp;  /* R_6b */
    gnomon_robust_ahrs_lowpass2 bias_Rb_lp;  /* (R_6b b)_xy */
    /* magnetometer */
    real_t mag_sum[3];   /* sum R_6b (m - o) over the current block */
    int32_t mag_count;
    gnomon_robust_ahrs_lowpass2 mag_lp;  /* norm, dip (rad) of the mean field in frame 6 */
    real_t mag_ref_norm;  /* learned reference (0: none yet) */
    real_t mag_ref_dip;
    real_t mag_undisturbed_t;
    real_t mag_reject_t;
    bool mag_disturbed;
    real_t cand_norm;    /* a candidate new field, and how long it held in motion */
    real_t cand_dip;
    real_t cand_t;
    real_t k_mag_init;   /* running-mean gain at start (0 once over) */
    real_t k_mag_used;   /* heading gain of the last update (0 while rejected) */
    real_t mag_dis;      /* rad: the last heading disagreement */
    real_t p_head;       /* heading variance */
    real_t rot2;         /* integral of |w - b|^2 dt since the last heading update, rad^2/s */
    gnomon_robust_ahrs_hard_iron hard_iron;
    /* arrivals since the last gyro sample (not in the kernel's STATE: its rows) */
    real_t acc_in_sum[3];
    real_t mag_in_sum[3];
    int32_t acc_in_count;
    int32_t mag_in_count;
} gnomon_robust_ahrs_state;

/* flags returned by update_gyro (the kernel's bits) */
#define GNOMON_ROBUST_AHRS_ACC_SKIPPED 1
#define GNOMON_ROBUST_AHRS_MAG_SKIPPED 2
#define GNOMON_ROBUST_AHRS_GAP 4
#define GNOMON_ROBUST_AHRS_BIAS_AT_LIMIT 8
#define GNOMON_ROBUST_AHRS_BAD_GYRO 128 /* a non-finite gyro sample: nothing done */

bool gnomon_robust_ahrs_init(gnomon_robust_ahrs_state *s, gnomon_robust_ahrs_coefficients *c,
                             const gnomon_robust_ahrs_params *p, real_t ts_s, real_t ts_acc_s,
                             real_t ts_mag_s);
void gnomon_robust_ahrs_coefficients_from(gnomon_robust_ahrs_coefficients *c,
                                          const gnomon_robust_ahrs_params *p, real_t ts_s,
                                          real_t ts_acc_s, real_t ts_mag_s);
void gnomon_robust_ahrs_reset(gnomon_robust_ahrs_state *s, const gnomon_robust_ahrs_params *p);
void gnomon_robust_ahrs_update_acc(gnomon_robust_ahrs_state *s, const real_t acc[3]);
void gnomon_robust_ahrs_update_mag(gnomon_robust_ahrs_state *s, const real_t mag[3]);
int gnomon_robust_ahrs_update_gyro(gnomon_robust_ahrs_state *s,
                                   const gnomon_robust_ahrs_coefficients *c, real_t dt_s,
                                   const real_t gyro[3]);
void gnomon_robust_ahrs_get_quat(const gnomon_robust_ahrs_state *s, real_t q_nb[4]);
void gnomon_robust_ahrs_get_bias(const gnomon_robust_ahrs_state *s, real_t bias_rad_s[3]);

#ifdef __cplusplus
}
#endif

#endif /* GNOMON_ROBUST_AHRS_H */
