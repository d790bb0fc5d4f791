"""Leader-follower (l-psi) formation control: the baseline the paper argues against.

Desai, Ostrowski & Kumar (1998), "Controlling formations of multiple mobile
robots": one robot leads, each follower j keeps a distance l and a bearing psi
to the leader i. The follower controls an off-axis point q_j at distance d
ahead of its wheel axle (so the unicycle can be feedback-linearised):

    q_j = p_i + l (cos(th_i + psi), sin(th_i + psi))      (psi: bearing in the leader's frame)

With gamma = th_i + psi - th_j the kinematics are

    l'   = v_j cos(gamma) + d w_j sin(gamma) - v_i cos(psi)
    psi' = (v_i sin(psi) - v_j sin(gamma) + d w_j cos(gamma)) / l - w_i

and the law below makes l' = a1 (l_d - l), psi' = a2 (psi_d - psi) exactly (it
inverts a rotation by gamma, so it has no singularity). The leader drives to its
own point of the goal pose (go-to-goal at up to the mission's speed_max and
turn_rate_max), then turns to the goal heading. Followers know the leader's
twist from its wheel odometry (what a real leader would broadcast) at the
frame's observation; like every command, theirs take effect one frame later.

Everything here is pure except the simulation loops, which run the same
physics (simfleet.physics.step_fleet, its Fault model, the scenario's fault
timeline), tracker noise and command latency as simfleet.offline.run_offline,
which drives the virtual structure's real Agent objects.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from vsfleet.simfleet.offline import run_offline
from vsfleet.simfleet.physics import Fault, RobotState, step_fleet
from vsfleet.analysis import goal_distance
from vsfleet.envelope import Envelope
from vsfleet.fit import fit_structure
from vsfleet.geometry import Pose2, wrap_angle
from vsfleet.kinematics import limit_wheels, twist_from_wheels, wheels_from_twist
from vsfleet.scenario import FaultEvent, Scenario
from vsfleet.step import mission_envelopes, mission_template
from vsfleet.wire import Mission

BROKEN_M = 0.10      # a formation error above this (a third of the 0.3 m template radius) = broken
AT_GOAL_M = 0.02     # a robot within this of its goal point has arrived
ERROR_METRIC = "l2"  # formation error: distance to the template point under the l2-best-fit structure


@dataclass(frozen=True)
class LFGains:
    """Gains of the l-psi law and the leader's go-to-goal.

    d_m and the two rates are the best of TUNING_GRID on the no-fault paper triangle (lowest
    max formation error; see ``tune``): a larger d leaves a follower's axle off its point when
    the leader turns in place, a smaller one amplifies tracker noise.
    """

    d_m: float = 0.02                 # off-axis point ahead of the follower's axle [m]
    a_l_per_s: float = 1.0            # distance convergence rate [1/s]
    a_psi_per_s: float = 1.0          # bearing convergence rate [1/s]
    leader_speed_gain_per_s: float = 1.0   # leader: v = min(speed_max, k dist) cos(heading error)
    leader_turn_gain_per_s: float = 2.0    # leader: w = k heading error, clipped to turn_rate_max
    leader_arrive_m: float = 0.005    # leader turns to the goal heading within this of its point


@dataclass(frozen=True)
class Slot:
    """A follower's place: its off-axis point at distance l_m, bearing psi_rad from the leader."""

    robot: str
    l_m: float
    psi_rad: float


@dataclass(frozen=True)
class Plan:
    leader: str
    leader_goal: Pose2          # the leader's own point of the goal pose, with the goal heading
    slots: tuple[Slot, ...]
    speed_max_m_s: float
    turn_rate_max_rad_s: float


# ---------------------------------------------------------------- pure control


def slot_for(offset_xy, d_m: float) -> tuple[float, float]:
    """(l_d [m], psi_d [rad]) of the off-axis point for a follower whose axle sits at
    ``offset_xy`` [m; leader frame]: at rest in line the point is d ahead of the axle."""
    ox, oy = float(offset_xy[0]) + d_m, float(offset_xy[1])
    return math.hypot(ox, oy), math.atan2(oy, ox)


