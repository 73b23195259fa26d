/* gnomon_run: a gnomon CSV on stdin through the exported filter, its attitude on stdout.
 *
 *   ./gnomon_run < rec.csv > q.csv        t,q_w,q_x,q_y,q_z (17 significant digits), one
 *                                         row per gyro sample, as `gnomon estimate --out`
 *   ./gnomon_run --bench < rec.csv        {"ns_per_update": ..., ...} on this machine
 *   ./gnomon_run --ts G,A,M < rec.csv     the sensors' nominal sample times (s), gnomon's
 *                                         Recording.nominal_dt_s (filters with coefficients
 *                                         of the sample times; default: from the rows)
 *   ./gnomon_count < rec.csv              (make count) operations per update, counted
 *   ./gnomon_run --phases < rec.csv       (adapters that define GN_ADAPTER_PHASES) ns per
 *                                         phase of the step; gnomon_count --phases: operations
 *
 * Input: a header naming t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z (any order;
 * the magnetometer columns may be absent) in s, rad/s, m/s^2 and uT; an empty cell is no
 * sample of that sensor in that row: each sensor at its own stamps, as gnomon reads a
 * multi-rate CSV (`gnomon convert LOG rec.csv` writes one). The whole file is read first:
 * the filter starts from its first samples as gnomon's `run` starts from a recording
 * (gn_runner_start in runner_adapter.h), then every row is one call of each of its
 * sensors' updates, the gyro's last (the step, with the samples that came since the
 * previous gyro sample: Recording.on_time_base). One output row per gyro sample.
 *
 * The runner is a test and measurement tool for a computer (heap, stdio, clock); the
 * library itself (the filter's .c/.h) has none of them.
 */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "gnomon_real.h"

#ifdef GNOMON_COUNT_OPS
gn_op_counts gn_ops;
#endif

typedef struct {
    long n;                /* rows: sample events in time order */
    double *t, *g, *a, *m; /* (n,), (n,3) each */
    bool *g_ok, *a_ok, *m_ok; /* which sensors have a sample in the row */
    bool has_mag;
    long n_gyro;           /* rows with a gyro sample: the filter's rows, one estimate each */
    double t0;             /* the first gyro sample's time (gnomon's rec.t[0]) */
    /* the nominal sample times (s) of the gyro, accelerometer and magnetometer when the
     * caller knows them (--ts; gnomon_run_rows_ts), 0 when not: gn_sensor_dt */
    double ts[3];
} gn_rows;

static const char *COLS[10] = {"t", "gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z",
                               "mag_x", "mag_y", "mag_z"};

static inline void die(const char *what, long row)
{
    if (row >= 0) {
        fprintf(stderr, "gnomon_run: row %ld: %s\n", row, what);
    } else {
        fprintf(stderr, "gnomon_run: %s\n", what);
    }
    exit(2);
}

/* split `line` at commas in place; returns the number of cells */
static inline int split(char *line, char **cells, int max)
{
    int n = 0;
    char *p = line;
    while (n < max) {
        cells[n++] = p;
        char *c = strchr(p, ',');
        if (c == 0) {
            break;
        }
        *c = '\0';
        p = c + 1;
    }
    for (int i = 0; i < n; ++i) { /* trim */
        char *s = cells[i];
        while (*s == ' ' || *s == '\t') {
            ++s;
        }
        char *e = s + strlen(s);
        while (e > s && (e[-1] == ' ' || e[-1] == '\t' || e[-1] == '\r' || e[-1] == '\n')) {
            *--e = '\0';
        }
        cells[i] = s;
    }
    return n;
}

