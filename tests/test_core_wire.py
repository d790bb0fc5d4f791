"""The core's frame decoder (vsfleet/_core/vs_wire.c, ``_core.decode_frame``) against the readable one
(``vsfleet.wire.decode_frame``): every payload one accepts the other accepts, with the same bits; every
payload one refuses the other refuses. Real frames as the trackers encode them, random valid frames in
every msgpack form a sender may choose, and hostile bytes: truncations at every byte, flips, wrong types
for each field, duplicate and extra keys, non-finite numbers, huge lengths, deep nesting, limits.

The reasons differ in wording; REASONS says which of the core's reasons stands for which of the
reference's (checked on payloads with a single fault, where both must name the same one).
"""

from __future__ import annotations

import random
import re
import struct
from dataclasses import dataclass

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vsfleet import _core
from vsfleet.wire import (MAX_FRAME_BYTES, MAX_ROBOTS, FrameMsg, WireError, decode_frame, decode_frame_core,
                          encode_frame)

# the core's reason (the end of its message) -> the reference's message for the same fault
REASONS = {
    "payload over 65536 bytes": r"exceeds the 65536-byte limit",
    "not valid msgpack: truncated": r"^not valid msgpack",
    "not valid msgpack: the unused byte 0xc1": r"^not valid msgpack",
    "trailing bytes after the map": r"^not valid msgpack: ExtraData",
    "payload is not a msgpack map": r"payload must be a msgpack map",
    # an int or nil key: msgpack's strict_map_key; a bin key: not one of the names
    "unknown field (a key that is not a string)": r"^not valid msgpack: ValueError|^unknown field",
    "unknown field (a frame has only t, seq, src, poses)": r"^unknown field|^not valid msgpack: UnicodeDecodeError",
    "duplicate key": r"^duplicate key",
    "missing": r"^missing field|field 'poses' must be a map",
    "must be a number": r"must be a number",
    "not finite": r"must be finite|not finite or beyond",
    "out of range": r"out of range|not finite or beyond",
    "out of range (0 <= seq < 2^63)": r"field 'seq' out of range",
    "must be an integer": r"field 'seq' must be an integer",
    "must be a non-empty string of <= 128 chars": r"field 'src' must be a non-empty string",
    "must match [A-Za-z0-9_-]+ (1 to 128 chars)": r"field 'src' must be a non-empty string|src must match"
                                                  r"|^not valid msgpack: UnicodeDecodeError",
    "is not the key's last chunk": r"is not the key's last chunk",
    "must be a map {robot: [x, y, th]}": r"field 'poses' must be a map",
    "more than 1000 robots": r"more than 1000",
    "a robot id that is not a string": r"robot id must match|^not valid msgpack: ValueError",
    # "invalid poses": the reference's own wording, should its slow path find no culprit
    "robot id must match [A-Za-z0-9_-]+": r"robot id must match|^invalid poses$|^not valid msgpack: UnicodeDecodeError",
    "robot listed twice (a duplicate key)": r"^duplicate key",
    "pose must be [x, y, th]": r"must be \[x, y, th\]",
    "pose must hold numbers": r"must hold numbers",
}


# ---------------------------------------------------------------- both decoders, side by side


def bits(x: float) -> bytes:
    return struct.pack("<d", x)


def reference(payload, src: str | None = None):
    """('ok', values) or ('refused', reason) from vsfleet.wire.decode_frame (and the agent's key check)."""
    try:
        m = decode_frame(payload)
    except WireError as exc:
        return "refused", str(exc)
    if src is not None and m.src != src:
        return "refused", f"src {m.src!r} is not the key's last chunk"
    flat = [v for p in m.poses.values() for v in p]
    return "ok", (bits(m.t), m.seq, m.src, tuple(m.poses), b"".join(map(bits, flat)))


def core(payload, src: str | None = None):
    """The same from _core.decode_frame; the reason is the core's own (a key of REASONS)."""
    try:
        t, seq, s, ids, xyth = _core.decode_frame(payload, src)
    except WireError as exc:
        return "refused", str(exc)
    flat = memoryview(xyth).cast("d").tolist()
    return "ok", (bits(t), seq, s, ids, b"".join(map(bits, flat)))


