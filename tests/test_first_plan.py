"""The first plan (vsfleet.field.first_lattice, docs/planning.md "The first plan"): where a small structure's room has
a large lattice, every agent follows a coarse lattice's field for the mission's first FIRST_PLAN_S, and the room's
own field from then on. Which field a frame follows is a function of the mission and the frame's time alone: the
one pass and the long way, the core and the glue, and an agent that has not built the room's own field yet all
decide the same bits. The rule that gives a room a first plan, and the prepare thread's order."""

from __future__ import annotations

import dataclasses
import math
import threading

import numpy as np
import pytest

import vsfleet.agentstate as agentstate
from bench.plan_cost import room as plan_cost_room
from bench.room import Room, to_scenario
from vsfleet.agentstate import first_plan, in_first_plan
from vsfleet.field import (
    FIRST_MAX_STATES,
    MAX_STATES,
    build_field,
    first_lattice,
    follow_field,
    lattice_inflation_m,
    lattice_states,
    room_lattice,
)
from vsfleet.frames import Frame
from vsfleet.geometry import Pose2
from vsfleet.step import PLAN_MARGIN_M, AgentState, StepConfig, agent_step
from vsfleet.structure import FIRST_PLAN_S

from test_core_agent_step import assert_same, both, twin_agents
from test_core_step import TOLERANCE

TOL = TOLERANCE["l2"]


def triangle_room(seed: int, duration_s: float = 10.0, effective_t: float = 0.0):
    """bench/plan_cost.py's triangle among 64 pillars (room `seed`) as a scenario: its mission effective at
    effective_t, the robots at their points of the start pose."""
    tpl, rad, obs, start, goal = plan_cost_room(3, seed)
    room = Room(seed, "pillars", "triangle", tpl, rad, np.full(3, 0.16), np.ones((3, 2)), start, goal, obs)
    sc = to_scenario(room, duration_s)
    return dataclasses.replace(sc, mission=dataclasses.replace(sc.mission, effective_t=effective_t)), start


def robot_poses(mission, start) -> dict:
    c, s = math.cos(start[2]), math.sin(start[2])
    out = {}
    for r in mission.robot_ids:
        px, py = mission.spec(r).p
        out[r] = (start[0] + c * px - s * py, start[1] + s * px + c * py, start[2])
    return out


def first_inflation(tpl, rad, obs, goal, lattice: dict) -> float:
    return lattice_inflation_m(tpl, rad, PLAN_MARGIN_M, obs, goal[:2], lattice["n_headings"],
                               max_states=lattice.get("max_states", MAX_STATES))


def test_a_small_structure_in_a_large_room_has_a_first_plan_and_a_large_one_or_a_small_room_none():
    for seed in range(4):
        tpl, rad, obs, _start, goal = plan_cost_room(3, seed)
        own = room_lattice(tpl, rad, PLAN_MARGIN_M, obs, goal[:2])
        first = first_lattice(tpl, rad, PLAN_MARGIN_M, obs, goal[:2])
        # provisional, and it asks no finer lattice: where it has no way, the room's own field gives the verdict
        assert first is not None and first["provisional"] and "refine" not in first
        states = lattice_states(tpl, rad, PLAN_MARGIN_M, obs, goal[:2], first["n_headings"], FIRST_MAX_STATES)
        assert states <= FIRST_MAX_STATES
        assert lattice_states(tpl, rad, PLAN_MARGIN_M, obs, goal[:2], own["n_headings"]) > 4 * FIRST_MAX_STATES
        # built, it is the lattice the rule sized
        fld = build_field(tpl, rad, PLAN_MARGIN_M, obs, Pose2(*goal), **first, deferred=True)
        assert fld.lattice.nx * fld.lattice.ny * fld.lattice.n_headings == states and fld.provisional
        assert first_inflation(tpl, rad, obs, goal, first) <= first_inflation(tpl, rad, obs, goal, own) + 0.04
        # 30 robots among 256 pillars: a coarse lattice of theirs inflates 6 cm more than their own (12.6 cm), so
        # theirs is no coarse lattice (their own: the next test)
        tpl, rad, obs, _start, goal = plan_cost_room(30, seed)
        assert "max_states" not in first_lattice(tpl, rad, PLAN_MARGIN_M, obs, goal[:2])
    # one pillar beside the way: the room's own lattice is small already
    tpl = np.array([[0.0, 0.29], [-0.25, -0.14], [0.25, -0.14]])
    assert first_lattice(tpl, np.full(3, 0.09), PLAN_MARGIN_M, np.array([[1.0, 0.75, 0.15]]), (2.0, 1.5)) is None


