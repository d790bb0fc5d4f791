"""Crowded starts in a shuffled order, offline (issue 28, "Crowds"): does the fleet assemble?

n robots (a multiple of 5) start packed in a block of n/5 rows x 5 columns, centres 0.12 m apart (bodies of
radius 0.05 m: 2 cm gaps), random headings; each is assigned to a point of a grid of the same shape with
0.3 m spacing, in a random (shuffled) order, so the template must untangle the block. The mission's goal is
the grid centred where the block is (the origin, heading 0), so the structure itself barely moves: what is
measured is assembly. simfleet.offline.run_offline (the real agents, kinematic physics at 120 Hz, tracker
at 30 Hz, noise sigma 1 mm / 5 mrad), l2, 0.08 m/s, 0.3 rad/s, wheel base 0.12 m, 0.3 m/s, 0.8 m/s^2,
failure rule on_failure = hold with its default thresholds.

Per seed: t_assembled_s, the first frame at which every robot is within ASSEMBLED_M of its point on the
structure fitted to the true positions (None: not within duration_s); the smallest gap between two bodies
over the run and the frames in which two bodies overlap (contacts); the failure decisions (robot, t, kind)
of agent r01 (every agent decides the same); the largest deviation at the end and how many robots are
within ASSEMBLED_M of their points then.

    PYTHONPATH=. .venv/bin/python -m bench.crowd --n 10 --seeds 1,2,3 --duration 60

``--tiebreak-cost 10,30,100`` measures instead what the tie-break costs per frame at a crowd's first frame
(:func:`tiebreak_cost_us`).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

from vsfleet.scenario import scenario_from_dict
from vsfleet.simfleet.offline import run_offline

from .room import min_gaps_m

RADIUS_M = 0.05
PITCH_START_M = 0.12      # centres in the packed block: 2 cm gaps
PITCH_GRID_M = 0.3        # the template's spacing
COLS = 5
ASSEMBLED_M = 0.01
GOAL = (1.5, 0.5, 0.0)   # the goal of scenarios/crowd-10.toml


def crowd_doc(n: int, seed: int, duration_s: float, goal=GOAL) -> dict:
    """The shuffled crowd of n robots (seed) as a scenario table (vsfleet.scenario.scenario_from_dict)."""
    if n % COLS:
        raise ValueError(f"n must be a multiple of {COLS}, got {n}")
    rows = n // COLS
    rng = np.random.default_rng(seed)
    cells = [((c - (COLS - 1) / 2), (r - (rows - 1) / 2)) for r in range(rows) for c in range(COLS)]
    order = rng.permutation(n)          # robot i starts in block cell order[i], its point is grid cell i
    heading = rng.uniform(-math.pi, math.pi, n)
    gains = 1.0 + rng.uniform(-0.03, 0.03, (n, 2))
    robots = {}
    for i in range(n):
        gx, gy = cells[i]
        bx, by = cells[int(order[i])]
        robots[f"r{i + 1:02d}"] = {"p": [gx * PITCH_GRID_M, gy * PITCH_GRID_M],
                                   "start": [bx * PITCH_START_M, by * PITCH_START_M, float(heading[i])],
                                   "gain": [float(gains[i, 0]), float(gains[i, 1])]}
    return {"schema": 1, "fleet": {"name": "crowd", "duration_s": duration_s},
            "mission": {"metric": "l2", "speed_max": 0.08, "turn_rate_max": 0.3,
                        "goal": {"x": goal[0], "y": goal[1], "th": goal[2]}},
            "tracker": {"rate_hz": 30.0, "noise_xy_m": 0.001, "noise_th_rad": 0.005, "latency_s": 0.005},
            "sim": {"rate_hz": 120.0, "truth_rate_hz": 30.0},
            "defaults": {"wheel_base": 0.12, "wheel_speed_max": 0.3, "wheel_accel_max": 0.8, "radius": RADIUS_M},
            "robots": robots}


def measure(n: int, seed: int, duration_s: float, goal=GOAL) -> dict:
    """One shuffled crowd's run: see the module docstring."""
    scenario = scenario_from_dict(crowd_doc(n, seed, duration_s, goal), name=f"crowd-{n}-{seed}")
    wall = time.perf_counter()
    run = run_offline(scenario, duration_s, seed=seed, stop_at_goal=False)
    wall = time.perf_counter() - wall
    dt_s = duration_s / len(run.deviations_m)
    worst = run.deviations_m.max(axis=1)
    within = np.flatnonzero(worst < ASSEMBLED_M)
    radii = np.full(n, RADIUS_M)
    gap_m, _ = min_gaps_m(run.positions_m, radii, np.zeros((0, 3)))
    iu = np.triu_indices(n, 1)
    p = run.positions_m
    d = np.hypot(p[:, iu[0], 0] - p[:, iu[1], 0], p[:, iu[0], 1] - p[:, iu[1], 1]) - 2 * RADIUS_M
    contact_frames = int((d < 0.0).any(axis=1).sum())
    decisions = [(d_.robot, round(d_.t, 2), d_.kind) for d_ in run.decisions[run.robots[0]]
                 if d_.kind in ("fail", "recover", "drop", "rejoin")]
    still = sorted(set(r for r, _, k in decisions if k == "fail") - set(r for r, _, k in decisions if k == "recover"))
    return {"n": n, "seed": seed, "duration_s": duration_s,
            "t_assembled_s": round(float((within[0] + 1) * dt_s), 2) if within.size else None,
            "final_worst_m": round(float(worst[-1]), 4),
            "placed_at_end": int((run.deviations_m[-1] < ASSEMBLED_M).sum()), "min_gap_m": round(gap_m, 4),
            "contact_frames": contact_frames,
            "fails": sum(1 for _, _, k in decisions if k == "fail"),
            "first_fail_s": min((t for _, t, k in decisions if k == "fail"), default=None),
            "failed_at_end": still, "decisions": decisions, "wall_s": round(wall, 1)}