def core_reason(message: str) -> str:
    found = [r for r in REASONS if r in message]
    assert found, f"the core refused with a reason REASONS does not know: {message!r}"
    return max(found, key=len)


def agree(payload, src: str | None = None) -> str:
    """Assert both decoders give the same verdict (and, accepted, the same bits); return it."""
    ref, got = reference(payload, src), core(payload, src)
    assert ref[0] == got[0], f"{bytes(payload)[:80]!r}...: reference {ref}, core {got}"
    if ref[0] == "ok":
        assert ref[1] == got[1]
    else:
        core_reason(got[1])
    return ref[0]


def same_reason(payload, src: str | None = None) -> None:
    """A payload with one fault: both refuse, and the core's reason maps to the reference's."""
    (rv, rmsg), (cv, cmsg) = reference(payload, src), core(payload, src)
    assert rv == cv == "refused", (rmsg, cmsg)
    assert re.search(REASONS[core_reason(cmsg)], rmsg), f"core {cmsg!r} vs reference {rmsg!r}"


# ---------------------------------------------------------------- a packer that chooses the msgpack forms


@dataclass(frozen=True)
class F32:
    x: float


@dataclass(frozen=True)
class Bin:
    data: bytes


@dataclass(frozen=True)
class Ext:
    code: int
    data: bytes


@dataclass(frozen=True)
class Raw:
    data: bytes


@dataclass(frozen=True)
class Pairs:
    """A map in this order, keys possibly repeated."""
    items: tuple


def _int_forms(v: int) -> list[bytes]:
    forms = []
    if 0 <= v < 128:
        forms.append(bytes([v]))
    if -32 <= v < 0:
        forms.append(struct.pack(">b", v))
    for code, fmt, lo, hi in ((0xcc, ">B", 0, 2**8), (0xcd, ">H", 0, 2**16), (0xce, ">I", 0, 2**32),
                              (0xcf, ">Q", 0, 2**64), (0xd0, ">b", -2**7, 2**7), (0xd1, ">h", -2**15, 2**15),
                              (0xd2, ">i", -2**31, 2**31), (0xd3, ">q", -2**63, 2**63)):
        if lo <= v < hi:
            forms.append(bytes([code]) + struct.pack(fmt, v))
    return forms


def _head(n: int, fix: int | None, fix_max: int, codes: tuple, widths=(1, 2, 4)) -> list[bytes]:
    forms = [bytes([fix | n])] if fix is not None and n <= fix_max else []
    for code, w in zip(codes, widths):
        if n < 2 ** (8 * w):
            forms.append(bytes([code]) + n.to_bytes(w, "big"))
    return forms


def pack(v, rng: random.Random | None = None) -> bytes:
    """msgpack of v; with rng, each header in a random one of the forms a sender may use (fixstr or
    str8/16/32, fixint or any wider int, ...); without, the shortest (msgpack-python's choice)."""
    pick = (lambda forms: forms[0]) if rng is None else rng.choice
    if isinstance(v, Raw):
        return v.data
    if v is None:
        return b"\xc0"
    if v is True or v is False:
        return b"\xc3" if v else b"\xc2"
    if isinstance(v, int):
        return pick(_int_forms(v))
    if isinstance(v, F32):
        return b"\xca" + struct.pack(">f", v.x)
    if isinstance(v, float):
        return b"\xcb" + struct.pack(">d", v)
    if isinstance(v, str):
        data = v.encode("utf-8", "surrogatepass")
        return pick(_head(len(data), 0xa0, 31, (0xd9, 0xda, 0xdb))) + data
    if isinstance(v, Bin):
        return pick(_head(len(v.data), None, 0, (0xc4, 0xc5, 0xc6))) + v.data
    if isinstance(v, Ext):
        fixed = {1: 0xd4, 2: 0xd5, 4: 0xd6, 8: 0xd7, 16: 0xd8}
        forms = [bytes([fixed[len(v.data)]])] if len(v.data) in fixed else []
        forms += _head(len(v.data), None, 0, (0xc7, 0xc8, 0xc9))
        return pick(forms) + struct.pack(">b", v.code) + v.data
    if isinstance(v, (list, tuple)):
        return pick(_head(len(v), 0x90, 15, (0xdc, 0xdd), (2, 4))) + b"".join(pack(x, rng) for x in v)
    if isinstance(v, dict):
        v = Pairs(tuple(v.items()))
    if isinstance(v, Pairs):
        return (pick(_head(len(v.items), 0x80, 15, (0xde, 0xdf), (2, 4)))
                + b"".join(pack(k, rng) + pack(x, rng) for k, x in v.items))
    raise TypeError(type(v))


