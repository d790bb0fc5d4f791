"""Strict decoding: one table with every message kind of the wire contract (docs/protocol.md).

Each kind round-trips bit for bit, and a misspelt key is rejected with the key named, for
every field of every kind, and for the maps inside a mission. Telemetry (pose, state, truth,
event) says which protocol version ``v`` it follows: it is closed at our version, and only a
newer version's extra fields are ignored.
"""

from __future__ import annotations

import math

import msgpack
import pytest

from vsfleet import control
from vsfleet.control import make_controller
from vsfleet.failure import FailurePolicy
from vsfleet.wire import (
    DECODERS,
    ContactMsg,
    PROTOCOL_V,
    CmdMsg,
    EventMsg,
    FaultMsg,
    FrameMsg,
    HealthMsg,
    Mission,
    PoseMsg,
    RobotSpec,
    StateMsg,
    TruthMsg,
    UnknownFieldError,
    WireError,
    controller_gain_names,
    decode_mission,
    encode,
    encode_event,
    encode_frame,
    encode_health,
    encode_mission,
    failure_names,
    mission_from_dict,
)

T = 1.7e9 + 0.123456789
ROBOTS = (("r1", RobotSpec((0.3, 0.0), 0.12, 0.3, 0.8, radius=0.05)),
          ("r2", RobotSpec((-0.15, 0.26), 0.12, 0.25, 0.8)))
MISSION = Mission(7, "linf", ROBOTS, 0.08, 0.3, T, goal=(1.6, 1.0, 0.3), controller="tracking", on_failure="drop",
                  failure=(("fail_after_s", 2.5), ("fail_deviation_m", 0.04)),
                  controller_gains=(("along_gain_per_s", 1.5), ("deadband_m", 0.003)),
                  obstacles=((0.8, 0.4, 0.1),))

# kind -> (a message, its encoder); the decoder is DECODERS[kind]
TABLE = {
    "pose": (PoseMsg(T, 42, 1.5, -2.25, 3.0, "cam1"), encode),
    "frame": (FrameMsg(T, 42, "cam1", {"r1": (0.1, 0.2, 0.3), "r2": (-1.0, 2.0, -3.0)}), encode_frame),
    "cmd": (CmdMsg(T, 42, 0.1, -0.2, 0.3), encode),
    "state": (StateMsg(T, 42, 1.0, 2.0, 0.1, 1.1, 2.1, 0.2, 0.004, 0.002, ("r1", "r2"), 7, False, 3), encode),
    "truth": (TruthMsg(T, 1.0, 2.0, -3.1, 0.1, 0.2), encode),
    "fault": (FaultMsg("slow", 0.5, 2.0), encode),
    "mission": (MISSION, encode_mission),
    "event": (EventMsg(T, 42, "r2", "fail", 0.061, "r1"), encode_event),
    "health": (HealthMsg(T, 42, 7, ("r2",), ("r2",), (("r1", T - 1.0),)), encode_health),
    "contact": (ContactMsg(T, "r1", "obstacle", "3", 0.8, 0.3, 0.0004), encode),
}
TELEMETRY = ("pose", "state", "truth", "event", "contact")
CLOSED = tuple(k for k in TABLE if k not in TELEMETRY)


def as_map(kind):
    msg, enc = TABLE[kind]
    return msgpack.unpackb(enc(msg), raw=False)


def typo(name: str) -> str:
    """A plausible misspelling: the last two letters swapped (on_failure -> on_failuer), or a letter doubled."""
    return name[:-2] + name[-1] + name[-2] if len(name) >= 2 and name[-1] != name[-2] else name + name[-1]


def pack(m) -> bytes:
    return msgpack.packb(m, use_bin_type=True)


def assert_names(exc_info, key):
    assert isinstance(exc_info.value, UnknownFieldError)
    assert key in exc_info.value.fields
    assert repr(key) in str(exc_info.value)


def test_the_table_covers_every_message_kind_the_wire_decodes():
    assert set(TABLE) == set(DECODERS)


@pytest.mark.parametrize("kind", sorted(TABLE))
def test_every_kind_round_trips_bit_for_bit(kind):
    msg, enc = TABLE[kind]
    payload = enc(msg)
    got = DECODERS[kind](payload)
    assert got == msg
    assert enc(got) == payload


