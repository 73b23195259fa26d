/* gnomon flight code: the robust decoupled AHRS, twin of gnomon.kernels.robust_ahrs (its
 * coefficients(), new_state() and the step robust_ahrs_step with q_nb as _row, phase by
 * phase, with the same arithmetic in the same order). See robust_ahrs.h for frames, units
 * and how to call it. */
#include "robust_ahrs.h"

#include "gnomon_quat.h"

#define RA_PI R(3.141592653589793)

/* ---------------------------------------------------------------- coefficients */

typedef gnomon_robust_ahrs_lp_t lp_t;
#define LPV(x) ((lp_t)(x))
#if defined(GNOMON_FLOAT) && !defined(GNOMON_COUNT_OPS) && !defined(GNOMON_ROBUST_AHRS_FLOAT_LOWPASS)
#define LP_SQRT(x) sqrt(x) /* the low-pass filters in double in a float build */
#define LP_TAN(x) tan(x)
#else
#define LP_SQRT(x) GN_SQRT(x)
#define LP_TAN(x) GN_TAN(x)
#endif

/* butter2 + LowPass: second-order Butterworth, cutoff sqrt(2) / (2 pi tau) (bilinear
 * transform); a cutoff at or above 0.45 fs gives the identity filter */
static void lowpass_coefficients(gnomon_robust_ahrs_lowpass *lp, real_t tau, real_t ts)
{
    lp_t tau_s = LPV(tau), ts_s = LPV(ts), pi = LPV(3.141592653589793);
    lp_t sqrt2 = LP_SQRT(LPV(2.0));
    lp->tau_s = tau_s;
    lp->ts_s = ts_s;
    lp->b0 = LPV(1.0);
    lp->b1 = LPV(0.0);
    lp->b2 = LPV(0.0);
    lp->a1 = LPV(0.0);
    lp->a2 = LPV(0.0);
    if (!(tau_s > LPV(0.0))) {
        return;  /* fc = inf */
    }
    lp_t fc = sqrt2 / (LPV(2.0) * pi * tau_s);
    if (fc * ts_s >= LPV(0.45)) {
        return;
    }
    lp_t c = LP_TAN(pi * fc * ts_s);
    lp_t d = c * c + sqrt2 * c + LPV(1.0);
    lp_t b0 = c * c / d;
    lp->b0 = b0;
    lp->b1 = LPV(2.0) * b0;
    lp->b2 = b0;
    lp->a1 = LPV(2.0) * (c * c - LPV(1.0)) / d;
    lp->a2 = (LPV(1.0) - sqrt2 * c + c * c) / d;
}

/* first-order filter gain 1 - exp(-ts / tau) (tau = 0: 1) */
static real_t gain(real_t tau_s, real_t ts_s)
{
    return tau_s <= R(0.0) ? R(1.0) : R(1.0) - GN_EXP(-ts_s / tau_s);
}

void gnomon_robust_ahrs_coefficients_from(gnomon_robust_ahrs_coefficients *c,
                                          const gnomon_robust_ahrs_params *p, real_t ts_s,
                                          real_t ts_acc_s, real_t ts_mag_s)
{
    real_t d2r = RA_PI / R(180.0);
    real_t ts_acc = ts_acc_s > R(0.0) ? ts_acc_s : ts_s;
    real_t ts_m = ts_mag_s > R(0.0) ? ts_mag_s : ts_s;
    real_t tsm = ts_m * R(p->mag_every);  /* the heading filter's interval */
    real_t ts_b = ts_acc * R(p->bias_every);  /* the bias filter's interval */
    /* bias process noise: the variance grows by (0.1 deg/s)^2 in bias_forgetting_s; the
     * measurement variances make the steady-state std the stated sigma */
    real_t v01 = R(0.1) * d2r;
    real_t bias_v = v01 * v01 * ts_b / p->bias_forgetting_s;
    real_t sm = p->bias_sigma_motion_deg_s * d2r, sr = p->bias_sigma_rest_deg_s * d2r;
    real_t pm = sm * sm, pr = sr * sr;
    real_t w_motion = pm * pm / bias_v + pm;
    real_t k_mag = gain(p->tau_mag_s, tsm);
    real_t r_head = p->tau_mag_s > R(0.0) ? p->tau_mag_s * p->tau_mag_s / tsm : R(1.0);
    real_t new_gyro = p->mag_new_min_gyro_deg_s * d2r;
    real_t x;

    c->ts_s = ts_s;
    c->ts_acc_s = ts_acc;
    c->max_dt_s = p->max_dt_s;
    c->rest_bias = p->rest_bias;
    lowpass_coefficients(&c->rest_lp, p->rest_tau_s, ts_s);
    lowpass_coefficients(&c->rest_acc_lp, p->rest_tau_s, ts_acc);
    x = p->rest_th_gyro_deg_s * d2r;
    c->rest_th_gyro2 = x * x;
    c->rest_th_acc2 = p->rest_th_acc_m_s2 * p->rest_th_acc_m_s2;
    c->rest_min_s = p->rest_min_s;
    c->rest_th_rate = p->rest_th_rate_deg_s * d2r;
    c->rest_min_large_s = p->rest_min_large_bias_s;
    lowpass_coefficients(&c->rest_mag_lp, p->rest_tau_s, ts_m);
    x = R(2.0) * GN_SIN(R(0.5) * p->rest_th_turn_deg * d2r);
    c->rest_th_turn2 = x * x;
    c->rest_reset = p->rest_reset;
    lowpass_coefficients(&c->acc_lp, p->tau_acc_s, ts_acc);
    c->motion_bias = p->motion_bias;
    c->bias_every = p->bias_every;
    lowpass_coefficients(&c->bias_lp, p->tau_acc_s, ts_b);
    x = p->bias_sigma_init_deg_s * d2r;
    c->bias_p0 = x * x;
    c->bias_v = bias_v;
    c->w_rest = pr * pr / bias_v + pr;
    c->w_motion = w_motion;
    c->w_vertical = w_motion / p->bias_vertical_forgetting;
    c->bias_clip = p->bias_clip_deg_s * d2r;
    c->huber = p->bias_huber_deg_s * d2r;
    c->mag_every = p->mag_every;
    c->ts_mag = tsm;
    c->hi_lambda = p->hard_iron_tau_s > R(0.0) ? GN_EXP(-tsm / p->hard_iron_tau_s) : R(0.0);
    c->hi_reg = p->hard_iron_reg;
    c->hi_gate = p->hard_iron_gate;
    c->mag_rejection = p->mag_rejection;
    lowpass_coefficients(&c->mag_lp, p->mag_current_tau_s, tsm);
    c->k_mag_ref = gain(p->mag_ref_tau_s, tsm);
    c->mag_norm_th = p->mag_norm_th;
    c->mag_dip_th = p->mag_dip_th_deg * d2r;
    c->mag_new_s = p->mag_new_s;
    c->mag_new_first_s = p->mag_new_first_s;
    c->mag_new_min_gyro2 = new_gyro * new_gyro;
    c->mag_min_undisturbed_s = p->mag_min_undisturbed_s;
    c->mag_max_reject_s = p->mag_max_reject_s;
    c->mag_reject_factor = p->mag_reject_factor;
    c->mag_heading_dis = p->mag_heading_dis_deg * d2r;
    c->soft_norm = p->mag_soft_norm > R(0.0) ? R(1.0) / (p->mag_soft_norm * p->mag_soft_norm)
                                             : R(0.0);
    x = p->mag_soft_dip_deg * d2r;
    c->soft_dip = p->mag_soft_dip_deg > R(0.0) ? R(1.0) / (x * x) : R(0.0);
    c->tau_mag_s = p->tau_mag_s;
    c->k_mag = k_mag;
    c->heading_kf = p->heading_kf;
    c->r_head = r_head;
    c->q_head = k_mag < R(1.0) ? r_head * k_mag * k_mag / (R(1.0) - k_mag) : R(1e12);
    c->q_rate = p->heading_rate_noise_s * p->heading_rate_noise_s;
    x = p->heading_bias_ref_deg_s * d2r;
    c->inv_bias_ref2 = p->heading_bias_ref_deg_s > R(0.0) ? R(1.0) / (x * x) : R(0.0);
    c->k_mag_bias = p->mag_bias_gain_per_s;
}

