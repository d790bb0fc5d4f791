"""The agent's reaction to messages, without transport: nothing a peer sends ends it or moves a robot."""

import dataclasses
import struct

import msgpack
import pytest

import vsfleet.agent.main as agent_main
import vsfleet.agentcore as agentcore
import vsfleet.agentstate as agentstate
import vsfleet.glue as glue
import vsfleet.impl as impl_module
import vsfleet.step as step_mod
from vsfleet.agent.main import Agent
from vsfleet.control import DEFAULT_CONTROLLER, make_controller
from vsfleet.failure import Health
from vsfleet.step import SyncPhase
from vsfleet.wire import (
    EventMsg,
    HealthMsg,
    Keys,
    Mission,
    FrameMsg,
    RobotSpec,
    decode_cmd,
    decode_event,
    decode_health,
    decode_state,
    encode_frame,
    encode_health,
    encode_mission,
)

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


def frame(agent, clock, seq, t, poses, src="sim"):
    clock.t = t
    agent.on_frame(KEYS.frame(src), encode_frame(FrameMsg(t, seq, src, poses)))
    return agent.poll()


def set_health(agent, health):
    agent.state = dataclasses.replace(agent.state, health=health)


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
        ("frame", KEYS.frame("x"), msgpack.packb({"t": 100.0, "seq": 2**62, "src": "x",
                                                   "poses": {"r1": [1e300, 0.0, 0.0]}})),  # out of range
        ("frame", KEYS.frame("x"), msgpack.packb({"t": float("nan")})),
        ("frame", KEYS.frame("y"), encode_frame(FrameMsg(100.0, 1, "s", POSES))),        # src is not the key's
        ("frame", KEYS.frame("s"), b"\x00" * 100000),                                    # oversized
    ]
    for kind, key, payload in bad:
        if kind == "frame":
            agent.on_frame(key, payload)
            assert agent.poll() is None
        else:
            agent.on_message(kind, key, payload)
    assert agent.rejections.count == len(bad)
    assert agent.poll() is None and cmds == []
    # a valid but huge frame number, then a restarted tracker: the agent keeps working
    frame(agent, clock, 2**62, 100.0, POSES)
    frame(agent, clock, 1, 100.05, POSES)
    assert [decode_cmd(c).seq for c in cmds] == [2**62, 1]


@pytest.mark.parametrize("reference", [False, True], ids=["core", "reference"])
def test_a_frame_is_decoded_by_the_core_or_by_the_readable_decoder_to_the_same_message(monkeypatch, reference):
    """The agent decodes frames with the compiled core (vsfleet._core.decode_frame, the key's src checked there),
    and with StepConfig.reference with vsfleet.wire.decode_frame: the same message, the same refusals."""
    used = []
    for name in ("core", "reference"):   # StepConfig takes its namespace from vsfleet.impl when it is made
        ns = getattr(impl_module, name)
        monkeypatch.setattr(impl_module, name, dataclasses.replace(
            ns, decode_frame=lambda *a, real=ns.decode_frame, name=name: used.append(name) or real(*a)))
    agent = Agent("r1", KEYS, lambda b: None, lambda b: None, clock=Clock(100.0), reference=reference)
    msg = FrameMsg(100.0, 1, "cam-1", {"r1": (0.1, -0.0, 3.0), "r2": (1e6, -1e6, 5e-324)})
    agent.on_frame(KEYS.frame("cam-1"), encode_frame(msg), wake=False)
    assert agent._slot == {"cam-1": msg} and used == ["reference" if reference else "core"]
    assert [struct.pack("<3d", *p) for p in agent._slot["cam-1"].poses.values()] == \
        [struct.pack("<3d", *p) for p in msg.poses.values()]
    bad = [(KEYS.frame("cam-2"), msg), (Keys("other").frame("cam-1"), msg), (KEYS.frame("cam-1") + "/x", msg),
           (KEYS.frame("cam-1") + "\n", msg), ("vs/demo/frames/cam-1", msg), (KEYS.frame(""), msg),
           (KEYS.frame("cam1\n"), FrameMsg(100.0, 2, "cam1\n", msg.poses)),
           (KEYS.frame("cam-1"), FrameMsg(100.0, 2, "cam-1", {"r1\x00r2": (0.0, 0.0, 0.0)}))]
    for key, m in bad:
        agent.on_frame(key, msgpack.packb({"t": m.t, "seq": m.seq, "src": m.src,
                                           "poses": {r: list(p) for r, p in m.poses.items()}}), wake=False)
    assert agent.rejections.count == len(bad) and agent._slot == {"cam-1": msg}


