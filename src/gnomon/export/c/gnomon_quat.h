/* gnomon flight code: quaternions (Hamilton, scalar first [w, x, y, z]; q_ab maps
 * b-coordinates to a-coordinates, v_a = q_ab (x) [0, v_b] (x) q_ab*), the twins of
 * gnomon.kernels.quat and gnomon.estimators.initial.
 *
 * Static inline functions on real_t arrays: no heap, no globals, no I/O.
 */
#ifndef GNOMON_QUAT_H
#define GNOMON_QUAT_H

#include "gnomon_real.h"

/* (0.05 rad)^2: below it the Taylor form of exp equals the trigonometric one */
#define GN_SMALL_TH2 R(0.0025)
/* | |q|^2 - 1 | below it: normalised by one Newton step */
#define GN_NEAR_UNIT R(1e-7)

/* out = p (x) q (out may alias neither) */
static inline void gn_quat_mul(const real_t p[4], const real_t q[4], real_t out[4])
{
    out[0] = p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3];
    out[1] = p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2];
    out[2] = p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1];
    out[3] = p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0];
}

/* q <- q (x) exp(r), r = (rx, ry, rz) a rotation vector (rad) in q's body frame;
 * normalised when `normalise` (one Newton step near unit norm, 1/sqrt otherwise).
 * gnomon.kernels.quat.exp_mul with its exact forms (trig = True). */
/* exp(r) = [dw, k r] for th2 = |r|^2: cos(|r|/2) and sin(|r|/2)/|r| (their series below
 * GN_SMALL_TH2), the exact forms of gnomon.kernels.quat.exp_mul */
static inline void gn_exp_half(real_t th2, real_t *dw, real_t *k)
{
    if (th2 >= GN_SMALL_TH2) {
        real_t th = GN_SQRT(th2);
        *dw = GN_COS(R(0.5) * th);
        *k = GN_SIN(R(0.5) * th) / th;
    } else {
        real_t t4 = th2 * th2;
        *dw = (R(1.0) - th2 * R(1.0 / 8.0)) + t4 * (R(1.0 / 384.0) - th2 * R(1.0 / 46080.0));
        *k = (R(0.5) - th2 * R(1.0 / 48.0)) + t4 * (R(1.0 / 3840.0) - th2 * R(1.0 / 645120.0));
    }
}

static inline void gn_exp_mul(real_t q[4], real_t rx, real_t ry, real_t rz, bool normalise)
{
    real_t th2 = rx * rx + ry * ry + rz * rz;
    real_t dw, k;
    gn_exp_half(th2, &dw, &k);
    real_t dx = k * rx, dy = k * ry, dz = k * rz;
    real_t w = q[0], x = q[1], y = q[2], z = q[3];
    real_t nw = w * dw - x * dx - y * dy - z * dz;
    real_t nx = w * dx + x * dw + y * dz - z * dy;
    real_t ny = w * dy - x * dz + y * dw + z * dx;
    real_t nz = w * dz + x * dy - y * dx + z * dw;
    if (normalise) {
        real_t n2 = (nw * nw + nx * nx) + (ny * ny + nz * nz);
        real_t s = GN_FABS(n2 - R(1.0)) < GN_NEAR_UNIT ? R(1.5) - R(0.5) * n2 : R(1.0) / GN_SQRT(n2);
        nw *= s;
        nx *= s;
        ny *= s;
        nz *= s;
    }
    q[0] = nw;
    q[1] = nx;
    q[2] = ny;
    q[3] = nz;
}

/* the rotation matrix R(q), row-major c[0..8], for a unit q */
static inline void gn_dcm(const real_t q[4], real_t c[9])
{
    real_t w = q[0], x = q[1], y = q[2], z = q[3];
    c[0] = R(1.0) - R(2.0) * (y * y + z * z);
    c[1] = R(2.0) * (x * y - w * z);
    c[2] = R(2.0) * (x * z + w * y);
    c[3] = R(2.0) * (x * y + w * z);
    c[4] = R(1.0) - R(2.0) * (x * x + z * z);
    c[5] = R(2.0) * (y * z - w * x);
    c[6] = R(2.0) * (x * z - w * y);
    c[7] = R(2.0) * (y * z + w * x);
    c[8] = R(1.0) - R(2.0) * (x * x + y * y);
}

