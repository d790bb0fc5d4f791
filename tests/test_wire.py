"""The wire contract: round trips for every message, and a rejection table for bad ones."""

import math

import msgpack
import pytest

from vsfleet.wire import (
    CmdMsg,
    FaultMsg,
    Keys,
    Mission,
    PoseMsg,
    RobotSpec,
    StateMsg,
    TruthMsg,
    WireError,
    decode_cmd,
    decode_fault,
    decode_mission,
    decode_pose,
    decode_state,
    decode_frame,
    decode_truth,
    encode,
    encode_mission,
)

MISSION = Mission(version=3, metric="linf",
                  robots=(("r1", RobotSpec((0.3, 0.0), 0.1, 0.3, 1.0)),
                          ("r2", RobotSpec((-0.1, 0.2), 0.1, 0.3, 1.0))),
                  speed_max=0.1, turn_rate_max=0.3, effective_t=1.7e9, goal=(1.0, 2.0, 0.5))

ROUND_TRIP = [
    (PoseMsg(1.7e9 + 0.123456789, 42, 1.5, -2.25, 3.0, "cam1"), decode_pose),
    (CmdMsg(1.7e9, 42, 0.1, -0.2, 0.3), decode_cmd),
    (StateMsg(1.7e9, 42, 1.0, 2.0, 0.1, 1.1, 2.1, 0.2, 0.004, 0.002, ("r1", "r2"), 7), decode_state),
    (TruthMsg(1.7e9, 1.0, 2.0, -3.1, 0.1, 0.2), decode_truth),
    (TruthMsg(1.7e9, 1.0, 2.0, -3.1, 0.1, 0.2, why="expired", why_t=1.7e9 - 0.005,
              expired_t=1.7e9 - 0.005, rejected=3), decode_truth),
    (FaultMsg("slow", 0.5, 2.0), decode_fault),
]


@pytest.mark.parametrize("msg, decode", ROUND_TRIP, ids=lambda v: type(v).__name__)
def test_every_message_survives_a_round_trip_bit_for_bit(msg, decode):
    assert decode(encode(msg)) == msg


@pytest.mark.parametrize("mission", [
    MISSION,
    Mission(1, "l2", MISSION.robots, 0.1, 0.3, 0.0, path=((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))),
    Mission(2, "l1", MISSION.robots, 0.1, 0.3, 5.0, twist=(0.1, 0.0, 0.05), controller="arc",
            on_failure="drop"),
])
def test_missions_survive_a_round_trip(mission):
    assert decode_mission(encode_mission(mission)) == mission


def test_a_receiver_ignores_only_the_fields_a_newer_protocol_version_adds():
    m = {"t": 1.0, "seq": 1, "x": 0.0, "y": 0.0, "th": 0.0, "src": "s", "confidence": 0.9, "extra": [1, 2]}
    assert decode_pose(msgpack.packb({**m, "v": 2})) == PoseMsg(1.0, 1, 0.0, 0.0, 0.0, "s", v=2)
    with pytest.raises(WireError, match="'confidence'"):
        decode_pose(msgpack.packb({**m, "v": 1}))


def test_a_truth_message_of_an_older_simfleet_without_why_still_decodes():
    old = {"t": 1.0, "x": 0.5, "y": 0.0, "th": 0.0, "vl": 0.1, "vr": 0.1}
    assert decode_truth(msgpack.packb(old)) == TruthMsg(1.0, 0.5, 0.0, 0.0, 0.1, 0.1, why="", why_t=0.0,
                                                               expired_t=0.0, rejected=-1)


POSE = {"t": 1.0, "seq": 1, "x": 0.0, "y": 0.0, "th": 0.0, "src": "s"}
CMD = {"t": 1.0, "seq": 1, "vl": 0.0, "vr": 0.0, "ttl": 0.3}
STATE = {"t": 1.0, "seq": 1, "x": 0.0, "y": 0.0, "th": 0.0, "gx": 0.0, "gy": 0.0, "gth": 0.0,
         "cost": 0.0, "err": 0.0, "used": ["r1"], "rejected": 0}
TRUTH = {"t": 1.0, "x": 0.0, "y": 0.0, "th": 0.0, "vl": 0.0, "vr": 0.0}
FAULT = {"kind": "stop", "factor": 0.0, "duration": 0.0}
MISSION_MAP = MISSION.to_dict()


def without(d, k):
    return {a: b for a, b in d.items() if a != k}


def with_(d, **kw):
    return {**d, **kw}


