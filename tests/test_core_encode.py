"""The core's encoders of the agent's two per-frame messages (vsfleet/_core/vs_wire_enc.c, ``_core.encode_cmd``
and ``_core.encode_state``) against the readable one (``vsfleet.wire.encode``): the same bytes, byte for byte, for
random messages and at every edge of msgpack's forms (integers at each width's boundary, -0.0, NaN payloads,
infinities, subnormals, str and array headers at each width's boundary, non-ASCII ids); a message within the
contract decodes back (``decode_cmd``, ``decode_state``) to the same values, bit for bit; an argument whose bytes
would differ from encode's, or that the C fields cannot hold, is refused with a TypeError or ValueError.
"""

from __future__ import annotations

import math
import struct
from dataclasses import fields

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from vsfleet import _core
from vsfleet.wire import MAX_TTL_S, PROTOCOL_V, CmdMsg, StateMsg, decode_cmd, decode_state, encode

# ---------------------------------------------------------------- values at every edge

UINT_EDGES = (0, 1, 127, 128, 255, 256, 65535, 65536, 2**32 - 1, 2**32, 2**63 - 1, 2**63, 2**64 - 1)
INT_EDGES = (*UINT_EDGES[:-2], -1, -32, -33, -128, -129, -32768, -32769, -2**31, -2**31 - 1, -2**63)


def from_bits(b: int) -> float:
    return struct.unpack("<d", struct.pack("<Q", b))[0]


FLOAT_EDGES = (0.0, -0.0, 1.0, -1.0, 0.1, 1e6, -1e6, 1e11, -1e11, 5e-324, -5e-324, 2.2250738585072014e-308,
               2.225073858507201e-308, 1.7976931348623157e308, -1.7976931348623157e308, 1e300, -1e-300,
               math.inf, -math.inf, math.nan, from_bits(0x7ff8000000000001), from_bits(0xfff0000000000001),
               from_bits(0x7ff4000000000000))
NAME_CHARS = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_-"

floats = st.one_of(st.floats(), st.sampled_from(FLOAT_EDGES),
                   st.integers(0, 2**64 - 1).map(from_bits))           # any bits: every NaN payload too
uints = st.one_of(st.integers(0, 2**64 - 1), st.sampled_from(UINT_EDGES), st.integers(0, 300))
ints = st.one_of(st.integers(-2**63, 2**63 - 1), st.sampled_from(INT_EDGES), st.integers(-300, 300))
ids = st.text(NAME_CHARS, min_size=1, max_size=128)
any_ids = st.one_of(ids, st.text(min_size=0, max_size=40).filter(lambda s: not any(0xd800 <= ord(c) < 0xe000 for c in s)))


def state_args(m: StateMsg) -> tuple:
    """StateMsg's fields in order: _core.encode_state's positional arguments."""
    return (m.t, m.seq, m.x, m.y, m.th, m.gx, m.gy, m.gth, m.cost, m.err, m.used, m.rejected, m.complete,
            m.mission, m.shape, m.v)


@st.composite
def states(draw, used=st.lists(any_ids, max_size=20)) -> StateMsg:
    return StateMsg(t=draw(floats), seq=draw(uints), x=draw(floats), y=draw(floats), th=draw(floats),
                    gx=draw(floats), gy=draw(floats), gth=draw(floats), cost=draw(floats), err=draw(floats),
                    used=tuple(draw(used)), rejected=draw(uints), complete=draw(st.booleans()),
                    mission=draw(ints), shape=draw(ints), v=draw(st.one_of(st.just(PROTOCOL_V), ints)))


def plain_state(used=("r1", "r2", "r3"), **changes) -> StateMsg:
    base = dict(t=12.5, seq=7, x=0.1, y=-0.2, th=0.3, gx=1.0, gy=2.0, gth=-3.0, cost=0.004, err=0.002, used=used,
                rejected=0, complete=True, mission=3, shape=0)
    base.update(changes)
    return StateMsg(**base)


# ---------------------------------------------------------------- the same bytes


@settings(max_examples=200, deadline=None)
@given(floats, uints, floats, floats, floats)
@example(0.0, 0, 0.0, 0.0, 0.0)
@example(-0.0, 2**64 - 1, -0.0, math.inf, math.nan)
def test_encode_cmd_writes_wire_encodes_bytes(t, seq, vl, vr, ttl):
    assert _core.encode_cmd(t, seq, vl, vr, ttl) == encode(CmdMsg(t=t, seq=seq, vl=vl, vr=vr, ttl=ttl))