/* ---------------------------------------------------------------- state */

static void zero(real_t *v, int n)
{
    for (int i = 0; i < n; ++i) {
        v[i] = R(0.0);
    }
}

static void zero_lp(lp_t *v, int n)
{
    for (int i = 0; i < n; ++i) {
        v[i] = LPV(0.0);
    }
}

void gnomon_robust_ahrs_reset(gnomon_robust_ahrs_state *s, const gnomon_robust_ahrs_params *p)
{
    /* new_state: all zero but these */
    zero(s->q_gyr, 4);
    zero(s->q_acc, 4);
    s->q_gyr[0] = R(1.0);
    s->q_acc[0] = R(1.0);
    s->delta = R(0.0);
    s->cos_half_delta = R(1.0);
    s->sin_half_delta = R(0.0);
    zero(s->bias, 3);
    real_t sd = p->bias_sigma_init_deg_s * RA_PI / R(180.0);
    zero(s->P, 9);
    s->P[0] = s->P[4] = s->P[8] = sd * sd;
    zero_lp(s->rest_gyro_lp.z0, 3);
    zero_lp(s->rest_gyro_lp.z1, 3);
    s->rest_gyro_lp.n = 0;
    zero(s->gyro_lp, 3);
    zero_lp(s->rest_acc_lp.z0, 3);
    zero_lp(s->rest_acc_lp.z1, 3);
    s->rest_acc_lp.n = 0;
    s->rest_t = R(0.0);
    zero_lp(s->rest_mag_lp.z0, 3);
    zero_lp(s->rest_mag_lp.z1, 3);
    s->rest_mag_lp.n = 0;
    zero(s->mag_body_lp, 3);
    zero(s->rest_a0, 3);
    zero(s->rest_m0, 3);
    zero(s->rest_q, 4);
    s->rest_q[0] = R(1.0);
    s->rest = false;
    s->bias_at_limit = false;
    s->mag_body_ok = false;
    s->rest_m0_ok = false;
    s->reset_done = false;
    s->heading_reset = false;
    zero_lp(s->acc_lp.z0, 3);
    zero_lp(s->acc_lp.z1, 3);
    s->acc_lp.n = 0;
    s->acc_rate = R(0.0);
    s->bias_count = 0;
    zero_lp(s->bias_R_lp.z0, 9);
    zero_lp(s->bias_R_lp.z1, 9);
    s->bias_R_lp.n = 0;
    zero_lp(s->bias_Rb_lp.z0, 2);
    zero_lp(s->bias_Rb_lp.z1, 2);
    s->bias_Rb_lp.n = 0;
    zero(s->mag_sum, 3);
    s->mag_count = 0;
    zero_lp(s->mag_lp.z0, 2);
    zero_lp(s->mag_lp.z1, 2);
    s->mag_lp.n = 0;
    s->mag_ref_norm = R(0.0);
    s->mag_ref_dip = R(0.0);
    s->mag_undisturbed_t = R(0.0);
    s->mag_reject_t = p->mag_max_reject_s;
    s->mag_disturbed = true;
    s->cand_norm = R(-1.0);
    s->cand_dip = R(0.0);
    s->cand_t = R(0.0);
    s->k_mag_init = R(1.0);
    s->k_mag_used = R(0.0);
    s->mag_dis = R(0.0);
    s->p_head = R(1e6);
    s->rot2 = R(0.0);
    s->hard_iron.w = R(0.0);
    zero(s->hard_iron.S, 9);
    zero(s->hard_iron.rm, 3);
    zero(s->hard_iron.m, 3);
    s->hard_iron.mm = R(0.0);
    zero(s->hard_iron.o, 3);
    zero(s->hard_iron.block_m, 3);
    s->hard_iron.block_mm = R(0.0);
    zero(s->hard_iron.block_S, 9);
    zero(s->hard_iron.block_rm, 3);
    zero(s->acc_in_sum, 3);
    zero(s->mag_in_sum, 3);
    s->acc_in_count = 0;
    s->mag_in_count = 0;
}

