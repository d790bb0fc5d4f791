"""The issue-13 measuring conditions, shared by bench/precision.py, bench/faults.py and the tests.

The paper triangle (scenarios/paper-triangle.toml) with a tracker at 30 Hz, sigma 2 mm / 0.01 rad,
commands in effect one frame (33 ms) after the observation (10 ms of tracker latency plus the
agent's step and the command's transport), wheel gains drawn per seed within +-4%, and a goal
2.5 m away at speed_max 0.1 m/s. A second mission turns the structure 90 deg while translating.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from vsfleet.zglue.scenario_file import load_scenario
from vsfleet.scenario import Scenario

ROOT = Path(__file__).resolve().parent.parent
NOISE_XY_M = 0.002
NOISE_TH_RAD = 0.01
GAIN_SPREAD = 0.04
SPEED_M_S = 0.1
LEG_M = 2.5


def issue_scenario(seed: int, turn: bool = False, gain_spread: float = GAIN_SPREAD,
                   noise_xy_m: float = NOISE_XY_M, noise_th_rad: float = NOISE_TH_RAD) -> Scenario:
    """The paper triangle under the issue's conditions; wheel gains drawn from ``seed``.

    turn: the goal also turns the structure by 90 deg (turn-while-translating), else by 0.3 rad
    as in the paper's goal. The goal lies LEG_M from the start, at 0.6 rad.
    """
    base = load_scenario(ROOT / "scenarios" / "paper-triangle.toml")
    rng = np.random.default_rng(10_000 + seed)
    robots = tuple(dataclasses.replace(r, gain=tuple(float(g) for g in 1.0 + rng.uniform(-gain_spread, gain_spread, 2)))
                   for r in base.robots)
    th = 0.5 * math.pi if turn else 0.3
    goal = (LEG_M * math.cos(0.6), LEG_M * math.sin(0.6), th)
    mission = dataclasses.replace(base.mission, goal=goal, speed_max=SPEED_M_S)
    tracker = dataclasses.replace(base.tracker, noise_xy_m=noise_xy_m, noise_th_rad=noise_th_rad, latency_s=0.01)
    return dataclasses.replace(base, robots=robots, mission=mission, tracker=tracker, duration_s=45.0)


def ideal_time_s(scenario: Scenario) -> float:
    """Time [s] to the goal at speed_max, ramps ignored (the issue's 'ideal time')."""
    m = scenario.mission
    return math.hypot(m.goal[0], m.goal[1]) / m.speed_max
