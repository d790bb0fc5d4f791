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
from .envelope import Envelope
from .fit import fit_structure
from .geometry import Pose2
from .kinematics import integrate_arc
from .wire import Mission

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
