"""Precision against the paper: deviation from the structure, under the issue-13 conditions.

The closed loop of simfleet.offline.run_offline (the real Agent objects, the simulated physics,
a noisy tracker, commands in effect one frame after the observation) on the paper triangle
(bench/conditions.py: sigma 2 mm / 0.01 rad, 30 Hz, wheel gains within +-4% drawn per seed, a
goal 2.5 m away at 0.1 m/s), for each controller and metric, and on a 90 deg turn while
translating. A robot's deviation at a frame is its distance from its template point under the
structure fitted (with the run's metric) to the true positions, pooled over robots, frames
(until the structure is within 5 mm of the goal, else the whole run) and seeds.

Figs 9 and 10 again go to runs/bench/precision/, or --out DIR, or with --docs docs/img/ (as make
bench does: bench/run_all.py).

Run: .venv/bin/python bench/precision.py [--seeds 1 2 3] [--out DIR | --docs]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.conditions import NOISE_TH_RAD, NOISE_XY_M, ideal_time_s, issue_scenario  # noqa: E402
from bench.outputs import DOCS, add_output_flags  # noqa: E402
from vsfleet.simfleet.offline import OfflineRun, run_offline  # noqa: E402
from vsfleet.analysis import goal_distance  # noqa: E402
from vsfleet.control import CONTROLLERS, DEFAULT_CONTROLLER  # noqa: E402
from vsfleet.scenario import Scenario  # noqa: E402
from vsfleet.wire import METRICS  # noqa: E402

# the paper's names for them
CONTROLLER_LABELS = {"turn_then_go": "turn then go (eqs 9-11)", "arc": "arc (eqs 12-16)",
                     "tracking": "tracking (Kanayama)", "precision": "precision (feed-forward, filter)"}
SETTLE_S = 3.0  # "max after settling" leaves out the start, where the robots are placed off their points


@dataclass(frozen=True)
class PrecisionRow:
    controller: str
    metric: str
    scenario: str
    noise_xy_m: float
    mean_m: float
    std_m: float
    max_m: float
    max_settled_m: float             # max from SETTLE_S on
    start_m: float                   # max deviation in the first frame (where the robots were placed)
    jitter_m_s: float                # mean |command(k) - command(k-1)| per wheel and frame
    jerk_m_s3: float                 # mean |second difference of the command| / dt^2
    samples: int
    t_goal_s: tuple[float | None, ...]   # per seed
    ideal_s: float
    goal_left_m: tuple[float, ...]       # per seed: distance of the structure to the goal at the end
    overshoot_m: tuple[float, ...]       # per seed: how far the structure went past the goal


def command_smoothness(run: OfflineRun, dt_s: float) -> tuple[float, float]:
    """(mean |frame-to-frame change| [m/s], mean |second difference| / dt^2 [m/s^3]) of the
    commands sent, per wheel, until the goal (or the end)."""
    c = run.commands_m_s
    if run.t_goal_s is not None:
        c = c[: max(3, int(round(run.t_goal_s / dt_s)))]
    d1 = np.abs(np.diff(c, axis=0))
    d2 = np.abs(np.diff(c, 2, axis=0)) / dt_s ** 2
    return float(d1.mean()), float(d2.mean())


def overshoot_m(run: OfflineRun, scenario: Scenario) -> float:
    """Largest distance [m] the structure went past the goal, along the start -> goal line."""
    m = scenario.mission
    x0, y0 = run.trace[0][1].x, run.trace[0][1].y
    ux, uy = m.goal[0] - x0, m.goal[1] - y0
    n = math.hypot(ux, uy)
    return max(0.0, max(((p.x - x0) * ux + (p.y - y0) * uy) / n - n for _, p in run.trace))


def precision_row(controller: str, metric: str, seeds, turn: bool = False, duration_s: float = 60.0,
                  noise_xy_m: float = NOISE_XY_M, after_goal_s: float = 3.0,
                  scenario: Scenario | None = None) -> PrecisionRow:
    """One controller and metric over seeds, on the issue's scenario (bench/conditions.py) or on
    ``scenario`` as it is (its own noise unless noise_xy_m is given)."""
    devs, settled, starts, goals, left, over, jit, jerk = [], [], [], [], [], [], [], []
    ideal = 0.0
    for seed in seeds:
        if scenario is None:
            sc = issue_scenario(seed, turn=turn, noise_xy_m=noise_xy_m)
        else:
            sc = dataclasses.replace(scenario, tracker=dataclasses.replace(scenario.tracker, noise_xy_m=noise_xy_m))
        sc = dataclasses.replace(sc, mission=dataclasses.replace(sc.mission, metric=metric))
        ideal = ideal_time_s(sc)
        dt = 1.0 / sc.tracker.rate_hz
        run = run_offline(sc, duration_s, controller=controller, seed=seed)
        d = run.deviations_m
        devs.append(d.ravel())
        ts = np.array([t for t, _ in run.trace])
        settled.append(d[ts >= SETTLE_S].ravel())
        starts.append(float(d[0].max()))
        goals.append(run.t_goal_s)
        left.append(goal_distance(sc.mission, run.trace[-1][1]))
        j1, j2 = command_smoothness(run, dt)
        jit.append(j1)
        jerk.append(j2)
        if run.t_goal_s is not None:   # the same run continued: does the structure stop at the goal?
            longer = run_offline(sc, run.t_goal_s + after_goal_s, controller=controller, seed=seed,
                                 stop_at_goal=False)
            over.append(overshoot_m(longer, sc))
        else:
            over.append(math.nan)
    d = np.concatenate(devs)
    s = np.concatenate(settled)
    name = scenario.name if scenario is not None else ("turn 90 deg" if turn else "triangle")
    return PrecisionRow(controller, metric, name, noise_xy_m, float(d.mean()),
                        float(d.std()), float(d.max()), float(s.max()) if s.size else math.nan, max(starts),
                        float(np.mean(jit)), float(np.mean(jerk)), int(d.size), tuple(goals), ideal,
                        tuple(left), tuple(over))


def _goal(row: PrecisionRow) -> str:
    reached = [t for t in row.t_goal_s if t is not None]
    if len(reached) < len(row.t_goal_s):
        return f"{len(row.t_goal_s) - len(reached)} of {len(row.t_goal_s)} not reached (left {100 * max(row.goal_left_m):.1f} cm)"
    return f"{np.mean(reached):.1f} s ({np.mean(reached) / row.ideal_s:.2f}x)"


def table(rows: list[PrecisionRow]) -> str:
    out = ["| controller | metric | scenario | mean (cm) | σ (cm) | max (cm) | max after 3 s (cm) "
           "| Δcommand / frame (m/s) | jerk (m/s³) | goal (× ideal) | overshoot (mm) |",
           "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ov = [o for o in r.overshoot_m if not math.isnan(o)]
        ov_s = f"{1e3 * max(ov):.1f}" if ov else "n/a"
        out.append(f"| {CONTROLLER_LABELS.get(r.controller, r.controller)} | {r.metric} | {r.scenario} "
                   f"| {100 * r.mean_m:.3f} | {100 * r.std_m:.3f} | {100 * r.max_m:.3f} | {100 * r.max_settled_m:.3f} "
                   f"| {r.jitter_m_s:.4f} | {r.jerk_m_s3:.1f} | {_goal(r)} | {ov_s} |")
    return "\n".join(out)


def issue_noise_sweep(controller: str, metric: str, noises_m=(0.0, 0.001, 0.002, 0.003, 0.005), seeds=(1, 2, 3),
                      log=print) -> list[PrecisionRow]:
    """The issue's scenario at several tracker position noises (heading noise 0.01 rad)."""
    out = []
    for i, nz in enumerate(noises_m):
        log(f"[precision noise {i + 1}/{len(noises_m)}] sigma {1e3 * nz:.0f} mm")
        out.append(precision_row(controller, metric, seeds, noise_xy_m=nz))
    return out


