/* gnomon flight code: the error-state AHRS Kalman filter (seed 002), twin of
 * gnomon.kernels.eskf: its row step step_row (predict, reference_and_gates, bias_gate,
 * accel_lowpass, measure_r6 / measure_r3, correct, follow_correction; one_sensor and
 * correct_rows for a row with one sensor's sample), gain and joseph. See eskf.h for
 * frames, units and how to call it.
 *
 * The Kalman update is gain + joseph, twice: as the loops of gnomon.kernels.eskf (any r:
 * the rows of one sensor; r = 1, 2, 3), and for the full GNOMON_ESKF_R rows as the
 * straight-line function of eskf_unrolled.h, which tools/codegen_eskf.py writes from the
 * same trace of those loops as the Python kernel's eskf_unrolled.py. Both do the same
 * operations in the same order (the results are equal to the last bit; gnomon_count
 * counts exactly what gnomon.estimators.eskf.count_update_operations traces); the
 * straight-line one ran the update 1.5x (r = 6) to 1.9x (r = 3) faster here, for
 * 10 KB (r = 3) to 23 KB (r = 6) more code. GNOMON_ESKF_LOOPS defined (in gnomon_config.h
 * or -D): the loops alone, the smallest code. */
#include "eskf.h"

#include "gnomon_quat.h"
#ifndef GNOMON_ESKF_LOOPS
#include "eskf_unrolled.h"
#endif

#define GN_P(i, j) P[6 * (i) + (j)]

void gnomon_eskf_init(gnomon_eskf_state *s, const gnomon_eskf_params *p)
{
    for (int i = 0; i < 4; ++i) {
        s->q[i] = i == 0 ? R(1.0) : R(0.0);
    }
    real_t va = (R(0.5) * p->init_att_std) * (R(0.5) * p->init_att_std);
    real_t vb = p->init_bias_std * p->init_bias_std;
    for (int i = 0; i < 36; ++i) {
        s->P[i] = R(0.0);
    }
    for (int i = 0; i < 3; ++i) {
        s->bias[i] = R(0.0);
        s->acc_lp[i] = R(0.0);
        s->acc_sum[i] = R(0.0);
        s->mag_sum[i] = R(0.0);
        s->P[7 * i] = va;
        s->P[7 * (i + 3)] = vb;
    }
    /* no sample yet: an inclination of 60 deg (Eskf._init_state) */
    s->dip_s = -R(0.8660254037844386);
    s->dip_count = R(1.0);
    if (p->inclination_known) {
        s->dip_s = -GN_SIN(p->inclination);
    }
    s->dip_s = gn_clip(s->dip_s, GNOMON_ESKF_MAX_ABS_DIP);
    s->acc_lp_started = false;
    s->since_acc_s = R(0.0);
    s->acc_dev2 = R(0.0);
    s->b0_mag_uT = R(1e6);  /* 1 T, as Eskf without a magnetometer sample */
    s->acc_count = 0;
    s->mag_count = 0;
}

