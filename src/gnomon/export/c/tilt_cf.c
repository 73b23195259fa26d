/* gnomon flight code: the 3D tilt complementary filter, twin of gnomon.kernels.tilt_cf
 * (_row: predict then correct_accel, and the start row _start_row) and of the start tilt
 * of gnomon.estimators.complementary (quat_from_accel). See tilt_cf.h for frames, units and
 * how to call it. */
#include "tilt_cf.h"

#include "gnomon_quat.h"

/* level attitude q_nb (yaw 0) from a specific force: roll atan2(a_y, a_z), pitch
 * atan2(-a_x, |(a_y, a_z)|) (complementary.quat_from_accel); the identity for zero */
static void quat_from_accel(const real_t a[3], real_t q[4])
{
    real_t hr = R(0.5) * GN_ATAN2(a[1], a[2]);
    real_t hp = R(0.5) * GN_ATAN2(-a[0], GN_SQRT(a[1] * a[1] + a[2] * a[2]));
    real_t cr = GN_COS(hr), sr = GN_SIN(hr), cp = GN_COS(hp), sp = GN_SIN(hp);
    q[0] = cp * cr;  /* quat_from_euler([roll, pitch, 0]) */
    q[1] = cp * sr;
    q[2] = sp * cr;
    q[3] = -(sp * sr);
}

void gnomon_tilt_cf_init(gnomon_tilt_cf_state *s, const gnomon_tilt_cf_params *p)
{
    (void)p;
    for (int i = 0; i < 4; ++i) {
        s->q[i] = i == 0 ? R(1.0) : R(0.0);
    }
    for (int i = 0; i < 3; ++i) {
        s->bias[i] = R(0.0);
        s->acc_in_sum[i] = R(0.0);
    }
    s->since_acc_s = R(0.0);
    s->acc_rejected = false;
    s->start_pending = true;
    s->started = false;
    s->acc_in_count = 0;
}

void gnomon_tilt_cf_start(gnomon_tilt_cf_state *s, const gnomon_tilt_cf_params *p,
                          const real_t acc[3])
{
    (void)p;
    quat_from_accel(acc, s->q);
    s->start_pending = true;
    s->started = true;
}

void gnomon_tilt_cf_update_acc(gnomon_tilt_cf_state *s, const real_t acc[3])
{
    if (!(GN_ISFINITE(acc[0]) && GN_ISFINITE(acc[1]) && GN_ISFINITE(acc[2]))) {
        return;  /* a broken sample is no sample */
    }
    for (int i = 0; i < 3; ++i) {
        s->acc_in_sum[i] += acc[i];
    }
    s->acc_in_count += 1;
}

/* gyro phase: q <- normalise(q (x) exp((w - b) dt)) */
static void predict(gnomon_tilt_cf_state *s, real_t dt, const real_t g[3])
{
    gn_exp_mul(s->q, (g[0] - s->bias[0]) * dt, (g[1] - s->bias[1]) * dt,
               (g[2] - s->bias[2]) * dt, true);
}

/* accelerometer phase (new_a false: no new sample in this row) */
static void correct_accel(gnomon_tilt_cf_state *s, const gnomon_tilt_cf_params *p, real_t dt,
                          bool new_a, const real_t a[3])
{
    s->acc_rejected = true;
    s->since_acc_s += dt;
    if (!new_a) {
        return;
    }
    dt = s->since_acc_s;  /* the correction covers the time since the previous sample */
    s->since_acc_s = R(0.0);
    real_t nf = GN_SQRT(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    real_t g = p->gravity_m_s2;
    if (!(nf > R(0.0)) ||
        (p->accel_rejection_rel > R(0.0) && GN_FABS(nf - g) > p->accel_rejection_rel * g)) {
        return;
    }
    s->acc_rejected = false;
    real_t mx = a[0] / nf, my = a[1] / nf, mz = a[2] / nf;
    real_t *q = s->q;
    real_t w = q[0], x = q[1], y = q[2], z = q[3];
    /* up in body: the third row of R_nb */
    real_t ux = R(2.0) * (x * z - w * y), uy = R(2.0) * (y * z + w * x);
    real_t uz = R(1.0) - R(2.0) * (x * x + y * y);
    real_t cx = my * uz - mz * uy, cy = mz * ux - mx * uz, cz = mx * uy - my * ux;
    real_t sn = GN_SQRT(cx * cx + cy * cy + cz * cz);
    if (sn > R(0.0)) {
        real_t k = GN_ATAN2(sn, mx * ux + my * uy + mz * uz) / sn;
        real_t ex = k * cx, ey = k * cy, ez = k * cz;
        real_t r2 = p->bias_gain_1_s2;
        if (r2 > R(0.0)) {
            s->bias[0] -= r2 * dt * ex;
            s->bias[1] -= r2 * dt * ey;
            s->bias[2] -= r2 * dt * ez;
        }
        real_t f = dt / (p->time_constant_s + dt);
        gn_exp_mul(q, f * ex, f * ey, f * ez, true);
    }
}

int gnomon_tilt_cf_update_gyro(gnomon_tilt_cf_state *s, const gnomon_tilt_cf_params *p,
                               real_t dt_s, const real_t gyro[3])
{
    bool new_a = s->acc_in_count > 0;
    real_t a[3] = {R(0.0), R(0.0), R(0.0)};
    for (int i = 0; i < 3; ++i) {
        if (new_a) {
            a[i] = s->acc_in_sum[i] / R(s->acc_in_count);
        }
        s->acc_in_sum[i] = R(0.0);
    }
    s->acc_in_count = 0;
    if (!(GN_ISFINITE(gyro[0]) && GN_ISFINITE(gyro[1]) && GN_ISFINITE(gyro[2]))) {
        return GNOMON_TILT_CF_BAD_GYRO;
    }
    if (s->start_pending) {  /* the start row: the start attitude as it is (_start_row) */
        if (!s->started) {
            if (!new_a) {
                return GNOMON_TILT_CF_ACC_REJECTED;  /* no tilt yet: still waiting */
            }
            quat_from_accel(a, s->q);
            s->started = true;
        }
        s->start_pending = false;
        s->acc_rejected = !(new_a && a[0] * a[0] + a[1] * a[1] + a[2] * a[2] > R(0.0));
    } else {
        predict(s, dt_s, gyro);
        correct_accel(s, p, dt_s, new_a, a);
    }
    return s->acc_rejected ? GNOMON_TILT_CF_ACC_REJECTED : 0;
}

void gnomon_tilt_cf_get_quat(const gnomon_tilt_cf_state *s, real_t q_nb[4])
{
    for (int i = 0; i < 4; ++i) {
        q_nb[i] = s->q[i];
    }
}

void gnomon_tilt_cf_get_bias(const gnomon_tilt_cf_state *s, real_t bias_rad_s[3])
{
    for (int i = 0; i < 3; ++i) {
        bias_rad_s[i] = s->bias[i];
    }
}