@pytest.mark.parametrize("seq", UINT_EDGES)
def test_encode_cmd_writes_seq_in_msgpacks_smallest_form_at_every_width(seq):
    assert _core.encode_cmd(1.0, seq, 0.0, 0.0, 0.3) == encode(CmdMsg(t=1.0, seq=seq, vl=0.0, vr=0.0, ttl=0.3))


@pytest.mark.parametrize("v", FLOAT_EDGES)
def test_encode_cmd_writes_every_float_by_its_bits(v):
    got = _core.encode_cmd(v, 1, v, v, v)
    assert got == encode(CmdMsg(t=v, seq=1, vl=v, vr=v, ttl=v))
    assert got.count(b"\xcb" + struct.pack(">d", v)) >= 4


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(states())
def test_encode_state_writes_wire_encodes_bytes(msg):
    assert _core.encode_state(*state_args(msg)) == encode(msg)


@settings(max_examples=100, deadline=None)
@given(states(), uints)
def test_encode_state_writes_what_the_agent_sends_with_its_rejection_count(msg, rejected):
    """agent/main.py sends encode(out.state, rejected=count)."""
    args = list(state_args(msg))
    args[11] = rejected
    assert _core.encode_state(*args) == encode(msg, rejected=rejected)


@pytest.mark.parametrize("field,value", [(f, v) for f in ("seq", "rejected", "mission", "shape", "v")
                                         for v in INT_EDGES if v >= 0 or f not in ("seq", "rejected")])
def test_encode_state_writes_each_integer_in_msgpacks_smallest_form_at_every_width(field, value):
    """seq and rejected are counters, uint64 in the core (a negative one: ValueError, below)."""
    msg = plain_state(**{field: value})
    assert _core.encode_state(*state_args(msg)) == encode(msg)


@pytest.mark.parametrize("value", [2**63, 2**64 - 1])
@pytest.mark.parametrize("field", ["seq", "rejected"])
def test_encode_state_writes_counters_up_to_2_64(field, value):
    msg = plain_state(**{field: value})
    assert _core.encode_state(*state_args(msg)) == encode(msg)


@pytest.mark.parametrize("n", [0, 1, 15, 16, 100, 1000, 1001, 65535, 65536])
def test_encode_state_writes_the_used_array_header_for_every_count(n):
    """fixarray up to 15, array 16 from 16, array 32 from 65536; past 1000 ids the binding allocates."""
    used = tuple(f"r{i}" for i in range(n))
    msg = plain_state(used=used)
    got = _core.encode_state(*state_args(msg))
    assert got == encode(msg)
    assert _core.encode_state(*state_args(msg)[:10], list(used), *state_args(msg)[11:]) == got   # a list too


