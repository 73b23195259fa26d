/* gnomon_run for the spacecraft filters: the CSV of a spacecraft recording on stdin through
 * the exported filter, its attitude on stdout.
 *
 *   gnomon convert rec.h5 rec.csv          (or gnomon.io.write("rec.csv", rec))
 *   ./gnomon_run < rec.csv > q.csv         t,q_w,q_x,q_y,q_z (17 significant digits), q_ob,
 *                                          one row per gyro sample, as `gnomon estimate --out`
 *   ./gnomon_run --bench < rec.csv         {"ns_per_update": ..., ...} on this machine
 *   ./gnomon_count < rec.csv               (make count) operations per update, counted
 *
 * Input: a header naming the columns (any order; read by name, others ignored), one row
 * per gyro sample: t (s), gyr_x..z (w_ib_b, rad/s) required; mag_x..z (uT) with the field
 * model b_o_nT_x..z (nT, o; b_o_model_nT_x..z preferred when present); sun_x..z (b) with
 * sun_valid (0/1) and the sun model s_o_x..z (o); the orbital frame's rate w_io_o_x..z
 * (rad/s, o); the star tracker's st_q_ib_0..3 (q_ib) with st_valid (0/1),
 * st_boresight_b_x..z and the orbital frame's q_io_0..3. An empty cell is no value (NaN).
 * The whole file is read first: the filter starts as gnomon's `run` starts from a
 * recording (gn_runner_start in runner_adapter.h: NULL, or what the recording lacks), then
 * every row is one call of each sensor's update (gn_adapter_row).
 *
 * gnomon_run_columns (make shared): the same on arrays, for ctypes.
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

/* the columns the runner reads (a group of 3 or 4 starts at its first name) */
enum {
    C_T, C_GYR, C_GYR_Y, C_GYR_Z, C_MAG, C_MAG_Y, C_MAG_Z, C_B_O, C_B_O_Y, C_B_O_Z,
    C_B_O_MODEL, C_B_O_MODEL_Y, C_B_O_MODEL_Z, C_SUN, C_SUN_Y, C_SUN_Z, C_SUN_VALID,
    C_S_O, C_S_O_Y, C_S_O_Z, C_W_IO, C_W_IO_Y, C_W_IO_Z, C_Q_IO, C_Q_IO_1, C_Q_IO_2,
    C_Q_IO_3, C_ST_Q, C_ST_Q_1, C_ST_Q_2, C_ST_Q_3, C_ST_VALID, C_ST_BORE, C_ST_BORE_Y,
    C_ST_BORE_Z, GN_NCOLS
};

static const char *COLS[GN_NCOLS] = {
    "t", "gyr_x", "gyr_y", "gyr_z", "mag_x", "mag_y", "mag_z", "b_o_nT_x", "b_o_nT_y",
    "b_o_nT_z", "b_o_model_nT_x", "b_o_model_nT_y", "b_o_model_nT_z", "sun_x", "sun_y",
    "sun_z", "sun_valid", "s_o_x", "s_o_y", "s_o_z", "w_io_o_x", "w_io_o_y", "w_io_o_z",
    "q_io_0", "q_io_1", "q_io_2", "q_io_3", "st_q_ib_0", "st_q_ib_1", "st_q_ib_2",
    "st_q_ib_3", "st_valid", "st_boresight_b_x", "st_boresight_b_y", "st_boresight_b_z"};

typedef struct {
    long n;
    double *c[GN_NCOLS]; /* (n,) each, NaN where empty; the magnetometer in nT */
    bool has[GN_NCOLS];
} gn_rows;

static inline void die(const char *what, long row)
{
    if (row >= 0) {
        fprintf(stderr, "gnomon_run: row %ld: %s\n", row, what);
    } else {
        fprintf(stderr, "gnomon_run: %s\n", what);
    }
    exit(2);
}

/* whether the columns first .. first + width - 1 are all there */
static inline bool gn_has(const gn_rows *r, int first, int width)
{
    for (int k = first; k < first + width; ++k) {
        if (!r->has[k]) {
            return false;
        }
    }
    return true;
}

