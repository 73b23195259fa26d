/* gnomon_run's adapter for robust-ahrs: the start as gnomon's RobustAHRS.prepare (the
 * nominal sample times of the gyro, the accelerometer and the magnetometer: the median of
 * each sensor's first 100 intervals in (0, max_dt_s], 0.01 s when there is none), then
 * one call per sensor. Included by runner.c only.
 *
 * The CSV keeps each sample at its own stamp (a row per stamp: gnomon's multi-rate CSV), so
 * these are the intervals Recording.nominal_dt_s takes; `gnomon_run --ts G,A,M` (and
 * gnomon_run_rows_ts) give them instead, as a board that knows its rates passes them to
 * gnomon_robust_ahrs_init. */
#include "robust_ahrs.h"
#include "robust_ahrs_params.h"

#define GN_STATE_TYPE gnomon_robust_ahrs_state
#define GN_PARAMS_TYPE gnomon_robust_ahrs_params

typedef struct {
    gnomon_robust_ahrs_state s;
    gnomon_robust_ahrs_coefficients c;
    gnomon_robust_ahrs_params p;
    int flags;  /* the last update_gyro's */
} gn_filter;

static void gn_runner_start(gn_filter *f, const gn_rows *r)
{
    f->p = GNOMON_ROBUST_AHRS_PARAMS;
    double max_dt = (double)GN_TO_DOUBLE(f->p.max_dt_s);
    double ts = gn_sensor_dt(r, 0, max_dt, 100, 0.01);
    double ts_acc = gn_sensor_dt(r, 1, max_dt, 100, 0.01);
    double ts_mag = gn_sensor_dt(r, 2, max_dt, 100, 0.01);
    gnomon_robust_ahrs_init(&f->s, &f->c, &f->p, R(ts), R(ts_acc), R(ts_mag));
    f->flags = 0;
}

static void gn_adapter_acc(gn_filter *f, const real_t a[3]) { gnomon_robust_ahrs_update_acc(&f->s, a); }
static void gn_adapter_mag(gn_filter *f, const real_t m[3]) { gnomon_robust_ahrs_update_mag(&f->s, m); }
static void gn_adapter_gyro(gn_filter *f, real_t dt, const real_t g[3])
{
    f->flags = gnomon_robust_ahrs_update_gyro(&f->s, &f->c, dt, g);
}
static void gn_adapter_quat(const gn_filter *f, real_t q[4]) { gnomon_robust_ahrs_get_quat(&f->s, q); }

/* gnomon_run_signals' columns per estimate, in the order of gnomon's robust-ahrs Estimate
 * signals (FilterSpec.signals): bias_rad_s (3), bias_at_limit, rest, mag_disturbed,
 * acc_correction_rad_s, mag_gain, hard_iron (3), acc_skipped, mag_skipped, gap */
#define GN_N_SIGNALS 14
static void gn_adapter_signals(const gn_filter *f, double *out)
{
    const gnomon_robust_ahrs_state *s = &f->s;
    for (int k = 0; k < 3; ++k) {
        out[k] = GN_TO_DOUBLE(s->bias[k]);
        out[8 + k] = GN_TO_DOUBLE(s->hard_iron.o[k]);
    }
    out[3] = (f->flags & GNOMON_ROBUST_AHRS_BIAS_AT_LIMIT) != 0;
    out[4] = s->rest;
    out[5] = s->mag_disturbed;
    out[6] = GN_TO_DOUBLE(s->acc_rate);
    out[7] = GN_TO_DOUBLE(s->k_mag_used);
    out[11] = (f->flags & GNOMON_ROBUST_AHRS_ACC_SKIPPED) != 0;
    out[12] = (f->flags & GNOMON_ROBUST_AHRS_MAG_SKIPPED) != 0;
    out[13] = (f->flags & GNOMON_ROBUST_AHRS_GAP) != 0;
}