REJECT = [
    # (decoder, payload bytes, words expected in the error)
    (decode_pose, msgpack.packb(without(POSE, "seq")), "missing field 'seq'"),
    (decode_pose, msgpack.packb(with_(POSE, x="1.0")), "must be a number"),
    (decode_pose, msgpack.packb(with_(POSE, x=True)), "must be a number"),
    (decode_pose, msgpack.packb(with_(POSE, y=math.nan)), "finite"),
    (decode_pose, msgpack.packb(with_(POSE, th=math.inf)), "finite"),
    (decode_pose, msgpack.packb(with_(POSE, seq=-1)), "out of range"),
    (decode_pose, msgpack.packb(with_(POSE, seq=1.5)), "integer"),
    (decode_pose, msgpack.packb(with_(POSE, src="")), "non-empty string"),
    (decode_pose, msgpack.packb(POSE)[:-3], "not valid msgpack"),
    (decode_pose, b"\xc1", "not valid msgpack"),
    (decode_pose, msgpack.packb([1, 2, 3]), "must be a msgpack map"),
    (decode_pose, msgpack.packb(with_(POSE, pad="x" * 5000)), "exceeds"),
    (decode_cmd, msgpack.packb(without(CMD, "ttl")), "missing field 'ttl'"),
    (decode_cmd, msgpack.packb(with_(CMD, ttl=0.0)), "> 0"),
    (decode_cmd, msgpack.packb(with_(CMD, vl=math.nan)), "finite"),
    (decode_cmd, msgpack.packb(with_(CMD, vr=[1])), "must be a number"),
    (decode_state, msgpack.packb(without(STATE, "gth")), "missing field 'gth'"),
    (decode_state, msgpack.packb(with_(STATE, used="r1")), "'used'"),
    (decode_state, msgpack.packb(with_(STATE, cost=-1.0)), ">= 0"),
    (decode_truth, msgpack.packb(without(TRUTH, "vr")), "missing field 'vr'"),
    (decode_truth, msgpack.packb(with_(TRUTH, x=1e400)), "finite"),
    (decode_truth, msgpack.packb(with_(TRUTH, why="halted")), "field 'why' must be one of"),
    (decode_truth, msgpack.packb(with_(TRUTH, why=1)), "field 'why' must be one of"),
    (decode_truth, msgpack.packb(with_(TRUTH, why="expired", why_t="soon")), "must be a number"),
    (decode_truth, msgpack.packb(with_(TRUTH, rejected=-2)), "out of range"),
    (decode_fault, msgpack.packb(with_(FAULT, kind="explode")), "unknown fault kind"),
    (decode_fault, msgpack.packb(without(FAULT, "duration")), "missing field 'duration'"),
    (decode_fault, msgpack.packb(with_(FAULT, factor=-1)), ">= 0"),
    (decode_mission, msgpack.packb(with_(MISSION_MAP, metric="l3")), "unknown metric"),
    (decode_mission, msgpack.packb(without(MISSION_MAP, "version")), "missing field 'version'"),
    (decode_mission, msgpack.packb(with_(MISSION_MAP, robots={})), "non-empty map"),
    (decode_mission, msgpack.packb(with_(MISSION_MAP, robots={"bad/id": MISSION_MAP["robots"]["r1"]})),
     "robot id"),
    (decode_mission, msgpack.packb(with_(MISSION_MAP, robots={"r1": {"p": [0, 0], "wheel_base": 0.1,
                                                                      "wheel_speed_max": -1,
                                                                      "wheel_accel_max": 1}})), "> 0"),
    (decode_mission, msgpack.packb(with_(MISSION_MAP, path=[[0, 0, 0]])), "exactly one of"),
    (decode_mission, msgpack.packb(without(MISSION_MAP, "goal")), "exactly one of"),
    (decode_mission, msgpack.packb(with_(MISSION_MAP, goal={"x": 1, "y": math.nan, "th": 0})), "finite"),
    (decode_mission, msgpack.packb(with_(MISSION_MAP, on_failure="panic")), "on_failure"),
    (decode_mission, b"\x00" * (2 << 20), "exceeds"),
    (decode_mission, msgpack.packb(with_(MISSION_MAP, controller="pid")), "'controller'"),
    (decode_mission, msgpack.packb(with_(MISSION_MAP, robots={b"r1": MISSION_MAP["robots"]["r1"],
                                                              "r2": MISSION_MAP["robots"]["r2"]})), "robot id"),
    (decode_pose, msgpack.packb(with_(POSE, x=1e300)), "out of range"),
    (decode_cmd, msgpack.packb(with_(CMD, ttl=60.0)), "<= 5.0 s"),
]