bool gnomon_robust_ahrs_init(gnomon_robust_ahrs_state *s, gnomon_robust_ahrs_coefficients *c,
                             const gnomon_robust_ahrs_params *p, real_t ts_s, real_t ts_acc_s,
                             real_t ts_mag_s)
{
    bool ok = ts_s > R(0.0) && GN_ISFINITE(ts_s) && GN_ISFINITE(ts_acc_s) &&
              GN_ISFINITE(ts_mag_s);
    if (!ok) {
        ts_s = R(0.01);
    }
    gnomon_robust_ahrs_coefficients_from(c, p, ts_s, ts_acc_s, ts_mag_s);
    gnomon_robust_ahrs_reset(s, p);
    return ok;
}

void gnomon_robust_ahrs_update_acc(gnomon_robust_ahrs_state *s, const real_t acc[3])
{
    if (!(GN_ISFINITE(acc[0]) && GN_ISFINITE(acc[1]) && GN_ISFINITE(acc[2]))) {
        return;  /* a broken sample is no sample */
    }
    for (int i = 0; i < 3; ++i) {
        s->acc_in_sum[i] += acc[i];
    }
    s->acc_in_count += 1;
}

void gnomon_robust_ahrs_update_mag(gnomon_robust_ahrs_state *s, const real_t mag[3])
{
    if (!(GN_ISFINITE(mag[0]) && GN_ISFINITE(mag[1]) && GN_ISFINITE(mag[2]))) {
        return;
    }
    for (int i = 0; i < 3; ++i) {
        s->mag_in_sum[i] += mag[i];
    }
    s->mag_in_count += 1;
}

/* ---------------------------------------------------------------- 3x3 helpers
 * row-major real_t[9], sums left to right over the inner index (gnomon.kernels.linalg) */

static void mat3_vec(const real_t a[9], real_t x, real_t y, real_t z, real_t out[3])
{
    out[0] = a[0] * x + a[1] * y + a[2] * z;
    out[1] = a[3] * x + a[4] * y + a[5] * z;
    out[2] = a[6] * x + a[7] * y + a[8] * z;
}

static void mat3_tvec(const real_t a[9], real_t x, real_t y, real_t z, real_t out[3])
{
    out[0] = a[0] * x + a[3] * y + a[6] * z;
    out[1] = a[1] * x + a[4] * y + a[7] * z;
    out[2] = a[2] * x + a[5] * y + a[8] * z;
}

/* out = A B */
static void mat3_mul(const real_t a[9], const real_t b[9], real_t out[9])
{
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            out[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j];
        }
    }
}

/* out = A B^T */
static void mat3_mul_bt(const real_t a[9], const real_t b[9], real_t out[9])
{
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            out[3 * i + j] = a[3 * i] * b[3 * j] + a[3 * i + 1] * b[3 * j + 1] +
                             a[3 * i + 2] * b[3 * j + 2];
        }
    }
}

/* out = A^T B */
static void mat3_tmul(const real_t a[9], const real_t b[9], real_t out[9])
{
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            out[3 * i + j] = a[i] * b[j] + a[3 + i] * b[3 + j] + a[6 + i] * b[6 + j];
        }
    }
}

/* inverse by cofactors (linalg.inv3); returns the determinant (inv not meaningful at 0) */
static real_t inv3(const real_t m[9], real_t inv[9])
{
    real_t a = m[0], b = m[1], c = m[2], d = m[3], e = m[4], f = m[5], g = m[6], h = m[7],
           i = m[8];
    real_t c0 = e * i - f * h;
    real_t c1 = -(d * i - f * g);
    real_t c2 = d * h - e * g;
    real_t det = a * c0 + b * c1 + c * c2;
    real_t s = R(1.0) / det;
    inv[0] = c0 * s;
    inv[1] = -(b * i - c * h) * s;
    inv[2] = (b * f - c * e) * s;
    inv[3] = c1 * s;
    inv[4] = (a * i - c * g) * s;
    inv[5] = -(a * f - c * d) * s;
    inv[6] = c2 * s;
    inv[7] = -(a * h - b * g) * s;
    inv[8] = (a * e - b * d) * s;
    return det;
}

static real_t copysign_lim(real_t lim, real_t v)
{
    return v < R(0.0) ? -lim : lim;
}

/* ---------------------------------------------------------------- low-pass filters */

/* count one start-up sample: n, and whether the running mean is over (done) */
static int32_t lp_start(int32_t *fn, const gnomon_robust_ahrs_lowpass *lp, bool *done)
{
    int32_t n = *fn + 1;
    *done = LPV(n) * lp->ts_s >= lp->tau_s;
    *fn = *done ? -1 : n;
    return n;
}

/* `count` values x through the low-pass lp with state (z0, z1, *fn); y the outputs */
/* component i of a low-pass's delay lines set to its steady state for a constant input v */
static void lp_settle(lp_t *z0, lp_t *z1, int i, lp_t v, const gnomon_robust_ahrs_lowpass *lp)
{
    z0[i] = v * (LPV(1.0) - lp->b0);
    z1[i] = v * (lp->b2 - lp->a2);
}

static void lowpass(lp_t *z0, lp_t *z1, int32_t *fn, const real_t *x, int count,
                    const gnomon_robust_ahrs_lowpass *lp, real_t *y)
{
    if (*fn >= 0) {  /* start-up: the running mean, then its steady state */
        bool done;
        int32_t n = lp_start(fn, lp, &done);
        for (int i = 0; i < count; ++i) {
            z0[i] += LPV(x[i]);
            lp_t v = z0[i] / LPV(n);
            if (done) {
                lp_settle(z0, z1, i, v, lp);
            }
            y[i] = R(v);
        }
        return;
    }
    for (int i = 0; i < count; ++i) {  /* direct form II transposed */
        lp_t xi = LPV(x[i]);
        lp_t v = lp->b0 * xi + z0[i];
        z0[i] = lp->b1 * xi - lp->a1 * v + z1[i];
        z1[i] = lp->b2 * xi - lp->a2 * v;
        y[i] = R(v);
    }
}