FIELD_CASES = [(kind, field) for kind in sorted(TABLE) for field in as_map(kind)]


@pytest.mark.parametrize("kind, field", FIELD_CASES, ids=[f"{k}-{f}" for k, f in FIELD_CASES])
def test_a_misspelt_key_is_rejected_with_the_key_named_whether_added_or_in_place_of_the_right_one(kind, field):
    m = as_map(kind)
    bad = typo(field)
    with pytest.raises(WireError) as added:
        DECODERS[kind](pack({**m, bad: m[field]}))
    assert_names(added, bad)
    replaced = {(bad if k == field else k): v for k, v in m.items()}
    with pytest.raises(WireError) as instead:
        DECODERS[kind](pack(replaced))
    assert_names(instead, bad)


def test_the_misspelt_on_failure_of_the_issue_is_rejected_and_the_right_name_suggested():
    m = as_map("mission")
    del m["on_failure"]
    with pytest.raises(UnknownFieldError, match=r"'on_faliure' \(did you mean 'on_failure'\?\)"):
        decode_mission(pack({**m, "on_faliure": "drop"}))


NESTED = [
    ("robot spec", lambda m: m["robots"]["r1"], "wheel_base"),
    ("robot spec radius", lambda m: m["robots"]["r1"], "radius"),
    ("goal", lambda m: m["goal"], "th"),
    ("failure", lambda m: m["failure"], "fail_after_s"),
    ("controller gains", lambda m: m["controller_gains"], "along_gain_per_s"),
]


@pytest.mark.parametrize("where, table, field", NESTED, ids=[n[0] for n in NESTED])
def test_a_misspelt_key_inside_a_mission_is_rejected_with_the_key_named(where, table, field):
    m = as_map("mission")
    inner = table(m)
    inner[typo(field)] = inner.pop(field)
    with pytest.raises(WireError) as err:
        decode_mission(pack(m))
    assert_names(err, typo(field))


def test_a_misspelt_twist_key_is_rejected():
    m = {**as_map("mission"), "twist": {"vx": 0.1, "vy": 0.0, "ww": 0.1}}
    del m["goal"]
    with pytest.raises(WireError) as err:
        decode_mission(pack(m))
    assert_names(err, "ww")


@pytest.mark.parametrize("kind", TELEMETRY)
def test_telemetry_says_its_protocol_version_and_a_newer_versions_extra_fields_are_ignored(kind):
    m = as_map(kind)
    assert m["v"] == PROTOCOL_V == 1
    newer = DECODERS[kind](pack({**m, "v": PROTOCOL_V + 1, "confidence": 0.9, "extra": [1, 2]}))
    msg, _ = TABLE[kind]
    assert newer.v == PROTOCOL_V + 1
    assert {k: v for k, v in vars(newer).items() if k != "v"} == {k: v for k, v in vars(msg).items() if k != "v"}
    with pytest.raises(WireError) as err:
        DECODERS[kind](pack({**m, "confidence": 0.9}))
    assert_names(err, "confidence")


@pytest.mark.parametrize("kind", TELEMETRY)
def test_telemetry_without_a_version_is_read_as_version_1_as_recorded_before_versioning(kind):
    m = as_map(kind)
    del m["v"]
    assert DECODERS[kind](pack(m)) == TABLE[kind][0]


@pytest.mark.parametrize("kind", TELEMETRY)
@pytest.mark.parametrize("v", [0, -1, True, 1.0, "1", None, 2**40])
def test_a_protocol_version_that_is_not_a_positive_integer_is_rejected(kind, v):
    with pytest.raises(WireError, match="'v'"):
        DECODERS[kind](pack({**as_map(kind), "v": v}))


@pytest.mark.parametrize("kind", CLOSED)
def test_closed_messages_take_no_version_and_no_extra_field_whatever_they_claim(kind):
    with pytest.raises(WireError) as err:
        DECODERS[kind](pack({**as_map(kind), "v": 2, "extra": 1}))
    assert set(err.value.fields) == {"v", "extra"}