def test_a_frame_follows_the_first_plan_before_first_plan_s_and_the_rooms_own_field_from_then_on():
    sc, start = triangle_room(7, effective_t=100.0)
    mission = sc.mission
    assert first_plan(mission)
    assert in_first_plan(mission, 100.0) and in_first_plan(mission, 100.0 + FIRST_PLAN_S - 1e-9)
    assert not in_first_plan(mission, 100.0 + FIRST_PLAN_S) and not in_first_plan(mission, 200.0)
    no_room = dataclasses.replace(mission, obstacles=())
    assert not first_plan(no_room) and not in_first_plan(no_room, 100.0)
    # the two fields' ways from the start differ (this room's coarse way goes round the other side: 46 % longer)
    first_cm, own_cm = agentstate.core_mission_of(mission, True), agentstate.core_mission_of(mission)
    way_first, _, _ = follow_field(first_cm.field, Pose2(*start))
    way_own, _, _ = follow_field(own_cm.field, Pose2(*start))
    assert first_cm.field.lattice.n_headings * first_cm.field.lattice.nx * first_cm.field.lattice.ny <= FIRST_MAX_STATES
    assert not np.array_equal(way_first[:5], way_own[:5])
    poses = robot_poses(mission, start)
    config = StepConfig()
    goals = {}
    for t in (100.25, 101.0):
        state = AgentState(robot=mission.robot_ids[0])
        frame = Frame(seq=1, t=t, poses=poses, complete=True, fresh=frozenset(poses), src="sim",
                      sources=frozenset({"sim"}))
        _state, out = agent_step(state, mission, frame, t + 0.01, config)
        goals[t] = out.structure.goal_pose
    # each frame's advance as the step computes it on the one field and on the other
    from vsfleet.glue import mission_arrays, structure_step, frame_arrays
    for t, first in ((100.25, True), (101.0, False)):
        arrays = mission_arrays(mission, first)
        pose, seen, _fresh = frame_arrays(arrays.ids, poses)
        none = np.zeros(len(arrays.ids), dtype=bool)
        s = structure_step(arrays, mission.metric, pose, seen, none, none, t - 100.0, config.dt_s)
        other = structure_step(mission_arrays(mission, not first), mission.metric, pose, seen, none, none,
                               t - 100.0, config.dt_s)
        assert s.goal_pose == goals[t]
        assert other.goal_pose != goals[t]


def test_core_and_glue_decide_alike_through_the_first_plan_and_after_it():
    """bench/plan_cost.py's triangle room 7 for 2.5 s: the first plan's half second, the switch, and the room's own
    field; the numpy glue (structures shared) and the core, every command, truth and decision the same bits."""
    sc, _start = triangle_room(7, duration_s=2.5)
    assert first_plan(sc.mission)
    glue, core = both(sc, 2.5, seed=7)
    assert_same(glue, core)


def test_the_reference_step_follows_the_first_plan_as_the_core_does():
    """The numpy reference (its own field builds, vsfleet.field.build_field_reference) on the same frames as the
    core, over the first plan's half second: the same advance, within tests/test_core_step.py's tolerance (the fits
    differ in their last bits), where the first plan's way and the room's own differ."""
    from vsfleet.glue import frame_arrays, mission_arrays, structure_step

    sc, start = triangle_room(7, effective_t=20.0)
    mission = sc.mission
    poses = robot_poses(mission, start)
    sc_state = sr_state = AgentState(robot=mission.robot_ids[0])
    apart = 0
    for k in range(14):
        t = 20.0 + k / 30.0
        moved = {r: (x - 0.002 * k, y + 0.001 * k, th) for r, (x, y, th) in poses.items()}
        frame = Frame(seq=k + 1, t=t, poses=moved, complete=True, fresh=frozenset(moved))
        sc_state, oc = agent_step(sc_state, mission, frame, t + 0.001, StepConfig())
        sr_state, orf = agent_step(sr_state, mission, frame, t + 0.001, StepConfig(reference=True))
        a, b = oc.structure.goal_pose, orf.structure.goal_pose
        assert abs(a.x - b.x) <= TOL and abs(a.y - b.y) <= TOL and abs(a.th - b.th) <= TOL, (k, a, b)
        assert oc.structure.blocked == orf.structure.blocked is False
        # the room's own field would advance elsewhere: the first plan's was followed
        own = mission_arrays(mission, False)
        pose, seen, _fresh = frame_arrays(own.ids, moved)
        none = np.zeros(len(own.ids), dtype=bool)
        o = structure_step(own, mission.metric, pose, seen, none, none, t - 20.0, StepConfig().dt_s).goal_pose
        apart += max(abs(o.x - a.x), abs(o.y - a.y), abs(o.th - a.th)) > 1e3 * TOL
    assert apart >= 10