def test_a_robot_that_no_mission_names_is_ignored_not_rejected():
    agent, cmds, states, clock = make_agent()
    frame(agent, clock, 1, 100.0, {**POSES, "forklift": (0.0, 0.0, 0.0)})
    assert agent.rejections.count == 0 and agent.merger.ignored == 1 and len(cmds) == 1


def test_a_restarted_agent_adopts_its_peers_failure_state_once():
    peer, _, _, peer_clock = make_agent()
    set_health(peer, Health(since_t={"r3": 99.0}, failed=frozenset({"r2"}), dropped=frozenset({"r2"})))
    frame(peer, peer_clock, 1, 100.0, POSES)
    assert peer.health_payload is not None
    fresh, cmds, states, clock = make_agent()
    assert fresh.on_query_replies("health", [(KEYS.peer_health("r2"), peer.health_payload)])  # the only peer
    assert fresh.state.health.dropped == {"r2"} and fresh.state.health.failed == {"r2"}
    sent = decode_health(peer.health_payload)
    assert fresh.state.health.since_t == dict(sent.since) and sent.seq == 1 and sent.mission == 1
    # a later reply does not overwrite what was adopted; a bad one is counted
    other, _, _, other_clock = make_agent()
    frame(other, other_clock, 2, 100.03, POSES)
    assert not fresh.on_query_replies("health", [(KEYS.peer_health("r3"), other.health_payload)])
    assert fresh.state.health.dropped == {"r2"}
    fresh.on_message("health-replies", KEYS.peer_health(), [(KEYS.peer_health("r3"), b"\x93\x01")])
    assert fresh.rejections.count == 1
    # with r2 dropped, both agents now fit the same robots
    frame(fresh, clock, 3, 100.06, POSES)
    frame(peer, peer_clock, 3, 100.06, POSES)
    assert decode_state(states[-1]).used == ("r1", "r3")


def test_health_of_an_unknown_mission_is_not_adopted():
    peer, _, _, peer_clock = make_agent()
    set_health(peer, Health(failed=frozenset({"r2"}), dropped=frozenset({"r2"})))
    frame(peer, peer_clock, 1, 100.0, POSES)
    fresh = Agent("r1", KEYS, lambda b: None, lambda b: None, clock=Clock(100.0))
    fresh.on_query_replies("health", [(KEYS.peer_health("r2"), peer.health_payload)])   # no mission yet
    assert fresh.state.phase is SyncPhase.JOINING and fresh.state.health.dropped == frozenset()


class SpyController:
    """The default controller, recording the previous commands it is given."""

    def __init__(self):
        self.inner = make_controller(DEFAULT_CONTROLLER)
        self.prev = []

    def initial(self, n):
        return self.inner.initial(n)

    def __call__(self, state, inp):
        self.prev.append(inp.wheels_prev_m_s.copy())
        return self.inner(state, inp)


def test_after_a_frame_gap_longer_than_ttl_the_predicted_commands_start_from_rest():
    spy = SpyController()
    cmds = []
    clock = Clock(100.0)
    agent = Agent("r1", KEYS, cmds.append, lambda b: None, clock=clock, controller=spy)
    agent.on_message("mission", KEYS.mission, encode_mission(MISSION))
    far = {"r1": (0.0, 0.0, 0.0), "r2": (-0.45, 0.26, 0.0), "r3": (-0.45, -0.26, 0.0)}
    frame(agent, clock, 1, 100.0, far)
    frame(agent, clock, 2, 100.033, far)
    assert any(vl or vr for vl, vr in agent.state.predicted_m_s.values())
    assert spy.prev[-1].any()                                   # frame 2 started from frame 1's commands
    frame(agent, clock, 3, 101.5, far)                          # 1.5 s of tracker silence
    assert not spy.prev[-1].any()


# bodies (no obstacle, so no field to build): the safety filter runs
ROOM = dataclasses.replace(MISSION, robots=tuple((r, dataclasses.replace(s, radius=0.05)) for r, s in MISSION.robots))