/* row i of the columns first .. first + width - 1 (as real_t); whether all are finite */
static inline bool gn_get(const gn_rows *r, int first, int width, long i, real_t *out)
{
    bool ok = true;
    for (int k = 0; k < width; ++k) {
        double v = r->c[first + k][i];
        ok = ok && isfinite(v);
        out[k] = R(v);
    }
    return ok;
}

/* a 0/1 column: true where it is 1 (or the column is absent) */
static inline bool gn_flag(const gn_rows *r, int col, long i)
{
    return !r->has[col] || (r->c[col][i] == r->c[col][i] && r->c[col][i] != 0.0);
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

#define GN_MAX_CELLS 512

static inline void alloc_rows(gn_rows *r, long cap)
{
    for (int k = 0; k < GN_NCOLS; ++k) {
        r->c[k] = r->has[k] ? (double *)malloc(sizeof(double) * (size_t)cap) : 0;
    }
}

static inline void check_rows(const gn_rows *r)
{
    if (r->n == 0) {
        die("no data rows", -1);
    }
    for (long i = 0; i < r->n; ++i) {
        if (!(isfinite(r->c[C_T][i]) && isfinite(r->c[C_GYR][i]) && isfinite(r->c[C_GYR_Y][i])
              && isfinite(r->c[C_GYR_Z][i]))) {
            die("every row needs t and a gyro sample", i + 1);
        }
    }
}

static inline void read_rows(FILE *in, gn_rows *r)
{
    static char line[1 << 17];
    char *cells[GN_MAX_CELLS];
    int col[GN_NCOLS];
    if (fgets(line, sizeof line, in) == 0) {
        die("no header line", -1);
    }
    int nh = split(line, cells, GN_MAX_CELLS);
    for (int k = 0; k < GN_NCOLS; ++k) {
        col[k] = -1;
        for (int j = 0; j < nh; ++j) {
            if (strcmp(cells[j], COLS[k]) == 0) {
                col[k] = j;
            }
        }
        r->has[k] = col[k] >= 0;
        if (!r->has[k] && k <= C_GYR_Z) {
            fprintf(stderr, "gnomon_run: missing column %s\n", COLS[k]);
            exit(2);
        }
    }
    long cap = 1024;
    r->n = 0;
    alloc_rows(r, cap);
    while (fgets(line, sizeof line, in) != 0) {
        if (line[0] == '\n' || line[0] == '\r' || line[0] == '#') {
            continue;
        }
        if (r->n == cap) {
            cap *= 2;
            for (int k = 0; k < GN_NCOLS; ++k) {
                if (r->has[k]) {
                    r->c[k] = (double *)realloc(r->c[k], sizeof(double) * (size_t)cap);
                }
            }
        }
        int nc = split(line, cells, GN_MAX_CELLS);
        if (nc != nh) {
            die("wrong number of cells", r->n + 1);
        }
        long i = r->n++;
        for (int k = 0; k < GN_NCOLS; ++k) {
            if (r->has[k]) {
                const char *cell = cells[col[k]];
                double v = cell[0] == '\0' ? NAN : strtod(cell, 0);
                r->c[k][i] = (k >= C_MAG && k <= C_MAG_Z) ? v * 1000.0 : v; /* uT -> nT */
            }
        }
    }
    check_rows(r);
}

static inline double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* the filter: gn_filter, gn_runner_start (gnomon's prepare) and gn_adapter_row (one call
 * per sensor of a row) */
#include "runner_adapter.h"

static void run_row(gn_filter *f, const gn_rows *r, long i)
{
    gn_adapter_row(f, r, i, R(i == 0 ? 0.0 : r->c[C_T][i] - r->c[C_T][i - 1]));
}

/* the whole recording through the filter, for ctypes (built as a shared library with
 * GN_RUNNER_NO_MAIN): `ncols` columns of `n` rows named as in the CSV (`names`; the
 * magnetometer in uT), q_out (n, 4). Returns 0 (2: no t and gyro columns, or the filter
 * cannot run on these columns: gn_runner_start's message). */
int gnomon_run_columns(long n, int ncols, const char *const *names, const double *const *cols,
                       double *q_out)
{
    gn_rows r;
    r.n = n;
    for (int k = 0; k < GN_NCOLS; ++k) {
        r.has[k] = false;
        for (int j = 0; j < ncols; ++j) {
            if (strcmp(names[j], COLS[k]) == 0) {
                r.has[k] = true;
            }
        }
    }
    if (!gn_has(&r, C_T, 4) || n < 1) {
        return 2;
    }
    alloc_rows(&r, n);
    for (int k = 0; k < GN_NCOLS; ++k) {
        for (int j = 0; j < ncols && r.has[k]; ++j) {
            if (strcmp(names[j], COLS[k]) == 0) {
                for (long i = 0; i < n; ++i) {
                    r.c[k][i] = (k >= C_MAG && k <= C_MAG_Z) ? cols[j][i] * 1000.0 : cols[j][i];
                }
            }
        }
    }
    gn_filter f;
    int rc = gn_runner_start(&f, &r) == 0 ? 0 : 2;
    for (long i = 0; i < n && rc == 0; ++i) {
        run_row(&f, &r, i);
        real_t q[4];
        gn_adapter_quat(&f, q);
        for (int k = 0; k < 4; ++k) {
            q_out[4 * i + k] = GN_TO_DOUBLE(q[k]);
        }
    }
    for (int k = 0; k < GN_NCOLS; ++k) {
        free(r.c[k]);
    }
    return rc;
}

#ifndef GN_RUNNER_NO_MAIN
int main(int argc, char **argv)
{
    bool bench = argc > 1 && strcmp(argv[1], "--bench") == 0;
    gn_rows r;
    read_rows(stdin, &r);
    gn_filter f;
    const char *err = gn_runner_start(&f, &r);
    if (err != 0) {
        die(err, -1);
    }
#ifdef GNOMON_COUNT_OPS
    gn_ops = gn_op_counts();
    for (long i = 0; i < r.n; ++i) {
        run_row(&f, &r, i);
    }
    long total = gn_ops.add + gn_ops.mul + gn_ops.div + gn_ops.sqrt + gn_ops.trig + gn_ops.other;
    printf("{\"rows\": %ld, \"ops_per_update\": {\"add\": %.2f, \"mul\": %.2f, \"div\": %.2f, "
           "\"sqrt\": %.2f, \"trig\": %.2f, \"other\": %.2f, \"total\": %.2f}}\n",
           r.n, (double)gn_ops.add / r.n, (double)gn_ops.mul / r.n, (double)gn_ops.div / r.n,
           (double)gn_ops.sqrt / r.n, (double)gn_ops.trig / r.n, (double)gn_ops.other / r.n,
           (double)total / r.n);
    (void)bench;
    return 0;
#else
    if (bench) {
        long passes = 0;
        double elapsed = 0.0, best = 1e300;
        while (elapsed < 1.0 || passes < 3) {
            if (passes > 0) {
                gn_runner_start(&f, &r);
            }
            double t0 = now_s();
            for (long i = 0; i < r.n; ++i) {
                run_row(&f, &r, i);
            }
            double dt = now_s() - t0;
            elapsed += dt;
            best = dt < best ? dt : best;
            ++passes;
        }
        real_t q[4];
        gn_adapter_quat(&f, q); /* keeps the loop from being optimised away */
        printf("{\"ns_per_update\": %.2f, \"rows\": %ld, \"passes\": %ld, \"state_bytes\": %lu, "
               "\"params_bytes\": %lu, \"tail_bytes\": %lu, \"q_w\": %.3f}\n",
               1e9 * best / (double)r.n, r.n, passes, (unsigned long)sizeof(GN_STATE_TYPE),
               (unsigned long)sizeof(GN_PARAMS_TYPE), (unsigned long)GN_TAIL_BYTES(&f),
               GN_TO_DOUBLE(q[0]));
        return 0;
    }
    printf("t,q_w,q_x,q_y,q_z\n");
    for (long i = 0; i < r.n; ++i) {
        run_row(&f, &r, i);
        real_t q[4];
        gn_adapter_quat(&f, q);
        printf("%.17g,%.17g,%.17g,%.17g,%.17g\n", r.c[C_T][i], GN_TO_DOUBLE(q[0]),
               GN_TO_DOUBLE(q[1]), GN_TO_DOUBLE(q[2]), GN_TO_DOUBLE(q[3]));
    }
    return 0;
#endif
}
#endif /* GN_RUNNER_NO_MAIN */