/* delta (rad) and the half-angle cosine and sine the estimate is built from */
static void set_heading(gnomon_robust_ahrs_state *s, real_t d)
{
    s->delta = d;
    s->cos_half_delta = GN_COS(R(0.5) * d);
    s->sin_half_delta = GN_SIN(R(0.5) * d);
}

static real_t wrap(real_t a)
{
    if (a > RA_PI) {
        return a - R(2.0) * RA_PI;
    }
    if (a < -RA_PI) {
        return a + R(2.0) * RA_PI;
    }
    return a;
}

/* R(q) v (quat.rotate) */
static void rotate(const real_t q[4], const real_t v[3], real_t out[3])
{
    real_t c[9];
    gn_dcm(q, c);
    mat3_vec(c, v[0], v[1], v[2], out);
}

/* ---------------------------------------------------------------- 1. rest detection */

static void rest_gyro(gnomon_robust_ahrs_state *s, const gnomon_robust_ahrs_coefficients *c,
                      const real_t g[3])
{
    real_t l[3];
    lowpass(s->rest_gyro_lp.z0, s->rest_gyro_lp.z1, &s->rest_gyro_lp.n, g, 3, &c->rest_lp, l);
    s->gyro_lp[0] = l[0];
    s->gyro_lp[1] = l[1];
    s->gyro_lp[2] = l[2];
    real_t dx = g[0] - l[0], dy = g[1] - l[1], dz = g[2] - l[2];
    real_t big = gn_max(GN_FABS(l[0]), gn_max(GN_FABS(l[1]), GN_FABS(l[2])));
    if (dx * dx + dy * dy + dz * dz >= c->rest_th_gyro2 || big > c->bias_clip) {
        s->rest_t = R(0.0);
        s->rest = false;
    }
}

