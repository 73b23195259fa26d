/* gnomon flight code: the explicit complementary filter (Mahony et al. 2008), 9-axis,
 * twin of gnomon.kernels.mahony (gnomon filter "mahony").
 *
 * Frames: the estimate is q_nb, ENU (x east, y north, z up) from the sensor (body) frame;
 * a resting accelerometer reads [0, 0, +g] in the body frame. Units: gyro rad/s,
 * accelerometer and magnetometer any unit (only their directions are used), times s.
 *
 * How to call it, at any rates:
 *   gnomon_mahony_init(&s, &params);            once
 *   gnomon_mahony_start(&s, &params, acc, mag);  once, from the first samples (TRIAD)
 *   then for every sample as it arrives:
 *     gnomon_mahony_update_acc(&s, acc);   an accelerometer sample
 *     gnomon_mahony_update_mag(&s, mag);   a magnetometer sample
 *     gnomon_mahony_update_gyro(&s, &params, dt_s, gyro);  a gyro sample: the step, with
 *         the accelerometer and magnetometer samples that arrived since the last gyro
 *         sample (their mean when several did); dt_s since the previous gyro sample.
 *   gnomon_mahony_get_quat(&s, q); gnomon_mahony_get_bias(&s, b);
 */
#ifndef GNOMON_MAHONY_H
#define GNOMON_MAHONY_H

#include "gnomon_real.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    real_t kp_acc_rad_s;  /* proportional gain of the accelerometer correction, rad/s */
    real_t kp_mag_rad_s;  /* proportional gain of the magnetometer correction, rad/s */
    real_t ki_rad_s2;     /* integral gain (gyro bias), rad/s^2 */
    bool mag_heading_only;  /* the magnetometer corrects the heading only */
    int32_t init_samples;   /* samples averaged for the initial attitude (by the caller) */
    real_t max_dt_s;      /* longer gyro intervals are gaps: gyro propagation only, s */
} gnomon_mahony_params;

typedef struct {
    real_t q[4];         /* q_nb [w, x, y, z] */
    real_t bias[3];      /* gyro bias, rad/s, body */
    real_t since_acc_s;  /* time since the accelerometer was last used, s */
    real_t since_mag_s;  /* time since the magnetometer was last used, s */
    real_t acc_sum[3];   /* accelerometer samples since the last gyro sample */
    real_t mag_sum[3];   /* magnetometer samples since the last gyro sample */
    int32_t acc_count;
    int32_t mag_count;
} gnomon_mahony_state;

/* flags returned by update_gyro */
#define GNOMON_MAHONY_ACC_SKIPPED 1
#define GNOMON_MAHONY_MAG_SKIPPED 2
#define GNOMON_MAHONY_GAP 4

void gnomon_mahony_init(gnomon_mahony_state *s, const gnomon_mahony_params *p);
bool gnomon_mahony_start(gnomon_mahony_state *s, const gnomon_mahony_params *p,
                         const real_t acc[3], const real_t *mag);
void gnomon_mahony_update_acc(gnomon_mahony_state *s, const real_t acc[3]);
void gnomon_mahony_update_mag(gnomon_mahony_state *s, const real_t mag[3]);
int gnomon_mahony_update_gyro(gnomon_mahony_state *s, const gnomon_mahony_params *p,
                              real_t dt_s, const real_t gyro[3]);
void gnomon_mahony_get_quat(const gnomon_mahony_state *s, real_t q_nb[4]);
void gnomon_mahony_get_bias(const gnomon_mahony_state *s, real_t bias_rad_s[3]);

#ifdef __cplusplus
}
#endif

#endif /* GNOMON_MAHONY_H */
