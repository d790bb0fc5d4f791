"""Randomised rooms through vsfleet's own step, judged against OMPL (offline: simfleet.offline, the real
agents on counted frames, simfleet's physics at 120 Hz, tracker at 30 Hz with noise sigma 2 mm).

Every room is a fleet, a start pose, a goal pose and round obstacles (x, y, r):

- fleets of 3 (triangle, side 0.5 m, a random vertex angle), 4 (square, side 0.5 m), 10 (a 2 x 5 grid or a
  line, spacing 0.3 m) and 30 robots (a 5 x 6 grid, spacing 0.3 m), in turn; templates centred on their
  centroid; bodies of radius 0.05-0.09 m, wheel base 0.12-0.16 m, wheel speed 0.3 m/s, accel 0.8 m/s^2,
  wheel gains 1 +- 4 % (each robot its own draw); mission 0.1 m/s, 0.5 rad/s, metric l2;
- the fleet starts ASSEMBLED: every robot exactly on its template point at the start pose, heading the
  structure's heading;
- the room, one of four kinds drawn at random: ``pillars`` (1-12 round pillars, r 0.1-0.3 m, scattered
  around the straight path), ``wall`` (a closed corridor, a thin wall of overlapping discs across it with
  1-2 gaps of random widths), ``bend`` (a closed corridor with one bend of 45-90 degrees), ``sealed``
  (the goal inside a closed ring of discs whose 1-4 gaps are narrower than any body, plus 0-4 pillars);
  every body is >= 0.05 m from every obstacle at the start pose and at the goal pose.

Whether a room *has a way* is OMPL's say (bench/ompl_ref.py: RRTConnect on the rigid footprint in SE(2),
margin 0.02 m, motions checked every 0.5 cm of body travel, seed 1, at most 300 000 state checks, about
4-8 s, then simplified). Our plan
(vsfleet.field.build_field + follow_field from the start pose, the agents' own lattice) is reported next
to it; then the fleet runs (run_offline) for max(60 s, 2.5 x the reference time), at most 150 s; the
reference time is OMPL's path length / 0.1 m/s (ours where OMPL found none). The goal is reached when the
fitted structure is within 5 mm of the goal's position AND 0.03 rad of its heading (run_offline's t_goal_s
looks at the position only and ends the run there; when the heading is not there yet, the room's run is
made again, to its end, and the first frame at the goal pose counts).

    .venv/bin/python -m bench.room --rooms 200 --jobs 2   # progress on stderr, tables on stdout
    .venv/bin/python -m bench.room --rooms 8 --out /tmp/rooms   # rooms.json and rooms.png there

Output: runs/bench/room/ unless --out DIR (or --docs: docs/bench/room/) holds rooms.json (every room's
record) and rooms.png (six rooms drawn). ``--picture PATH`` still draws scenarios/paper-triangle-obstacle.toml's
run there, as before.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import platform
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vsfleet import _core
from vsfleet.field import PATH_CAP, PATH_M, build_field, follow_field, room_lattice
from vsfleet.geometry import Pose2
from vsfleet.scenario import scenario_from_dict
from vsfleet.simfleet.offline import run_offline
from vsfleet.step import PLAN_MARGIN_M

from . import ompl_ref
from .outputs import DOCS, add_output_flags

FLEETS = (3, 4, 10, 30)
KINDS = ("pillars", "wall", "bend", "sealed")
SPEED = 0.1              # mission speed [m/s]
TURN = 0.5               # mission turn rate [rad/s]
CLEAR_M = 0.05           # every body this far from every obstacle at the start and at the goal
WALL_R = 0.1             # wall discs [m] ...
WALL_STEP = 0.15         # ... this far apart (overlapping: the wall is >= 0.13 m thick everywhere)
WITHIN = 1.5             # "reached in time": within this many reference times
GOAL_M = 0.005           # the goal pose is reached: the fitted structure within this of its position (as
GOAL_RAD = 0.03          # run_offline's t_goal_s) and within this of its heading (run_offline does not look)
MAX_OBSTACLES = 256      # a mission's limit


# ------------------------------------------------------------------------------------------ rooms


@dataclass
class Room:
    seed: int
    kind: str
    shape: str
    template: np.ndarray       # (n, 2) [m; structure frame], centred on its centroid
    radii: np.ndarray          # (n,) [m]
    wheel_base: np.ndarray     # (n,) [m]
    gains: np.ndarray          # (n, 2) true / commanded wheel speed, left and right
    start: tuple               # (x, y, th) [m, rad; world]
    goal: tuple
    obstacles: np.ndarray      # (m, 3) [m; world]
    notes: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.template)


def fleet_template(n: int, rng: np.random.Generator) -> tuple[str, np.ndarray]:
    """(shape, template (n, 2)) of the issue's fleets, centred on the centroid."""
    if n == 3:
        rc, phi = 0.5 / math.sqrt(3.0), rng.uniform(0.0, 2 * math.pi / 3)
        return "triangle", np.array([(rc * math.cos(phi + a), rc * math.sin(phi + a))
                                     for a in (0.0, 2 * math.pi / 3, 4 * math.pi / 3)])
    if n == 4:
        return "square", np.array([(x, y) for x in (-0.25, 0.25) for y in (-0.25, 0.25)])
    if n == 10:
        if rng.random() < 0.5:
            return "line", np.array([(0.3 * (i - 4.5), 0.0) for i in range(10)])
        return "grid 2x5", np.array([(0.3 * (i - 2), 0.3 * (j - 0.5)) for j in range(2) for i in range(5)])
    if n == 30:
        return "grid 5x6", np.array([(0.3 * (i - 2.5), 0.3 * (j - 2)) for j in range(5) for i in range(6)])
    raise ValueError(f"no fleet of {n} robots: one of {FLEETS}")