static real_t norm3(const real_t v[3])
{
    return GN_SQRT(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

bool gnomon_eskf_start(gnomon_eskf_state *s, const gnomon_eskf_params *p, int32_t n,
                       const real_t *acc, const real_t *mag)
{
    gnomon_eskf_init(s, p);
    real_t a_sum[3] = {R(0.0), R(0.0), R(0.0)}, m_sum[3] = {R(0.0), R(0.0), R(0.0)};
    real_t b0_sum = R(0.0), cos_sum = R(0.0);
    int32_t n_b0 = 0, n_ok = 0;
    for (int32_t k = 0; k < n; ++k) {
        const real_t *ak = acc + 3 * k, *mk = mag != 0 ? mag + 3 * k : 0;
        real_t na = norm3(ak);
        real_t nm = mk != 0 ? norm3(mk) : R(0.0);
        if (nm > R(0.0)) {
            b0_sum += nm;
            n_b0 += 1;
        }
        if (!(na > R(0.0) && nm > R(0.0))) {
            continue;  /* a dropout of either sensor: not a pair */
        }
        for (int i = 0; i < 3; ++i) {
            a_sum[i] += ak[i];
            m_sum[i] += mk[i];
        }
        cos_sum += (ak[0] * mk[0] + ak[1] * mk[1] + ak[2] * mk[2]) / (p->gravity * nm);
        n_ok += 1;
    }
    if (n_b0 > 0) {
        s->b0_mag_uT = b0_sum / R(n_b0);
    }
    bool ok = n_ok > 0;
    if (ok) {
        real_t a[3], m[3];
        for (int i = 0; i < 3; ++i) {
            a[i] = a_sum[i] / R(n_ok);
            m[i] = m_sum[i] / R(n_ok);
        }
        gn_attitude_from_acc_mag(a, m, s->q);
        s->dip_s = cos_sum / R(n_ok);
        s->dip_count = R(n_ok);
    }
    if (p->inclination_known) {
        s->dip_s = -GN_SIN(p->inclination);
        s->dip_count = R(n_ok > 1 ? n_ok : 1);
    }
    /* field along gravity: heading unobservable for now; keep H > 0 */
    s->dip_s = gn_clip(s->dip_s, GNOMON_ESKF_MAX_ABS_DIP);
    return ok;
}

void gnomon_eskf_update_acc(gnomon_eskf_state *s, const real_t acc[3])
{
    if (!(GN_ISFINITE(acc[0]) && GN_ISFINITE(acc[1]) && GN_ISFINITE(acc[2]))) {
        return;  /* a broken sample is no sample */
    }
    for (int i = 0; i < 3; ++i) {
        s->acc_sum[i] += acc[i];
    }
    s->acc_count += 1;
}

void gnomon_eskf_update_mag(gnomon_eskf_state *s, const real_t mag_uT[3])
{
    if (!(GN_ISFINITE(mag_uT[0]) && GN_ISFINITE(mag_uT[1]) && GN_ISFINITE(mag_uT[2]))) {
        return;
    }
    for (int i = 0; i < 3; ++i) {
        s->mag_sum[i] += mag_uT[i];
    }
    s->mag_count += 1;
}

/* ------------------------------------------------------------ phase 1: gyro prediction */
void gnomon_eskf_predict(gnomon_eskf_state *s, const gnomon_eskf_params *p, real_t dt,
                         const real_t gyro[3])
{
    real_t *P = s->P;
    real_t wx = gyro[0] - s->bias[0], wy = gyro[1] - s->bias[1], wz = gyro[2] - s->bias[2];
    gn_exp_mul(s->q, wx * dt, wy * dt, wz * dt, true);
    /* Phi P Phi^T = [T A^T + cU, U; U^T, P22], T = A P11 + c P21, U = A P12 + c P22 */
    real_t cc = -R(0.5) * dt;
    real_t A[9], T[9], U[9];
    A[0] = R(1.0);
    A[1] = wz * dt;
    A[2] = -wy * dt;
    A[3] = -wz * dt;
    A[4] = R(1.0);
    A[5] = wx * dt;
    A[6] = wy * dt;
    A[7] = -wx * dt;
    A[8] = R(1.0);
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            T[3 * i + j] = A[3 * i] * GN_P(0, j) + A[3 * i + 1] * GN_P(1, j)
                           + A[3 * i + 2] * GN_P(2, j) + cc * GN_P(3 + i, j);
            U[3 * i + j] = A[3 * i] * GN_P(0, 3 + j) + A[3 * i + 1] * GN_P(1, 3 + j)
                           + A[3 * i + 2] * GN_P(2, 3 + j) + cc * GN_P(3 + i, 3 + j);
        }
    }
    real_t qa = R(0.25) * p->var_gyro * dt;
    real_t qb = p->var_bias * dt;
    for (int i = 0; i < 3; ++i) {
        for (int j = i; j < 3; ++j) {
            real_t v = T[3 * i] * A[3 * j] + T[3 * i + 1] * A[3 * j + 1]
                       + T[3 * i + 2] * A[3 * j + 2] + cc * U[3 * i + j];
            if (i == j) {
                v = v + qa;
            }
            GN_P(i, j) = v;
            GN_P(j, i) = v;
        }
    }
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            GN_P(i, 3 + j) = U[3 * i + j];
            GN_P(3 + j, i) = U[3 * i + j];
        }
        GN_P(3 + i, 3 + i) = GN_P(3 + i, 3 + i) + qb;
    }
}

