"""The agent's step as the agent process runs it: in the compiled core, with no numpy (issue 29).

``agent_step(state, mission, frame, now_s, config) -> (state, StepOutput)`` is everything an agent decides per
frame (vsfleet.step re-exports every name here; vsfleet.glue holds the readable numpy glue). What runs in an
agent process is this module's: the mission's constants packed for the core once per mission (``core_mission_of``),
the core's configuration once per mission and robot (``agent_kernel``), the state's arrays as plain buffers
(vsfleet.buffers) that the core advances in place, and one call into the core per frame (``vsfleet._core.agent_step``
from a merged frame, ``vsfleet._core.agent_frame`` from a frame's payload bytes). numpy is never loaded on this path
(tests/integration/test_agent_numpy_free.py). A frame the core does not run (the reference implementation, a controller the core
does not have, an offline run that shares structures between its agents) goes to vsfleet.glue's numpy glue,
imported then: the same decisions, bit for bit (tests/test_core_agent_step.py).
"""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, replace
from itertools import chain, repeat
from typing import Mapping

from . import _core
from .agentstate import (FAILURE_FIELDS, PRECISION_STATE_FIELDS, AgentState, Controller, CoreMission, Note, answer,
                         StepConfig, StepOutput, SyncPhase, _evolve, blocked_note, blocked_why, core_mission_of,
                         failure_initial, failure_with_health, first_plan, health_of, in_first_plan,
                         mission_controller, mission_policy, safety_params, shape_name, used_ids)
from .buffers import filled
from .control import Arc, Held, Precision, PrecisionState, Tracking, TurnThenGo
from .coreconst import (AGENT_CONTROLLERS, AGENT_POLICY, AGENT_SAFETY, AGENT_SCALARS,
                        AGENT_SCRATCH_F64_PER_ROBOT, AGENT_SCRATCH_U8_PER_ROBOT, AGENT_STATE, AGENT_TIMES,
                        DECISION_KINDS, FAILURE_MODES, PRECISION_HISTORY)
from .failure import Decision, FailurePolicy, Health
from .frames import MAX_AGE_S, Frame
from .impl import core as core_impl
from .structure import FIRST_PLAN_S
from .wire import CmdMsg, EventMsg, HealthMsg, Mission, StateMsg


# ---------------------------------------------------------------- the agent's state


def enter_mission(state: AgentState, mission: Mission, policy: FailurePolicy, config: StepConfig) -> AgentState:
    """The state re-rowed for a new mission: decisions and timers carried by robot id, motion and
    commands afresh (the controller restarts)."""
    ids = mission.robot_ids
    health = health_of(state.failure, state.ids) if state.failure is not None else state.health
    health = Health(since_t={r: t for r, t in health.since_t.items() if r in ids},
                    failed=frozenset(r for r in health.failed if r in ids),
                    dropped=frozenset(r for r in health.dropped if r in ids))
    failure = failure_with_health(failure_initial(len(ids), policy, config.dt_s), health, ids)
    return replace(state, mission_version=mission.version, ids=ids, health=health, failure=failure,
                   wheels_m_s=filled("d", (len(ids), 2)), ctrl=None, stall_since_t=math.nan, stall_pose=None)


def adopt_health(state: AgentState, msg: HealthMsg | None, timers: bool = True,
                 mission: Mission | None = None, config: StepConfig = StepConfig()) -> AgentState:
    """Take the peers' agreed failure state (None: nothing agreed; keep this agent's own).

    Joining, with ``timers``, the failure timers are taken too; resyncing (or without timers) only
    which robots are failed or dropped. Either way the agent then decides on its own (SYNCED).
    ``mission`` (the one msg is for) lets an agent that has run no frame of it yet take it now.
    """
    if state.phase is SyncPhase.SYNCED:
        return state
    if msg is None:
        return replace(state, phase=SyncPhase.SYNCED)
    timers = timers and state.phase is SyncPhase.JOINING
    current = health_of(state.failure, state.ids) if state.failure is not None else state.health
    health = Health(since_t=dict(msg.since) if timers else dict(current.since_t), failed=frozenset(msg.failed),
                    dropped=frozenset(msg.dropped))
    if mission is not None and mission.version != state.mission_version:
        state = enter_mission(state, mission, mission_policy(mission), config)
    failure = state.failure
    if failure is not None:
        failure = failure_with_health(failure, health, state.ids, timers=True)
    return replace(state, phase=SyncPhase.SYNCED, health=health, failure=failure)


