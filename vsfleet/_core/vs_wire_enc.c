/* vs_wire_enc.c - a small msgpack writer and the encoders of the agent's cmd and state messages
 * (vs_wire.h, docs/decoder.md, "The encoders"): the bytes vsfleet.wire.encode writes, byte for byte. */
#include <string.h>

#include "vs_wire.h"

#define FIT_32 ((uint64_t)0xffffffffu)     /* the longest str, array or map a 32-bit header holds */

/* ---------------------------------------------------------------- the writer */

void vs_mp_writer_init(vs_mp_writer *w, unsigned char *buf, size_t cap)
{
    w->buf = buf;
    w->cap = cap;
    w->n = 0;
    w->full = 0;
}

size_t vs_mp_end(const vs_mp_writer *w)
{
    return w->full ? 0 : w->n;
}

/* k bytes, or nothing (and the writer full) when they do not fit. */
static void put(vs_mp_writer *w, const unsigned char *p, size_t k)
{
    if (w->full) return;
    if (k > w->cap - w->n) {
        w->full = 1;
        return;
    }
    if (k > 0) memcpy(w->buf + w->n, p, k);
    w->n += k;
}

/* A format byte, then v as a big-endian integer of k (0, 1, 2, 4 or 8) bytes, written out byte by byte. */
static void put_head(vs_mp_writer *w, unsigned code, uint64_t v, size_t k)
{
    unsigned char b[9];
    b[0] = (unsigned char)code;
    for (size_t i = 0; i < k; i++) b[1 + i] = (unsigned char)(v >> (8 * (k - 1 - i)));
    put(w, b, 1 + k);
}

/* A length or count's header: the fix form below fix_end (fix_code | len), then the 8-bit form
 * (code8, when there is one: str only), the 16-bit and the 32-bit ones; longer does not fit. */
static void put_len(vs_mp_writer *w, uint64_t len, unsigned fix_code, uint64_t fix_end, int code8, unsigned code16)
{
    if (len < fix_end) put_head(w, fix_code | (unsigned)len, 0, 0);
    else if (code8 >= 0 && len < 0x100u) put_head(w, (unsigned)code8, len, 1);
    else if (len < 0x10000u) put_head(w, code16, len, 2);
    else if (len <= FIT_32) put_head(w, code16 + 1u, len, 4);
    else w->full = 1;
}

void vs_mp_put_map(vs_mp_writer *w, uint64_t count)
{
    put_len(w, count, 0x80u, 16u, -1, 0xdeu);                    /* fixmap, map 16, map 32 */
}

void vs_mp_put_array(vs_mp_writer *w, uint64_t count)
{
    put_len(w, count, 0x90u, 16u, -1, 0xdcu);                    /* fixarray, array 16, array 32 */
}

void vs_mp_put_str(vs_mp_writer *w, const unsigned char *s, size_t len)
{
    put_len(w, (uint64_t)len, 0xa0u, 32u, 0xd9, 0xdau);          /* fixstr, str 8, 16, 32 */
    if (!w->full) put(w, s, len);
}

void vs_mp_put_uint(vs_mp_writer *w, uint64_t v)
{
    if (v < 0x80u) put_head(w, (unsigned)v, 0, 0);               /* positive fixint */
    else if (v < 0x100u) put_head(w, 0xccu, v, 1);               /* uint 8 */
    else if (v < 0x10000u) put_head(w, 0xcdu, v, 2);             /* uint 16 */
    else if (v <= FIT_32) put_head(w, 0xceu, v, 4);              /* uint 32 */
    else put_head(w, 0xcfu, v, 8);                               /* uint 64 */
}

