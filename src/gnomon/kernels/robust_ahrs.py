"""Compiled step of the robust decoupled AHRS (``gnomon.estimators.robust_ahrs``): its
coefficients, its state and the per-sample step, phase by phase.

Twin of ``RobustAHRS.update_reference`` (the tests compare the two sample by sample). The shape
is the one of every gnomon kernel (``gnomon/kernels/__init__.py`` says why): the
``Coefficients`` named tuple is built once from the parameters and the nominal sample
time by ``coefficients(params, ts_s)``; the evolving state is one record of the
structured dtype ``STATE`` (``new_state(params)`` gives a fresh one-element array), whose
low-pass filters and hard-iron sums are nested records (``LOWPASS_3``, ``HARD_IRON``);
both are defined in ``gnomon.kernels.robust_ahrs_state`` and re-exported here.
The readable twin works on the very same record (``state.view(np.recarray)[0]``).

Frames: body b (sensor), almost-inertial I (``q_gyr = q_Ib``, strapdown), the
inclination-corrected frame 6 (``q_acc = q_6I``, z up) and ENU n
(``q_nb = q_z(delta) ⊗ q_6b``). Units: rad, rad/s, m/s², s; the magnetometer in any
one unit (the tests use µT).

The step (``robust_ahrs_step``) calls the phases in order; each is a short compiled
function of its own (``cache=True``; only the few-line helpers are ``inline="always"``):
inlined into one function, the step took numba 58 s to compile on a 2-core machine, as
separate functions 8 s, for a batch loop about 1.4x slower (still faster than VQF's C++
``updateBatch``; ``gnomon/kernels/__init__.py`` says why):

1. ``rest_gyro``: gyro low-pass and deviation (rest detection, gyro part);
2. ``strapdown``: ``q_gyr <- q_gyr ⊗ exp((ω - b) dt)`` (and ``rest_turn``: the same
   rotation since a rest candidacy began); a gap (``dt > max_dt_s``) ends the step here;
3. ``rest_acc`` and ``inclination``: the rest detection's accelerometer part (its
   direction must not turn; a large rate is a bias only where ``gyro_says_turned``; the
   first rest of the start-up restarts the low-pass in I at the rest's force and asks
   for the heading, ``first_rest_reset``), accelerometer low-pass in I and the
   correction of ``q_acc`` that takes it to up;
4. ``bias_kf``: the gyro-bias Kalman filter, at rest (``H = I``) or in motion (the
   inclination correction as a measurement of the horizontal bias);
5. ``rest_mag`` (the field's direction in the body frame must not turn during a rest),
   ``heading_reset`` (after a first rest), ``mag_accumulate`` → ``hard_iron`` →
   ``mag_disturbance`` / ``new_field`` → ``heading_gain`` → ``heading``: the
   magnetometer, heading only.

The batch loop (``robust_ahrs_batch``) and the per-sample kernel of the filter's ``update``
(``robust_ahrs_sample``) take the coefficients as a record (``gnomon.kernels.entry.record``)
and run the same row, compiled once for both (``_row``: the
step and ``q_nb``).

The 3x3 matrices of a phase (``R_6b``, ``P``, ``S``) are row-major 9-tuples
(``gnomon.kernels.linalg.mat3_*``), read from the record once and written back once.
"""

from __future__ import annotations

import math

from numba import njit

from gnomon.kernels import linalg, quat
from gnomon.kernels.entry import BAD_GYRO
from gnomon.kernels.robust_ahrs_state import (  # noqa: F401 - re-exported: the kernel's names
    HARD_IRON,
    LOWPASS_2,
    LOWPASS_3,
    LOWPASS_33,
    STATE,
    Coefficients,
    LowPass,
    butter2,
    coefficients,
    new_state,
)

__all__ = ["LowPass", "Coefficients", "coefficients", "butter2", "STATE", "LOWPASS_2",
           "LOWPASS_3", "LOWPASS_33", "HARD_IRON", "new_state", "robust_ahrs_step",
           "robust_ahrs_batch", "robust_ahrs_sample", "ACC_SKIPPED", "MAG_SKIPPED", "GAP",
           "BIAS_AT_LIMIT"]

# flag bits returned by the step (``flags`` signal of ``run``)
ACC_SKIPPED = 1
MAG_SKIPPED = 2
GAP = 4
BIAS_AT_LIMIT = 8  # written by the batch loop: a component of the bias at ``bias_clip``


# ---------------------------------------------------------------- low-pass filters
@njit(inline="always", error_model="numpy")
def _settle(z0, z1, i, y, lp):
    """Component ``i`` of a low-pass's delay lines ``z0``, ``z1`` set to its steady state
    for a constant input ``y``."""
    z0[i] = y * (1.0 - lp.b0)
    z1[i] = y * (lp.b2 - lp.a2)


@njit(inline="always", error_model="numpy")
def _mean_step(z0, z1, i, x, n, done, lp):
    """Start-up of a low-pass: the running mean of component ``i`` (its sum in ``z0[i]``);
    ``done``: the mean becomes the filter's steady state (``z0``, ``z1`` (k,) views of a
    low-pass record's delay lines)."""
    z0[i] += x
    y = z0[i] / n
    if done:
        _settle(z0, z1, i, y, lp)
    return y