@pytest.mark.parametrize("path", ["one-pass", "core-long-way", "reference"])
@pytest.mark.parametrize("age_s, room", [(0.1, True), (0.25, True), (0.25, False)])
def test_a_commands_ttl_ends_where_the_safety_filters_guarantee_for_it_ends(age_s, room, path):
    """The filter certifies a command for 1/gamma after the poses it was computed from (docs/safety.md): a robot
    holding it longer, or a frame run later, could drive a body past the barrier. In a room the ttl is cut there,
    and a frame older than that is not run (counted as too_old), as a stale frame. Without a safety filter the ttl
    stays, and such a frame runs."""
    from vsfleet.safety import SafetyParams
    cmds, clock = [], Clock(100.0)
    agent = Agent("r1", KEYS, cmds.append, lambda b: None, clock=clock, reference=path == "reference")
    agent.on_message("mission", KEYS.mission, encode_mission(ROOM if room else MISSION))
    frame(agent, clock, 1, 100.0, POSES)
    frame(agent, clock, 2, 100.0 + 1 / 30, POSES)   # the agent follows "sim" from now on
    t3 = 100.0 + 2 / 30
    clock.t = t3 + age_s
    payload = encode_frame(FrameMsg(t3, 3, "sim", POSES))
    if path != "one-pass" or not agent.fast_frame(KEYS.frame("sim"), payload):   # as the frame callback does
        agent.on_frame(KEYS.frame("sim"), payload)
        agent.poll()
    horizon_s = 1.0 / SafetyParams().gamma_per_s
    too_old = room and age_s >= horizon_s
    assert (agent._fast_last is not None) == (path == "one-pass" and not too_old)   # the path named ran it
    sent = [decode_cmd(c) for c in cmds]
    assert sent[0].vr > 0.0 and (sent[0].ttl == 0.3 if not room else sent[0].ttl < 0.3)   # on its way
    assert [c.seq for c in sent] == ([1, 2] if too_old else [1, 2, 3])
    assert agent.state.too_old == int(too_old) and agent.state.stale == 0
    if not room:
        assert sent[2].ttl == 0.3 and sent[2].vr > 0.0
    elif not too_old:
        assert sent[2].ttl == t3 + horizon_s - clock.t and sent[2].vr > 0.0


def test_a_stale_frame_commands_nothing():
    agent, cmds, states, clock = make_agent()
    clock.t = 101.0
    agent.on_frame(KEYS.frame("sim"), encode_frame(FrameMsg(100.0, 1, "sim", POSES)))
    assert agent.poll() is not None and cmds == [] and agent.state.stale == 1


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
    agent.health_replies([])                                    # the start-up query: no peer answered
    assert agent.state.phase is SyncPhase.SYNCED
    set_health(agent, Health(since_t={"r3": 99.5}))
    frame(agent, clock, 2, 105.0, POSES)                        # 5 s without a frame (a partition)
    assert agent.state.phase is SyncPhase.RESYNCING
    assert "r3" not in agent.state.health.since_t
    peer, _, _, peer_clock = make_agent()
    set_health(peer, Health(since_t={"r1": 104.0}, failed=frozenset({"r1"}), dropped=frozenset({"r1"})))
    frame(peer, peer_clock, 2, 105.0, {**POSES, "r1": (0.0, 0.0, 0.0)})
    agent.on_query_replies("health", [(KEYS.peer_health("r2"), peer.health_payload)])
    assert agent.state.health.dropped == {"r1"}                 # the decision it missed
    assert "r1" not in agent.state.health.since_t               # but its own timers
    assert agent.state.phase is SyncPhase.SYNCED


# ---------------------------------------------------------------- answers from peers: a majority or nothing

FORGED = dataclasses.replace(MISSION, version=10**12, goal=(-5.0, -5.0, 0.0))  # newer than any real one


def fresh_agent(robot="r1"):
    return Agent(robot, KEYS, lambda b: None, lambda b: None, clock=Clock(100.0))


def peer_missions(**by_peer):
    return [(KEYS.peer_mission(r), encode_mission(m)) for r, m in by_peer.items()]


