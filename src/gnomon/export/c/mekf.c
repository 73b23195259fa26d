/* gnomon flight code: the spacecraft MEKF, twin of gnomon.kernels.mekf (its row: the tail
 * of the delayed pair, step's phases: gyro prediction, magnetometer and its magnitude row,
 * the sun or the delayed pair, the star tracker; the gyro sample held). Each function
 * below names the kernel function it follows; the arithmetic is written in the same order.
 * See mekf.h for frames, units and how to call it. */
#include "mekf.h"

#include "gnomon_quat.h"

#define NX GNOMON_MEKF_NX

/* the kernels' "finite and below 1e300" bound (float: its largest finite values) */
#if defined(GNOMON_FLOAT) && !(defined(GNOMON_COUNT_OPS) && defined(__cplusplus))
#define MEKF_HUGE R(3.0e38)
#else
#define MEKF_HUGE R(1e300)
#endif

typedef struct { /* scratch of one 3-row update (kernels.mekf._Work) */
    real_t H[3][NX];
    real_t R[3][3];
} mekf_rows;

/* ---------------------------------------------------------------- small helpers */

/* R(q)^T v for a unit q (kernels.quat.rotate_inv) */
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

/* exp(r) as a quaternion (kernels.quat.exp: exp_mul of the identity, exact forms) */
static void quat_exp(real_t rx, real_t ry, real_t rz, real_t e[4])
{
    real_t dw, k;
    gn_exp_half(rx * rx + ry * ry + rz * rz, &dw, &k);
    e[0] = dw;
    e[1] = k * rx;
    e[2] = k * ry;
    e[3] = k * rz;
}

/* q <- normalise(q (x) exp(r)); an absurd rotation leaves q (spacecraft_cf.turn) */
static void turn(real_t q[4], real_t rx, real_t ry, real_t rz)
{
    if (!(rx * rx + ry * ry + rz * rz < R(1e12))) {
        return;
    }
    gn_exp_mul(q, rx, ry, rz, true);
}

/* unit vectors of a body/reference pair; false if either is zero or not finite
 * (spacecraft_cf.unit_pair) */
static bool unit_pair(const real_t vb[3], const real_t vo[3], real_t ub[3], real_t uo[3])
{
    real_t nb = GN_SQRT(vb[0] * vb[0] + vb[1] * vb[1] + vb[2] * vb[2]);
    real_t no = GN_SQRT(vo[0] * vo[0] + vo[1] * vo[1] + vo[2] * vo[2]);
    if (!(nb > R(0.0) && no > R(0.0) && nb < MEKF_HUGE && no < MEKF_HUGE)) {
        return false;
    }
    for (int i = 0; i < 3; ++i) {
        ub[i] = vb[i] / nb;
        uo[i] = vo[i] / no;
    }
    return true;
}

/* out = m^-1 (row-major 3x3) by cofactors; returns det (kernels.linalg.inv3) */
static real_t inv3(real_t m[3][3], real_t o[3][3])
{
    real_t a = m[0][0], b = m[0][1], c = m[0][2], d = m[1][0], e = m[1][1], f = m[1][2];
    real_t g = m[2][0], h = m[2][1], i = m[2][2];
    real_t c0 = e * i - f * h;
    real_t c1 = -(d * i - f * g);
    real_t c2 = d * h - e * g;
    real_t det = a * c0 + b * c1 + c * c2;
    real_t s = R(1.0) / det;
    o[0][0] = c0 * s;
    o[0][1] = -(b * i - c * h) * s;
    o[0][2] = (b * f - c * e) * s;
    o[1][0] = c1 * s;
    o[1][1] = (a * i - c * g) * s;
    o[1][2] = -(a * f - c * d) * s;
    o[2][0] = c2 * s;
    o[2][1] = -(a * h - b * g) * s;
    o[2][2] = (a * e - b * d) * s;
    return det;
}

static void symmetrise(int n, real_t P[NX][NX])
{
    for (int a = 0; a < n; ++a) {
        for (int k = 0; k < a; ++k) {
            real_t v = R(0.5) * (P[a][k] + P[k][a]);
            P[a][k] = v;
            P[k][a] = v;
        }
    }
}

/* ---------------------------------------------------------------- init, start */