def stop_command(state: AgentState, now_s: float, ttl_s: float) -> CmdMsg:
    """The zero command an agent sends on any exit."""
    return CmdMsg(t=now_s, seq=state.last_seq, vl=0.0, vr=0.0, ttl=ttl_s)


# ---------------------------------------------------------------- the agent step


def command_ttl_s(room: bool, frame_t: float, now_s: float, config: StepConfig) -> float:
    """The ttl [s] of the command answering a frame taken at frame_t [s, tracker clock] and sent at now_s [s, this
    host's clock]: config.ttl_s, cut in a room (the safety filter runs) where the filter's guarantee for that
    command ends, 1 / gamma_per_s after the poses were taken (docs/safety.md, "Stale poses and held commands").
    <= 0: the frame is too old to move on; the agent does not run it. The core's vs_agent_command_ttl."""
    if not room:
        return config.ttl_s
    return min(config.ttl_s, frame_t + 1.0 / safety_params(config.dt_s).gamma_per_s - now_s)


def agent_step(state: AgentState, mission: Mission | None, frame: Frame, now_s: float,
               config: StepConfig = StepConfig()) -> tuple[AgentState, StepOutput]:
    """Decide one frame at local clock reading now_s [s]; see vsfleet.step's docstring.

    mission is the one active at frame.t (vsfleet.frames.MissionBook.active), None if none is.
    In a room the command's ttl ends where the safety filter's guarantee for it ends (command_ttl_s), and a frame
    older than that is not run, as a stale frame: no command answers it, and the robot halts when the last one
    runs out. It is counted (too_old) and logged.
    """
    if mission is None or state.robot not in mission.robot_ids or frame.t < now_s - config.max_stale_s:
        return _decide(state, mission, frame, now_s, config)
    ttl = command_ttl_s(core_mission_of(mission, in_first_plan(mission, frame.t)).room, frame.t, now_s, config)
    if not ttl > 0.0:
        n = state.too_old + 1
        note = Note("warning", f"frame {frame.seq} skipped, too old to move on: {now_s - frame.t:.3f} s behind this "
                               f"host's clock, more than the safety filter's horizon of "
                               f"{1.0 / safety_params(config.dt_s).gamma_per_s:.2f} s (#{n}; a loaded host, a "
                               "stalled link or clock skew); the robot halts")
        return replace(state, too_old=n), StepOutput(notes=(note,) if n <= 10 or n % 100 == 0 else ())
    state, out = _decide(state, mission, frame, now_s, config)
    if out.cmd is not None and out.cmd.ttl != ttl:
        out = replace(out, cmd=replace(out.cmd, ttl=ttl))
    return state, out


def _decide(state: AgentState, mission: Mission | None, frame: Frame, now_s: float,
            config: StepConfig) -> tuple[AgentState, StepOutput]:
    """agent_step before the command's ttl: the frame's age, the mission, then the core (or the numpy glue)."""
    notes: list[Note] = []
    if frame.t < now_s - config.max_stale_s:
        n = state.stale + 1
        if n <= 10 or n % 100 == 0:
            notes.append(Note("warning", f"stale frame #{n} skipped: tracker time {now_s - frame.t:.2f} s behind "
                                         f"this host's clock (more than {config.max_stale_s:.2f} s: clock skew "
                                         "or a stalled link); the robot halts"))
        return replace(state, stale=n), StepOutput(notes=tuple(notes))
    if mission is None:
        return state, StepOutput()
    if state.robot not in mission.robot_ids:
        if mission.version in state.unnamed:
            return state, StepOutput()
        return (replace(state, unnamed=state.unnamed | {mission.version}),
                StepOutput(notes=(Note("warning", f"mission v{mission.version} does not name robot "
                                                  f"{state.robot}: it stays stopped"),)))
    cm = core_mission_of(mission, in_first_plan(mission, frame.t))   # the first plan's fields, or the room's own
    controller = config.controller or mission_controller(mission.controller, mission.controller_gains)
    if mission.version != state.mission_version:
        notes.append(Note("info", f"frame {frame.seq}: switching to mission v{mission.version}"))
        state = enter_mission(state, mission, cm.policy, config)
    if config.impl is core_impl and config.shared_structures is None:
        kernel = agent_kernel(cm, mission, state.robot, controller, config)
        if kernel is not None:   # the rest of the frame in one call into the core (vs_agent_step)
            return _frame_in_core(kernel, state, mission, cm, controller, frame, config, notes)
    from .glue import decide_in_numpy   # the readable glue: the reference, or a controller the core lacks
    return decide_in_numpy(state, mission, controller, frame, config, notes)