/* squared distance between the directions of two non-zero 3-vectors */
static real_t chord2(const real_t u[3], const real_t v[3])
{
    real_t nu = GN_SQRT(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
    real_t nv = GN_SQRT(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    real_t dx = u[0] / nu - v[0] / nv, dy = u[1] / nu - v[1] / nv, dz = u[2] / nu - v[2] / nv;
    return dx * dx + dy * dy + dz * dz;
}

/* a rest candidacy begins: keep the low-passed accelerometer l (unit) and magnetometer
 * and start the gyro's rotation rest_q at the identity */
static void rest_begin(gnomon_robust_ahrs_state *s, const real_t l[3])
{
    real_t n = GN_SQRT(l[0] * l[0] + l[1] * l[1] + l[2] * l[2]);
    for (int i = 0; i < 3; ++i) {
        s->rest_a0[i] = l[i] / n;
        s->rest_m0[i] = s->mag_body_lp[i];
    }
    s->rest_m0_ok = s->mag_body_ok;
    s->rest_q[0] = R(1.0);
    s->rest_q[1] = s->rest_q[2] = s->rest_q[3] = R(0.0);
}

/* during a candidacy: rest_q <- rest_q (x) exp((g - b) dt) */
static void rest_turn(gnomon_robust_ahrs_state *s, real_t dt, const real_t g[3])
{
    if (s->rest_t > R(0.0) && dt > R(0.0)) {
        gn_exp_mul(s->rest_q, (g[0] - s->bias[0]) * dt, (g[1] - s->bias[1]) * dt,
                   (g[2] - s->bias[2]) * dt, true);
    }
}

/* the gyro's rotation since the candidacy began would have turned the accelerometer's or
 * the magnetometer's (hard-iron offset removed) direction by twice rest_th_turn */
static bool gyro_says_turned(const gnomon_robust_ahrs_state *s,
                             const gnomon_robust_ahrs_coefficients *c)
{
    real_t Rq[9], pr[3], m[3];
    real_t big = R(4.0) * c->rest_th_turn2;
    gn_dcm(s->rest_q, Rq);
    mat3_tvec(Rq, s->rest_a0[0], s->rest_a0[1], s->rest_a0[2], pr);
    if (chord2(pr, s->rest_a0) >= big) {
        return true;
    }
    if (s->rest_m0_ok) {
        for (int i = 0; i < 3; ++i) {
            m[i] = s->rest_m0[i] - s->hard_iron.o[i];
        }
        if (m[0] * m[0] + m[1] * m[1] + m[2] * m[2] > R(0.0)) {
            mat3_tvec(Rq, m[0], m[1], m[2], pr);
            return chord2(pr, m) >= big;
        }
    }
    return false;
}

/* the first rest, while the heading is still starting (k_mag_init not 0): the accelerometer
 * low-pass in frame I restarts settled at the rest's low-passed force l (body; the
 * inclination that follows turns q_acc to it), and the next magnetometer sample sets the
 * heading (heading_reset); a first rest after the start-up changes nothing */
static void first_rest_reset(gnomon_robust_ahrs_state *s,
                             const gnomon_robust_ahrs_coefficients *c, const real_t l[3])
{
    real_t ia[3];
    s->reset_done = true;
    if (s->k_mag_init == R(0.0)) {
        return;
    }
    rotate(s->q_gyr, l, ia);
    for (int i = 0; i < 3; ++i) {
        lp_settle(s->acc_lp.z0, s->acc_lp.z1, i, LPV(ia[i]), &c->acc_lp);
    }
    s->acc_lp.n = -1;
    s->heading_reset = true;
}

/* delta set to the heading, in frame 6 (Rm = R_6b), of the low-passed magnetometer
 * (hard-iron offset removed): the first rest's heading */
static void heading_reset(gnomon_robust_ahrs_state *s, const real_t Rm[9])
{
    real_t m[3], e[3];
    s->heading_reset = false;
    for (int i = 0; i < 3; ++i) {
        m[i] = s->mag_body_lp[i] - s->hard_iron.o[i];
    }
    mat3_vec(Rm, m[0], m[1], m[2], e);
    if (e[0] * e[0] + e[1] * e[1] > R(0.0)) {
        set_heading(s, GN_ATAN2(e[0], e[1]));
    }
}

static void rest_acc(gnomon_robust_ahrs_state *s, const gnomon_robust_ahrs_coefficients *c,
                     const real_t a[3])
{
    real_t l[3];
    lowpass(s->rest_acc_lp.z0, s->rest_acc_lp.z1, &s->rest_acc_lp.n, a, 3, &c->rest_acc_lp, l);
    real_t dx = a[0] - l[0], dy = a[1] - l[1], dz = a[2] - l[2];
    if (dx * dx + dy * dy + dz * dz >= c->rest_th_acc2) {
        s->rest_t = R(0.0);
        s->rest = false;
        return;
    }
    if (s->rest_t == R(0.0)) {
        rest_begin(s, l);
    } else if (c->rest_th_turn2 > R(0.0) && chord2(l, s->rest_a0) >= c->rest_th_turn2) {
        s->rest = false;  /* the direction turned: not rest, a new candidacy from here */
        s->rest_t = R(0.0);
        rest_begin(s, l);
    }
    s->rest_t += c->ts_acc_s;
    if (s->rest_t >= c->rest_min_s && !s->rest) {
        const real_t *gl = s->gyro_lp, *b = s->bias;
        real_t far = gn_max(GN_FABS(gl[0] - b[0]),
                            gn_max(GN_FABS(gl[1] - b[1]), GN_FABS(gl[2] - b[2])));
        if (far <= c->rest_th_rate || (s->rest_t >= c->rest_min_large_s && (
                c->rest_th_turn2 == R(0.0) || gyro_says_turned(s, c)))) {
            s->rest = true;
            if (c->rest_reset && !s->reset_done) {
                first_rest_reset(s, c, l);
            }
        }
    }
}

/* the magnetometer part: low-pass the field in the body frame; a direction farther than
 * rest_th_turn from the candidacy's first ends the rest and the candidacy */
static void rest_mag(gnomon_robust_ahrs_state *s, const gnomon_robust_ahrs_coefficients *c,
                     const real_t m[3])
{
    real_t l[3];
    lowpass(s->rest_mag_lp.z0, s->rest_mag_lp.z1, &s->rest_mag_lp.n, m, 3, &c->rest_mag_lp, l);
    s->mag_body_lp[0] = l[0];
    s->mag_body_lp[1] = l[1];
    s->mag_body_lp[2] = l[2];
    s->mag_body_ok = true;
    if (s->rest_t > R(0.0) && s->rest_m0_ok && c->rest_th_turn2 > R(0.0)
            && chord2(l, s->rest_m0) >= c->rest_th_turn2) {
        s->rest_t = R(0.0);
        s->rest = false;
    }
}

/* ---------------------------------------------------------------- 2. strapdown */

static void strapdown(gnomon_robust_ahrs_state *s, real_t dt, const real_t g[3])
{
    if (dt > R(0.0)) {
        real_t rx = (g[0] - s->bias[0]) * dt;
        real_t ry = (g[1] - s->bias[1]) * dt;
        real_t rz = (g[2] - s->bias[2]) * dt;
        real_t th2 = rx * rx + ry * ry + rz * rz;
        s->rot2 += th2 / dt;
        if (th2 > R(0.0)) {
            gn_exp_mul(s->q_gyr, rx, ry, rz, true);
        }
    }
}

/* ---------------------------------------------------------------- 3. inclination */

/* returns whether the filtered force is non-zero; f = its normalised x, y in frame 6
 * before the correction */
static bool inclination(gnomon_robust_ahrs_state *s, const gnomon_robust_ahrs_coefficients *c,
                        const real_t a[3], real_t f[2])
{
    real_t ia[3], l[3], fv[3];
    rotate(s->q_gyr, a, ia);
    lowpass(s->acc_lp.z0, s->acc_lp.z1, &s->acc_lp.n, ia, 3, &c->acc_lp, l);
    real_t *q = s->q_acc;
    rotate(q, l, fv);
    real_t fx = fv[0], fy = fv[1], fz = fv[2];
    real_t nf = GN_SQRT(fx * fx + fy * fy + fz * fz);
    f[0] = R(0.0);
    f[1] = R(0.0);
    if (!(nf > R(0.0))) {
        return false;
    }
    fx = fx / nf;
    fy = fy / nf;
    fz = fz / nf;
    /* the rotation taking f onto up [0, 0, 1], applied on the left of q_acc */
    real_t cw = GN_SQRT(gn_max(R(0.5) * (fz + R(1.0)), R(0.0)));
    real_t pq[4];
    if (cw > R(1e-6)) {
        pq[0] = cw;
        pq[1] = R(0.5) * fy / cw;
        pq[2] = R(-0.5) * fx / cw;
    } else {
        pq[0] = R(0.0);
        pq[1] = R(1.0);
        pq[2] = R(0.0);
    }
    pq[3] = R(0.0);
    real_t n[4];
    gn_quat_mul(pq, q, n);
    real_t k = R(1.0) / GN_SQRT(n[0] * n[0] + n[1] * n[1] + n[2] * n[2] + n[3] * n[3]);
    for (int i = 0; i < 4; ++i) {
        q[i] = n[i] * k;
    }
    s->acc_rate = GN_SQRT(fx * fx + fy * fy) / c->ts_acc_s;  /* sin(correction angle) / ts */
    f[0] = fx;
    f[1] = fy;
    return true;
}

/* ---------------------------------------------------------------- 4. gyro bias */

/* Kalman update of the bias with the innovation e = y - H b, H (row-major 9), diagonal
 * measurement variances w, Huber weights beyond ei (linalg-style, as the kernel) */
static void bias_update(gnomon_robust_ahrs_state *s, const gnomon_robust_ahrs_coefficients *c,
                        const real_t H[9], const real_t e[3], real_t w0, real_t w1, real_t w2,
                        real_t ei)
{
    real_t lim = c->bias_clip;
    real_t a0 = GN_FABS(e[0]), a1 = GN_FABS(e[1]), a2 = GN_FABS(e[2]);
    if (a0 > ei) {
        w0 *= a0 / ei;
    }
    if (a1 > ei) {
        w1 *= a1 / ei;
    }
    if (a2 > ei) {
        w2 *= a2 / ei;
    }
    real_t P[9], PHt[9], S[9], r[9], K[9], KHP[9];
    for (int i = 0; i < 9; ++i) {
        P[i] = s->P[i];
    }
    mat3_mul_bt(P, H, PHt);
    mat3_mul(H, PHt, S);
    S[0] = S[0] + w0;
    S[4] = S[4] + w1;
    S[8] = S[8] + w2;
    inv3(S, r);
    mat3_mul(PHt, r, K);
    bool at = false;
    for (int i = 0; i < 3; ++i) {
        real_t v = s->bias[i] + K[3 * i] * e[0] + K[3 * i + 1] * e[1] + K[3 * i + 2] * e[2];
        if (GN_FABS(v) >= lim) {
            v = copysign_lim(lim, v);
            at = true;
        }
        s->bias[i] = v;
    }
    s->bias_at_limit = at;
    mat3_mul_bt(K, PHt, KHP);
    for (int i = 0; i < 9; ++i) {
        s->P[i] = P[i] - KHP[i];
    }
    for (int i = 0; i < 3; ++i) {  /* symmetrise */
        for (int j = i + 1; j < 3; ++j) {
            real_t m = R(0.5) * (s->P[3 * i + j] + s->P[3 * j + i]);
            s->P[3 * i + j] = m;
            s->P[3 * j + i] = m;
        }
    }
}

/* the bias filter on every bias_every-th accelerometer sample; R = R_6b after the
 * inclination correction f (have_f false: none) */
static void bias_kf(gnomon_robust_ahrs_state *s, const gnomon_robust_ahrs_coefficients *c,
                    const real_t Rm[9], const real_t f[2], bool have_f)
{
    bool run = s->bias_count == 0;
    s->bias_count = (s->bias_count + 1) % c->bias_every;
    if (!(run && (c->rest_bias || c->motion_bias))) {
        return;
    }
    real_t b0 = s->bias[0], b1 = s->bias[1], b2 = s->bias[2];
    real_t rb[3], H[9], rbl[2];
    mat3_vec(Rm, b0, b1, b2, rb);
    lowpass(s->bias_R_lp.z0, s->bias_R_lp.z1, &s->bias_R_lp.n, Rm, 9, &c->bias_lp, H);
    lowpass(s->bias_Rb_lp.z0, s->bias_Rb_lp.z1, &s->bias_Rb_lp.n, rb, 2, &c->bias_lp, rbl);
    for (int i = 0; i < 3; ++i) {
        if (s->P[4 * i] < c->bias_p0) {
            s->P[4 * i] += c->bias_v;
        }
    }
    if (c->rest_bias && s->rest) {
        real_t I[9], e[3];  /* H = I */
        for (int i = 0; i < 9; ++i) {
            I[i] = i % 4 == 0 ? R(1.0) : R(0.0);
        }
        e[0] = s->gyro_lp[0] - b0;
        e[1] = s->gyro_lp[1] - b1;
        e[2] = s->gyro_lp[2] - b2;
        bias_update(s, c, I, e, c->w_rest, c->w_rest, c->w_rest, c->bias_clip);
    } else if (c->motion_bias && have_f) {
        real_t hb[3], e[3];
        mat3_vec(H, b0, b1, b2, hb);
        e[0] = -f[1] / c->ts_acc_s + rbl[0] - hb[0];
        e[1] = f[0] / c->ts_acc_s + rbl[1] - hb[1];
        e[2] = -hb[2];
        bias_update(s, c, H, e, c->w_motion, c->w_motion, c->w_vertical, c->huber);
    }
}

/* ---------------------------------------------------------------- 5. magnetometer */

/* add the field (offset removed) seen in frame 6 to the block sum, the raw field to the
 * hard-iron block sums; returns whether the block is complete */
static bool mag_accumulate(gnomon_robust_ahrs_state *s, const gnomon_robust_ahrs_coefficients *c,
                           const real_t Rm[9], real_t mx, real_t my, real_t mz)
{
    gnomon_robust_ahrs_hard_iron *hi = &s->hard_iron;
    if (c->hi_lambda > R(0.0)) {
        hi->block_m[0] += mx;
        hi->block_m[1] += my;
        hi->block_m[2] += mz;
        hi->block_mm += mx * mx + my * my + mz * mz;
        real_t r[3];
        mat3_vec(Rm, mx, my, mz, r);
        for (int i = 0; i < 3; ++i) {
            hi->block_rm[i] += r[i];
        }
        for (int i = 0; i < 9; ++i) {
            hi->block_S[i] += Rm[i];
        }
        mx -= hi->o[0];
        my -= hi->o[1];
        mz -= hi->o[2];
    }
    real_t e[3];
    mat3_vec(Rm, mx, my, mz, e);
    s->mag_sum[0] += e[0];
    s->mag_sum[1] += e[1];
    s->mag_sum[2] += e[2];
    s->mag_count += 1;
    return s->mag_count >= c->mag_every || s->k_mag_init == R(1.0);
}

/* fold the block of cnt samples into the weighted sums (sum R and sum R m summed sample by
 * sample, each with its own R_6b), solve for the offset o (body) */
static void hard_iron(gnomon_robust_ahrs_state *s, const gnomon_robust_ahrs_coefficients *c,
                      int32_t cnt)
{
    gnomon_robust_ahrs_hard_iron *hi = &s->hard_iron;
    real_t lam = c->hi_lambda, rc = R(cnt);
    hi->w = lam * hi->w + rc;
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            hi->S[3 * i + j] = lam * hi->S[3 * i + j] + hi->block_S[3 * i + j];
            hi->block_S[3 * i + j] = R(0.0);
        }
        hi->rm[i] = lam * hi->rm[i] + hi->block_rm[i];
        hi->block_rm[i] = R(0.0);
        hi->m[i] = lam * hi->m[i] + hi->block_m[i];
        hi->block_m[i] = R(0.0);
    }
    hi->mm = lam * hi->mm + hi->block_mm;
    hi->block_mm = R(0.0);
    real_t w = hi->w;
    const real_t *S = hi->S, *rm = hi->rm, *m = hi->m;
    real_t StS[9], A[9], a[9];
    mat3_tmul(S, S, StS);
    real_t d = w * w * (R(1.0) + c->hi_reg);
    for (int i = 0; i < 9; ++i) {
        A[i] = -StS[i];
    }
    A[0] = d - StS[0];
    A[4] = d - StS[4];
    A[8] = d - StS[8];
    if (inv3(A, a) <= R(0.0)) {
        return;
    }
    real_t sr[3], o[3], so[3], h[3];
    mat3_tvec(S, rm[0], rm[1], rm[2], sr);
    mat3_vec(a, w * m[0] - sr[0], w * m[1] - sr[1], w * m[2] - sr[2], o);
    mat3_vec(S, o[0], o[1], o[2], so);
    for (int i = 0; i < 3; ++i) {
        h[i] = (rm[i] - so[i]) / w;
    }
    /* residual energy of the fit with the offset (e1) and without it (e0) */
    real_t e0 = hi->mm - (rm[0] * rm[0] + rm[1] * rm[1] + rm[2] * rm[2]) / w;
    real_t e1 = hi->mm - (h[0] * rm[0] + h[1] * rm[1] + h[2] * rm[2]) -
                (o[0] * m[0] + o[1] * m[1] + o[2] * m[2]);
    bool fits = e1 < c->hi_gate * e0;
    for (int i = 0; i < 3; ++i) {
        hi->o[i] = fits ? o[i] : R(0.0);
    }
}