def test_failure_thresholds_and_gains_are_encoded_sorted_and_build_the_same_policy_and_controller():
    m = as_map("mission")
    assert list(m["failure"]) == sorted(m["failure"]) and list(m["controller_gains"]) == sorted(m["controller_gains"])
    got = decode_mission(encode_mission(MISSION))
    assert [v.hex() for _, v in got.failure] == [v.hex() for _, v in MISSION.failure]
    policy = FailurePolicy(mode=got.on_failure, **dict(got.failure))
    assert (policy.mode, policy.fail_after_s, policy.fail_deviation_m) == ("drop", 2.5, 0.04)
    assert policy.rejoin_after_s == FailurePolicy().rejoin_after_s  # an absent threshold keeps its default
    make_controller(got.controller, **dict(got.controller_gains))


def test_a_mission_without_thresholds_or_gains_encodes_as_before():
    plain = Mission(1, "l2", ROBOTS, 0.1, 0.3, 0.0, goal=(1.0, 1.0, 0.0))
    assert not {"failure", "controller_gains"} & set(plain.to_dict())
    assert decode_mission(encode_mission(plain)) == plain


def test_failure_names_are_the_failure_policys_thresholds_and_carry_units():
    assert set(failure_names()) == {"fail_deviation_m", "fail_after_s", "rejoin_deviation_m", "rejoin_after_s",
                                    "recover_after_s", "min_progress_ratio", "min_expected_m", "min_approach_m"}
    assert all(n.endswith(("_m", "_s", "_ratio")) for n in failure_names())


UNIT_SUFFIXES = ("_m", "_s", "_m_s", "_per_s", "_per_m", "_per_m2", "_per_rad", "_rad", "_rad_s",
                 "_ratio")  # _ratio: a dimensionless gain (a fraction per frame, a cosine, a wheel gain)


@pytest.mark.parametrize("name", sorted(control.CONTROLLERS))
def test_every_controllers_gains_are_read_from_its_factory_and_carry_units(name):
    gains = controller_gain_names(name)
    assert "deadband_m" in gains  # make_controller's own
    assert all(g.endswith(UNIT_SUFFIXES) for g in gains), gains
    for g in gains:  # every name is one the factory takes (a value out of its range is another matter)
        try:
            make_controller(name, **{g: 0.01})
        except control.ControllerGainError:
            pass


def test_a_new_controller_s_gains_are_known_without_a_table_to_update(monkeypatch):
    def make_pid(k_p_per_s: float = 1.0, k_i_per_s2: float = 0.0, clamp: bool = True):
        return lambda *a: (0.0, 0.0)

    monkeypatch.setitem(control.CONTROLLERS, "pid", make_pid)
    assert controller_gain_names("pid") == ("deadband_m", "k_i_per_s2", "k_p_per_s")


BAD_PARAMS = [
    ({"failure": {"mode": 1.0}}, "'mode'"),  # the mode is on_failure
    ({"failure": {"fail_after_s": -1.0}}, "fail_after_s"),
    ({"failure": {"fail_after_s": math.inf}}, "finite"),
    ({"failure": {"fail_after_s": "2"}}, "must be a number"),
    ({"failure": [1.0]}, "'failure' must be a map"),
    ({"controller_gains": {"horizon_s": 1.0}}, "'horizon_s'"),  # arc's, but this mission's is tracking
    ({"controller_gains": {"along_gain_per_s": 0.0}}, "along_gain_per_s"),  # must be > 0
    ({"controller_gains": {"along_gain_per_s": True}}, "must be a number"),
    ({"controller_gains": {"allow_reverse": 0.0}}, "'allow_reverse'"),
]


@pytest.mark.parametrize("change, words", BAD_PARAMS, ids=[w for _, w in BAD_PARAMS])
def test_bad_thresholds_and_gains_are_rejected_with_the_name(change, words):
    with pytest.raises(WireError, match=words):
        mission_from_dict({**MISSION.to_dict(), **change})


def test_gains_are_checked_against_the_default_controller_when_the_mission_names_none():
    d = {**MISSION.to_dict(), "controller_gains": {"offset_m": 0.03}}
    del d["controller"]
    assert mission_from_dict(d).controller_gains == (("offset_m", 0.03),)
    with pytest.raises(WireError, match="horizon_s"):  # the arc's gain: not the default controller's
        mission_from_dict({**d, "controller_gains": {"horizon_s": 0.5}})
    assert controller_gain_names(None) == controller_gain_names(control.DEFAULT_CONTROLLER)