@njit(inline="always", error_model="numpy")
def _filter_step(z0, z1, i, x, lp):
    """One Butterworth step of component ``i`` (direct form II transposed)."""
    y = lp.b0 * x + z0[i]
    z0[i] = lp.b1 * x - lp.a1 * y + z1[i]
    z1[i] = lp.b2 * x - lp.a2 * y
    return y


@njit(inline="always", error_model="numpy")
def _start(f, lp):
    """Count one start-up sample: ``(n, done)``."""
    n = f.n + 1
    done = n * lp.ts_s >= lp.tau_s
    f.n = -1 if done else n
    return n, done


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def lowpass2(f, x0, x1, lp):
    """``LowPass`` ``lp`` of two values, state ``f`` (``LOWPASS_2``): the outputs."""
    z0, z1 = f.z0, f.z1
    if f.n >= 0:
        n, done = _start(f, lp)
        return _mean_step(z0, z1, 0, x0, n, done, lp), _mean_step(z0, z1, 1, x1, n, done, lp)
    return _filter_step(z0, z1, 0, x0, lp), _filter_step(z0, z1, 1, x1, lp)


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def _lowpass3_lines(z0, z1, x0, x1, x2, n, done, lp):
    """Three components on the delay lines ``z0``, ``z1`` (3,): the running mean while
    ``n > 0`` (the ``n``-th start-up sample), the Butterworth step otherwise."""
    if n > 0:
        return (_mean_step(z0, z1, 0, x0, n, done, lp), _mean_step(z0, z1, 1, x1, n, done, lp),
                _mean_step(z0, z1, 2, x2, n, done, lp))
    return (_filter_step(z0, z1, 0, x0, lp), _filter_step(z0, z1, 1, x1, lp),
            _filter_step(z0, z1, 2, x2, lp))


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def lowpass3(f, x0, x1, x2, lp):
    """``LowPass`` ``lp`` of a 3-vector, state ``f`` (``LOWPASS_3``): the outputs."""
    n, done = _start(f, lp) if f.n >= 0 else (0, False)
    # the delay lines as views ([:]), as lowpass33 passes its rows: one compiled signature
    return _lowpass3_lines(f.z0[:], f.z1[:], x0, x1, x2, n, done, lp)


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def lowpass33(f, a, lp):
    """``LowPass`` ``lp`` of a 3x3 matrix (row-major 9-tuple ``a``), state ``f``
    (``LOWPASS_33``, a row of delay lines per matrix row): the output as a 9-tuple."""
    n, done = _start(f, lp) if f.n >= 0 else (0, False)
    z0, z1 = f.z0, f.z1
    r0 = _lowpass3_lines(z0[0], z1[0], a[0], a[1], a[2], n, done, lp)
    r1 = _lowpass3_lines(z0[1], z1[1], a[3], a[4], a[5], n, done, lp)
    r2 = _lowpass3_lines(z0[2], z1[2], a[6], a[7], a[8], n, done, lp)
    return r0[0], r0[1], r0[2], r1[0], r1[1], r1[2], r2[0], r2[1], r2[2]


@njit(inline="always", error_model="numpy")
def set_heading(s, d):
    """``delta`` (rad) and the half-angle cosine and sine the estimate is built from."""
    s.delta = d
    s.cos_half_delta = math.cos(0.5 * d)
    s.sin_half_delta = math.sin(0.5 * d)


@njit(inline="always", error_model="numpy")
def wrap(a):
    """An angle difference (rad, within (-3π, 3π)) wrapped into [-π, π]."""
    if a > math.pi:
        return a - 2.0 * math.pi
    if a < -math.pi:
        return a + 2.0 * math.pi
    return a


# ---------------------------------------------------------------- 1. rest detection
@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def rest_gyro(s, c, gx, gy, gz):
    """Gyro part of the rest detection: low-pass the rate (kept in ``s.gyro_lp``, the bias
    measurement at rest); a deviation above the threshold, or a low-passed rate beyond
    the bias bound, ends a rest phase."""
    lx, ly, lz = lowpass3(s.rest_gyro_lp, gx, gy, gz, c.rest_lp)
    s.gyro_lp[0], s.gyro_lp[1], s.gyro_lp[2] = lx, ly, lz
    dx, dy, dz = gx - lx, gy - ly, gz - lz
    big = max(abs(lx), max(abs(ly), abs(lz)))
    if dx * dx + dy * dy + dz * dz >= c.rest_th_gyro2 or big > c.bias_clip:
        s.rest_t = 0.0
        s.rest = False


