"""Benchmark: vsfleet.fit.fit_structure against scipy's Powell on the same cost.

Run: .venv/bin/python bench/fit.py   (or: make bench-fit)

For each n in {3, 10, 100, 1000} and metric in {l1, l2, linf}: one seeded
formation (template uniform in [-1, 1]^2, a random rigid transform, Gaussian
noise 0.05 m).  Both methods run side by side in this process, interleaved.
Powell minimises a minimal hand-written numpy objective for each metric (no
input validation; d = hypot of the residuals, then l1 = sum d, l2 =
sqrt(sum d^2), linf = max d) from the centroid translation with th = 0, with
scipy's default tolerances; its reported cost is re-evaluated with
``structure_cost`` at Powell's pose.  Times are the minimum over the repeats
(the least disturbed run on a shared machine; run under ``nice``); "ratio" is
powell / ours.  Progress goes to stderr; the table to stdout.
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np
from scipy.optimize import minimize

from vsfleet.fit import METRICS, fit_structure, structure_cost
from vsfleet.geometry import Pose2

SIZES = (3, 10, 100, 1000)
# repetitions (ours, powell) per size: keeps the whole run well under two minutes
REPS = {3: (500, 40), 10: (500, 40), 100: (60, 10), 1000: (10, 5)}
NOISE_M = 0.05


def formation(n: int, seed: int):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-1.0, 1.0, (n, 2))
    g = Pose2(rng.uniform(-5.0, 5.0), rng.uniform(-5.0, 5.0), rng.uniform(-math.pi, math.pi))
    r = g.apply(p) + rng.normal(0.0, NOISE_M, (n, 2))
    return p, r


def _objective(p, r, metric):
    """A minimal cost function of (x, y, th): no validation, a few numpy calls."""
    px, py = p[:, 0].copy(), p[:, 1].copy()
    rx, ry = r[:, 0].copy(), r[:, 1].copy()
    cos, sin, hypot, sqrt = math.cos, math.sin, np.hypot, math.sqrt

    def dist(x):
        c, s = cos(x[2]), sin(x[2])
        return hypot(rx - (c * px - s * py + x[0]), ry - (s * px + c * py + x[1]))

    if metric == "l1":
        return lambda x: dist(x).sum()
    if metric == "l2":
        return lambda x: sqrt((dist(x) ** 2).sum())
    return lambda x: dist(x).max()


def run_powell(p, r, metric):
    cost = _objective(p, r, metric)
    c = r.mean(axis=0) - p.mean(axis=0)
    x = minimize(cost, [c[0], c[1], 0.0], method="Powell").x
    return x


def measure(log=lambda line: print(line, file=sys.stderr, flush=True)) -> list[tuple]:
    """Rows (n, metric, ours_s, powell_s, time ratio powell/ours, our cost, powell cost); progress to ``log``."""
    rows = []
    jobs, done, start = len(SIZES) * len(METRICS), 0, time.perf_counter()
    for n in SIZES:
        p, r = formation(n, seed=1000 + n)
        reps_ours, reps_powell = REPS[n]
        for metric in METRICS:
            elapsed = time.perf_counter() - start
            eta = f"ETA {elapsed / done * (jobs - done):.0f} s" if done else "ETA ?"
            log(f"[fit {done + 1}/{jobs}] n={n:<5} {metric:<5} {eta}")
            done += 1
            fit_structure(p, r, metric)  # warm caches
            t_ours, t_powell = [], []
            ours_cost = powell_cost = math.nan
            every = max(1, reps_ours // reps_powell)
            for k in range(reps_ours):
                t0 = time.perf_counter()
                res = fit_structure(p, r, metric)
                t_ours.append(time.perf_counter() - t0)
                ours_cost = res.cost
                if k % every == 0 and len(t_powell) < reps_powell:
                    t0 = time.perf_counter()
                    xp = run_powell(p, r, metric)
                    t_powell.append(time.perf_counter() - t0)
            while len(t_powell) < reps_powell:
                t0 = time.perf_counter()
                xp = run_powell(p, r, metric)
                t_powell.append(time.perf_counter() - t0)
            powell_cost = structure_cost(p, r, (xp[0], xp[1], xp[2]), metric)
            mo = min(t_ours)
            mp = min(t_powell)
            rows.append((n, metric, mo, mp, mp / mo, ours_cost, powell_cost))
    return rows


def main() -> int:
    rows = measure()
    head = f"{'n':>5} {'metric':<6} {'ours [ms]':>10} {'powell [ms]':>12} {'ratio':>8} {'our cost':>14} {'powell cost':>14}"
    print(head)
    print("-" * len(head))
    for n, metric, mo, mp, ratio, oc, pc in rows:
        print(f"{n:>5} {metric:<6} {mo * 1e3:>10.3f} {mp * 1e3:>12.3f} {ratio:>8.1f} {oc:>14.9f} {pc:>14.9f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
