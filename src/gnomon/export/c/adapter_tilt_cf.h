/* gnomon_run's adapter for tilt-cf: the start as gnomon's TiltComplementaryFilter.prepare
 * (the start tilt from the mean of the first init_samples gyro rows with an accelerometer
 * sample, each row's the mean of its samples; the first row outputs it as it is), then one call per sensor (the magnetometer
 * is not used). Included by runner.c only. */
#include "tilt_cf.h"
#include "tilt_cf_params.h"

#define GN_STATE_TYPE gnomon_tilt_cf_state
#define GN_PARAMS_TYPE gnomon_tilt_cf_params

typedef struct {
    gnomon_tilt_cf_state s;
    gnomon_tilt_cf_params p;
    int flags;  /* the last update_gyro's */
} gn_filter;

static void gn_runner_start(gn_filter *f, const gn_rows *r)
{
    double a[3] = {0.0, 0.0, 0.0}, row[3] = {0.0, 0.0, 0.0};
    int used = 0, in_row = 0;
    f->p = GNOMON_TILT_CF_PARAMS;
    gnomon_tilt_cf_init(&f->s, &f->p);
    f->flags = 0;
    /* the gyro rows' accelerometer (the mean of the samples since the previous gyro
     * sample: Recording.on_time_base), zero vectors too, as gnomon's _start_at */
    for (long i = 0; i < r->n && used < f->p.init_samples; ++i) {
        if (r->a_ok[i]) {
            for (int k = 0; k < 3; ++k) {
                row[k] += r->a[3 * i + k];
            }
            ++in_row;
        }
        if (r->g_ok[i] && in_row > 0) {
            for (int k = 0; k < 3; ++k) {
                a[k] += row[k] / in_row;
                row[k] = 0.0;
            }
            in_row = 0;
            ++used;
        }
    }
    if (used > 0) {
        real_t ar[3];
        for (int k = 0; k < 3; ++k) {
            a[k] /= used;
        }
        to_real(a, ar);
        gnomon_tilt_cf_start(&f->s, &f->p, ar);
    }
}

static void gn_adapter_acc(gn_filter *f, const real_t a[3]) { gnomon_tilt_cf_update_acc(&f->s, a); }
static void gn_adapter_mag(gn_filter *f, const real_t m[3]) { (void)f; (void)m; }
static void gn_adapter_gyro(gn_filter *f, real_t dt, const real_t g[3])
{
    f->flags = gnomon_tilt_cf_update_gyro(&f->s, &f->p, dt, g);
}
static void gn_adapter_quat(const gn_filter *f, real_t q[4]) { gnomon_tilt_cf_get_quat(&f->s, q); }

/* gnomon_run_signals' columns per estimate, in the order of gnomon's tilt-cf Estimate
 * signals (FilterSpec.signals): acc_rejected, bias_rad_s (3) */
#define GN_N_SIGNALS 4
static void gn_adapter_signals(const gn_filter *f, double *out)
{
    out[0] = (f->flags & GNOMON_TILT_CF_ACC_REJECTED) != 0;
    for (int k = 0; k < 3; ++k) {
        out[1 + k] = GN_TO_DOUBLE(f->s.bias[k]);
    }
}
