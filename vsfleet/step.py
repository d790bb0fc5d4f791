"""The agent's decision at one frame, as one pure function: ``agent_step``.

``agent_step(state, mission, frame, now_s, config) -> (state, StepOutput)`` is
everything an agent decides per frame: the frame's age (stale frames are not
run), gaps and resynchronisation, the fit and the advance (``control_step``),
its own command and every robot's predicted command, and the failure rule. The
agent process (agent/main.py), the offline fleet (simfleet.offline), the benches
and the tests all drive this same function. The structure part depends only on
(mission, frame), so duplicated agents that saw the same frames compute
bit-identical structure poses: the paper's "distributed duplication".
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Callable, Mapping

import numpy as np

from .advance import (
    Goal,
    GoalPath,
    GoalPose,
    GoalTwist,
    StructureLimits,
    Twist2,
    advance_structure,
)
from .control import DEFAULT_CONTROLLER, make_controller
from .envelope import Envelope
from .failure import FailurePolicy, Health, Motion, update_health, update_motion
from .fit import fit_structure
from .frames import Frame
from .geometry import Pose2
from .kinematics import integrate_arc
from .wire import CmdMsg, EventMsg, HealthMsg, Mission, StateMsg

Controller = Callable[[Pose2, np.ndarray, np.ndarray, float, Envelope, tuple[float, float]],
                      tuple[float, float]]


def mission_goal(mission: Mission) -> Goal:
    """The advance goal named by a mission (pose, path or twist)."""
    if mission.goal is not None:
        return GoalPose(Pose2(*mission.goal))
    if mission.path is not None:
        return GoalPath(tuple(Pose2(*w) for w in mission.path))
    assert mission.twist is not None
    return GoalTwist(*mission.twist)


def mission_envelopes(mission: Mission) -> list[Envelope]:
    return [Envelope(s.wheel_base, s.wheel_speed_max, s.wheel_accel_max) for _, s in mission.robots]


def mission_template(mission: Mission) -> np.ndarray:
    """Template points (n, 2) [m; structure frame], in the mission's sorted robot order."""
    return np.array([s.p for _, s in mission.robots], dtype=float)


@dataclass(frozen=True)
class StepResult:
    """Result of one tick.

    fit_pose / goal_pose: fitted and advanced structure poses [m, rad; world].
    cost [m]: the fit's cost; err_m: own robot's distance to its fitted point (NaN if unseen).
    used: robot ids in the fit; vl/vr [m/s]: own wheel speeds (0 when own robot unseen).
    """

    fit_pose: Pose2
    goal_pose: Pose2
    twist: Twist2
    cost: float
    err_m: float
    used: tuple[str, ...]
    vl_m_s: float
    vr_m_s: float
    at_goal: bool
    deviations_m: dict[str, float]  # every seen robot's distance to its point [m] (see judged_apart)
    commands: dict[str, tuple[float, float]]  # (vl, vr) [m/s] of own robot, and of others if predicted