DEFAULT = object()


def frame(t=1.5, seq=7, src="cam1", poses=DEFAULT, **extra) -> dict:
    """A frame as a dict in the usual field order (poses: {id: [x, y, th]})."""
    out = {"t": t, "seq": seq, "src": src,
           "poses": {"r1": [0.5, -0.25, 0.125], "r2": [1.0, 2.0, -3.0]} if poses is DEFAULT else poses}
    out.update(extra)
    return out


def without(d: dict, key: str) -> dict:
    return {k: v for k, v in d.items() if k != key}


def with_field(name: str, value) -> dict:
    return frame(**{name: value})


# ---------------------------------------------------------------- (a) frames as the trackers encode them


def tracker_frame(n: int, seed: int = 0, t: float = 12.34, seq: int = 99, src: str = "sim") -> FrameMsg:
    rng = random.Random(seed)
    poses = {f"r{i}": (rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-3.2, 3.2)) for i in range(1, n + 1)}
    return FrameMsg(t=t, seq=seq, src=src, poses=poses)


@pytest.mark.parametrize("n", [0, 1, 3, 30, 100, 1000])
def test_a_frame_as_the_tracker_encodes_it_decodes_to_the_same_bits(n):
    msg = tracker_frame(n, seed=n)
    payload = encode_frame(msg)
    assert agree(payload) == "ok"
    t, seq, src, ids, xyth = _core.decode_frame(payload)
    assert (t, seq, src, ids) == (msg.t, msg.seq, msg.src, tuple(msg.poses))
    assert memoryview(xyth).cast("d").tolist() == [v for p in msg.poses.values() for v in p]


@pytest.mark.parametrize("n", [0, 1, 3, 100, 1000])
def test_decode_frame_core_gives_the_references_message_bit_for_bit(n):
    """vsfleet.wire.decode_frame_core (the agent's decoder): the FrameMsg decode_frame gives, poses in the order sent;
    WireError when src is not the key's."""
    payload = encode_frame(tracker_frame(n, seed=n))
    ref, got = decode_frame(payload), decode_frame_core(payload, "sim")
    assert got == ref and list(got.poses) == list(ref.poses) and decode_frame_core(payload) == ref
    assert [bits(v) for p in got.poses.values() for v in (got.t, *p)] == \
        [bits(v) for p in ref.poses.values() for v in (ref.t, *p)]
    with pytest.raises(WireError, match="key's last chunk"):
        decode_frame_core(payload, "sim2")


def test_the_payload_may_be_bytes_bytearray_or_a_memoryview_and_nothing_else():
    payload = encode_frame(tracker_frame(3))
    for p in (payload, bytearray(payload), memoryview(payload)):
        assert agree(p) == "ok"
    for p in (payload.decode("latin-1"), None, 7, [1, 2]):
        with pytest.raises(WireError):
            decode_frame(p)
        with pytest.raises(WireError, match="payload must be bytes"):
            _core.decode_frame(p)


def test_src_must_be_the_keys_last_chunk_when_the_key_is_given():
    payload = encode_frame(tracker_frame(3, src="cam2"))
    assert agree(payload, "cam2") == "ok"
    for other in ("cam1", "cam", "cam22", ""):
        same_reason(payload, other)


