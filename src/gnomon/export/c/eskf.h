/* gnomon flight code: the error-state quaternion Kalman filter of seed 002 (Bilous &
 * Nesterenko), full (r = 6) or reduced (r = 3) measurement, twin of gnomon.kernels.eskf
 * (gnomon filters "eskf-r6" and "eskf-r3"; GNOMON_ESKF_R in gnomon_config.h says which).
 *
 * Frames: the estimate is q_nb, ENU (x east, y north, z up) from the sensor (body) frame;
 * a resting accelerometer reads [0, 0, +g] in the body frame. Units: gyro rad/s,
 * accelerometer m/s^2, magnetometer uT (normalised inside by the reference magnitude
 * |B0| found at the start), times s. Error state [de; db]: de the vector part of the
 * body-frame error quaternion (true = estimate (x) [1, de]), db the gyro bias error.
 *
 * How to call it, at any rates:
 *   gnomon_eskf_init(&s, &params);              once
 *   gnomon_eskf_start(&s, &params, n, acc, mag);  once, from the first n accelerometer and
 *       magnetometer samples (those of the first init_time s; TRIAD, |B0|, the
 *       inclination), as gnomon's Eskf.prepare
 *   then for every sample as it arrives:
 *     gnomon_eskf_update_acc(&s, acc);     an accelerometer sample, m/s^2
 *     gnomon_eskf_update_mag(&s, mag);     a magnetometer sample, uT
 *     gnomon_eskf_update_gyro(&s, &params, dt_s, gyro);  a gyro sample: the step, with the
 *         accelerometer and magnetometer samples that arrived since the last gyro sample
 *         (their mean when several did); dt_s since the previous gyro sample. Both: the
 *         full correction; one of them: that sensor's rows of the model; none: prediction.
 *   gnomon_eskf_get_quat(&s, q); gnomon_eskf_get_bias(&s, b); gnomon_eskf_get_cov(&s, P);
 * update_gyro is predict + measure + apply (below); those phases, and the Kalman update
 * they share, can be called on their own (gnomon_run --phases times and counts them).
 */
#ifndef GNOMON_ESKF_H
#define GNOMON_ESKF_H

#include "gnomon_real.h"

#ifndef GNOMON_ESKF_R
#error "GNOMON_ESKF_R (3 or 6: the measurement rows) must be defined in gnomon_config.h"
#endif
#if GNOMON_ESKF_R != 3 && GNOMON_ESKF_R != 6
#error "GNOMON_ESKF_R must be 3 (eskf-r3) or 6 (eskf-r6)"
#endif