# The agent binding's layouts are the core's (vsfleet.coreconst.AGENT_*, py_agent.c): the tuples it takes are built
# by name, the state's numbers read at the places found here, agent_step's answer by name (vsfleet.agentstate.answer).
SCALAR_AT = {name: k for k, name in enumerate(AGENT_SCALARS)}
# The state's arrays go in the order of their dataclasses (no mapping per frame); the core's order is checked once.
STATE_ARRAYS = ("wheels_m_s", *PRECISION_STATE_FIELDS, *FAILURE_FIELDS)
if STATE_ARRAYS != AGENT_STATE:
    raise ImportError(f"vsfleet.agentcore: the core's agent state is {AGENT_STATE}, this module's {STATE_ARRAYS}")


def scalars_of(**numbers: float) -> array:
    """The state's numbers as agent_step takes them (float64, in AGENT_SCALARS' order); every one named."""
    return array("d", (float(numbers[name]) for name in AGENT_SCALARS))


@dataclass(frozen=True)
class Kernel:
    """A mission's and an agent's constants for vs_agent_step (vsfleet._core.agent_config), and its scratch."""

    config: object              # the capsule
    scratch_f64: memoryview
    scratch_u8: memoryview
    stateless: tuple            # Precision's buffers standing in for a controller that keeps no state
    precision: bool             # the controller keeps Precision's state (PrecisionState)


def precision_initial(n: int) -> PrecisionState:
    """Precision's state for n robots, as buffers (vsfleet.control.Precision.initial, without numpy)."""
    return PrecisionState(filled("d", (n, 3)), filled("d", (n, 2), 1.0), filled("d", (n, PRECISION_HISTORY, 2)),
                          filled("d", (n, 2)), filled("d", (n, 2)), filled("d", (n,)), filled("d", (n,), 1.0),
                          filled("d", (n, 2)), filled("?", (n,)))


def agent_kernel(cm: CoreMission, mission: Mission, robot: str, controller: Controller,
                 config: StepConfig) -> Kernel | None:
    """The core's agent step for this mission, robot, controller and config (built once; None: a controller the
    core does not run, whose frames then go through vsfleet.glue's numpy glue)."""
    timing = (config.dt_s, config.ttl_s, config.age_s, config.resync_gap_s)
    hit = cm.kernels.get(robot)   # held by the mission, one per robot: its latest controller and timing
    if hit is not None and hit[0] is controller and hit[1] == timing:
        return hit[2]
    inner, deadband, still = controller, 0.0, 0.0
    if isinstance(controller, Held):
        inner, deadband, still = controller.inner, controller.deadband_m, controller.still_speed_m_s
    name = {Precision: "precision", TurnThenGo: "turn_then_go", Arc: "arc", Tracking: "tracking"}.get(type(inner))
    if name is None:
        return None
    gains = (inner.horizon_s,) if name == "arc" else tuple(float(g) for g in inner._core)
    p = cm.policy
    policy = {"mode": FAILURE_MODES.index(p.mode), "fail_deviation_m": p.fail_deviation_m,
              "fail_after_s": p.fail_after_s, "rejoin_deviation_m": p.rejoin_deviation_m,
              "rejoin_after_s": p.rejoin_after_s, "recover_after_s": p.recover_after_s,
              "min_progress_ratio": p.min_progress_ratio, "min_expected_m2": p.min_expected_m ** 2,
              "min_approach_m": p.min_approach_m}
    sp = safety_params(config.dt_s)
    safety = {"margin_m": sp.margin_m, "gamma_per_s": sp.gamma_per_s, "offset_m": sp.offset_m, "dt_s": sp.dt_s}
    times = {"dt_s": config.dt_s, "ttl_s": config.ttl_s, "age_s": config.age_s, "resync_gap_s": config.resync_gap_s,
             "effective_t": mission.effective_t}
    n = len(cm.ids)
    capsule = _core.agent_config(cm.core, cm.index[robot], AGENT_CONTROLLERS.index(name), gains, deadband,
                                 still, tuple(policy[k] for k in AGENT_POLICY), tuple(safety[k] for k in AGENT_SAFETY),
                                 tuple(times[k] for k in AGENT_TIMES), cm.room, cm.bodies, cm.ids)
    stateless = precision_initial(n)
    kernel = Kernel(capsule, filled("d", (AGENT_SCRATCH_F64_PER_ROBOT * n,)),
                    filled("?", (AGENT_SCRATCH_U8_PER_ROBOT * n,)),
                    tuple(getattr(stateless, k) for k in PRECISION_STATE_FIELDS), name == "precision")
    cm.kernels[robot] = (controller, timing, kernel)   # a robot's kernel for another controller is let go
    return kernel