def test_frames_of_the_simulated_tracker_and_of_a_replay_decode_alike():
    """Noisy frames, a robot missing, negative zero, whole-number poses as the tracker's floats."""
    rng = random.Random(3)
    for k in range(200):
        poses = {f"r{i}": (round(rng.gauss(0, 1), rng.randint(0, 17)), -0.0 if k % 7 == 0 else rng.gauss(0, 1e-9),
                           float(rng.randint(-3, 3))) for i in range(1, 11) if rng.random() > 0.1}
        msg = FrameMsg(t=10.0 + k / 30.0, seq=k, src=rng.choice(["sim", "cam1", "mocap", "replay"]), poses=poses)
        assert agree(encode_frame(msg)) == "ok"


# ---------------------------------------------------------------- (b) random valid frames, every form

# from_regex(r"[A-Za-z0-9_-]{1,12}", fullmatch=True) draws a list of the class's characters and joins it, inside a
# group-cache composite and a fullmatch filter that a plain character class never needs: these are that list and
# join alone, the same choices and the same strings seed for seed (checked on 3000 seeds), 15 % cheaper to draw
WORD_CHAR = st.characters(categories=(), include_characters="ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz"
                                                             "0123456789_-")
NAME = st.lists(WORD_CHAR, min_size=1, max_size=12).map("".join)
SRC = st.lists(WORD_CHAR, min_size=1, max_size=128).map("".join)
COORD = st.one_of(st.floats(-1e6, 1e6, allow_nan=False), st.integers(-10**6, 10**6),
                  st.floats(-1e6, 1e6, width=32).map(F32), st.sampled_from([0.0, -0.0, 1e6, -1e6, 5e-324, -5e-324]))
TIME = st.one_of(st.floats(-1e11, 1e11, allow_nan=False), st.integers(-10**11, 10**11),
                 st.floats(-1e10, 1e10, width=32).map(F32))


@st.composite
def valid_frames(draw):
    ids = draw(st.lists(NAME, unique=True, max_size=40))
    poses = {r: [draw(COORD) for _ in range(3)] for r in ids}
    fields = [("t", draw(TIME)), ("seq", draw(st.integers(0, 2**63 - 1))), ("src", draw(SRC)), ("poses", poses)]
    draw(st.randoms(use_true_random=False)).shuffle(fields)
    return dict(fields), draw(st.integers(0, 2**32))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(valid_frames())
def test_a_random_valid_frame_in_any_msgpack_form_decodes_to_the_same_bits(case):
    obj, seed = case
    for rng in (None, random.Random(seed)):
        assert agree(pack(obj, rng)) == "ok"


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(valid_frames(), st.lists(st.tuples(st.integers(0, 2**16), st.integers(0, 255)), min_size=1, max_size=4))
def test_a_random_frame_with_bytes_overwritten_gets_the_same_verdict(case, edits):
    obj, seed = case
    payload = bytearray(pack(obj, random.Random(seed)))
    for at, value in edits:
        payload[at % len(payload)] = value
    agree(bytes(payload))


# ---------------------------------------------------------------- (c) hostile bytes

SEEDS = [encode_frame(tracker_frame(3, seed=1)), encode_frame(tracker_frame(0)),
         pack(frame(t=F32(2.5), seq=2**40, poses={"a": [1, -2, F32(0.5)], "b-c_9": [0, 0, 0]}), random.Random(5)),
         pack(frame(src="x" * 128, poses={"A" * 300: [0, 0, 0]}))]


@pytest.mark.parametrize("k", range(len(SEEDS)))
def test_every_truncation_of_a_valid_frame_is_refused_by_both(k):
    payload = SEEDS[k]
    assert agree(payload) == "ok"
    for end in range(len(payload)):
        assert agree(payload[:end]) == "refused"


@pytest.mark.parametrize("k", range(len(SEEDS)))
def test_random_byte_flips_inserts_and_deletions_get_the_same_verdict(k):
    rng = random.Random(k)
    seed = SEEDS[k]
    verdicts = {"ok": 0, "refused": 0}
    for _ in range(1500):
        p = bytearray(seed)
        for _ in range(rng.randint(1, 3)):
            op, at = rng.random(), rng.randrange(len(p) + 1)
            if op < 0.5 and at < len(p):
                p[at] ^= 1 << rng.randrange(8)
            elif op < 0.7 and at < len(p):
                p[at] = rng.choice([0xc0, 0xc1, 0xc2, 0xc3, 0xca, 0xcb, 0xd9, 0xdb, 0xdc, 0xdd, 0xde, 0xdf, 0xff,
                                    0x00, 0x7f, 0x80, 0x93, 0xa0, rng.randrange(256)])
            elif op < 0.85:
                p[at:at] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 4)))
            else:
                del p[at:at + rng.randint(1, 3)]
        verdicts[agree(bytes(p))] += 1
    assert verdicts["refused"] > 0 and verdicts["ok"] > 0, verdicts  # both verdicts seen