def reach_m(template, radii) -> float:
    """The footprint's enclosing radius about the structure origin: max |p_i| + r_i."""
    return float((np.hypot(template[:, 0], template[:, 1]) + radii).max())


def width_m(template, radii) -> float:
    """The footprint's least width over all directions (a gap narrower than this + 2 margins stops it)."""
    a = np.linspace(0.0, math.pi, 360, endpoint=False)
    proj = template[:, 0:1] * np.cos(a) + template[:, 1:2] * np.sin(a)        # (n, 360)
    return float(((proj + radii[:, None]).max(axis=0) - (proj - radii[:, None]).min(axis=0)).min())


def wall_line(p, q, r: float = WALL_R, step: float = WALL_STEP) -> list[tuple[float, float, float]]:
    """Overlapping discs from p to q (both ends), at most ``step`` apart."""
    p, q = np.asarray(p, float), np.asarray(q, float)
    k = max(1, math.ceil(float(np.hypot(*(q - p))) / step))
    return [(float(p[0] + (q[0] - p[0]) * i / k), float(p[1] + (q[1] - p[1]) * i / k), r) for i in range(k + 1)]


def clearance(template, radii, obstacles, pose) -> float:
    """The footprint's smallest body-to-obstacle-edge distance at pose [m]."""
    return ompl_ref.clearance_m(template, radii, obstacles, pose)


def _heading(rng, tpl, rad, obs, xy, along: float | None = None, tries: int = 400) -> float | None:
    """A heading at which the footprint at xy keeps CLEAR_M from every obstacle (None if none is found):
    uniform draws, and (along given) every other draw near along + k pi/2."""
    for i in range(tries):
        if along is not None and i % 2:
            th = along + 0.5 * math.pi * rng.integers(4) + rng.normal(0.0, 0.2)
        else:
            th = rng.uniform(-math.pi, math.pi)
        if not len(obs) or clearance(tpl, rad, obs, (xy[0], xy[1], th)) >= CLEAR_M:
            return th
    return None


def _pillars(rng, tpl, rad, rho):
    d = rng.uniform(2.0, 3.5) + rho
    th_s, th_g = rng.uniform(-math.pi, math.pi), rng.uniform(-math.pi, math.pi)
    spread = rho + 0.4
    obs: list[tuple[float, float, float]] = []
    for _ in range(int(rng.integers(1, 13))):
        for _ in range(100):
            o = (float(rng.uniform(0.0, d)), float(rng.uniform(-spread, spread)), float(rng.uniform(0.1, 0.3)))
            if (clearance(tpl, rad, [o], (0.0, 0.0, th_s)) >= CLEAR_M
                    and clearance(tpl, rad, [o], (d, 0.0, th_g)) >= CLEAR_M):
                obs.append(o)
                break
    return (0.0, 0.0, th_s), (d, 0.0, th_g), obs, {"length_m": d}


def _wall(rng, tpl, rad, rho, w):
    """A closed box (the corridor's two long walls and its two ends) with a thin wall across, 1-2 gaps."""
    width = 2 * (rho + CLEAR_M) + rng.uniform(0.05, 0.6)               # any heading fits at start and goal
    half = width / 2 + WALL_R                                           # wall discs' centres off the axis
    d = 2 * (rho + CLEAR_M + WALL_R) + 0.4 + rng.uniform(0.0, 1.0)
    u_wall = d / 2 + rng.uniform(-0.2, 0.2)
    back, front = -(rho + CLEAR_M + WALL_R + rng.uniform(0.05, 0.3)), d + rho + CLEAR_M + WALL_R + rng.uniform(0.05, 0.3)
    obs = wall_line((back, -half), (front, -half)) + wall_line((back, half), (front, half))
    obs += wall_line((back, -half), (back, half))[1:-1] + wall_line((front, -half), (front, half))[1:-1]
    n_gaps = int(rng.integers(1, 3))
    gaps = [(min(w, width - 0.05), 0.0)]                               # (width, centre) of each gap
    for _ in range(200):
        gs = [float(rng.uniform(0.6, 1.6) * w) for _ in range(n_gaps)]
        if max(gs) > width - 0.02:
            continue
        cand = sorted(((g, float(rng.uniform(-width / 2 + g / 2, width / 2 - g / 2))) for g in gs), key=lambda t: t[1])
        if all(b[1] - b[0] / 2 - (a[1] + a[0] / 2) > 2.5 * WALL_R for a, b in zip(cand, cand[1:])):
            gaps = cand
            break
    # the disc rows between the gaps: from one side wall to the first gap, between gaps, to the other wall
    edges = [-half] + [v for g, c in gaps for v in (c - g / 2 - WALL_R, c + g / 2 + WALL_R)] + [half]
    for a, b in zip(edges[0::2], edges[1::2]):
        obs += wall_line((u_wall, a), (u_wall, b))
    th_s, th_g = rng.uniform(-math.pi, math.pi), rng.uniform(-math.pi, math.pi)
    return (0.0, 0.0, th_s), (d, 0.0, th_g), obs, {"gaps_m": [round(g, 4) for g, _ in gaps],
                                                   "corridor_m": round(width, 4), "width_m": round(w, 4)}


