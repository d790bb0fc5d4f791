"""Robot faults in the closed loop: the bound on formation error for each fault and failure policy.

The paper triangle under the issue-13 conditions (bench/conditions.py: sigma 2 mm / 0.01 rad,
30 Hz, commands one frame late, wheel gains within +-4%, a 2.5 m leg at 0.1 m/s), offline (the
real agents, simulated physics), with r2 faulted at 8 s: stopped for good, one wheel dead, both
wheels at 50% for good and for 8 s, a 2 s and a 4 s stall; under on_failure = hold, drop and
rejoin, over seeds. Prints a markdown table (worst over the seeds) and draws the paper's Fig. 12
again (fig12-faults.png: structure path and formation error over time, hold, the first seed) into
runs/bench/faults/, or --out DIR, or with --docs docs/img/ (as make bench does: bench/run_all.py).

Run: .venv/bin/python bench/faults.py [--seeds 1 2 3] [--seconds 45] [--out DIR | --docs]
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.conditions import issue_scenario  # noqa: E402
from bench.outputs import DOCS, add_output_flags  # noqa: E402
from vsfleet.simfleet.offline import run_offline  # noqa: E402
from vsfleet.fit import fit_structure  # noqa: E402
from vsfleet.scenario import FaultEvent  # noqa: E402
from vsfleet.step import mission_template  # noqa: E402

FAULT_AT_S = 8.0
FAULTS = [("stop", "stop", 0.0, 0.0), ("one wheel dead", "wheel", 0.0, 0.0),
          ("slowed to 50%", "slow", 0.5, 0.0), ("slowed to 50% for 8 s", "slow", 0.5, 8.0),
          ("stall 2 s", "stall", 0.0, 2.0), ("stall 4 s", "stall", 0.0, 4.0)]
POLICIES = ("hold", "drop", "rejoin")
HALTED_M = 0.005     # the structure counts as halted if it moved less than this from 2 s into the fault
FIG12 = "fig12-faults.png"


def _in_structure(run, k_frames: int) -> list[np.ndarray]:
    """Per frame: the rows of the robots still in the structure (a dropped robot is out from its drop on)."""
    ids = list(run.robots)
    events = sorted((d.t, d.kind, d.robot) for d in next(iter(run.decisions.values())))
    out = []
    for k in range(k_frames):
        t = run.trace[k][0]
        dropped = set()
        for te, kind, robot in events:
            if te <= t:
                if kind == "drop":
                    dropped.add(robot)
                elif kind == "rejoin":
                    dropped.discard(robot)
        out.append(np.array([i for i, r in enumerate(ids) if r not in dropped]))
    return out


def formation_errors(run, mission) -> np.ndarray:
    """Per frame: max distance [m] of the robots still in the structure from their points,
    under the structure fitted to those robots (a dropped robot is out of it from its drop on)."""
    template = mission_template(mission)
    out = []
    for k, rows in enumerate(_in_structure(run, len(run.trace))):
        fit = fit_structure(template[rows], run.positions_m[k][rows], metric=mission.metric)
        out.append(float(np.max(fit.residuals_m)))
    return np.array(out)


def structure_travel_m(run, mission, t0: float, t1: float) -> float:
    """How far [m] the structure fitted to the robots still in it (at t1) moved from t0 to t1."""
    template = mission_template(mission)
    ts = np.array([t for t, _ in run.trace])
    k0, k1 = int(np.searchsorted(ts, t0)), int(np.searchsorted(ts, t1)) - 1
    if k1 <= k0:
        return math.nan
    rows = _in_structure(run, len(run.trace))
    a = fit_structure(template[rows[k1]], run.positions_m[k0][rows[k1]], metric=mission.metric).pose
    b = fit_structure(template[rows[k1]], run.positions_m[k1][rows[k1]], metric=mission.metric).pose
    return math.hypot(b.x - a.x, b.y - a.y)


def goal_time_s(run, mission, tol_m: float = 0.005) -> float | None:
    """First time [s] the structure fitted to the robots still in it came within tol_m of the goal."""
    template = mission_template(mission)
    rows = _in_structure(run, len(run.trace))
    for k in range(0, len(run.trace), 3):
        pose = fit_structure(template[rows[k]], run.positions_m[k][rows[k]], metric=mission.metric).pose
        if math.hypot(pose.x - mission.goal[0], pose.y - mission.goal[1]) < tol_m:
            return run.trace[k][0]
    return None


def swerve_m(run, mission) -> float:
    """Largest distance of the structure's path from the straight line start -> goal [m]."""
    (x0, y0), (gx, gy) = (run.trace[0][1].x, run.trace[0][1].y), mission.goal[:2]
    ux, uy = gx - x0, gy - y0
    n = math.hypot(ux, uy)
    return max(abs((p.x - x0) * uy - (p.y - y0) * ux) / n for _, p in run.trace)


