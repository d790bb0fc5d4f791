"""The agent step in one call into the core (vs_agent_step) against the numpy glue of vsfleet.step, bit for bit.

agent_step runs the per-frame part of a frame in the core whenever it can (the compiled implementation, no
structures shared between agents); offline runs that share structures between agents take the numpy glue. Both
must decide the same: every command sent, every robot's truth, every decision and every shape, on the same
frames. The scenarios cover the failure policies, the four controllers, a room with bodies (the safety filter,
the assembly tie-break), a thin wall threaded beside it, a goal walled in, reshaping, and gaps in the frames (past ttl and past the resync gap).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

import vsfleet.agentcore as agentcore
import vsfleet.step as step
from vsfleet.control import Precision
from vsfleet.frames import Frame
from vsfleet.simfleet.offline import run_offline
from vsfleet.step import AgentState, StepConfig, agent_step
from vsfleet.zglue.scenario_file import load_scenario

from test_room import room_4, thin_wall, triangle_in_a_room, walled_in

ROOT = Path(__file__).resolve().parent.parent


def both(scenario, seconds: float, **kw):
    """The same run twice: the numpy glue (structures shared between the agents) and the core (not shared)."""
    glue = run_offline(scenario, seconds, share_structures=True, **kw)
    core = run_offline(scenario, seconds, share_structures=False, **kw)
    return glue, core


def assert_same(glue, core) -> None:
    assert np.array_equal(glue.commands_m_s, core.commands_m_s)
    assert np.array_equal(glue.positions_m, core.positions_m)
    assert np.array_equal(glue.deviations_m, core.deviations_m, equal_nan=True)
    assert glue.decisions == core.decisions
    assert glue.shapes == core.shapes
    assert glue.t_goal_s == core.t_goal_s


@pytest.mark.parametrize("on_failure", ["hold", "drop", "rejoin"])
def test_a_halted_robot_under_each_policy(on_failure):
    sc = load_scenario(ROOT / "scenarios" / "paper-failure.toml")
    sc = dataclasses.replace(sc, mission=dataclasses.replace(sc.mission, on_failure=on_failure))
    glue, core = both(sc, 14.0, seed=2, stop_at_goal=False)
    assert any(glue.decisions.values())          # the halted robot was decided on
    assert_same(glue, core)


@pytest.mark.parametrize("controller", ["turn_then_go", "arc", "tracking", "precision"])
def test_every_controller(controller):
    sc = load_scenario(ROOT / "scenarios" / "paper-triangle.toml")
    glue, core = both(sc, 4.0, seed=3, controller=controller)
    assert_same(glue, core)


def test_room_4_threaded_close_to_its_wall_without_a_word_in_core_and_glue_alike():
    """bench/room.py's room 4: the structure threads a thin wall's gap close to the wall, its fitted pose falling
    between lattice states beside it (tests/test_room.py); until 2026-12-05 every agent said 'blocked' there."""
    glue, core = both(room_4(), 20.0, seed=4)
    assert all(ds == [] for ds in glue.decisions.values()), glue.decisions
    assert_same(glue, core)


def test_a_goal_walled_in_blocked_in_core_and_glue_alike():
    """A goal ringed with pillars: every agent says 'blocked' (the field's verdict) on the same frame, in the core and
    in the glue (tests/test_room.py)."""
    glue, core = both(walled_in(), 3.0, seed=1)
    assert all([d.kind for d in ds] == ["blocked"] for ds in glue.decisions.values()), glue.decisions
    assert_same(glue, core)
    for run in (glue, core):   # the reason on the wire: the field's own verdict, no way
        assert all([e.why for e in evs] == ["no_path"] for evs in run.events.values()), run.events


def test_a_room_threaded_with_the_clearance_barrier_at_work():
    """The thin wall's 0.52 m gap with the triangle turned 0.5 rad, threaded: the barrier changes the twist on
    the way (tests/test_room.py)."""
    glue, core = both(triangle_in_a_room(thin_wall(0.52), phi_rad=0.5), 20.0, seed=1)
    assert_same(glue, core)


def test_a_shuffled_crowd_goes_round_itself():
    from bench.crowd import crowd_doc
    from vsfleet.scenario import scenario_from_dict

    sc = scenario_from_dict(crowd_doc(10, 3, 6.0), name="crowd-10-shuffled")
    glue, core = both(sc, 6.0, seed=3, stop_at_goal=False)
    assert_same(glue, core)


def test_a_shuffled_crowd_past_its_first_priority_draws_in_core_and_glue_alike(monkeypatch):
    """10 robots, seed 6, for 25 s: the tie-break's priorities are drawn afresh at 10 s and 20 s of the mission, in
    the core's step (vs_agent.c) and the glue alike. The draws decide here: a glue that passed every frame's draw as 0
    (the mission's age lost) runs otherwise."""
    from bench.crowd import crowd_doc
    from vsfleet import _core
    from vsfleet.scenario import scenario_from_dict

    sc = scenario_from_dict(crowd_doc(10, 6, 25.0), name="crowd-10-seed-6")
    glue, core = both(sc, 25.0, seed=6, stop_at_goal=False)
    assert_same(glue, core)
    real = _core.assembly_targets

    def ageless(*a):
        return real(*a[:6], 0.0, *a[7:])

    monkeypatch.setattr(_core, "assembly_targets", ageless)
    lost = run_offline(sc, 25.0, share_structures=True, seed=6, stop_at_goal=False)
    assert np.array_equal(lost.positions_m[:299], core.positions_m[:299])    # the same for the first 10 s
    assert not np.array_equal(lost.positions_m, core.positions_m)


def test_a_column_switch():
    sc = load_scenario(ROOT / "scenarios" / "room-column-switch.toml")
    glue, core = both(sc, 12.0, seed=1, stop_at_goal=False)
    assert any(glue.shapes.values())
    assert_same(glue, core)


def test_gaps_past_ttl_and_past_the_resync_gap_and_robots_missing():
    """One agent's frames with holes: 0.4 s (past ttl: the controller starts afresh), 1.5 s (past the resync
    gap: the failure timers restart), robots missing from some frames."""
    sc = load_scenario(ROOT / "scenarios" / "paper-failure.toml")
    mission = dataclasses.replace(sc.mission, effective_t=0.0)
    ids = mission.robot_ids
    rng = np.random.default_rng(5)
    t, frames = 0.0, []
    for k in range(240):
        t += 1.0 / 30.0 + (0.4 if k == 60 else 1.5 if k == 150 else 0.0)
        poses = {r: (float(x), float(y), float(th)) for r, (x, y, th) in
                 zip(ids, rng.normal(0.0, 0.05, (len(ids), 3)) + [(0.01 * k, 0.0, 0.0)])
                 if not (k % 17 == 0 and r == ids[1])}
        frames.append(Frame(seq=k + 1, t=t, poses=poses, complete=len(poses) == len(ids),
                            fresh=frozenset(poses), src="sim"))
    outs = {}
    for glue in (True, False):
        config = StepConfig(shared_structures={} if glue else None)
        state, got = AgentState(ids[0]), []
        for f in frames:
            state, out = agent_step(state, mission, f, f.t + 0.01, config)
            got.append((out.cmd, out.state, out.health, out.events, out.notes,
                        None if out.wheels_m_s is None else out.wheels_m_s.tobytes()))
        outs[glue] = (got, state.phase, state.ticks)
    assert outs[True] == outs[False]
    notes = [n.text for got in outs[True][0] for n in got[4]]
    assert any("restarting failure timers" in n for n in notes)


def test_the_core_step_runs_when_it_can_and_the_glue_otherwise(monkeypatch):
    """agent_step takes the core for the compiled implementation without shared structures (the agent process)."""
    calls = []
    real = agentcore._frame_in_core
    monkeypatch.setattr(agentcore, "_frame_in_core", lambda *a: calls.append(1) or real(*a))
    sc = load_scenario(ROOT / "scenarios" / "paper-triangle.toml")
    run_offline(sc, 1.0, seed=1, share_structures=False)
    assert calls
    calls.clear()
    run_offline(sc, 1.0, seed=1, share_structures=True)
    assert not calls


# ------------------------------------------------------------------ the agent's one pass, payload to payload

def twin_agents(mission, keys, clock: list) -> tuple[dict, dict]:
    """Two agents of the mission's first robot on one clock (clock[0]), holding the mission: ({True: the one that
    runs frames in one pass when it can, False: the one that never does}, {the same: (commands, states, events)})."""
    from vsfleet.agent.main import Agent
    from vsfleet.wire import encode_mission

    out = {True: ([], [], []), False: ([], [], [])}
    agents = {}
    for fast in (True, False):
        cmds, states, events = out[fast]
        agents[fast] = Agent(mission.robot_ids[0], keys, cmds.append, states.append, clock=lambda: clock[0],
                             put_event=events.append)
        agents[fast].on_mission(keys.mission, encode_mission(mission))
    return agents, out


def test_the_agents_one_pass_sends_the_bytes_of_the_long_way_through_a_stream_that_leaves_it_and_comes_back():
    """Two agents on the same payloads at the same clock: one runs frames in one pass when it can (fast_frame, as
    its zenoh callback does), the other always the long way (decode, merger, agent_step, wire.encode). The stream
    leaves the common case and comes back: the first frames, a frame without one robot, a stale frame, a frame
    from the future, a repeated frame, a hostile payload, a gap past ttl, a second tracker source for a while, and
    a mission update. Every command and state payload must be the same bytes, and so must the events."""
    from vsfleet.wire import FrameMsg, Keys, encode_frame, encode_mission

    keys = Keys("demo")
    sc = load_scenario(ROOT / "scenarios" / "paper-failure.toml")
    mission = dataclasses.replace(sc.mission, effective_t=0.0, version=1)
    ids = mission.robot_ids
    clock = [0.0]
    agents, out = twin_agents(mission, keys, clock)
    rng = np.random.default_rng(9)
    base = np.array([mission.spec(r).p for r in ids])
    ran_fast = 0
    t = 0.0
    for k in range(420):
        t += 1.0 / 30.0 + (0.5 if k == 200 else 0.0)
        xy = base + (0.002 * k, 0.0) + rng.normal(0.0, 0.001, base.shape)
        poses = {r: (float(x), float(y), float(rng.normal(0.0, 0.01))) for r, (x, y) in zip(ids, xy)}
        if k % 50 == 7:
            poses.pop(ids[1])                                     # one robot missing
        src = "cam2" if 300 <= k < 320 and k % 2 else "sim"      # a second source for a while
        seq = k + 1
        frame_t = t + (5.0 if k == 90 else -2.0 if k == 91 else 0.0)   # from the future, then stale
        payload = encode_frame(FrameMsg(frame_t, seq, src, poses))
        if k == 120:
            payload = payload[:-3]                               # hostile: cut short
        if k == 350:
            for fast in (True, False):                           # a mission update, effective at once
                agents[fast].on_mission(keys.mission, encode_mission(dataclasses.replace(mission, version=2,
                                                                                            speed_max=0.05)))
        clock[0] = t + 0.004
        repeats = 2 if k == 150 else 1                           # the same payload twice
        for _ in range(repeats):
            for fast, agent in agents.items():
                key = keys.frame(src)
                if fast and agent.fast_frame(key, payload):
                    ran_fast += 1
                    continue
                agent.on_frame(key, payload, wake=False)
                agent.poll()
        clock[0] = t + 0.04                                     # a deadline passes (a second source's frame)
        for agent in agents.values():
            agent.poll()
    assert out[True][0] == out[False][0]
    assert out[True][1] == out[False][1]
    assert out[True][2] == out[False][2]
    assert 360 < ran_fast < 420 and len(out[True][0]) > 380   # back to one pass once the second source is quiet
    assert agents[True].state.ticks == agents[False].state.ticks


def test_the_binding_refuses_a_policy_mode_or_a_shape_that_is_not_a_code():
    """Numbers the binding casts to int are checked first (a NaN or a huge double cast to int is undefined)."""
    from vsfleet import _core
    from vsfleet.errors import VsfleetValueError

    sc = load_scenario(ROOT / "scenarios" / "paper-triangle.toml")
    arrays = step.mission_arrays(sc.mission)
    args = [arrays.core, 0, 0, tuple(float(g) for g in Precision()._core), 0.0, 0.0,
            (0.0, 0.05, 1.0, 0.05, 1.0, 1.0, 0.2, 1e-4, 0.02), (0.015, 5.0, 0.0, 1 / 30), (1 / 30, 0.3, 1 / 60, 1.0, 0.0),
            False, False, arrays.ids]
    _core.agent_config(*args)
    for mode in (math.nan, 1e300, 3.0, 0.5):
        args[6] = (mode, *args[6][1:])
        with pytest.raises(VsfleetValueError):
            _core.agent_config(*args)
    args[6] = (0.0, *args[6][1:])
    config = _core.agent_config(*args)
    n = len(arrays.ids)
    state = AgentState(arrays.ids[0])
    state = step.enter_mission(state, sc.mission, arrays.policy, StepConfig())
    kernel = agentcore.agent_kernel(agentcore.core_mission_of(sc.mission), sc.mission, arrays.ids[0], step.mission_controller(None), StepConfig())
    _, arrays_in, scalars = agentcore._core_inputs(kernel, state, step.mission_controller(None), n)
    pose = np.zeros((n, 3))
    seen = np.ones(n, dtype=bool)
    for shape in (math.nan, -1.0, 1e300):
        scalars[agentcore.SCALAR_AT["shape"]] = shape
        with pytest.raises(VsfleetValueError):
            _core.agent_step(config, arrays_in, scalars, pose, seen, seen, 0.0, np.empty(n, dtype=bool),
                             kernel.scratch_f64, kernel.scratch_u8)


def test_a_fleet_that_stood_through_a_frame_gap_is_not_stuck_in_core_and_glue_alike(monkeypatch):
    """Every agent stalls for 110 frames (3.7 s) twice on the thin wall's 0.52 m gap, the robots halting with their
    commands' ttl. The stall watch restarts with the failure timers after such a gap, as the frames not run are no
    time the structure stood still. Before (busy-loop rehearsal 68, 2026-12-05: an agent's 'stuck on the way' after
    'no frame for 2.86 s', then 'on its way again' 35 ms later), every agent here said 'blocked' on the first frame
    after the second gap (22.57 s, the watch begun before it and the barrier seen) and 'unblocked' at 23.8 s."""
    import vsfleet.agent.main as agent_main
    from vsfleet.simfleet.offline import Overload

    watched_gaps = []   # the premise: frames after a gap past the resync gap, the stall watch running before them
    real = agent_main.agent_step

    def spy(state, mission, frame, now_s, config):
        if mission is not None and frame.t - state.last_frame_t > config.resync_gap_s \
                and not math.isnan(state.stall_since_t):
            watched_gaps.append((state.robot, frame.seq))
        return real(state, mission, frame, now_s, config)

    monkeypatch.setattr(agent_main, "agent_step", spy)
    monkeypatch.setattr(agent_main, "agent_payload_step", lambda *a, **k: None)   # every frame through agent_step
    glue, core = both(triangle_in_a_room(thin_wall(0.52), phi_rad=0.5), 25.0, seed=1, stop_at_goal=False,
                      overload=Overload(stall_p=0.005, stall_frames=110, stall_seed=1))
    assert sorted({seq for _, seq in watched_gaps}) == [434, 678], watched_gaps
    assert all(ds == [] for ds in glue.decisions.values()), glue.decisions
    assert_same(glue, core)


def test_a_resync_on_a_frame_with_no_robot_usable_restarts_the_stall_watch_in_core_and_glue_alike():
    """The frame after a gap past the resync gap sees no robot (nothing to fit): both restart the stall watch there,
    and the still frames after it keep the same watch. Until review (2026-12-05) the core's answer for such a frame
    kept the watch from before the gap (agentcore took only last_frame_t back from it)."""
    from step_core_records import AGENT_RUNS, agent_run_frames

    run = next(run for run in AGENT_RUNS if run[0] == "room-wall-gap resync")
    robot, config, warm, _record = agent_run_frames(run)
    mission, last, _ = warm[-1]
    frames = [Frame(seq=last.seq + 41, t=last.t + 41 / 30.0, poses={}, complete=False, fresh=frozenset(), src="sim")]
    frames += [Frame(seq=last.seq + 42 + k, t=last.t + (42 + k) / 30.0, poses=last.poses, complete=last.complete,
                     fresh=last.fresh, src="sim") for k in range(120)]
    outs = {}
    for glue in (True, False):
        cfg = dataclasses.replace(config, shared_structures={} if glue else None)
        state = AgentState(robot)
        for m, f, now in warm:
            state, _ = agent_step(state, m, f, now, cfg)
        before = state.stall_since_t
        got = []
        for f in frames:
            state, out = agent_step(state, mission, f, f.t + 0.01, cfg)
            since = None if math.isnan(state.stall_since_t) else state.stall_since_t   # (nan != nan)
            got.append((out.events, out.notes, since, state.stall_pose, state.stalled))
        outs[glue] = got
    assert not math.isnan(before)                           # the watch ran before the gap
    assert any("no frame for" in n.text for n in outs[True][0][1])   # the first frame resynced
    assert outs[True][0][2] is None and outs[True][0][3] is None   # and restarted the watch
    assert outs[True][1][2] == frames[1].t                  # begun again on the first frame with robots
    assert outs[True] == outs[False]
