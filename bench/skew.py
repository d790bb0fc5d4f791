"""Clock skew between the tracker host and the agent hosts: which skews the fleet tolerates.

Runs the e2e triangle offline (the real agents and their frame rule; one frame of command
latency) with the agents' clocks behind (+) or ahead of (-) the tracker's by each skew, and
reports whether the fleet reached its goal, when, and its worst formation error. The
multi-process check of both edges is tests/integration/test_faults.py.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from vsfleet.zglue.scenario_file import load_scenario  # noqa: E402
from vsfleet.simfleet.offline import run_offline  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    args = ap.parse_args(argv)
    logging.getLogger("vsfleet").setLevel(logging.ERROR)
    sc = load_scenario(ROOT / "tests" / "data" / "e2e-triangle.toml")
    skews = [-1.0, -0.6, -0.55, -0.5, -0.45, -0.3, 0.0, 0.3, 0.6, 0.9, 0.95, 1.0, 1.05, 1.2]
    print("| tracker clock ahead of the agents' (s) | goal reached | time to goal (s) | max formation error (cm) |")
    print("|---|---|---|---|")
    t0 = time.monotonic()
    for i, skew in enumerate(skews):
        run = run_offline(sc, args.seconds, seed=1, tracker_clock_ahead_s=skew)
        moved = float(np.abs(run.positions_m[-1] - run.positions_m[0]).max())
        reached = run.t_goal_s is not None
        print(f"| {skew:+.2f} | {'yes' if reached else 'no (robots moved %.3f m)' % moved} | "
              f"{run.t_goal_s:.1f} |" if reached else
              f"| {skew:+.2f} | no (robots moved {moved:.3f} m) | - |", end="")
        print(f" {100 * float(run.deviations_m.max()):.2f} |")
        print(f"[{i + 1}/{len(skews)}] skew {skew:+.2f} s  (ETA "
              f"{(time.monotonic() - t0) / (i + 1) * (len(skews) - i - 1):.0f} s)", file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
