"""The agent's reaction to messages, without transport: nothing a peer sends ends it or moves a robot."""

import msgpack

from agent.main import Agent
from vsfleet.wire import Keys, Mission, PoseMsg, RobotSpec, decode_cmd, encode, encode_mission

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