def test_the_one_pass_and_the_long_way_send_the_same_bytes_across_the_first_plans_end():
    """Two agents on the same payloads (tests/test_core_agent_step.py's way): frames from before the mission takes
    effect to past its first plan. The one pass runs the first plan's frames and the room's own, and leaves to the
    long way only the frames that may fall on either side of FIRST_PLAN_S."""
    from vsfleet.wire import FrameMsg, Keys, encode_frame

    keys = Keys("demo")
    sc, start = triangle_room(7, effective_t=10.0)
    mission = dataclasses.replace(sc.mission, version=1)
    clock = [0.0]
    agents, out = twin_agents(mission, keys, clock)
    poses = robot_poses(mission, start)
    fast_t = []
    for k in range(75):
        t = 9.9 + k / 30.0
        moved = {r: (x + 0.001 * k, y, th) for r, (x, y, th) in poses.items()}
        payload = encode_frame(FrameMsg(t, k + 1, "sim", moved))
        clock[0] = t + 0.004
        for fast, agent in agents.items():
            key = keys.frame("sim")
            if fast and agent.fast_frame(key, payload):
                fast_t.append(t)
                continue
            agent.on_frame(key, payload, wake=False)
            agent.poll()
    assert out[True][0] == out[False][0] and len(out[True][0]) > 60
    assert out[True][1] == out[False][1]
    assert out[True][2] == out[False][2]
    assert any(t < 10.0 + FIRST_PLAN_S for t in fast_t) and any(t > 10.0 + FIRST_PLAN_S for t in fast_t)


def test_a_first_plan_frame_waits_for_the_first_plans_build_only_and_a_later_frame_for_the_whole(monkeypatch):
    """The prepare thread builds the first plan's arrays, then the room's own (held here until `go`): a frame of
    the first plan runs meanwhile, a frame after it waits for the room's own field, and no frame builds a field."""
    import vsfleet.agent.main as agent_main
    from vsfleet.agent.main import Agent, PrepareThread
    from vsfleet.wire import FrameMsg, Keys, encode_frame, encode_mission

    keys = Keys("demo")
    sc, start = triangle_room(5, effective_t=50.0)
    mission = dataclasses.replace(sc.mission, version=4)
    go, builds = threading.Event(), []
    core_mission_of, build = agentstate.core_mission_of, agentstate.build_field_deferred

    def held(m, first=False):   # the prepare thread's builds: the room's own held until go
        if not first:
            go.wait(timeout=30.0)
        return core_mission_of(m, first)

    def counted(*a, **k):
        builds.append((threading.current_thread().name, k.get("max_states", MAX_STATES)))
        return build(*a, **k)

    monkeypatch.setattr(agent_main, "core_mission_of", held)
    monkeypatch.setattr(agentstate, "build_field_deferred", counted)
    threads = []

    def prepare(m):
        th = PrepareThread(m)
        th.name = "prepare-held"
        th.start()
        threads.append(th)
        return th

    cmds, clock = [], [50.0]
    agent = Agent(mission.robot_ids[0], keys, cmds.append, lambda b: None, clock=lambda: clock[0], prepare=prepare)
    try:
        agent.on_mission(keys.mission, encode_mission(mission))
        assert threads[0].first_built.wait(timeout=30.0)
        poses = robot_poses(mission, start)
        done = threading.Event()

        def run(t):
            clock[0] = t + 0.004
            agent.on_frame(keys.frame("sim"), encode_frame(FrameMsg(t, int(t * 30), "sim", poses)), wake=False)
            agent.poll()
            done.set()

        run(50.25)                          # the first plan's: runs while the room's own field is held
        assert len(cmds) == 1 and threads[0].is_alive()
        done.clear()

        def run_fast(t):   # the frame callback's way: one pass when it can (fast_frame)
            clock[0] = t + 0.004
            agent.run_frame(keys.frame("sim"), encode_frame(FrameMsg(t, int(t * 30), "sim", poses)))
            done.set()

        later = threading.Thread(target=run_fast, args=(51.0,), daemon=True)
        later.start()
        assert not done.wait(timeout=0.5)   # after it: waits for the room's own field
        go.set()
        later.join(timeout=30.0)
        assert done.is_set() and len(cmds) == 2
    finally:
        go.set()
    # two builds, both on the prepare thread: the first plan's lattice, then the room's own
    assert builds == [("prepare-held", FIRST_MAX_STATES), ("prepare-held", MAX_STATES)]