def _core_inputs(kernel: Kernel, state: AgentState, controller, n: int) -> tuple[object, tuple, array]:
    """(the controller's state, the state's arrays, its numbers) as vsfleet._core.agent_step takes them."""
    ctrl = state.ctrl
    if ctrl is None:   # buffers of its own (the core writes the state in place)
        ctrl = precision_initial(n) if kernel.precision else controller.initial(n)
    precision = tuple(getattr(ctrl, k) for k in PRECISION_STATE_FIELDS) if isinstance(ctrl, PrecisionState) \
        else kernel.stateless
    f = state.failure
    at = state.stall_pose if state.stall_pose is not None else (0.0, 0.0, 0.0, False)
    scalars = scalars_of(last_frame_t=state.last_frame_t, last_cmd_t=state.last_cmd_t,
                         ctrl_ready=state.ctrl is not None, blocked=state.blocked, stall_since_t=state.stall_since_t,
                         stall_watch=state.stall_pose is not None, stall_x=at[0], stall_y=at[1], stall_th=at[2],
                         stall_filter=bool(at[3]), stalled=state.stalled, shape=state.shape)
    return ctrl, (state.wheels_m_s, *precision, *(getattr(f, k) for k in FAILURE_FIELDS)), scalars


def _core_outcome(state: AgentState, mission: Mission, cm: CoreMission, ctrl, t: float, seq: int, r: tuple,
                  scalars: array, notes: list) -> tuple[AgentState, HealthMsg | None, tuple]:
    """The new state, the health answer and the events of a frame the core ran (r: vsfleet._core.agent_step's
    answer, scalars: the state's numbers it wrote back); its log lines are added to notes."""
    sc, at = scalars, SCALAR_AT
    last_frame_t = sc[at["last_frame_t"]]
    if answer(r, "resynced")[0]:
        notes.append(Note("warning", f"frame {seq}: no frame for {t - state.last_frame_t:.2f} s; "
                                     "restarting failure timers and asking peers for their failure state"))
        state = replace(state, phase=SyncPhase.RESYNCING)
    stall_pose = (sc[at["stall_x"]], sc[at["stall_y"]], sc[at["stall_th"]], bool(sc[at["stall_filter"]])) \
        if sc[at["stall_watch"]] else None
    if len(r) == 1:   # no robot usable (a resync restarted the stall watch all the same)
        return _evolve(state, last_frame_t=last_frame_t, stall_since_t=sc[at["stall_since_t"]],
                       stall_pose=stall_pose), None, ()
    blocked, shape, event, event_dev, shape_before, made = answer(
        r, "blocked", "shape", "event", "event_dev_m", "shape_before", "decisions")
    health = health_of(state.failure, cm.ids)
    health_msg = HealthMsg(t=t, seq=seq, mission=mission.version, failed=tuple(sorted(health.failed)),
                           dropped=tuple(sorted(health.dropped)), since=tuple(sorted(health.since_t.items())))
    events: tuple = ()
    if made or event or shape != shape_before:
        ids = cm.ids
        decisions = [Decision(td, ids[i], DECISION_KINDS[k], d) for i, k, td, d in made]
        events = tuple(EventMsg(t=d.t, seq=seq, robot=d.robot, kind=d.kind, dev=d.deviation_m, by=state.robot)
                       for d in decisions)
        if event:
            now_blocked = event == 1
            events += (EventMsg(t=t, seq=seq, robot=state.robot, kind="blocked" if now_blocked else "unblocked",
                                dev=event_dev, by=state.robot, why=blocked_why(now_blocked, bool(blocked))),)
            notes.append(blocked_note(seq, blocked, now_blocked, event_dev))
        if shape != shape_before:
            notes.append(Note("info", f"frame {seq}: the structure takes {shape_name(cm, shape)}"))
        notes.extend(Note("warning", f"frame {seq}: robot {d.robot} {d.kind} (deviation {d.deviation_m:.3f} m, "
                                     f"on_failure={mission.on_failure})") for d in decisions)
    # the state's verdict as the core kept it (vs_agent.c: a held frame keeps the one before), not the frame's own
    state = _evolve(state, last_frame_t=last_frame_t, ctrl=ctrl, health=health, last_seq=seq,
                    blocked=bool(sc[at["blocked"]]), stall_since_t=sc[at["stall_since_t"]], stall_pose=stall_pose,
                    stalled=bool(sc[at["stalled"]]), shape=int(shape), last_cmd_t=t, ticks=state.ticks + 1)
    return state, health_msg, events