/* the low-passed norm and dip against the learned reference: flag or clear a disturbance */
static void mag_disturbance(gnomon_robust_ahrs_state *s, const gnomon_robust_ahrs_coefficients *c,
                            real_t nm, real_t dip, real_t cur[2])
{
    real_t x[2] = {nm, dip};
    lowpass(s->mag_lp.z0, s->mag_lp.z1, &s->mag_lp.n, x, 2, &c->mag_lp, cur);
    real_t ref_n = s->mag_ref_norm;
    if (GN_FABS(cur[0] - ref_n) < c->mag_norm_th * ref_n &&
        GN_FABS(cur[1] - s->mag_ref_dip) < c->mag_dip_th) {
        s->mag_undisturbed_t += c->ts_mag;
        if (s->mag_undisturbed_t >= c->mag_min_undisturbed_s) {
            s->mag_disturbed = false;
            s->mag_ref_norm += c->k_mag_ref * (cur[0] - ref_n);
            s->mag_ref_dip += c->k_mag_ref * (cur[1] - s->mag_ref_dip);
        }
    } else {
        s->mag_undisturbed_t = R(0.0);
        s->mag_disturbed = true;
    }
}

/* a steady new field becomes the reference; returns the soft de-weighting factor */
static real_t new_field(gnomon_robust_ahrs_state *s, const gnomon_robust_ahrs_coefficients *c,
                        const real_t cur[2])
{
    real_t cand_n = s->cand_norm;
    if (GN_FABS(cur[0] - cand_n) < c->mag_norm_th * cand_n &&
        GN_FABS(cur[1] - s->cand_dip) < c->mag_dip_th) {
        const real_t *g = s->gyro_lp;
        if (g[0] * g[0] + g[1] * g[1] + g[2] * g[2] >= c->mag_new_min_gyro2) {
            s->cand_t += c->ts_mag;
        }
        s->cand_norm += c->k_mag_ref * (cur[0] - cand_n);
        s->cand_dip += c->k_mag_ref * (cur[1] - s->cand_dip);
        if (s->mag_disturbed && (s->cand_t >= c->mag_new_s ||
                                 (s->mag_ref_norm == R(0.0) && s->cand_t >= c->mag_new_first_s))) {
            s->mag_ref_norm = s->cand_norm;
            s->mag_ref_dip = s->cand_dip;
            s->mag_disturbed = false;
            s->mag_undisturbed_t = c->mag_min_undisturbed_s;
        }
    } else {
        s->cand_t = R(0.0);
        s->cand_norm = cur[0];
        s->cand_dip = cur[1];
    }
    if (s->mag_ref_norm > R(0.0)) {
        real_t dn = (cur[0] - s->mag_ref_norm) / s->mag_ref_norm;
        real_t dd = cur[1] - s->mag_ref_dip;
        return R(1.0) + c->soft_norm * dn * dn + c->soft_dip * dd * dd;
    }
    return R(1.0);
}