static inline void read_rows(FILE *in, gn_rows *r)
{
    static char line[1 << 16];
    char *cells[64];
    int col[10];
    if (fgets(line, sizeof line, in) == 0) {
        die("no header line", -1);
    }
    int nh = split(line, cells, 64);
    for (int k = 0; k < 10; ++k) {
        col[k] = -1;
        for (int j = 0; j < nh; ++j) {
            if (strcmp(cells[j], COLS[k]) == 0) {
                col[k] = j;
            }
        }
        if (col[k] < 0 && k < 7) {
            fprintf(stderr, "gnomon_run: missing column %s\n", COLS[k]);
            exit(2);
        }
    }
    r->has_mag = col[7] >= 0 && col[8] >= 0 && col[9] >= 0;
    long cap = 1024;
    r->n = 0;
    r->ts[0] = r->ts[1] = r->ts[2] = 0.0;
    r->t = (double *)malloc(sizeof(double) * cap);
    r->g = (double *)malloc(sizeof(double) * 3 * cap);
    r->a = (double *)malloc(sizeof(double) * 3 * cap);
    r->m = (double *)malloc(sizeof(double) * 3 * cap);
    r->g_ok = (bool *)malloc(sizeof(bool) * cap);
    r->a_ok = (bool *)malloc(sizeof(bool) * cap);
    r->m_ok = (bool *)malloc(sizeof(bool) * cap);
    r->n_gyro = 0;
    r->t0 = NAN;
    while (fgets(line, sizeof line, in) != 0) {
        if (line[0] == '\n' || line[0] == '\r' || line[0] == '#') {
            continue;
        }
        if (r->n == cap) {
            cap *= 2;
            r->t = (double *)realloc(r->t, sizeof(double) * cap);
            r->g = (double *)realloc(r->g, sizeof(double) * 3 * cap);
            r->a = (double *)realloc(r->a, sizeof(double) * 3 * cap);
            r->m = (double *)realloc(r->m, sizeof(double) * 3 * cap);
            r->g_ok = (bool *)realloc(r->g_ok, sizeof(bool) * cap);
            r->a_ok = (bool *)realloc(r->a_ok, sizeof(bool) * cap);
            r->m_ok = (bool *)realloc(r->m_ok, sizeof(bool) * cap);
        }
        int nc = split(line, cells, 64);
        if (nc != nh) {
            die("wrong number of cells", r->n + 1);
        }
        double v[10];
        bool empty[10];
        for (int k = 0; k < 10; ++k) {
            empty[k] = col[k] < 0 || cells[col[k]][0] == '\0';
            v[k] = empty[k] ? NAN : strtod(cells[col[k]], 0);
        }
        if (empty[0]) {
            die("every row needs its time t", r->n + 1);
        }
        long i = r->n++;
        r->g_ok[i] = !empty[1] && !empty[2] && !empty[3];
        if (r->g_ok[i]) {
            r->t0 = r->n_gyro++ == 0 ? v[0] : r->t0;
        }
        r->t[i] = v[0];
        for (int k = 0; k < 3; ++k) {
            r->g[3 * i + k] = v[1 + k];
            r->a[3 * i + k] = v[4 + k];
            r->m[3 * i + k] = v[7 + k];
        }
        r->a_ok[i] = !empty[4] && !empty[5] && !empty[6];
        r->m_ok[i] = r->has_mag && !empty[7] && !empty[8] && !empty[9];
    }
    if (r->n_gyro == 0) {
        die("no gyro samples", -1);
    }
}

/* ---- what gnomon's run does before the first sample, for the adapters ---- */

/* the mean of the first k rows of `v` whose vector is usable (finite, non-zero); false
 * when there is none (gnomon.estimators.initial.initial_attitude) */
static inline bool gn_first_usable_mean(const gn_rows *r, const double *v, const bool *ok, int k,
                                 double out[3])
{
    int used = 0;
    out[0] = out[1] = out[2] = 0.0;
    for (long i = 0; i < r->n && used < k; ++i) {
        const double *x = v + 3 * i;
        if (!ok[i] || !isfinite(x[0]) || !isfinite(x[1]) || !isfinite(x[2]) ||
            (x[0] == 0.0 && x[1] == 0.0 && x[2] == 0.0)) {
            continue;
        }
        out[0] += x[0];
        out[1] += x[1];
        out[2] += x[2];
        ++used;
    }
    if (used == 0) {
        return false;
    }
    out[0] /= used;
    out[1] /= used;
    out[2] /= used;
    return true;
}

static inline int cmp_double(const void *x, const void *y)
{
    double a = *(const double *)x, b = *(const double *)y;
    return (a > b) - (a < b);
}

/* a sensor's nominal sample interval: the median of its first `first` intervals that
 * are > 0 and <= max_dt (Recording.nominal_dt_s); `fallback` when there is none.
 * `ok` NULL: every row (the gyro). */