/* ------------------------------------------------------------ phase 2: accel + mag */
/* variance inflation 1 + (dev/gate)^2 for inv_gate = 1/gate (0: gating off, 1) */
static real_t gate_factor(real_t dev, real_t inv_gate)
{
    real_t u = dev * inv_gate;
    return R(1.0) + u * u;
}

/* v <- R(q) v, v <- R(q)^T v (gnomon.kernels.quat.rotate / rotate_inv), for a unit q */
static void rotate(const real_t q[4], const real_t v[3], real_t out[3])
{
    real_t w = q[0], x = q[1], y = q[2], z = q[3];
    out[0] = (R(1.0) - R(2.0) * (y * y + z * z)) * v[0] + R(2.0) * (x * y - w * z) * v[1]
             + R(2.0) * (x * z + w * y) * v[2];
    out[1] = R(2.0) * (x * y + w * z) * v[0] + (R(1.0) - R(2.0) * (x * x + z * z)) * v[1]
             + R(2.0) * (y * z - w * x) * v[2];
    out[2] = R(2.0) * (x * z - w * y) * v[0] + R(2.0) * (y * z + w * x) * v[1]
             + (R(1.0) - R(2.0) * (x * x + y * y)) * v[2];
}

static void rotate_inv(const real_t q[4], const real_t v[3], real_t out[3])
{
    real_t w = q[0], x = q[1], y = q[2], z = q[3];
    out[0] = (R(1.0) - R(2.0) * (y * y + z * z)) * v[0] + R(2.0) * (x * y + w * z) * v[1]
             + R(2.0) * (x * z - w * y) * v[2];
    out[1] = R(2.0) * (x * y - w * z) * v[0] + (R(1.0) - R(2.0) * (x * x + z * z)) * v[1]
             + R(2.0) * (y * z + w * x) * v[2];
    out[2] = R(2.0) * (x * z + w * y) * v[0] + R(2.0) * (y * z - w * x) * v[1]
             + (R(1.0) - R(2.0) * (x * x + y * y)) * v[2];
}

/* the variance gates and the inclination estimate for a row with both samples (a m/s^2,
 * m normalised; na, nm their norms): reference_and_gates; *fa, *fm the inflations */
static void reference_and_gates(gnomon_eskf_state *s, const gnomon_eskf_params *p,
                                const real_t a[3], const real_t m[3], real_t na, real_t nm,
                                real_t dt, real_t *fa, real_t *fm)
{
    real_t cos_am = (a[0] * m[0] + a[1] * m[1] + a[2] * m[2]) * p->inv_gravity / nm;
    *fa = gate_factor(GN_FABS(na - p->gravity), p->inv_gate_acc);
    *fm = gate_factor(gn_max(GN_FABS(nm - R(1.0)), GN_FABS(cos_am - s->dip_s)),
                      p->inv_gate_mag);
    if (p->dip_tau > R(0.0) && *fm < R(2.0) && *fa < R(2.0)) {
        s->dip_count += R(1.0);
        real_t w = dt * p->dip_rate;  /* max(1/count, dt/dip_tau) */
        if (w * s->dip_count < R(1.0)) {
            w = R(1.0) / s->dip_count;
        }
        s->dip_s = gn_clip(s->dip_s + w * (cos_am - s->dip_s), GNOMON_ESKF_MAX_ABS_DIP);
    }
}