void vs_mp_put_int(vs_mp_writer *w, int64_t v)
{
    if (v >= 0) { vs_mp_put_uint(w, (uint64_t)v); return; }
    uint64_t bits = (uint64_t)v;                                 /* two's complement, by C99's conversion rule */
    if (v >= -32) put_head(w, (unsigned)(bits & 0xffu), 0, 0);   /* negative fixint */
    else if (v >= -128) put_head(w, 0xd0u, bits & 0xffu, 1);     /* int 8 */
    else if (v >= -32768) put_head(w, 0xd1u, bits & 0xffffu, 2); /* int 16 */
    else if (v >= -2147483647 - 1) put_head(w, 0xd2u, bits & FIT_32, 4);   /* int 32 */
    else put_head(w, 0xd3u, bits, 8);                            /* int 64 */
}

void vs_mp_put_f64(vs_mp_writer *w, double v)
{
    uint64_t bits;
    memcpy(&bits, &v, 8);                                        /* the bits as they are, no conversion */
    put_head(w, 0xcbu, bits, 8);
}

void vs_mp_put_bool(vs_mp_writer *w, int v)
{
    put_head(w, v ? 0xc3u : 0xc2u, 0, 0);
}

/* ---------------------------------------------------------------- the agent's messages */

/* A key: a str literal, its length known at compile time. */
#define PUT_KEY(w, k) vs_mp_put_str((w), (const unsigned char *)(k), sizeof(k) - 1)

size_t vs_wire_encode_cmd(double t, uint64_t seq, double vl, double vr, double ttl, unsigned char *buf, size_t cap)
{
    vs_mp_writer w;
    vs_mp_writer_init(&w, buf, cap);
    vs_mp_put_map(&w, 5);
    PUT_KEY(&w, "t");
    vs_mp_put_f64(&w, t);
    PUT_KEY(&w, "seq");
    vs_mp_put_uint(&w, seq);
    PUT_KEY(&w, "vl");
    vs_mp_put_f64(&w, vl);
    PUT_KEY(&w, "vr");
    vs_mp_put_f64(&w, vr);
    PUT_KEY(&w, "ttl");
    vs_mp_put_f64(&w, ttl);
    return vs_mp_end(&w);
}

size_t vs_wire_encode_state(const vs_wire_state *s, unsigned char *buf, size_t cap)
{
    vs_mp_writer w;
    vs_mp_writer_init(&w, buf, cap);
    vs_mp_put_map(&w, 16);
    PUT_KEY(&w, "t");
    vs_mp_put_f64(&w, s->t);
    PUT_KEY(&w, "seq");
    vs_mp_put_uint(&w, s->seq);
    PUT_KEY(&w, "x");
    vs_mp_put_f64(&w, s->x);
    PUT_KEY(&w, "y");
    vs_mp_put_f64(&w, s->y);
    PUT_KEY(&w, "th");
    vs_mp_put_f64(&w, s->th);
    PUT_KEY(&w, "gx");
    vs_mp_put_f64(&w, s->gx);
    PUT_KEY(&w, "gy");
    vs_mp_put_f64(&w, s->gy);
    PUT_KEY(&w, "gth");
    vs_mp_put_f64(&w, s->gth);
    PUT_KEY(&w, "cost");
    vs_mp_put_f64(&w, s->cost);
    PUT_KEY(&w, "err");
    vs_mp_put_f64(&w, s->err);
    PUT_KEY(&w, "used");
    vs_mp_put_array(&w, (uint64_t)s->n_used);
    for (size_t j = 0; j < s->n_used && !w.full; j++) vs_mp_put_str(&w, s->used[j].s, s->used[j].len);
    PUT_KEY(&w, "rejected");
    vs_mp_put_uint(&w, s->rejected);
    PUT_KEY(&w, "complete");
    vs_mp_put_bool(&w, s->complete);
    PUT_KEY(&w, "mission");
    vs_mp_put_int(&w, s->mission);
    PUT_KEY(&w, "shape");
    vs_mp_put_int(&w, s->shape);
    PUT_KEY(&w, "v");
    vs_mp_put_int(&w, s->v);
    return vs_mp_end(&w);
}