def test_random_bytes_get_the_same_verdict():
    rng = random.Random(11)
    for _ in range(3000):
        agree(bytes(rng.randrange(256) for _ in range(rng.randint(0, 40))))
        agree(b"\x84" + bytes(rng.randrange(256) for _ in range(rng.randint(0, 40))))


WRONG = {"nil": None, "true": True, "false": False, "int": 3, "negative int": -3, "float": 1.5,
         "float32": F32(1.5), "str": "x", "empty str": "", "bin": Bin(b"x"), "empty array": [],
         "array": [1.0, 2.0, 3.0], "empty map": {}, "map": {"a": 1}, "ext": Ext(5, b"abcd"),
         "timestamp": Ext(-1, b"\x00\x00\x00\x01"), "uint64 max": 2**64 - 1, "int64 min": -2**63,
         "nan": float("nan"), "inf": float("inf"), "-inf": float("-inf"), "float32 nan": F32(float("nan")),
         "float32 inf": F32(float("inf")), "1e300": 1e300}


@pytest.mark.parametrize("kind", list(WRONG))
@pytest.mark.parametrize("where", ["t", "seq", "src", "poses", "pose", "x", "y", "th", "id"])
def test_each_kind_of_value_in_each_place_gets_the_same_verdict_and_reason(where, kind):
    value = WRONG[kind]
    if where in ("t", "seq", "src", "poses"):
        obj = with_field(where, value)
    elif where == "pose":
        obj = frame(poses={"r1": [0.0, 0.0, 0.0], "r2": value})
    elif where == "id":  # as the second robot's id (Pairs: a map or a list may be a key on the wire)
        obj = frame(poses=Pairs((("r1", [0.0, 0.0, 0.0]), (value, [1.0, 1.0, 1.0]))))
    else:
        pose = [0.5, 0.5, 0.5]
        pose[{"x": 0, "y": 1, "th": 2}[where]] = value
        obj = frame(poses={"r1": pose})
    payload = pack(obj)
    if agree(payload) == "refused":
        same_reason(payload)


def test_numbers_at_and_beyond_every_limit_get_the_same_verdict():
    cases = []
    for t in (1e11, -1e11, 10**11, -10**11, 10**11 + 1, 1e11 * (1 + 2**-52), 2**53, 2**53 + 1, -2**53 - 1, F32(1e11),
              -0.0, 0, 5e-324):
        cases.append(with_field("t", t))
    for seq in (0, 2**63 - 1, 2**63, 2**64 - 1, -1, -2**63, 1.0, F32(0.0)):
        cases.append(with_field("seq", seq))
    for v in (1e6, -1e6, 10**6, -10**6, 10**6 + 1, -10**6 - 1, 1e6 * (1 + 2**-52), F32(1e6), F32(1000000.0625),
              2**53, 2**53 + 1, 2**63, -2**63, 2**64 - 1, -0.0, 5e-324, F32(1e-45)):
        for pose in ([v, 0, 0], [0, v, 0], [0, 0, v]):
            cases.append(frame(poses={"r1": pose}))
    for obj in cases:
        for rng in (None, random.Random(len(repr(obj)))):
            p = pack(obj, rng)
            if agree(p) == "refused":
                same_reason(p)