/* the mean of (| |a| - g |)^2 (weight min(1, dt/bias_gate_tau)); true: hold the bias */
static bool bias_gate(gnomon_eskf_state *s, const gnomon_eskf_params *p, real_t na, real_t dt)
{
    if (p->bias_gate2 <= R(0.0)) {
        return false;
    }
    real_t dev = na - p->gravity;
    s->acc_dev2 += gn_min(R(1.0), dt * p->bias_gate_rate) * (dev * dev - s->acc_dev2);
    return s->acc_dev2 > p->bias_gate2;
}

/* the accelerometer low-passed in the computed navigation frame, back in body (a in
 * place); dt the time since the accelerometer's previous sample */
static void accel_lowpass(gnomon_eskf_state *s, const gnomon_eskf_params *p, real_t a[3],
                          real_t dt)
{
    real_t *lp = s->acc_lp;
    real_t w;
    if (s->acc_lp_started) {
        w = gn_min(R(1.0), dt * p->acc_lp_rate);
    } else {
        lp[0] = R(0.0);
        lp[1] = R(0.0);
        lp[2] = R(0.0);
        w = R(1.0);
    }
    real_t v[3];
    rotate(s->q, a, v);
    for (int i = 0; i < 3; ++i) {
        lp[i] += w * (v[i] - lp[i]);
    }
    s->acc_lp_started = true;
    rotate_inv(s->q, lp, a);
}

#if GNOMON_ESKF_R == 6
/* full model: y = [a - C_bn g_n; m - C_bn m_n], D1 = [2[a^x]; 2[m^x]], R diagonal */
static void measure_model(const real_t q[4], const gnomon_eskf_params *p, const real_t a[3],
                          const real_t m[3], real_t mag_h, real_t mag_z, real_t fa, real_t fm,
                          gnomon_eskf_measurement *out)
{
    real_t c[9];
    gn_dcm(q, c);
    real_t g = p->gravity;
    real_t ap[3] = {g * c[6], g * c[7], g * c[8]};
    real_t mp[3] = {mag_h * c[3] - mag_z * c[6], mag_h * c[4] - mag_z * c[7],
                    mag_h * c[5] - mag_z * c[8]};
    real_t *D1 = out->D1;
    for (int blk = 0; blk < 2; ++blk) {
        const real_t *v = blk == 0 ? ap : mp;
        const real_t *meas = blk == 0 ? a : m;
        real_t *d = D1 + 9 * blk;
        for (int i = 0; i < 3; ++i) {
            out->y[3 * blk + i] = meas[i] - v[i];
        }
        d[0] = R(0.0);             /* 2 [v x] */
        d[1] = -R(2.0) * v[2];
        d[2] = R(2.0) * v[1];
        d[3] = R(2.0) * v[2];
        d[4] = R(0.0);
        d[5] = -R(2.0) * v[0];
        d[6] = -R(2.0) * v[1];
        d[7] = R(2.0) * v[0];
        d[8] = R(0.0);
    }
    real_t ra = p->var_acc * fa, rm = p->var_mag * fm;
    for (int i = 0; i < 3; ++i) {
        out->Rd[i] = ra;
        out->Rd[3 + i] = rm;
    }
}
#else
/* reduced model: y = [a~_x/g, a~_y/g, m~_x/H] (a~ = C_nb a, m~ = C_nb m), D1 = D_n C_nb */
static void measure_model(const real_t q[4], const gnomon_eskf_params *p, const real_t a[3],
                          const real_t m[3], real_t mag_h, real_t mag_z, real_t fa, real_t fm,
                          gnomon_eskf_measurement *out)
{
    real_t c[9];
    gn_dcm(q, c);
    real_t ig = p->inv_gravity;
    real_t ih = R(1.0) / mag_h;
    out->y[0] = (c[0] * a[0] + c[1] * a[1] + c[2] * a[2]) * ig;
    out->y[1] = (c[3] * a[0] + c[4] * a[1] + c[5] * a[2]) * ig;
    out->y[2] = (c[0] * m[0] + c[1] * m[1] + c[2] * m[2]) * ih;
    real_t t2 = R(2.0) * mag_z * ih;
    real_t *D1 = out->D1;
    for (int j = 0; j < 3; ++j) {
        D1[j] = -R(2.0) * c[3 + j];
        D1[3 + j] = R(2.0) * c[j];
        D1[6 + j] = t2 * c[3 + j] + R(2.0) * c[6 + j];
    }
    real_t ra = p->var_acc * fa * ig * ig;
    out->Rd[0] = ra;
    out->Rd[1] = ra;
    out->Rd[2] = p->var_mag * fm * ih * ih;
}
#endif