def lpsi_measure(leader: Pose2, follower: Pose2, d_m: float) -> tuple[float, float, float]:
    """(l [m], psi [rad], gamma [rad]) of a follower's off-axis point relative to the leader."""
    qx = follower.x + d_m * math.cos(follower.th) - leader.x
    qy = follower.y + d_m * math.sin(follower.th) - leader.y
    psi = wrap_angle(math.atan2(qy, qx) - leader.th)
    return math.hypot(qx, qy), psi, wrap_angle(leader.th + psi - follower.th)


def lpsi_command(leader: Pose2, leader_twist: tuple[float, float], follower: Pose2, l_d_m: float,
                 psi_d_rad: float, d_m: float, a_l_per_s: float, a_psi_per_s: float) -> tuple[float, float]:
    """Follower twist (v [m/s], w [rad/s]) that gives l' = a_l (l_d - l), psi' = a_psi (psi_d - psi)."""
    v_i, w_i = leader_twist
    l, psi, gamma = lpsi_measure(leader, follower, d_m)
    p = a_l_per_s * (l_d_m - l) + v_i * math.cos(psi)
    q = l * (a_psi_per_s * wrap_angle(psi_d_rad - psi) + w_i) - v_i * math.sin(psi)
    c, s = math.cos(gamma), math.sin(gamma)
    return p * c - q * s, (p * s + q * c) / d_m


def leader_command(pose: Pose2, goal: Pose2, speed_max_m_s: float, turn_rate_max_rad_s: float,
                   gains: LFGains) -> tuple[float, float]:
    """Leader twist (v [m/s], w [rad/s]): to its goal point, then to the goal heading."""
    dx, dy = goal.x - pose.x, goal.y - pose.y
    dist = math.hypot(dx, dy)
    if dist > gains.leader_arrive_m:
        err = wrap_angle(math.atan2(dy, dx) - pose.th)
        v = min(speed_max_m_s, gains.leader_speed_gain_per_s * dist) * max(0.0, math.cos(err))
    else:
        err, v = wrap_angle(goal.th - pose.th), 0.0
    w = max(-turn_rate_max_rad_s, min(turn_rate_max_rad_s, gains.leader_turn_gain_per_s * err))
    return v, w


def plan_for(mission: Mission, leader: str, gains: LFGains) -> Plan:
    """Slots from the mission's template: followers keep their template offsets to the leader."""
    if mission.goal is None:
        raise ValueError("the leader-follower baseline needs a mission with a goal pose")
    goal = Pose2(*mission.goal)
    pl = np.array(mission.spec(leader).p)
    gx, gy = goal.apply(pl[None, :])[0]
    slots = tuple(Slot(r, *slot_for(np.array(mission.spec(r).p) - pl, gains.d_m))
                  for r in mission.robot_ids if r != leader)
    return Plan(leader, Pose2(float(gx), float(gy), goal.th), slots, mission.speed_max,
                mission.turn_rate_max)


def formation_wheels(plan: Plan, poses: dict[str, Pose2], leader_twist: tuple[float, float], dt_s: float,
                     wheels_prev: dict[str, tuple[float, float]], envelopes: dict[str, Envelope],
                     gains: LFGains) -> dict[str, tuple[float, float]]:
    """One tick of the whole leader-follower fleet: wheel commands (vl, vr) [m/s] per robot,
    clipped to each robot's envelope like the virtual structure's controllers."""
    out = {}
    twists = {plan.leader: leader_command(poses[plan.leader], plan.leader_goal, plan.speed_max_m_s,
                                          plan.turn_rate_max_rad_s, gains)}
    for s in plan.slots:
        twists[s.robot] = lpsi_command(poses[plan.leader], leader_twist, poses[s.robot], s.l_m, s.psi_rad,
                                       gains.d_m, gains.a_l_per_s, gains.a_psi_per_s)
    for r, (v, w) in twists.items():
        env = envelopes[r]
        vl, vr = wheels_from_twist(v, w, env.wheel_base_m)
        out[r] = limit_wheels(vl, vr, wheels_prev.get(r, (0.0, 0.0)), dt_s, env)
    return out


