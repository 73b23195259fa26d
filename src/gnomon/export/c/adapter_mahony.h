/* gnomon_run's adapter for mahony: the start as gnomon's Mahony.prepare (the initial
 * attitude from the mean of the first init_samples usable accelerometer and magnetometer
 * samples), then one call per sensor. Included by runner.c only. */
#include "mahony.h"
#include "mahony_params.h"

#define GN_STATE_TYPE gnomon_mahony_state
#define GN_PARAMS_TYPE gnomon_mahony_params

typedef struct {
    gnomon_mahony_state s;
    gnomon_mahony_params p;
    int flags;  /* the last update_gyro's */
} gn_filter;

static void gn_runner_start(gn_filter *f, const gn_rows *r)
{
    double a[3] = {0.0, 0.0, 0.0}, m[3] = {0.0, 0.0, 0.0};
    real_t ar[3], mr[3];
    f->p = GNOMON_MAHONY_PARAMS;
    gnomon_mahony_init(&f->s, &f->p);
    f->flags = 0;
    bool has_a = gn_first_usable_mean(r, r->a, r->a_ok, f->p.init_samples, a);
    bool has_m = r->has_mag && gn_first_usable_mean(r, r->m, r->m_ok, f->p.init_samples, m);
    if (has_a) {
        to_real(a, ar);
        to_real(m, mr);
        gnomon_mahony_start(&f->s, &f->p, ar, has_m ? mr : 0);
    }
}

static void gn_adapter_acc(gn_filter *f, const real_t a[3]) { gnomon_mahony_update_acc(&f->s, a); }
static void gn_adapter_mag(gn_filter *f, const real_t m[3]) { gnomon_mahony_update_mag(&f->s, m); }
static void gn_adapter_gyro(gn_filter *f, real_t dt, const real_t g[3])
{
    f->flags = gnomon_mahony_update_gyro(&f->s, &f->p, dt, g);
}
static void gn_adapter_quat(const gn_filter *f, real_t q[4]) { gnomon_mahony_get_quat(&f->s, q); }

/* gnomon_run_signals' columns per estimate, in the order of gnomon's mahony Estimate
 * signals (FilterSpec.signals): bias_rad_s (3), acc_skipped, mag_skipped, gap */
#define GN_N_SIGNALS 6
static void gn_adapter_signals(const gn_filter *f, double *out)
{
    for (int k = 0; k < 3; ++k) {
        out[k] = GN_TO_DOUBLE(f->s.bias[k]);
    }
    out[3] = (f->flags & GNOMON_MAHONY_ACC_SKIPPED) != 0;
    out[4] = (f->flags & GNOMON_MAHONY_MAG_SKIPPED) != 0;
    out[5] = (f->flags & GNOMON_MAHONY_GAP) != 0;
}