/* a row with one sensor's sample (one_sensor and the bias gate of _one_sensor_correction):
 * that sensor's rows of the model (r6: three each; r3: the two tilt rows or the heading
 * row); the magnetometer's gate reads the field's vertical through the attitude
 * estimate, the inclination does not move */
static void measure_one_sensor(gnomon_eskf_state *s, const gnomon_eskf_params *p,
                               bool new_a, real_t a[3], real_t m[3], real_t na, real_t nm,
                               gnomon_eskf_measurement *out)
{
    real_t dip = s->dip_s;
    real_t mag_h = GN_SQRT(R(1.0) - dip * dip), mag_z = -dip;
    real_t fa, fm;
    out->hold = p->bias_gate2 > R(0.0) && s->acc_dev2 > p->bias_gate2;
    if (new_a) {
        out->hold = bias_gate(s, p, na, s->since_acc_s);
        fa = gate_factor(GN_FABS(na - p->gravity), p->inv_gate_acc);
        fm = R(1.0);
        if (p->acc_lp_tau > R(0.0)) {
            accel_lowpass(s, p, a, s->since_acc_s);
        }
        m[0] = R(0.0);
        m[1] = R(0.0);
        m[2] = R(0.0);
        s->since_acc_s = R(0.0);
    } else {
        real_t v[3];
        rotate(s->q, m, v);
        fa = R(1.0);
        fm = gate_factor(gn_max(GN_FABS(nm - R(1.0)), GN_FABS(v[2] / nm - dip)), p->inv_gate_mag);
        a[0] = R(0.0);
        a[1] = R(0.0);
        a[2] = R(0.0);
    }
    measure_model(s->q, p, a, m, mag_h, mag_z, fa, fm, out);
#if GNOMON_ESKF_R == 6
    int first = new_a ? 0 : 3, r = 3;
#else
    int first = new_a ? 0 : 2, r = new_a ? 2 : 1;
#endif
    for (int i = 0; i < r; ++i) {
        out->y[i] = out->y[first + i];
        out->Rd[i] = out->Rd[first + i];
        for (int j = 0; j < 3; ++j) {
            out->D1[3 * i + j] = out->D1[3 * (first + i) + j];
        }
    }
    out->r = r;
    out->follow = p->acc_lp_tau > R(0.0) && p->acc_lp_follow > R(0.0) && s->acc_lp_started;
    if (out->follow) {
        rotate_inv(s->q, s->acc_lp, out->a_body);
    }
}