static inline double gn_nominal_dt(const gn_rows *r, const bool *ok, double max_dt, int first,
                            double fallback)
{
    double d[128];
    int n = 0;
    double prev = NAN;
    for (long i = 0; i < r->n && n < first && n < 128; ++i) {
        if (!(ok != 0 ? ok[i] : r->g_ok[i])) {
            continue;
        }
        if (!isnan(prev)) {
            double dt = r->t[i] - prev;
            if (dt > 0.0 && dt <= max_dt) {
                d[n++] = dt;
            }
        }
        prev = r->t[i];
    }
    if (n == 0) {
        return fallback;
    }
    qsort(d, (size_t)n, sizeof(double), cmp_double);
    return n % 2 ? d[n / 2] : 0.5 * (d[n / 2 - 1] + d[n / 2]);
}

/* sensor k's nominal sample interval (0 gyro, 1 accelerometer, 2 magnetometer): the
 * caller's (r->ts, from gnomon's Recording.nominal_dt_s: the sensor's own time stamps,
 * which a gnomon CSV does not keep) when given, else gn_nominal_dt over the rows with a
 * sample of it (`fallback` for a magnetometer the rows do not have) */
static inline double gn_sensor_dt(const gn_rows *r, int k, double max_dt, int first,
                                  double fallback)
{
    if (r->ts[k] > 0.0) {
        return r->ts[k];
    }
    if (k == 2 && !r->has_mag) {
        return fallback;
    }
    return gn_nominal_dt(r, k == 0 ? 0 : (k == 1 ? r->a_ok : r->m_ok), max_dt, first, fallback);
}

static void to_real(const double *x, real_t out[3])
{
    out[0] = R(x[0]);
    out[1] = R(x[1]);
    out[2] = R(x[2]);
}

/* the filter: gn_filter, gn_runner_start (gnomon's prepare) and one call per sensor */
#include "runner_adapter.h"

/* one row: its accelerometer and magnetometer samples, then its gyro sample's step (dt
 * since the previous gyro sample, 0 at the first: *t_gyro NAN); whether it had a gyro */
static bool run_row(gn_filter *f, const gn_rows *r, long i, double *t_gyro)
{
    real_t v[3];
    if (r->a_ok[i]) {
        to_real(r->a + 3 * i, v);
        gn_adapter_acc(f, v);
    }
    if (r->m_ok[i]) {
        to_real(r->m + 3 * i, v);
        gn_adapter_mag(f, v);
    }
    if (!r->g_ok[i]) {
        return false;
    }
    to_real(r->g + 3 * i, v);
    gn_adapter_gyro(f, R(isnan(*t_gyro) ? 0.0 : r->t[i] - *t_gyro), v);
    *t_gyro = r->t[i];
    return true;
}

/* the signals an adapter reports per estimate besides the attitude (GN_N_SIGNALS doubles,
 * gn_adapter_signals; gnomon's FilterSpec.signals names them): none by default */
#ifndef GN_N_SIGNALS
#define GN_N_SIGNALS 0
static void gn_adapter_signals(const gn_filter *f, double *out)
{
    (void)f;
    (void)out;
}
#endif

/* the whole recording through the filter, for gnomon's Python backend (ctypes; built
 * as a shared library with GN_RUNNER_NO_MAIN): rows as gn_rows holds them (sample events in
 * time order, g_ok/a_ok/m_ok saying which sensors each has); ts (3,) the sensors' nominal
 * sample times or a null pointer (gn_rows.ts); q_out (rows with a gyro sample, 4);
 * sig_out (rows with a gyro sample, GN_N_SIGNALS) or a null pointer.
 * Returns the number of estimates. */