def test_a_mission_is_taken_from_a_strict_majority_of_the_peers_that_replied():
    for replies in (peer_missions(r2=MISSION),                      # the only peer: a majority of 1
                    peer_missions(r2=MISSION, r3=MISSION),
                    peer_missions(r2=MISSION, r3=MISSION, r4=FORGED)):
        agent = fresh_agent()
        assert agent.on_query_replies("mission", replies)
        assert agent.missions.latest() == MISSION


def test_a_forged_mission_without_a_majority_is_not_taken_and_the_agent_says_why(caplog):
    for replies in (peer_missions(r2=MISSION, r3=FORGED), peer_missions(r2=FORGED, r3=MISSION),
                    peer_missions(r2=MISSION, r3=FORGED, r4=dataclasses.replace(MISSION, version=2))):
        agent = fresh_agent()
        caplog.clear()
        assert not agent.on_query_replies("mission", replies)
        assert agent.missions.latest() is None and agent.mission_payload is None
        assert agent.no_quorum == 1
        assert "no answer has a strict majority" in caplog.text and "asking again" in caplog.text
    # the next query (a second later) with the forger gone: taken
    assert agent.on_query_replies("mission", peer_missions(r2=MISSION))
    assert agent.missions.latest() == MISSION


def test_two_sessions_with_one_robots_login_cannot_outvote_the_others():
    """r3's real agent and a rogue with r3's login both answer under r3's key: r3 counts once."""
    agent = fresh_agent()
    replies = peer_missions(r2=MISSION) + peer_missions(r3=MISSION) + peer_missions(r3=FORGED)
    assert agent.on_query_replies("mission", replies)
    assert agent.missions.latest() == MISSION
    agent = fresh_agent()  # the rogue alone against one honest peer: nothing
    assert not agent.on_query_replies("mission", peer_missions(r2=MISSION) + [
        (KEYS.peer_mission("r3"), encode_mission(FORGED)), (KEYS.peer_mission("r3"), encode_mission(FORGED))])
    assert agent.missions.latest() is None


def test_the_operators_answer_is_taken_as_its_put_is_and_the_agents_own_answer_never_counts():
    agent = fresh_agent()
    assert agent.on_query_replies("mission", [(KEYS.mission, encode_mission(MISSION))]
                                  + peer_missions(r2=FORGED, r3=dataclasses.replace(FORGED, version=7)))
    assert agent.missions.latest() == MISSION
    agent = fresh_agent()
    # its own queryable (r1's key) cannot make up a majority for it
    assert not agent.on_query_replies("mission", peer_missions(r1=FORGED, r2=MISSION, r3=FORGED))
    assert agent.missions.latest() is None


def test_replies_under_keys_that_name_no_peer_are_rejected_and_never_counted():
    agent = fresh_agent()
    payload = encode_mission(FORGED)
    bad = [(f"{KEYS.prefix}/peer/a/b/mission", payload), (f"{KEYS.prefix}/peer//mission", payload),
           (f"{KEYS.prefix}/health", payload), (KEYS.peer_health("r2"), payload)]
    assert agent.on_query_replies("mission", bad + peer_missions(r3=MISSION))
    assert agent.missions.latest() == MISSION and agent.rejections.count == len(bad)


def health_of(robot, seq, t, failed=(), dropped=(), since=(), mission=1):
    """Peer ``robot``'s answer to a health query, sent after frame ``seq`` (tracker time t)."""
    return KEYS.peer_health(robot), encode_health(HealthMsg(t=t, seq=seq, mission=mission, failed=tuple(failed),
                                                            dropped=tuple(dropped), since=tuple(since)))


def test_a_forged_health_answer_without_a_majority_is_not_adopted_and_the_agent_keeps_its_own(caplog):
    agent, _, _, _ = make_agent()
    honest = health_of("r2", 7, 100.2)
    forged = health_of("r3", 7, 100.2, failed=("r1", "r2"), dropped=("r1", "r2"))
    assert not agent.on_query_replies("health", [honest, forged])
    assert agent.state.health == Health() and agent.state.phase is SyncPhase.JOINING
    assert "keeping this agent's own failure state" in caplog.text
    # with a second honest peer (a frame further on: t and seq differ) the honest state wins
    other = health_of("r4", 8, 100.233)
    assert decode_health(other[1]).seq != decode_health(honest[1]).seq
    assert agent.on_query_replies("health", [honest, forged, other])
    assert agent.state.phase is SyncPhase.SYNCED
    assert agent.state.health.dropped == frozenset() and agent.state.health.failed == frozenset()


