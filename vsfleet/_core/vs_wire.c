/* vs_wire.c - a small msgpack reader and the tracker frame's decoder (vs_wire.h, docs/decoder.md). */
#include <string.h>

#include "vs_wire.h"

#define TWO_53 9007199254740992.0          /* 2^53: every integer up to it converts to double exactly */
#define INT_EXACT ((uint64_t)1 << 53)
#define UINT63_END ((uint64_t)1 << 63)

/* ---------------------------------------------------------------- the reader */

void vs_mp_init(vs_mp_reader *r, const unsigned char *buf, size_t len)
{
    r->buf = buf;
    r->len = len;
    r->pos = 0;
    r->why = NULL;
    r->code = VS_OK;
}

int vs_mp_fail(vs_mp_reader *r, int code, const char *why)
{
    if (r->why == NULL) {
        r->why = why;
        r->code = code;
    }
    return 0;
}

/* The next k bytes, or NULL (and the error "truncated" when fewer remain). */
static const unsigned char *take(vs_mp_reader *r, size_t k)
{
    if (r->why != NULL) return NULL;
    if (r->len - r->pos < k) {
        vs_mp_fail(r, VS_EVALUE, "not valid msgpack: truncated");
        return NULL;
    }
    const unsigned char *at = r->buf + r->pos;
    r->pos += k;
    return at;
}

/* A big-endian unsigned integer of 4 bytes, written out so that compilers see a byte swap. */
static uint64_t be32(const unsigned char *p)
{
    return (uint64_t)p[0] << 24 | (uint64_t)p[1] << 16 | (uint64_t)p[2] << 8 | (uint64_t)p[3];
}

/* A big-endian unsigned integer of k (1, 2, 4 or 8) bytes; 0 after an error. */
static uint64_t take_be(vs_mp_reader *r, size_t k)
{
    const unsigned char *p = take(r, k);
    if (p == NULL) return 0;
    switch (k) {
    case 1: return p[0];
    case 2: return (uint64_t)p[0] << 8 | (uint64_t)p[1];
    case 4: return be32(p);
    default: return be32(p) << 32 | be32(p + 4);
    }
}

/* A two's-complement integer of `bits` bits (8..64) as read, as an item: UINT when >= 0, else NEGINT. */
static int signed_item(vs_mp_item *it, uint64_t v, unsigned bits)
{
    uint64_t sign = (uint64_t)1 << (bits - 1);
    if ((v & sign) == 0) {
        it->kind = VS_MP_UINT;
        it->u = v;
        return 1;
    }
    uint64_t mag = bits == 64 ? ~v + 1 : (((uint64_t)1 << bits) - v);   /* in [1, 2^(bits-1)] */
    it->kind = VS_MP_NEGINT;
    it->i = mag == UINT63_END ? INT64_MIN : -(int64_t)mag;
    return 1;
}

/* A str, bin or ext body of k bytes: recorded (offset, length), skipped. */
static int body_item(vs_mp_reader *r, vs_mp_item *it, vs_mp_kind kind, uint64_t k)
{
    if (r->why != NULL) return 0;
    if (k > r->len - r->pos) return vs_mp_fail(r, VS_EVALUE, "not valid msgpack: truncated");
    it->kind = kind;
    it->u = k;
    it->off = r->pos;
    r->pos += (size_t)k;
    return 1;
}

/* An array or map header of `count` entries; the entries need at least 1 (array) or 2 (map) bytes each. */
static int container_item(vs_mp_reader *r, vs_mp_item *it, vs_mp_kind kind, uint64_t count)
{
    if (r->why != NULL) return 0;
    uint64_t room = r->len - r->pos;
    if (count > (kind == VS_MP_MAP ? room / 2 : room)) return vs_mp_fail(r, VS_EVALUE, "not valid msgpack: truncated");
    it->kind = kind;
    it->u = count;
    return 1;
}

