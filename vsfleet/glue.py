"""The agent step's numpy glue: ``decide_in_numpy`` runs a frame from its poses on with numpy arrays around the
kernels of the implementation a StepConfig selects (vsfleet.impl: the compiled core's one by one, or the numpy
reference), and the mission's arrays it reads (``mission_arrays``).

It is the readable account of what the core's agent step (vs_agent_step, vsfleet.agentcore) does in one call,
held equal to it bit for bit (tests/test_core_agent_step.py, tests/test_core_agent_golden.py), and it runs the
frames the core's agent step does not: the reference, a controller the core lacks, an offline run that shares
structures between its agents. The agent process never imports it (issue 29: it does not load numpy).

Robots are rows of numpy arrays in the mission's sorted id order; a robot's id
turns into its row once, when the frame's poses are read (``frame_arrays``).
The structure part (``structure_step``) depends only on (mission, frame, the
robots dropped), so duplicated agents that saw the same frames compute
bit-identical structure poses: the paper's "distributed duplication". The
controller runs on every robot at once, so the predicted commands the failure
rule judges by are the very commands each robot's own agent sends.
"""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, field, replace
from functools import cached_property
from itertools import chain, repeat
from typing import Mapping

from .lazy import lazy_numpy
from .advance import Goal, GoalPath, GoalPose, StructureLimits
from .agentstate import (FAILURE_FIELDS, PRECISION_STATE_FIELDS, STALL_MOVE_M, STALL_S, STALL_TURN_RAD, AgentState,
                         Note, StepConfig, StepOutput, SyncPhase, _evolve, answer, blocked_note, blocked_why,
                         core_mission_of, health_of, in_first_plan, mission_shape_points, pack_mission,
                         safety_params, shape_name, used_ids)
from .control import ControlInput, PrecisionState
from .envelope import Envelope, Envelopes
from .failure import FailurePolicy, FailureState, restart_timers
from .frames import Frame
from .geometry import Pose2, angle_diff
from .field import Field, follow_field
from .impl import Impl, core as core_impl
from .structure import MISSION_ARGS, Structure, make_structure
from .wire import CmdMsg, EventMsg, HealthMsg, Mission, StateMsg

np = lazy_numpy(globals())   # numpy on first use: the agent process never loads it (vsfleet.lazy)



def mission_envelopes(mission: Mission) -> list[Envelope]:
    return [Envelope(s.wheel_base, s.wheel_speed_max, s.wheel_accel_max) for _, s in mission.robots]


def mission_envelope_arrays(mission: Mission) -> Envelopes:
    """The mission's envelopes as (n,) arrays, in its sorted robot order."""
    return Envelopes.of(mission_envelopes(mission))


def mission_template(mission: Mission) -> np.ndarray:
    """Template points (n, 2) [m; structure frame], in the mission's sorted robot order."""
    return np.array([s.p for _, s in mission.robots], dtype=float)


def mission_shapes(mission: Mission) -> tuple[tuple[str, np.ndarray], ...]:
    """vsfleet.agentcore.mission_shape_points with each shape's points as an (n, 2) array [m; structure frame]."""
    return tuple((name, np.array(pts, dtype=float)) for name, pts in mission_shape_points(mission))


@dataclass(frozen=True)
class MissionArrays:
    """What a mission fixes for every frame, as arrays over its robots (sorted id order)."""

    ids: tuple[str, ...]
    index: Mapping[str, int]
    template: np.ndarray          # (n, 2) [m; structure frame]
    envelopes: Envelopes
    goal: Goal
    limits: StructureLimits
    policy: FailurePolicy          # the failure rule's mode and thresholds
    radii: np.ndarray = field(default_factory=lambda: np.zeros(0))      # (n,) body radii [m] (0: a point)
    obstacles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (k, 3) (x, y, r) [m; world]
    core: tuple = ()
    field: Field | None = None     # the room's navigation function (vsfleet.field), built once per mission
    # reshape: the shapes beyond the template, in the order tried ((name, points (n, 2)), mission_shapes), and
    # each one's field (built once per mission; none without the template's field)
    shapes: tuple = ()
    shape_fields: tuple = ()
    first: bool = False           # the fields are the first plan's (vsfleet.field.first_lattice)

    @cached_property
    def room(self) -> bool:
        """The mission knows robot bodies or obstacles: commands go through the safety filter (once per mission)."""
        return bool(self.radii.any()) or len(self.obstacles) > 0