def test_peers_that_disagree_on_the_failure_timers_give_their_decisions_but_not_their_timers(caplog):
    """r3 forges a timer that would fail r2 at its first bad frame: the decisions, which both
    peers agree on, are adopted; the timers are this agent's own."""
    a = health_of("r2", 7, 100.2, failed=("r3",), dropped=("r3",), since=(("r3", 100.1),))
    b = health_of("r3", 7, 100.2, failed=("r3",), dropped=("r3",), since=(("r2", 0.0), ("r3", 100.1)))
    caplog.set_level("INFO", "vsfleet.agent")
    agent, _, _, _ = make_agent()
    set_health(agent, Health(since_t={"r1": 100.0}))
    assert agent.on_query_replies("health", [a, b])
    assert agent.state.health.dropped == {"r3"} and agent.state.health.failed == {"r3"}
    assert agent.state.health.since_t == {"r1": 100.0}
    assert "not on the failure timers" in caplog.text
    agent, _, _, _ = make_agent()   # when they agree on the timers too, the timers are adopted
    assert agent.on_query_replies("health", [a, health_of("r3", 8, 100.233, failed=("r3",), dropped=("r3",),
                                                          since=(("r3", 100.1),))])
    assert agent.state.health.since_t == {"r3": 100.1}


def test_health_for_a_mission_the_agent_does_not_hold_is_not_adopted_even_by_a_majority(caplog):
    agent, _, _, _ = make_agent()
    assert not agent.on_query_replies("health", [health_of("r2", 7, 100.2, dropped=("r3",), mission=5),
                                                 health_of("r3", 7, 100.2, dropped=("r3",), mission=5)])
    assert agent.state.phase is SyncPhase.JOINING and "does not hold" in caplog.text


def test_a_frame_missing_a_robot_feeds_the_motion_test_only_the_poses_of_that_frame():
    agent, cmds, states, clock = make_agent()
    frame(agent, clock, 1, 100.0, POSES)
    clock.t = 100.033                                        # r3 is missing from frame 2
    ran = frame(agent, clock, 2, 100.033, {r: POSES[r] for r in ("r1", "r2")})
    assert ran is not None and not ran.complete and ran.fresh == {"r1", "r2"}
    assert "r3" in ran.poses                                 # still in the fit (held pose)
    last_t = dict(zip(agent.state.ids, agent.state.failure.last_t))
    assert last_t["r3"] == 100.0                             # but the motion test waits for a fresh one
    assert last_t["r1"] == 100.033


def test_the_agent_refuses_a_deadline_outside_its_range():
    assert agent_main.main(["--robot", "r1", "--deadline", "0"]) == 2
    assert agent_main.main(["--robot", "r1", "--deadline", "2"]) == 2


@pytest.mark.parametrize("on_failure, judged", [("hold", {"r2"}), ("drop", set()), ("rejoin", set())])
def test_only_under_hold_are_failed_robots_judged_apart(monkeypatch, on_failure, judged):
    seen = []
    real = glue.structure_step

    def spy(arrays, metric, pose, seen_rows, excluded, judged_apart, *args):
        seen.append(frozenset(r for r, j in zip(arrays.ids, judged_apart) if j))
        return real(arrays, metric, pose, seen_rows, excluded, judged_apart, *args)

    monkeypatch.setattr(glue, "structure_step", spy)
    monkeypatch.setattr(agentcore, "agent_kernel", lambda *args: None)   # the numpy glue, which calls structure_step
    agent, cmds, states, clock = make_agent()
    agent.on_message("mission", KEYS.mission, encode_mission(dataclasses.replace(MISSION, version=2,
                                                                                 on_failure=on_failure)))
    set_health(agent, Health(failed=frozenset({"r2"})))   # failed (under hold, say), not dropped
    frame(agent, clock, 1, 100.0, POSES)
    assert seen == [frozenset(judged)]