bool gnomon_mekf_init(gnomon_mekf_state *s, const gnomon_mekf_params *p, gnomon_mekf_past *ring,
                      int32_t ring_len)
{
    if (p->substitute != 0 && (ring == 0 || ring_len < p->delay_samples || p->delay_samples < 1)) {
        return false;
    }
    int n = 6, i_mag = -1, i_scale = -1;
    if (p->estimate_mag_bias) {
        i_mag = n;
        n += 3;
    }
    if (p->estimate_gyro_scale) {
        i_scale = n;
        n += 3;
    }
    s->n = (int8_t)n;
    s->i_mag = (int8_t)i_mag;
    s->i_scale = (int8_t)i_scale;
    for (int i = 0; i < 4; ++i) {
        s->q[i] = i == 0 ? R(1.0) : R(0.0);
    }
    for (int i = 0; i < 3; ++i) {
        s->bias[i] = R(0.0);
        s->mag_bias[i] = R(0.0);
        s->scale[i] = R(0.0);
        s->gyro_b[i] = R(0.0);
        s->w_io_o[i] = R(0.0);
        s->w_ib[i] = R(0.0);
        s->old_mag_b[i] = R(0.0);
        s->old_mag_o[i] = R(0.0);
    }
    for (int a = 0; a < NX; ++a) {
        s->dx[a] = R(0.0);
        for (int k = 0; k < NX; ++k) {
            s->P[a][k] = R(0.0);
        }
    }
    for (int a = 0; a < 3; ++a) { /* P0 = diag(sigma0^2) */
        s->P[a][a] = p->sigma0_att_rad * p->sigma0_att_rad;
        s->P[3 + a][3 + a] = p->sigma0_bias_rad_s * p->sigma0_bias_rad_s;
        if (i_mag >= 0) {
            s->P[i_mag + a][i_mag + a] = p->sigma0_mag_bias_nT * p->sigma0_mag_bias_nT;
        }
        if (i_scale >= 0) {
            s->P[i_scale + a][i_scale + a] = p->sigma0_gyro_scale * p->sigma0_gyro_scale;
        }
    }
    s->n_seen = 0;
    s->slot = 0;
    s->has_old = false;
    s->pending = false;
    s->phase = 0;
    s->ring = p->substitute != 0 ? ring : 0;
    s->ring_len = p->substitute != 0 ? ring_len : 0;
    for (int32_t j = 0; j < s->ring_len; ++j) {
        for (int i = 0; i < 4; ++i) {
            if (i < 3) {
                ring[j].mag_b[i] = R(0.0);
                ring[j].mag_o[i] = R(0.0);
            }
            ring[j].q[i] = R(0.0);
        }
    }
    return true;
}

void gnomon_mekf_start(gnomon_mekf_state *s, const real_t q_ob[4])
{
    real_t n = GN_SQRT(q_ob[0] * q_ob[0] + q_ob[1] * q_ob[1] + q_ob[2] * q_ob[2] + q_ob[3] * q_ob[3]);
    for (int i = 0; i < 4; ++i) {
        s->q[i] = q_ob[i] / n;
    }
}

void gnomon_mekf_star_q_ob(const real_t q_io[4], const real_t q_ib[4], real_t q_ob[4])
{
    real_t q_oi[4] = {q_io[0], -q_io[1], -q_io[2], -q_io[3]};
    gn_quat_mul(q_oi, q_ib, q_ob);
}