def control_step(mission: Mission, poses: Mapping[str, tuple[float, float, float]], robot: str,
                 frame_t: float, dt_s: float, wheels_prev_m_s: tuple[float, float],
                 controller: Controller, excluded: frozenset[str] = frozenset(),
                 drive_excluded: bool = False,
                 others_wheels_prev: Mapping[str, tuple[float, float]] | None = None,
                 judged_apart: frozenset[str] = frozenset()) -> StepResult | None:
    """Fit, advance and control one robot for one frame at tracker time ``frame_t`` [s].

    The structure poses depend only on (mission, poses, frame_t, dt_s, excluded): the
    advance ramps on the time since the mission's effective_t, not on past ticks.

    poses maps robot id -> (x, y, th) [m, rad; world] for the robots in this frame;
    robots of the mission that are absent or in ``excluded`` are left out of the fit
    but still bound the advance (they must be able to follow). An excluded own robot
    is stopped, unless drive_excluded (on_failure = rejoin: it keeps chasing its
    point so that it can rejoin). Returns None when no mission robot is in the frame.

    With others_wheels_prev (every robot's previous command, as this agent predicted
    it), the commands every other robot's agent computes are predicted too, into
    ``commands``: the failure rule compares them with how the robots moved.

    ``deviations_m`` (what the failure rule judges) are distances to the fitted structure's
    points. Robots in ``judged_apart`` stay in the fit the robots follow, but the deviations
    are measured on the structure fitted without them (when two or more others remain): under
    on_failure = hold a failed robot bends the structure, and the healthy robots it bends
    must not look non-compliant for it.
    """
    ids = mission.robot_ids
    used = tuple(r for r in ids if r in poses and r not in excluded)
    if not used:
        return None
    template = mission_template(mission)
    index = {r: i for i, r in enumerate(ids)}
    rows = [index[r] for r in used]
    positions = np.array([[poses[r][0], poses[r][1]] for r in used], dtype=float)
    fit = fit_structure(template[rows], positions, metric=mission.metric)
    limits = StructureLimits(speed_max_m_s=mission.speed_max, turn_rate_max_rad_s=mission.turn_rate_max)
    adv = advance_structure(fit.pose, mission_goal(mission), dt_s, limits, template,
                            mission_envelopes(mission), elapsed_s=frame_t - mission.effective_t,
                            headings_rad=[poses[r][2] if r in used else None for r in ids])

    now_pts, next_pts = fit.pose.apply(template), adv.pose.apply(template)
    judged_pts = now_pts
    judges = [i for i, r in enumerate(used) if r not in judged_apart]  # indices into used
    if 2 <= len(judges) < len(used):  # a rigid fit needs two points to fix the heading
        judge_fit = fit_structure(template[[rows[i] for i in judges]], positions[judges], metric=mission.metric)
        judged_pts = judge_fit.pose.apply(template)
    deviations = {r: float(np.hypot(poses[r][0] - q[0], poses[r][1] - q[1]))
                  for r, q in zip(ids, judged_pts) if r in poses}
    err = math.nan
    if robot in poses and robot in index:
        own = now_pts[index[robot]]
        err = float(np.hypot(poses[robot][0] - own[0], poses[robot][1] - own[1]))
    envelopes = mission_envelopes(mission)
    targets = [robot] + (list(ids) if others_wheels_prev is not None else [])
    commands: dict[str, tuple[float, float]] = {}
    for r in targets:
        if r in commands or r not in poses or (r in excluded and not drive_excluded):
            continue
        i = index[r]
        prev = wheels_prev_m_s if r == robot else others_wheels_prev.get(r, (0.0, 0.0))
        vl_r, vr_r = controller(Pose2(*poses[r]), now_pts[i], next_pts[i], dt_s, envelopes[i], prev)
        commands[r] = (float(vl_r), float(vr_r))
    vl, vr = commands.get(robot, (0.0, 0.0))
    return StepResult(fit_pose=fit.pose, goal_pose=adv.pose, twist=adv.twist, cost=float(fit.cost),
                      err_m=err, used=used, vl_m_s=float(vl), vr_m_s=float(vr), at_goal=adv.at_goal,
                      deviations_m=deviations, commands=commands)


def expected_steps(mission: Mission, poses: Mapping[str, tuple[float, float, float]],
                   commands: Mapping[str, tuple[float, float]], dt_s: float) -> dict[str, tuple[float, float]]:
    """Displacement [m; world] each commanded robot should make in dt_s at its command (eqs 17-18)."""
    out = {}
    for r, (vl, vr) in commands.items():
        pose = Pose2(*poses[r])
        nxt = integrate_arc(pose, vl, vr, dt_s, mission.spec(r).wheel_base)
        out[r] = (nxt.x - pose.x, nxt.y - pose.y)
    return out


# ---------------------------------------------------------------- the agent step


class SyncPhase(enum.Enum):
    """Where an agent stands with its peers' failure-policy state."""

    JOINING = "joining"      # (re)started: take the peers' whole failure state (with timers) once
    RESYNCING = "resyncing"  # after a gap in frames: take only which robots are failed or dropped
    SYNCED = "synced"        # decides on its own