def test_under_a_flood_the_slot_keeps_only_the_newest_frame_and_counts_the_ones_it_dropped():
    agent, cmds, states, clock = make_agent()
    clock.t = 100.0
    for k in range(1, 1001):                                  # 1000 frames before the agent gets to run
        agent.on_frame(KEYS.frame("sim"), encode_frame(FrameMsg(100.0 + k * 1e-4, k, "sim", POSES)))
    ran = agent.poll()
    assert ran.seq == 1000 and agent.frames_replaced == 999
    assert [decode_cmd(c).seq for c in cmds] == [1000] and agent.poll() is None
    # each source has its own slot: a second camera's frame is not dropped for the first's
    agent.on_frame(KEYS.frame("cam2"), encode_frame(FrameMsg(100.2, 1, "cam2", {"r2": POSES["r2"]})))
    agent.on_frame(KEYS.frame("sim"), encode_frame(FrameMsg(100.2, 1001, "sim", {"r1": POSES["r1"]})))
    clock.t = 100.2
    assert agent.poll() is None                               # r3 unseen by both: its deadline first
    clock.t = 100.24
    ran = agent.poll()
    assert ran.seq == 1001 and set(ran.fresh) == {"r1", "r2"} and not ran.complete
    assert agent.frames_replaced == 999


def test_an_agent_that_runs_for_ever_keeps_only_its_newest_decisions_and_publishes_every_one(monkeypatch):
    """Agent.decisions is bounded (DECISIONS_KEPT, the newest); every decision still goes out as an event."""
    events = []
    clock = Clock(100.0)
    agent = Agent("r1", KEYS, lambda b: None, lambda b: None, clock=clock, put_event=events.append)
    agent.on_message("mission", KEYS.mission, encode_mission(MISSION))
    n = 3 * agent_main.DECISIONS_KEPT + 7

    def deciding_step(state, mission, frame, now, config):  # one "fail" per frame, as a flapping robot's
        return state, step_mod.StepOutput(events=(EventMsg(t=frame.t, seq=frame.seq, robot="r2", kind="fail",
                                                           dev=0.1, by="r1"),))

    monkeypatch.setattr(agent_main, "agent_step", deciding_step)
    for k in range(1, n + 1):
        assert frame(agent, clock, k, 100.0 + k / 30.0, POSES) is not None
    assert len(events) == n                                       # every decision published
    assert len(agent.decisions) == agent_main.DECISIONS_KEPT      # the agent keeps the newest only
    assert [d.t for d in agent.decisions] == [decode_event(e).t for e in events[-agent_main.DECISIONS_KEPT:]]


def test_a_new_mission_with_a_room_is_prepared_off_the_frame_path_once_and_its_field_is_the_steps():
    """run_agent hands every new mission to prepare_mission (a thread of its own builds the room's field), so
    the frame that first runs it finds the field built; a mission heard again is not prepared again."""
    room = dataclasses.replace(MISSION, version=2, obstacles=((0.6, 0.3, 0.1),),
                               robots=tuple((r, dataclasses.replace(s, radius=0.05)) for r, s in MISSION.robots))
    prepared = []

    def prepare(mission):
        prepared.append(mission.version)
        agent_main.prepare_mission(mission).join(timeout=30.0)

    agent = Agent("r1", KEYS, lambda b: None, lambda b: None, clock=Clock(100.0), prepare=prepare)
    agent.on_message("mission", KEYS.mission, encode_mission(room))
    agent.on_message("mission", KEYS.mission, encode_mission(room))
    assert prepared == [2]
    built = step_mod.mission_arrays(agent.missions.latest())
    assert built.field is not None
    calls = []
    original = agentstate.build_field_deferred
    agentstate.build_field_deferred = lambda *a, **k: calls.append(1) or original(*a, **k)
    try:
        frame(agent, Clock(100.0), 1, 100.0, POSES)  # the agent's own clock object is not this one: t is fresh
    finally:
        agentstate.build_field_deferred = original
    assert calls == []  # the step found the prepared field