/* the triad [v1, v1 x v2 / |v1 x v2|, v1 x t2] as columns, row-major t[9] */
static void triad_frame(const real_t v1[3], const real_t v2[3], real_t t[9])
{
    real_t c[3] = {v1[1] * v2[2] - v1[2] * v2[1], v1[2] * v2[0] - v1[0] * v2[2],
                   v1[0] * v2[1] - v1[1] * v2[0]};
    real_t nc = GN_SQRT(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
    real_t t2[3] = {c[0] / nc, c[1] / nc, c[2] / nc};
    real_t t3[3] = {v1[1] * t2[2] - v1[2] * t2[1], v1[2] * t2[0] - v1[0] * t2[2],
                    v1[0] * t2[1] - v1[1] * t2[0]};
    for (int i = 0; i < 3; ++i) {
        t[3 * i] = v1[i];
        t[3 * i + 1] = t2[i];
        t[3 * i + 2] = t3[i];
    }
}

/* gnomon.estimators.wahba.triad of [sun, field] with unit weights (the sun exact), and
 * its degenerate test: quality s2/s1 of the profile matrix below 1e-4, which for two unit
 * pairs is sqrt(min(a, c) / max(a, c)), a = (1 + r1.r2)(1 + b1.b2), c = (1 - r1.r2)(1 - b1.b2) */
bool gnomon_mekf_triad(const real_t sun_b[3], const real_t sun_o[3], const real_t mag_b[3],
                       const real_t mag_o[3], real_t q_ob[4])
{
    real_t b1[3], r1[3], b2[3], r2[3];
    if (!unit_pair(sun_b, sun_o, b1, r1) || !unit_pair(mag_b, mag_o, b2, r2)) {
        return false;
    }
    real_t cr = r1[0] * r2[0] + r1[1] * r2[1] + r1[2] * r2[2];
    real_t cb = b1[0] * b2[0] + b1[1] * b2[1] + b1[2] * b2[2];
    real_t a = (R(1.0) + cr) * (R(1.0) + cb), c = (R(1.0) - cr) * (R(1.0) - cb);
    if (!(gn_max(a, c) > R(0.0) && gn_min(a, c) >= R(1e-8) * gn_max(a, c))) {
        return false;
    }
    real_t tr[9], tb[9], m[9];
    triad_frame(r1, r2, tr);
    triad_frame(b1, b2, tb);
    for (int i = 0; i < 3; ++i) { /* R_ob = [t_o] [t_b]^T */
        for (int j = 0; j < 3; ++j) {
            m[3 * i + j] = tr[3 * i] * tb[3 * j] + tr[3 * i + 1] * tb[3 * j + 1]
                           + tr[3 * i + 2] * tb[3 * j + 2];
        }
    }
    gn_quat_from_dcm(m, q_ob);
    return true;
}

/* ---------------------------------------------------------------- gyro prediction */

/* w_ib = (g - b) / (1 + s); false (zeros) for an unusable sample (kernels.mekf.rate) */
static bool rate(const gnomon_mekf_state *s, const real_t g[3], real_t w[3])
{
    w[0] = w[1] = w[2] = R(0.0);
    if (!(GN_FABS(g[0]) < R(1e6) && GN_FABS(g[1]) < R(1e6) && GN_FABS(g[2]) < R(1e6))) {
        return false;
    }
    for (int i = 0; i < 3; ++i) {
        w[i] = g[i] - s->bias[i];
    }
    if (s->i_scale >= 0) {
        for (int i = 0; i < 3; ++i) {
            w[i] = w[i] / (R(1.0) + s->scale[i]);
        }
    }
    return true;
}

/* P <- Phi P Phi^T + Q dt (kernels.mekf.propagate_covariance) */
static void propagate_covariance(gnomon_mekf_state *s, const gnomon_mekf_params *p,
                                 const real_t w[3], real_t dt)
{
    real_t A[3][3];
    real_t PP[NX][NX];
    int n = s->n, isc = s->i_scale;
    real_t wx = w[0], wy = w[1], wz = w[2];
    if (p->exponential || (wx * wx + wy * wy + wz * wz) * dt * dt > R(0.01)) {
        real_t e[4], r[9];
        quat_exp(-wx * dt, -wy * dt, -wz * dt, e);
        gn_dcm(e, r); /* exp(-[w x] dt) = R(exp(-w dt)) */
        for (int a = 0; a < 3; ++a) {
            for (int k = 0; k < 3; ++k) {
                A[a][k] = r[3 * a + k];
            }
        }
    } else { /* I - [w x] dt (linalg.skew_into with scale -dt) */
        real_t sc = -dt;
        A[0][0] = R(1.0);
        A[0][1] = -sc * wz;
        A[0][2] = sc * wy;
        A[1][0] = sc * wz;
        A[1][1] = R(1.0);
        A[1][2] = -sc * wx;
        A[2][0] = -sc * wy;
        A[2][1] = sc * wx;
        A[2][2] = R(1.0);
    }
    real_t (*P)[NX] = s->P;
    for (int k = 0; k < n; ++k) { /* PP = Phi P */
        for (int a = 0; a < 3; ++a) {
            real_t v = A[a][0] * P[0][k] + A[a][1] * P[1][k] + A[a][2] * P[2][k] - dt * P[3 + a][k];
            if (isc >= 0) {
                v -= w[a] * dt * P[isc + a][k];
            }
            PP[a][k] = v;
        }
        for (int a = 3; a < n; ++a) {
            PP[a][k] = P[a][k];
        }
    }
    for (int a = 0; a < n; ++a) { /* P = PP Phi^T */
        for (int k = 0; k < 3; ++k) {
            real_t v = PP[a][0] * A[k][0] + PP[a][1] * A[k][1] + PP[a][2] * A[k][2] - dt * PP[a][3 + k];
            if (isc >= 0) {
                v -= w[k] * dt * PP[a][isc + k];
            }
            P[a][k] = v;
        }
        for (int k = 3; k < n; ++k) {
            P[a][k] = PP[a][k];
        }
    }
    for (int a = 0; a < 3; ++a) {
        P[a][a] += p->arw_rad_rt_s * p->arw_rad_rt_s * dt;
        P[3 + a][3 + a] += p->bias_rw_rad_s_rt_s * p->bias_rw_rad_s_rt_s * dt;
        if (s->i_mag >= 0) {
            P[s->i_mag + a][s->i_mag + a] += p->mag_bias_rw_nT_rt_s * p->mag_bias_rw_nT_rt_s * dt;
        }
        if (isc >= 0) {
            P[isc + a][isc + a] += p->gyro_scale_rw_rt_s * p->gyro_scale_rw_rt_s * dt;
        }
    }
}

/* ---------------------------------------------------------------- updates */

/* one 3-row update about this sample's earlier corrections dx: K = P H^T S^-1,
 * dx += K (y - H dx), P <- P - K H P (symmetrised); H zero but in columns 0-2 and
 * i_h2..i_h2+2 (i_h2 >= 0). Returns chi2 of the innovation, or -1 (nothing changed) for a
 * singular S (kernels.mekf.update3) */
static real_t update3(gnomon_mekf_state *s, const mekf_rows *m, real_t y0, real_t y1, real_t y2,
                      int i_h2)
{
    real_t PHt[NX][3], K[NX][3], S[3][3], Si[3][3];
    int n = s->n;
    real_t (*P)[NX] = s->P;
    real_t *dx = s->dx;
    const real_t (*H)[NX] = m->H;
    for (int a = 0; a < n; ++a) { /* P H^T */
        for (int j = 0; j < 3; ++j) {
            real_t v = P[a][0] * H[j][0] + P[a][1] * H[j][1] + P[a][2] * H[j][2];
            if (i_h2 >= 0) {
                v += (P[a][i_h2] * H[j][i_h2] + P[a][i_h2 + 1] * H[j][i_h2 + 1]
                      + P[a][i_h2 + 2] * H[j][i_h2 + 2]);
            }
            PHt[a][j] = v;
        }
    }
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            real_t v = H[i][0] * PHt[0][j] + H[i][1] * PHt[1][j] + H[i][2] * PHt[2][j];
            if (i_h2 >= 0) {
                v += (H[i][i_h2] * PHt[i_h2][j] + H[i][i_h2 + 1] * PHt[i_h2 + 1][j]
                      + H[i][i_h2 + 2] * PHt[i_h2 + 2][j]);
            }
            S[i][j] = v + m->R[i][j];
        }
    }
    real_t det = inv3(S, Si);
    if (!(det > R(0.0) && det < MEKF_HUGE)) {
        return R(-1.0);
    }
    real_t r0 = y0, r1 = y1, r2 = y2;
    for (int k = 0; k < n; ++k) { /* H dx (dx is zero but after an earlier update) */
        if (dx[k] != R(0.0)) {
            r0 -= H[0][k] * dx[k];
            r1 -= H[1][k] * dx[k];
            r2 -= H[2][k] * dx[k];
        }
    }
    real_t chi2 = (r0 * (Si[0][0] * r0 + Si[0][1] * r1 + Si[0][2] * r2)
                   + r1 * (Si[1][0] * r0 + Si[1][1] * r1 + Si[1][2] * r2)
                   + r2 * (Si[2][0] * r0 + Si[2][1] * r1 + Si[2][2] * r2));
    for (int a = 0; a < n; ++a) {
        for (int j = 0; j < 3; ++j) {
            K[a][j] = PHt[a][0] * Si[0][j] + PHt[a][1] * Si[1][j] + PHt[a][2] * Si[2][j];
        }
    }
    for (int a = 0; a < n; ++a) {
        dx[a] += K[a][0] * r0 + K[a][1] * r1 + K[a][2] * r2;
    }
    for (int a = 0; a < n; ++a) {
        for (int k = 0; k < n; ++k) {
            P[a][k] -= K[a][0] * PHt[k][0] + K[a][1] * PHt[k][1] + K[a][2] * PHt[k][2];
        }
    }
    symmetrise(n, P);
    return chi2;
}