long gnomon_run_signals(long n, double *t, double *g, double *a, bool *g_ok, bool *a_ok,
                        double *m, bool *m_ok, int has_mag, const double *ts, double *q_out,
                        double *sig_out)
{
    gn_rows r;
    for (int k = 0; k < 3; ++k) {
        r.ts[k] = ts != 0 && ts[k] > 0.0 ? ts[k] : 0.0;
    }
    r.n = n;
    r.t = t;
    r.g = g;
    r.a = a;
    r.m = m;
    r.g_ok = g_ok;
    r.a_ok = a_ok;
    r.m_ok = m_ok;
    r.has_mag = has_mag != 0;
    r.n_gyro = 0;
    r.t0 = NAN;
    for (long i = 0; i < n; ++i) {
        if (g_ok[i]) {
            r.t0 = r.n_gyro++ == 0 ? t[i] : r.t0;
        }
    }
    gn_filter f;
    gn_runner_start(&f, &r);
    double t_gyro = NAN;
    long k = 0;
    for (long i = 0; i < n; ++i) {
        if (run_row(&f, &r, i, &t_gyro)) {
            real_t q[4];
            gn_adapter_quat(&f, q);
            for (int j = 0; j < 4; ++j) {
                q_out[4 * k + j] = GN_TO_DOUBLE(q[j]);
            }
            if (sig_out != 0 && GN_N_SIGNALS > 0) {
                gn_adapter_signals(&f, sig_out + (long)GN_N_SIGNALS * k);
            }
            ++k;
        }
    }
    return k;
}

/* GN_N_SIGNALS: the width of gnomon_run_signals' sig_out rows */
int gnomon_n_signals(void)
{
    return GN_N_SIGNALS;
}

/* streaming from Python (gnomon.export.backend.c_filter_class, `gnomon live`): the
 * filter in the caller's memory (gnomon_filter_size bytes), started with the sensors'
 * nominal sample times (s; the adapters whose start needs only those: the ones that name
 * their signals), then any number of calls of gnomon_filter_rows */
long gnomon_filter_size(void)
{
    return (long)sizeof(gn_filter);
}

void gnomon_filter_start(gn_filter *f, double ts_gyro, double ts_acc, double ts_mag)
{
    gn_rows r;
    memset(&r, 0, sizeof r);
    r.ts[0] = ts_gyro;
    r.ts[1] = ts_acc;
    r.ts[2] = ts_mag;
    r.has_mag = true;
    r.t0 = 0.0;
    gn_runner_start(f, &r);
}

/* n rows through the filter: dt (n,) s since the previous row, g (n,3) rad/s, a (n,3)
 * m/s^2 and m (n,3) uT or null pointers (a non-finite row: no sample of that sensor);
 * q_out (n,4), sig_out (n, GN_N_SIGNALS) or a null pointer */
void gnomon_filter_rows(gn_filter *f, long n, const double *dt, const double *g,
                        const double *a, const double *m, double *q_out, double *sig_out)
{
    real_t v[3], q[4];
    for (long i = 0; i < n; ++i) {
        if (a != 0) {
            to_real(a + 3 * i, v);
            gn_adapter_acc(f, v);
        }
        if (m != 0) {
            to_real(m + 3 * i, v);
            gn_adapter_mag(f, v);
        }
        to_real(g + 3 * i, v);
        gn_adapter_gyro(f, R(dt[i]), v);
        gn_adapter_quat(f, q);
        for (int j = 0; j < 4; ++j) {
            q_out[4 * i + j] = GN_TO_DOUBLE(q[j]);
        }
        if (sig_out != 0 && GN_N_SIGNALS > 0) {
            gn_adapter_signals(f, sig_out + (long)GN_N_SIGNALS * i);
        }
    }
}

/* gnomon_run_signals without the signals */
long gnomon_run_rows_ts(long n, double *t, double *g, double *a, bool *g_ok, bool *a_ok,
                        double *m, bool *m_ok, int has_mag, const double *ts, double *q_out)
{
    return gnomon_run_signals(n, t, g, a, g_ok, a_ok, m, m_ok, has_mag, ts, q_out, 0);
}

/* gnomon_run_rows_ts without nominal sample times (each from the rows) */
long gnomon_run_rows(long n, double *t, double *g, double *a, bool *g_ok, bool *a_ok,
                     double *m, bool *m_ok, int has_mag, double *q_out)
{
    return gnomon_run_rows_ts(n, t, g, a, g_ok, a_ok, m, m_ok, has_mag, 0, q_out);
}

#ifndef GN_RUNNER_NO_MAIN
static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