/* unit q from a rotation matrix (row-major m[0..8]), Shepperd's method (the largest of
 * w^2, x^2, y^2, z^2 from the diagonal), largest component positive: rotation.quat_from_dcm */
static inline void gn_quat_from_dcm(const real_t m[9], real_t q[4])
{
    real_t tr = m[0] + m[4] + m[8];
    real_t cand[4];
    cand[0] = R(1.0) + tr;
    cand[1] = R(1.0) + R(2.0) * m[0] - tr;
    cand[2] = R(1.0) + R(2.0) * m[4] - tr;
    cand[3] = R(1.0) + R(2.0) * m[8] - tr;
    int k = 0;
    for (int i = 1; i < 4; ++i) {
        if (cand[i] > cand[k]) {
            k = i;
        }
    }
    real_t s = R(2.0) * GN_SQRT(gn_max(cand[k], R(1e-300)));
    real_t d21 = m[7] - m[5], d02 = m[2] - m[6], d10 = m[3] - m[1];
    real_t s21 = m[7] + m[5], s02 = m[2] + m[6], s10 = m[3] + m[1];
    if (k == 0) {
        q[0] = R(0.25) * s; q[1] = d21 / s; q[2] = d02 / s; q[3] = d10 / s;
    } else if (k == 1) {
        q[0] = d21 / s; q[1] = R(0.25) * s; q[2] = s10 / s; q[3] = s02 / s;
    } else if (k == 2) {
        q[0] = d02 / s; q[1] = s10 / s; q[2] = R(0.25) * s; q[3] = s21 / s;
    } else {
        q[0] = d10 / s; q[1] = s02 / s; q[2] = s21 / s; q[3] = R(0.25) * s;
    }
    real_t n = GN_SQRT(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    for (int i = 0; i < 4; ++i) {
        q[i] = q[i] / n;
    }
}

/* q_nb (ENU from body) from an accelerometer (pointing up at rest) and, when mag is not
 * a null pointer, a magnetometer vector (any units): TRIAD with the accelerometer exact, the yaw 0
 * without a field (or with one parallel to gravity). gnomon.estimators.initial.
 * Returns false (and the identity) for a zero accelerometer vector. */
static inline bool gn_attitude_from_acc_mag(const real_t a[3], const real_t *mag, real_t q[4])
{
    real_t na = GN_SQRT(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    q[0] = R(1.0); q[1] = R(0.0); q[2] = R(0.0); q[3] = R(0.0);
    if (!(na > R(0.0))) {
        return false;
    }
    real_t u[3] = {a[0] / na, a[1] / na, a[2] / na};
    real_t hr = R(0.5) * GN_ATAN2(u[1], u[2]);
    real_t hp = R(0.5) * GN_ATAN2(-u[0], GN_SQRT(u[1] * u[1] + u[2] * u[2]));
    real_t cr = GN_COS(hr), sr = GN_SIN(hr), cp = GN_COS(hp), sp = GN_SIN(hp);
    q[0] = cp * cr;  /* quat_from_euler([roll, pitch, 0]) */
    q[1] = cp * sr;
    q[2] = sp * cr;
    q[3] = -(sp * sr);
    if (mag == 0) {
        return true;
    }
    real_t m[3] = {mag[0], mag[1], mag[2]};
    real_t e[3] = {m[1] * u[2] - m[2] * u[1], m[2] * u[0] - m[0] * u[2], m[0] * u[1] - m[1] * u[0]};
    real_t ne = GN_SQRT(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]);
    real_t nm = GN_SQRT(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
    if (!(ne > R(1e-9) * gn_max(nm, R(1e-300)))) {
        return true;
    }
    for (int i = 0; i < 3; ++i) {
        e[i] = e[i] / ne;
    }
    real_t n[3] = {u[1] * e[2] - u[2] * e[1], u[2] * e[0] - u[0] * e[2], u[0] * e[1] - u[1] * e[0]};
    real_t dcm[9] = {e[0], e[1], e[2], n[0], n[1], n[2], u[0], u[1], u[2]};
    gn_quat_from_dcm(dcm, q);
    return true;
}

#endif /* GNOMON_QUAT_H */
