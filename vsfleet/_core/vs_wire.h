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
 *
 * The writer and the encoders of the agent's two per-frame messages, cmd and state (vs_wire_enc.c),
 * are at the end: they write the bytes vsfleet.wire.encode writes, byte for byte, into the caller's
 * buffer.
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


/* ---------------------------------------------------------------- the writer (vs_wire_enc.c)
 * msgpack as msgpack-python's packb(obj, use_bin_type=True) writes it, for the types our messages
 * hold: every integer in its smallest form (fixint, then uint/int 8, 16, 32, 64; a value >= 0 always
 * in an unsigned form), a float as float64 (big-endian, its bits as they are: -0.0, NaN payloads and
 * infinities too), a bool, a str with its smallest header (fixstr, str 8, 16, 32), arrays and maps
 * with theirs (fix, 16, 32).  Writes go into the caller's buffer, never past cap.  The first write
 * that does not fit sticks (as the reader's first error): every later write does nothing, and
 * vs_mp_end returns 0.  Nothing is allocated. */

typedef struct {
    unsigned char *buf;
    size_t cap, n;     /* n: the bytes written so far (n <= cap) */
    int full;          /* 0 until a write did not fit (or a length msgpack cannot hold), then 1 */
} vs_mp_writer;

void vs_mp_writer_init(vs_mp_writer *w, unsigned char *buf, size_t cap);
/* The bytes written, or 0 when a write did not fit (the buffer then holds a partial message). */
size_t vs_mp_end(const vs_mp_writer *w);
void vs_mp_put_map(vs_mp_writer *w, uint64_t count);       /* entries: count key-value pairs follow */
void vs_mp_put_array(vs_mp_writer *w, uint64_t count);     /* entries: count items follow */
/* A str of len bytes (UTF-8, not checked); a len above 2^32 - 1 does not fit, whatever cap is. */
void vs_mp_put_str(vs_mp_writer *w, const unsigned char *s, size_t len);
void vs_mp_put_uint(vs_mp_writer *w, uint64_t v);
void vs_mp_put_int(vs_mp_writer *w, int64_t v);            /* v >= 0 as vs_mp_put_uint */
void vs_mp_put_f64(vs_mp_writer *w, double v);
void vs_mp_put_bool(vs_mp_writer *w, int v);               /* nonzero: true */

/* ---------------------------------------------------------------- the agent's messages
 * The encoders are serialisers, as vsfleet.wire.encode is: they check no value against the contract
 * (a NaN is written as its bits; receivers refuse it).  Each returns the number of bytes written, or
 * 0 when cap is too small (the buffer's contents are then unspecified; nothing is written past cap).
 * The keys are written in the message dataclass's field order, every field always (the optional
 * ones too), as encode(msg) does. */

#define VS_WIRE_PROTOCOL_V 1       /* vsfleet.wire.PROTOCOL_V: the telemetry version written by default */

/* A command, vsfleet.wire.CmdMsg, the msgpack map {t, seq, vl, vr, ttl}:
 * t [s] the answered frame's observation time, tracker clock (or now, for a stop command); seq the
 * answered frame's number; vl, vr the left and right wheel ground speeds [m/s]; ttl [s] how long the
 * robot may keep them.  At most VS_WIRE_CMD_MAX_BYTES bytes (seq as uint 64). */
#define VS_WIRE_CMD_MAX_BYTES 62u
size_t vs_wire_encode_cmd(double t, uint64_t seq, double vl, double vr, double ttl, unsigned char *buf, size_t cap);

/* A byte string given by pointer and length: the caller's, read, never copied or kept. */
typedef struct {
    const unsigned char *s;   /* len bytes (may be NULL when len is 0) */
    size_t len;
} vs_wire_str;

/* A state, vsfleet.wire.StateMsg: the agent's view after frame seq. */
typedef struct {
    double t;                 /* [s] the answered frame's observation time, tracker clock */
    uint64_t seq;             /* the answered frame's number */
    double x, y, th;          /* the fitted structure pose [m, m, rad; world] */
    double gx, gy, gth;       /* the desired (advanced) structure pose [m, m, rad; world] */
    double cost;              /* [m] the fit's cost */
    double err;               /* [m] the own robot's distance to its fitted point */
    const vs_wire_str *used;  /* the robot ids in the fit (UTF-8; ASCII [A-Za-z0-9_-] by the contract),
                                 n_used of them, sent as an array in this order */
    size_t n_used;
    uint64_t rejected;        /* bad messages the agent counted so far */
    int complete;             /* 0: the frame ran on its deadline without every pose; else 1 (a bool) */
    int64_t mission;          /* the version of the mission used; -1: not sent (none) */
    int64_t shape;            /* the structure's shape: 0 the template, k >= 1 the mission's k-th reshape */
    int64_t v;                /* the protocol version followed: VS_WIRE_PROTOCOL_V */
} vs_wire_state;

/* At most this many bytes for a state of n_used ids of id_bytes bytes in all (every integer as
 * (u)int 64, every header in its widest form). */
#define VS_WIRE_STATE_FIXED_MAX_BYTES 206u
#define VS_WIRE_STATE_MAX_BYTES(n_used, id_bytes) (VS_WIRE_STATE_FIXED_MAX_BYTES + 5u * (n_used) + (id_bytes))

/* The msgpack map {t, seq, x, y, th, gx, gy, gth, cost, err, used, rejected, complete, mission,
 * shape, v} (16 keys: a map 16 header), as vsfleet.wire.encode(StateMsg(...)) writes it. */
size_t vs_wire_encode_state(const vs_wire_state *s, unsigned char *buf, size_t cap);

#endif