@njit(inline="always", error_model="numpy")
def _chord2(ax, ay, az, bx, by, bz):
    """Squared distance between the directions of two non-zero 3-vectors."""
    na = math.sqrt(ax * ax + ay * ay + az * az)
    nb = math.sqrt(bx * bx + by * by + bz * bz)
    dx, dy, dz = ax / na - bx / nb, ay / na - by / nb, az / na - bz / nb
    return dx * dx + dy * dy + dz * dz


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def rest_begin(s, lx, ly, lz):
    """A rest candidacy begins at this accelerometer sample: keep the low-passed
    accelerometer ``l`` and magnetometer directions and start the gyro's rotation."""
    n = math.sqrt(lx * lx + ly * ly + lz * lz)
    s.rest_a0[0], s.rest_a0[1], s.rest_a0[2] = lx / n, ly / n, lz / n
    m = s.mag_body_lp
    s.rest_m0[0], s.rest_m0[1], s.rest_m0[2] = m[0], m[1], m[2]
    s.rest_m0_ok = s.mag_body_ok
    q = s.rest_q
    q[0], q[1], q[2], q[3] = 1.0, 0.0, 0.0, 0.0


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def rest_turn(s, dt, gx, gy, gz):
    """During a rest candidacy, ``rest_q <- rest_q ⊗ exp((ω - b) dt)``: the rotation the
    gyro (minus the bias estimate) says the body made since it began."""
    if s.rest_t > 0.0 and dt > 0.0:
        q = s.rest_q
        q[0], q[1], q[2], q[3], _ = quat.exp_mul(
            q[0], q[1], q[2], q[3], (gx - s.bias[0]) * dt, (gy - s.bias[1]) * dt,
            (gz - s.bias[2]) * dt, True, True)


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def gyro_says_turned(s, c):
    """Whether the gyro's rotation since the candidacy began (``rest_q``) would have turned
    the accelerometer's direction, or the magnetometer's (its hard-iron offset removed), by
    at least twice ``rest_th_turn`` (squared chords compared)."""
    q, a = s.rest_q, s.rest_a0
    px, py, pz = quat.rotate_inv(q[0], q[1], q[2], q[3], a[0], a[1], a[2])
    big = 4.0 * c.rest_th_turn2
    if _chord2(px, py, pz, a[0], a[1], a[2]) >= big:
        return True
    if s.rest_m0_ok:
        o = s.hard_iron.o
        mx, my, mz = s.rest_m0[0] - o[0], s.rest_m0[1] - o[1], s.rest_m0[2] - o[2]
        if mx * mx + my * my + mz * mz > 0.0:
            px, py, pz = quat.rotate_inv(q[0], q[1], q[2], q[3], mx, my, mz)
            return _chord2(px, py, pz, mx, my, mz) >= big
    return False


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def settle3(f, x0, x1, x2, lp):
    """Restart the ``LowPass`` ``lp`` of a 3-vector (state ``f``, ``LOWPASS_3``) settled at
    ``x``: its steady state for a constant input ``x`` (the start-up's running mean over)."""
    z0, z1 = f.z0, f.z1
    _settle(z0, z1, 0, x0, lp)
    _settle(z0, z1, 1, x1, lp)
    _settle(z0, z1, 2, x2, lp)
    f.n = -1


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def first_rest_reset(s, c, lx, ly, lz):
    """The first rest, while the heading is still starting (``k_mag_init`` not 0; without a
    magnetometer: the first rest): before it the gyro bias was unknown and the estimate
    drifted, the start-up's running means keep that drift for seconds. The accelerometer
    low-pass in frame I restarts settled at the rest's low-passed specific force ``l``
    (body; the inclination phase that follows turns ``q_acc`` to it), and the next
    magnetometer sample sets the heading (``heading_reset``). A first rest after the
    start-up changes nothing."""
    s.reset_done = True
    if s.k_mag_init == 0.0:
        return
    g = s.q_gyr
    ix, iy, iz = quat.rotate(g[0], g[1], g[2], g[3], lx, ly, lz)
    settle3(s.acc_lp, ix, iy, iz, c.acc_lp)
    s.heading_reset = True


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def heading_reset(s, R):
    """``delta`` set to the heading, in frame 6 (``R`` = R_6b, 9-tuple), of the low-passed
    magnetometer (hard-iron offset removed): the heading of the first rest
    (``first_rest_reset``)."""
    s.heading_reset = False
    m, o = s.mag_body_lp, s.hard_iron.o
    ex, ey, _ = linalg.mat3_vec(R, m[0] - o[0], m[1] - o[1], m[2] - o[2])
    if ex * ex + ey * ey > 0.0:
        set_heading(s, math.atan2(ex, ey))


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def rest_acc(s, c, ax, ay, az):
    """Accelerometer part of the rest detection: rest after ``rest_min_s`` within the
    threshold of the low-passed specific force while its direction stays within
    ``rest_th_turn`` of where it was when the candidacy began (a larger turn begins a new
    one). A low-passed rate farther than ``rest_th_rate`` from the bias estimate (a large
    bias not yet estimated, or a slow rotation) counts as rest only after
    ``rest_min_large_s``, and only when the gyro says the accelerometer or magnetometer
    would have turned by twice ``rest_th_turn`` meanwhile: they did not, so the rate is a
    bias. A turn about the field and gravity both cannot be told from a bias: no rest.
    The first rest may reset the start-up's estimate (``first_rest_reset``)."""
    lx, ly, lz = lowpass3(s.rest_acc_lp, ax, ay, az, c.rest_acc_lp)
    dx, dy, dz = ax - lx, ay - ly, az - lz
    if dx * dx + dy * dy + dz * dz >= c.rest_th_acc2:
        s.rest_t = 0.0
        s.rest = False
        return
    if s.rest_t == 0.0:
        rest_begin(s, lx, ly, lz)
    elif c.rest_th_turn2 > 0.0 and _chord2(lx, ly, lz, s.rest_a0[0], s.rest_a0[1],
                                           s.rest_a0[2]) >= c.rest_th_turn2:
        s.rest = False  # the direction turned: not rest, a new candidacy from here
        s.rest_t = 0.0
        rest_begin(s, lx, ly, lz)
    s.rest_t += c.ts_acc_s
    if s.rest_t >= c.rest_min_s and not s.rest:
        g, b = s.gyro_lp, s.bias
        far = max(abs(g[0] - b[0]), max(abs(g[1] - b[1]), abs(g[2] - b[2])))
        if far <= c.rest_th_rate or (s.rest_t >= c.rest_min_large_s and (
                c.rest_th_turn2 == 0.0 or gyro_says_turned(s, c))):
            s.rest = True
            if c.rest_reset and not s.reset_done:
                first_rest_reset(s, c, lx, ly, lz)


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def rest_mag(s, c, mx, my, mz):
    """Magnetometer part of the rest detection: low-pass the field in the body frame; a
    direction farther than ``rest_th_turn`` from the one the candidacy began with ends
    the rest and the candidacy (the next accelerometer sample begins a new one)."""
    lx, ly, lz = lowpass3(s.rest_mag_lp, mx, my, mz, c.rest_mag_lp)
    m = s.mag_body_lp
    m[0], m[1], m[2] = lx, ly, lz
    s.mag_body_ok = True
    if s.rest_t > 0.0 and s.rest_m0_ok and c.rest_th_turn2 > 0.0:
        m0 = s.rest_m0
        if _chord2(lx, ly, lz, m0[0], m0[1], m0[2]) >= c.rest_th_turn2:
            s.rest_t = 0.0
            s.rest = False