# ---------------------------------------------------------------- runs


@dataclass(frozen=True)
class FormationRun:
    """One closed-loop run: per frame t [s], each robot's formation error [m] (ERROR_METRIC fit of
    the true positions) and the fitted structure pose; positions_m is (frames, n, 2) or None."""

    method: str
    robots: tuple[str, ...]
    t_s: np.ndarray
    errors_m: np.ndarray
    structure: tuple[Pose2, ...]
    start_structure: Pose2
    final_xy: dict[str, tuple[float, float]]
    positions_m: np.ndarray | None


def _start_fit(scenario: Scenario) -> Pose2:
    m = scenario.mission
    starts = {r.robot: r.start for r in scenario.robots}
    pos = np.array([starts[r][:2] for r in m.robot_ids])
    return fit_structure(mission_template(m), pos, metric=ERROR_METRIC).pose


def run_leader_follower(scenario: Scenario, duration_s: float, leader: str | None = None,
                        gains: LFGains = LFGains(), latency_frames: int = 1, seed: int = 0) -> FormationRun:
    """The l-psi fleet under run_offline's physics, tracker noise and command latency."""
    mission = scenario.mission
    ids = mission.robot_ids
    leader = leader or ids[0]
    plan = plan_for(mission, leader, gains)
    envelopes = dict(zip(ids, mission_envelopes(mission)))
    template = mission_template(mission)
    tr = scenario.tracker
    rng = np.random.default_rng(seed)
    robots = {r.robot: r for r in scenario.robots}
    states = {r.robot: RobotState(Pose2(*r.start)) for r in scenario.robots}
    faults = {r: Fault() for r in robots}
    timeline = list(scenario.faults)
    dt = 1.0 / tr.rate_hz
    substeps = max(1, round(scenario.sim.rate_hz / tr.rate_hz))
    dt_phys = dt / substeps
    cmds = {r: (0.0, 0.0) for r in robots}
    prev: dict[str, tuple[float, float]] = {}
    pending: list[dict] = []
    t = 0.0
    ts, errs, trace, xy = [], [], [], []
    for _ in range(int(round(duration_s / dt))):
        seen = {r: Pose2(s.pose.x + rng.normal(0.0, tr.noise_xy_m), s.pose.y + rng.normal(0.0, tr.noise_xy_m),
                         s.pose.th + rng.normal(0.0, tr.noise_th_rad)) for r, s in states.items()}
        odo = twist_from_wheels(states[leader].vl, states[leader].vr, robots[leader].wheel_base)
        prev = formation_wheels(plan, seen, odo, dt, prev, envelopes, gains)
        pending.append(prev)
        if len(pending) > latency_frames:
            cmds = pending.pop(0)
        t = step_fleet(states, robots, cmds, faults, timeline, t, dt_phys, substeps)
        pos = np.array([[states[r].pose.x, states[r].pose.y] for r in ids])
        fit = fit_structure(template, pos, metric=ERROR_METRIC)
        ts.append(t)
        errs.append(fit.residuals_m)
        trace.append(fit.pose)
        xy.append(pos)
    return FormationRun("leader-follower", ids, np.array(ts), np.array(errs), tuple(trace),
                        _start_fit(scenario), {r: (s.pose.x, s.pose.y) for r, s in states.items()},
                        np.array(xy))


def run_virtual_structure(scenario: Scenario, duration_s: float, seed: int = 0,
                          latency_frames: int = 1) -> FormationRun:
    """The virtual structure (real Agent objects, simfleet.offline) fitting with ERROR_METRIC."""
    run = run_offline(scenario, duration_s, metric=ERROR_METRIC, seed=seed, latency_frames=latency_frames,
                      stop_at_goal=False)
    return FormationRun("virtual structure", run.robots, np.array([t for t, _ in run.trace]),
                        run.deviations_m, tuple(p for _, p in run.trace), _start_fit(scenario),
                        {r: (p.x, p.y) for r, p in run.final_poses.items()}, None)