int gnomon_eskf_measure(gnomon_eskf_state *s, const gnomon_eskf_params *p, real_t dt,
                        const real_t *acc, const real_t *mag_uT, gnomon_eskf_measurement *m)
{
    real_t a[3] = {R(0.0), R(0.0), R(0.0)}, mg[3] = {R(0.0), R(0.0), R(0.0)};
    real_t na = R(0.0), nm = R(0.0);
    m->r = 0;
    m->hold = false;
    m->follow = false;
    if (acc != 0 && GN_ISFINITE(acc[0]) && GN_ISFINITE(acc[1]) && GN_ISFINITE(acc[2])) {
        for (int i = 0; i < 3; ++i) {
            a[i] = acc[i];
        }
        na = norm3(a);
    }
    if (mag_uT != 0 && GN_ISFINITE(mag_uT[0]) && GN_ISFINITE(mag_uT[1])
        && GN_ISFINITE(mag_uT[2])) {
        real_t b0 = s->b0_mag_uT;
        for (int i = 0; i < 3; ++i) {
            mg[i] = mag_uT[i] / b0;  /* the magnetometer normalised by |B0| */
        }
        nm = norm3(mg);
    }
    s->since_acc_s += dt;
    bool new_a = na > R(0.0), new_m = nm > R(0.0);  /* false for a zero vector */
    if (!(new_a && new_m)) {
        if (new_a || new_m) {
            measure_one_sensor(s, p, new_a, a, mg, na, nm, m);
        }
        return GNOMON_ESKF_SKIPPED;
    }
    real_t fa, fm;
    reference_and_gates(s, p, a, mg, na, nm, dt, &fa, &fm);
    real_t mag_h = GN_SQRT(R(1.0) - s->dip_s * s->dip_s), mag_z = -s->dip_s;
    m->hold = bias_gate(s, p, na, s->since_acc_s);
    if (p->acc_lp_tau > R(0.0)) {
        accel_lowpass(s, p, a, s->since_acc_s);  /* a: the filtered reading, body */
    }
    s->since_acc_s = R(0.0);
    measure_model(s->q, p, a, mg, mag_h, mag_z, fa, fm, m);
    m->r = GNOMON_ESKF_R;
    m->follow = p->acc_lp_tau > R(0.0) && p->acc_lp_follow > R(0.0);
    for (int i = 0; i < 3; ++i) {
        m->a_body[i] = a[i];
    }
    return 0;
}

/* ------------------------------------------------------------ phase 3: Kalman correction */
/* gnomon.kernels.eskf.gain, loop for loop; S the LDL^T factors (S[i][j] = L_ij d_j below
 * the diagonal, 1/d_j on it), PDt = P D^T; both 6x6 row-major scratch */
static void gain(const real_t P[36], const real_t *D1, const real_t *Rd, int r, real_t *PDt,
                 real_t *S, real_t *K)
{
    for (int i = 0; i < 6; ++i) {
        for (int k = 0; k < r; ++k) {
            PDt[6 * i + k] = GN_P(i, 0) * D1[3 * k] + GN_P(i, 1) * D1[3 * k + 1]
                             + GN_P(i, 2) * D1[3 * k + 2];
        }
    }
    for (int k = 0; k < r; ++k) {
        for (int m = k; m < r; ++m) {
            real_t s = D1[3 * k] * PDt[m] + D1[3 * k + 1] * PDt[6 + m]
                       + D1[3 * k + 2] * PDt[12 + m];
            if (m == k) {
                s = s + Rd[k];
            }
            S[6 * m + k] = s;
        }
    }
    for (int j = 0; j < r; ++j) {
        real_t dj = S[7 * j];
        for (int k = 0; k < j; ++k) {
            dj = dj - S[6 * j + k] * S[6 * j + k] * S[7 * k];
        }
        S[7 * j] = R(1.0) / dj;
        for (int i = j + 1; i < r; ++i) {
            real_t s = S[6 * i + j];
            for (int k = 0; k < j; ++k) {
                s = s - S[6 * i + k] * S[6 * j + k] * S[7 * k];
            }
            S[6 * i + j] = s;
        }
    }
    for (int i = 0; i < 6; ++i) {
        real_t *Ki = K + 6 * i;
        for (int j = 0; j < r; ++j) {  /* forward: w_j = (p_j - sum_k<j w_k L_jk d_k) / d_j */
            real_t s = PDt[6 * i + j];
            for (int k = 0; k < j; ++k) {
                s = s - Ki[k] * S[6 * j + k];
            }
            Ki[j] = s * S[7 * j];
        }
        for (int j = r - 2; j >= 0; --j) {  /* back: k_j = w_j - sum_m>j k_m L_mj */
            real_t s = Ki[j + 1] * S[6 * (j + 1) + j];
            for (int m = j + 2; m < r; ++m) {
                s = s + Ki[m] * S[6 * m + j];
            }
            Ki[j] = Ki[j] - s * S[7 * j];
        }
    }
}

void gnomon_eskf_gain(const real_t P[36], const real_t *D1, const real_t *Rd, int r,
                      real_t K[36])
{
    real_t PDt[36], S[36];
    gain(P, D1, Rd, r, PDt, S, K);
}

