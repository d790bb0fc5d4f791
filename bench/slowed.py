"""The robot slowed to 50% (issue 30): the worst bending over seeds, which robot is slowed, and when.

The issue-13 conditions (bench/conditions.py: the paper triangle, sigma 2 mm / 0.01 rad, 30 Hz, commands
one frame late, wheel gains within +-4% drawn per seed, 2.5 m at 0.1 m/s), offline (simfleet.offline: the
real agents, simulated physics), under hold. For each seed, each robot and each moment, that robot's wheels
are slowed to 50% (for good, or --for-s seconds) and the worst formation error from the moment on is kept
(bench/faults.py's measure: the largest distance of a robot from its point on the structure fitted to the
robots' true positions). Prints the worst cases and how many runs exceed 1.0 cm; --jsonl keeps every run.
--boost-off measures the controller without the faster gain adaptation of a robot off its point
(Precision's gain_boost_per_m = 0: the controller before issue 30).

Run: .venv/bin/python bench/slowed.py [--seeds 1 41] [--at 3 8 13 18] [--for-s 0] [--boost-off]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.conditions import issue_scenario  # noqa: E402
from bench.faults import formation_errors  # noqa: E402
from vsfleet.scenario import FaultEvent  # noqa: E402
from vsfleet.simfleet.offline import run_offline  # noqa: E402


def slowed_case(seed: int, robot: str, at_s: float, for_s: float = 0.0, factor: float = 0.5,
                seconds: float = 30.0, **gains: float) -> dict:
    """One run: ``robot`` slowed to ``factor`` at at_s (for for_s seconds, 0 = for good); the worst after it."""
    sc = issue_scenario(seed)
    sc = dataclasses.replace(sc, faults=(FaultEvent(robot, at_s, "slow", factor, for_s),))
    run = run_offline(sc, seconds, seed=seed, stop_at_goal=False, **gains)
    err, ts = formation_errors(run, sc.mission), np.array([t for t, _ in run.trace])
    after = ts >= at_s
    k = int(np.argmax(np.where(after, err, -1.0)))
    return dict(seed=seed, robot=robot, at_s=at_s, for_s=for_s, max_cm=100 * float(err[k]), t_max_s=float(ts[k]),
                mean_cm=100 * float(err[after].mean()),
                decisions=[(d.kind, d.robot, round(d.t, 2)) for d in run.decisions[run.robots[0]]])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs=2, default=[1, 41], help="seeds from, to (exclusive)")
    ap.add_argument("--robots", nargs="+", default=["r1", "r2", "r3"])
    ap.add_argument("--at", type=float, nargs="+", default=[3.0, 8.0, 13.0, 18.0], help="moments [s]")
    ap.add_argument("--for-s", type=float, default=0.0, help="slowed for this long [s] (0: for good)")
    ap.add_argument("--seconds", type=float, default=30.0, help="simulated seconds per run")
    ap.add_argument("--boost-off", action="store_true", help="without Precision's gain boost (before issue 30)")
    ap.add_argument("--jsonl", type=Path, default=None, help="every run, one JSON line each")
    ap.add_argument("--worst", type=int, default=10, help="print this many worst runs")
    a = ap.parse_args(argv)
    logging.getLogger("vsfleet").setLevel(logging.ERROR)  # decisions are in the records
    gains = {"gain_boost_per_m": 0.0} if a.boost_off else {}
    rows, t0 = [], time.monotonic()
    out = a.jsonl.open("w") if a.jsonl else None
    for seed in range(*a.seeds):
        for robot in a.robots:
            for at in a.at:
                seconds = max(a.seconds, at + a.for_s + 4.0)
                rows.append(slowed_case(seed, robot, at, a.for_s, seconds=seconds, **gains))
                if out:
                    out.write(json.dumps(rows[-1]) + "\n")
        print(f"seed {seed}: {len(rows)} runs, {time.monotonic() - t0:.0f} s", file=sys.stderr, flush=True)
    if out:
        out.close()
    worst = sorted(rows, key=lambda r: -r["max_cm"])
    over = sum(r["max_cm"] > 1.0 for r in rows)
    print(f"{len(rows)} runs (seeds {a.seeds[0]}-{a.seeds[1] - 1}, robots {' '.join(a.robots)}, at {a.at} s, "
          f"{'for ' + str(a.for_s) + ' s' if a.for_s else 'for good'}{', boost off' if a.boost_off else ''}): "
          f"worst {worst[0]['max_cm']:.3f} cm, mean of the worsts {np.mean([r['max_cm'] for r in rows]):.3f} cm, "
          f"over 1.0 cm: {over} ({100 * over / len(rows):.1f}%), a robot flagged in "
          f"{sum(bool(r['decisions']) for r in rows)}")
    print("| seed | robot slowed | at (s) | worst (cm) | at t (s) |")
    print("|---|---|---|---|---|")
    for r in worst[:a.worst]:
        print(f"| {r['seed']} | {r['robot']} | {r['at_s']:g} | {r['max_cm']:.3f} | {r['t_max_s']:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