@pytest.mark.parametrize("decode, payload, words", REJECT,
                         ids=[f"{d.__name__}-{w}" for d, _, w in REJECT])
def test_malformed_messages_are_rejected_with_a_clear_wire_error(decode, payload, words):
    with pytest.raises(WireError) as err:
        decode(payload)
    assert words in str(err.value)
    assert isinstance(err.value, ValueError)


def test_keys_follow_the_contract_and_refuse_bad_names():
    k = Keys("lab-1")
    assert k.pose("r1") == "vs/lab-1/pose/r1"
    assert k.cmd() == "vs/lab-1/cmd/*"
    assert k.mission == "vs/lab-1/mission"
    assert k.alive("agent", "r1") == "vs/lab-1/alive/agent/r1"
    assert k.robot_of("vs/lab-1/pose/r7", "pose") == "r7"
    with pytest.raises(WireError):
        k.robot_of("vs/lab-1/pose/a/b", "pose")
    with pytest.raises(WireError):
        k.robot_of("vs/other/pose/r1", "pose")
    for bad in ("a/b", "", "*", "x y", "r$", "lab\n", "lab\x00", "\nlab"):
        with pytest.raises(WireError):
            Keys(bad)


def test_a_frame_whose_src_ends_in_a_newline_or_whose_robot_id_holds_a_nul_is_refused():
    """Names are whole key chunks: re.match's ``$`` once let "cam1\\n" through, and an id "a\\x00b" once passed
    as two ids (the ids are checked joined by NUL)."""
    def payload(src="cam1", poses=None):
        return msgpack.packb({"t": 1.0, "seq": 1, "src": src, "poses": {"r1": [0.0, 0.0, 0.0]} if poses is None
                              else poses})
    assert decode_frame(payload()).src == "cam1"
    for src in ("cam1\n", "cam1\x00", "cam1\n\n", "\ncam1"):
        with pytest.raises(WireError, match="src must match"):
            decode_frame(payload(src=src))
    pose = [0.0, 0.0, 0.0]
    for poses in ({"a\x00b": pose}, {"a\x00b": pose, "a": pose, "b": pose}, {"r1": pose, "a\x00b\x00c": pose},
                  {"r1\n": pose}):
        with pytest.raises(WireError, match="robot id must match"):
            decode_frame(payload(poses=poses))


def test_each_agent_answers_and_decides_under_its_own_key():
    k = Keys("lab")
    assert k.event("r2") == "vs/lab/event/r2" and k.event() == "vs/lab/event/*"
    assert k.peer_mission("r1") == "vs/lab/peer/r1/mission" and k.peer_mission() == "vs/lab/peer/*/mission"
    assert k.peer_health("r3") == "vs/lab/peer/r3/health" and k.peer("r3") == "vs/lab/peer/r3"
    assert k.peer_of("vs/lab/peer/r3/health", "health") == "r3"
    assert k.robot_of(k.event("r2"), "event") == "r2"
    for bad in ("vs/lab/peer/r3/mission", "vs/lab/peer/a/b/health", "vs/lab/peer//health", "vs/lab/health",
                "vs/other/peer/r3/health", "vs/lab/peer/*/health"):
        with pytest.raises(WireError):
            k.peer_of(bad, "health")


def test_a_contact_round_trips_and_a_bad_kind_or_other_is_refused():
    from vsfleet.wire import ContactMsg, Keys, WireError, decode_contact, encode

    for msg in (ContactMsg(10.0, "r1", "robot", "r2", 0.5, -0.25, 0.001),
                ContactMsg(10.0, "r3", "obstacle", "12", 1.0, 2.0, 0.0)):
        assert decode_contact(encode(msg)) == msg
    assert Keys("demo").contact("r1") == "vs/demo/contact/r1"
    for bad in (ContactMsg(10.0, "r1", "wall", "0", 0.0, 0.0, 0.0), ContactMsg(10.0, "r1", "obstacle", "x1", 0.0, 0.0, 0.0),
                ContactMsg(10.0, "r1", "robot", "r 2", 0.0, 0.0, 0.0), ContactMsg(10.0, "r1", "robot", "r2", 0.0, 0.0, -1.0)):
        with pytest.raises(WireError):
            decode_contact(encode(bad))