/* gnomon.kernels.eskf.joseph, loop for loop: dx = K y and the Joseph covariance (upper
 * triangle into P); L 6x3, M and G 6x6 scratch */
static void joseph(real_t P[36], const real_t *D1, const real_t *Rd, const real_t *y,
                   const real_t *K, int r, real_t *L, real_t *M, real_t *G, real_t dx[6])
{
    for (int i = 0; i < 6; ++i) {
        const real_t *Ki = K + 6 * i;
        real_t s = Ki[0] * y[0];
        for (int k = 1; k < r; ++k) {
            s = s + Ki[k] * y[k];
        }
        dx[i] = s;
        for (int j = 0; j < 3; ++j) {
            s = Ki[0] * D1[j];
            for (int k = 1; k < r; ++k) {
                s = s + Ki[k] * D1[3 * k + j];
            }
            L[3 * i + j] = s;
        }
    }
    for (int i = 0; i < 6; ++i) {
        const real_t *Li = L + 3 * i;
        for (int j = 0; j < 3; ++j) {
            M[6 * i + j] = GN_P(i, j) - (Li[0] * GN_P(0, j) + Li[1] * GN_P(1, j)
                                         + Li[2] * GN_P(2, j));
        }
        for (int j = i > 3 ? i : 3; j < 6; ++j) {
            M[6 * i + j] = GN_P(i, j) - (Li[0] * GN_P(0, j) + Li[1] * GN_P(1, j)
                                         + Li[2] * GN_P(2, j));
        }
    }
    for (int i = 0; i < 6; ++i) {
        for (int k = 0; k < r; ++k) {
            G[6 * i + k] = K[6 * i + k] * Rd[k] - (M[6 * i] * D1[3 * k] + M[6 * i + 1] * D1[3 * k + 1]
                                                   + M[6 * i + 2] * D1[3 * k + 2]);
        }
    }
    for (int i = 0; i < 6; ++i) {
        for (int j = i; j < 6; ++j) {
            real_t s = G[6 * i] * K[6 * j];
            for (int k = 1; k < r; ++k) {
                s = s + G[6 * i + k] * K[6 * j + k];
            }
            GN_P(i, j) = M[6 * i + j] + s;
        }
    }
}

void gnomon_eskf_kalman_update(real_t P[36], const real_t *D1, const real_t *Rd,
                               const real_t *y, int r, real_t dx[6])
{
#ifndef GNOMON_ESKF_LOOPS
    if (r == GNOMON_ESKF_R) {
#if GNOMON_ESKF_R == 3
        gnomon_eskf_update_r3(P, D1, Rd, y, dx);
#else
        gnomon_eskf_update_r6(P, D1, Rd, y, dx);
#endif
        return;
    }
#endif
    real_t PDt[36], S[36], K[36], L[18], M[36], G[36];
    gain(P, D1, Rd, r, PDt, S, K);
    joseph(P, D1, Rd, y, K, r, L, M, G, dx);
    for (int i = 0; i < 6; ++i) {  /* the mirror: P symmetric */
        for (int j = i + 1; j < 6; ++j) {
            GN_P(j, i) = GN_P(i, j);
        }
    }
}