# ---------------------------------------------------------------- 2. strapdown
@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def strapdown(s, dt, gx, gy, gz):
    """``q_gyr <- q_gyr ⊗ exp((ω - b) dt)`` over the actual interval ``dt`` (s); adds
    ``|ω - b|² dt`` to ``s.rot2`` (the heading KF's rotation noise)."""
    if dt > 0.0:
        rx = (gx - s.bias[0]) * dt
        ry = (gy - s.bias[1]) * dt
        rz = (gz - s.bias[2]) * dt
        th2 = rx * rx + ry * ry + rz * rz
        s.rot2 += th2 / dt
        if th2 > 0.0:
            q = s.q_gyr
            q[0], q[1], q[2], q[3], _ = quat.exp_mul(q[0], q[1], q[2], q[3], rx, ry, rz,
                                                     True, True)


# ---------------------------------------------------------------- 3. inclination
@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def inclination(s, c, ax, ay, az):
    """Low-pass the specific force in frame I, see it in frame 6 and turn ``q_acc`` by
    the rotation that takes it to up. Returns ``(fx, fy, ok)``: the normalised filtered
    force in frame 6 before the correction (``ok`` False when it is zero)."""
    g = s.q_gyr
    ix, iy, iz = quat.rotate(g[0], g[1], g[2], g[3], ax, ay, az)
    lx, ly, lz = lowpass3(s.acc_lp, ix, iy, iz, c.acc_lp)
    q = s.q_acc
    fx, fy, fz = quat.rotate(q[0], q[1], q[2], q[3], lx, ly, lz)
    nf = math.sqrt(fx * fx + fy * fy + fz * fz)
    if not nf > 0.0:
        return 0.0, 0.0, False
    fx /= nf
    fy /= nf
    fz /= nf
    # the rotation taking f onto up [0, 0, 1], applied on the left of q_acc
    cw = math.sqrt(max(0.5 * (fz + 1.0), 0.0))
    if cw > 1e-6:
        pw, px, py = cw, 0.5 * fy / cw, -0.5 * fx / cw
    else:
        pw, px, py = 0.0, 1.0, 0.0
    w, x, y, z = quat.mul(pw, px, py, 0.0, q[0], q[1], q[2], q[3])
    q[0], q[1], q[2], q[3] = quat.normalised(w, x, y, z)
    s.acc_rate = math.sqrt(fx * fx + fy * fy) / c.ts_acc_s  # sin(correction angle) / ts
    return fx, fy, True


