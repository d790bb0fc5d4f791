"""The agent's reaction to messages, without transport: nothing a peer sends ends it or moves a robot."""

import msgpack
import pytest

import agent.main as agent_main
from agent.main import Agent
from vsfleet.failure import Health
from vsfleet.wire import Keys, Mission, PoseMsg, RobotSpec, decode_cmd, decode_health, decode_state, encode, encode_mission

KEYS = Keys("demo")
MISSION = Mission(1, "linf", (("r1", RobotSpec((0.3, 0.0), 0.12, 0.3, 0.8)),
                              ("r2", RobotSpec((-0.15, 0.26), 0.12, 0.3, 0.8)),
                              ("r3", RobotSpec((-0.15, -0.26), 0.12, 0.3, 0.8))),
                  0.08, 0.3, 0.0, goal=(1.0, 0.5, 0.0))


class Clock:
    def __init__(self, t):
        self.t = t

    def __call__(self):
        return self.t


def make_agent():
    cmds, states = [], []
    clock = Clock(100.0)
    agent = Agent("r1", KEYS, cmds.append, states.append, clock=clock)
    agent.on_message("mission", KEYS.mission, encode_mission(MISSION))
    return agent, cmds, states, clock


def frame(agent, clock, seq, t, poses):
    clock.t = t
    for r, (x, y, th) in poses.items():
        agent.on_message("pose", KEYS.pose(r), encode(PoseMsg(t, seq, x, y, th, "sim")))
    return agent.poll()


POSES = {"r1": (0.3, 0.0, 0.0), "r2": (-0.15, 0.26, 0.0), "r3": (-0.15, -0.26, 0.0)}


def test_a_complete_frame_yields_one_command_and_one_state():
    agent, cmds, states, clock = make_agent()
    frame(agent, clock, 1, 100.0, POSES)
    assert len(cmds) == 1 and len(states) == 1
    assert decode_cmd(cmds[0]).seq == 1


def test_hostile_messages_are_counted_and_never_raise_or_command_motion():
    agent, cmds, states, clock = make_agent()
    bad = [
        ("mission", KEYS.mission, msgpack.packb({**MISSION.to_dict(),
                                                 "robots": {b"r1": {}, "r2": {}}})),  # bytes keys
        ("mission", KEYS.mission, b"\x81\xa1"),                                       # truncated
        ("pose", KEYS.pose("r1"), msgpack.packb({"t": 100.0, "seq": 2**62, "x": 1e300, "y": 0.0,
                                                  "th": 0.0, "src": "x"})),            # out of range
        ("pose", KEYS.pose("r1"), msgpack.packb({"t": float("nan")})),
        ("pose", "vs/demo/pose/a/b", encode(PoseMsg(100.0, 1, 0.0, 0.0, 0.0, "s"))),  # bad key
        ("pose", KEYS.pose("r1"), b"\x00" * 100000),                                  # oversized
    ]
    for kind, key, payload in bad:
        agent.on_message(kind, key, payload)
    assert agent.rejections.count == len(bad)
    assert agent.poll() is None and cmds == []
    # a valid but huge frame number, then a restarted tracker: the agent keeps working
    frame(agent, clock, 2**62, 100.0, POSES)
    frame(agent, clock, 1, 100.05, POSES)
    assert [decode_cmd(c).seq for c in cmds] == [2**62, 1]


def test_a_robot_that_no_mission_names_is_ignored_not_rejected():
    agent, cmds, states, clock = make_agent()
    agent.on_message("pose", KEYS.pose("forklift"), encode(PoseMsg(100.0, 1, 0.0, 0.0, 0.0, "s")))
    assert agent.rejections.count == 0 and agent.ignored == 1


def test_a_restarted_agent_adopts_its_peers_failure_state_once():
    peer, _, _, peer_clock = make_agent()
    peer.health = Health(since_t={"r3": 99.0}, failed=frozenset({"r2"}), dropped=frozenset({"r2"}))
    frame(peer, peer_clock, 1, 100.0, POSES)
    assert peer.health_payload is not None
    fresh, cmds, states, clock = make_agent()
    fresh.on_message("health", KEYS.health, peer.health_payload)
    assert fresh.health.dropped == {"r2"} and fresh.health.failed == {"r2"}
    sent = decode_health(peer.health_payload)
    assert fresh.health.since_t == dict(sent.since) and sent.seq == 1 and sent.mission == 1
    # a later reply does not overwrite what was adopted; a bad one is counted
    other, _, _, other_clock = make_agent()
    frame(other, other_clock, 2, 100.03, POSES)
    fresh.on_message("health", KEYS.health, other.health_payload)
    assert fresh.health.dropped == {"r2"}
    fresh.on_message("health", KEYS.health, b"\x93\x01")
    assert fresh.rejections.count == 1
    # with r2 dropped, both agents now fit the same robots
    frame(fresh, clock, 3, 100.06, POSES)
    frame(peer, peer_clock, 3, 100.06, POSES)
    assert decode_state(states[-1]).used == ("r1", "r3")