void gnomon_eskf_apply(gnomon_eskf_state *s, const gnomon_eskf_params *p,
                       const gnomon_eskf_measurement *m)
{
    if (m->r <= 0) {
        return;
    }
    real_t *P = s->P;
    real_t b[3] = {s->bias[0], s->bias[1], s->bias[2]};  /* bias_block */
    real_t pbb[6] = {GN_P(3, 3), GN_P(3, 4), GN_P(3, 5), GN_P(4, 4), GN_P(4, 5), GN_P(5, 5)};
    real_t dx[6];
    gnomon_eskf_kalman_update(P, m->D1, m->Rd, m->y, m->r, dx);
    /* inject: q <- normalise(q (x) [1, de]), b <- b + db within +-bias_limit */
    real_t one[4] = {R(1.0), dx[0], dx[1], dx[2]}, qn[4];
    gn_quat_mul(s->q, one, qn);
    real_t sc = R(1.0) / GN_SQRT(qn[0] * qn[0] + qn[1] * qn[1] + qn[2] * qn[2] + qn[3] * qn[3]);
    for (int i = 0; i < 4; ++i) {
        s->q[i] = qn[i] * sc;
    }
    for (int i = 0; i < 3; ++i) {
        s->bias[i] = gn_clip(s->bias[i] + dx[3 + i], p->bias_limit);
    }
    if (m->hold) {  /* hold_bias: the Schmidt update, the bias and its block put back */
        for (int i = 0; i < 3; ++i) {
            s->bias[i] = b[i];
        }
        GN_P(3, 3) = pbb[0];
        GN_P(4, 4) = pbb[3];
        GN_P(5, 5) = pbb[5];
        GN_P(3, 4) = GN_P(4, 3) = pbb[1];
        GN_P(3, 5) = GN_P(5, 3) = pbb[2];
        GN_P(4, 5) = GN_P(5, 4) = pbb[4];
    }
    if (m->follow) {  /* follow_correction: lp <- lp + lambda (C_nb a_body - lp) */
        real_t v[3];
        rotate(s->q, m->a_body, v);
        for (int i = 0; i < 3; ++i) {
            s->acc_lp[i] += p->acc_lp_follow * (v[i] - s->acc_lp[i]);
        }
    }
}

/* ------------------------------------------------------------ the row */
int gnomon_eskf_update_gyro(gnomon_eskf_state *s, const gnomon_eskf_params *p, real_t dt_s,
                            const real_t gyro[3])
{
    gnomon_eskf_measurement meas;
    return gnomon_eskf_update_gyro_measured(s, p, dt_s, gyro, &meas);
}

int gnomon_eskf_update_gyro_measured(gnomon_eskf_state *s, const gnomon_eskf_params *p,
                                     real_t dt_s, const real_t gyro[3],
                                     gnomon_eskf_measurement *meas)
{
    real_t a[3], m[3];
    bool new_a = s->acc_count > 0, new_m = s->mag_count > 0;
    for (int i = 0; i < 3; ++i) {
        a[i] = new_a ? s->acc_sum[i] / R(s->acc_count) : R(0.0);
        m[i] = new_m ? s->mag_sum[i] / R(s->mag_count) : R(0.0);
        s->acc_sum[i] = R(0.0);
        s->mag_sum[i] = R(0.0);
    }
    s->acc_count = 0;
    s->mag_count = 0;
    meas->r = 0;
    if (!(GN_ISFINITE(gyro[0]) && GN_ISFINITE(gyro[1]) && GN_ISFINITE(gyro[2]))) {
        return GNOMON_ESKF_BAD_GYRO;
    }
    gnomon_eskf_predict(s, p, dt_s, gyro);
    int flags = gnomon_eskf_measure(s, p, dt_s, new_a ? a : 0, new_m ? m : 0, meas);
    gnomon_eskf_apply(s, p, meas);
    real_t lim = p->bias_limit;
    if (GN_FABS(s->bias[0]) >= lim || GN_FABS(s->bias[1]) >= lim || GN_FABS(s->bias[2]) >= lim) {
        flags |= GNOMON_ESKF_AT_LIMIT;
    }
    return flags;
}

void gnomon_eskf_get_quat(const gnomon_eskf_state *s, real_t q_nb[4])
{
    for (int i = 0; i < 4; ++i) {
        q_nb[i] = s->q[i];
    }
}

void gnomon_eskf_get_bias(const gnomon_eskf_state *s, real_t bias_rad_s[3])
{
    for (int i = 0; i < 3; ++i) {
        bias_rad_s[i] = s->bias[i];
    }
}

void gnomon_eskf_get_cov(const gnomon_eskf_state *s, real_t P[36])
{
    for (int i = 0; i < 36; ++i) {
        P[i] = s->P[i];
    }
}
