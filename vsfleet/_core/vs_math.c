/* vs_math.c - see vs_math.h.  Compiled with -ffp-contract=off: no fused multiply-add. */
#include "vs_math.h"

#include <math.h>   /* sqrt only */
#include <stdint.h>
#include <string.h>

static uint64_t bits(double x) { uint64_t u; memcpy(&u, &x, sizeof u); return u; }
static double from_bits(uint64_t u) { double x; memcpy(&x, &u, sizeof x); return x; }
static uint32_t high_word(double x) { return (uint32_t)(bits(x) >> 32); }

double vs_hypot(double x, double y) { return sqrt(x * x + y * y); }

/* ---- sin, cos (fdlibm kernels on [-pi/4, pi/4]) */

static const double
    S1 = -1.66666666666666324348e-01, S2 = 8.33333333332248946124e-03,
    S3 = -1.98412698298579493134e-04, S4 = 2.75573137070700676789e-06,
    S5 = -2.50507602534068634195e-08, S6 = 1.58969099521155010221e-10,
    C1 = 4.16666666666666019037e-02, C2 = -1.38888888888741095749e-03,
    C3 = 2.48015872894767294178e-05, C4 = -2.75573143513906633035e-07,
    C5 = 2.08757232129817482790e-09, C6 = -1.13596475577881948265e-11;

static double k_sin(double x, double y, int iy)
{
    double z = x * x, w = z * z;
    double r = S2 + z * (S3 + z * S4) + z * w * (S5 + z * S6);
    double v = z * x;
    if (iy == 0) return x + v * (S1 + z * r);
    return x - ((z * (0.5 * y - v * r) - y) - v * S1);
}

static double k_cos(double x, double y)
{
    double z = x * x, w = z * z;
    double r = z * (C1 + z * (C2 + z * C3)) + w * w * (C4 + z * (C5 + z * C6));
    double hz = 0.5 * z;
    w = 1.0 - hz;
    return w + (((1.0 - w) - hz) + (z * r - x * y));
}

static const double
    invpio2 = 6.36619772367581382433e-01,
    pio2_1 = 1.57079632673412561417e+00, pio2_1t = 6.07710050650619224932e-11,
    pio2_2 = 6.07710050630396597660e-11, pio2_2t = 2.02226624879595063154e-21,
    pio2_3 = 2.02226624871116645580e-21, pio2_3t = 8.47842766036889956997e-32;

/* x = n pi/2 + y[0] + y[1], |y| <= pi/4 (fdlibm's medium case, used for every finite x). */
static int rem_pio2(double x, double y[2])
{
    double fn = x * invpio2 + 0x1.8p52;
    fn = fn - 0x1.8p52;                       /* round to nearest, no libm */
    int n = (int)((int64_t)fn & 3);           /* the quadrant is all the callers use */
    double r = x - fn * pio2_1, w = fn * pio2_1t;
    int j = (int)((high_word(x) >> 20) & 0x7ff);
    y[0] = r - w;
    int i = j - (int)((high_word(y[0]) >> 20) & 0x7ff);
    if (i > 16) {
        double t = r;
        w = fn * pio2_2;
        r = t - w;
        w = fn * pio2_2t - ((t - r) - w);
        y[0] = r - w;
        i = j - (int)((high_word(y[0]) >> 20) & 0x7ff);
        if (i > 49) {
            t = r;
            w = fn * pio2_3;
            r = t - w;
            w = fn * pio2_3t - ((t - r) - w);
            y[0] = r - w;
        }
    }
    y[1] = (r - y[0]) - w;
    return n;
}

void vs_sincos(double x, double *s, double *c)
{
    uint32_t ix = high_word(x) & 0x7fffffff;
    if (ix <= 0x3fe921fb) {                   /* |x| ~<= pi/4 */
        if (ix < 0x3e400000) { *s = x; *c = 1.0; return; }   /* |x| < 2^-27 */
        *s = k_sin(x, 0.0, 0);
        *c = k_cos(x, 0.0);
        return;
    }
    if (ix >= 0x7ff00000) { *s = *c = x - x; return; }      /* NaN, inf -> NaN */
    double y[2];
    if (ix >= 0x43300000) {                   /* |x| >= 2^52: reduce by 2 pi exactly first */
        x = vs_fmod(x, VS_TWO_PI);
    }
    int n = rem_pio2(x, y);
    double ks = k_sin(y[0], y[1], 1), kc = k_cos(y[0], y[1]);
    switch (n & 3) {
    case 0: *s = ks; *c = kc; break;
    case 1: *s = kc; *c = -ks; break;
    case 2: *s = -ks; *c = -kc; break;
    default: *s = -kc; *c = ks; break;
    }
}

double vs_sin(double x) { double s, c; vs_sincos(x, &s, &c); return s; }
double vs_cos(double x) { double s, c; vs_sincos(x, &s, &c); return c; }

/* ---- atan, atan2 (fdlibm) */

static const double atanhi[] = {
    4.63647609000806093515e-01, 7.85398163397448278999e-01,
    9.82793723247329054082e-01, 1.57079632679489655800e+00};
static const double atanlo[] = {
    2.26987774529616870924e-17, 3.06161699786838301793e-17,
    1.39033110312309984516e-17, 6.12323399573676603587e-17};
static const double aT[] = {
    3.33333333333329318027e-01, -1.99999999998764832476e-01, 1.42857142725034663711e-01,
    -1.11111104054623557880e-01, 9.09088713343650656196e-02, -7.69187620504482999495e-02,
    6.66107313738753120669e-02, -5.83357013379057348645e-02, 4.97687799461593236017e-02,
    -3.65315727442169155270e-02, 1.62858201153657823623e-02};