/* u^T P u, u the third row of R_6b (up in body) */
static real_t vertical_bias_var(const gnomon_robust_ahrs_state *s, const real_t Rm[9])
{
    real_t v = R(0.0);
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            v += Rm[6 + i] * s->P[3 * i + j] * Rm[6 + j];
        }
    }
    return v;
}

/* this update's heading gain (first-order or the heading KF's; 0 while rejected) */
static real_t heading_gain(gnomon_robust_ahrs_state *s, const gnomon_robust_ahrs_coefficients *c,
                           real_t soft, real_t p_bv)
{
    real_t tsm = c->ts_mag;
    real_t k = c->k_mag, r_head = c->r_head;
    if (c->heading_kf) {
        s->p_head += c->q_head * (R(1.0) + p_bv * c->inv_bias_ref2) + c->q_rate * s->rot2;
    }
    s->rot2 = R(0.0);
    if (c->mag_rejection) {
        if (s->mag_disturbed) {
            if (s->mag_reject_t <= c->mag_max_reject_s) {
                s->mag_reject_t += tsm;
                k = R(0.0);
                r_head = R(0.0);
            } else {
                k /= c->mag_reject_factor;
                r_head = c->r_head * c->mag_reject_factor * c->mag_reject_factor;
            }
        } else {
            s->mag_reject_t = gn_max(s->mag_reject_t - c->mag_reject_factor * tsm, R(0.0));
        }
    }
    k /= soft;
    r_head *= soft;
    if (c->heading_kf && r_head > R(0.0)) {
        k = s->p_head / (s->p_head + r_head);
        s->p_head *= R(1.0) - k;
    }
    real_t ki = s->k_mag_init;
    if (ki != R(0.0)) {  /* running mean at start: the gain is at least 1/count */
        if (k < ki) {
            k = ki;
            s->p_head = ki * c->r_head;
        }
        ki = ki / (ki + R(1.0));
        s->k_mag_init = ki * c->tau_mag_s < tsm ? R(0.0) : ki;
    }
    return k;
}