def _offset_corner(b, n1, n2, d1, d2, h):
    """Where the two legs' walls offset by h meet (the lines b + h n1 + t d1 and b + h n2 + s d2)."""
    p1, p2 = b + h * n1, b + h * n2
    m = np.array([d1, -d2]).T
    t, _ = np.linalg.solve(m, p2 - p1)
    return p1 + t * d1


def _bend(rng, tpl, rad, rho, w):
    """A closed corridor along +x, then turning by 45-90 degrees (left or right), the goal in the second leg."""
    width = w + 2 * CLEAR_M + rng.uniform(0.1, 0.8)
    half = width / 2 + WALL_R
    beta = math.radians(rng.uniform(45.0, 90.0)) * (1 if rng.random() < 0.5 else -1)
    l1, l2 = rho + rng.uniform(0.4, 1.2), rho + rng.uniform(0.4, 1.2)
    d1, d2 = np.array([1.0, 0.0]), np.array([math.cos(beta), math.sin(beta)])
    n1, n2 = np.array([-d1[1], d1[0]]), np.array([-d2[1], d2[0]])
    s = np.zeros(2)
    b = s + l1 * d1
    g = b + l2 * d2
    a = s - (rho + CLEAR_M + WALL_R + rng.uniform(0.05, 0.3)) * d1      # the closed ends
    c = g + (rho + CLEAR_M + WALL_R + rng.uniform(0.05, 0.3)) * d2
    obs = []
    for side in (-1.0, 1.0):
        k = _offset_corner(b, n1, n2, d1, d2, side * half)
        obs += wall_line(a + side * half * n1, k) + wall_line(k, c + side * half * n2)[1:]
    obs += wall_line(a - half * n1, a + half * n1)[1:-1] + wall_line(c - half * n2, c + half * n2)[1:-1]
    th_s = _heading(rng, tpl, rad, obs, s, along=0.0)
    th_g = _heading(rng, tpl, rad, obs, g, along=beta)
    if th_s is None or th_g is None:
        return None
    return (0.0, 0.0, th_s), (float(g[0]), float(g[1]), th_g), obs, {
        "corridor_m": round(width, 4), "bend_deg": round(math.degrees(beta), 1), "width_m": round(w, 4)}


def _sealed(rng, tpl, rad, rho):
    """The goal inside a closed ring of overlapping discs with 1-4 gaps narrower than the smallest body."""
    r_d = rng.uniform(0.08, 0.15)
    ring = rho + CLEAR_M + r_d + rng.uniform(0.05, 0.4)
    d = ring + r_d + rho + rng.uniform(0.4, 1.5)
    centre = np.array([d, 0.0])
    n_gaps = int(rng.integers(1, 5))
    gap_w = rng.uniform(0.02, min(0.09, 2 * float(rad.min()) - 0.01), n_gaps)
    span = [2 * math.asin((g + 2 * r_d) / (2 * ring)) for g in gap_w]        # a gap's two centres, apart
    fill = 2 * math.asin(1.5 * r_d / (2 * ring))                              # overlapping neighbours
    # the gaps' first discs at random angles, one of them facing the start
    first = np.sort(np.concatenate([[math.pi], rng.uniform(0.0, 2 * math.pi, n_gaps - 1)]) % (2 * math.pi))
    obs = []
    for i in range(n_gaps):
        a0 = first[i]
        a1 = a0 + span[i]                                          # past the gap
        a2 = first[(i + 1) % n_gaps] + (2 * math.pi if i + 1 == n_gaps else 0.0)   # the next gap's first disc
        if a2 - a1 < fill:                                         # gaps too close: this one is dropped
            continue
        k = math.ceil((a2 - a1) / fill)
        for j in range(k + 1):
            t = a1 + (a2 - a1) * j / k
            obs.append((float(centre[0] + ring * math.cos(t)), float(centre[1] + ring * math.sin(t)), float(r_d)))
    if len(obs) and max(obs_gap_m(np.array(obs), centre)) >= 2 * float(rad.min()):
        return None
    th_s, th_g = rng.uniform(-math.pi, math.pi), rng.uniform(-math.pi, math.pi)
    for _ in range(int(rng.integers(0, 5))):                       # a few pillars outside the ring
        for _ in range(50):
            o = (float(rng.uniform(0.0, d - ring - r_d)), float(rng.uniform(-rho - 0.5, rho + 0.5)),
                 float(rng.uniform(0.1, 0.3)))
            if (clearance(tpl, rad, [o], (0.0, 0.0, th_s)) >= CLEAR_M and math.hypot(o[0] - d, o[1]) > ring + r_d + o[2]):
                obs.append(o)
                break
    return (0.0, 0.0, th_s), (d, 0.0, th_g), obs, {"ring_m": round(ring, 4), "gaps_m": [round(float(g), 4) for g in gap_w]}


