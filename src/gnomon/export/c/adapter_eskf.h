/* gnomon_run's adapter for eskf-r3 / eskf-r6: the start as gnomon's Eskf.prepare, then one
 * call per sensor; and `gnomon_run --phases` (GN_ADAPTER_PHASES): the phases of the step
 * timed (ns) or, in gnomon_count, counted (operations), for seed 002's cost comparison.
 * Included by runner.c only (the runner's heap and clock; the library has neither).
 *
 * The start (Eskf.prepare): the first init_time seconds after the first gyro sample
 * (rec.t[0] + init_time): n = min(accelerometer samples, magnetometer samples) stamped in
 * them (at least one each), and the first n of each, paired by index (Eskf._init_state).
 * The CSV keeps each sample at its own stamp (a row per stamp: gnomon's multi-rate CSV),
 * so these are the samples Eskf.prepare reads. */
#include "eskf.h"
#include "eskf_params.h"

#define GN_STATE_TYPE gnomon_eskf_state
#define GN_PARAMS_TYPE gnomon_eskf_params

typedef struct {
    gnomon_eskf_state s;
    gnomon_eskf_params p;
    int flags;                      /* the last update_gyro's */
    gnomon_eskf_measurement meas;   /* and its measurement (the innovation signal) */
} gn_filter;

/* rows of `ok` up to time t_end: how many, at least one (np.searchsorted, side right) */
static long gn_eskf_count_until(const gn_rows *r, const bool *ok, double t_end)
{
    long n = 0;
    for (long i = 0; i < r->n && r->t[i] <= t_end; ++i) {
        n += ok[i] ? 1 : 0;
    }
    return n > 0 ? n : 1;
}

/* the first n rows of v with ok into out (zero rows, dropouts, where there are fewer) */
static void gn_eskf_first(const gn_rows *r, const double *v, const bool *ok, long n,
                          real_t *out)
{
    long k = 0;
    for (long i = 0; i < r->n && k < n; ++i) {
        if (ok[i]) {
            to_real(v + 3 * i, out + 3 * k++);
        }
    }
    for (; k < n; ++k) {
        out[3 * k] = out[3 * k + 1] = out[3 * k + 2] = R(0.0);
    }
}

static void gn_runner_start(gn_filter *f, const gn_rows *r)
{
    f->p = GNOMON_ESKF_PARAMS;
    gnomon_eskf_init(&f->s, &f->p);
    f->flags = 0;
    f->meas.r = 0;
    double t_end = r->t0 + GN_TO_DOUBLE(f->p.init_time);
    long n = gn_eskf_count_until(r, r->a_ok, t_end);
    if (r->has_mag) {
        long n_mag = gn_eskf_count_until(r, r->m_ok, t_end);
        n = n_mag < n ? n_mag : n;
    }
    real_t *a = (real_t *)malloc(sizeof(real_t) * 3 * (size_t)n);
    real_t *m = (real_t *)malloc(sizeof(real_t) * 3 * (size_t)n);
    if (a == 0 || m == 0) {
        die("out of memory", -1);
    }
    gn_eskf_first(r, r->a, r->a_ok, n, a);
    gn_eskf_first(r, r->m, r->m_ok, n, m);
    gnomon_eskf_start(&f->s, &f->p, (int32_t)n, a, r->has_mag ? m : 0);
    free(a);
    free(m);
}

static void gn_adapter_acc(gn_filter *f, const real_t a[3]) { gnomon_eskf_update_acc(&f->s, a); }
static void gn_adapter_mag(gn_filter *f, const real_t m[3]) { gnomon_eskf_update_mag(&f->s, m); }
static void gn_adapter_gyro(gn_filter *f, real_t dt, const real_t g[3])
{
    f->flags = gnomon_eskf_update_gyro_measured(&f->s, &f->p, dt, g, &f->meas);
}
static void gn_adapter_quat(const gn_filter *f, real_t q[4]) { gnomon_eskf_get_quat(&f->s, q); }

/* gnomon_run_signals' columns per estimate, in the order of gnomon's eskf Estimate signals
 * (FilterSpec.signals): bias_rad_s (3), bias_at_limit, innovation (r: the measurement of
 * a row both sensors corrected, else 0, as the kernel leaves it), cov_diag (6: the
 * diagonal of P), update_skipped */
#define GN_N_SIGNALS (11 + GNOMON_ESKF_R)
static void gn_adapter_signals(const gn_filter *f, double *out)
{
    bool full = f->meas.r == GNOMON_ESKF_R;
    for (int k = 0; k < 3; ++k) {
        out[k] = GN_TO_DOUBLE(f->s.bias[k]);
    }
    out[3] = (f->flags & GNOMON_ESKF_AT_LIMIT) != 0;
    for (int j = 0; j < GNOMON_ESKF_R; ++j) {
        out[4 + j] = full ? GN_TO_DOUBLE(f->meas.y[j]) : 0.0;
    }
    for (int j = 0; j < 6; ++j) {
        out[4 + GNOMON_ESKF_R + j] = GN_TO_DOUBLE(f->s.P[7 * j]);
    }
    out[10 + GNOMON_ESKF_R] = (f->flags & GNOMON_ESKF_SKIPPED) != 0;
}

