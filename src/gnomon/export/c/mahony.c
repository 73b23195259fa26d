/* gnomon flight code: the explicit complementary filter, twin of gnomon.kernels.mahony
 * (its single-stream step, _row with the multi-rate bookkeeping and the exact forms).
 * See mahony.h for frames, units and how to call it. */
#include "mahony.h"

#include "gnomon_quat.h"

void gnomon_mahony_init(gnomon_mahony_state *s, const gnomon_mahony_params *p)
{
    (void)p;
    for (int i = 0; i < 4; ++i) {
        s->q[i] = i == 0 ? R(1.0) : R(0.0);
    }
    for (int i = 0; i < 3; ++i) {
        s->bias[i] = R(0.0);
        s->acc_sum[i] = R(0.0);
        s->mag_sum[i] = R(0.0);
    }
    s->since_acc_s = R(0.0);
    s->since_mag_s = R(0.0);
    s->acc_count = 0;
    s->mag_count = 0;
}

bool gnomon_mahony_start(gnomon_mahony_state *s, const gnomon_mahony_params *p,
                         const real_t acc[3], const real_t *mag)
{
    (void)p;
    return gn_attitude_from_acc_mag(acc, mag, s->q);
}

void gnomon_mahony_update_acc(gnomon_mahony_state *s, const real_t acc[3])
{
    if (!(GN_ISFINITE(acc[0]) && GN_ISFINITE(acc[1]) && GN_ISFINITE(acc[2]))) {
        return;  /* a broken sample is no sample */
    }
    for (int i = 0; i < 3; ++i) {
        s->acc_sum[i] += acc[i];
    }
    s->acc_count += 1;
}

void gnomon_mahony_update_mag(gnomon_mahony_state *s, const real_t mag[3])
{
    if (!(GN_ISFINITE(mag[0]) && GN_ISFINITE(mag[1]) && GN_ISFINITE(mag[2]))) {
        return;
    }
    for (int i = 0; i < 3; ++i) {
        s->mag_sum[i] += mag[i];
    }
    s->mag_count += 1;
}

/* e_acc = a/|a| x up_b (body), up_b the third row of R_nb; false for a zero vector */
static bool accel_error(const real_t c[9], const real_t a_in[3], real_t e[3])
{
    real_t na = GN_SQRT(a_in[0] * a_in[0] + a_in[1] * a_in[1] + a_in[2] * a_in[2]);
    real_t ia = na > R(0.0) ? R(1.0) / na : R(0.0);
    real_t ax = a_in[0] * ia, ay = a_in[1] * ia, az = a_in[2] * ia;
    real_t ux = c[6], uy = c[7], uz = c[8];
    e[0] = ay * uz - az * uy;
    e[1] = az * ux - ax * uz;
    e[2] = ax * uy - ay * ux;
    return na != R(0.0);
}

/* e_mag = m/|m| x R_nb^T ref, ref = [0, |h_xy|, h_z], h = R_nb m; with heading_only its
 * vertical part alone (along up); false for a zero vector */
static bool mag_error(const real_t c[9], const real_t m_in[3], bool heading_only, real_t f[3])
{
    real_t nm = GN_SQRT(m_in[0] * m_in[0] + m_in[1] * m_in[1] + m_in[2] * m_in[2]);
    real_t im = nm > R(0.0) ? R(1.0) / nm : R(0.0);
    real_t mx = m_in[0] * im, my = m_in[1] * im, mz = m_in[2] * im;
    real_t hx = c[0] * mx + c[1] * my + c[2] * mz;
    real_t hy = c[3] * mx + c[4] * my + c[5] * mz;
    real_t rn = GN_SQRT(hx * hx + hy * hy);
    real_t ux = c[6], uy = c[7], uz = c[8];
    if (heading_only) {
        real_t d = hx * rn;
        f[0] = d * ux;
        f[1] = d * uy;
        f[2] = d * uz;
    } else {
        real_t hz = ux * mx + uy * my + uz * mz;
        real_t n0 = hz * (hy - rn), n1 = -hx * hz, n2 = hx * rn;
        f[0] = c[0] * n0 + c[3] * n1 + ux * n2;
        f[1] = c[1] * n0 + c[4] * n1 + uy * n2;
        f[2] = c[2] * n0 + c[5] * n1 + uz * n2;
    }
    return nm != R(0.0);
}