def obs_gap_m(ring: np.ndarray, centre) -> list[float]:
    """Edge-to-edge gaps between angularly adjacent discs of a ring about centre [m]."""
    a = np.arctan2(ring[:, 1] - centre[1], ring[:, 0] - centre[0])
    o = ring[np.argsort(a)]
    nxt = np.roll(o, -1, axis=0)
    return list(np.hypot(nxt[:, 0] - o[:, 0], nxt[:, 1] - o[:, 1]) - o[:, 2] - nxt[:, 2])


def make_room(seed: int, n: int | None = None, kind: str | None = None) -> Room:
    """Room ``seed``: its fleet (FLEETS[seed % 4] robots unless n), its kind (random unless given), its
    obstacles, start and goal; the same seed gives the same room."""
    rng = np.random.default_rng([seed, 20261204])
    n = FLEETS[seed % len(FLEETS)] if n is None else n
    kind = KINDS[int(rng.integers(len(KINDS)))] if kind is None else kind
    shape, tpl = fleet_template(n, rng)
    rad = rng.uniform(0.05, 0.09, n)
    base = rng.uniform(0.12, 0.16, n)
    gains = 1.0 + rng.uniform(-0.04, 0.04, (n, 2))
    rho, w = reach_m(tpl, rad), width_m(tpl, rad)
    for _ in range(50):
        made = {"pillars": lambda: _pillars(rng, tpl, rad, rho), "wall": lambda: _wall(rng, tpl, rad, rho, w),
                "bend": lambda: _bend(rng, tpl, rad, rho, w), "sealed": lambda: _sealed(rng, tpl, rad, rho)}[kind]()
        if made is None:
            continue
        start, goal, obs, notes = made
        obs = np.array(obs, dtype=float).reshape(-1, 3)
        if (len(obs) <= MAX_OBSTACLES and clearance(tpl, rad, obs, start) >= CLEAR_M
                and clearance(tpl, rad, obs, goal) >= CLEAR_M):
            break
    else:
        raise RuntimeError(f"room {seed}: no {kind} room for the {shape} in 50 tries")
    # the whole room turned by a random angle about the start (the lattice is axis-aligned)
    alpha = rng.uniform(-math.pi, math.pi)
    c, s = math.cos(alpha), math.sin(alpha)

    def turn(p):
        return (c * p[0] - s * p[1], s * p[0] + c * p[1], math.remainder(p[2] + alpha, 2 * math.pi))

    obs = np.array([(c * x - s * y, s * x + c * y, r) for x, y, r in obs]).reshape(-1, 3)
    notes.update(reach_m=round(rho, 4), width_m=round(w, 4))
    return Room(seed, kind, shape, tpl, rad, base, gains, turn(start), turn(goal), obs, notes)


# ------------------------------------------------------------------------------------------ a room's run


def assembled_starts(room: Room) -> np.ndarray:
    """(n, 3): every robot on its template point at the start pose, heading the structure's heading."""
    x, y, th = room.start
    c, s = math.cos(th), math.sin(th)
    t = room.template
    return np.column_stack([x + c * t[:, 0] - s * t[:, 1], y + s * t[:, 0] + c * t[:, 1], np.full(len(t), th)])


def to_scenario(room: Room, duration_s: float):
    starts = assembled_starts(room)
    robots = {f"r{i + 1:02d}": {"p": [float(v) for v in room.template[i]], "start": [float(v) for v in starts[i]],
                                "radius": float(room.radii[i]), "wheel_base": float(room.wheel_base[i]),
                                "gain": [float(v) for v in room.gains[i]]}
              for i in range(room.n)}
    doc = {"schema": 1, "fleet": {"name": "room", "duration_s": duration_s},
           "mission": {"metric": "l2", "speed_max": SPEED, "turn_rate_max": TURN,
                       "goal": {"x": room.goal[0], "y": room.goal[1], "th": room.goal[2]},
                       "obstacles": [[float(v) for v in o] for o in room.obstacles]},
           "tracker": {"rate_hz": 30.0, "noise_xy_m": 0.002, "noise_th_rad": 0.005, "latency_s": 0.0},
           "sim": {"rate_hz": 120.0, "truth_rate_hz": 30.0},
           "defaults": {"wheel_speed_max": 0.3, "wheel_accel_max": 0.8},
           "robots": robots}
    return scenario_from_dict(doc)