int vs_mp_next(vs_mp_reader *r, vs_mp_item *it)
{
    memset(it, 0, sizeof *it);
    it->kind = VS_MP_NIL;
    const unsigned char *p = take(r, 1);
    if (p == NULL) return 0;
    unsigned c = p[0];
    if (c <= 0x7f) { it->kind = VS_MP_UINT; it->u = c; return 1; }                 /* positive fixint */
    if (c >= 0xe0) { it->kind = VS_MP_NEGINT; it->i = (int64_t)c - 256; return 1; } /* negative fixint */
    if (c <= 0x8f) return container_item(r, it, VS_MP_MAP, c & 0x0fu);              /* fixmap */
    if (c <= 0x9f) return container_item(r, it, VS_MP_ARRAY, c & 0x0fu);            /* fixarray */
    if (c <= 0xbf) return body_item(r, it, VS_MP_STR, c & 0x1fu);                    /* fixstr */
    switch (c) {
    case 0xc0: return 1;                                                              /* nil */
    case 0xc2: case 0xc3: it->kind = VS_MP_BOOL; it->u = c & 1u; return 1;
    case 0xc4: case 0xc5: case 0xc6: {                                                /* bin 8/16/32 */
        uint64_t k = take_be(r, (size_t)1 << (c - 0xc4));
        return body_item(r, it, VS_MP_BIN, k);
    }
    case 0xc7: case 0xc8: case 0xc9: {                                                /* ext 8/16/32 */
        uint64_t k = take_be(r, (size_t)1 << (c - 0xc7));
        take_be(r, 1);                                                                /* its type */
        return body_item(r, it, VS_MP_EXT, k);
    }
    case 0xca: {                                                                      /* float32 */
        uint32_t bits = (uint32_t)take_be(r, 4);
        float f;
        memcpy(&f, &bits, 4);
        it->kind = VS_MP_FLOAT;
        it->d = (double)f;
        it->is_f32 = 1;
        return r->why == NULL;
    }
    case 0xcb: {                                                                      /* float64 */
        uint64_t bits = take_be(r, 8);
        it->kind = VS_MP_FLOAT;
        memcpy(&it->d, &bits, 8);
        return r->why == NULL;
    }
    case 0xcc: case 0xcd: case 0xce: case 0xcf:                                      /* uint 8/16/32/64 */
        it->kind = VS_MP_UINT;
        it->u = take_be(r, (size_t)1 << (c - 0xcc));
        return r->why == NULL;
    case 0xd0: case 0xd1: case 0xd2: case 0xd3: {                                     /* int 8/16/32/64 */
        size_t k = (size_t)1 << (c - 0xd0);
        uint64_t v = take_be(r, k);
        return r->why == NULL && signed_item(it, v, 8u * (unsigned)k);
    }
    case 0xd4: case 0xd5: case 0xd6: case 0xd7: case 0xd8:                           /* fixext 1..16 */
        take_be(r, 1);
        return body_item(r, it, VS_MP_EXT, (uint64_t)1 << (c - 0xd4));
    case 0xd9: case 0xda: case 0xdb: {                                                /* str 8/16/32 */
        uint64_t k = take_be(r, (size_t)1 << (c - 0xd9));
        return body_item(r, it, VS_MP_STR, k);
    }
    case 0xdc: case 0xdd: {                                                           /* array 16/32 */
        uint64_t k = take_be(r, (size_t)2 << (c - 0xdc));
        return container_item(r, it, VS_MP_ARRAY, k);
    }
    case 0xde: case 0xdf: {                                                           /* map 16/32 */
        uint64_t k = take_be(r, (size_t)2 << (c - 0xde));
        return container_item(r, it, VS_MP_MAP, k);
    }
    default:                                                                          /* 0xc1 */
        return vs_mp_fail(r, VS_EVALUE, "not valid msgpack: the unused byte 0xc1");
    }
}

uint64_t vs_mp_expect_map(vs_mp_reader *r, const char *why_type)
{
    vs_mp_item it;
    if (!vs_mp_next(r, &it)) return 0;
    if (it.kind != VS_MP_MAP) return (uint64_t)vs_mp_fail(r, VS_EVALUE, why_type);
    return it.u;
}

uint64_t vs_mp_expect_array(vs_mp_reader *r, const char *why_type)
{
    vs_mp_item it;
    if (!vs_mp_next(r, &it)) return 0;
    if (it.kind != VS_MP_ARRAY) return (uint64_t)vs_mp_fail(r, VS_EVALUE, why_type);
    return it.u;
}

size_t vs_mp_expect_str(vs_mp_reader *r, size_t *len, const char *why_type)
{
    vs_mp_item it;
    *len = 0;
    if (!vs_mp_next(r, &it)) return 0;
    if (it.kind != VS_MP_STR) return (size_t)vs_mp_fail(r, VS_EVALUE, why_type);
    *len = (size_t)it.u;
    return it.off;
}