def test_duplicate_keys_are_refused_by_both_at_every_level():
    base = list(frame().items())
    for k in range(4):
        same_reason(pack(Pairs(tuple(base + [base[k]]))))
        same_reason(pack(Pairs(tuple(base[:k + 1] + [base[k]] + base[k + 1:]))))
    pose = [0.0, 0.0, 0.0]
    for ids in (["a", "a"], ["a", "b", "a"], ["r1", "r2", "r3", "r2"], [f"r{i}" for i in range(999)] + ["r500"]):
        same_reason(pack(frame(poses=Pairs(tuple((r, pose) for r in ids)))))
    # the same id in two encodings (fixstr and str8) is still the same id
    same_reason(pack(frame(poses=Pairs((("a", pose), (Raw(b"\xd9\x01a"), pose))))))
    # a str key and a bin key of the same bytes are different keys: the bin one is refused for its type
    same_reason(pack(frame(poses=Pairs((("a", pose), (Bin(b"a"), pose))))))


def test_extra_missing_and_misnamed_fields_are_refused_by_both():
    for extra in ({"v": 1}, {"x": 0.0}, {"T": 1.0}, {"pose": {}}, {"": 0}):
        same_reason(pack(frame(**extra)))
    for name in ("t", "seq", "src", "poses"):
        same_reason(pack(without(frame(), name)))
    for key in (1, None, Bin(b"t"), "t\x00", "seq ", "\u00e9"):
        same_reason(pack(Pairs(tuple(list(without(frame(), "t").items()) + [(key, 1.0)]))))
    same_reason(pack({}))


def test_src_and_robot_ids_are_key_chunks_for_both():
    """src and every robot id must be [A-Za-z0-9_-]+ and nothing else: "cam1\\n" (which re.match's $ once let
    through) and an id "a\\x00b" (which once passed as two ids, the ids being checked joined by NUL) are refused
    by both decoders."""
    for src in ("a", "A-z_9", "x" * 128):
        assert agree(pack(with_field("src", src))) == "ok"
    for src in ("", "x" * 129, "x" * 128 + "\n", "\n", "cam1\n", "x" * 127 + "\n", "cam1\n\n", "\ncam1", "cam 1",
                "cam1\r", "cam\x001", "cam1\x00", "cam/1", "caméra", "\u00e9" * 64, "*"):
        same_reason(pack(with_field("src", src)))
    pose = [0.0, 0.0, 0.0]
    for rid in ("a", "A" * 5000, "-_"):
        assert agree(pack(frame(poses={rid: pose}))) == "ok"
        assert agree(pack(frame(poses={"z": pose, rid: pose}))) == "ok"
    for rid in ("", "\x00", "\x00a", "a\x00", "a\x00b", "a\x00b\x00c", "a\x00\x00b", "a\n", "a b", "é", "a/b", "*",
                "a\x01b"):
        same_reason(pack(frame(poses={rid: pose})))
        same_reason(pack(frame(poses={"z": pose, rid: pose})))
        same_reason(pack(frame(poses={rid: pose, "z": pose})))
    # an id with a NUL is refused even where the join of all ids would look like valid ids
    same_reason(pack(frame(poses={"a\x00b": pose, "a": pose, "b": pose})))
    same_reason(pack(frame(poses={"a": pose, "b\x00c": pose})))


def test_a_src_ending_in_a_newline_or_an_id_holding_a_nul_is_refused_with_the_keys_src_too():
    """The agent's path: the key's last chunk given as src. A frame whose src is "cam1\\n" is refused even
    when the key ends in that newline, and an id "a\\x00b" whatever the key."""
    pose = [0.0, 0.0, 0.0]
    assert agree(pack(with_field("src", "cam1\n")), "cam1\n") == "refused"
    assert agree(pack(frame(src="cam1", poses={"a\x00b": pose})), "cam1") == "refused"
    assert agree(pack(frame(src="cam1", poses={"a": pose})), "cam1") == "ok"
    # invalid UTF-8 in a src or an id
    same_reason(pack(with_field("src", Raw(b"\xa2\xff\xfe"))))
    same_reason(pack(frame(poses=Pairs(((Raw(b"\xa2\xc3\x28"), pose),)))))


def test_poses_of_other_shapes_are_refused_by_both():
    for pose in ([], [0.0], [0.0, 0.0], [0.0] * 4, [[0.0, 0.0, 0.0]], {"x": 0, "y": 0, "th": 0},
                 [0.0, 0.0, [0.0]], [0.0, 0.0, None], [0.0, True, 0.0], Raw(b"\xdc\x00\x03")):
        same_reason(pack(frame(poses={"r1": pose})))
    for poses in ([], [["r1", [0, 0, 0]]], "r1", 0, None):
        same_reason(pack(with_field("poses", poses)))


