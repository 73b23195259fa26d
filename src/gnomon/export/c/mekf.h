/* gnomon flight code: the spacecraft multiplicative EKF (Lefferts, Markley & Shuster 1982;
 * Markley & Crassidis 2014, ch. 6), twin of gnomon.kernels.mekf (gnomon filters "mekf",
 * "mekf-delayed", "mekf-spacecraft": one filter, three parameter sets).
 *
 * Frames: the estimate is q_ob, the orbital frame o (z to nadir, y along the negative orbit
 * normal) from the body frame b. Error state x = [theta (rad, body), gyro bias error
 * (rad/s), magnetometer bias error (nT; estimate_mag_bias), gyro scale error (1;
 * estimate_gyro_scale)]: 6, 9 or 12 states. Units: gyro w_ib_b rad/s (the body's rate
 * relative to inertial space, in b), w_io_o rad/s (the orbital frame's rate, in o; NULL:
 * [0, -orbital_rate_rad_s, 0]), the field model b_o in nT (in o), the measured field in
 * nT (any unit when its bias is not estimated), sun directions any length, times s.
 *
 * How to call it: one sample = one gyro sample and the measurements taken with it.
 *   gnomon_mekf_init(&s, &params, ring, ring_len);   once; ring: storage for
 *       delay_samples records when sun_substitute is "delayed" (else NULL, 0)
 *   gnomon_mekf_start(&s, q_ob);     once, the first attitude: the star tracker's
 *       (gnomon_mekf_star_q_ob) or TRIAD of sun and field (gnomon_mekf_triad)
 *   then for every sample, in this order:
 *     gnomon_mekf_update_gyro(&s, &params, dt_s, gyro, w_io_o);  the prediction over dt_s
 *         (with the previous gyro sample when gyro_sample is "previous"; gyro NULL: none)
 *     gnomon_mekf_update_mag(&s, &params, mag_b, b_o);       a magnetometer sample
 *     gnomon_mekf_update_sun(&s, &params, sun_b, sun_o);     the sun sensor; call it with
 *         NULL, NULL when it has no valid sample (eclipse): the delayed pair takes its place
 *     gnomon_mekf_correct(&s, &params);    the joint correction of the vectors (also done
 *         by update_star and by the next update_gyro)
 *     gnomon_mekf_update_star(&s, &params, q_ob, boresight_b);  a star-tracker attitude
 *   gnomon_mekf_get_quat(&s, q_ob); gnomon_mekf_get_bias(&s, b); gnomon_mekf_get_mag_bias;
 *   gnomon_mekf_get_gyro_scale.
 * Each update returns the GNOMON_MEKF_* bits of what it could not use. A sample with
 * dt_s <= 0 or dt_s > max_dt_s (a gap: prediction only) uses no measurement.
 */
#ifndef GNOMON_MEKF_H
#define GNOMON_MEKF_H

#include "gnomon_real.h"

