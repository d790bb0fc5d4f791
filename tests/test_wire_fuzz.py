"""Property tests for every decoder: whatever the bytes, a decoder returns a valid message or
raises WireError; it never raises anything else, and what it returns re-encodes to itself."""

import math

import msgpack
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vsfleet.wire import (
    DECODERS,
    HealthMsg,
    MAX_ABS,
    WireError,
    decode_health,
    encode,
    encode_event,
    encode_health,
    encode_mission,
)

SETTINGS = settings(max_examples=75, deadline=None, suppress_health_check=[HealthCheck.too_slow])

# msgpack-able values, with the numbers a fuzzer would pick: NaN, inf, huge, negative zero
scalars = st.one_of(st.none(), st.booleans(), st.integers(min_value=-2**63, max_value=2**64 - 1),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=20),
                    st.binary(max_size=20),
                    st.sampled_from([float("nan"), float("inf"), -float("inf"), 1e308, -0.0, 2**63]))
values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=5), st.dictionaries(st.text(max_size=8), inner, max_size=5)), max_leaves=20)
FIELDS = ["t", "seq", "x", "y", "th", "src", "vl", "vr", "ttl", "gx", "gy", "gth", "cost", "err",
          "used", "rejected", "kind", "factor", "duration", "robot", "dev", "by", "version",
          "metric", "robots", "goal", "path", "twist", "speed_max", "turn_rate_max",
          "effective_t", "mission", "failed", "dropped", "since", "complete"]
maps = st.dictionaries(st.sampled_from(FIELDS), values, max_size=len(FIELDS))


def reencode(name, msg):
    if name == "mission":
        return encode_mission(msg)
    if name == "event":
        return encode_event(msg)
    if name == "health":
        return encode_health(msg)
    return encode(msg)


def check(payload: bytes) -> None:
    for name, decode in DECODERS.items():
        try:
            msg = decode(payload)
        except WireError:
            continue
        assert DECODERS[name](reencode(name, msg)) == msg
        for v in vars(msg).values():
            if isinstance(v, float):
                assert math.isfinite(v) or (name == "event" and v == math.inf)
                assert abs(v) <= 1e11 or v == math.inf


@SETTINGS
@given(st.binary(max_size=300))
def test_random_bytes_never_raise_anything_but_wire_error(payload):
    check(payload)


@SETTINGS
@given(maps)
def test_maps_with_wrong_types_nan_and_huge_numbers_never_raise_anything_but_wire_error(m):
    check(msgpack.packb(m, use_bin_type=True))


@SETTINGS
@given(maps, st.integers(min_value=0, max_value=200))
def test_truncated_msgpack_never_raises_anything_but_wire_error(m, cut):
    payload = msgpack.packb(m, use_bin_type=True)
    check(payload[:min(cut, max(0, len(payload) - 1))])


def test_health_round_trips_and_names_are_checked():
    h = HealthMsg(1.7e9, 3, 2, ("r2",), ("r2",), (("r1", 1.7e9 - 1.0),))
    assert decode_health(encode_health(h)) == h
    bad = msgpack.packb({"t": 1.0, "seq": 1, "mission": 1, "failed": ["a/b"], "dropped": [], "since": {}})
    try:
        decode_health(bad)
    except WireError as exc:
        assert "failed" in str(exc)
    else:
        raise AssertionError("a robot id with a slash was accepted")
    assert MAX_ABS == 1e6