/* ---- gnomon_run --phases / gnomon_count --phases ---- */
#ifndef GN_RUNNER_NO_MAIN
#define GN_ADAPTER_PHASES 1

/* Rows with both sensors (the full correction, r = GNOMON_ESKF_R rows) captured from one
 * pass over the recording: the state after the prediction, the measurement and the row's
 * inputs. At most `cap` of them, evenly spread (0: all). */
typedef struct {
    long n, full;                  /* rows captured; rows with both sensors */
    gnomon_eskf_state *pre;        /* the state after predict, before measure */
    gnomon_eskf_state *mid;        /* after measure, before apply */
    gnomon_eskf_measurement *meas; /* measure's result */
    double *in;                    /* per row: dt, gyro[3], acc[3], mag[3] */
} gn_eskf_capture;

static void gn_eskf_capture_rows(const gn_rows *r, long cap, gn_eskf_capture *c)
{
    gn_filter f;
    long full = 0;
    gn_runner_start(&f, r);
    for (long i = 0; i < r->n; ++i) {
        full += r->g_ok[i] && r->a_ok[i] && r->m_ok[i];
    }
    long every = cap > 0 && full > cap ? (full + cap - 1) / cap : 1;
    c->full = full;
    size_t room = (size_t)(full / every + 1);
    c->n = 0;
    c->pre = (gnomon_eskf_state *)malloc(sizeof(gnomon_eskf_state) * room);
    c->mid = (gnomon_eskf_state *)malloc(sizeof(gnomon_eskf_state) * room);
    c->meas = (gnomon_eskf_measurement *)malloc(sizeof(gnomon_eskf_measurement) * room);
    c->in = (double *)malloc(sizeof(double) * 10 * room);
    if (c->pre == 0 || c->mid == 0 || c->meas == 0 || c->in == 0) {
        die("out of memory", -1);
    }
    long seen = 0;
    double t_gyro = NAN;
    for (long i = 0; i < r->n; ++i) {
        real_t a[3], m[3], g[3];
        if (!r->g_ok[i]) {  /* the phases are timed on rows with all three sensors */
            continue;
        }
        double dt = isnan(t_gyro) ? 0.0 : r->t[i] - t_gyro;
        t_gyro = r->t[i];
        to_real(r->a + 3 * i, a);
        to_real(r->m + 3 * i, m);
        to_real(r->g + 3 * i, g);
        gnomon_eskf_predict(&f.s, &f.p, R(dt), g);
        gnomon_eskf_state pre = f.s;
        gnomon_eskf_measurement meas;
        gnomon_eskf_measure(&f.s, &f.p, R(dt), r->a_ok[i] ? a : 0, r->m_ok[i] ? m : 0, &meas);
        if (meas.r == GNOMON_ESKF_R && (seen++ % every) == 0 && (size_t)c->n < room) {
            long k = c->n++;
            double *in = c->in + 10 * k;
            c->pre[k] = pre;
            c->mid[k] = f.s;
            c->meas[k] = meas;
            in[0] = dt;
            for (int j = 0; j < 3; ++j) {
                in[1 + j] = r->g[3 * i + j];
                in[4 + j] = r->a[3 * i + j];
                in[7 + j] = r->m[3 * i + j];
            }
        }
        gnomon_eskf_apply(&f.s, &f.p, &meas);
    }
}

/* phase `ph` of a captured row on the state s (in place; for apply the state after
 * measure, for the others the state after predict): 1 predict, 2 measure, 3 gain,
 * 4 kalman_update, 5 apply; returns a value of the result (kept by the caller) */
static double gn_eskf_phase(int ph, gnomon_eskf_state *s, const gnomon_eskf_measurement *mk,
                            const double *in)
{
    real_t v[3], w[3], K[36];
    gnomon_eskf_measurement meas;
    switch (ph) {
    case 1:
        to_real(in + 1, v);
        gnomon_eskf_predict(s, &GNOMON_ESKF_PARAMS, R(in[0]), v);
        return GN_TO_DOUBLE(s->P[0]);
    case 2:
        to_real(in + 4, v);
        to_real(in + 7, w);
        gnomon_eskf_measure(s, &GNOMON_ESKF_PARAMS, R(in[0]), v, w, &meas);
        return GN_TO_DOUBLE(meas.y[0]);
    case 3:
        gnomon_eskf_gain(s->P, mk->D1, mk->Rd, mk->r, K);
        return GN_TO_DOUBLE(K[0]);
    case 4:
        gnomon_eskf_kalman_update(s->P, mk->D1, mk->Rd, mk->y, mk->r, K);
        return GN_TO_DOUBLE(s->P[0]);
    default:
        gnomon_eskf_apply(s, &GNOMON_ESKF_PARAMS, mk);
        return GN_TO_DOUBLE(s->q[0]);
    }
}