def test_the_one_pass_bounds_hold_only_frames_of_the_side_they_name():
    """first_plan_bounds: every frame time agent_frame would run within the bounds given (its own sums) falls on the
    side named, down to the last bit at the first plan's end; and a frame of either side can be run in one pass."""
    from vsfleet.agentcore import first_plan_bounds

    rng = np.random.default_rng(11)
    sides = set()
    for _ in range(4000):
        eff = float(rng.choice([0.0, 1.7, 1234.5678, 1.7e9 + rng.uniform(0, 1)]))
        end = eff + FIRST_PLAN_S
        now = end + float(rng.choice([rng.uniform(-2.0, 2.0), rng.uniform(-1e-6, 1e-6), 0.0]))
        future, stale = float(rng.choice([1.0, 0.05, 0.0])), float(rng.choice([0.5, 0.1]))
        side, f, s = first_plan_bounds(eff, now, future, stale)
        assert f <= future and s <= stale
        if side is None:
            continue
        sides.add(side)
        for t in (now + f, now - s, now, end, np.nextafter(end, -np.inf), np.nextafter(end, np.inf),
                  float(rng.uniform(now - s, now + f))):
            t = float(t)
            if t > now + f or t < now - s:
                continue   # agent_frame leaves it to the long way
            assert (t - eff < FIRST_PLAN_S) == side, (eff, now, future, stale, t)
    assert sides == {True, False}


def test_a_large_structures_first_plan_is_its_own_lattice_provisional_and_its_room_field_builds_the_finer_one():
    """30 robots among 256 pillars (bench/plan_cost.py): their own lattice asks a finer one, so their first plan is
    their own lattice without it, provisional; the room's own field (followed from FIRST_PLAN_S on) has its finer
    lattice built with it, before any frame asks. The triangle's room field leaves its finer lattice for later."""
    for seed in range(3):
        tpl, rad, obs, _start, goal = plan_cost_room(30, seed)
        own = room_lattice(tpl, rad, PLAN_MARGIN_M, obs, goal[:2])
        assert own["refine"] is not None
        assert first_lattice(tpl, rad, PLAN_MARGIN_M, obs, goal[:2]) == {"n_headings": own["n_headings"],
                                                                          "provisional": True}
    sc, _ = thirty_room(0)
    first_cm, own_cm = agentstate.core_mission_of(sc.mission, True), agentstate.core_mission_of(sc.mission)
    assert first_cm.field.provisional and first_cm.field.refine is None and not own_cm.field.provisional
    assert own_cm.field.refined
    sc, _ = triangle_room(3)
    assert not agentstate.core_mission_of(sc.mission).field.refined


def thirty_room(seed: int, effective_t: float = 0.0):
    """bench/plan_cost.py's 30 robots among 256 pillars (room `seed`) as a scenario (triangle_room's way)."""
    tpl, rad, obs, start, goal = plan_cost_room(30, seed)
    room = Room(seed, "pillars", "grid 5x6", tpl, rad, np.full(30, 0.16), np.ones((30, 2)), start, goal, obs)
    sc = to_scenario(room, 10.0)
    return dataclasses.replace(sc, mission=dataclasses.replace(sc.mission, effective_t=effective_t)), start


