"""The plan's cost in the two cases issue 28 names: 3 robots among 64 obstacles, 30 robots among 256.

Each case is a square room of round pillars (radius 0.05-0.15 m) scattered at random, with the structure's start
and goal in opposite corners, every body clear of every pillar there by 5 cm (pillars that would not be are drawn
again). The fleets: the paper triangle (side 0.5 m, bodies of 0.09 m) in a room of 6 m; a 5 x 6 grid (spacing 0.3 m,
bodies of 0.05-0.09 m) in a room of 12 m. For each room, on the compiled core:

- ``plan``: what an agent does before its structure moves: the deferred build (vsfleet.field.build_field_deferred)
  of the field its first frames follow, and the first frame's descent from the start (which resolves the start's
  component when the goal cannot be reached from it, and asks a finer lattice where this one has one and no way).
  That field is the first plan's (vsfleet.field.first_lattice: a coarse lattice, or the room's own lattice without its
  finer one; either provisional) where the room has one, else the room's own;
- ``own``: the room's own field (vsfleet.field.room_lattice) as the agents build it meanwhile and follow it from the
  mission's FIRST_PLAN_S on: its deferred build (with its finer lattice, where the first plan is the room's own
  lattice: vsfleet.structure builds it with the field) and the descent from the start;
- ``whole``: the whole build (every component the goal cannot reach resolved up front), as before 2026-12-06;
- ``follow``: one frame's descent (vsfleet.field.follow_field, 2 m of it), timed along the way from the start.

Times are wall-clock on this host, the best of 3 for builds (median of the frames for follow), and for the plan also
the CPU time of the same run (every thread of this process: the raster runs on two, vs_field.c). An agent builds each
mission's field once, into memory its process has not touched yet, so ``first`` is the plan again as the first build
of a fresh process (``--first N SEED``, run as a child process): the best of 3 reuses memory the C library keeps
after the first of them. Progress on stderr.

    .venv/bin/python -m bench.plan_cost --rooms 10
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from vsfleet.field import build_field, first_lattice, follow_field, room_lattice
from vsfleet.geometry import Pose2
from vsfleet.step import PLAN_MARGIN_M
from vsfleet.structure import FIRST_PLAN_S

CASES = {3: (64, 6.0), 30: (256, 12.0)}   # robots: (pillars, room side [m])


def fleet(n: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """(template (n, 2) [m; structure frame], radii (n,) [m]), centred on the centroid."""
    if n == 3:
        a = np.array([0.0, 2 * math.pi / 3, 4 * math.pi / 3])
        tpl = 0.5 / math.sqrt(3.0) * np.c_[np.cos(a), np.sin(a)]
        return tpl, np.full(3, 0.09)
    g = np.array([(0.3 * c, 0.3 * r) for r in range(5) for c in range(6)], dtype=float)
    return g - g.mean(axis=0), rng.uniform(0.05, 0.09, n)


def bodies(tpl: np.ndarray, pose) -> np.ndarray:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.c_[pose[0] + c * tpl[:, 0] - s * tpl[:, 1], pose[1] + s * tpl[:, 0] + c * tpl[:, 1]]


def room(n: int, seed: int):
    """A room of the case for n robots: (template, radii, obstacles (m, 3), start, goal)."""
    rng = np.random.default_rng([seed, n, 20261206])
    tpl, rad = fleet(n, rng)
    m, side = CASES[n]
    reach = float(np.max(np.hypot(tpl[:, 0], tpl[:, 1]) + rad))
    start = (reach + 0.1, reach + 0.1, float(rng.uniform(-math.pi, math.pi)))
    goal = (side - reach - 0.1, side - reach - 0.1, float(rng.uniform(-math.pi, math.pi)))
    keep = np.vstack([bodies(tpl, start), bodies(tpl, goal)])
    kept_r = np.concatenate([rad, rad])
    obs = []
    while len(obs) < m:
        x, y, r = rng.uniform(0.0, side), rng.uniform(0.0, side), rng.uniform(0.05, 0.15)
        if np.all(np.hypot(keep[:, 0] - x, keep[:, 1] - y) - kept_r - r >= 0.05):
            obs.append((x, y, r))
    return tpl, rad, np.array(obs), start, goal


def best_of(fn, times: int = 3) -> tuple[float, float, object]:
    """(wall [s], CPU [s] of this process's threads, in the same run) of the fastest of `times` runs, its result."""
    best, best_cpu, out = math.inf, math.inf, None
    for _ in range(times):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        wall, cpu_s = time.perf_counter() - t0, time.process_time() - c0
        if wall < best:
            best, best_cpu = wall, cpu_s
    return best, best_cpu, out


def start_lattice(tpl, rad, obs, goal) -> dict:
    """The lattice of the field an agent's first frames follow: the first plan's where the room has one."""
    return (first_lattice(tpl, rad, PLAN_MARGIN_M, obs, goal[:2])
            or room_lattice(tpl, rad, PLAN_MARGIN_M, obs, goal[:2]))


def way_m(way) -> float:
    return float(np.hypot(*np.diff(np.asarray(way)[:, :2], axis=0).T).sum())


def plan_room(tpl, rad, obs, start, goal, lattice: dict, refine_now: bool = False):
    """The room's plan as an agent makes it: (the deferred field, the first frame's descent from the start, which
    builds the finer lattice where the room's own has no way from there). refine_now: its finer lattice built with
    it (the room's own field where the first plan is the room's own lattice)."""
    f = build_field(tpl, rad, PLAN_MARGIN_M, obs, Pose2(*goal), **lattice, deferred=True)
    if refine_now:
        f.refine_now()
    return f, follow_field(f, Pose2(*start))


def first_plan_ms(n: int, seed: int) -> float:
    """The plan's wall time [ms] as the first field a fresh process builds (this module run as a child)."""
    out = subprocess.run([sys.executable, "-m", "bench.plan_cost", "--first", str(n), str(seed)], check=True,
                         capture_output=True, text=True, cwd=Path(__file__).resolve().parent.parent)
    return float(out.stdout.split()[-1])


def measure(n: int, seed: int) -> dict:
    tpl, rad, obs, start, goal = room(n, seed)
    lattice = room_lattice(tpl, rad, PLAN_MARGIN_M, obs, goal[:2])
    first_lat = first_lattice(tpl, rad, PLAN_MARGIN_M, obs, goal[:2])
    heads = lattice["n_headings"]
    args = (tpl, rad, PLAN_MARGIN_M, obs, Pose2(*goal))
    eager = first_lat is not None and "max_states" not in first_lat   # the room's own lattice: its finer one now
    own_s, own_cpu_s, (fld, _) = best_of(lambda: plan_room(tpl, rad, obs, start, goal, lattice, eager))
    plan_s, plan_cpu_s, first_way = own_s, own_cpu_s, None
    if first_lat is not None:
        plan_s, plan_cpu_s, (ffld, _) = best_of(lambda: plan_room(tpl, rad, obs, start, goal, first_lat))
        first_way = follow_field(ffld, Pose2(*start), path_m=1e9, cap=200000)
    whole_s, _, _ = best_of(lambda: build_field(*args, n_headings=heads))
    way, blocked, _ = follow_field(fld, Pose2(*start), path_m=1e9, cap=200000)
    follow_us = []
    for k in range(0, len(way), max(1, len(way) // 50)):   # about 50 frames along the way
        t0 = time.perf_counter()
        follow_field(fld, Pose2(*way[k]))
        follow_us.append(1e6 * (time.perf_counter() - t0))
    lat = fld.lattice
    return {"n": n, "seed": seed, "obstacles": len(obs), "headings": heads, "cell_m": lat.cell_m,
            "states": lat.nx * lat.ny * lat.n_headings, "way": not blocked, "plan_ms": 1e3 * plan_s,
            "plan_cpu_ms": 1e3 * plan_cpu_s, "first_ms": first_plan_ms(n, seed), "own_ms": 1e3 * own_s,
            "first_plan": first_lat is not None,
            "first_kind": None if first_lat is None else "the room's own lattice" if eager else "coarse",
            # the first plan's way from the start against the room's own (its length, or None: no way, or none)
            "first_way_ratio": (way_m(first_way[0]) / way_m(way) if first_way is not None and not first_way[1]
                                and not blocked else None),
            "whole_ms": 1e3 * whole_s, "follow_us": statistics.median(follow_us)}


def cpu() -> str:
    """The CPU's model name (/proc/cpuinfo), else the machine's architecture."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.machine()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rooms", type=int, default=10, help="rooms per case (seeds 0..rooms-1)")
    ap.add_argument("--first", type=int, nargs=2, metavar=("N", "SEED"),
                    help="(a child's run) print the wall time [ms] of one plan, this process's first field")
    args = ap.parse_args(argv)
    if args.first:
        tpl, rad, obs, start, goal = room(*args.first)
        lattice = start_lattice(tpl, rad, obs, goal)
        t0 = time.perf_counter()
        plan_room(tpl, rad, obs, start, goal, lattice)
        print(f"{1e3 * (time.perf_counter() - t0):.3f}")
        return 0
    rows = []
    for n in CASES:
        for seed in range(args.rooms):
            r = measure(n, seed)
            rows.append(r)
            which = f"the first plan, {r['first_kind']}" if r["first_plan"] else "the room's own"
            print(f"[{n} robots, room {seed + 1}/{args.rooms}] {r['obstacles']} obstacles, {r['states']:,} states, "
                  f"{'a way' if r['way'] else 'blocked'}: plan {r['plan_ms']:.1f} ms "
                  f"({which}; CPU {r['plan_cpu_ms']:.1f} ms; a "
                  f"fresh process's first {r['first_ms']:.1f} ms), the room's own field {r['own_ms']:.1f} ms, "
                  f"whole build {r['whole_ms']:.1f} ms, follow {r['follow_us']:.1f} us", file=sys.stderr, flush=True)
    print(f"bench/plan_cost.py, {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, {cpu()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}\n")
    print("| robots | obstacles | rooms (a way) | rooms with a first plan | states (the room's own) | "
          "plan: deferred build + first descent, median / max | the plan's CPU time, median / max | "
          "the plan, a fresh process's first field, median / max | "
          "the first plan's way / the room's own, median / max | "
          f"the room's own field (followed from {FIRST_PLAN_S} s on; with its finer lattice where the first plan "
          "is the room's own lattice), median / max | "
          "whole build, median / max | follow a frame, median / max |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for n, (m, _side) in CASES.items():
        sel = [r for r in rows if r["n"] == n]
        plan, plan_cpu, first, own, whole, fol = ([r[k] for r in sel] for k in (
            "plan_ms", "plan_cpu_ms", "first_ms", "own_ms", "whole_ms", "follow_us"))
        states = [r["states"] for r in sel]
        ratios = [r["first_way_ratio"] for r in sel if r["first_way_ratio"] is not None]
        ratio = f"{statistics.median(ratios):.2f} / {max(ratios):.2f}" if ratios else "-"
        kinds = sorted({r["first_kind"] for r in sel if r["first_plan"]})
        print(f"| {n} | {m} | {len(sel)} ({sum(r['way'] for r in sel)}) | {sum(r['first_plan'] for r in sel)} "
              f"({', '.join(kinds) or '-'}) | "
              f"{min(states):,}-{max(states):,} | "
              f"{statistics.median(plan):.1f} / {max(plan):.1f} ms | "
              f"{statistics.median(plan_cpu):.1f} / {max(plan_cpu):.1f} ms | "
              f"{statistics.median(first):.1f} / {max(first):.1f} ms | {ratio} | "
              f"{statistics.median(own):.1f} / {max(own):.1f} ms | "
              f"{statistics.median(whole):.1f} / {max(whole):.1f} ms | "
              f"{statistics.median(fol):.1f} / {max(fol):.1f} us |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
