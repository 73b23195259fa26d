/* Operation counts for cost.json: a number type that counts what is done with it.
 *
 * Used only by `make count` (the filter's C source compiled as C++ with GNOMON_COUNT_OPS,
 * see gnomon_real.h): each +, -, *, / on real_t adds one to its counter, each call of a
 * math function one to its own; comparisons and copies are free. The counts are of the
 * source's arithmetic as written (what the compiler may fuse or hoist is not seen).
 */
#ifndef GNOMON_COUNT_HPP
#define GNOMON_COUNT_HPP

#include <cmath>

struct gn_op_counts {
    long add, mul, div, sqrt, trig, other;
};
extern gn_op_counts gn_ops;

struct gn_counted {
    double v;
    gn_counted() : v(0.0) {}
    gn_counted(double x) : v(x) {}  /* NOLINT: literals and ints convert implicitly */
    explicit operator double() const { return v; }
    gn_counted &operator+=(gn_counted o) { ++gn_ops.add; v += o.v; return *this; }
    gn_counted &operator-=(gn_counted o) { ++gn_ops.add; v -= o.v; return *this; }
    gn_counted &operator*=(gn_counted o) { ++gn_ops.mul; v *= o.v; return *this; }
    gn_counted &operator/=(gn_counted o) { ++gn_ops.div; v /= o.v; return *this; }
};

inline gn_counted operator+(gn_counted a, gn_counted b) { ++gn_ops.add; return gn_counted(a.v + b.v); }
inline gn_counted operator-(gn_counted a, gn_counted b) { ++gn_ops.add; return gn_counted(a.v - b.v); }
inline gn_counted operator*(gn_counted a, gn_counted b) { ++gn_ops.mul; return gn_counted(a.v * b.v); }
inline gn_counted operator/(gn_counted a, gn_counted b) { ++gn_ops.div; return gn_counted(a.v / b.v); }
inline gn_counted operator-(gn_counted a) { return gn_counted(-a.v); }
inline bool operator<(gn_counted a, gn_counted b) { return a.v < b.v; }
inline bool operator>(gn_counted a, gn_counted b) { return a.v > b.v; }
inline bool operator<=(gn_counted a, gn_counted b) { return a.v <= b.v; }
inline bool operator>=(gn_counted a, gn_counted b) { return a.v >= b.v; }
inline bool operator==(gn_counted a, gn_counted b) { return a.v == b.v; }
inline bool operator!=(gn_counted a, gn_counted b) { return a.v != b.v; }

inline gn_counted gn_sqrt(gn_counted a) { ++gn_ops.sqrt; return gn_counted(std::sqrt(a.v)); }
inline gn_counted gn_sin(gn_counted a) { ++gn_ops.trig; return gn_counted(std::sin(a.v)); }
inline gn_counted gn_cos(gn_counted a) { ++gn_ops.trig; return gn_counted(std::cos(a.v)); }
inline gn_counted gn_tan(gn_counted a) { ++gn_ops.trig; return gn_counted(std::tan(a.v)); }
inline gn_counted gn_atan2(gn_counted y, gn_counted x) { ++gn_ops.trig; return gn_counted(std::atan2(y.v, x.v)); }
inline gn_counted gn_asin(gn_counted a) { ++gn_ops.trig; return gn_counted(std::asin(a.v)); }
inline gn_counted gn_acos(gn_counted a) { ++gn_ops.trig; return gn_counted(std::acos(a.v)); }
inline gn_counted gn_exp(gn_counted a) { ++gn_ops.other; return gn_counted(std::exp(a.v)); }
inline gn_counted gn_log(gn_counted a) { ++gn_ops.other; return gn_counted(std::log(a.v)); }
inline gn_counted gn_fabs(gn_counted a) { return gn_counted(std::fabs(a.v)); }
inline bool gn_isfinite(gn_counted a) { return std::isfinite(a.v); }

#endif /* GNOMON_COUNT_HPP */