def fault_case(label, kind, factor, duration, policy, seed, seconds):
    sc = issue_scenario(seed)
    sc = dataclasses.replace(sc, mission=dataclasses.replace(sc.mission, on_failure=policy),
                             faults=(FaultEvent("r2", FAULT_AT_S, kind, factor, duration),))
    run = run_offline(sc, seconds, seed=seed, stop_at_goal=False)
    err = formation_errors(run, sc.mission)
    ts = np.array([t for t, _ in run.trace])
    decisions = next(iter(run.decisions.values()))
    agree = all(v == decisions for v in run.decisions.values())
    healthy_flagged = any(d.robot != "r2" for v in run.decisions.values() for d in v)
    end_fault = FAULT_AT_S + (duration if duration > 0 else seconds)
    # during the fault, from 2 s after it began (the structure's reaction; 1 s for a 2 s stall) to
    # its end (or the run's)
    react_s = min(2.0, 0.5 * duration) if duration > 0 else 2.0
    travel = structure_travel_m(run, sc.mission, FAULT_AT_S + react_s, min(end_fault, seconds) - 0.1)
    return dict(run=run, sc=sc, ts=ts, err=err, max_m=float(err[ts >= FAULT_AT_S].max()),
                mean_m=float(err[ts >= FAULT_AT_S].mean()), decisions=decisions, agree=agree,
                healthy_flagged=healthy_flagged, halted=travel < HALTED_M, travel=travel,
                goal=goal_time_s(run, sc.mission), swerve=swerve_m(run, sc.mission))


def _curve(case) -> tuple:
    """One fault's line in Fig. 12: (t, formation error, the structure's path)."""
    return case["ts"], case["err"], np.array([(p.x, p.y) for _, p in case["run"].trace])


def fig12(out_dir: Path, seed: int = 1, seconds: float = 45.0) -> Path:
    """Fig. 12 alone, as main draws it (every fault under hold, one seed), into out_dir."""
    curves = {}
    for label, kind, factor, duration in FAULTS:
        case = fault_case(label, kind, factor, duration, "hold", seed, seconds)
        curves[label] = _curve(case)
    path = out_dir / FIG12
    plot_fig12(curves, case["sc"].mission.goal, path)
    return path


def plot_fig12(curves, goal, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.5))
    for label, (ts, err, xy) in curves.items():
        ax1.plot(xy[:, 0], xy[:, 1], label=label)
        ax2.plot(ts, 100 * err, label=label, lw=0.9)
    ax1.plot(*goal[:2], "k*", ms=12, label="goal")
    ax1.set(title="Fig. 12 again: structure path, r2 faulted at 8 s (hold)", xlabel="x [m]", ylabel="y [m]",
            aspect="equal")
    ax2.axvline(FAULT_AT_S, color="grey", ls=":")
    ax2.axhline(2.5, color="red", ls="--", lw=0.8, label="2.5 cm (stop bound)")
    ax2.axhline(1.0, color="orange", ls="--", lw=0.8, label="1 cm (slow bound)")
    ax2.set(title="formation error (max over robots)", xlabel="t [s]", ylabel="cm")
    ax1.legend(fontsize=7)
    ax2.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=45.0, help="simulated seconds per run")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    add_output_flags(ap, "faults", DOCS / "img", f"the plot ({FIG12})")
    args = ap.parse_args(argv)
    logging.getLogger("vsfleet").setLevel(logging.ERROR)  # the agents' decisions are in the table
    jobs = [(f, p) for f in FAULTS for p in POLICIES]
    rows, curves = [], {}
    t_start = time.monotonic()
    for i, ((label, kind, factor, duration), policy) in enumerate(jobs):
        cases = [fault_case(label, kind, factor, duration, policy, s, args.seconds) for s in args.seeds]
        worst = max(cases, key=lambda c: c["max_m"])
        made = ", ".join(f"{d.kind} {d.robot} @{d.t:.2f}" for d in worst["decisions"]) or "none"
        goals = [c["goal"] for c in cases]
        goal = (f"{np.mean(goals):.1f} s" if all(g is not None for g in goals)
                else f"{sum(g is not None for g in goals)}/{len(goals)} reached")
        rows.append((label, policy, 100 * worst["max_m"], 100 * float(np.mean([c["mean_m"] for c in cases])),
                     "yes" if all(c["halted"] for c in cases) else ("no" if not any(c["halted"] for c in cases)
                                                                   else "some seeds"),
                     100 * max(c["travel"] for c in cases), made,
                     "yes" if all(c["agree"] for c in cases) else "NO",
                     "NO" if not any(c["healthy_flagged"] for c in cases) else "YES", goal))
        if policy == "hold":
            curves[label] = _curve(cases[0])
            goal_xy = cases[0]["sc"].mission.goal
        eta = (time.monotonic() - t_start) / (i + 1) * (len(jobs) - i - 1)
        print(f"[{i + 1}/{len(jobs)}] {label} / {policy}: max {rows[-1][2]:.2f} cm, goal {goal}  "
              f"(ETA {eta:.0f} s)", file=sys.stderr, flush=True)
    print(f"machine: {platform.node()} {platform.machine()}, python {platform.python_version()}, "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; seeds {args.seeds}, {args.seconds:.0f} s per run")
    print()
    print("| fault on r2 at 8 s | on_failure | max formation error after the fault (cm, worst seed) | mean (cm) "
          "| structure halted (moved < 5 mm from 2 s into the fault, 1 s for a 2 s stall, to its end) | it moved (cm, most) | decisions (worst seed, tracker "
          "time) | agents agree | healthy robot flagged | goal (robots still in the structure) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]:.2f} | {r[3]:.2f} | {r[4]} | {r[5]:.2f} | {r[6]} | {r[7]} | {r[8]} "
              f"| {r[9]} |")
    plot_fig12(curves, goal_xy, args.out / FIG12)
    print(f"\nplot: {args.out / FIG12}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