def precision_table(scenario: Scenario, seeds=(1, 2, 3), duration_s: float | None = None,
                    log=print) -> list[PrecisionRow]:
    """Every controller x metric on ``scenario`` as it is (bench/run_all.py section 4)."""
    duration = scenario.duration_s if duration_s is None else duration_s
    jobs = [(c, m) for c in CONTROLLERS for m in METRICS]
    rows = []
    for i, (c, m) in enumerate(jobs):
        log(f"[precision {i + 1}/{len(jobs)}] {c} {m} ({len(seeds)} seeds)")
        rows.append(precision_row(c, m, seeds, duration_s=duration, noise_xy_m=scenario.tracker.noise_xy_m,
                                  scenario=scenario))
    return rows


def noise_sweep(scenario: Scenario, controller: str, metric: str, noises_m=(0.0, 0.001, 0.002, 0.005),
                seeds=(1,), duration_s: float | None = None, log=print) -> list[PrecisionRow]:
    """One controller and metric on ``scenario`` at several tracker position noises."""
    duration = scenario.duration_s if duration_s is None else duration_s
    out = []
    for i, nz in enumerate(noises_m):
        log(f"[precision noise {i + 1}/{len(noises_m)}] sigma {1e3 * nz:.0f} mm")
        out.append(precision_row(controller, metric, seeds, duration_s=duration, noise_xy_m=nz, scenario=scenario))
    return out