_UNSEEN = (math.nan, math.nan, math.nan)


def frame_buffers(ids: tuple[str, ...], poses: Mapping[str, tuple[float, float, float]],
                  fresh: frozenset[str] = frozenset()) -> tuple[memoryview, memoryview, memoryview]:
    """(pose_world (n, 3) [m, m, rad], seen (n,), fresh (n,)) of a frame's poses as buffers; NaN rows unseen
    (vsfleet.step.frame_arrays, without numpy)."""
    n = len(ids)
    values = array("d", chain.from_iterable(map(poses.get, ids, repeat(_UNSEEN))))
    seen = bytearray(x == x for x in values[0::3])
    if fresh.issuperset(ids):   # every robot listed by the frame itself: the common case
        now = bytearray(seen)
    else:
        now = bytearray(s and r in fresh for s, r in zip(seen, ids))
    pose = memoryview(values).cast("B").cast("d", (n, 3)) if n else memoryview(values)
    return pose, memoryview(seen).cast("?"), memoryview(now).cast("?")


def _frame_in_core(kernel: Kernel, state: AgentState, mission: Mission, cm: CoreMission, controller: Controller,
                   frame: Frame, config: StepConfig, notes: list) -> tuple[AgentState, StepOutput]:
    """agent_step from the frame's poses on, in the core (vs_agent_step): the same bits as the numpy glue.
    The state's arrays (wheels, the controller's, the failure rule's) are advanced in place: the state passed in
    is consumed, and only the one returned is to be used."""
    n = len(cm.ids)
    pose, seen, fresh = frame_buffers(cm.ids, frame.poses, frame.fresh)
    ctrl, arrays_in, scalars = _core_inputs(kernel, state, controller, n)
    used = filled("?", (n,))
    r = _core.agent_step(kernel.config, arrays_in, scalars, pose, seen, fresh, float(frame.t), used,
                         kernel.scratch_f64, kernel.scratch_u8)
    state, health_msg, events = _core_outcome(state, mission, cm, ctrl, frame.t, frame.seq, r, scalars, notes)
    if len(r) == 1:
        return state, StepOutput(notes=tuple(notes))
    fx, fy, fth, gx, gy, gth, cost, shape, vl, vr, own_seen, err = answer(
        r, "fit_x", "fit_y", "fit_th", "goal_x", "goal_y", "goal_th", "cost", "shape", "vl_m_s", "vr_m_s", "own_seen",
        "err_m")
    cmd = CmdMsg(t=frame.t, seq=frame.seq, vl=vl, vr=vr, ttl=config.ttl_s)
    state_msg = None
    if own_seen:
        state_msg = StateMsg(t=frame.t, seq=frame.seq, x=fx, y=fy, th=fth, gx=gx, gy=gy, gth=gth, cost=cost, err=err,
                             used=used_ids(cm.ids, used), rejected=0, complete=frame.complete,
                             mission=mission.version, shape=shape)
    if not config.outputs:
        return state, StepOutput(cmd=cmd, state=state_msg, health=health_msg, events=events, notes=tuple(notes))
    from .glue import core_outputs   # numpy: tools and tests only
    structure, wheels = core_outputs(r, used, kernel.scratch_f64, state.wheels_m_s, n)
    return state, StepOutput(cmd=cmd, state=state_msg, health=health_msg, events=events, notes=tuple(notes),
                             structure=structure, wheels_m_s=wheels)