double vs_atan(double x)
{
    uint32_t hx = high_word(x), ix = hx & 0x7fffffff;
    int id;
    if (ix >= 0x44100000) {                   /* |x| >= 2^66 */
        if (vs_isnan(x)) return x + x;
        return (hx >> 31) ? -atanhi[3] - atanlo[3] : atanhi[3] + atanlo[3];
    }
    if (ix < 0x3fdc0000) {                    /* |x| < 0.4375 */
        if (ix < 0x3e400000) return x;        /* |x| < 2^-27 */
        id = -1;
    } else {
        x = vs_fabs(x);
        if (ix < 0x3ff30000) {
            if (ix < 0x3fe60000) { id = 0; x = (2.0 * x - 1.0) / (2.0 + x); }
            else { id = 1; x = (x - 1.0) / (x + 1.0); }
        } else {
            if (ix < 0x40038000) { id = 2; x = (x - 1.5) / (1.0 + 1.5 * x); }
            else { id = 3; x = -1.0 / x; }
        }
    }
    double z = x * x, w = z * z;
    double s1 = z * (aT[0] + w * (aT[2] + w * (aT[4] + w * (aT[6] + w * (aT[8] + w * aT[10])))));
    double s2 = w * (aT[1] + w * (aT[3] + w * (aT[5] + w * (aT[7] + w * aT[9]))));
    if (id < 0) return x - x * (s1 + s2);
    z = atanhi[id] - ((x * (s1 + s2) - atanlo[id]) - x);
    return (hx >> 31) ? -z : z;
}

static const double pi_o_4 = 7.8539816339744827900E-01, pi_o_2 = 1.5707963267948965580E+00,
    pi = 3.1415926535897931160E+00, pi_lo = 1.2246467991473531772E-16;

double vs_atan2(double y, double x)
{
    if (vs_isnan(x) || vs_isnan(y)) return x + y;
    if (x == 1.0) return vs_atan(y);
    uint32_t hx = high_word(x), hy = high_word(y);
    uint32_t ix = hx & 0x7fffffff, iy = hy & 0x7fffffff;
    int m = (int)(((hy >> 31) & 1) | ((hx >> 30) & 2));
    if (y == 0.0) {
        switch (m) {
        case 0: case 1: return y;
        case 2: return pi;
        default: return -pi;
        }
    }
    if (x == 0.0) return (hy >> 31) ? -pi_o_2 : pi_o_2;
    if (ix == 0x7ff00000) {
        if (iy == 0x7ff00000) {
            switch (m) {
            case 0: return pi_o_4;
            case 1: return -pi_o_4;
            case 2: return 3.0 * pi_o_4;
            default: return -3.0 * pi_o_4;
            }
        }
        switch (m) {
        case 0: return 0.0;
        case 1: return -0.0;
        case 2: return pi;
        default: return -pi;
        }
    }
    if (iy == 0x7ff00000) return (hy >> 31) ? -pi_o_2 : pi_o_2;
    int k = ((int)iy - (int)ix) >> 20;
    double z;
    if (k > 60) { z = pi_o_2 + 0.5 * pi_lo; m &= 1; }
    else if ((hx >> 31) && k < -60) z = 0.0;
    else z = vs_atan(vs_fabs(y / x));
    switch (m) {
    case 0: return z;
    case 1: return -z;
    case 2: return pi - (z - pi_lo);
    default: return (z - pi_lo) - pi;
    }
}

/* ---- fmod (musl, integer only: exact) */

double vs_fmod(double x, double y)
{
    uint64_t uxi = bits(x), uyi = bits(y), i;
    int ex = (int)(uxi >> 52 & 0x7ff), ey = (int)(uyi >> 52 & 0x7ff);
    uint64_t sx = uxi >> 63;
    if ((uyi << 1) == 0 || vs_isnan(y) || ex == 0x7ff) return (x * y) / (x * y);
    if ((uxi << 1) <= (uyi << 1)) {
        if ((uxi << 1) == (uyi << 1)) return 0 * x;
        return x;
    }
    if (!ex) {
        for (i = uxi << 12; i >> 63 == 0; ex--, i <<= 1) ;
        uxi <<= -ex + 1;
    } else {
        uxi &= (uint64_t)-1 >> 12;
        uxi |= 1ULL << 52;
    }
    if (!ey) {
        for (i = uyi << 12; i >> 63 == 0; ey--, i <<= 1) ;
        uyi <<= -ey + 1;
    } else {
        uyi &= (uint64_t)-1 >> 12;
        uyi |= 1ULL << 52;
    }
    for (; ex > ey; ex--) {
        i = uxi - uyi;
        if (i >> 63 == 0) {
            if (i == 0) return 0 * x;
            uxi = i;
        }
        uxi <<= 1;
    }
    i = uxi - uyi;
    if (i >> 63 == 0) {
        if (i == 0) return 0 * x;
        uxi = i;
    }
    for (; uxi >> 52 == 0; uxi <<= 1, ex--) ;
    if (ex > 0) {
        uxi -= 1ULL << 52;
        uxi |= (uint64_t)ex << 52;
    } else {
        uxi >>= -ex + 1;
    }
    uxi |= sx << 63;
    return from_bits(uxi);
}

double vs_wrap_angle(double th_rad)
{
    double w = vs_fmod(th_rad + VS_PI, VS_TWO_PI);
    if (w < 0.0) w += VS_TWO_PI;
    return w - VS_PI;
}