/* q <- q (x) exp(theta) (or normalise(q (x) [1, theta/2])), the biases and scales added,
 * dx cleared (kernels.mekf.apply_correction) */
static void apply_correction(gnomon_mekf_state *s, const gnomon_mekf_params *p)
{
    real_t *dx = s->dx, *q = s->q;
    if (p->exp_correction) {
        turn(q, dx[0], dx[1], dx[2]);
    } else {
        real_t d[4] = {R(1.0), R(0.5) * dx[0], R(0.5) * dx[1], R(0.5) * dx[2]};
        real_t o[4];
        gn_quat_mul(q, d, o);
        real_t sc = R(1.0) / GN_SQRT(o[0] * o[0] + o[1] * o[1] + o[2] * o[2] + o[3] * o[3]);
        for (int i = 0; i < 4; ++i) {
            q[i] = o[i] * sc;
        }
    }
    for (int a = 0; a < 3; ++a) {
        s->bias[a] += dx[3 + a];
        if (s->i_mag >= 0) {
            s->mag_bias[a] += dx[s->i_mag + a];
        }
        if (s->i_scale >= 0) {
            s->scale[a] += dx[s->i_scale + a];
        }
    }
    for (int a = 0; a < s->n; ++a) {
        dx[a] = R(0.0);
    }
    s->pending = false;
}