# ---------------------------------------------------------------- scenarios and summary

TUNING_GRID = tuple((d, a) for d in (0.01, 0.02, 0.05) for a in (1.0, 2.0, 4.0))


def tune(scenario: Scenario, duration_s: float = 45.0, seed: int = 2):
    """[(d_m, rate_per_s, mean error [m], max error [m])] over TUNING_GRID, no fault."""
    sc = dataclasses.replace(scenario, faults=())
    out = []
    for d, a in TUNING_GRID:
        run = run_leader_follower(sc, duration_s, gains=LFGains(d_m=d, a_l_per_s=a, a_psi_per_s=a), seed=seed)
        out.append((d, a, float(run.errors_m.mean()), float(run.errors_m.max())))
    return out



def fault_cases(leader: str, follower: str, at_s: float) -> dict[str, tuple[FaultEvent, ...]]:
    """The four cases of the comparison."""
    return {
        "no fault": (),
        f"follower {follower} stopped": (FaultEvent(follower, at_s, "stop", 0.0, 0.0),),
        f"leader {leader} stopped": (FaultEvent(leader, at_s, "stop", 0.0, 0.0),),
        f"follower {follower} slowed to 50%": (FaultEvent(follower, at_s, "slow", 0.5, 0.0),),
    }


@dataclass(frozen=True)
class FormationSummary:
    case: str
    method: str
    mean_error_m: float
    max_error_m: float
    broke: bool
    t_broke_s: float | None
    progress: float               # 1 - final / initial distance of the fitted structure to the goal
    t_goal_s: float | None        # first time the fitted structure was within AT_GOAL_M of the goal
    at_goal: int                  # robots within AT_GOAL_M of their goal point at the end
    robots: int


def summarise(case: str, run: FormationRun, mission: Mission) -> FormationSummary:
    worst = run.errors_m.max(axis=1)
    broke_at = np.flatnonzero(worst > BROKEN_M)
    d0 = goal_distance(mission, run.start_structure)
    d1 = goal_distance(mission, run.structure[-1])
    near = [t for t, p in zip(run.t_s, run.structure) if goal_distance(mission, p) <= AT_GOAL_M]
    goal = Pose2(*mission.goal)
    pts = goal.apply(mission_template(mission))
    at_goal = sum(math.hypot(run.final_xy[r][0] - pts[i, 0], run.final_xy[r][1] - pts[i, 1]) <= AT_GOAL_M
                  for i, r in enumerate(mission.robot_ids))
    return FormationSummary(case, run.method, float(run.errors_m.mean()), float(run.errors_m.max()),
                            bool(broke_at.size), float(run.t_s[broke_at[0]]) if broke_at.size else None,
                            1.0 - d1 / d0, float(near[0]) if near else None, int(at_goal),
                            len(mission.robot_ids))


def compare(scenario: Scenario, duration_s: float = 45.0, fault_at_s: float = 8.0, seed: int = 2,
            leader: str | None = None, follower: str | None = None, log=print):
    """Both methods on each fault case: [(case, vs run, lf run, vs summary, lf summary)]."""
    ids = scenario.mission.robot_ids
    leader = leader or ids[0]
    follower = follower or ids[1]
    out = []
    cases = fault_cases(leader, follower, fault_at_s)
    for i, (case, faults) in enumerate(cases.items()):
        log(f"[leader-follower {i + 1}/{len(cases)}] {case}")
        sc = dataclasses.replace(scenario, faults=faults)
        vs = run_virtual_structure(sc, duration_s, seed=seed)
        lf = run_leader_follower(sc, duration_s, leader=leader, seed=seed)
        out.append((case, vs, lf, summarise(case, vs, sc.mission), summarise(case, lf, sc.mission)))
    return out