def core_mission(metric: str, template: np.ndarray, envelopes: Envelopes, goal: Goal,
                 limits: StructureLimits, radii=None, obstacles=(), field: Field | None = None,
                 shapes: tuple = (), shape_fields: tuple = ()) -> tuple:
    """The mission's constants as the compiled core takes them (vsfleet.agentcore.pack_mission), in structure_step's
    argument order (vsfleet.structure.MISSION_ARGS), its buffers read as numpy arrays (the template (n, 2))."""
    n = len(template)
    packed = pack_mission(metric, template, envelopes.wheel_base_m, envelopes.wheel_speed_max_m_s,
                          envelopes.wheel_accel_max_m_s2, goal, limits, [0.0] * n if radii is None else radii,
                          obstacles, field, shapes, shape_fields)
    return tuple(np.frombuffer(v).reshape(n, 2) if a == "template_xy"
                 else np.frombuffer(v) if isinstance(v, (array, memoryview))
                 else v for a, v in zip(MISSION_ARGS, packed))


_ARRAYS: dict[tuple[int, bool], tuple[Mission, MissionArrays]] = {}


def mission_arrays(mission: Mission, first: bool = False) -> MissionArrays:
    """The arrays of a mission, built once per mission object (memoised: a pure function). first: with its first
    plan's fields (vsfleet.agentstate.core_mission_of), for the frames that follow it (in_first_plan)."""
    hit = _ARRAYS.get((id(mission), first))
    if hit is not None and hit[0] is mission:
        return hit[1]
    cm = core_mission_of(mission, first)   # the packed constants and the room's fields, shared by equal missions
    template, envelopes = mission_template(mission), mission_envelope_arrays(mission)
    limits = cm.limits
    arrays = MissionArrays(ids=cm.ids, index=cm.index, template=template, envelopes=envelopes, goal=cm.goal,
                           limits=limits, policy=cm.policy, radii=np.array(mission.radii, dtype=float),
                           obstacles=np.array(mission.obstacles, dtype=float).reshape(-1, 3), core=cm.core,
                           field=cm.field, shapes=mission_shapes(mission) if cm.field is not None else (),
                           shape_fields=cm.shape_fields, first=first)
    if len(_ARRAYS) >= 16:
        _ARRAYS.clear()
    _ARRAYS[(id(mission), first)] = (mission, arrays)
    return arrays


_UNSEEN = (math.nan, math.nan, math.nan)


def frame_arrays(ids: tuple[str, ...], poses: Mapping[str, tuple[float, float, float]],
                 fresh: frozenset[str] = frozenset()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pose_world (n, 3) [m, m, rad], seen (n,), fresh (n,)) of a frame's poses; NaN rows unseen."""
    n = len(ids)
    pose = np.fromiter(chain.from_iterable(map(poses.get, ids, repeat(_UNSEEN))), dtype=float, count=3 * n)
    pose = pose.reshape(n, 3)
    seen = ~np.isnan(pose[:, 0])
    if fresh.issuperset(ids):   # every robot listed by the frame itself: the common case
        return pose, seen, seen.copy()
    return pose, seen, seen & np.fromiter(map(fresh.__contains__, ids), dtype=bool, count=n)


def structure_step(arrays: MissionArrays, metric: str, pose_world: np.ndarray, seen: np.ndarray,
                   excluded: np.ndarray, judged_apart: np.ndarray, elapsed_s: float, dt_s: float,
                   impl: Impl = core_impl) -> Structure | None:
    """Fit the structure to the robots seen and not excluded, advance it one dt_s toward the goal, in the
    implementation ``impl`` (vsfleet.impl: the compiled core, or the numpy reference for tests).

    Robots absent or excluded are left out of the fit but still bound the advance. The
    deviations are measured on the structure fitted without the ``judged_apart`` robots (when two
    or more others remain): under hold a failed robot bends the structure the robots follow, and
    the healthy robots it bends must not look non-compliant for it. None if no robot is usable.
    """
    return impl.structure_step(arrays, metric, pose_world, seen, excluded, judged_apart, elapsed_s, dt_s)