static void magnetometer(gnomon_robust_ahrs_state *s, const gnomon_robust_ahrs_coefficients *c,
                         const real_t Rm[9], const real_t mg[3])
{
    if (!mag_accumulate(s, c, Rm, mg[0], mg[1], mg[2])) {
        return;  /* accumulating: the heading filter runs on every mag_every-th sample */
    }
    int32_t cnt = s->mag_count;
    real_t inv = R(1.0) / R(cnt);
    real_t ex = s->mag_sum[0] * inv, ey = s->mag_sum[1] * inv, ez = s->mag_sum[2] * inv;
    if (c->hi_lambda > R(0.0)) {
        hard_iron(s, c, cnt);
    }
    zero(s->mag_sum, 3);
    s->mag_count = 0;
    real_t soft = R(1.0);
    if (c->mag_rejection) {
        real_t nm = GN_SQRT(ex * ex + ey * ey + ez * ez);
        real_t dip = -GN_ASIN(gn_min(gn_max(ez / nm, R(-1.0)), R(1.0)));
        real_t cur[2];
        mag_disturbance(s, c, nm, dip, cur);
        soft = new_field(s, c, cur);
    }
    real_t dis = wrap(GN_ATAN2(ex, ey) - s->delta);
    s->mag_dis = dis;
    if (c->mag_heading_dis > R(0.0) && !s->mag_disturbed && s->k_mag_init == R(0.0) &&
        GN_FABS(dis) > c->mag_heading_dis && s->mag_reject_t <= c->mag_max_reject_s) {
        /* within the norm and dip bounds, but turned away from the heading: a field that
         * turns (a room's), or one back in the bounds turned away, not the Earth's */
        s->mag_disturbed = true;
        s->mag_undisturbed_t = R(0.0);
    }
    real_t k = heading_gain(s, c, soft, vertical_bias_var(s, Rm));
    s->k_mag_used = k;
    set_heading(s, wrap(s->delta + k * dis));
    if (c->k_mag_bias > R(0.0) && k > R(0.0) && s->k_mag_init == R(0.0)) {
        /* heading-rate bias: integral action about the vertical (third row of R_6b) */
        real_t db = -c->k_mag_bias * (k / c->k_mag) * dis * c->ts_mag;
        bool at = false;
        for (int i = 0; i < 3; ++i) {
            real_t v = s->bias[i] + db * Rm[6 + i];
            if (GN_FABS(v) >= c->bias_clip) {
                v = copysign_lim(c->bias_clip, v);
                at = true;
            }
            s->bias[i] = v;
        }
        s->bias_at_limit = at;
    }
}

/* ---------------------------------------------------------------- the step */

int gnomon_robust_ahrs_update_gyro(gnomon_robust_ahrs_state *s,
                                   const gnomon_robust_ahrs_coefficients *c, real_t dt_s,
                                   const real_t gyro[3])
{
    bool new_a = s->acc_in_count > 0, new_m = s->mag_in_count > 0;
    real_t a[3] = {R(0.0), R(0.0), R(0.0)}, m[3] = {R(0.0), R(0.0), R(0.0)};
    for (int i = 0; i < 3; ++i) {
        if (new_a) {
            a[i] = s->acc_in_sum[i] / R(s->acc_in_count);
        }
        if (new_m) {
            m[i] = s->mag_in_sum[i] / R(s->mag_in_count);
        }
        s->acc_in_sum[i] = R(0.0);
        s->mag_in_sum[i] = R(0.0);
    }
    s->acc_in_count = 0;
    s->mag_in_count = 0;
    if (!(GN_ISFINITE(gyro[0]) && GN_ISFINITE(gyro[1]) && GN_ISFINITE(gyro[2]))) {
        return GNOMON_ROBUST_AHRS_BAD_GYRO;
    }
    /* gyro phase */
    if (c->rest_bias || c->mag_rejection) {
        rest_gyro(s, c, gyro);
    }
    strapdown(s, dt_s, gyro);
    if (c->rest_bias) {
        rest_turn(s, dt_s, gyro);
    }
    if (dt_s > c->max_dt_s) {
        return GNOMON_ROBUST_AHRS_GAP | (s->bias_at_limit ? GNOMON_ROBUST_AHRS_BIAS_AT_LIMIT : 0);
    }
    int flags = 0;
    real_t q6[4], Rm[9];
    /* accelerometer phase (a zero vector is no sample) */
    if (new_a && a[0] * a[0] + a[1] * a[1] + a[2] * a[2] > R(0.0)) {
        if (c->rest_bias) {
            rest_acc(s, c, a);
        }
        real_t f[2];
        bool have_f = inclination(s, c, a, f);
        gn_quat_mul(s->q_acc, s->q_gyr, q6);
        gn_dcm(q6, Rm);
        bias_kf(s, c, Rm, f, have_f);
    } else {
        flags |= GNOMON_ROBUST_AHRS_ACC_SKIPPED;
        gn_quat_mul(s->q_acc, s->q_gyr, q6);
        gn_dcm(q6, Rm);
    }
    /* magnetometer phase */
    if (new_m && m[0] * m[0] + m[1] * m[1] + m[2] * m[2] > R(0.0)) {
        if (c->rest_bias) {
            rest_mag(s, c, m);
        }
        if (s->heading_reset) {
            heading_reset(s, Rm);
        }
        magnetometer(s, c, Rm, m);
    } else {
        flags |= GNOMON_ROBUST_AHRS_MAG_SKIPPED;
    }
    return flags | (s->bias_at_limit ? GNOMON_ROBUST_AHRS_BIAS_AT_LIMIT : 0);
}

void gnomon_robust_ahrs_get_quat(const gnomon_robust_ahrs_state *s, real_t q_nb[4])
{
    real_t q6[4], qz[4];
    gn_quat_mul(s->q_acc, s->q_gyr, q6);
    qz[0] = s->cos_half_delta;
    qz[1] = R(0.0);
    qz[2] = R(0.0);
    qz[3] = s->sin_half_delta;
    gn_quat_mul(qz, q6, q_nb);
}

void gnomon_robust_ahrs_get_bias(const gnomon_robust_ahrs_state *s, real_t bias_rad_s[3])
{
    for (int i = 0; i < 3; ++i) {
        bias_rad_s[i] = s->bias[i];
    }
}