# headers whose length or count the rest of the payload cannot hold: both say the payload is cut short
HUGE = [b"\xdb\xff\xff\xff\xff", b"\xda\xff\xff", b"\xd9\xff", b"\xc6\xff\xff\xff\xff", b"\xc9\xff\xff\xff\xff\x01",
        b"\xdd\xff\xff\xff\xff", b"\xdc\xff\xff", b"\xdf\xff\xff\xff\xff", b"\xde\xff\xff", b"\xdd\x80\x00\x00\x00",
        b"\xdf\x00\x00\x03\xe9"]


@pytest.mark.parametrize("head", HUGE, ids=lambda h: h.hex())
def test_huge_lengths_and_counts_are_refused_by_both_without_reading_past_the_end(head):
    agree(head)
    agree(head + b"\x00" * 8)
    agree(head + pack(frame()))
    for where in ("t", "seq", "src", "poses"):
        same_reason(pack(with_field(where, Raw(head))))
    same_reason(pack(frame(poses={"r1": Raw(head)})))
    same_reason(pack(frame(poses={"r1": [0.0, Raw(head), 0.0]})))
    same_reason(pack(Pairs(tuple(list(frame().items()) + [(Raw(head), 0)]))))


@pytest.mark.parametrize("head", [b"\x9f", b"\x8f", b"\xbf", b"\xc7\x05\x01", b"\xd8\x00"], ids=lambda h: h.hex())
def test_headers_that_swallow_the_fields_after_them_are_refused_by_both(head):
    """A fixarray of 15 as t swallows seq, src and poses: the core refuses the array (t is no number),
    the reference on what follows; the verdict is the same."""
    for where in ("t", "seq", "src", "poses"):
        assert agree(pack(with_field(where, Raw(head)))) == "refused"
    assert agree(pack(frame(poses={"r1": [0.0, Raw(head), 0.0], "r2": [0.0, 0.0, 0.0]}))) == "refused"


@pytest.mark.parametrize("depth", [1, 2, 10, 100, 1000, 30000])
def test_deep_nesting_is_refused_by_both(depth):
    nest = b"\x91" * depth + b"\x00"
    agree(nest)
    agree(b"\x81" * depth + b"\xc0")
    for where in ("t", "seq", "src", "poses"):
        assert agree(pack(with_field(where, Raw(nest)))) == "refused"
    assert agree(pack(frame(poses={"r1": Raw(nest)}))) == "refused"
    assert agree(pack(frame(poses={"r1": [0.0, 0.0, Raw(nest)]}))) == "refused"
    assert agree(pack(frame(poses={"r1": Raw(b"\x93" + nest + b"\x00\x00")}))) == "refused"


def test_float32_and_float64_and_integers_decode_to_the_same_bits():
    for v in (0.1, 1 / 3, -2.5, 1e-40, 123456.789, 999999.9999999999):
        f32 = struct.unpack(">f", struct.pack(">f", v))[0]
        for obj in (frame(t=F32(v), poses={"r": [F32(v), v, F32(-v)]}), frame(t=v, poses={"r": [f32, F32(f32), 7]})):
            payload = pack(obj)
            assert agree(payload) == "ok"
        t, _, _, _, xyth = _core.decode_frame(pack(frame(t=F32(v), poses={"r": [F32(v), v, 7]})))
        assert bits(t) == bits(f32) and memoryview(xyth).cast("d").tolist() == [f32, v, 7.0]


def test_the_robot_and_byte_limits_are_the_references():
    pose = [0.0, 0.0, 0.0]
    assert agree(pack(frame(poses={f"r{i}": pose for i in range(MAX_ROBOTS)}))) == "ok"
    same_reason(pack(frame(poses={f"r{i}": pose for i in range(MAX_ROBOTS + 1)})))
    # a payload of exactly MAX_FRAME_BYTES bytes (one long robot id, a str16), then one more
    short = len(pack(frame(poses={"r": pose})))   # "r": a fixstr, 1 header byte; a long id has 3
    exact = pack(frame(poses={"r" * (MAX_FRAME_BYTES - short - 1): pose}))
    assert len(exact) == MAX_FRAME_BYTES and agree(exact) == "ok"
    same_reason(pack(frame(poses={"r" * (MAX_FRAME_BYTES - short): pose})))
    same_reason(exact + b"\x00")