def planned_way(mission: Mission, pose: Pose2, cap: int = 100_000,
                shape: int = 0) -> tuple[np.ndarray, bool] | None:
    """The whole way the room's field gives from a structure pose [m, rad; world] to the goal (or the closest
    safe pose: blocked True), as (k, 3) poses; None without a field (no obstacles, or a twist goal). For tools
    that draw the plan (vsfleet plot, the Foxglove scene); agents follow 2 m of it a frame. shape: the
    structure's (a state's ``shape``: 0 the template, k the mission's k-th reshape), whose field it follows."""
    arrays = mission_arrays(mission)
    field = arrays.field
    if 0 < shape <= len(arrays.shape_fields):
        field = arrays.shape_fields[shape - 1]
    if field is None:
        return None
    way, blocked, _left = follow_field(field, pose, path_m=1e9, cap=cap)
    return way, blocked


def _shared_structure_step(shared: dict | None, mission: Mission, arrays: MissionArrays, pose_world: np.ndarray,
                           seen: np.ndarray, excluded: np.ndarray, judged_apart: np.ndarray, elapsed_s: float,
                           dt_s: float, impl: Impl = core_impl) -> Structure | None:
    """structure_step, taken from ``shared`` when another agent of an offline run computed it on the
    very same inputs (an equal mission, whose arrays these are, and the arrays' bytes, NaN rows of
    unseen robots included); its arrays are then read-only, as they are shared."""
    metric = mission.metric
    if shared is None:
        return structure_step(arrays, metric, pose_world, seen, excluded, judged_apart, elapsed_s, dt_s, impl)
    key = (mission, pose_world.tobytes(), seen.tobytes(), excluded.tobytes(), judged_apart.tobytes(),
           elapsed_s, dt_s, impl.name)
    if key in shared:
        return shared[key]
    s = structure_step(arrays, metric, pose_world, seen, excluded, judged_apart, elapsed_s, dt_s, impl)
    if s is not None:
        for a in (s.used, s.points_now, s.points_next, s.deviations_m):
            a.flags.writeable = False
    if len(shared) >= 64:  # the newest frames only: agents of one run step the same frame in turn
        shared.clear()
    shared[key] = s
    return s


def expected_steps_m(pose_world: np.ndarray, wheels_m_s: np.ndarray, dt_s: float,
                     wheel_base_m: np.ndarray, impl: Impl = core_impl) -> np.ndarray:
    """Displacement (n, 2) [m; world] each robot makes in dt_s at its command (paper eqs 17-18)."""
    return impl.integrate_arcs(pose_world, wheels_m_s, dt_s, wheel_base_m)[:, :2] - pose_world[:, :2]


# ---------------------------------------------------------------- the agent step


def numpy_state(state: AgentState) -> AgentState:
    """The state with its arrays read as numpy arrays (no copy: the same memory; vsfleet.buffers) for the glue."""
    if state.failure is None:
        return state
    ctrl = state.ctrl
    if isinstance(ctrl, PrecisionState) and type(ctrl.gains) is not np.ndarray:
        ctrl = PrecisionState(*(np.asarray(getattr(ctrl, k)) for k in PRECISION_STATE_FIELDS))
    failure = FailureState(*(np.asarray(getattr(state.failure, k)) for k in FAILURE_FIELDS))
    return _evolve(state, wheels_m_s=np.asarray(state.wheels_m_s), ctrl=ctrl, failure=failure)


def core_outputs(r: tuple, used, scratch_f64, wheels_m_s, n: int) -> tuple[Structure, np.ndarray]:
    """(the structure, every robot's wheels (n, 2)) of a frame the core ran (vsfleet.agentcore, StepConfig.outputs):
    r its answer, used its rows used, scratch_f64 its scratch (the poses seen, points_now, points_next, deviations,
    in this order), wheels_m_s the state's commands; copies, as the next frame overwrites them."""
    fx, fy, fth, gx, gy, gth, vx, vy, w, cost, at_goal, blocked, left_m, shape = answer(
        r, "fit_x", "fit_y", "fit_th", "goal_x", "goal_y", "goal_th", "vx_m_s", "vy_m_s", "w_rad_s", "cost", "at_goal",
        "blocked", "left_m", "shape")
    sf = np.asarray(scratch_f64)
    structure = make_structure(fx, fy, fth, gx, gy, gth, vx, vy, w, cost, at_goal, np.array(used, dtype=bool),
                               sf[3 * n:5 * n].reshape(n, 2).copy(), sf[5 * n:7 * n].reshape(n, 2).copy(),
                               sf[7 * n:8 * n].copy(), blocked, left_m, shape)
    return structure, np.array(wheels_m_s, dtype=float).reshape(n, 2)


