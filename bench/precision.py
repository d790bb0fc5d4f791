"""Precision against the paper: deviation from the structure in the paper's scenario.

The closed loop of simfleet.offline.run_offline (the real Agent objects, the
simulated physics with unequal wheel gains, a noisy tracker, commands applied
one frame after the observation) on scenarios/paper-triangle.toml, for each
controller and each metric. A robot's deviation at a frame is its distance from
its template point under the structure fitted (with the run's metric) to the
true positions; it is pooled over robots, frames (until the structure is within
5 mm of the goal, else the whole run) and seeds.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from simfleet.offline import run_offline
from vsfleet.analysis import goal_distance
from vsfleet.control import CONTROLLERS
from vsfleet.scenario import Scenario
from vsfleet.wire import METRICS

# the paper's names for them
CONTROLLER_LABELS = {"turn_then_go": "turn then go (eqs 9-11)", "arc": "arc (eqs 12-16)",
                     "tracking": "tracking (Kanayama)"}


@dataclass(frozen=True)
class PrecisionRow:
    controller: str
    metric: str
    noise_xy_m: float
    mean_m: float
    std_m: float
    max_m: float
    samples: int
    t_goal_s: tuple[float | None, ...]   # per seed
    goal_left_m: tuple[float, ...]       # per seed: distance of the structure to the goal at the end


def precision_row(scenario: Scenario, controller: str, metric: str, seeds, duration_s: float,
                  noise_xy_m: float | None = None) -> PrecisionRow:
    devs, goals, left = [], [], []
    for seed in seeds:
        run = run_offline(scenario, duration_s, controller=controller, metric=metric, seed=seed,
                          noise_xy_m=noise_xy_m)
        devs.append(run.deviations_m.ravel())
        goals.append(run.t_goal_s)
        left.append(goal_distance(scenario.mission, run.trace[-1][1]))
    d = np.concatenate(devs)
    nxy = scenario.tracker.noise_xy_m if noise_xy_m is None else noise_xy_m
    return PrecisionRow(controller, metric, nxy, float(d.mean()), float(d.std()), float(d.max()), int(d.size),
                        tuple(goals), tuple(left))


def precision_table(scenario: Scenario, seeds=(1, 2, 3), duration_s: float | None = None,
                    log=print) -> list[PrecisionRow]:
    """Every controller x metric, pooled over seeds."""
    duration = scenario.duration_s if duration_s is None else duration_s
    jobs = [(c, m) for c in CONTROLLERS for m in METRICS]
    rows, t0 = [], time.perf_counter()
    for i, (c, m) in enumerate(jobs):
        eta = f"ETA {(time.perf_counter() - t0) / i * (len(jobs) - i):.0f} s" if i else "ETA ?"
        log(f"[precision {i + 1}/{len(jobs)}] {c} {m} ({len(seeds)} seeds) {eta}")
        rows.append(precision_row(scenario, c, m, seeds, duration))
    return rows


def noise_sweep(scenario: Scenario, controller: str, metric: str, noises_m=(0.0, 0.001, 0.002, 0.005),
                seeds=(1,), duration_s: float | None = None, log=print) -> list[PrecisionRow]:
    """One controller and metric at several tracker position noises (heading noise as the scenario)."""
    duration = scenario.duration_s if duration_s is None else duration_s
    out = []
    for i, nz in enumerate(noises_m):
        log(f"[precision noise {i + 1}/{len(noises_m)}] sigma {1e3 * nz:.0f} mm")
        out.append(precision_row(scenario, controller, metric, seeds, duration, nz))
    return out
