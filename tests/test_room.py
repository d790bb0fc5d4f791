"""Missions in a room, offline (simfleet.offline: the real agents on counted frames, simfleet's physics):
the structure goes around an obstacle, a crowded start assembles, and no two bodies touch."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from vsfleet.analysis import min_gap_m
from vsfleet.simfleet.offline import run_offline
from vsfleet.wire import Mission, RobotSpec, TruthMsg
from vsfleet.zglue.scenario_file import load_scenario

ROOT = Path(__file__).resolve().parent.parent


def gap_of(scenario, run) -> float:
    frames = [(k, {r: TruthMsg(t=float(k), x=float(p[0]), y=float(p[1]), th=0.0, vl=0.0, vr=0.0, why="idle")
                   for r, p in zip(run.robots, pos)}) for k, pos in enumerate(run.positions_m)]
    return min_gap_m(scenario.mission, frames)


@pytest.mark.parametrize("name", ["paper-triangle-obstacle", "tight-row"])
def test_the_fleet_reaches_its_goal_without_any_body_touching_another_or_an_obstacle(name):
    scenario = load_scenario(ROOT / "scenarios" / f"{name}.toml")
    run = run_offline(scenario, 90.0, seed=1)
    assert run.t_goal_s is not None
    assert gap_of(scenario, run) > 0.005  # at least 5 mm apart at every frame


def test_the_structure_passes_the_pillar_instead_of_crossing_it():
    scenario = load_scenario(ROOT / "scenarios" / "paper-triangle-obstacle.toml")
    run = run_offline(scenario, 90.0, seed=2)
    (x, y, r), = scenario.mission.obstacles
    centre = np.array([[p.x, p.y] for _, p in run.trace])
    assert np.hypot(centre[:, 0] - x, centre[:, 1] - y).min() > r  # the structure's origin went round it
    assert run.t_goal_s is not None


def test_a_goal_walled_in_stops_the_structure_short_and_every_agent_says_so_once():
    scenario = load_scenario(ROOT / "scenarios" / "paper-triangle-obstacle.toml")
    gx, gy, _ = scenario.mission.goal  # a closed ring of 20 pillars 0.75 m around the goal
    ring = tuple((gx + 0.75 * math.cos(2 * math.pi * k / 20), gy + 0.75 * math.sin(2 * math.pi * k / 20), 0.14)
                 for k in range(20))
    scenario = dataclasses.replace(scenario, mission=dataclasses.replace(scenario.mission, obstacles=ring))
    run = run_offline(scenario, 40.0, seed=1)
    assert run.t_goal_s is None
    assert gap_of(scenario, run) > 0.005
    for robot, decisions in run.decisions.items():
        assert [d.kind for d in decisions] == ["blocked"], robot
    last = run.trace[-1][1]
    assert math.hypot(last.x - gx, last.y - gy) > 0.89  # stopped outside the ring
    assert math.hypot(last.x - gx, last.y - gy) < 1.5   # but came as close as it safely could


def test_min_gap_is_the_smallest_clearance_between_bodies_and_obstacles():
    robots = tuple((r, RobotSpec(p=p, wheel_base=0.1, wheel_speed_max=0.3, wheel_accel_max=1.0, radius=0.05))
                   for r, p in (("a", (0.0, 0.0)), ("b", (1.0, 0.0))))
    mission = Mission(version=1, metric="l2", robots=robots, speed_max=0.1, turn_rate_max=0.1, effective_t=0.0,
                      goal=(0.0, 0.0, 0.0), obstacles=((0.0, 1.0, 0.2),))
    t = {"a": TruthMsg(t=0.0, x=0.0, y=0.0, th=0.0, vl=0.0, vr=0.0, why="idle"),
         "b": TruthMsg(t=0.0, x=0.12, y=0.0, th=0.0, vl=0.0, vr=0.0, why="idle")}
    assert min_gap_m(mission, [(0.0, t)]) == pytest.approx(0.02)
    t["a"] = TruthMsg(t=0.0, x=0.0, y=0.76, th=0.0, vl=0.0, vr=0.0, why="idle")
    assert min_gap_m(mission, [(0.0, t)]) == pytest.approx(-0.01)  # a body inside the obstacle's edge