def our_plan(room: Room) -> dict:
    """Our planner on the room: the field the agents build, followed from the start pose to its end. build_s: the
    agents' plan, the deferred build (vsfleet.field.build_field_deferred) and the first frame's descent from the start
    (which resolves the start's component when the goal cannot be reached from it, and builds the finer lattice when
    the room's own has no way from there: vs_field_set_refine); build_whole_s: the whole build (vs_field_build) of the
    room's own lattice, every component resolved up front. refined: the finer lattice was built."""
    args = (room.template, room.radii, PLAN_MARGIN_M, room.obstacles, Pose2(*room.goal))
    lattice = room_lattice(room.template, room.radii, PLAN_MARGIN_M, room.obstacles, room.goal)
    t0 = time.perf_counter()
    fld = build_field(*args, **lattice, deferred=True)
    follow_field(fld, Pose2(*room.start))
    build_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    build_field(*args, n_headings=lattice["n_headings"])
    build_whole_s = time.perf_counter() - t0
    way, blocked, left = follow_field(fld, Pose2(*room.start), path_m=1e9, cap=100000)
    lat = fld.lattice
    return {"success": not blocked, "length_m": ompl_ref.path_length_m(way), "build_s": build_s,
            "build_whole_s": build_whole_s,
            "left_m": float(left), "cell_m": lat.cell_m, "inflation_m": lat.inflation_m, "refined": fld.refined,
            "length_shortcut_m": ompl_ref.path_length_m(shortcut_path(fld, room.start)), "path": way}


def shortcut_path(fld, start, steps: int = 20000) -> np.ndarray:
    """The way the agents take it: from a pose, the field's descent over PATH_M with its any-angle shortcut;
    its first waypoint is the next pose (the whole descent's own length counts every lattice step)."""
    p, way = tuple(start), [tuple(start)]
    for _ in range(steps):
        w, _, _ = follow_field(fld, Pose2(*p), PATH_M, PATH_CAP)
        ahead = [q for q in w[1:] if not np.allclose(q, p, atol=1e-9)]
        if not ahead:
            break
        p = tuple(float(v) for v in ahead[0])
        way.append(p)
    return np.array(way)


def min_gaps_m(pos: np.ndarray, radii: np.ndarray, obstacles: np.ndarray) -> tuple[float, float]:
    """(bodies vs bodies, bodies vs obstacles): the smallest gaps over every frame of pos (F, n, 2)."""
    iu = np.triu_indices(pos.shape[1], 1)
    bb = bo = math.inf
    for k in range(0, len(pos), 256):
        p = pos[k:k + 256]
        d = np.hypot(p[:, :, None, 0] - p[:, None, :, 0], p[:, :, None, 1] - p[:, None, :, 1])
        d = d - radii[:, None] - radii[None, :]
        bb = min(bb, float(d[:, iu[0], iu[1]].min()))
        if len(obstacles):
            e = np.hypot(p[:, :, None, 0] - obstacles[None, None, :, 0], p[:, :, None, 1] - obstacles[None, None, :, 1])
            bo = min(bo, float((e - radii[None, :, None] - obstacles[None, None, :, 2]).min()))
    return bb, bo


def heading_error(pose: Pose2, goal) -> float:
    return abs(math.remainder(pose.th - goal[2], 2 * math.pi))


def goal_time(run, goal) -> float | None:
    """The first time the fitted structure is within GOAL_M and GOAL_RAD of the goal pose (None: never)."""
    for t, p in run.trace:
        if math.hypot(p.x - goal[0], p.y - goal[1]) < GOAL_M and heading_error(p, goal) <= GOAL_RAD:
            return float(t)
    return None


