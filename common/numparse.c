/* numparse.c - integer and decimal tokens from the mesh readers' buffers.
 * See numparse.h for the contract.
 *
 * Decimal numbers give exactly what strtod gives, rounded once to double;
 * the fast path below is exact (Clinger), not an approximation.
 */
#include "numparse.h"

#include <float.h>
#include <stdlib.h>
#include <string.h>

int num_parse_int(const char *s, size_t len, int64_t *out)
{
    size_t i = 0;
    int neg = 0;
    if (i < len && (s[i] == '+' || s[i] == '-')) {
        neg = s[i] == '-';
        i++;
    }
    if (i == len)
        return -1;
    uint64_t v = 0;
    for (; i < len; i++) {
        unsigned d = (unsigned)((unsigned char)s[i] - '0');
        if (d > 9 || v > (UINT64_C(9223372036854775807) - d) / 10)
            return -1;
        v = v * 10 + d;
    }
    *out = neg ? -(int64_t)v : (int64_t)v;
    return 0;
}

static const double pow10_exact[23] = {1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,
                                       1e8,  1e9,  1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
                                       1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};

/* strtod on a NUL-terminated copy, because the buffer itself is not
 * terminated and strtod must not run past the token. */
static int parse_double_slow(const char *s, size_t len, double *out)
{
    char buf[128];
    if (len == 0 || len >= sizeof buf)
        return -1;
    memcpy(buf, s, len);
    buf[len] = '\0';
    char *end = NULL;
    double v = strtod(buf, &end);
    if (end != buf + len)
        return -1;
    *out = v;
    return 0;
}

/* The common case (at most 19 significant digits, mantissa <= 2^53,
 * |power of ten| <= 22) is one exact integer conversion and one correctly
 * rounded multiply or divide; everything else (nan, inf, hex, long
 * mantissas, big exponents) goes to parse_double_slow. */
int num_parse_double(const char *s, size_t len, double *out)
{
    const char *p = s, *e = s + len;
    int neg = 0, sig = 0, nd = 0;
    uint64_t m = 0;
    long e10 = 0;

    if (FLT_EVAL_METHOD != 0)
        goto slow; /* the exactness argument needs plain double arithmetic */
    if (p < e && (*p == '+' || *p == '-')) {
        neg = *p == '-';
        p++;
    }
    for (; p < e && num_is_digit((unsigned char)*p); p++, nd++) {
        if (m || *p != '0') {
            if (sig == 19)
                goto slow;
            m = m * 10 + (uint64_t)(*p - '0');
            sig++;
        }
    }
    if (p < e && *p == '.') {
        for (p++; p < e && num_is_digit((unsigned char)*p); p++, nd++) {
            if (m || *p != '0') {
                if (sig == 19)
                    goto slow;
                m = m * 10 + (uint64_t)(*p - '0');
                sig++;
            }
            e10--;
        }
    }
    if (nd == 0)
        goto slow;
    if (p < e && (*p == 'e' || *p == 'E')) {
        int eneg = 0;
        long x = 0;
        p++;
        if (p < e && (*p == '+' || *p == '-')) {
            eneg = *p == '-';
            p++;
        }
        if (p == e || !num_is_digit((unsigned char)*p))
            return -1;
        for (; p < e && num_is_digit((unsigned char)*p); p++)
            if (x < 100000)
                x = x * 10 + (*p - '0');
        e10 += eneg ? -x : x;
    }
    if (p != e)
        goto slow;
    if (m == 0) {
        *out = neg ? -0.0 : 0.0;
        return 0;
    }
    if (m > (UINT64_C(1) << 53) || e10 < -22 || e10 > 22)
        goto slow;
    {
        double v = (double)m;
        v = e10 < 0 ? v / pow10_exact[-e10] : v * pow10_exact[e10];
        *out = neg ? -v : v;
        return 0;
    }
slow:
    return parse_double_slow(s, len, out);
}