void gnomon_mekf_correct(gnomon_mekf_state *s, const gnomon_mekf_params *p)
{
    if (s->pending) {
        apply_correction(s, p);
    }
}

/* one unit-vector measurement: m = R_bo uo, H = [[m x], 0, (I - ub ub^T)/|B| (mag_norm > 0:
 * the magnetometer with its bias), 0], y = ub - m; applied at once when relinearise
 * (kernels.mekf.vector_update) */
static bool vector_update(gnomon_mekf_state *s, const gnomon_mekf_params *p, const real_t ub[3],
                          const real_t uo[3], real_t sigma, real_t mag_norm)
{
    mekf_rows m;
    real_t mv[3];
    rotate_inv(s->q, uo, mv);
    for (int j = 0; j < 3; ++j) {
        for (int k = 0; k < NX; ++k) {
            m.H[j][k] = R(0.0);
        }
    }
    m.H[0][1] = -mv[2];
    m.H[0][2] = mv[1];
    m.H[1][0] = mv[2];
    m.H[1][2] = -mv[0];
    m.H[2][0] = -mv[1];
    m.H[2][1] = mv[0];
    if (mag_norm > R(0.0)) {
        for (int j = 0; j < 3; ++j) {
            for (int k = 0; k < 3; ++k) {
                m.H[j][s->i_mag + k] = ((j == k ? R(1.0) : R(0.0)) - ub[j] * ub[k]) / mag_norm;
            }
        }
    }
    for (int j = 0; j < 3; ++j) {
        for (int k = 0; k < 3; ++k) {
            m.R[j][k] = j == k ? sigma * sigma : R(0.0);
        }
    }
    if (update3(s, &m, ub[0] - mv[0], ub[1] - mv[1], ub[2] - mv[2],
                mag_norm > R(0.0) ? s->i_mag : -1) < R(0.0)) {
        return false;
    }
    s->pending = true;
    if (p->relinearise) {
        apply_correction(s, p);
    }
    return true;
}

/* the scalar row |B - m| - |B_model| = u^T dm + noise (kernels.mekf.magnitude_update) */
static void magnitude_update(gnomon_mekf_state *s, const gnomon_mekf_params *p, const real_t u[3],
                             real_t y)
{
    real_t ph[NX];
    int n = s->n, i = s->i_mag;
    real_t (*P)[NX] = s->P;
    real_t *dx = s->dx;
    for (int a = 0; a < n; ++a) {
        ph[a] = P[a][i] * u[0] + P[a][i + 1] * u[1] + P[a][i + 2] * u[2];
    }
    real_t S = u[0] * ph[i] + u[1] * ph[i + 1] + u[2] * ph[i + 2]
               + p->sigma_mag_norm_nT * p->sigma_mag_norm_nT;
    if (!(S > R(0.0) && S < MEKF_HUGE)) {
        return;
    }
    real_t r = y - (u[0] * dx[i] + u[1] * dx[i + 1] + u[2] * dx[i + 2]);
    for (int a = 0; a < n; ++a) {
        dx[a] += ph[a] / S * r;
    }
    for (int a = 0; a < n; ++a) {
        for (int k = 0; k < n; ++k) {
            P[a][k] -= ph[a] * ph[k] / S;
        }
    }
    symmetrise(n, P);
    s->pending = true;
    if (p->relinearise) {
        apply_correction(s, p);
    }
}