def test_health_of_an_unknown_mission_is_not_adopted():
    peer, _, _, peer_clock = make_agent()
    peer.health = Health(failed=frozenset({"r2"}), dropped=frozenset({"r2"}))
    frame(peer, peer_clock, 1, 100.0, POSES)
    fresh = Agent("r1", KEYS, lambda b: None, lambda b: None, clock=Clock(100.0))
    fresh.on_message("health", KEYS.health, peer.health_payload)   # no mission yet
    assert not fresh.health_adopted and fresh.health.dropped == frozenset()


def test_after_a_frame_gap_longer_than_ttl_the_predicted_commands_start_from_rest():
    agent, cmds, states, clock = make_agent()
    far = {"r1": (0.0, 0.0, 0.0), "r2": (-0.45, 0.26, 0.0), "r3": (-0.45, -0.26, 0.0)}
    frame(agent, clock, 1, 100.0, far)
    frame(agent, clock, 2, 100.033, far)
    assert any(vl or vr for vl, vr in agent.predicted.values())
    seen = {}
    real_step = agent_main.control_step

    def spy(*args, **kwargs):
        seen["others"] = dict(kwargs["others_wheels_prev"])
        return real_step(*args, **kwargs)

    agent_main.control_step = spy
    try:
        frame(agent, clock, 3, 101.5, far)                      # 1.5 s of tracker silence
    finally:
        agent_main.control_step = real_step
    assert seen["others"] == {}


def test_a_stale_frame_commands_nothing():
    agent, cmds, states, clock = make_agent()
    clock.t = 101.0
    for r, (x, y, th) in POSES.items():
        agent.on_message("pose", KEYS.pose(r), encode(PoseMsg(100.0, 1, x, y, th, "sim")))
    assert agent.poll() is None and cmds == [] and agent.frames.stale == 1


@pytest.mark.parametrize("change, words", [
    ({"metric": "l3"}, "unknown metric"),
    ({"robots": {}}, "non-empty"),
    ({"robots": {"r1": {"p": [0.0, 0.0], "wheel_base": 0.1, "wheel_speed_max": 0.3,
                        "wheel_accel_max": 1.0},
                 "r2": {"p": [0.0, 0.0], "wheel_base": 0.1, "wheel_speed_max": 0.3,
                        "wheel_accel_max": 1.0}}}, "share the template point"),
    ({"goal": {"x": float("inf"), "y": 0.0, "th": 0.0}}, "finite"),
])
def test_a_bad_mission_is_rejected_and_the_previous_one_stays_in_force(change, words, caplog):
    agent, cmds, states, clock = make_agent()
    bad = {**MISSION.to_dict(), "version": 2, **change}
    agent.on_message("mission", KEYS.mission, msgpack.packb(bad))
    assert agent.rejections.count == 1
    assert words in caplog.text
    assert agent.missions.latest().version == 1
    frame(agent, clock, 1, 100.0, POSES)
    assert decode_state(states[-1]).mission == 1


def test_a_mission_with_a_robot_listed_twice_is_rejected():
    agent, cmds, states, clock = make_agent()
    d = MISSION.to_dict()
    spec = d["robots"]["r1"]
    # a msgpack map with the key "r1" twice (a dict cannot hold it, so pack the pairs by hand)
    robots = msgpack.packb({"r1": spec, "r2": d["robots"]["r2"]})
    robots = b"\x83" + robots[1:] + msgpack.packb("r1") + msgpack.packb({**spec, "p": [9.0, 9.0]})
    body = {k: v for k, v in {**d, "version": 2}.items() if k != "robots"}
    payload = bytes([0x80 | (len(body) + 1)]) + msgpack.packb(body)[1:] + msgpack.packb("robots") + robots
    agent.on_message("mission", KEYS.mission, payload)
    assert agent.rejections.count == 1 and agent.missions.latest().version == 1


def test_after_a_long_gap_the_agent_restarts_its_timers_and_adopts_only_its_peers_decisions():
    agent, cmds, states, clock = make_agent()
    frame(agent, clock, 1, 100.0, POSES)
    agent.want_health = False                                   # the start-up query was made
    agent.health = Health(since_t={"r3": 99.5})
    frame(agent, clock, 2, 105.0, POSES)                        # 5 s without a frame (a partition)
    assert agent.want_health and agent.resyncing and not agent.health_adopted
    assert "r3" not in agent.health.since_t
    peer, _, _, peer_clock = make_agent()
    peer.health = Health(since_t={"r1": 104.0}, failed=frozenset({"r1"}), dropped=frozenset({"r1"}))
    frame(peer, peer_clock, 2, 105.0, {**POSES, "r1": (0.0, 0.0, 0.0)})
    agent.on_message("health", KEYS.health, peer.health_payload)
    assert agent.health.dropped == {"r1"}                       # the decision it missed
    assert "r1" not in agent.health.since_t                     # but its own timers