def tiebreak_cost_us(n: int, seed: int = 1, repeats: int = 200) -> dict:
    """The assembly tie-break's cost per frame [us] at a crowd's first frame: n robots packed in crowd_doc's block,
    their points the shuffled grid round the block's centre, so that nearly every robot is on its way and barred.
    ``core_us``: the compiled vs_assembly_targets, the call as the step makes it (outputs allocated once; the
    agent's step calls it in C, so this includes one Python call's overhead); ``reference_us``: the numpy
    reference; ``assembled_core_us``: the core once every robot stands on its point. Medians over ``repeats``
    calls (the reference: a tenth as many, at least 5)."""
    from vsfleet import _core  # noqa: PLC0415 - only this mode
    from vsfleet.assembly import assembly_targets_reference  # noqa: PLC0415
    doc = crowd_doc(n, seed, 1.0)
    ids = sorted(doc["robots"])
    pose = np.array([doc["robots"][r]["start"] for r in ids], dtype=float)
    points = np.array([doc["robots"][r]["p"] for r in ids], dtype=float)
    radii, seen = np.full(n, RADIUS_M), np.ones(n, dtype=bool)
    now, nxt, det = np.empty((n, 2)), np.empty((n, 2)), np.empty(n, dtype=bool)
    args = (radii, pose, seen, points, points, 0.015, 0.0, now, nxt, det)

    def median_us(fn, count: int) -> float:
        times = []
        for _ in range(count):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        return float(np.median(times)) * 1e6

    core = median_us(lambda: _core.assembly_targets(*args), repeats)
    detoured = int(det.sum())
    ref = median_us(lambda: assembly_targets_reference(radii, pose, seen, points, points, 0.015, 0.0),
                    max(5, repeats // 10))
    placed = np.ascontiguousarray(pose[:, :2])          # every robot on its point: the frames after assembly
    assembled = median_us(lambda: _core.assembly_targets(radii, pose, seen, placed, placed, 0.015, 0.0, now, nxt, det),
                          repeats)
    return {"n": n, "detoured": detoured, "core_us": round(core, 1), "reference_us": round(ref, 1),
            "assembled_core_us": round(assembled, 1)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10)
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--goal", default="1.5,0.5,0", help="the mission's goal x,y,th [m, m, rad]")
    ap.add_argument("--json", action="store_true", help="one JSON record per seed (with every decision)")
    ap.add_argument("--tiebreak-cost", metavar="SIZES",
                    help="instead: the tie-break's cost per frame at these crowd sizes (e.g. 10,30,100)")
    a = ap.parse_args(argv)
    if a.tiebreak_cost:
        for n in (int(v) for v in a.tiebreak_cost.split(",")):
            rec = tiebreak_cost_us(n)
            print(json.dumps(rec) if a.json else
                  f"n={n}: tie-break {rec['core_us']} us per frame in the core, {rec['reference_us']} us in the "
                  f"numpy reference ({rec['detoured']} robots sent round); {rec['assembled_core_us']} us once "
                  f"assembled", flush=True)
        return 0
    for seed in (int(s) for s in a.seeds.split(",")):
        rec = measure(a.n, seed, a.duration, tuple(float(v) for v in a.goal.split(",")))
        if a.json:
            print(json.dumps(rec), flush=True)
        else:
            print(f"n={rec['n']} seed={seed}: assembled {rec['t_assembled_s']} s, end worst {rec['final_worst_m']} m, "
                  f"placed at the end {rec['placed_at_end']}/{rec['n']}, min gap {rec['min_gap_m']} m, contact frames {rec['contact_frames']}, fails {rec['fails']} "
                  f"(first {rec['first_fail_s']} s, failed at end {len(rec['failed_at_end'])}), "
                  f"wall {rec['wall_s']} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
