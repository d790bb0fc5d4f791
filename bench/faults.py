"""Robot faults in the closed loop: the bound on formation error for each fault and failure policy.

Runs the paper-failure scenario offline (the real agents, simulated physics, tracker noise)
with r2 faulted at 8 s: stop, one wheel dead, both wheels at 50%, a 2 s stall and a 4 s
stall, under on_failure = hold, drop and rejoin. Prints a markdown table and writes
docs/img/faults.png (structure path and formation error over time, hold policy).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from fleetctl.scenario_file import load_scenario  # noqa: E402
from simfleet.offline import run_offline  # noqa: E402
from vsfleet.fit import fit_structure  # noqa: E402
from vsfleet.scenario import FaultEvent  # noqa: E402
from vsfleet.step import mission_template  # noqa: E402

FAULT_AT_S = 8.0
FAULTS = [("stop", "stop", 0.0, 0.0), ("one wheel dead", "wheel", 0.0, 0.0), ("slowed to 50%", "slow", 0.5, 0.0),
          ("stall 2 s", "stall", 0.0, 2.0), ("stall 4 s", "stall", 0.0, 4.0)]
POLICIES = ("hold", "drop", "rejoin")


def formation_errors(run, mission) -> np.ndarray:
    """Per frame: max distance [m] of the robots still in the structure from their points,
    under the structure fitted to those robots (a dropped robot is out of it from its drop on)."""
    template = mission_template(mission)
    ids = list(run.robots)
    events = sorted((d.t, d.kind, d.robot) for d in next(iter(run.decisions.values())))
    out = []
    for k, (t, _pose) in enumerate(run.trace):
        dropped = set()
        for te, kind, robot in events:
            if te <= t:
                if kind == "drop":
                    dropped.add(robot)
                elif kind == "rejoin":
                    dropped.discard(robot)
        rows = [i for i, r in enumerate(ids) if r not in dropped]
        fit = fit_structure(template[rows], run.positions_m[k][rows], metric=mission.metric)
        out.append(float(np.max(fit.residuals_m)))
    return np.array(out)


def swerve_m(run, mission) -> float:
    """Largest distance of the structure's path from the straight line start -> goal [m]."""
    (x0, y0), (gx, gy) = (run.trace[0][1].x, run.trace[0][1].y), mission.goal[:2]
    ux, uy = gx - x0, gy - y0
    n = math.hypot(ux, uy)
    return max(abs((p.x - x0) * uy - (p.y - y0) * ux) / n for _, p in run.trace)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated seconds per run")
    ap.add_argument("--plot", default=str(ROOT / "docs" / "img" / "faults.png"))
    args = ap.parse_args(argv)
    logging.getLogger("vsfleet").setLevel(logging.ERROR)  # the agents' decisions are in the table
    base = load_scenario(ROOT / "scenarios" / "paper-failure.toml")
    jobs = [(f, p) for f in FAULTS for p in POLICIES]
    rows, curves = [], {}
    t_start = time.monotonic()
    for i, ((label, kind, factor, duration), policy) in enumerate(jobs):
        sc = dataclasses.replace(base, mission=dataclasses.replace(base.mission, on_failure=policy),
                                 faults=(FaultEvent("r2", FAULT_AT_S, kind, factor, duration),))
        run = run_offline(sc, args.seconds, seed=2, stop_at_goal=False)
        err = formation_errors(run, sc.mission)
        ts = np.array([t for t, _ in run.trace])
        during = err[ts >= FAULT_AT_S]
        decisions = next(iter(run.decisions.values()))
        agree = all(v == decisions for v in run.decisions.values())
        goal = f"{run.t_goal_s:.1f} s" if run.t_goal_s is not None else "not reached"
        made = ", ".join(f"{d.kind} {d.robot} @{d.t:.2f}" for d in decisions) or "none"
        rows.append((label, policy, made, "yes" if agree else "NO", 100 * float(during.max()),
                     100 * float(np.mean(during)), 100 * swerve_m(run, sc.mission), goal))
        if policy == "hold":
            curves[label] = (ts, err, [(p.x, p.y) for _, p in run.trace])
        done = i + 1
        eta = (time.monotonic() - t_start) / done * (len(jobs) - done)
        print(f"[{done}/{len(jobs)}] {label} / {policy}: max {rows[-1][4]:.2f} cm, goal {goal}  "
              f"(ETA {eta:.0f} s)", file=sys.stderr, flush=True)
    print("| fault on r2 at 8 s | on_failure | decisions (every agent, tracker time from start) | agents agree "
          "| max formation error after the fault (cm) | mean (cm) | structure swerve (cm) | goal |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]} | {r[4]:.2f} | {r[5]:.2f} | {r[6]:.1f} | {r[7]} |")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.5))
    for label, (ts, err, path) in curves.items():
        xy = np.array(path)
        ax1.plot(xy[:, 0], xy[:, 1], label=label)
        ax2.plot(ts, 100 * err, label=label)
    ax1.plot(*base.mission.goal[:2], "k*", ms=12, label="goal")
    ax1.set(title="structure path (on_failure = hold)", xlabel="x [m]", ylabel="y [m]", aspect="equal")
    ax2.axvline(FAULT_AT_S, color="grey", ls=":")
    ax2.set(title="formation error (max over robots)", xlabel="t [s]", ylabel="cm")
    ax1.legend(fontsize=8)
    ax2.legend(fontsize=8)
    fig.tight_layout()
    Path(args.plot).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.plot, dpi=110)
    print(f"\nplot: {args.plot}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
