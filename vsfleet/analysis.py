"""Run analysis, pure: deviation from the structure, agreement between agents, progress.

Inputs are decoded messages; outputs are plain dataclasses. Used by ``vsfleet run``'s
summary, the tests and the benchmarks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

import numpy as np

from .fit import fit_structure
from .geometry import Pose2, angle_diff
from .wire import Mission, StateMsg, TruthMsg

PAPER_MEAN_M = 0.00783
PAPER_STD_M = 0.00318
PAPER_MAX_M = 0.025


@dataclass(frozen=True)
class DeviationStats:
    """One robot's distance from its structure point over a run [m]."""

    robot: str
    mean_m: float
    std_m: float
    max_m: float
    samples: int


def truth_frames(truth: Iterable[tuple[str, TruthMsg]]) -> list[tuple[float, dict[str, TruthMsg]]]:
    """Group (robot, truth) messages by their time stamp, oldest first."""
    by_t: dict[float, dict[str, TruthMsg]] = {}
    for robot, msg in truth:
        by_t.setdefault(msg.t, {})[robot] = msg
    return sorted(by_t.items())


def fitted_truth(mission: Mission, frames: Sequence[tuple[float, Mapping[str, TruthMsg]]],
                 robots: Sequence[str] | None = None):
    """Per complete truth frame: (t, fitted pose, {robot: deviation [m]}), fitting ``robots``."""
    ids = tuple(robots) if robots is not None else mission.robot_ids
    tpl = np.array([mission.spec(r).p for r in ids], dtype=float)
    out = []
    for t, frame in frames:
        if not all(r in frame for r in ids):
            continue
        pos = np.array([[frame[r].x, frame[r].y] for r in ids])
        fit = fit_structure(tpl, pos, metric=mission.metric)
        out.append((t, fit.pose, dict(zip(ids, map(float, fit.residuals_m)))))
    return out


def deviation_stats(fitted: Sequence[tuple[float, Pose2, Mapping[str, float]]]) -> list[DeviationStats]:
    if not fitted:
        return []
    robots = sorted(fitted[0][2])
    out = []
    for r in robots:
        d = np.array([f[2][r] for f in fitted])
        out.append(DeviationStats(r, float(d.mean()), float(d.std()), float(d.max()), len(d)))
    return out


@dataclass(frozen=True)
class Agreement:
    """How far agents' copies of the structure disagree, over frames seen by >= 2 agents.

    frames: frames compared; identical: frames where every agent's (x, y, th, gx, gy, gth)
    are bit-identical; max_pos_m / max_th_rad: the largest difference seen.
    """

    frames: int
    identical: int
    max_pos_m: float
    max_th_rad: float


def pose_spread(poses: Sequence[tuple[float, float, float]]) -> tuple[float, float]:
    """Largest pairwise position [m] and heading [rad] difference among (x, y, th) poses."""
    pos = max((math.hypot(a[0] - b[0], a[1] - b[1]) for a in poses for b in poses), default=0.0)
    th = max((abs(angle_diff(a[2], b[2])) for a in poses for b in poses), default=0.0)
    return pos, th


def agreement(states: Iterable[tuple[str, StateMsg]], min_agents: int = 2,
              complete_only: bool = True) -> Agreement:
    """Compare agents frame by frame; with complete_only, only frames every agent saw whole."""
    by_seq: dict[int, dict[str, StateMsg]] = {}
    for agent, msg in states:
        by_seq.setdefault(msg.seq, {})[agent] = msg
    frames = identical = 0
    max_pos = max_th = 0.0
    for seq, group in by_seq.items():
        if len(group) < min_agents or (complete_only and not all(m.complete for m in group.values())):
            continue
        frames += 1
        vals = [(m.x, m.y, m.th, m.gx, m.gy, m.gth, m.shape) for m in group.values()]   # the shape taken too
        if all(v == vals[0] for v in vals):
            identical += 1
            continue
        for part in ([v[:3] for v in vals], [v[3:6] for v in vals]):  # fitted, then advanced pose
            pos, th = pose_spread(part)
            max_pos, max_th = max(max_pos, pos), max(max_th, th)
    return Agreement(frames, identical, max_pos, max_th)


def goal_distance(mission: Mission, pose: Pose2) -> float:
    """Distance [m] from a structure pose to the mission's final goal (0 for a twist mission)."""
    if mission.goal is not None:
        gx, gy = mission.goal[0], mission.goal[1]
    elif mission.path is not None:
        gx, gy = mission.path[-1][0], mission.path[-1][1]
    else:
        return 0.0
    return math.hypot(gx - pose.x, gy - pose.y)


def min_gap_m(mission: Mission, frames: Sequence[tuple[float, Mapping[str, TruthMsg]]]) -> float:
    """The smallest clearance [m] over the frames between two robot bodies, or a body and an obstacle:
    centre distance less the radii (the mission's ``radius``, 0 for a point robot; an obstacle's r).
    Negative means contact. +inf when the mission knows no bodies and no obstacles, or no frame has two
    things to compare."""
    radii = dict(zip(mission.robot_ids, mission.radii))
    if not any(radii.values()) and not mission.obstacles:
        return math.inf
    obstacles = np.array(mission.obstacles, dtype=float).reshape(-1, 3)
    gap = math.inf
    for _, robots in frames:
        ids = [r for r in robots if r in radii]
        if not ids:
            continue
        xy = np.array([[robots[r].x, robots[r].y] for r in ids])
        rad = np.array([radii[r] for r in ids])
        if len(ids) > 1:
            d = np.hypot(xy[:, None, 0] - xy[None, :, 0], xy[:, None, 1] - xy[None, :, 1]) - rad[:, None] - rad[None, :]
            gap = min(gap, float(d[np.triu_indices(len(ids), 1)].min()))
        if len(obstacles):
            d = np.hypot(xy[:, None, 0] - obstacles[None, :, 0], xy[:, None, 1] - obstacles[None, :, 1])
            gap = min(gap, float((d - rad[:, None] - obstacles[None, :, 2]).min()))
    return gap
