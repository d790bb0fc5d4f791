"""Missions in a room through vsfleet's own step: randomised scenarios run offline (simfleet.offline: the
real agents on counted frames, simfleet's physics at 120 Hz, tracker noise sigma 2 mm).

The scenarios are bench/safety.py's (make_scenario: N 3..30, random templates, random crowded starts
1.5-4 cm apart, 0-6 round obstacles between the start and the goal, 1.5-3 m away), given to the fleet as
a mission with robot bodies of 0.05 m: the structure plans its path around the obstacles every frame,
and every command passes the safety filter. Reported per scenario and pooled: contacts (truth, every
physics step), the smallest gap, whether and when the structure reached its goal (within 5 mm), the
formation deviation (robots from their points on the structure fitted to the truth) while any robot
is within 0.3 m of an obstacle, and blocked events.

    .venv/bin/python -m bench.room --scenarios 40      # progress on stderr, table on stdout
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from vsfleet.scenario import scenario_from_dict
from vsfleet.simfleet.offline import run_offline

from .safety import RADIUS, make_scenario


def to_vsfleet(sc, duration_s: float):
    robots = {f"r{i + 1:02d}": {"p": [float(p[0]), float(p[1])], "start": [float(v) for v in sc.start[i]]}
              for i, p in enumerate(sc.template)}
    doc = {"schema": 1, "fleet": {"name": "room", "duration_s": duration_s},
           "mission": {"metric": "l2", "speed_max": 0.1, "turn_rate_max": 0.3,
                       "goal": {"x": sc.goal[0], "y": sc.goal[1], "th": sc.goal[2]},
                       **({"obstacles": [[float(v) for v in o] for o in sc.obstacles]} if len(sc.obstacles) else {})},
           "tracker": {"rate_hz": 30.0, "noise_xy_m": 0.002, "noise_th_rad": 0.005, "latency_s": 0.0},
           "sim": {"rate_hz": 120.0, "truth_rate_hz": 30.0},
           "defaults": {"wheel_base": 0.12, "wheel_speed_max": 0.3, "wheel_accel_max": 0.8, "radius": RADIUS},
           "robots": robots}
    return scenario_from_dict(doc)


def evaluate(seed: int, duration_s: float) -> dict:
    sc = make_scenario(seed)
    scenario = to_vsfleet(sc, duration_s)
    t0 = time.perf_counter()
    run = run_offline(scenario, duration_s, seed=seed)
    wall = time.perf_counter() - t0
    pos, rad, obs = run.positions_m, RADIUS, sc.obstacles
    gap, near_dev = math.inf, []
    for k in range(pos.shape[0]):
        P = pos[k]
        d = np.hypot(P[:, None, 0] - P[None, :, 0], P[:, None, 1] - P[None, :, 1]) - 2 * rad
        gap = min(gap, float(d[np.triu_indices(len(P), 1)].min()))
        if len(obs):
            do = np.hypot(P[:, None, 0] - obs[None, :, 0], P[:, None, 1] - obs[None, :, 1]) - rad - obs[None, :, 2]
            gap = min(gap, float(do.min()))
            if float(do.min()) < 0.3:
                near_dev.append(float(np.mean(run.deviations_m[k])))
    blocked = sum(d.kind == "blocked" for d in next(iter(run.decisions.values())))
    return {"seed": seed, "n": sc.n, "obstacles": len(obs), "gap_m": gap, "goal_s": run.t_goal_s,
            "dev_near_m": float(np.mean(near_dev)) if near_dev else math.nan, "blocked": blocked, "wall_s": wall}


def picture(path: str, scenario_path: str, seed: int = 1) -> None:
    """One run drawn: every robot's path, its body at the start and at the end, the obstacles."""
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    from vsfleet.zglue.scenario_file import load_scenario  # noqa: PLC0415
    scenario = load_scenario(scenario_path)
    run = run_offline(scenario, 90.0, seed=seed)
    radii = dict(zip(scenario.mission.robot_ids, scenario.mission.radii))
    fig, ax = plt.subplots(figsize=(6, 5))
    for x, y, r in scenario.mission.obstacles:
        ax.add_patch(plt.Circle((x, y), r, color="0.6"))
    for i, robot in enumerate(run.robots):
        xy = run.positions_m[:, i]
        line, = ax.plot(xy[:, 0], xy[:, 1], lw=1, label=robot)
        for k, style in ((0, ":"), (-1, "-")):
            ax.add_patch(plt.Circle(tuple(xy[k]), radii[robot], fill=False, ls=style, color=line.get_color()))
    centre = np.array([[p.x, p.y] for _, p in run.trace])
    ax.plot(centre[:, 0], centre[:, 1], "k--", lw=0.8, label="structure origin")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m; world]")
    ax.set_ylabel("y [m; world]")
    ax.set_title(f"{scenario.name}: goal at {run.t_goal_s:.1f} s (dotted: start, solid: end)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", type=int, default=200)
    ap.add_argument("--seconds", type=float, default=90.0, help="simulated seconds per scenario at most")
    ap.add_argument("--picture", default=None, help="also draw scenarios/paper-triangle-obstacle.toml's run here")
    a = ap.parse_args(argv)
    if a.picture:
        picture(a.picture, "scenarios/paper-triangle-obstacle.toml")
    rows, t0 = [], time.perf_counter()
    for seed in range(a.scenarios):
        r = evaluate(seed, a.seconds)
        rows.append(r)
        el = time.perf_counter() - t0
        print(f"[room {seed + 1}/{a.scenarios}] N={r['n']:2d} obstacles={r['obstacles']} gap {1e3 * r['gap_m']:7.1f} mm "
              f"goal {'-' if r['goal_s'] is None else round(r['goal_s'], 1)} s "
              f"blocked {r['blocked']}  (ETA {el / (seed + 1) * (a.scenarios - seed - 1):.0f} s)", file=sys.stderr, flush=True)
    contacts = sum(r["gap_m"] < 0 for r in rows)
    reached = [r for r in rows if r["goal_s"] is not None]
    near = [r["dev_near_m"] for r in rows if not math.isnan(r["dev_near_m"])]
    print(f"| scenarios | runs with contact | min gap | reached the goal | median time to goal | "
          f"mean deviation near obstacles | blocked |")
    print("|---|---|---|---|---|---|---|")
    print(f"| {len(rows)} | {contacts} | {1e3 * min(r['gap_m'] for r in rows):.1f} mm | {len(reached)}/{len(rows)} | "
          f"{np.median([r['goal_s'] for r in reached]) if reached else math.nan:.1f} s | "
          f"{1e2 * np.mean(near) if near else math.nan:.2f} cm | {sum(r['blocked'] > 0 for r in rows)} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
