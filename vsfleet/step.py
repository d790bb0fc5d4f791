"""One control tick of the paper's loop (steps 1-4), as a pure function.

``control_step`` is what every agent runs at every frame: it fits the structure
to the robots seen in the frame, advances it toward the mission goal, and
computes one robot's wheel speeds. The structure part depends only on
(mission, frame), so duplicated agents that saw the same
frames compute bit-identical structure poses: the paper's "distributed
duplication".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
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
from .control import ControlInput
from .envelope import Envelope, Envelopes
from .fit import fit_structure
from .geometry import Pose2
from .kinematics import integrate_arcs
from .wire import Mission

Controller = Callable  # vsfleet.control: controller(state, ControlInput) -> (state, wheels (n, 2))


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


def mission_envelope_arrays(mission: Mission) -> Envelopes:
    """The mission's envelopes as (n,) arrays, in its sorted robot order."""
    return Envelopes.of(mission_envelopes(mission))


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
    controller_state: object = None  # the controller's state after this frame (every robot's rows)
    wheels_m_s: np.ndarray | None = None  # (n, 2) every commanded robot's wheels, zero rows for the rest


def control_step(mission: Mission, poses: Mapping[str, tuple[float, float, float]], robot: str,
                 frame_t: float, dt_s: float, wheels_prev_m_s: tuple[float, float],
                 controller: Controller, excluded: frozenset[str] = frozenset(),
                 drive_excluded: bool = False,
                 others_wheels_prev: Mapping[str, tuple[float, float]] | None = None,
                 judged_apart: frozenset[str] = frozenset(), controller_state=None,
                 age_s: float | None = None) -> StepResult | None:
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

    controller_state: the controller's state from the previous frame (None: controller.initial(n));
    the new one is returned in the result. age_s [s]: the time from the frame's observation to when
    the command takes effect (default dt_s).
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
    n = len(ids)
    headings = np.full(n, np.nan)
    fit_dev = np.full(n, np.nan)  # each robot in the fit: its distance to its point (the throttle's input)
    now_pts = fit.pose.apply(template)
    for i, r in zip(rows, used):
        headings[i] = poses[r][2]
    fit_dev[rows] = np.hypot(positions[:, 0] - now_pts[rows, 0], positions[:, 1] - now_pts[rows, 1])
    envelopes = mission_envelope_arrays(mission)
    adv = advance_structure(fit.pose, mission_goal(mission), dt_s, limits, template,
                            envelopes, elapsed_s=frame_t - mission.effective_t,
                            headings_rad=headings, deviations_m=fit_dev)

    next_pts = adv.pose.apply(template)
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
    seen = np.array([r in poses for r in ids], dtype=bool)
    drivable = seen & np.array([(r not in excluded) or drive_excluded for r in ids], dtype=bool)
    if others_wheels_prev is None:
        drivable &= np.array([r == robot for r in ids], dtype=bool)
    others = others_wheels_prev or {}
    prev = np.array([wheels_prev_m_s if r == robot else others.get(r, (0.0, 0.0)) for r in ids], dtype=float)
    pose_arr = np.array([poses[r] if r in poses else (0.0, 0.0, 0.0) for r in ids], dtype=float)
    state = controller.initial(n) if controller_state is None else controller_state
    inp = ControlInput(pose_world=pose_arr, point_now_world=now_pts, point_next_world=next_pts,
                       wheels_prev_m_s=prev, dt_s=dt_s, age_s=dt_s if age_s is None else age_s,
                       envelopes=envelopes, active=drivable)
    state, wheels = controller(state, inp)
    commands = {r: (float(wheels[i, 0]), float(wheels[i, 1])) for i, r in enumerate(ids) if drivable[i]}
    vl, vr = commands.get(robot, (0.0, 0.0))
    return StepResult(fit_pose=fit.pose, goal_pose=adv.pose, twist=adv.twist, cost=float(fit.cost),
                      err_m=err, used=used, vl_m_s=float(vl), vr_m_s=float(vr), at_goal=adv.at_goal,
                      deviations_m=deviations, commands=commands, controller_state=state, wheels_m_s=wheels)


def expected_steps(mission: Mission, poses: Mapping[str, tuple[float, float, float]],
                   commands: Mapping[str, tuple[float, float]], dt_s: float) -> dict[str, tuple[float, float]]:
    """Displacement [m; world] each commanded robot should make in dt_s at its command (eqs 17-18)."""
    rs = [r for r in commands if r in poses]
    if not rs:
        return {}
    pose = np.array([poses[r] for r in rs], dtype=float)
    wheels = np.array([commands[r] for r in rs], dtype=float)
    base = np.array([mission.spec(r).wheel_base for r in rs], dtype=float)
    nxt = integrate_arcs(pose, wheels, dt_s, base)
    return {r: (float(nxt[i, 0] - pose[i, 0]), float(nxt[i, 1] - pose[i, 1])) for i, r in enumerate(rs)}