def evaluate(seed: int, ompl_checks: int = ompl_ref.MAX_CHECKS, cap_s: float = 150.0) -> dict:
    room = make_room(seed)
    ref = ompl_ref.plan_ompl(room.template, room.radii, room.obstacles, room.start, room.goal,
                             margin_m=PLAN_MARGIN_M, max_checks=ompl_checks)
    ours = our_plan(room)
    length = ref.length_m if ref.success else (ours["length_m"] if ours["success"] else math.nan)
    ref_s = length / SPEED if not math.isnan(length) else math.nan
    duration = min(cap_s, max(60.0, 2.5 * ref_s)) if not math.isnan(ref_s) else 60.0
    t0 = time.perf_counter()
    scenario = to_scenario(room, duration)
    run = run_offline(scenario, duration, seed=seed, goal_tol_m=GOAL_M)
    if run.t_goal_s is not None and heading_error(run.trace[-1][1], room.goal) > GOAL_RAD:
        # at the goal's position but not yet at its heading: the same run again, to its end this time
        run = run_offline(scenario, duration, seed=seed, goal_tol_m=GOAL_M, stop_at_goal=False)
    t_goal = goal_time(run, room.goal)
    wall = time.perf_counter() - t0
    bb, bo = min_gaps_m(run.positions_m, room.radii, room.obstacles)
    said = {r: [d.kind for d in ds if d.kind in ("blocked", "unblocked")] for r, ds in run.decisions.items()}
    first = next(iter(said.values()))
    ended_blocked = t_goal is None and any(k and k[-1] == "blocked" for k in said.values())
    trace = np.array([[p.x, p.y, p.th] for _, p in run.trace])
    end = trace[-1]
    return {
        "seed": seed, "kind": room.kind, "shape": room.shape, "n": room.n, "obstacles": len(room.obstacles),
        "notes": room.notes, "start": list(room.start), "goal": list(room.goal),
        "ompl": {"success": ref.success, "length_m": ref.length_m, "time_s": ref.time_s, "checks": ref.checks,
                 "status": ref.status},
        "ours": {k: v for k, v in ours.items() if k != "path"},
        "ref_length_m": length, "ref_s": ref_s, "duration_s": duration,
        "t_goal_s": t_goal, "t_position_s": run.t_goal_s,
        "in_time": t_goal is not None and not math.isnan(ref_s) and t_goal <= WITHIN * ref_s,
        "gap_bodies_m": bb, "gap_obstacles_m": bo, "gap_m": min(bb, bo),
        "blocked_events": sum(k == "blocked" for k in first),
        "agents_ended_blocked": sum(bool(k) and k[-1] == "blocked" for k in said.values()),
        "ended_blocked": ended_blocked,
        "other_decisions": sorted({d.kind for ds in run.decisions.values() for d in ds} - {"blocked", "unblocked"}),
        "end_goal_m": float(math.hypot(end[0] - room.goal[0], end[1] - room.goal[1])),
        "end_heading_rad": heading_error(Pose2(*end), room.goal),
        "wall_s": wall,
        # for the figure: the room, the origin's path every 0.5 s, the bodies at the start and at the end
        "draw": {"obstacles": room.obstacles.round(4).tolist(), "radii": room.radii.round(4).tolist(),
                 "origin": trace[::15, :2].round(4).tolist(), "first": run.positions_m[0].round(4).tolist(),
                 "last": run.positions_m[-1].round(4).tolist(), "ompl": np.round(ref.path, 4).tolist(),
                 "ours": np.round(ours["path"][:: max(1, len(ours["path"]) // 200)], 4).tolist()},
    }


# ------------------------------------------------------------------------------------------ the report


def _pct(a: int, b: int) -> str:
    return f"{a}/{b} ({100.0 * a / b:.0f} %)" if b else "-"


def _m(v) -> str:
    return "none" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.2f} m"


def _t(v) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.2f}"


def has_way(r: dict) -> bool:
    """Whether the room has a way: OMPL found one, or our fleet drove one (it reached the goal pose without a
    contact). OMPL's budget (MAX_CHECKS) can run out in a room that has one: rooms 54 and 174 of the 200 (a line of
    10 through a wall's gap), which our fleet drove through with 20 mm to spare, were counted as rooms with no way
    that did not end blocked until 2026-12-06."""
    return bool(r["ompl"]["success"]) or (r["t_goal_s"] is not None and r["gap_m"] > 0.0)


def pooled(rows: list[dict]) -> dict:
    way = [r for r in rows if has_way(r)]
    noway = [r for r in rows if not has_way(r)]
    ours_way = [r for r in rows if r["ours"]["success"]]
    return {
        "rooms": len(rows), "way": len(way), "ompl_way": sum(bool(r["ompl"]["success"]) for r in rows),
        "ours_way": len(ours_way),
        "agree": sum(r["ompl"]["success"] == r["ours"]["success"] for r in rows),
        "way_in_time": sum(r["in_time"] for r in way), "way_reached": sum(r["t_goal_s"] is not None for r in way),
        "noway_blocked": sum(r["ended_blocked"] for r in noway), "noway": len(noway),
        "way_blocked": sum(r["ended_blocked"] for r in way),
        "contacts": sum(r["gap_m"] < 0 for r in rows),
        "min_gap_m": min((r["gap_m"] for r in rows), default=math.nan),
        "ours_build_s": [r["ours"]["build_s"] for r in rows], "ompl_s": [r["ompl"]["time_s"] for r in rows],
        "ours_whole_s": [r["ours"].get("build_whole_s", math.nan) for r in rows],
        "ompl_s_way": [r["ompl"]["time_s"] for r in way if r["ompl"]["success"]],
        "ratio": [r["t_goal_s"] / r["ref_s"] for r in way
                  if r["t_goal_s"] is not None and r["ref_s"] is not None and math.isfinite(r["ref_s"])],
        "len_ratio": [r["ours"]["length_m"] / r["ompl"]["length_m"] for r in way
                      if r["ours"]["success"] and r["ompl"]["success"]],
    }


def table(rows: list[dict], key: str, groups) -> str:
    out = [f"| {key} | rooms | OMPL: a way | ours: a way | agree | a way (OMPL's, or driven by our fleet) | "
           f"way rooms reached in {WITHIN:g}x ref | reached at all | "
           f"time / ref (median) | our path / OMPL's (median) | no-way rooms ended blocked | way rooms ended blocked | "
           f"contacts | smallest gap | our plan (median / max) | whole build (median / max) | "
           f"OMPL (median / max; way rooms median) |",
           "|---|" + "---|" * 16]
    for name, sel in groups:
        p = pooled(sel)
        if not p["rooms"]:
            continue
        way_ms = f"{1e3 * np.median(p['ompl_s_way']):.0f} ms" if p["ompl_s_way"] else "-"
        out.append(
            f"| {name} | {p['rooms']} | {p['ompl_way']} | {p['ours_way']} | {p['agree']} | {p['way']} | "
            f"{_pct(p['way_in_time'], p['way'])} | {p['way_reached']}/{p['way']} | "
            f"{_t(float(np.median(p['ratio'])) if p['ratio'] else math.nan)} | "
            f"{_t(float(np.median(p['len_ratio'])) if p['len_ratio'] else math.nan)} | {_pct(p['noway_blocked'], p['noway'])} | "
            f"{p['way_blocked']} | {p['contacts']} | {1e3 * p['min_gap_m']:.1f} mm | "
            f"{1e3 * np.median(p['ours_build_s']):.0f} / {1e3 * max(p['ours_build_s']):.0f} ms | "
            f"{1e3 * np.median(p['ours_whole_s']):.0f} / {1e3 * max(p['ours_whole_s']):.0f} ms | "
            f"{1e3 * np.median(p['ompl_s']):.0f} / {1e3 * max(p['ompl_s']):.0f} ms; "
            f"{way_ms} |")
    return "\n".join(out)


def summary(rows: list[dict]) -> str:
    by_n = [(f"N={n}", [r for r in rows if r["n"] == n]) for n in FLEETS] + [("all", rows)]
    by_kind = [(k, [r for r in rows if r["kind"] == k]) for k in KINDS]
    lines = [table(rows, "fleet", by_n), "", table(rows, "room", by_kind), ""]
    odd = [r for r in rows if has_way(r) and not r["in_time"]]
    if odd:
        lines.append("Rooms with a way (OMPL's, or driven by our fleet) not reached within "
                     f"{WITHIN:g}x the reference time:\n")
        lines.append("| room | kind | fleet | obstacles | OMPL length | ours: a way / length | goal pose reached | ref | ended blocked | "
                     "end, from goal | gap |")
        lines.append("|---|" + "---|" * 10)
        for r in odd:
            reached = "-" if r["t_goal_s"] is None else f"{r['t_goal_s']:.1f} s (position {r['t_position_s']:.1f} s)"
            lines.append(f"| {r['seed']} | {r['kind']} | {r['shape']} ({r['n']}) | {r['obstacles']} | "
                         f"{_m(r['ompl']['length_m'])} | {'yes' if r['ours']['success'] else 'no'} / "
                         f"{r['ours']['length_m']:.2f} m | {reached} | {_t(r['ref_s'])} s | "
                         f"{'yes' if r['ended_blocked'] else 'no'} | {r['end_goal_m']:.2f} m | {1e3 * r['gap_m']:.1f} mm |")
    return "\n".join(lines)


def _plain(v):
    """JSON-ready: numpy scalars as Python numbers, NaN and inf as null."""
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v) if math.isfinite(v) else None
    return v


def draw(rows: list[dict], path: Path, count: int = 6) -> None:
    """~six rooms: one of each kind first (a way and none), then rooms with a way not reached in time."""
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    pick: list[dict] = []
    for r in [r for r in rows if has_way(r) and not r["in_time"]][:2]:
        pick.append(r)
    for k in KINDS:
        for r in rows:
            if r["kind"] == k and r not in pick and len(pick) < count:
                pick.append(r)
                break
    for r in rows:
        if len(pick) >= count:
            break
        if r not in pick and r["n"] not in {p["n"] for p in pick}:
            pick.append(r)
    if not pick:
        return
    cols = 3
    rows_n = math.ceil(len(pick) / cols)
    fig, axes = plt.subplots(rows_n, cols, figsize=(5 * cols, 4.4 * rows_n), squeeze=False)
    for ax in axes.ravel()[len(pick):]:
        ax.axis("off")
    for ax, r in zip(axes.ravel(), pick):
        d = r["draw"]
        for x, y, rr in d["obstacles"]:
            ax.add_patch(plt.Circle((x, y), rr, color="0.65", lw=0))
        for key, style in (("ompl", "C2-"), ("ours", "C1:")):
            p = np.array(d[key]).reshape(-1, 3)
            if len(p):
                ax.plot(p[:, 0], p[:, 1], style, lw=1, label=f"{key} plan")
        o = np.array(d["origin"])
        ax.plot(o[:, 0], o[:, 1], "k-", lw=1.2, label="structure origin")
        for key, style in (("first", ":"), ("last", "-")):
            for (x, y), rr in zip(d[key], d["radii"]):
                ax.add_patch(plt.Circle((x, y), rr, fill=False, ls=style, color="C0" if key == "first" else "C3", lw=0.8))
        ax.plot(*r["goal"][:2], "r+", ms=10)
        ax.set_aspect("equal")
        ax.autoscale_view()
        goal = "not reached" if r["t_goal_s"] is None else f"goal {r['t_goal_s']:.0f} s (ref {_t(r['ref_s'])} s)"
        ax.set_title(f"room {r['seed']}: {r['kind']}, {r['shape']}; OMPL {'way' if r['ompl']['success'] else 'no way'}, "
                     f"ours {'way' if r['ours']['success'] else 'blocked'}\n{goal}"
                     f"{', ended blocked' if r['ended_blocked'] else ''}", fontsize=8)
        ax.tick_params(labelsize=7)
    axes.ravel()[0].legend(fontsize=6, loc="best")
    fig.suptitle("bench/room.py: dotted bodies at the start, solid at the end; green OMPL's path, orange dotted ours",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


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


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True,
                              cwd=Path(__file__).resolve().parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "?"


def _evaluated(seeds, ompl_checks: int, cap_s: float, jobs: int):
    """evaluate() of every seed, each row as it is done: in this process (jobs 1), or in jobs worker processes."""
    if jobs == 1:
        for seed in seeds:
            yield evaluate(seed, ompl_checks, cap_s)
        return
    from concurrent.futures import ProcessPoolExecutor, as_completed
    pool = ProcessPoolExecutor(max_workers=jobs)
    try:
        for done in as_completed([pool.submit(evaluate, seed, ompl_checks, cap_s) for seed in seeds]):
            yield done.result()
    finally:   # an error (a room's, or the caller's) does not wait for the rooms still queued
        pool.shutdown(wait=True, cancel_futures=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rooms", type=int, default=200)
    ap.add_argument("--first", type=int, default=0, help="the first room's seed (room k is seed first + k)")
    ap.add_argument("--ompl-checks", type=int, default=ompl_ref.MAX_CHECKS,
                    help="OMPL's budget per room: state validity checks")
    ap.add_argument("--cap-s", type=float, default=150.0, help="simulated seconds per room at most")
    ap.add_argument("--jobs", type=int, default=1,
                    help="rooms run at a time, in worker processes (each room is a pure function of its seed; the "
                         "plan times, and OMPL's 30 s time limit behind its check budget, then share the host "
                         "with the other jobs; rooms.json keeps the rows in seed order, those done so far)")
    ap.add_argument("--picture", default=None, help="also draw scenarios/paper-triangle-obstacle.toml's run here")
    add_output_flags(ap, "room", DOCS / "bench" / "room", "rooms.json and rooms.png")
    ap.add_argument("--report", type=Path, default=None,
                    help="no runs: the tables (stdout) and rooms.png (next to it) of a rooms.json written before")
    a = ap.parse_args(argv)
    if a.jobs < 1:
        ap.error("--jobs must be at least 1")
    if a.picture:
        picture(a.picture, "scenarios/paper-triangle-obstacle.toml")
    if a.report is not None:
        rows = json.loads(a.report.read_text())["rooms"]
        print(summary(rows))
        draw(rows, a.report.with_name("rooms.png"))
        return 0
    if a.rooms <= 0:
        return 0
    if not ompl_ref.available():
        print("bench/room.py needs OMPL's Python bindings: pip install 'ompl>=2.0' (the bench extra)", file=sys.stderr)
        return 2
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"machine": f"{platform.machine()} {platform.processor() or ''}".strip(), "python": platform.python_version(),
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "rooms": a.rooms, "first": a.first,
            "ompl_checks": a.ompl_checks, "cap_s": a.cap_s, "commit": _commit(), "jobs": a.jobs,
            "core_sha256": hashlib.sha256(Path(_core.__file__).read_bytes()).hexdigest()[:16]}
    rows, t0 = [], time.perf_counter()
    for k, r in enumerate(_evaluated(range(a.first, a.first + a.rooms), a.ompl_checks, a.cap_s, a.jobs)):
        rows.append(r)
        rows.sort(key=lambda row: row["seed"])
        (out / "rooms.json").write_text(json.dumps(_plain({"meta": {**meta, "done": k + 1}, "rooms": rows})))
        el = time.perf_counter() - t0
        print(f"[room {k + 1}/{a.rooms}] seed {r['seed']} {r['kind']:7s} {r['shape']:9s} obstacles {r['obstacles']:3d} | "
              f"OMPL {'way' if r['ompl']['success'] else 'none'} {r['ompl']['time_s']:.2f} s | "
              f"ours {'way' if r['ours']['success'] else 'blocked'} {1e3 * r['ours']['build_s']:.0f} ms | "
              f"goal {_t(r['t_goal_s'])} s (ref {_t(r['ref_s'])} s) blocked {r['blocked_events']} "
              f"gap {1e3 * r['gap_m']:.1f} mm | run {r['wall_s']:.0f} s, "
              f"ETA {el / (k + 1) * (a.rooms - k - 1) / 60:.1f} min", file=sys.stderr, flush=True)
    text = summary(rows)
    print(text)
    meta.update(done=a.rooms, wall_s=time.perf_counter() - t0)
    (out / "rooms.json").write_text(json.dumps(_plain({"meta": meta, "summary": text, "rooms": rows}), indent=1))
    draw(rows, out / "rooms.png")
    print(f"\nwritten: {out / 'rooms.json'}, {out / 'rooms.png'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