double vs_mp_expect_number(vs_mp_reader *r, double max_abs, const char *why_type)
{
    vs_mp_item it;
    double v;
    if (!vs_mp_next(r, &it)) return 0.0;
    if (it.kind == VS_MP_UINT) {
        if (it.u > INT_EXACT) return vs_mp_fail(r, VS_EVALUE, "out of range");
        v = (double)it.u;
    } else if (it.kind == VS_MP_NEGINT) {
        if (it.i < -(int64_t)INT_EXACT) return vs_mp_fail(r, VS_EVALUE, "out of range");
        v = (double)it.i;
    } else if (it.kind == VS_MP_FLOAT) {
        v = it.d;
    } else {
        return vs_mp_fail(r, VS_EVALUE, why_type);
    }
    if (!vs_isfinite(v)) return vs_mp_fail(r, VS_ENONFINITE, "not finite");
    if (!(v >= -max_abs && v <= max_abs)) return vs_mp_fail(r, VS_EVALUE, "out of range");
    return v;
}

uint64_t vs_mp_expect_uint63(vs_mp_reader *r, const char *why_type)
{
    vs_mp_item it;
    if (!vs_mp_next(r, &it)) return 0;
    if (it.kind == VS_MP_NEGINT || (it.kind == VS_MP_UINT && it.u >= UINT63_END))
        return (uint64_t)vs_mp_fail(r, VS_EVALUE, "out of range (0 <= seq < 2^63)");
    if (it.kind != VS_MP_UINT) return (uint64_t)vs_mp_fail(r, VS_EVALUE, why_type);
    return it.u;
}

/* ---------------------------------------------------------------- the frame's rules */

static int name_char(unsigned c)
{
    return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' || c == '-';
}

/* A key chunk, as the reference's check_name: 1..max_len characters (bytes, once ASCII) of
 * [A-Za-z0-9_-] and nothing else (no final newline, no NUL).  A robot id: the same, of any length. */
static int name_ok(const unsigned char *s, size_t n, size_t max_len)
{
    if (n == 0 || n > max_len) return 0;
    for (size_t i = 0; i < n; i++)
        if (!name_char(s[i])) return 0;
    return 1;
}

static uint32_t fnv1a(const unsigned char *s, size_t n)
{
    uint32_t h = 2166136261u;
    for (size_t i = 0; i < n; i++) h = (h ^ s[i]) * 16777619u;
    return h;
}

enum { FIELD_T, FIELD_SEQ, FIELD_SRC, FIELD_POSES, N_FIELDS };
static const char *const FIELD_NAMES[N_FIELDS] = {"t", "seq", "src", "poses"};

static int field_index(const unsigned char *s, size_t n)
{
    for (int f = 0; f < N_FIELDS; f++)
        if (strlen(FIELD_NAMES[f]) == n && memcmp(FIELD_NAMES[f], s, n) == 0) return f;
    return -1;
}

/* poses: {robot: [x, y, th]} into ids and poses (rows in the order sent); *n robots; *row: the robot
 * whose pose is being read (-1 while no valid id of it has been read), for the error.  Duplicates are
 * found in an open-addressing table of robot rows on the stack (<= 2048 slots for <= 1000 robots). */
static void read_poses(vs_mp_reader *r, vs_wire_slice *ids, double *poses, size_t cap, size_t *n, long *row)
{
    enum { SLOTS_MAX = 2048 };
    uint16_t slot_row[SLOTS_MAX];     /* row + 1 of the id in the slot; 0: empty */
    uint32_t slot_hash[SLOTS_MAX];
    uint64_t count = vs_mp_expect_map(r, "must be a map {robot: [x, y, th]}");
    if (r->why != NULL) return;
    if (count > VS_WIRE_MAX_ROBOTS) { vs_mp_fail(r, VS_EVALUE, "more than 1000 robots"); return; }
    if (count > cap) { vs_mp_fail(r, VS_ENOMEM, "more robots than the caller's buffers hold"); return; }
    size_t slots = 16;
    while (slots < 2 * count) slots *= 2;
    memset(slot_row, 0, slots * sizeof slot_row[0]);
    for (size_t j = 0; j < count && r->why == NULL; j++) {
        *row = -1;
        size_t len, off = vs_mp_expect_str(r, &len, "a robot id that is not a string");
        if (r->why != NULL) break;
        const unsigned char *id = r->buf + off;
        if (!name_ok(id, len, SIZE_MAX)) { vs_mp_fail(r, VS_EVALUE, "robot id must match [A-Za-z0-9_-]+"); break; }
        ids[j].off = (uint32_t)off;
        ids[j].len = (uint32_t)len;
        *row = (long)j;   /* from here on, an error names this robot */
        uint32_t h = fnv1a(id, len);
        size_t s = h & (slots - 1);
        while (slot_row[s] != 0) {
            const vs_wire_slice *other = &ids[slot_row[s] - 1];
            if (slot_hash[s] == h && other->len == len && memcmp(r->buf + other->off, id, len) == 0) {
                vs_mp_fail(r, VS_EVALUE, "robot listed twice (a duplicate key)");
                return;
            }
            s = (s + 1) & (slots - 1);
        }
        slot_row[s] = (uint16_t)(j + 1);
        slot_hash[s] = h;
        if (vs_mp_expect_array(r, "pose must be [x, y, th]") != 3) { vs_mp_fail(r, VS_EVALUE, "pose must be [x, y, th]"); break; }
        for (int c = 0; c < 3; c++)
            poses[3 * j + (size_t)c] = vs_mp_expect_number(r, VS_WIRE_MAX_ABS, "pose must hold numbers");
    }
    *n = (size_t)count;
}