@pytest.mark.parametrize("fast", [True, False], ids=["one pass", "long way"])
def test_a_frame_waits_for_its_missions_prepare_thread_instead_of_building_beside_it(monkeypatch, fast):
    """A mission whose prepare thread is still building when its first frame comes: the frame waits for that
    build and builds nothing itself (before, it built a second copy beside the thread, on the CPU the thread
    needed: an agent that joins a fleet in a room gets its mission and its first frame together). Through
    run_frame (the frame callback's way: a mission's first frame never goes in one pass, so the long way waits)
    and through on_frame and poll."""
    import threading

    obstacle = (0.6, 0.35, 0.11) if fast else (0.6, 0.4, 0.12)   # a room no other test built (they are memoised)
    room = dataclasses.replace(MISSION, version=3, obstacles=(obstacle,), effective_t=100.5,
                               robots=tuple((r, dataclasses.replace(s, radius=0.05)) for r, s in MISSION.robots))
    go, builds = threading.Event(), []
    original = agentstate.build_field_deferred

    def counted(*a, **k):
        builds.append(threading.current_thread().name)
        return original(*a, **k)

    def held_build(mission):
        go.wait(timeout=30.0)
        agent_main.build_mission_arrays(mission)

    def prepare(mission):
        thread = threading.Thread(target=held_build, args=(mission,), name="prepare-held", daemon=True)
        thread.start()
        return thread

    monkeypatch.setattr(agentstate, "build_field_deferred", counted)
    clock = Clock(100.0)
    agent = Agent("r1", KEYS, lambda b: None, lambda b: None, clock=clock, prepare=prepare)
    agent.on_message("mission", KEYS.mission, encode_mission(room))
    # a frame before the mission takes effect: it needs no arrays, and the agent follows "sim" from it on, so
    # the next frame could go in one pass (fast_frame), its mission the only one held
    agent.run_frame(KEYS.frame("sim"), encode_frame(FrameMsg(100.0, 1, "sim", POSES)))
    assert agent.following == frozenset({"sim"}) and builds == []
    done = threading.Event()

    def run():
        clock.t = 100.6   # the mission in force
        if fast:
            agent.run_frame(KEYS.frame("sim"), encode_frame(FrameMsg(100.6, 2, "sim", POSES)))
        else:
            agent.on_frame(KEYS.frame("sim"), encode_frame(FrameMsg(100.6, 2, "sim", POSES)))
            agent.poll()
        done.set()

    runner = threading.Thread(target=run, daemon=True)
    runner.start()
    assert not done.wait(timeout=0.5) and builds == []   # the frame waits: nothing built while the thread is held
    go.set()
    runner.join(timeout=30.0)
    assert done.is_set()
    assert builds == ["prepare-held"]                      # built once, by the prepare thread
    assert agent.state.mission_version == 3                # and the frame ran the mission


@pytest.mark.parametrize("fast", [True, False], ids=["one pass", "long way"])
def test_with_every_robot_dropped_a_frame_sends_no_command_and_the_agent_goes_on(fast):
    """Peers agree that every robot is dropped (on_failure drop): no robot is usable, so a frame answers with no
    command and no state, in one pass as the long way (before, the one pass handed None to put_cmd, which zenoh
    refuses: every agent of the fleet ended on that frame). The robot halts when its last command runs out."""
    agent, cmds, states, clock = make_agent()
    agent.on_message("mission", KEYS.mission, encode_mission(dataclasses.replace(MISSION, version=2,
                                                                                 on_failure="drop")))
    for seq in range(1, 4):
        clock.t = 100.0 + seq / 30
        agent.run_frame(KEYS.frame("sim"), encode_frame(FrameMsg(clock.t, seq, "sim", POSES)))
    assert len(cmds) == 3
    agent.state = dataclasses.replace(agent.state, phase=SyncPhase.RESYNCING)
    all_dropped = HealthMsg(t=clock.t, seq=3, mission=2, failed=("r1", "r2", "r3"), dropped=("r1", "r2", "r3"),
                            since=())
    assert agent.on_health(KEYS.peer_health("r2"), encode_health(all_dropped), timers=False)
    clock.t += 1 / 30
    payload = encode_frame(FrameMsg(clock.t, 4, "sim", POSES))
    if fast:
        assert agent.fast_frame(KEYS.frame("sim"), payload)   # the one pass ran it
    else:
        agent.on_frame(KEYS.frame("sim"), payload, wake=False)
        agent.poll()
    assert len(cmds) == 3 and len(states) == 3 and agent.rejections.count == 0
    decode_cmd(agent.stop_command())   # and it still stops cleanly