def decide_in_numpy(state: AgentState, mission: Mission, controller, frame: Frame, config: StepConfig,
                    notes: list) -> tuple[AgentState, StepOutput]:
    """agent_step from the frame's poses on, in numpy glue around the implementation config.impl selects (the
    reference, or the core's kernels one by one): for a controller the core's agent step does not run, for offline
    runs that share structures, and as the readable account of what vs_agent_step does (the same bits)."""
    arrays = mission_arrays(mission, in_first_plan(mission, frame.t))
    policy = arrays.policy
    n = len(arrays.ids)
    state = numpy_state(state)
    wheels_prev, ctrl = state.wheels_m_s, state.ctrl
    if frame.t - state.last_cmd_t > config.ttl_s or ctrl is None:
        # a gap longer than ttl: every robot has halted since the last commands
        wheels_prev, ctrl = np.zeros((n, 2)), controller.initial(n)
    failure = state.failure
    if frame.t - state.last_frame_t > config.resync_gap_s and state.last_frame_t > -math.inf:
        # this agent (or the whole fleet) saw no frame for a while: restart the failure timers and
        # the motion window, and ask the peers which robots they failed or dropped
        notes.append(Note("warning", f"frame {frame.seq}: no frame for {frame.t - state.last_frame_t:.2f} s; "
                                     "restarting failure timers and asking peers for their failure state"))
        failure = restart_timers(failure)
        state = replace(state, phase=SyncPhase.RESYNCING)
        if not state.stalled:   # and the stall watch: frames not run are no time the structure stood still
            state = replace(state, stall_since_t=math.nan, stall_pose=None)
    state = _evolve(state, last_frame_t=frame.t, failure=failure)

    pose, seen, fresh = frame_arrays(arrays.ids, frame.poses, frame.fresh)
    own = arrays.index[state.robot]
    hold = policy.mode == "hold"
    judged_apart = failure.failed & ~failure.dropped if hold else np.zeros(n, dtype=bool)
    s = _shared_structure_step(config.shared_structures, mission, arrays, pose, seen, failure.dropped,
                               judged_apart, frame.t - mission.effective_t, config.dt_s, config.impl)
    if s is None:
        return state, StepOutput(notes=tuple(notes))
    # every robot's command, as its own agent computes it: seen, and not dropped (rejoin: driven on)
    active = seen & (~failure.dropped if policy.mode != "rejoin" else True)
    pose_seen = np.where(seen[:, None], pose, 0.0)   # unseen rows zeroed: the controller, kinematics, failure rule
    points_now, points_next, detoured = s.points_now, s.points_next, None
    if arrays.radii.any():   # bodies: the assembly tie-break (robots barred on their way go round)
        points_now, points_next, detoured = config.impl.assembly_targets(
            arrays.radii, pose_seen, seen & active, s.points_now, s.points_next, safety_params(config.dt_s).margin_m,
            frame.t - mission.effective_t)
    ctrl, wheels = config.impl.control(controller, ctrl, ControlInput(
        pose_world=pose_seen, point_now_world=points_now,
        point_next_world=points_next, wheels_prev_m_s=wheels_prev, dt_s=config.dt_s, age_s=config.age_s,
        envelopes=arrays.envelopes, active=active))
    wheels = np.where(active[:, None], wheels, 0.0)
    filtered = False
    held = None      # the robots whose command the safety filter cut: on their way (the failure rule)
    if arrays.room:  # bodies or obstacles: every robot's command through the fleet-wide safety filter
        nominal = wheels
        wheels = _safe_wheels(arrays, pose, seen, active, wheels, wheels_prev, config)
        held = np.any(wheels != nominal, axis=1)
        filtered = bool(np.any(held))
        if detoured is not None:
            held = held | detoured                   # sent round another robot: on its way too
    vl, vr = float(wheels[own, 0]), float(wheels[own, 1])
    cmd = CmdMsg(t=frame.t, seq=frame.seq, vl=vl, vr=vr, ttl=config.ttl_s)
    state_msg = None
    if seen[own]:
        f, g = s.fit_pose, s.goal_pose
        err = _norm(float(pose[own, 0] - s.points_now[own, 0]), float(pose[own, 1] - s.points_now[own, 1]))
        state_msg = StateMsg(t=frame.t, seq=frame.seq, x=f.x, y=f.y, th=f.th, gx=g.x, gy=g.y, gth=g.th,
                             cost=s.cost, err=err, used=used_ids(arrays.ids, s.used),
                             rejected=0, complete=frame.complete, mission=mission.version, shape=s.shape)
    # the motion test takes only poses of this very frame: a pose held over from an earlier frame
    # would count as "did not move" here and double next frame, and agents that got that pose in
    # time would disagree on the frame of a decision
    moved = fresh & active
    expected = np.where(moved[:, None], expected_steps_m(pose_seen, wheels, config.dt_s,
                                                         arrays.envelopes.wheel_base_m, config.impl), 0.0)
    failure, decisions = config.impl.failure_step(policy, failure, arrays.ids, frame.t, seen=seen, fresh=fresh,
                                                  xy_world=pose_seen[:, :2],
                                                  deviations_m=s.deviations_m, expected_step_m=expected,
                                                  step_s=config.dt_s, max_gap_s=config.ttl_s, held=held)
    health = health_of(failure, arrays.ids)
    health_msg = HealthMsg(t=frame.t, seq=frame.seq, mission=mission.version, failed=tuple(sorted(health.failed)),
                           dropped=tuple(sorted(health.dropped)), since=tuple(sorted(health.since_t.items())))
    events = tuple(EventMsg(t=d.t, seq=frame.seq, robot=d.robot, kind=d.kind, dev=d.deviation_m, by=state.robot)
                   for d in decisions)
    failed_any = arrays.field is not None and bool(np.count_nonzero(failure.failed))  # (stall_state's only use)
    # a held frame (a provisional first plan with no way: vs_step.h) gives no verdict: the blocked flag and the stall
    # watch stay as they were, and no event is sent (as vs_agent.c)
    blocked = state.blocked if s.held else s.blocked
    stall_since, stall_pose, stalled = ((state.stall_since_t, state.stall_pose, state.stalled) if s.held else
                                        stall_state(state, arrays, s, filtered or s.cleared, failed_any, frame.t))
    was, now = state.blocked or state.stalled, blocked or stalled
    if now != was:  # the room: no path to the goal (stopping short) or stuck on the way, or going again
        short = s.left_m if s.blocked else _goal_distance(arrays, s.fit_pose)
        events += (EventMsg(t=frame.t, seq=frame.seq, robot=state.robot, kind="blocked" if now else "unblocked",
                            dev=short, by=state.robot, why=blocked_why(now, s.blocked)),)
        notes.append(blocked_note(frame.seq, s.blocked, now, short))
    if s.shape != state.shape:   # reshape: every agent at the same frame (a function of the frame)
        notes.append(Note("info", f"frame {frame.seq}: the structure takes {shape_name(arrays, s.shape)}"))
    notes.extend(Note("warning", f"frame {frame.seq}: robot {d.robot} {d.kind} (deviation {d.deviation_m:.3f} m, "
                                 f"on_failure={mission.on_failure})") for d in decisions)
    state = _evolve(state, wheels_m_s=wheels, ctrl=ctrl, failure=failure, health=health, last_seq=frame.seq,
                    blocked=blocked, stall_since_t=stall_since, stall_pose=stall_pose, stalled=stalled,
                    shape=s.shape, last_cmd_t=frame.t, ticks=state.ticks + 1)
    return state, StepOutput(cmd=cmd, state=state_msg, health=health_msg, events=events, notes=tuple(notes),
                             structure=s, wheels_m_s=wheels)


