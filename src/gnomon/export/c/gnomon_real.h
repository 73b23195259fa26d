/* gnomon flight code: the number type and the math every filter uses.
 *
 * real_t is double, or float when gnomon_config.h defines GNOMON_FLOAT (gnomon export c
 * --precision float). Write literals as R(0.5) and call math through the GN_ macros: the
 * same source then builds in either precision, and as C++ with GNOMON_COUNT_OPS for the
 * operation counts of cost.json (gnomon_count.hpp: every +, -, *, / and function call on
 * real_t counted).
 *
 * C99; only <math.h>, <stdint.h> and <stdbool.h>. No heap, no globals, no I/O.
 */
#ifndef GNOMON_REAL_H
#define GNOMON_REAL_H

#include <math.h>
#include <stdbool.h>
#include <stdint.h>

#include "gnomon_config.h"

#if defined(GNOMON_COUNT_OPS) && defined(__cplusplus)
#include "gnomon_count.hpp"
typedef gn_counted real_t;
#define R(x) gn_counted((double)(x))
#define GN_SQRT(x) gn_sqrt(x)
#define GN_SIN(x) gn_sin(x)
#define GN_COS(x) gn_cos(x)
#define GN_TAN(x) gn_tan(x)
#define GN_ATAN2(y, x) gn_atan2((y), (x))
#define GN_ASIN(x) gn_asin(x)
#define GN_ACOS(x) gn_acos(x)
#define GN_EXP(x) gn_exp(x)
#define GN_LOG(x) gn_log(x)
#define GN_FABS(x) gn_fabs(x)
#define GN_ISFINITE(x) gn_isfinite(x)
#define GN_TO_DOUBLE(x) ((x).v)
#elif defined(GNOMON_FLOAT)
typedef float real_t;
#define R(x) ((float)(x))
#define GN_SQRT(x) sqrtf(x)
#define GN_SIN(x) sinf(x)
#define GN_COS(x) cosf(x)
#define GN_TAN(x) tanf(x)
#define GN_ATAN2(y, x) atan2f((y), (x))
#define GN_ASIN(x) asinf(x)
#define GN_ACOS(x) acosf(x)
#define GN_EXP(x) expf(x)
#define GN_LOG(x) logf(x)
#define GN_FABS(x) fabsf(x)
#define GN_ISFINITE(x) isfinite(x)
#define GN_TO_DOUBLE(x) ((double)(x))
#else
typedef double real_t;
#define R(x) ((double)(x))
#define GN_SQRT(x) sqrt(x)
#define GN_SIN(x) sin(x)
#define GN_COS(x) cos(x)
#define GN_TAN(x) tan(x)
#define GN_ATAN2(y, x) atan2((y), (x))
#define GN_ASIN(x) asin(x)
#define GN_ACOS(x) acos(x)
#define GN_EXP(x) exp(x)
#define GN_LOG(x) log(x)
#define GN_FABS(x) fabs(x)
#define GN_ISFINITE(x) isfinite(x)
#define GN_TO_DOUBLE(x) ((double)(x))
#endif

static inline real_t gn_min(real_t a, real_t b) { return a < b ? a : b; }
static inline real_t gn_max(real_t a, real_t b) { return a > b ? a : b; }
static inline real_t gn_clip(real_t v, real_t lim) { return v > lim ? lim : (v < -lim ? -lim : v); }

#endif /* GNOMON_REAL_H */