static int refuse(vs_wire_error *err, int code, const char *field, const char *why, long robot, size_t at)
{
    err->why = why;
    err->field = field;
    err->robot = robot;
    err->at = at;
    return code;
}

int vs_wire_decode_frame(const unsigned char *payload, size_t len,
                         const unsigned char *expect_src, size_t expect_src_len,
                         vs_wire_slice *ids, double *poses, size_t cap,
                         vs_frame *frame, vs_wire_error *err)
{
    vs_mp_reader r;
    int seen[N_FIELDS] = {0, 0, 0, 0};
    const char *field = "payload";
    long row = -1;
    double t = 0.0;
    uint64_t seq = 0;
    size_t src_off = 0, src_len = 0, n = 0;
    err->why = NULL;
    err->field = field;
    err->robot = -1;
    err->at = 0;
    if (len > VS_WIRE_MAX_FRAME_BYTES) return refuse(err, VS_EVALUE, field, "payload over 65536 bytes", -1, 0);
    vs_mp_init(&r, payload, len);
    uint64_t pairs = vs_mp_expect_map(&r, "payload is not a msgpack map");
    for (uint64_t k = 0; k < pairs && r.why == NULL; k++) {
        field = "payload";
        size_t key_len, key_off = vs_mp_expect_str(&r, &key_len, "unknown field (a key that is not a string)");
        if (r.why != NULL) break;
        int f = field_index(payload + key_off, key_len);
        if (f < 0) { vs_mp_fail(&r, VS_EVALUE, "unknown field (a frame has only t, seq, src, poses)"); break; }
        field = FIELD_NAMES[f];
        if (seen[f]) { vs_mp_fail(&r, VS_EVALUE, "duplicate key"); break; }
        seen[f] = 1;
        if (f == FIELD_T) {
            t = vs_mp_expect_number(&r, VS_WIRE_MAX_ABS_T, "must be a number");
        } else if (f == FIELD_SEQ) {
            seq = vs_mp_expect_uint63(&r, "must be an integer");
        } else if (f == FIELD_SRC) {
            src_off = vs_mp_expect_str(&r, &src_len, "must be a non-empty string of <= 128 chars");
            if (r.why == NULL && !name_ok(payload + src_off, src_len, VS_WIRE_MAX_SRC))
                vs_mp_fail(&r, VS_EVALUE, "must match [A-Za-z0-9_-]+ (1 to 128 chars)");
            if (r.why == NULL && expect_src != NULL
                    && (src_len != expect_src_len || memcmp(payload + src_off, expect_src, src_len) != 0))
                vs_mp_fail(&r, VS_EVALUE, "is not the key's last chunk");
        } else {
            read_poses(&r, ids, poses, cap, &n, &row);
            if (r.why == NULL) row = -1;   /* a later error concerns no robot */
        }
    }
    if (r.why != NULL) return refuse(err, r.code, field, r.why, row, r.pos);
    if (r.pos != len) return refuse(err, VS_EVALUE, "payload", "trailing bytes after the map", -1, r.pos);
    for (int f = 0; f < N_FIELDS; f++)
        if (!seen[f]) return refuse(err, VS_EVALUE, FIELD_NAMES[f], "missing", -1, r.pos);
    frame->t = t;
    frame->seq = seq;
    frame->src.off = (uint32_t)src_off;
    frame->src.len = (uint32_t)src_len;
    frame->n = n;
    return VS_OK;
}