int main(int argc, char **argv)
{
    /* --ts GYRO,ACC,MAG (s): the sensors' nominal sample times (gn_rows.ts), taken out of
     * argv before the other options are read */
    double ts[3] = {0.0, 0.0, 0.0};
    for (int i = 1; i < argc; ++i) {
        if (strcmp(argv[i], "--ts") == 0) {
            if (i + 1 >= argc || sscanf(argv[i + 1], "%lf,%lf,%lf", &ts[0], &ts[1], &ts[2]) != 3) {
                die("--ts needs GYRO,ACC,MAG (s)", -1);
            }
            for (int j = i; j + 2 <= argc; ++j) {
                argv[j] = argv[j + 2];
            }
            argc -= 2;
            break;
        }
    }
    bool bench = argc > 1 && strcmp(argv[1], "--bench") == 0;
    gn_rows r;
    read_rows(stdin, &r);
    for (int k = 0; k < 3; ++k) {
        r.ts[k] = ts[k] > 0.0 ? ts[k] : 0.0;
    }
#ifdef GN_ADAPTER_PHASES
    if (argc > 1 && strcmp(argv[1], "--phases") == 0) {
        return gn_adapter_phases(&r); /* the adapter's own breakdown by phase (JSON) */
    }
#endif
    gn_filter f;
#ifdef GNOMON_COUNT_OPS
    gn_runner_start(&f, &r);
    gn_ops = gn_op_counts();
    double t_gyro = NAN;
    for (long i = 0; i < r.n; ++i) {
        run_row(&f, &r, i, &t_gyro);
    }
    long total = gn_ops.add + gn_ops.mul + gn_ops.div + gn_ops.sqrt + gn_ops.trig + gn_ops.other;
    printf("{\"rows\": %ld, \"ops_per_update\": {\"add\": %.2f, \"mul\": %.2f, \"div\": %.2f, "
           "\"sqrt\": %.2f, \"trig\": %.2f, \"other\": %.2f, \"total\": %.2f}}\n",
           r.n_gyro, (double)gn_ops.add / r.n_gyro, (double)gn_ops.mul / r.n_gyro,
           (double)gn_ops.div / r.n_gyro, (double)gn_ops.sqrt / r.n_gyro,
           (double)gn_ops.trig / r.n_gyro, (double)gn_ops.other / r.n_gyro,
           (double)total / r.n_gyro);
    (void)bench;
    return 0;
#else
    if (bench) {
        long passes = 0;
        double elapsed = 0.0, best = 1e300;
        while (elapsed < 1.0 || passes < 3) {
            gn_runner_start(&f, &r);
            double t_gyro = NAN, t0 = now_s();
            for (long i = 0; i < r.n; ++i) {
                run_row(&f, &r, i, &t_gyro);
            }
            double dt = now_s() - t0;
            elapsed += dt;
            best = dt < best ? dt : best;
            ++passes;
        }
        real_t q[4];
        gn_adapter_quat(&f, q); /* keeps the loop from being optimised away */
        printf("{\"ns_per_update\": %.2f, \"rows\": %ld, \"passes\": %ld, \"state_bytes\": %lu, "
               "\"params_bytes\": %lu, \"q_w\": %.3f}\n",
               1e9 * best / (double)r.n_gyro, r.n_gyro, passes, (unsigned long)sizeof(GN_STATE_TYPE),
               (unsigned long)sizeof(GN_PARAMS_TYPE), GN_TO_DOUBLE(q[0]));
        return 0;
    }
    gn_runner_start(&f, &r);
    printf("t,q_w,q_x,q_y,q_z\n");
    double t_gyro = NAN;
    for (long i = 0; i < r.n; ++i) {
        if (!run_row(&f, &r, i, &t_gyro)) {
            continue;
        }
        real_t q[4];
        gn_adapter_quat(&f, q);
        printf("%.17g,%.17g,%.17g,%.17g,%.17g\n", r.t[i], GN_TO_DOUBLE(q[0]),
               GN_TO_DOUBLE(q[1]), GN_TO_DOUBLE(q[2]), GN_TO_DOUBLE(q[3]));
    }
    return 0;
#endif
}
#endif /* GN_RUNNER_NO_MAIN */