@dataclass(frozen=True)
class StepConfig:
    """What the agent process fixes at start: dt_s [s] (the structure's advance per frame), the
    command ttl_s [s], max_stale_s [s] (a frame further behind the local clock is not run),
    resync_gap_s [s] (a longer gap between frames run restarts the failure timers), and a
    controller that overrides the mission's (offline runs, tests; None = the mission's)."""

    dt_s: float = 1.0 / 30.0
    ttl_s: float = 0.3
    max_stale_s: float = 0.5
    resync_gap_s: float = 1.0
    controller: Controller | None = None


@dataclass(frozen=True)
class AgentState:
    """Everything an agent carries from one frame to the next; replaced, never mutated.

    predicted_m_s: every robot's last command (vl, vr) [m/s] as this agent predicted it;
    wheels_prev_m_s: its own robot's last command. Times [s] are on the tracker's clock.
    """

    robot: str
    phase: SyncPhase = SyncPhase.JOINING
    mission_version: int = -1
    health: Health = field(default_factory=Health)
    motion: Motion = field(default_factory=Motion)
    predicted_m_s: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    wheels_prev_m_s: tuple[float, float] = (0.0, 0.0)
    last_frame_t: float = -math.inf
    last_cmd_t: float = -math.inf
    last_seq: int = 0
    ticks: int = 0
    stale: int = 0
    unnamed: frozenset[int] = frozenset()  # mission versions that do not name this robot (noted once)


@dataclass(frozen=True)
class Note:
    """A line for the agent's log: level is "info" or "warning"."""

    level: str
    text: str


@dataclass(frozen=True)
class StepOutput:
    """What the agent publishes and logs for one frame (None / empty: nothing)."""

    cmd: CmdMsg | None = None
    state: StateMsg | None = None        # its ``rejected`` count is the process's to fill in
    health: HealthMsg | None = None      # the answer to peers' health queries from now on
    events: tuple[EventMsg, ...] = ()
    notes: tuple[Note, ...] = ()
    result: StepResult | None = None


@lru_cache(maxsize=16)
def mission_controller(name: str | None) -> Controller:
    """The controller a mission names (the default if none): the same object for every frame."""
    return make_controller(name or DEFAULT_CONTROLLER)