# ---------------------------------------------------------------- 4. gyro bias
@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def bias_kf(s, c, R, fx, fy, have_f):
    """Gyro-bias Kalman filter on every ``bias_every``-th accelerometer sample.

    ``R`` = ``R_6b`` (9-tuple) after the inclination correction ``(fx, fy)`` (rad, per
    sample). At rest the measurement is the low-passed gyro (``H = I``); in motion the
    correction rate is the measurement of the horizontal ``R_6b b`` (both sides
    low-passed like the accelerometer), the vertical weakly pulled to zero."""
    run = s.bias_count == 0
    s.bias_count = (s.bias_count + 1) % c.bias_every
    if not (run and (c.rest_bias or c.motion_bias)):
        return
    b0, b1, b2 = s.bias[0], s.bias[1], s.bias[2]
    rb0, rb1, _ = linalg.mat3_vec(R, b0, b1, b2)
    H = lowpass33(s.bias_R_lp, R, c.bias_lp)
    rb0, rb1 = lowpass2(s.bias_Rb_lp, rb0, rb1, c.bias_lp)
    for i in range(3):
        if s.P[i, i] < c.bias_p0:
            s.P[i, i] += c.bias_v
    if c.rest_bias and s.rest:
        g = s.gyro_lp
        bias_update(s, c, (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
                    g[0] - b0, g[1] - b1, g[2] - b2, c.w_rest, c.w_rest, c.w_rest, c.bias_clip)
    elif c.motion_bias and have_f:
        hb0, hb1, hb2 = linalg.mat3_vec(H, b0, b1, b2)
        e0 = -fy / c.ts_acc_s + rb0 - hb0
        e1 = fx / c.ts_acc_s + rb1 - hb1
        bias_update(s, c, H, e0, e1, -hb2, c.w_motion, c.w_motion, c.w_vertical,
                    c.huber)


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def bias_update(s, c, H, e0, e1, e2, w0, w1, w2, ei):
    """Kalman update of the bias with the innovation ``e = y - H b``, ``H`` a 9-tuple,
    measurement variances ``w`` (diagonal): ``K = P Hᵀ (H P Hᵀ + W)⁻¹``, ``b += K e``
    (clipped to ``bias_clip``), ``P -= K (P Hᵀ)ᵀ``, kept symmetric.

    Huber weights: a component beyond ``ei`` has its variance multiplied by ``|e_i| / ei``,
    so that its pull is about that of an innovation clipped to ``ei`` while the
    covariance shrinks by less (it was only partly used): a large bias not yet estimated
    keeps the gain that lets it converge, and a single wild innovation moves little."""
    lim = c.bias_clip
    a0, a1, a2 = abs(e0), abs(e1), abs(e2)
    if a0 > ei:
        w0 *= a0 / ei
    if a1 > ei:
        w1 *= a1 / ei
    if a2 > ei:
        w2 *= a2 / ei
    P = linalg.mat3_load(s.P)
    PHt = linalg.mat3_mul_bt(P, H)
    S = linalg.mat3_mul(H, PHt)
    r = linalg.inv3(S[0] + w0, S[1], S[2], S[3], S[4] + w1, S[5], S[6], S[7], S[8] + w2)
    K = linalg.mat3_mul(PHt, r[1:])
    b = s.bias
    at = False
    for i in range(3):
        v = b[i] + K[3 * i] * e0 + K[3 * i + 1] * e1 + K[3 * i + 2] * e2
        if abs(v) >= lim:
            v, at = math.copysign(lim, v), True
        b[i] = v
    s.bias_at_limit = at
    KHP = linalg.mat3_mul_bt(K, PHt)
    for i in range(3):
        for j in range(3):
            s.P[i, j] = P[3 * i + j] - KHP[3 * i + j]
    linalg.symmetrise(s.P)  # the short form lets rounding asymmetry grow over 1e6+ updates


# ---------------------------------------------------------------- 5. magnetometer
@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def mag_accumulate(s, c, R, mx, my, mz):
    """Add the field (hard-iron offset removed) seen in frame 6 to the block sum, and the
    raw field to the hard-iron block sums. Returns whether the block is complete (the
    first sample is a block of its own)."""
    hi = s.hard_iron
    if c.hi_lambda > 0.0:
        hi.block_m[0] += mx
        hi.block_m[1] += my
        hi.block_m[2] += mz
        hi.block_mm += mx * mx + my * my + mz * mz
        rx, ry, rz = linalg.mat3_vec(R, mx, my, mz)
        hi.block_rm[0] += rx
        hi.block_rm[1] += ry
        hi.block_rm[2] += rz
        for i in range(3):
            for j in range(3):
                hi.block_S[i, j] += R[3 * i + j]
        mx -= hi.o[0]
        my -= hi.o[1]
        mz -= hi.o[2]
    ex, ey, ez = linalg.mat3_vec(R, mx, my, mz)
    s.mag_sum[0] += ex
    s.mag_sum[1] += ey
    s.mag_sum[2] += ez
    s.mag_count += 1
    return s.mag_count >= c.mag_every or s.k_mag_init == 1.0


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def hard_iron(s, c, cnt):
    """Fold the block of ``cnt`` samples into the weighted hard-iron sums (``Σ R_6b`` and
    ``Σ R_6b m`` summed sample by sample, each with its own rotation: with the block's last
    ``R_6b`` for all, a turning body showed an offset of about |h|·ω·1.5·dt that was not
    there) and solve for the offset ``o`` (body).

    ``R m = h + R o`` with ``h`` fixed in frame 6: least squares with the prior
    ``reg·w|o|²``, ``(w²(1+reg) I - SᵀS) o = w Σm - Sᵀ Σ R m``. ``o`` is used only when it
    leaves less than ``hi_gate`` of the residual energy without an offset."""
    hi, lam = s.hard_iron, c.hi_lambda
    hi.w = lam * hi.w + cnt
    for i in range(3):
        for j in range(3):
            hi.S[i, j] = lam * hi.S[i, j] + hi.block_S[i, j]
            hi.block_S[i, j] = 0.0
        hi.rm[i] = lam * hi.rm[i] + hi.block_rm[i]
        hi.block_rm[i] = 0.0
        hi.m[i] = lam * hi.m[i] + hi.block_m[i]
        hi.block_m[i] = 0.0
    hi.mm = lam * hi.mm + hi.block_mm
    hi.block_mm = 0.0
    w, S = hi.w, linalg.mat3_load(hi.S)
    rm0, rm1, rm2 = hi.rm[0], hi.rm[1], hi.rm[2]
    m0, m1, m2 = hi.m[0], hi.m[1], hi.m[2]
    StS = linalg.mat3_tmul(S, S)
    d = w * w * (1.0 + c.hi_reg)
    a = linalg.inv3(d - StS[0], -StS[1], -StS[2], -StS[3], d - StS[4], -StS[5],
                    -StS[6], -StS[7], d - StS[8])
    if a[0] <= 0.0:
        return
    sr0, sr1, sr2 = linalg.mat3_tvec(S, rm0, rm1, rm2)
    o0, o1, o2 = linalg.mat3_vec(a[1:], w * m0 - sr0, w * m1 - sr1, w * m2 - sr2)
    so0, so1, so2 = linalg.mat3_vec(S, o0, o1, o2)
    h0, h1, h2 = (rm0 - so0) / w, (rm1 - so1) / w, (rm2 - so2) / w
    # residual energy of the fit with the offset (e1) and without it (e0, h = mean of R m)
    e0 = hi.mm - (rm0 * rm0 + rm1 * rm1 + rm2 * rm2) / w
    e1 = hi.mm - (h0 * rm0 + h1 * rm1 + h2 * rm2) - (o0 * m0 + o1 * m1 + o2 * m2)
    fits = e1 < c.hi_gate * e0
    hi.o[0], hi.o[1], hi.o[2] = (o0, o1, o2) if fits else (0.0, 0.0, 0.0)


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def mag_disturbance(s, c, nm, dip):
    """Compare the low-passed norm and dip of the field with the learned reference: flag
    a disturbance outside the thresholds, clear it after ``mag_min_undisturbed_s``
    within them (and then follow the reference slowly). Returns the low-passed
    ``(norm, dip)``."""
    tsm = c.ts_mag
    cur_n, cur_d = lowpass2(s.mag_lp, nm, dip, c.mag_lp)
    ref_n = s.mag_ref_norm
    if abs(cur_n - ref_n) < c.mag_norm_th * ref_n \
            and abs(cur_d - s.mag_ref_dip) < c.mag_dip_th:
        s.mag_undisturbed_t += tsm
        if s.mag_undisturbed_t >= c.mag_min_undisturbed_s:
            s.mag_disturbed = False
            s.mag_ref_norm += c.k_mag_ref * (cur_n - ref_n)
            s.mag_ref_dip += c.k_mag_ref * (cur_d - s.mag_ref_dip)
    else:
        s.mag_undisturbed_t = 0.0
        s.mag_disturbed = True
    return cur_n, cur_d


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def new_field(s, c, cur_n, cur_d):
    """A new, steady field replaces the reference after ``mag_new_s`` of motion in it
    (``mag_new_first_s`` while there is no reference yet). Returns the soft de-weighting
    factor ``1 + soft_norm (Δnorm/norm)² + soft_dip Δdip²`` of the heading variance."""
    cand_n = s.cand_norm
    if abs(cur_n - cand_n) < c.mag_norm_th * cand_n \
            and abs(cur_d - s.cand_dip) < c.mag_dip_th:
        g = s.gyro_lp
        if g[0] * g[0] + g[1] * g[1] + g[2] * g[2] >= c.mag_new_min_gyro2:
            s.cand_t += c.ts_mag
        s.cand_norm += c.k_mag_ref * (cur_n - cand_n)
        s.cand_dip += c.k_mag_ref * (cur_d - s.cand_dip)
        if s.mag_disturbed and (s.cand_t >= c.mag_new_s or (
                s.mag_ref_norm == 0.0 and s.cand_t >= c.mag_new_first_s)):
            s.mag_ref_norm = s.cand_norm
            s.mag_ref_dip = s.cand_dip
            s.mag_disturbed = False
            s.mag_undisturbed_t = c.mag_min_undisturbed_s
    else:
        s.cand_t = 0.0
        s.cand_norm = cur_n
        s.cand_dip = cur_d
    if s.mag_ref_norm > 0.0:
        dn = (cur_n - s.mag_ref_norm) / s.mag_ref_norm
        dd = cur_d - s.mag_ref_dip
        return 1.0 + c.soft_norm * dn * dn + c.soft_dip * dd * dd
    return 1.0


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def vertical_bias_var(s, R):
    """Variance (rad/s)² of the bias estimate about the vertical: ``uᵀ P u`` with ``u``
    the third row of ``R`` = R_6b (up in body coordinates)."""
    P = s.P
    v = 0.0
    for i in range(3):
        for j in range(3):
            v += R[6 + i] * P[i, j] * R[6 + j]
    return v


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def heading_gain(s, c, soft, p_bv):
    """The heading gain of this update: first-order ``k_mag`` or the heading KF's gain
    (its random walk raised by the vertical bias variance ``p_bv``, (rad/s)²); 0 while a
    disturbance is rejected (reduced after ``mag_max_reject_s``), divided by the soft
    de-weighting ``soft``; at least the running-mean gain at start."""
    tsm = c.ts_mag
    k, r_head = c.k_mag, c.r_head
    if c.heading_kf:
        s.p_head += c.q_head * (1.0 + p_bv * c.inv_bias_ref2) + c.q_rate * s.rot2
    s.rot2 = 0.0
    if c.mag_rejection:
        if s.mag_disturbed:
            if s.mag_reject_t <= c.mag_max_reject_s:
                s.mag_reject_t += tsm
                k, r_head = 0.0, 0.0
            else:
                k /= c.mag_reject_factor
                r_head = c.r_head * c.mag_reject_factor * c.mag_reject_factor
        else:
            s.mag_reject_t = max(s.mag_reject_t - c.mag_reject_factor * tsm, 0.0)
    k /= soft
    r_head *= soft
    if c.heading_kf and r_head > 0.0:
        k = s.p_head / (s.p_head + r_head)
        s.p_head *= 1.0 - k
    ki = s.k_mag_init
    if ki != 0.0:  # running mean at start: the gain is at least 1/count
        if k < ki:
            k = ki
            s.p_head = ki * c.r_head
        ki = ki / (ki + 1.0)
        s.k_mag_init = 0.0 if ki * c.tau_mag_s < tsm else ki
    return k


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def magnetometer(s, c, R, mx, my, mz):
    """Heading from the magnetometer ``m`` (body), ``R`` = R_6b: accumulate; on a complete
    block update the hard-iron offset, test for disturbances, turn ``delta`` towards the
    field's heading in frame 6 and (optionally) feed the vertical bias."""
    if not mag_accumulate(s, c, R, mx, my, mz):
        return  # accumulating: the heading filter runs on every mag_every-th sample
    cnt = s.mag_count
    inv = 1.0 / cnt
    ex, ey, ez = s.mag_sum[0] * inv, s.mag_sum[1] * inv, s.mag_sum[2] * inv
    if c.hi_lambda > 0.0:
        hard_iron(s, c, cnt)
    s.mag_sum[0], s.mag_sum[1], s.mag_sum[2] = 0.0, 0.0, 0.0
    s.mag_count = 0
    soft = 1.0
    if c.mag_rejection:
        nm = math.sqrt(ex * ex + ey * ey + ez * ez)
        dip = -math.asin(min(max(ez / nm, -1.0), 1.0))
        cur_n, cur_d = mag_disturbance(s, c, nm, dip)
        soft = new_field(s, c, cur_n, cur_d)
    dis = wrap(math.atan2(ex, ey) - s.delta)
    s.mag_dis = dis
    if c.mag_heading_dis > 0.0 and not s.mag_disturbed and s.k_mag_init == 0.0 \
            and abs(dis) > c.mag_heading_dis and s.mag_reject_t <= c.mag_max_reject_s:
        # within the norm and dip bounds, but turned away from the heading: a field that
        # turns (a room's), or one back in the bounds turned away, not the Earth's
        s.mag_disturbed = True
        s.mag_undisturbed_t = 0.0
    k = heading_gain(s, c, soft, vertical_bias_var(s, R))
    s.k_mag_used = k
    set_heading(s, wrap(s.delta + k * dis))
    if c.k_mag_bias > 0.0 and k > 0.0 and s.k_mag_init == 0.0:
        # heading-rate bias: integral action about the vertical (third row of R_6b)
        # dis < 0: the field turned clockwise in frame 6, i.e. frame 6 turned
        # counter-clockwise about up too fast: the bias along up is too small
        db = -c.k_mag_bias * (k / c.k_mag) * dis * c.ts_mag
        at = False
        for i in range(3):
            v = s.bias[i] + db * R[6 + i]
            if abs(v) >= c.bias_clip:
                v, at = math.copysign(c.bias_clip, v), True
            s.bias[i] = v
        s.bias_at_limit = at


# ---------------------------------------------------------------- the step
@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def robust_ahrs_step(s, c, dt, gx, gy, gz, ax, ay, az, mx, my, mz):
    """One sample in place on the state record ``s``: ``dt`` (s) since the last sample,
    gyro (rad/s), accelerometer (m/s²), magnetometer (body); a zero accelerometer or
    magnetometer vector is no sample. Returns ``(flags, q_6b)``: the bits ``ACC_SKIPPED``,
    ``MAG_SKIPPED``, ``GAP`` and ``q_acc ⊗ q_gyr`` (a 4-tuple)."""
    if c.rest_bias or c.mag_rejection:
        rest_gyro(s, c, gx, gy, gz)
    strapdown(s, dt, gx, gy, gz)
    if c.rest_bias:
        rest_turn(s, dt, gx, gy, gz)
    qa, qg = s.q_acc, s.q_gyr
    if dt > c.max_dt_s:
        return GAP, quat.mul(qa[0], qa[1], qa[2], qa[3], qg[0], qg[1], qg[2], qg[3])
    flags = 0
    if ax * ax + ay * ay + az * az > 0.0:
        if c.rest_bias:
            rest_acc(s, c, ax, ay, az)
        fx, fy, have_f = inclination(s, c, ax, ay, az)
        q6 = quat.mul(qa[0], qa[1], qa[2], qa[3], qg[0], qg[1], qg[2], qg[3])
        R = quat.dcm(q6[0], q6[1], q6[2], q6[3])
        bias_kf(s, c, R, fx, fy, have_f)
    else:
        flags |= ACC_SKIPPED
        q6 = quat.mul(qa[0], qa[1], qa[2], qa[3], qg[0], qg[1], qg[2], qg[3])
        R = quat.dcm(q6[0], q6[1], q6[2], q6[3])
    if mx * mx + my * my + mz * mz > 0.0:
        if c.rest_bias:
            rest_mag(s, c, mx, my, mz)
        if s.heading_reset:
            heading_reset(s, R)
        magnetometer(s, c, R, mx, my, mz)
    else:
        flags |= MAG_SKIPPED
    return flags, q6


@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def _row(s, c, dt, gx, gy, gz, ax, ay, az, mx, my, mz):
    """One row of the batch loop (and the sample kernel): ``robust_ahrs_step`` on the state
    record ``s``, then ``q_nb = q_z(delta) ⊗ q_6b``. Returns ``(flags, q_nb)``: the step's
    bits and ``BIAS_AT_LIMIT`` while a component of the bias is at ``bias_clip``."""
    f, q6 = robust_ahrs_step(s, c, dt, gx, gy, gz, ax, ay, az, mx, my, mz)
    q = quat.mul(s.cos_half_delta, 0.0, 0.0, s.sin_half_delta, q6[0], q6[1], q6[2], q6[3])
    if s.bias_at_limit:
        f |= BIAS_AT_LIMIT
    return f, q


@njit(cache=True, error_model="numpy", no_cfunc_wrapper=True)
def robust_ahrs_batch(dt, gyro, acc, mag, state, c, q_out, bias_out, rest_out, dist_out,
                      acc_rate_out, k_mag_out, hi_out, flags_out):
    """Run N samples (``dt`` (N,) s, sensors (N, 3) body) from ``state`` (an array of one
    ``STATE`` record, updated in place) with the ``Coefficients`` ``c``.

    Outputs: ``q_out`` (N, 4) ``q_nb`` (ENU from body), ``bias_out`` (N, 3) rad/s,
    ``rest_out``, ``dist_out`` (N,) bool, ``acc_rate_out`` rad/s, ``k_mag_out`` (N,),
    ``hi_out`` (N, 3) hard-iron offset in use, ``flags_out`` (N,) int bits (uint8: the
    step's and ``BIAS_AT_LIMIT``).
    """
    s = state[0]
    c = c[0]
    for i in range(dt.shape[0]):
        f, q = _row(s, c, dt[i], gyro[i, 0], gyro[i, 1], gyro[i, 2], acc[i, 0], acc[i, 1],
                    acc[i, 2], mag[i, 0], mag[i, 1], mag[i, 2])
        q_out[i, 0], q_out[i, 1], q_out[i, 2], q_out[i, 3] = q
        bias_out[i, 0], bias_out[i, 1], bias_out[i, 2] = s.bias[0], s.bias[1], s.bias[2]
        rest_out[i] = s.rest
        dist_out[i] = s.mag_disturbed
        acc_rate_out[i] = s.acc_rate
        k_mag_out[i] = s.k_mag_used
        hi = s.hard_iron.o
        hi_out[i, 0], hi_out[i, 1], hi_out[i, 2] = hi[0], hi[1], hi[2]
        flags_out[i] = f


@njit(cache=True, error_model="numpy", no_cfunc_wrapper=True)
def robust_ahrs_sample(dt, gyro, acc, mag, state, c, q_out):
    """One sample as a row of ``robust_ahrs_batch`` (the same arithmetic): ``dt`` (s),
    ``gyro``, ``acc``, ``mag`` (3,) body frame (an ``acc``/``mag`` with a non-finite
    component, or a zero one, is no new sample of that sensor); ``state`` updated in place;
    ``c`` the coefficients as a record (``gnomon.kernels.entry.record``); ``q_out`` (4,)
    the estimate ``q_nb``. Returns the row's flags, or ``BAD_GYRO`` alone for a non-finite
    gyro sample (nothing done). The filter's ``update`` calls it through
    ``gnomon.kernels.entry.entry_point``; no memory is allocated."""
    gx, gy, gz = gyro[0], gyro[1], gyro[2]
    if not (math.isfinite(gx) and math.isfinite(gy) and math.isfinite(gz)):
        return BAD_GYRO
    ax, ay, az = linalg.finite_or_nan(acc[0], acc[1], acc[2])
    mx, my, mz = linalg.finite_or_nan(mag[0], mag[1], mag[2])
    f, q = _row(state[0], c[0], dt, gx, gy, gz, ax, ay, az, mx, my, mz)
    q_out[0], q_out[1], q_out[2], q_out[3] = q
    return f