def test_trailing_bytes_and_a_payload_that_is_not_a_map_are_refused_by_both():
    good = pack(frame())
    for tail in (b"\x00", b"\xc0", good, b"\xc1"):
        same_reason(good + tail)
    for top in ([1, 2], "frame", 3, None, Bin(b"x"), Ext(1, b"x")):
        same_reason(pack(top))
    for bad in (b"", b"\xc1", b"\x84\xc1"):
        same_reason(bad)


# ---------------------------------------------------------------- the reasons

POSE = [0.0, 0.0, 0.0]
EXAMPLES = {  # one payload per reason of the core, with that one fault
    "payload over 65536 bytes": pack(frame(poses={"r" * 70000: POSE})),
    "not valid msgpack: truncated": pack(frame())[:-1],
    "not valid msgpack: the unused byte 0xc1": pack(with_field("t", Raw(b"\xc1"))),
    "trailing bytes after the map": pack(frame()) + b"\x00",
    "payload is not a msgpack map": pack([1.0]),
    "unknown field (a key that is not a string)": pack(Pairs(tuple(frame().items()) + ((1, 0),))),
    "unknown field (a frame has only t, seq, src, poses)": pack(frame(v=1)),
    "duplicate key": pack(Pairs(tuple(frame().items()) + (("seq", 8),))),
    "missing": pack(without(frame(), "seq")),
    "must be a number": pack(with_field("t", "1.5")),
    "not finite": pack(with_field("t", float("nan"))),
    "out of range": pack(with_field("t", 1e12)),
    "out of range (0 <= seq < 2^63)": pack(with_field("seq", -1)),
    "must be an integer": pack(with_field("seq", 7.0)),
    "must be a non-empty string of <= 128 chars": pack(with_field("src", Bin(b"cam1"))),
    "must match [A-Za-z0-9_-]+ (1 to 128 chars)": pack(with_field("src", "cam 1")),
    "is not the key's last chunk": pack(frame()),  # with src "cam2", below
    "must be a map {robot: [x, y, th]}": pack(with_field("poses", [])),
    "more than 1000 robots": pack(frame(poses={f"r{i}": POSE for i in range(1001)})),
    "a robot id that is not a string": pack(frame(poses=Pairs(((1, POSE),)))),
    "robot id must match [A-Za-z0-9_-]+": pack(frame(poses={"r 1": POSE})),
    "robot listed twice (a duplicate key)": pack(frame(poses=Pairs((("r1", POSE), ("r1", POSE))))),
    "pose must be [x, y, th]": pack(frame(poses={"r1": [0.0, 0.0]})),
    "pose must hold numbers": pack(frame(poses={"r1": [0.0, "0", 0.0]})),
}


@pytest.mark.parametrize("reason", list(REASONS))
def test_each_reason_of_the_core_maps_to_the_references(reason):
    src = "cam2" if reason == "is not the key's last chunk" else None
    payload = EXAMPLES[reason]
    _, message = core(payload, src)
    assert core_reason(message) == reason, message
    same_reason(payload, src)


def test_REASONS_lists_every_reason_the_core_can_give():
    """Every refusal text in vs_wire.c (comments aside) is a key of REASONS, and the other way round;
    "more robots than the caller's buffers hold" (VS_ENOMEM) needs a cap below 1000: C callers only."""
    from pathlib import Path
    text = (Path(__file__).resolve().parent.parent / "vsfleet" / "_core" / "vs_wire.c").read_text()
    code = re.sub(r"/\*.*?\*/|^#include[^\n]*", "", text, flags=re.S | re.M)
    written = set(re.findall(r'"((?:[^"\\]|\\.)*)"', code))
    written -= {"t", "seq", "src", "poses", "payload", "more robots than the caller's buffers hold"}
    assert written == set(REASONS)