/* ---------------------------------------------------------------- one sample */

/* the sample begins: the previous one's estimate into the tail, this one's slot, its
 * delayed pair (kernels.mekf.row and spacecraft_cf.second_pair); the gyro prediction over
 * dt (kernels.mekf.step's first phase); the gyro sample held */
int gnomon_mekf_update_gyro(gnomon_mekf_state *s, const gnomon_mekf_params *p, real_t dt_s,
                            const real_t *gyro, const real_t *w_io_o)
{
    real_t g[3], io[3];
    for (int i = 0; i < 3; ++i) {
        g[i] = gyro != 0 ? gyro[i] : R(1e30); /* none: beyond the usable 1e6 rad/s (coast) */
        io[i] = w_io_o != 0 ? w_io_o[i] : (i == 1 ? -p->orbital_rate_rad_s : R(0.0));
    }
    gnomon_mekf_correct(s, p);
    if (!(GN_ISFINITE(g[0]) && GN_ISFINITE(g[1]) && GN_ISFINITE(g[2]))) {
        s->phase = 0;
        return GNOMON_MEKF_BAD_GYRO;
    }
    if (s->ring != 0) { /* the tail: the estimate after the previous sample, this slot */
        int32_t m = p->delay_samples;
        if (s->n_seen > 0) {
            gnomon_mekf_past *prev = &s->ring[s->slot];
            for (int i = 0; i < 4; ++i) {
                prev->q[i] = s->q[i];
            }
            s->slot = s->slot + 1 == m ? 0 : s->slot + 1;
        }
        gnomon_mekf_past *r = &s->ring[s->slot];
        s->has_old = s->n_seen >= m;
        for (int i = 0; i < 3; ++i) {
            s->old_mag_b[i] = r->mag_b[i];
            s->old_mag_o[i] = r->mag_o[i];
            r->mag_b[i] = R(0.0); /* no magnetometer sample (yet) in this one */
            r->mag_o[i] = R(0.0);
        }
        if (s->n_seen < m) {
            s->n_seen += 1;
        }
    } else {
        s->has_old = false;
    }
    int f = 0;
    s->phase = 1;
    if (dt_s > R(0.0) && dt_s < MEKF_HUGE) {
        const real_t *gp = p->previous_gyro ? s->gyro_b : g;
        const real_t *iop = p->previous_gyro ? s->w_io_o : io;
        bool ok_g = rate(s, gp, s->w_ib);
        if (ok_g) { /* q <- q (x) exp((w_ib - R_bo w_io) dt) */
            real_t t[3];
            rotate_inv(s->q, iop, t);
            turn(s->q, (s->w_ib[0] - t[0]) * dt_s, (s->w_ib[1] - t[1]) * dt_s,
                 (s->w_ib[2] - t[2]) * dt_s);
        } else {
            f |= GNOMON_MEKF_COAST;
        }
        propagate_covariance(s, p, s->w_ib, dt_s);
        if (dt_s > p->max_dt_s) {
            f |= GNOMON_MEKF_GAP | GNOMON_MEKF_COAST;
        } else {
            s->phase = 2;
        }
    }
    for (int i = 0; i < 3; ++i) { /* hold: propagates to the next sample when previous_gyro */
        s->gyro_b[i] = g[i];
        s->w_io_o[i] = io[i];
    }
    return f;
}

/* the magnetometer pair, its bias removed when estimated; a zero or non-finite field is a
 * dropout; then the magnitude row (kernels.mekf.magnetometer) */