def stall_state(state: AgentState, arrays: MissionArrays, s: Structure, filtered: bool, failed_any: bool,
                t: float) -> tuple[float, tuple | None, bool]:
    """The stall watch of a room (its field): (stall_since_t, stall_watch, stalled) after a frame at t [s].

    Watched while the structure is neither at the goal nor blocked, no robot is failed (the failure rule
    speaks for those) and every robot used is within the failure rule's deviation of its point (so not a
    fleet still assembling). Stuck: watched for STALL_S, the fitted structure all the while within
    STALL_MOVE_M and STALL_TURN_RAD of where the watch began, and the safety filter changed some command (or the
    room's clearance barrier the structure's twist, ``filtered`` either way) on some frame of it. The plan said go,
    the filter said no: without this the fleet stood still and said
    nothing (issue 28). Going again: the structure moved more than that within STALL_S of the watch's pose; a
    structure that only crawls (less than that each STALL_S) stays stuck, the watch's pose moving on with it every
    STALL_S, so a crawl is one `blocked`, not a `blocked`/`unblocked` pair each time it crosses the threshold.
    stall_watch: (x, y, th, filter seen). A pure function of the frames run, as the failure rule is."""
    if arrays.field is None:
        return math.nan, None, False
    dev = s.deviations_m[s.used]
    watched = not s.at_goal and not s.blocked and not failed_any and dev.size > 0 and \
        float(dev.max()) < arrays.policy.fail_deviation_m
    p = s.fit_pose
    since, at, stalled = state.stall_since_t, state.stall_pose, state.stalled
    moved = at is None or (_norm(p.x - at[0], p.y - at[1]) > STALL_MOVE_M
                           or abs(angle_diff(p.th, at[2])) > STALL_TURN_RAD)
    if stalled:   # going again: moved past the thresholds within STALL_S of the watch's pose
        if not moved and t - since >= STALL_S:   # a crawl: the watch moves on with it
            return t, (p.x, p.y, p.th, at[3]), True
        return (since, at, not moved)
    if not watched:
        return math.nan, None, False
    if math.isnan(since) or moved:
        return t, (p.x, p.y, p.th, filtered), False
    at = (*at[:3], at[3] or filtered)
    return since, at, bool(at[3]) and t - since >= STALL_S