#ifdef GNOMON_COUNT_OPS
static const char *GN_ESKF_PHASES[6] = {"", "predict", "measure", "gain", "kalman_update",
                                        "apply"};

/* operations of one call of each phase, the mean over every captured row */
static int gn_adapter_phases(const gn_rows *r)
{
    gn_eskf_capture c;
    gn_eskf_capture_rows(r, 0, &c);
    double ops[6][6], sink = 0.0;  /* [phase][add, mul, div, sqrt, trig, other] */
    for (int ph = 1; ph < 6; ++ph) {
        gn_op_counts before = gn_ops;
        for (long k = 0; k < c.n; ++k) {
            gnomon_eskf_state s = ph == 5 ? c.mid[k] : c.pre[k];
            sink += gn_eskf_phase(ph, &s, &c.meas[k], c.in + 10 * k);
        }
        double d = c.n > 0 ? (double)c.n : 1.0;
        ops[ph][0] = (double)(gn_ops.add - before.add) / d;
        ops[ph][1] = (double)(gn_ops.mul - before.mul) / d;
        ops[ph][2] = (double)(gn_ops.div - before.div) / d;
        ops[ph][3] = (double)(gn_ops.sqrt - before.sqrt) / d;
        ops[ph][4] = (double)(gn_ops.trig - before.trig) / d;
        ops[ph][5] = (double)(gn_ops.other - before.other) / d;
    }
    for (int j = 0; j < 6; ++j) {  /* measure + apply: the row after the prediction */
        ops[0][j] = ops[2][j] + ops[5][j];
    }
    printf("{\"r\": %d, \"rows\": %ld, \"updates\": %ld, \"ops\": {", GNOMON_ESKF_R, r->n,
           c.full);
    for (int ph = 0; ph < 6; ++ph) {
        const double *o = ops[(ph + 1) % 6];
        printf("\"%s\": {\"add\": %.2f, \"mul\": %.2f, \"div\": %.2f, \"sqrt\": %.2f, "
               "\"trig\": %.2f, \"other\": %.2f, \"total\": %.2f}%s",
               ph == 5 ? "measurement_update" : GN_ESKF_PHASES[ph + 1], o[0], o[1], o[2],
               o[3], o[4], o[5], o[0] + o[1] + o[2] + o[3] + o[4] + o[5], ph == 5 ? "" : ", ");
    }
    printf("}, \"sink\": %.3g}\n", sink);
    return 0;
}
#else
/* the names of the timed phases: the gain alone is timed in its loop form (gnomon_eskf_gain;
 * the filter runs it only inside the straight-line kalman_update) */
static const char *GN_ESKF_TIMED[6] = {"", "predict", "measure", "gain_loops",
                                       "kalman_update", "apply"};

static double gn_eskf_now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* ns of one call of each phase: the fastest of many passes over up to 1024 captured rows
 * (each pass on a fresh copy of their states, made outside the timed loop) */
static int gn_adapter_phases(const gn_rows *r)
{
    gn_eskf_capture c;
    gn_eskf_capture_rows(r, 1024, &c);
    gnomon_eskf_state *work = (gnomon_eskf_state *)malloc(sizeof(gnomon_eskf_state)
                                                          * (size_t)(c.n > 0 ? c.n : 1));
    if (work == 0) {
        die("out of memory", -1);
    }
    double ns[6], sink = 0.0;
    for (int ph = 1; ph < 6; ++ph) {
        double best = 1e300, elapsed = 0.0;
        long passes = 0;
        while (c.n > 0 && (elapsed < 0.1 || passes < 5)) {
            memcpy(work, ph == 5 ? c.mid : c.pre, sizeof(gnomon_eskf_state) * (size_t)c.n);
            double t0 = gn_eskf_now_s();
            for (long k = 0; k < c.n; ++k) {
                sink += gn_eskf_phase(ph, &work[k], &c.meas[k], c.in + 10 * k);
            }
            double dt = gn_eskf_now_s() - t0;
            elapsed += dt;
            best = dt < best ? dt : best;
            ++passes;
        }
        ns[ph] = c.n > 0 ? 1e9 * best / (double)c.n : 0.0;
    }
    ns[0] = ns[2] + ns[5];
    printf("{\"r\": %d, \"rows\": %ld, \"updates\": %ld, \"timed\": %ld, \"ns\": {",
           GNOMON_ESKF_R, r->n, c.full, c.n);
    for (int ph = 1; ph < 6; ++ph) {
        printf("\"%s\": %.2f, ", GN_ESKF_TIMED[ph], ns[ph]);
    }
    printf("\"measurement_update\": %.2f}, \"sink\": %.3g}\n", ns[0], sink);
    free(work);
    return 0;
}
#endif
#endif /* GN_RUNNER_NO_MAIN */