int gnomon_mekf_update_mag(gnomon_mekf_state *s, const gnomon_mekf_params *p,
                           const real_t mag_b[3], const real_t mag_o[3])
{
    if (s->phase == 0) {
        return GNOMON_MEKF_NOT_OPEN | GNOMON_MEKF_MAG_UNUSABLE;
    }
    if (s->ring != 0) { /* this sample's pair joins the tail */
        gnomon_mekf_past *r = &s->ring[s->slot];
        for (int i = 0; i < 3; ++i) {
            r->mag_b[i] = mag_b[i];
            r->mag_o[i] = mag_o[i];
        }
    }
    if (s->phase != 2) {
        return GNOMON_MEKF_NOT_OPEN | GNOMON_MEKF_MAG_UNUSABLE;
    }
    real_t nb = mag_b[0] * mag_b[0] + mag_b[1] * mag_b[1] + mag_b[2] * mag_b[2];
    if (!(nb > R(0.0) && nb < MEKF_HUGE)) {
        return GNOMON_MEKF_MAG_UNUSABLE;
    }
    real_t v[3] = {mag_b[0] - s->mag_bias[0], mag_b[1] - s->mag_bias[1], mag_b[2] - s->mag_bias[2]};
    real_t ub[3], uo[3];
    if (!unit_pair(v, mag_o, ub, uo)) {
        return GNOMON_MEKF_MAG_UNUSABLE;
    }
    real_t norm = GN_SQRT(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    real_t sigma = p->sigma_mag_rad;
    if (p->mag_noise_nT > R(0.0)) {
        real_t e = p->mag_noise_nT / norm;
        sigma = GN_SQRT(sigma * sigma + e * e);
    }
    if (!vector_update(s, p, ub, uo, sigma, s->i_mag >= 0 ? norm : R(0.0))) {
        return GNOMON_MEKF_MAG_UNUSABLE;
    }
    if (s->i_mag >= 0 && p->sigma_mag_norm_nT > R(0.0)) {
        real_t n_o = GN_SQRT(mag_o[0] * mag_o[0] + mag_o[1] * mag_o[1] + mag_o[2] * mag_o[2]);
        magnitude_update(s, p, ub, norm - n_o);
    }
    return 0;
}

/* the sun pair, or where there is none (NULL) the magnetometer pair delay_samples ago with
 * the noise sqrt(sigma_mag^2 + (swing_gain * swing)^2), the swing the angle the estimate
 * turned since then (spacecraft_cf.second_pair, kernels.mekf.second_sigma, step) */
int gnomon_mekf_update_sun(gnomon_mekf_state *s, const gnomon_mekf_params *p,
                           const real_t *sun_b, const real_t *sun_o)
{
    if (s->phase != 2) {
        return GNOMON_MEKF_NOT_OPEN | GNOMON_MEKF_SUN_UNUSABLE;
    }
    if (!p->use_sun) {
        return GNOMON_MEKF_SUN_UNUSABLE;
    }
    bool sub = sun_b == 0 || sun_o == 0;
    const real_t *vb = sun_b, *vo = sun_o;
    if (sub) {
        if (s->ring == 0 || !s->has_old) {
            return GNOMON_MEKF_SUN_UNUSABLE;
        }
        vb = s->old_mag_b;
        vo = s->old_mag_o;
    }
    int f = sub ? GNOMON_MEKF_SUBSTITUTED : 0;
    real_t ub[3], uo[3];
    if (!unit_pair(vb, vo, ub, uo)) {
        return f | GNOMON_MEKF_SUN_UNUSABLE;
    }
    real_t sigma = p->sigma_sun_rad;
    if (sub) {
        const real_t *qo = s->ring[s->slot].q;
        const real_t *q = s->q;
        real_t cq = GN_FABS(q[0] * qo[0] + q[1] * qo[1] + q[2] * qo[2] + q[3] * qo[3]);
        real_t swing = R(2.0) * GN_ACOS(gn_min(R(1.0), cq));
        real_t e = p->swing_gain * swing;
        sigma = GN_SQRT(p->sigma_mag_rad * p->sigma_mag_rad + e * e);
    }
    if (!vector_update(s, p, ub, uo, sigma, R(0.0))) {
        return f | GNOMON_MEKF_SUN_UNUSABLE;
    }
    return f;
}

/* the star tracker's q_ob = q_oi(t) (x) q_ib(t - L), carried to t with the rate estimate:
 * q_m = q_ob (x) exp(w_ib L); y = rotvec(q^-1 (x) q_m), H = [I, 0], R = sc^2 (I - b b^T) +
 * sa^2 b b^T; the gain that of P - arw^2 L I; gated at chi2 > st_gate_chi2; applied at once
 * (kernels.mekf.star_tracker) */
int gnomon_mekf_update_star(gnomon_mekf_state *s, const gnomon_mekf_params *p,
                            const real_t q_ob[4], const real_t boresight_b[3])
{
    gnomon_mekf_correct(s, p); /* the vectors' joint correction comes first */
    if (s->phase != 2) {
        return GNOMON_MEKF_NOT_OPEN | GNOMON_MEKF_STAR_UNUSED;
    }
    if (!p->use_star_tracker) {
        return GNOMON_MEKF_STAR_UNUSED;
    }
    const real_t *st = q_ob, *bore = boresight_b;
    if (!(GN_FABS(st[0]) <= R(1.0) && GN_FABS(st[1]) <= R(1.0) && GN_FABS(st[2]) <= R(1.0)
          && GN_FABS(st[3]) <= R(1.0))) {
        return GNOMON_MEKF_STAR_UNUSED;
    }
    real_t nb = GN_SQRT(bore[0] * bore[0] + bore[1] * bore[1] + bore[2] * bore[2]);
    if (!(nb > R(0.0) && nb < MEKF_HUGE)) {
        return GNOMON_MEKF_STAR_UNUSED;
    }
    real_t L = p->st_latency_s;
    real_t e[4], qm[4], d[4];
    quat_exp(s->w_ib[0] * L, s->w_ib[1] * L, s->w_ib[2] * L, e);
    gn_quat_mul(st, e, qm);
    real_t qc[4] = {s->q[0], -s->q[1], -s->q[2], -s->q[3]};
    gn_quat_mul(qc, qm, d); /* q^-1 (x) q_m */
    if (d[0] < R(0.0)) {
        for (int i = 0; i < 4; ++i) {
            d[i] = -d[i];
        }
    }
    real_t v = GN_SQRT(d[1] * d[1] + d[2] * d[2] + d[3] * d[3]);
    real_t f = v > R(1e-12) ? R(2.0) * GN_ATAN2(v, d[0]) / v : R(2.0);
    mekf_rows m;
    int n = s->n;
    for (int j = 0; j < 3; ++j) {
        for (int k = 0; k < NX; ++k) {
            m.H[j][k] = j == k ? R(1.0) : R(0.0);
        }
    }
    real_t b[3] = {bore[0] / nb, bore[1] / nb, bore[2] / nb};
    real_t sc2 = p->st_sigma_cross_rad * p->st_sigma_cross_rad;
    real_t sa2 = p->st_sigma_about_rad * p->st_sigma_about_rad;
    for (int j = 0; j < 3; ++j) {
        for (int k = 0; k < 3; ++k) {
            m.R[j][k] = (sa2 - sc2) * b[j] * b[k] + (j == k ? sc2 : R(0.0));
        }
    }
    real_t saved[NX][NX];
    for (int a = 0; a < n; ++a) {
        for (int k = 0; k < n; ++k) {
            saved[a][k] = s->P[a][k];
        }
    }
    /* the measurement sees the error of t - L: the gyro noise since (arw^2 L) is in P(t)
     * and in the carried measurement alike, so the gain is that of P(t) - Q_L */
    real_t lat = p->arw_rad_rt_s * p->arw_rad_rt_s * L;
    for (int a = 0; a < 3; ++a) {
        s->P[a][a] -= lat;
    }
    real_t chi2 = update3(s, &m, f * d[1], f * d[2], f * d[3], -1);
    for (int a = 0; a < 3; ++a) {
        s->P[a][a] += lat;
    }
    if (chi2 < R(0.0) || (p->st_gate_chi2 > R(0.0) && chi2 > p->st_gate_chi2)) { /* undo */
        for (int a = 0; a < n; ++a) {
            s->dx[a] = R(0.0);
            for (int k = 0; k < n; ++k) {
                s->P[a][k] = saved[a][k];
            }
        }
        return GNOMON_MEKF_STAR_UNUSED;
    }
    apply_correction(s, p);
    return 0;
}

/* ---------------------------------------------------------------- getters */

void gnomon_mekf_get_quat(const gnomon_mekf_state *s, real_t q_ob[4])
{
    for (int i = 0; i < 4; ++i) {
        q_ob[i] = s->q[i];
    }
}

void gnomon_mekf_get_bias(const gnomon_mekf_state *s, real_t bias_rad_s[3])
{
    for (int i = 0; i < 3; ++i) {
        bias_rad_s[i] = s->bias[i];
    }
}

void gnomon_mekf_get_mag_bias(const gnomon_mekf_state *s, real_t mag_bias_nT[3])
{
    for (int i = 0; i < 3; ++i) {
        mag_bias_nT[i] = s->mag_bias[i];
    }
}

void gnomon_mekf_get_gyro_scale(const gnomon_mekf_state *s, real_t scale[3])
{
    for (int i = 0; i < 3; ++i) {
        scale[i] = s->scale[i];
    }
}
