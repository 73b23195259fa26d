/* gnomon_run's adapter for mekf (and its presets): the start as gnomon's MEKF.run (the
 * recording's sensors as MEKF._sensors and _rows find them; the initial attitude as
 * MEKF._prepare: the first star-tracker attitude q_io^-1 (x) q_ib, else TRIAD of the first
 * sample with a valid sun and a usable field, else the orbital frame), then each row as
 * the kernel's row: the gyro prediction, the magnetometer, the sun (or none: the delayed
 * pair in its place), the joint correction, the star tracker. Included by runner.c only
 * (runner_spacecraft.c: gn_rows, gn_has, gn_get, gn_flag). */
#include "mekf.h"
#include "mekf_params.h"

#define GN_STATE_TYPE gnomon_mekf_state
#define GN_PARAMS_TYPE gnomon_mekf_params
#define GN_TAIL_BYTES(f) (sizeof(gnomon_mekf_past) * (size_t)(f)->s.ring_len)

typedef struct {
    gnomon_mekf_state s;
    gnomon_mekf_params p;
    bool mag, sun, star, w_io; /* the sensors the recording has (and the orbital rate) */
    int mag_o;                 /* the field model's first column */
} gn_filter;

static gnomon_mekf_past *gn_tail = 0; /* the runner's storage of the delayed pair's tail */

/* NULL, or why the filter cannot run on the recording */
static const char *gn_runner_start(gn_filter *f, const gn_rows *r)
{
    f->p = GNOMON_MEKF_PARAMS;
    int32_t len = 0;
    if (f->p.substitute != 0) {
        len = f->p.delay_samples;
        if (gn_tail == 0) {
            gn_tail = (gnomon_mekf_past *)malloc(sizeof(gnomon_mekf_past) * (size_t)len);
        }
    }
    if (!gnomon_mekf_init(&f->s, &f->p, gn_tail, len)) {
        return "no storage for the delayed pair's tail";
    }
    /* MEKF.SENSOR_INPUTS: magnetometer (mag, extra.b_o_nT), sun sensor (sun, extra.s_o),
     * star tracker (extra.st_q_ib, extra.q_io) */
    f->mag = gn_has(r, C_MAG, 3) && gn_has(r, C_B_O, 3);
    f->mag_o = gn_has(r, C_B_O_MODEL, 3) ? C_B_O_MODEL : C_B_O; /* _field_reference */
    f->sun = gn_has(r, C_SUN, 3) && gn_has(r, C_S_O, 3);
    f->star = f->p.use_star_tracker && gn_has(r, C_ST_Q, 4);
    f->w_io = gn_has(r, C_W_IO, 3);
    if (f->star && !gn_has(r, C_Q_IO, 4)) {
        return "a star tracker's inertial attitude needs the orbital frame's attitude q_io "
               "(columns q_io_0..3)";
    }
    if (!(f->mag || (f->sun && f->p.use_sun) || f->star)) {
        return "no attitude sensor besides the gyro (magnetometer: mag_x..z and b_o_nT_x..z; "
               "sun sensor: sun_x..z and s_o_x..z; star tracker: st_q_ib_0..3 and q_io_0..3)";
    }
    real_t q[4], a[4], b[4], c[3], d[3];
    for (long i = 0; f->star && i < r->n; ++i) { /* the first star-tracker attitude */
        if (gn_get(r, C_ST_Q, 4, i, b) && gn_flag(r, C_ST_VALID, i)) {
            gn_get(r, C_Q_IO, 4, i, a);
            gnomon_mekf_star_q_ob(a, b, q);
            gnomon_mekf_start(&f->s, q);
            return 0;
        }
    }
    for (long i = 0; f->sun && f->p.use_sun && i < r->n; ++i) { /* TRIAD, the sun first */
        if (!(gn_flag(r, C_SUN_VALID, i) && gn_get(r, C_SUN, 3, i, a) && gn_get(r, C_S_O, 3, i, b))) {
            continue;
        }
        c[0] = c[1] = c[2] = d[0] = d[1] = d[2] = R(0.0);
        if (f->mag) {
            gn_get(r, C_MAG, 3, i, c);
            gn_get(r, f->mag_o, 3, i, d);
        }
        if (gnomon_mekf_triad(a, b, c, d, q)) {
            gnomon_mekf_start(&f->s, q);
            return 0;
        }
    }
    return 0; /* the orbital frame */
}

static void gn_adapter_row(gn_filter *f, const gn_rows *r, long i, real_t dt)
{
    real_t g[3], io[3], u[4], v[4];
    gn_get(r, C_GYR, 3, i, g);
    if (f->w_io) {
        gn_get(r, C_W_IO, 3, i, io);
    }
    gnomon_mekf_update_gyro(&f->s, &f->p, dt, g, f->w_io ? io : 0);
    if (f->mag) {
        gn_get(r, C_MAG, 3, i, u);
        gn_get(r, f->mag_o, 3, i, v);
        gnomon_mekf_update_mag(&f->s, &f->p, u, v);
    }
    if (f->sun && gn_flag(r, C_SUN_VALID, i) && gn_get(r, C_SUN, 3, i, u)
        && gn_get(r, C_S_O, 3, i, v)) {
        gnomon_mekf_update_sun(&f->s, &f->p, u, v);
    } else {
        gnomon_mekf_update_sun(&f->s, &f->p, 0, 0); /* none: the delayed pair, if it is on */
    }
    gnomon_mekf_correct(&f->s, &f->p);
    if (f->star && gn_get(r, C_ST_Q, 4, i, v) && gn_flag(r, C_ST_VALID, i)) {
        real_t q[4], bore[3] = {R(0.0), R(0.0), R(1.0)};
        gn_get(r, C_Q_IO, 4, i, u);
        if (gn_has(r, C_ST_BORE, 3)) {
            gn_get(r, C_ST_BORE, 3, i, bore);
        }
        gnomon_mekf_star_q_ob(u, v, q);
        gnomon_mekf_update_star(&f->s, &f->p, q, bore);
    }
}

static void gn_adapter_quat(const gn_filter *f, real_t q[4]) { gnomon_mekf_get_quat(&f->s, q); }