int gnomon_mahony_update_gyro(gnomon_mahony_state *s, const gnomon_mahony_params *p,
                              real_t dt_s, const real_t gyro[3])
{
    real_t h = dt_s;
    bool new_a = s->acc_count > 0, new_m = s->mag_count > 0;
    real_t a[3] = {R(0.0), R(0.0), R(0.0)}, m[3] = {R(0.0), R(0.0), R(0.0)};
    for (int i = 0; i < 3; ++i) {
        if (new_a) {
            a[i] = s->acc_sum[i] / R(s->acc_count);
        }
        if (new_m) {
            m[i] = s->mag_sum[i] / R(s->mag_count);
        }
        s->acc_sum[i] = R(0.0);
        s->mag_sum[i] = R(0.0);
    }
    s->acc_count = 0;
    s->mag_count = 0;
    if (!(GN_ISFINITE(gyro[0]) && GN_ISFINITE(gyro[1]) && GN_ISFINITE(gyro[2]))) {
        return 128;  /* a broken gyro sample: nothing done */
    }
    if (h > p->max_dt_s) {  /* gap: gyro propagation only */
        gn_exp_mul(s->q, (gyro[0] - s->bias[0]) * h, (gyro[1] - s->bias[1]) * h,
                   (gyro[2] - s->bias[2]) * h, true);
        s->since_acc_s = R(0.0);
        s->since_mag_s = R(0.0);
        return GNOMON_MAHONY_GAP;
    }
    if (!(h > R(0.0))) {
        return 0;
    }
    /* each correction over the time since that sensor's previous sample */
    s->since_acc_s += h;
    s->since_mag_s += h;
    real_t ra = new_a ? (s->since_acc_s == h ? R(1.0) : gn_min(s->since_acc_s, p->max_dt_s) / h)
                      : R(0.0);
    real_t rm = new_m ? (s->since_mag_s == h ? R(1.0) : gn_min(s->since_mag_s, p->max_dt_s) / h)
                      : R(0.0);
    if (new_a) {
        s->since_acc_s = R(0.0);
    }
    if (new_m) {
        s->since_mag_s = R(0.0);
    }
    /* prediction with the gyro over (t[k-1], t[k]], then the correction at t[k] */
    gn_exp_mul(s->q, (gyro[0] - s->bias[0]) * h, (gyro[1] - s->bias[1]) * h,
               (gyro[2] - s->bias[2]) * h, false);
    real_t c[9];
    gn_dcm(s->q, c);
    real_t e[3], f[3];
    bool ok_a = accel_error(c, a, e);
    bool ok_m = mag_error(c, m, p->mag_heading_only, f);
    for (int i = 0; i < 3; ++i) {
        e[i] = e[i] * ra;
        f[i] = f[i] * rm;
        s->bias[i] -= p->ki_rad_s2 * (e[i] + f[i]) * h;
    }
    real_t ka = p->kp_acc_rad_s, km = p->kp_mag_rad_s;
    gn_exp_mul(s->q, (ka * e[0] + km * f[0]) * h, (ka * e[1] + km * f[1]) * h,
               (ka * e[2] + km * f[2]) * h, true);
    return (ok_a ? 0 : GNOMON_MAHONY_ACC_SKIPPED) | (ok_m ? 0 : GNOMON_MAHONY_MAG_SKIPPED);
}

void gnomon_mahony_get_quat(const gnomon_mahony_state *s, real_t q_nb[4])
{
    for (int i = 0; i < 4; ++i) {
        q_nb[i] = s->q[i];
    }
}

void gnomon_mahony_get_bias(const gnomon_mahony_state *s, real_t bias_rad_s[3])
{
    for (int i = 0; i < 3; ++i) {
        bias_rad_s[i] = s->bias[i];
    }
}
