/* gnomon flight code: the 3D tilt complementary filter of seed 004 (first order, with an
 * optional gyro-bias integral and acceleration rejection), 6-axis, twin of
 * gnomon.kernels.tilt_cf (gnomon filter "tilt-cf").
 *
 * Frames: the estimate is q_nb, ENU (x east, y north, z up) from the sensor (body) frame;
 * a resting accelerometer reads [0, 0, +g] in the body frame. Heading is not observed (it
 * only integrates the gyro; its start is 0): use the inclination. Units: gyro rad/s,
 * accelerometer m/s^2, times s. No magnetometer.
 *
 * Not in the C: gnomon's speed_compensation (removing the vehicle's acceleration with a
 * forward speed sensor, TiltCFParams.speed_compensation); `gnomon export c` refuses it.
 *
 * How to call it, at any rates:
 *   gnomon_tilt_cf_init(&s, &params);             once
 *   gnomon_tilt_cf_start(&s, &params, acc);       optional: the start tilt from an
 *       accelerometer vector (gnomon's run: the mean of the first init_samples samples);
 *       without it the first gyro sample starts from the accelerometer sample of its row
 *   then for every sample as it arrives:
 *     gnomon_tilt_cf_update_acc(&s, acc);   an accelerometer sample
 *     gnomon_tilt_cf_update_gyro(&s, &params, dt_s, gyro);  a gyro sample: the step, with
 *         the accelerometer samples that arrived since the last gyro sample (their mean
 *         when several did); dt_s since the previous gyro sample. The first call after
 *         init is the start row: it outputs the start attitude, nothing is integrated.
 *         Returns GNOMON_TILT_CF_ACC_REJECTED when the accelerometer was not used.
 *   gnomon_tilt_cf_get_quat(&s, q); gnomon_tilt_cf_get_bias(&s, b);
 *
 * Phases (gnomon.kernels.tilt_cf._row) in update_gyro: predict (the gyro:
 * q <- q (x) exp((w - b) dt)), then with a new accelerometer sample correct_accel (the
 * fraction h / (T + h) of the rotation taking the measured up direction onto the predicted
 * one, h the time since the accelerometer's previous sample, and the bias integral).
 */
#ifndef GNOMON_TILT_CF_H
#define GNOMON_TILT_CF_H

#include "gnomon_real.h"

#ifdef __cplusplus
extern "C" {
#endif

/* The parameters: gnomon's TiltCFParams field by field (but speed_compensation). */
typedef struct {
    real_t time_constant_s;      /* T: time constant of the accelerometer correction, s */
    real_t bias_gain_1_s2;       /* r2: gain of the gyro-bias integral, 1/s^2 (0: off) */
    real_t accel_rejection_rel;  /* skip the correction when ||a| - g| > this * g (0: off) */
    real_t gravity_m_s2;         /* gravity magnitude for the rejection, m/s^2 */
    int32_t init_samples;        /* samples averaged for the start tilt (by the caller) */
} gnomon_tilt_cf_params;

/* The state: the kernel's STATE field by field (the same names), then the start and the
 * samples that arrived since the last gyro sample. */
typedef struct {
    real_t q[4];         /* q_nb [w, x, y, z] */
    real_t bias[3];      /* gyro bias, rad/s, body */
    real_t since_acc_s;  /* time since the accelerometer's previous sample, s */
    bool acc_rejected;   /* the last row's accelerometer was not used */
    bool start_pending;  /* the next update_gyro is the start row */
    bool started;        /* a start tilt is set (gnomon_tilt_cf_start) */
    real_t acc_in_sum[3];
    int32_t acc_in_count;
} gnomon_tilt_cf_state;

/* flags returned by update_gyro */
#define GNOMON_TILT_CF_ACC_REJECTED 1
#define GNOMON_TILT_CF_BAD_GYRO 128 /* a non-finite gyro sample: nothing done */

void gnomon_tilt_cf_init(gnomon_tilt_cf_state *s, const gnomon_tilt_cf_params *p);
void gnomon_tilt_cf_start(gnomon_tilt_cf_state *s, const gnomon_tilt_cf_params *p,
                          const real_t acc[3]);
void gnomon_tilt_cf_update_acc(gnomon_tilt_cf_state *s, const real_t acc[3]);
int gnomon_tilt_cf_update_gyro(gnomon_tilt_cf_state *s, const gnomon_tilt_cf_params *p,
                               real_t dt_s, const real_t gyro[3]);
void gnomon_tilt_cf_get_quat(const gnomon_tilt_cf_state *s, real_t q_nb[4]);
void gnomon_tilt_cf_get_bias(const gnomon_tilt_cf_state *s, real_t bias_rad_s[3]);

#ifdef __cplusplus
}
#endif

#endif /* GNOMON_TILT_CF_H */