def test_where_the_provisional_first_plan_has_no_way_the_structure_holds_and_the_verdict_comes_after_it():
    """bench/plan_cost.py's 30-robot room 0 has no way (nor on the finer lattice): before FIRST_PLAN_S the structure
    holds at its fitted pose (no move, not blocked, not at the goal, no event); from then on the room's own field
    says blocked, and the agent publishes it once."""
    sc, start = thirty_room(0, effective_t=30.0)
    mission = sc.mission
    poses = robot_poses(mission, start)
    state = AgentState(robot=mission.robot_ids[0])
    seen = []
    for k in range(30):   # 1 s at 30 Hz
        t = 30.0 + k / 30.0
        frame = Frame(seq=k + 1, t=t, poses=poses, complete=True, fresh=frozenset(poses))
        state, out = agent_step(state, mission, frame, t + 0.001, StepConfig())
        s = out.structure
        seen.append((t - 30.0 < FIRST_PLAN_S, s.blocked, s.at_goal, [e.kind for e in out.events]))
        if t - 30.0 < FIRST_PLAN_S:
            assert not s.blocked and not s.at_goal and out.events == ()
            assert (s.twist.vx_m_s, s.twist.vy_m_s, s.twist.w_rad_s) == (0.0, 0.0, 0.0)
            assert s.goal_pose == s.fit_pose
        else:
            assert s.blocked and not s.at_goal
    kinds = [k for *_, ks in seen for k in ks]
    assert kinds == ["blocked"]


def test_the_reference_holds_where_the_core_does(monkeypatch):
    """A provisional first plan in a small room (tests/test_room.py's goal walled in; the rule patched to give it
    one): the numpy reference and the core hold alike before FIRST_PLAN_S, and say blocked alike after it."""
    import vsfleet.structure as structure
    from test_room import walled_in

    def provisional(tpl, rad, margin, obs, goal_xy):
        return {"n_headings": room_lattice(tpl, rad, margin, obs, goal_xy)["n_headings"], "provisional": True}

    monkeypatch.setattr(structure, "first_lattice", provisional)
    structure._room_field.cache_clear()
    agentstate._FIRST.clear()
    try:
        sc = walled_in()
        mission = dataclasses.replace(sc.mission, effective_t=5.0, version=77)
        assert first_plan(mission)
        poses = {r.robot: tuple(r.start) for r in sc.robots}
        sc_state = sr_state = AgentState(robot=mission.robot_ids[0])
        for t in (5.1, 5.3, 5.6, 5.9):
            frame = Frame(seq=int(t * 30), t=t, poses=poses, complete=True, fresh=frozenset(poses))
            sc_state, oc = agent_step(sc_state, mission, frame, t + 0.001, StepConfig())
            sr_state, orf = agent_step(sr_state, mission, frame, t + 0.001, StepConfig(reference=True))
            a, b = oc.structure, orf.structure
            assert a.blocked == b.blocked == (t - 5.0 >= FIRST_PLAN_S) and a.at_goal == b.at_goal is False
            assert abs(a.goal_pose.x - b.goal_pose.x) <= TOL and abs(a.goal_pose.y - b.goal_pose.y) <= TOL
            if not a.blocked:
                assert a.goal_pose == a.fit_pose
    finally:
        structure._room_field.cache_clear()
        agentstate._FIRST.clear()


@pytest.mark.parametrize("glue", [False, True], ids=["core", "glue"])
def test_a_mission_that_follows_a_blocked_one_stays_blocked_through_its_provisional_first_plan(glue):
    """bench/plan_cost.py's 30-robot room 0 (no way): v1 says blocked half a second in; v2 (the same room, another
    speed) takes effect at 31.5 s, its first plan provisional. Its held frames give no verdict, so no `unblocked` and
    no second `blocked`: one event in all, in the core's agent step and the numpy glue alike (a review found the
    pair, 2026-12-07)."""
    sc, start = thirty_room(0, effective_t=30.0)
    v1 = dataclasses.replace(sc.mission, version=1)
    v2 = dataclasses.replace(v1, version=2, effective_t=31.5, speed_max=0.5 * v1.speed_max)
    assert first_plan(v2)
    poses = robot_poses(v1, start)
    config = StepConfig(shared_structures={}) if glue else StepConfig()
    state, kinds, held = AgentState(robot=v1.robot_ids[0]), [], 0
    for k in range(75):   # 2.5 s at 30 Hz
        t = 30.0 + k / 30.0
        mission = v2 if t >= v2.effective_t else v1
        frame = Frame(seq=k + 1, t=t, poses=poses, complete=True, fresh=frozenset(poses))
        state, out = agent_step(state, mission, frame, t + 0.001, config)
        kinds += [(round(t, 3), e.kind) for e in out.events]
        held += bool(glue and out.structure.held)
        assert out.structure.blocked == (not in_first_plan(mission, t))
    assert [kind for _t, kind in kinds] == ["blocked"] and kinds[0][0] == 30.5, kinds
    assert held == (30 if glue else 0)   # v1's and v2's first half seconds held (the glue's structure says so)
