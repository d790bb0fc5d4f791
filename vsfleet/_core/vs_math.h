/* vs_math.h - the core's own elementary functions.
 *
 * Written with + - * / and sqrt only (sqrt is correctly rounded by IEEE 754 on every
 * host), so every host computes the same bits: the core calls no other libm function.
 * Derived from FreeBSD msun (fdlibm): k_sin.c, k_cos.c, e_rem_pio2.c, s_atan.c,
 * e_atan2.c (Copyright (C) 1993 by Sun Microsystems, Inc.: "Permission to use, copy,
 * modify, and distribute this software is freely granted, provided that this notice is
 * preserved."), and musl's fmod.c (MIT).  Errors: < 1 ulp for |x| < 2^20 pi/2; beyond that
 * the reduction keeps 118 bits of pi/2 only (a defined, reproducible result; the core
 * wraps its angles first).  Angles [rad], counter-clockwise.
 */
#ifndef VS_MATH_H
#define VS_MATH_H

#include <stdint.h>
#include <string.h>

double vs_sin(double x);
double vs_cos(double x);
void vs_sincos(double x, double *s, double *c);
double vs_atan(double x);
double vs_atan2(double y, double x);
double vs_fmod(double x, double y);     /* exact, as C99 fmod */
double vs_hypot(double x, double y);    /* sqrt(x*x + y*y): NOT libm's hypot (no overflow guard) */
double vs_wrap_angle(double th_rad);    /* [-pi, pi), as vsfleet.geometry.wrap_angle */
/* the classifications and fabs, by the bits (inline: the kernels call them per element) */
static inline uint64_t vs_bits_(double x) { uint64_t u; memcpy(&u, &x, sizeof u); return u; }
static inline int vs_isfinite(double x) { return (vs_bits_(x) & 0x7ff0000000000000ULL) != 0x7ff0000000000000ULL; }
static inline int vs_isnan(double x) { return (vs_bits_(x) & 0x7fffffffffffffffULL) > 0x7ff0000000000000ULL; }
static inline double vs_fabs(double x)
{
    uint64_t u = vs_bits_(x) & 0x7fffffffffffffffULL;
    double y;
    memcpy(&y, &u, sizeof y);
    return y;
}

#define VS_PI 3.14159265358979311600e+00
#define VS_TWO_PI 6.28318530717958623200e+00

#endif