def _goal_distance(arrays: MissionArrays, pose: Pose2) -> float:
    """How far [m] a structure pose is from the mission's final goal position."""
    goal = arrays.goal
    target = goal.pose if isinstance(goal, GoalPose) else goal.waypoints[-1] if isinstance(goal, GoalPath) else None
    return 0.0 if target is None else _norm(target.x - pose.x, target.y - pose.y)


def _norm(dx: float, dy: float) -> float:
    """sqrt(dx*dx + dy*dy): + * sqrt only, as the core's vs_agent_step computes it (not math.hypot): the same bits."""
    return math.sqrt(dx * dx + dy * dy)


def _safe_wheels(arrays: MissionArrays, pose: np.ndarray, seen: np.ndarray, active: np.ndarray, wheels: np.ndarray,
                 wheels_prev: np.ndarray, config: StepConfig) -> np.ndarray:
    """Every robot's command through the safety filter (vsfleet.safety): the robots seen are its rows
    (a seen robot not driven, dropped, is a fixed disk); a robot not seen in this frame is not in it.
    Every agent filters the same commands the same way, so the failure rule predicts the filtered
    command each robot's own agent sends."""
    rows = np.flatnonzero(seen)
    if rows.size == 0:
        return wheels
    env = arrays.envelopes
    safe, _info = config.impl.safety_filter(
        np.ascontiguousarray(pose[rows]), arrays.radii[rows], np.ascontiguousarray(wheels[rows]),
        wheel_base_m=env.wheel_base_m[rows], wheel_speed_max_m_s=env.wheel_speed_max_m_s[rows],
        obstacles=arrays.obstacles, active=active[rows], wheel_accel_max_m_s2=env.wheel_accel_max_m_s2[rows],
        wheels_prev_m_s=np.ascontiguousarray(wheels_prev[rows]), params=safety_params(config.dt_s))
    out = wheels.copy()
    out[rows] = safe
    return out