#ifdef __cplusplus
extern "C" {
#endif

#define GNOMON_MEKF_NX 12 /* storage size of the error state */

typedef struct {
    real_t sigma_mag_rad;       /* direction noise of the magnetometer, rad */
    real_t mag_noise_nT;        /* magnetometer white noise (adds (it/|B|)^2), nT; 0: none */
    real_t sigma_sun_rad;       /* direction noise of the sun sensor, rad */
    real_t arw_rad_rt_s;        /* gyro angle random walk, rad/sqrt(s) */
    real_t bias_rw_rad_s_rt_s;  /* gyro bias random walk, rad/s/sqrt(s) */
    real_t sigma0_att_rad;      /* initial attitude std, rad */
    real_t sigma0_bias_rad_s;   /* initial gyro bias std, rad/s */
    bool estimate_mag_bias;     /* 3 magnetometer-bias states, nT */
    real_t sigma0_mag_bias_nT;  /* initial magnetometer bias std, nT */
    real_t mag_bias_rw_nT_rt_s; /* magnetometer bias random walk, nT/sqrt(s) */
    real_t sigma_mag_norm_nT;   /* noise of |B - bias| - |B_model| (bias estimated), nT; 0: none */
    bool estimate_gyro_scale;   /* 3 gyro scale-factor states */
    real_t sigma0_gyro_scale;   /* initial gyro scale std, 1 */
    real_t gyro_scale_rw_rt_s;  /* gyro scale random walk, 1/sqrt(s) */
    bool use_sun;               /* use the sun sensor (and its substitute) */
    int32_t substitute;         /* sun_substitute: 0 none, 1 delayed magnetometer pair */
    int32_t delay_samples;      /* M of the delayed pair, samples */
    real_t swing_gain;          /* the delayed pair's noise grows by it times the swing (rad) */
    bool use_star_tracker;      /* use star-tracker attitudes */
    real_t st_sigma_cross_rad;  /* star tracker noise across the boresight, rad */
    real_t st_sigma_about_rad;  /* star tracker noise about the boresight, rad */
    real_t st_latency_s;        /* an attitude stamped t is that of t - latency, s */
    real_t st_gate_chi2;        /* reject a star-tracker innovation chi2 above it; 0: never */
    bool previous_gyro;         /* gyro_sample "previous": the held sample propagates */
    bool exponential;           /* transition "exponential" (else first-order) */
    bool relinearise;           /* each vector about the attitude the ones before corrected */
    bool exp_correction;        /* correction "exponential" (else first-order) */
    real_t orbital_rate_rad_s;  /* mean motion n when no w_io_o is given, rad/s */
    real_t max_dt_s;            /* longer intervals are gaps: prediction only, s */
} gnomon_mekf_params;

/* one past sample of the delayed pair's tail (caller's storage, delay_samples of them) */
typedef struct {
    real_t mag_b[3]; /* its magnetometer sample (0: none) */
    real_t mag_o[3]; /* its field model */
    real_t q[4];     /* the estimate after it */
} gnomon_mekf_past;

typedef struct {
    real_t q[4];        /* q_ob [w, x, y, z] */
    real_t bias[3];     /* gyro bias, rad/s, b */
    real_t mag_bias[3]; /* magnetometer bias, nT, b (0 unless estimated) */
    real_t scale[3];    /* gyro scale factors, 1 (0 unless estimated) */
    real_t P[GNOMON_MEKF_NX][GNOMON_MEKF_NX]; /* error covariance (the first n rows in use) */
    real_t gyro_b[3];   /* the last gyro sample, rad/s (propagates when previous_gyro) */
    real_t w_io_o[3];   /* the last orbital rate, rad/s, o */
    int32_t n_seen;     /* samples joined the tail so far (counted up to delay_samples) */
    int32_t slot;       /* the tail's record of the sample in progress */
    /* the sample in progress */
    real_t w_ib[3];     /* its rate estimate, rad/s (the star tracker's latency) */
    real_t dx[GNOMON_MEKF_NX]; /* the correction not yet applied (joint update) */
    real_t old_mag_b[3], old_mag_o[3]; /* the delayed pair of this sample */
    bool has_old;       /* the tail held a pair delay_samples ago */
    bool pending;       /* dx holds a correction */
    int8_t phase;       /* 0: no sample; 1: no measurement used (first, gap); 2: open */
    int8_t n, i_mag, i_scale; /* states in use; first index of the mag bias, scale (-1) */
    gnomon_mekf_past *ring;   /* the tail (NULL without the delayed pair) */
    int32_t ring_len;
} gnomon_mekf_state;

/* bits returned by the updates: what was not used */
#define GNOMON_MEKF_MAG_UNUSABLE 1
#define GNOMON_MEKF_SUN_UNUSABLE 2
#define GNOMON_MEKF_GAP 4
#define GNOMON_MEKF_COAST 8
#define GNOMON_MEKF_STAR_UNUSED 16
#define GNOMON_MEKF_SUBSTITUTED 32 /* update_sun: the delayed pair took the sun's place */
#define GNOMON_MEKF_NOT_OPEN 64    /* a measurement outside an open sample: not used */
#define GNOMON_MEKF_BAD_GYRO 128   /* a non-finite gyro sample: the sample refused */

/* false (and nothing set) for a ring too short for the delayed pair */
bool gnomon_mekf_init(gnomon_mekf_state *s, const gnomon_mekf_params *p, gnomon_mekf_past *ring,
                      int32_t ring_len);
void gnomon_mekf_start(gnomon_mekf_state *s, const real_t q_ob[4]);
int gnomon_mekf_update_gyro(gnomon_mekf_state *s, const gnomon_mekf_params *p, real_t dt_s,
                            const real_t *gyro, const real_t *w_io_o);
int gnomon_mekf_update_mag(gnomon_mekf_state *s, const gnomon_mekf_params *p,
                           const real_t mag_b[3], const real_t mag_o[3]);
int gnomon_mekf_update_sun(gnomon_mekf_state *s, const gnomon_mekf_params *p,
                           const real_t *sun_b, const real_t *sun_o);
void gnomon_mekf_correct(gnomon_mekf_state *s, const gnomon_mekf_params *p);
int gnomon_mekf_update_star(gnomon_mekf_state *s, const gnomon_mekf_params *p,
                            const real_t q_ob[4], const real_t boresight_b[3]);
/* q_ob = q_io^-1 (x) q_ib: a star tracker's inertial attitude in the orbital frame */
void gnomon_mekf_star_q_ob(const real_t q_io[4], const real_t q_ib[4], real_t q_ob[4]);
/* q_ob by TRIAD of the sun (exact) and the field; false (q untouched) when degenerate */
bool gnomon_mekf_triad(const real_t sun_b[3], const real_t sun_o[3], const real_t mag_b[3],
                       const real_t mag_o[3], real_t q_ob[4]);
void gnomon_mekf_get_quat(const gnomon_mekf_state *s, real_t q_ob[4]);
void gnomon_mekf_get_bias(const gnomon_mekf_state *s, real_t bias_rad_s[3]);
void gnomon_mekf_get_mag_bias(const gnomon_mekf_state *s, real_t mag_bias_nT[3]);
void gnomon_mekf_get_gyro_scale(const gnomon_mekf_state *s, real_t scale[3]);

#ifdef __cplusplus
}
#endif

#endif /* GNOMON_MEKF_H */
