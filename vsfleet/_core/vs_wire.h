/* vs_wire.h - a small msgpack reader of our own, and the tracker frame's decoder on it.
 *
 * The frame (docs/protocol.md, "Frames"; vsfleet.wire.decode_frame is the readable reference and
 * this code accepts exactly what it accepts, with the same bits) is the msgpack map
 *     {t, seq, src, poses: {robot: [x, y, th]}}
 * t [s] observation time on the tracker's clock; seq the source's frame number; src the tracker's
 * id (the key's last chunk); poses every robot the source saw, (x, y, th) [m, m, rad; world frame,
 * the tracker's floor], in the order sent.  docs/decoder.md says why we read msgpack ourselves,
 * which subset is read and what is refused.
 *
 * Nothing is allocated and nothing is global: the reader reads the caller's bytes, the decoder
 * writes into the caller's fixed-size buffers, and strings (src, robot ids) are returned as slices
 * (offset, length) of the payload, never copied.  A refusal comes with one short reason (static
 * text), the field it concerns, and the robot row if any.
 */
#ifndef VS_WIRE_H
#define VS_WIRE_H

#include <stddef.h>
#include <stdint.h>

#include "vscore.h"

/* the frame contract's limits, as vsfleet.wire names them */
#define VS_WIRE_MAX_FRAME_BYTES 65536u  /* MAX_FRAME_BYTES: a longer payload is refused unread */
#define VS_WIRE_MAX_ROBOTS 1000u        /* MAX_ROBOTS: more robots in one frame are refused */
#define VS_WIRE_MAX_ABS 1e6             /* MAX_ABS: |x|, |y|, |th| <= this [m, rad] */
#define VS_WIRE_MAX_ABS_T 1e11          /* |t| <= this [s] */
#define VS_WIRE_MAX_SRC 128u            /* src: at most this many bytes */

/* ---------------------------------------------------------------- the reader
 * The subset of msgpack the frame contract uses: every header a conforming encoder may write
 * (fix/8/16/32-bit forms alike), read one item at a time.  The first error sticks (mpack's
 * "expect" style): every later call does nothing and returns an empty item, so a decoder is
 * straight-line code that checks r->why once. */

typedef enum {
    VS_MP_NIL, VS_MP_BOOL, VS_MP_UINT, VS_MP_NEGINT, VS_MP_FLOAT, VS_MP_STR, VS_MP_BIN,
    VS_MP_ARRAY, VS_MP_MAP, VS_MP_EXT
} vs_mp_kind;

typedef struct {
    vs_mp_kind kind;
    uint64_t u;        /* UINT: the value (any integer >= 0, whatever its format); BOOL: 0 or 1;
                          STR, BIN, EXT: the body's length [bytes]; ARRAY, MAP: the entry count */
    int64_t i;         /* NEGINT: the value (any integer < 0, whatever its format) */
    double d;          /* FLOAT: the value (a float32 widened to double, which is exact) */
    int is_f32;        /* FLOAT: 1 when sent as float32 */
    size_t off;        /* STR, BIN, EXT: offset of the body in the buffer */
} vs_mp_item;

typedef struct {
    const unsigned char *buf;
    size_t len, pos;   /* pos: the next byte to read */
    const char *why;   /* NULL until the first error, then its reason (static text) */
    int code;          /* VS_OK, then the first error's VS_E* code */
} vs_mp_reader;

void vs_mp_init(vs_mp_reader *r, const unsigned char *buf, size_t len);
/* Set the reader's error (the first one sticks); returns 0. */
int vs_mp_fail(vs_mp_reader *r, int code, const char *why);
/* One item: a scalar whole, a str/bin/ext with its body skipped, an array or map by its header
 * only (its entries follow).  A length or count that the remaining bytes cannot hold (a str's
 * body, one byte per array entry, two per map entry) is refused as truncated before any read. */
int vs_mp_next(vs_mp_reader *r, vs_mp_item *it);
/* Typed reads: on a mismatch they set the error to why_type and return 0 / an empty slice. */
uint64_t vs_mp_expect_map(vs_mp_reader *r, const char *why_type);     /* the entry count */
uint64_t vs_mp_expect_array(vs_mp_reader *r, const char *why_type);   /* the entry count */
/* A str (not bin): its body's offset and length. */
size_t vs_mp_expect_str(vs_mp_reader *r, size_t *len, const char *why_type);
/* A number: any integer or a float32/64 (never a bool), as the reference's
 * `isinstance(v, (int, float)) and not isinstance(v, bool)`, converted exactly to double.
 * max_abs (< 2^53, so every integer it admits converts exactly): a non-finite value is refused
 * (VS_ENONFINITE, "not finite"), |v| > max_abs too (VS_EVALUE, "out of range"). */
double vs_mp_expect_number(vs_mp_reader *r, double max_abs, const char *why_type);
/* An integer in [0, 2^63) in any integer format (never a float or a bool). */
uint64_t vs_mp_expect_uint63(vs_mp_reader *r, const char *why_type);

/* ---------------------------------------------------------------- the frame */

typedef struct {
    uint32_t off, len;     /* bytes payload[off .. off + len) */
} vs_wire_slice;

typedef struct {
    double t;              /* [s] observation time, tracker clock; |t| <= VS_WIRE_MAX_ABS_T */
    uint64_t seq;          /* the source's frame number, in [0, 2^63) */
    vs_wire_slice src;     /* the tracker's id */
    size_t n;              /* robots listed: rows 0..n-1 of ids and poses, in the order sent */
} vs_frame;

typedef struct {
    const char *why;       /* a short reason (static text); NULL on VS_OK */
    const char *field;     /* what it concerns: "payload", "t", "seq", "src" or "poses" */
    long robot;            /* the row of the robot concerned (its id is ids[robot]), -1: none */
    size_t at;             /* the byte offset where reading stopped */
} vs_wire_error;

/* Decode and check one frame payload of len bytes, every field as vsfleet.wire.decode_frame does.
 *
 * expect_src: NULL, or the tracker id the key names (expect_src_len bytes): src must equal it (the
 * agent's check that src is the key's last chunk).  ids (cap) and poses (cap, 3) [m, m, rad; world]
 * are the caller's buffers, cap >= VS_WIRE_MAX_ROBOTS takes any valid frame; ids are slices of the
 * payload, which must outlive them.
 *
 * Returns VS_OK and writes *frame; or refuses: VS_EVALUE (not a valid frame), VS_ENONFINITE (a
 * NaN or infinite t or coordinate) or VS_ENOMEM (a valid-looking frame of more robots than cap),
 * with *err filled.  *frame is written on VS_OK only; ids and poses are filled as the payload is
 * read, so after a refusal their contents are unspecified.  Robot ids are told apart with a hash
 * table of at most 2048 slots on the stack: no allocation. */
int vs_wire_decode_frame(const unsigned char *payload, size_t len,
                         const unsigned char *expect_src, size_t expect_src_len,
                         vs_wire_slice *ids, double *poses, size_t cap,
                         vs_frame *frame, vs_wire_error *err);

#endif