#ifdef __cplusplus
extern "C" {
#endif

/* |sin I| at most for the reference field (gnomon.kernels.eskf.MAX_ABS_DIP) */
#define GNOMON_ESKF_MAX_ABS_DIP R(0.999)

/* The coefficients of gnomon.kernels.eskf.Coefficients (derived once from EskfParams, by
 * the same names), then what the start reads. */
typedef struct {
    real_t var_gyro;        /* gyro white-noise density squared, (rad/s)^2/Hz */
    real_t var_bias;        /* gyro bias random walk squared, (rad/s)^2/s */
    real_t var_acc;         /* accelerometer noise variance per sample, (m/s^2)^2 */
    real_t var_mag;         /* magnetometer noise variance per sample, (of |B0|)^2 */
    real_t gravity;         /* g, m/s^2 */
    real_t dip_tau;         /* time constant of the inclination estimate, s (0: fixed) */
    real_t acc_lp_tau;      /* navigation-frame accelerometer low-pass, s (0: off) */
    real_t acc_lp_follow;   /* fraction of a correction the low-pass follows, 1 */
    real_t bias_gate2;      /* mean (| |a| - g |)^2 above which the bias is held, (m/s^2)^2 (0: off) */
    real_t bias_gate_rate;  /* 1 / the time constant of that mean, 1/s */
    real_t bias_limit;      /* bound on each component of the bias estimate, rad/s */
    real_t inv_gravity;     /* 1/g */
    real_t inv_gate_acc;    /* 1 / (| |a| - g | doubling the accelerometer variance) (0: off) */
    real_t inv_gate_mag;    /* 1 / (field deviation doubling the magnetometer variance) (0: off) */
    real_t dip_rate;        /* 1/dip_tau, 1/s */
    real_t acc_lp_rate;     /* 1/acc_lp_tau, 1/s */
    real_t init_att_std;    /* initial attitude error std per axis, rad */
    real_t init_bias_std;   /* initial gyro bias std per axis, rad/s */
    real_t init_time;       /* averaging window of the first samples for the start, s (by the caller) */
    bool inclination_known; /* the inclination is given (the paper's assumption), not estimated */
    real_t inclination;     /* magnetic inclination I, rad (tan I = Z/H), when known */
} gnomon_eskf_params;

/* The named fields of gnomon.kernels.eskf.STATE, |B0| and the samples since the last gyro
 * sample. */
typedef struct {
    real_t q[4];           /* q_nb [w, x, y, z] */
    real_t bias[3];        /* gyro bias estimate, rad/s, body */
    real_t P[36];          /* covariance of [de; db], 6x6 row-major (rad^2, (rad/s)^2) */
    real_t dip_s;          /* running mean of a.m/(g|m|) = -Z (normalised field) */
    real_t dip_count;      /* its weight, samples */
    real_t acc_lp[3];      /* low-passed accelerometer, navigation frame, m/s^2 */
    bool acc_lp_started;   /* acc_lp holds a value */
    real_t since_acc_s;    /* time since the accelerometer's previous sample, s */
    real_t acc_dev2;       /* mean of (| |a| - g |)^2, (m/s^2)^2: the bias gate */
    real_t b0_mag_uT;      /* reference field magnitude |B0|, uT (Eskf.b0_mag) */
    real_t acc_sum[3];     /* accelerometer samples since the last gyro sample, m/s^2 */
    real_t mag_sum[3];     /* magnetometer samples since the last gyro sample, uT */
    int32_t acc_count;
    int32_t mag_count;
} gnomon_eskf_state;

/* One measurement, ready to correct the state (gnomon_eskf_measure -> gnomon_eskf_apply). */
typedef struct {
    int32_t r;         /* rows (0: no correction; GNOMON_ESKF_R: both sensors) */
    real_t y[6];       /* measurement, first r entries (r6: residuals; r3: a_x/g, a_y/g, m_x/H) */
    real_t D1[18];     /* the attitude columns of D = [D1 0], r x 3 row-major */
    real_t Rd[6];      /* the diagonal of R */
    bool hold;         /* the bias gate is shut: the correction leaves the bias alone */
    bool follow;       /* the accelerometer low-pass follows the correction */
    real_t a_body[3];  /* the filtered accelerometer reading it follows, body, m/s^2 */
} gnomon_eskf_measurement;

/* flags returned by update_gyro (gnomon.kernels.eskf_sample) */
#define GNOMON_ESKF_SKIPPED 1    /* not both sensors had a usable sample */
#define GNOMON_ESKF_AT_LIMIT 2   /* a component of the bias estimate at bias_limit */
#define GNOMON_ESKF_BAD_GYRO 128 /* a non-finite gyro sample: nothing done */

void gnomon_eskf_init(gnomon_eskf_state *s, const gnomon_eskf_params *p);
/* Start from the first n samples (Eskf._init_state): acc (n x 3 row-major, m/s^2) and mag
 * (n x 3, uT) paired by row, a zero row a dropout (mag a null pointer: none). The attitude by
 * TRIAD on the means of the usable pairs, |B0| the mean magnitude of the magnetometer
 * rows, the inclination from the mean of a.m/(g|m|). Returns false (the identity, an
 * inclination of 60 deg) without a usable pair. */
bool gnomon_eskf_start(gnomon_eskf_state *s, const gnomon_eskf_params *p, int32_t n,
                       const real_t *acc, const real_t *mag);
void gnomon_eskf_update_acc(gnomon_eskf_state *s, const real_t acc[3]);
void gnomon_eskf_update_mag(gnomon_eskf_state *s, const real_t mag_uT[3]);
int gnomon_eskf_update_gyro(gnomon_eskf_state *s, const gnomon_eskf_params *p, real_t dt_s,
                            const real_t gyro[3]);
/* update_gyro that also gives the row's measurement (*meas: r rows, r = GNOMON_ESKF_R when
 * both sensors corrected the state; y, the innovation telemetry; r = 0 when nothing did) */
int gnomon_eskf_update_gyro_measured(gnomon_eskf_state *s, const gnomon_eskf_params *p,
                                     real_t dt_s, const real_t gyro[3],
                                     gnomon_eskf_measurement *meas);
void gnomon_eskf_get_quat(const gnomon_eskf_state *s, real_t q_nb[4]);
void gnomon_eskf_get_bias(const gnomon_eskf_state *s, real_t bias_rad_s[3]);
void gnomon_eskf_get_cov(const gnomon_eskf_state *s, real_t P[36]);

/* ---- the phases of update_gyro ---- */
/* the strapdown step q <- q (x) exp(w dt), P <- Phi P Phi^T + Q (gyro rad/s, finite) */
void gnomon_eskf_predict(gnomon_eskf_state *s, const gnomon_eskf_params *p, real_t dt_s,
                         const real_t gyro[3]);
/* after predict: the gates, the inclination, the low-pass and the measurement model for
 * the samples of this row (acc m/s^2, mag uT; a null pointer or a non-finite or zero
 * vector: no sample), into *m; returns the flags */
int gnomon_eskf_measure(gnomon_eskf_state *s, const gnomon_eskf_params *p, real_t dt_s,
                        const real_t *acc, const real_t *mag_uT, gnomon_eskf_measurement *m);
/* the correction by *m (nothing when m->r == 0): the Kalman update, the injection, the
 * bias held, the low-pass following */
void gnomon_eskf_apply(gnomon_eskf_state *s, const gnomon_eskf_params *p,
                       const gnomon_eskf_measurement *m);
/* the Kalman gain K = P D^T (D P D^T + R)^-1 for D = [D1 0] (r x 6; D1 r x 3 row-major, Rd
 * (r,) the diagonal of R), LDL^T without square roots: gnomon.kernels.eskf.gain; K 6 x r
 * in the first r columns of a 6x6 row-major array */
void gnomon_eskf_gain(const real_t P[36], const real_t *D1, const real_t *Rd, int r,
                      real_t K[36]);
/* the measurement update: gain, Joseph covariance (P updated, symmetric) and dx = K y:
 * gnomon.kernels.eskf.gain + joseph (eskf_unrolled.update_r3 / update_r6) */
void gnomon_eskf_kalman_update(real_t P[36], const real_t *D1, const real_t *Rd,
                               const real_t *y, int r, real_t dx[6]);

#ifdef __cplusplus
}
#endif

#endif /* GNOMON_ESKF_H */
