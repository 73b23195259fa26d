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
} gn_filter;

static void gn_runner_start(gn_filter *f, const gn_rows *r)
{
    f->p = GNOMON_ROBUST_AHRS_PARAMS;
    double max_dt = (double)GN_TO_DOUBLE(f->p.max_dt_s);
    double ts = gn_sensor_dt(r, 0, max_dt, 100, 0.01);
    double ts_acc = gn_sensor_dt(r, 1, max_dt, 100, 0.01);
    double ts_mag = gn_sensor_dt(r, 2, max_dt, 100, 0.01);
    gnomon_robust_ahrs_init(&f->s, &f->c, &f->p, R(ts), R(ts_acc), R(ts_mag));
}

static void gn_adapter_acc(gn_filter *f, const real_t a[3]) { gnomon_robust_ahrs_update_acc(&f->s, a); }
static void gn_adapter_mag(gn_filter *f, const real_t m[3]) { gnomon_robust_ahrs_update_mag(&f->s, m); }
static void gn_adapter_gyro(gn_filter *f, real_t dt, const real_t g[3])
{
    gnomon_robust_ahrs_update_gyro(&f->s, &f->c, dt, g);
}
static void gn_adapter_quat(const gn_filter *f, real_t q[4]) { gnomon_robust_ahrs_get_quat(&f->s, q); }