@pytest.mark.parametrize("length", [1, 2, 31, 32, 100, 128, 255, 256, 65535, 65536])
def test_encode_state_writes_every_id_length_with_msgpacks_str_header(length):
    """fixstr up to 31 bytes, str 8 up to 255, str 16 up to 65535, str 32 beyond (the contract's ids stop at
    128 bytes as key chunks, but encode writes any str, and so does the core)."""
    used = ("a" * length, "b" * (length // 2 + 1), "_-9Z" * (length // 4 + 1))
    msg = plain_state(used=used)
    assert _core.encode_state(*state_args(msg)) == encode(msg)


@pytest.mark.parametrize("used", [("é",), ("robot-α", "ロボ"), ("🤖" * 8,), ("é" * 16,), ("x" * 30 + "é",), ("",),
                                  ("a\x00b", "line\n")])
def test_encode_state_writes_non_ascii_and_odd_ids_as_encode_does(used):
    """The contract's ids are ASCII key chunks, but encode checks none: neither does the core. The str header
    counts UTF-8 bytes ("é" * 16 is 32 bytes: str 8)."""
    msg = plain_state(used=used)
    assert _core.encode_state(*state_args(msg)) == encode(msg)


def test_an_id_that_is_not_utf8_encodable_is_refused_by_both():
    msg = plain_state(used=("ok", "\ud800"))
    with pytest.raises(UnicodeEncodeError):
        encode(msg)
    with pytest.raises(UnicodeEncodeError):
        _core.encode_state(*state_args(msg))


def test_the_optional_fields_default_as_statemsgs_do():
    """12 arguments: complete True, mission -1, shape 0, v PROTOCOL_V (vs_wire.h VS_WIRE_PROTOCOL_V)."""
    msg = StateMsg(t=1.0, seq=2, x=0.0, y=0.0, th=0.0, gx=0.0, gy=0.0, gth=0.0, cost=0.0, err=0.0, used=("a",),
                   rejected=4)
    for k in range(12, 17):
        assert _core.encode_state(*state_args(msg)[:k]) == encode(msg)


def test_numpy_float64_values_are_written_as_floats_as_encode_writes_them():
    """vsfleet.step builds states from numpy scalars; numpy.float64 is a float."""
    msg = plain_state(x=np.float64(0.25), cost=np.float64(-0.0), err=np.float64(1e-300))
    assert _core.encode_state(*state_args(msg)) == encode(msg)
    assert _core.encode_cmd(np.float64(1.5), 3, np.float64(0.1), 0.2, 0.3) == encode(CmdMsg(1.5, 3, 0.1, 0.2, 0.3))


@pytest.mark.parametrize("reference", [False, True])
def test_the_agents_own_messages_as_agent_step_builds_them_encode_alike(reference):
    """The recorded paper-failure run (tests/golden_step.py), 60 frames of each agent, with the core's step and
    the reference's: every command, every state (with the agent's rejection count, as agent/main.py sends it)
    and the stop command take the binding's argument types and give encode's bytes."""
    from dataclasses import replace

    from golden_step import load

    from vsfleet.step import AgentState, agent_step, stop_command

    mission, frames, config, recorded = load()
    config = replace(config, reference=reference)
    states = 0
    for robot in sorted(recorded):
        agent = AgentState(robot)
        for frame, now in frames[:60]:
            agent, out = agent_step(agent, mission, frame, now, config)
            c = out.cmd
            assert _core.encode_cmd(c.t, c.seq, c.vl, c.vr, c.ttl) == encode(c)
            if out.state is not None:
                args = list(state_args(out.state))
                args[11] = 17
                assert _core.encode_state(*args) == encode(out.state, rejected=17)
                states += 1
        c = stop_command(agent, 99.5, config.ttl_s)
        assert _core.encode_cmd(c.t, c.seq, c.vl, c.vr, c.ttl) == encode(c)
    assert states >= 100


# ---------------------------------------------------------------- round trips within the contract

finite = st.floats(-1e6, 1e6, allow_nan=False)
times = st.floats(-1e11, 1e11, allow_nan=False)
seqs = st.one_of(st.integers(0, 2**63 - 1), st.sampled_from([u for u in UINT_EDGES if u < 2**63]))


@settings(max_examples=200, deadline=None)
@given(times, seqs, finite, finite, st.floats(0.0, MAX_TTL_S, exclude_min=True))
def test_a_command_within_the_contract_decodes_back_to_the_same_bits(t, seq, vl, vr, ttl):
    got = decode_cmd(_core.encode_cmd(t, seq, vl, vr, ttl))
    assert got == CmdMsg(t=t, seq=seq, vl=vl, vr=vr, ttl=ttl)
    assert [struct.pack("<d", v) for v in (got.t, got.vl, got.vr, got.ttl)] == \
           [struct.pack("<d", v) for v in (t, vl, vr, ttl)]   # -0.0 stays -0.0


@settings(max_examples=200, deadline=None)
@given(times, seqs, finite, finite, finite, finite, finite, finite, st.floats(0.0, 1e6), st.floats(0.0, 1e6),
       st.lists(ids, max_size=30, unique=True), seqs, st.booleans(),
       st.one_of(st.just(-1), seqs), seqs)
def test_a_state_within_the_contract_decodes_back_to_the_same_bits(t, seq, x, y, th, gx, gy, gth, cost, err, used,
                                                                   rejected, complete, mission, shape):
    msg = StateMsg(t=t, seq=seq, x=x, y=y, th=th, gx=gx, gy=gy, gth=gth, cost=cost, err=err, used=tuple(used),
                   rejected=rejected, complete=complete, mission=mission, shape=shape)
    got = decode_state(_core.encode_state(*state_args(msg)))
    assert got == msg
    assert encode(got) == encode(msg)   # the same bits: -0.0 too


# ---------------------------------------------------------------- arguments refused at the boundary

CMD = (1.0, 2, 0.1, 0.2, 0.3)
CMD_FIELDS = ("t", "seq", "vl", "vr", "ttl")
STATE = state_args(plain_state())
STATE_FIELDS = ("t", "seq", "x", "y", "th", "gx", "gy", "gth", "cost", "err", "used", "rejected", "complete",
                "mission", "shape", "v")


def test_the_arguments_are_the_dataclasses_fields_in_order():
    """The bindings take CmdMsg's and StateMsg's fields positionally: a field added or moved there fails here
    (and the keys the core writes are in this order: test_encode_*_writes_wire_encodes_bytes)."""
    assert tuple(f.name for f in fields(CmdMsg)) == CMD_FIELDS
    assert tuple(f.name for f in fields(StateMsg)) == STATE_FIELDS


FLOAT_ARGS = ("t", "x", "y", "th", "gx", "gy", "gth", "cost", "err")


def right_type(field: str, value) -> bool:
    """The argument types the binding takes: what msgpack-python packs the way the C field is written."""
    if field in ("seq", "rejected", "mission", "shape", "v"):
        return type(value) is int
    if field == "complete":
        return type(value) is bool
    if field == "used":
        return isinstance(value, (tuple, list))
    return isinstance(value, float)


BAD = [1, True, None, "1.0", np.float32(1.0), np.int64(1), np.bool_(True), 1.5, [1.0], {"a": 1}]


@pytest.mark.parametrize("k,bad", [(k, b) for k in range(5) for b in BAD if not right_type(CMD_FIELDS[k], b)])
def test_encode_cmd_refuses_a_type_whose_bytes_would_differ_from_encodes(k, bad):
    """An int for a float would be packed as an integer by encode, a bool as true: TypeError, never other bytes."""
    field = CMD_FIELDS[k]
    args = list(CMD)
    args[k] = bad
    with pytest.raises(TypeError, match=f"encode_cmd: {field} must be"):
        _core.encode_cmd(*args)


@pytest.mark.parametrize("k,bad", [(k, b) for k in range(16) for b in BAD if not right_type(STATE_FIELDS[k], b)])
def test_encode_state_refuses_a_type_whose_bytes_would_differ_from_encodes(k, bad):
    field = STATE_FIELDS[k]
    args = list(STATE)
    args[k] = bad
    with pytest.raises(TypeError, match=f"encode_state: {field} must be"):
        _core.encode_state(*args)


@pytest.mark.parametrize("field", FLOAT_ARGS)
def test_an_int_for_a_float_is_refused_because_encode_would_write_an_integer(field):
    msg = plain_state(**{field: 3})
    assert type(msgpack.unpackb(encode(msg))[field]) is int
    with pytest.raises(TypeError, match=f"{field} must be a float, got int"):
        _core.encode_state(*state_args(msg))


@pytest.mark.parametrize("used", [("a", 1), ("a", b"b"), ("a", None), "abc", b"ab", {"a"}])
def test_encode_state_refuses_used_that_is_not_a_tuple_or_list_of_str(used):
    args = list(STATE)
    args[10] = used
    with pytest.raises(TypeError, match="encode_state: used"):
        _core.encode_state(*args)


@pytest.mark.parametrize("k,value", [(1, -1), (1, 2**64), (11, -1), (11, 2**70), (13, 2**63), (13, -2**63 - 1),
                                     (14, 2**63), (15, -2**64)])
def test_encode_state_refuses_an_integer_beyond_its_c_field(k, value):
    args = list(STATE)
    args[k] = value
    with pytest.raises(ValueError, match=r"encode_state: \w+ must be in"):
        _core.encode_state(*args)


@pytest.mark.parametrize("seq", [-1, 2**64, -2**100])
def test_encode_cmd_refuses_a_seq_beyond_uint64(seq):
    with pytest.raises(ValueError, match=r"encode_cmd: seq must be in \[0, 2\^64\)"):
        _core.encode_cmd(1.0, seq, 0.0, 0.0, 0.3)


@pytest.mark.parametrize("n", [0, 4, 6])
def test_encode_cmd_takes_exactly_five_arguments(n):
    with pytest.raises(TypeError, match="takes 5 arguments"):
        _core.encode_cmd(*(CMD + CMD)[:n])


@pytest.mark.parametrize("n", [0, 11, 17])
def test_encode_state_takes_12_to_16_arguments(n):
    with pytest.raises(TypeError, match="takes 12 to 16 arguments"):
        _core.encode_state(*(STATE + STATE)[:n])