def noise_table(rows: list[PrecisionRow]) -> str:
    out = ["| σ xy (mm) | mean (cm) | max after 3 s (cm) | Δcommand / frame (m/s) | goal |", "|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {1e3 * r.noise_xy_m:.0f} | {100 * r.mean_m:.3f} | {100 * r.max_settled_m:.3f} "
                   f"| {r.jitter_m_s:.4f} | {_goal(r)} |")
    return "\n".join(out)


def figures(out_dir: Path, seed: int = 1) -> list[Path]:
    """The paper's Figs 9 and 10 from new runs: robot paths and the structure's deviation over time."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out_dir.mkdir(parents=True, exist_ok=True)
    sc = issue_scenario(seed)
    run = run_offline(sc, 40.0, controller=DEFAULT_CONTROLLER, seed=seed)
    paths = []
    fig, ax = plt.subplots(figsize=(6, 5))
    for i, r in enumerate(run.robots):
        ax.plot(run.positions_m[:, i, 0], run.positions_m[:, i, 1], label=r)
    for k in range(0, len(run.trace), 150):   # the triangle every 5 s
        xy = run.positions_m[k]
        ax.fill(xy[:, 0], xy[:, 1], fill=False, ls=":", color="grey")
    ax.plot(*sc.mission.goal[:2], "k*", ms=12, label="goal")
    ax.set(title=f"Fig. 9 again: robot paths ({DEFAULT_CONTROLLER}, σ 2 mm)", xlabel="x [m]", ylabel="y [m]",
           aspect="equal")
    ax.legend()
    fig.tight_layout()
    paths.append(out_dir / "fig9-paths.png")
    fig.savefig(paths[-1], dpi=110)
    fig, ax = plt.subplots(figsize=(7, 4))
    ts = np.array([t for t, _ in run.trace])
    for i, r in enumerate(run.robots):
        ax.plot(ts, 1000 * run.deviations_m[:, i], label=r, lw=0.8)
    ax.set(title="Fig. 10 again: deviation from the structure fitted to the true positions",
           xlabel="t [s]", ylabel="mm")
    ax.legend()
    fig.tight_layout()
    paths.append(out_dir / "fig10-deviation.png")
    fig.savefig(paths[-1], dpi=110)
    return paths


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--metrics", nargs="+", default=list(METRICS))
    ap.add_argument("--controllers", nargs="+", default=list(CONTROLLERS))
    add_output_flags(ap, "precision", DOCS / "img", "Figs 9 and 10 (fig9-paths.png, fig10-deviation.png)")
    ap.add_argument("--no-sweep", action="store_true")
    args = ap.parse_args(argv)
    print(f"machine: {platform.node()} {platform.machine()} {platform.processor() or ''}, python "
          f"{platform.python_version()}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; "
          f"sigma {1e3 * NOISE_XY_M:.0f} mm / {NOISE_TH_RAD} rad, seeds {args.seeds}")
    jobs = [(c, m, False) for c in args.controllers for m in args.metrics]
    jobs += [(c, "linf", True) for c in args.controllers]
    rows, t0 = [], time.perf_counter()
    for i, (c, m, turn) in enumerate(jobs):
        print(f"[precision {i + 1}/{len(jobs)}] {c} {m}{' turn' if turn else ''}", file=sys.stderr, flush=True)
        rows.append(precision_row(c, m, args.seeds, turn=turn))
    print(table(rows))
    if not args.no_sweep:
        print()
        print(noise_table(issue_noise_sweep(DEFAULT_CONTROLLER, "linf", seeds=args.seeds,
                                            log=lambda s: print(s, file=sys.stderr))))
    for p in figures(args.out):
        print(f"plot: {p}", file=sys.stderr)
    print(f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