def agent_step(state: AgentState, mission: Mission | None, frame: Frame, now_s: float,
               config: StepConfig = StepConfig()) -> tuple[AgentState, StepOutput]:
    """Decide one frame at local clock reading now_s [s]; see the module docstring.

    mission is the one active at frame.t (vsfleet.frames.MissionBook.active), None if none is.
    """
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
            return replace(state, wheels_prev_m_s=(0.0, 0.0)), StepOutput()
        return (replace(state, wheels_prev_m_s=(0.0, 0.0), unnamed=state.unnamed | {mission.version}),
                StepOutput(notes=(Note("warning", f"mission v{mission.version} does not name robot "
                                                  f"{state.robot}: it stays stopped"),)))
    if mission.version != state.mission_version:
        notes.append(Note("info", f"frame {frame.seq}: switching to mission v{mission.version}"))
        state = replace(state, mission_version=mission.version)
    if frame.t - state.last_cmd_t > config.ttl_s:
        # a gap longer than ttl: every robot has halted since the last commands
        state = replace(state, wheels_prev_m_s=(0.0, 0.0), predicted_m_s={})
    if frame.t - state.last_frame_t > config.resync_gap_s and state.last_frame_t > -math.inf:
        # this agent (or the whole fleet) saw no frame for a while: restart the failure timers and
        # the motion window, and ask the peers which robots they failed or dropped
        notes.append(Note("warning", f"frame {frame.seq}: no frame for {frame.t - state.last_frame_t:.2f} s; "
                                     "restarting failure timers and asking peers for their failure state"))
        state = replace(state, motion=Motion(), phase=SyncPhase.RESYNCING,
                        health=Health(failed=state.health.failed, dropped=state.health.dropped))
    state = replace(state, last_frame_t=frame.t)
    poses = {r: p for r, p in frame.poses.items() if r in mission.robot_ids}
    hold = mission.on_failure == "hold"
    result = control_step(mission, poses, state.robot, frame.t, config.dt_s, state.wheels_prev_m_s,
                          config.controller or mission_controller(mission.controller),
                          excluded=state.health.dropped, drive_excluded=mission.on_failure == "rejoin",
                          others_wheels_prev=state.predicted_m_s,
                          judged_apart=state.health.failed - state.health.dropped if hold else frozenset())
    if result is None:
        return state, StepOutput(notes=tuple(notes))
    cmd = CmdMsg(t=frame.t, seq=frame.seq, vl=result.vl_m_s, vr=result.vr_m_s, ttl=config.ttl_s)
    state_msg = None
    if not math.isnan(result.err_m):
        f, g = result.fit_pose, result.goal_pose
        state_msg = StateMsg(t=frame.t, seq=frame.seq, x=f.x, y=f.y, th=f.th, gx=g.x, gy=g.y, gth=g.th,
                             cost=result.cost, err=result.err_m, used=result.used, rejected=0,
                             complete=frame.complete, mission=mission.version)
    policy = FailurePolicy(mission.on_failure)
    # the motion test takes only poses of this very frame: a pose held over from an earlier frame
    # would count as "did not move" here and double next frame, and agents that got that pose in
    # time would disagree on the frame of a decision
    moved = {r: p for r, p in poses.items() if r in frame.fresh}
    expected = expected_steps(mission, moved, {r: c for r, c in result.commands.items() if r in moved},
                              config.dt_s)
    motion, progress = update_motion(policy, state.motion, moved, expected, frame.t,
                                     step_s=config.dt_s, max_gap_s=config.ttl_s)
    health, decisions = update_health(policy, state.health, result.deviations_m, mission.robot_ids,
                                      frame.t, progress)
    health_msg = HealthMsg(t=frame.t, seq=frame.seq, mission=mission.version, failed=tuple(sorted(health.failed)),
                           dropped=tuple(sorted(health.dropped)), since=tuple(sorted(health.since_t.items())))
    events = tuple(EventMsg(t=d.t, seq=frame.seq, robot=d.robot, kind=d.kind, dev=d.deviation_m, by=state.robot)
                   for d in decisions)
    notes.extend(Note("warning", f"frame {frame.seq}: robot {d.robot} {d.kind} (deviation {d.deviation_m:.3f} m, "
                                 f"on_failure={mission.on_failure})") for d in decisions)
    state = replace(state, wheels_prev_m_s=(result.vl_m_s, result.vr_m_s), predicted_m_s=dict(result.commands),
                    last_seq=frame.seq, last_cmd_t=frame.t, ticks=state.ticks + 1, motion=motion, health=health)
    return state, StepOutput(cmd=cmd, state=state_msg, health=health_msg, events=events, notes=tuple(notes),
                             result=result)


def adopt_health(state: AgentState, msg: HealthMsg | None, timers: bool = True) -> AgentState:
    """Take the peers' agreed failure state (None: nothing agreed; keep this agent's own).

    Joining, with ``timers``, the failure timers are taken too; resyncing (or without timers) only
    which robots are failed or dropped. Either way the agent then decides on its own (SYNCED).
    """
    if state.phase is SyncPhase.SYNCED:
        return state
    if msg is None:
        return replace(state, phase=SyncPhase.SYNCED)
    since = dict(msg.since) if timers and state.phase is SyncPhase.JOINING else dict(state.health.since_t)
    return replace(state, phase=SyncPhase.SYNCED,
                   health=Health(since_t=since, failed=frozenset(msg.failed), dropped=frozenset(msg.dropped)))


def stop_command(state: AgentState, now_s: float, ttl_s: float) -> CmdMsg:
    """The zero command an agent sends on any exit."""
    return CmdMsg(t=now_s, seq=state.last_seq, vl=0.0, vr=0.0, ttl=ttl_s)