@dataclass(frozen=True)
class PayloadStep:
    """What agent_payload_step gives for a frame it ran: the command's and the state's payloads (the state's
    ``rejected`` filled in), the frame's t and seq, the health answer, events and log lines (as StepOutput's)."""

    cmd: bytes
    state: bytes
    t: float
    seq: int
    health: HealthMsg | None
    events: tuple
    notes: tuple


def first_plan_bounds(effective_t: float, now_s: float, max_future_s: float,
                      max_stale_s: float) -> tuple[bool | None, float, float]:
    """For agent_payload_step, before the payload is decoded: which fields its frame follows (in_first_plan: True,
    the first plan's), and the bounds (max_future_s, max_stale_s) that agent_frame then runs a frame within (t in
    [now_s - max_stale_s, now_s + max_future_s]: the same sums as its own); a frame beyond them is left to the long
    way, which decides it alike. t - effective_t is monotone in t, so the bounds' own sums decide every frame within
    them. The side is the one now_s falls on; (None, ...): neither holds a frame."""
    end = FIRST_PLAN_S
    if (now_s + max_future_s) - effective_t < end:
        return True, max_future_s, max_stale_s
    if (now_s - max_stale_s) - effective_t >= end:
        return False, max_future_s, max_stale_s
    if now_s - effective_t < end:   # the first plan's frames: up to just before its end
        future = ((effective_t + end) - now_s) * (1.0 - 1e-9) - 1e-9
        if (now_s + future) - effective_t < end and future >= -max_stale_s:
            return True, future, max_stale_s
    else:                           # the room's own: from just after the first plan's end
        stale = (now_s - (effective_t + end)) * (1.0 - 1e-9) - 1e-9
        if (now_s - stale) - effective_t >= end and stale >= -max_future_s:
            return False, max_future_s, stale
    return None, max_future_s, max_stale_s


def agent_payload_step(state: AgentState, mission: Mission | None, payload: bytes, src: str, now_s: float,
                       config: StepConfig, done: tuple[float, int], max_future_s: float, rejected: int,
                       max_age_s: float = MAX_AGE_S,
                       others_t: float = -math.inf) -> tuple[AgentState, PayloadStep] | None:
    """One pass from a frame's payload to the command's and the state's payloads (vsfleet._core.agent_frame), for
    the agent's common case: a frame of one source that lists exactly the robots of the mission in force, which
    this state already runs, newer than the last frame run (done: its (t, seq)), neither stale against now_s nor
    more than max_future_s ahead of it, with no other source heard within max_age_s before it (others_t: the
    newest frame time of any other source; the merger's rule, vsfleet.frames.FrameMerger). None otherwise, and
    nothing is changed: the frame then goes the long way (decode, merge, agent_step), which decides the same bits
    (tests/test_core_agent_step.py). The state passed in is consumed when a frame runs, as in agent_step."""
    if (mission is None or state.mission_version != mission.version or state.ctrl is None
            or config.impl is not core_impl or config.shared_structures is not None):
        return None
    first, max_stale_s = False, config.max_stale_s
    if first_plan(mission):
        first, max_future_s, max_stale_s = first_plan_bounds(mission.effective_t, now_s, max_future_s, max_stale_s)
        if first is None:
            return None
    cm = core_mission_of(mission, first)
    if state.robot not in cm.index:
        return None
    controller = config.controller or mission_controller(mission.controller, mission.controller_gains)
    kernel = agent_kernel(cm, mission, state.robot, controller, config)
    if kernel is None:
        return None
    ctrl, arrays_in, scalars = _core_inputs(kernel, state, controller, len(cm.ids))
    got = _core.agent_frame(kernel.config, arrays_in, scalars, kernel.scratch_f64, kernel.scratch_u8, payload, src,
                            now_s, max_future_s, max_stale_s, done[0], done[1], mission.version, rejected,
                            max_age_s, others_t)
    if got is None:
        return None
    cmd, state_payload, t, seq, r = got   # cmd and state None: no robot usable (every one dropped)
    notes: list = []
    state, health_msg, events = _core_outcome(state, mission, cm, ctrl, t, seq, r, scalars, notes)
    return state, PayloadStep(cmd, state_payload, t, seq, health_msg, events, tuple(notes))
