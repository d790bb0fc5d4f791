"""The structure step's records for the core's golden vectors (tests/golden_core.py).

The recorded frames of the agent step's golden vectors (tests/data/golden-step.json: the paper failure
scenario, noise, a robot missing now and then) packed as vs_golden.c's ``structure_step`` entry, for
each metric: every 4th frame, all robots used, and the same frames with r2 excluded and judged apart;
then the linf mission in a room (a pillar on its straight path, bodies of 0.05 m, and a wall that
blocks it), every 8th frame: the field's descent and the blocked stop. And ``structure_step_shapes``
(shape_records): scenarios/room-column-switch.toml with scale_min 0.7 (three scales and a column), the
robots as the triangle, the column or between them, before, in and after the wall's gap. And
``assembly_targets`` (assembly_records): the tie-break on random crowds.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from golden_step import load
from vsfleet.coreconst import METRICS
from vsfleet.step import core_mission, frame_arrays, mission_arrays

#: the room's field in these records: a coarse lattice (8 cm, 16 headings), so that the replay under
#: qemu builds its 240 fields in seconds; the agents' own lattice is vsfleet.field's
FIELD = (0.08, 16.0, 200000.0)

PILLAR = ((0.8, 0.5, 0.3),)
WALL = tuple((1.3 + 0.0 * k, -1.0 + 0.25 * k, 0.14) for k in range(13))  # x = 1.3 m, y from -1 to 2 m


def step_records() -> list[tuple[str, list[float]]]:
    mission, frames, config, _ = load()
    out = []
    rooms = [(metric, (), None, 4) for metric in METRICS] + [("linf", PILLAR, 0.05, 8), ("linf", WALL, 0.05, 8)]
    for metric, obstacles, radius, every in rooms:
        m = dataclasses.replace(mission, metric=metric)
        arrays = mission_arrays(m)
        n = len(arrays.ids)
        radii = [0.0] * n if radius is None else [radius] * n
        (tpl, wb, vmax, amax, code, kind, goal, limits, _radii, _obs,
         margin, _field, *_shapes) = core_mission(metric, arrays.template, arrays.envelopes, arrays.goal,
                                                 arrays.limits)
        head = [float(n), float(code), float(kind), float(len(goal) // 3), *goal, *limits, *tpl.ravel(), *wb,
                *vmax, *amax]
        room = [margin, *FIELD, float(len(obstacles)), *radii, *(v for o in obstacles for v in o)]
        for k, (frame, _) in enumerate(frames):
            if k % every:
                continue
            pose, seen, _fresh = frame_arrays(arrays.ids, frame.poses, frame.fresh)
            pose = np.where(seen[:, None], pose, 0.0)
            for excluded, judged in ((np.zeros(n), np.zeros(n)), (np.array([0.0, 1.0, 0.0]), np.zeros(n)),
                                     (np.zeros(n), np.array([0.0, 1.0, 0.0]))):
                out.append(("structure_step", [*head, *pose.ravel(), *seen.astype(float), *excluded, *judged,
                                               frame.t - m.effective_t, config.dt_s, *room]))
    return out


def shape_records(seed: int = 23, count: int = 48) -> list[tuple[str, list[float]]]:
    from vsfleet.wire import mission_from_dict
    from vsfleet.zglue.scenario_file import load_scenario
    scenario = load_scenario(Path(__file__).resolve().parent.parent / "scenarios" / "room-column-switch.toml")
    m = mission_from_dict({**scenario.mission.to_dict(), "scale_min": 0.7})
    out = _shape_records(m, seed, count)
    # a structure 2.2 times the triangle (reach 0.64 m: the carrot runs 0.3 of it ahead, vs_step.h) round a pillar
    d = scenario.mission.to_dict()
    for spec in d["robots"].values():
        spec["p"] = [2.2 * v for v in spec["p"]]
    big = mission_from_dict({**d, "shapes": None, "obstacles": [[1.0, 0.4, 0.15]]})
    return out + _shape_records(big, seed + 1, count // 2)


def _shape_records(m, seed: int, count: int) -> list[tuple[str, list[float]]]:
    arrays = mission_arrays(m)
    n = len(arrays.ids)
    (tpl, wb, vmax, amax, code, kind, goal, limits, radii, obstacles,
     margin, _field, shapes_xy, _fields) = core_mission(m.metric, arrays.template, arrays.envelopes, arrays.goal,
                                                        arrays.limits, m.radii, m.obstacles, None, arrays.shapes,
                                                        ())
    head = [float(n), float(code), float(kind), float(len(goal) // 3), *goal, *limits, *tpl.ravel(), *wb, *vmax,
            *amax]
    room = [margin, *FIELD, float(len(m.obstacles)), *radii, *obstacles, float(len(arrays.shapes)), *shapes_xy]
    rng = np.random.default_rng(seed)
    col = arrays.shapes[-1][1] if arrays.shapes else arrays.template
    out = []
    for k in range(count):
        mix = rng.choice([0.0, 1.0, rng.uniform()])
        pts = (1 - mix) * arrays.template + mix * col
        th = rng.uniform(-math.pi, math.pi) if k % 3 else rng.choice([0.0, math.pi])
        x, y = [(0.0, 0.0), (0.6, 1.25), (1.0, 1.25), (1.3, 1.25), (1.9, 1.4), (0.5, 0.5)][k % 6]
        c, s = math.cos(th), math.sin(th)
        xy = np.stack([c * pts[:, 0] - s * pts[:, 1] + x, s * pts[:, 0] + c * pts[:, 1] + y], axis=1)
        pose = np.column_stack([xy + rng.normal(0, 0.01, xy.shape), rng.uniform(-3, 3, n)])
        out.append(("structure_step_shapes", [*head, *pose.ravel(), *np.ones(n), *np.zeros(n), *np.zeros(n),
                                              0.1 * k, 1.0 / 30.0, *room]))
    return out


def assembly_records(seed: int = 29, count: int = 150) -> list[tuple[str, list[float]]]:
    """The assembly tie-break (vs_golden.c's ``assembly_targets``) on crowds of 2-40 robots: blocks packed 1-5 cm
    apart, collinear rows, head-on pairs, a 1/32 m grid with points along the axes (blockers tied in along), and
    scattered robots at 1e-3 and 1e3 m scales; some robots near their points, some unseen (rows zeroed, as the
    step leaves them)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        n, kind = int(rng.integers(2, 41)), k % 5
        radius = 0.05 if k % 3 else float(rng.uniform(0.0, 0.08))
        gap = float(rng.uniform(0.01, 0.05))
        pitch = 2.0 * radius + gap
        if kind == 0:
            xy = np.array([(pitch * (i % 5), pitch * (i // 5)) for i in range(n)]) + rng.normal(0.0, 0.002, (n, 2))
        elif kind == 1:
            th = 0.0 if k % 2 else float(rng.uniform(-math.pi, math.pi))
            xy = np.c_[pitch * np.arange(n) * math.cos(th), pitch * np.arange(n) * math.sin(th)]
        elif kind == 2:
            xy = np.array([((i % 2) * pitch, 0.4 * (i // 2)) for i in range(n)])
        elif kind == 3:
            cells = rng.choice(64, size=n, replace=False)
            xy = np.c_[cells % 8, cells // 8] / 32.0
        else:
            xy = rng.uniform(-0.3, 0.3, (n, 2)) * math.sqrt(n) * [1e-3, 1.0, 1e3][k % 3]
        if kind == 2:
            points = xy + np.c_[np.where(np.arange(n) % 2 == 0, 0.5, -0.5), np.zeros(n)]
        elif kind == 3:
            axis = np.array([(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)])[rng.integers(0, 4, n)]
            points = xy + axis * rng.integers(1, 9, (n, 1)) / 8.0
        else:
            points = xy + rng.uniform(-0.6, 0.6, (n, 2)) * math.sqrt(n / 5.0) * ([1e-3, 1.0, 1e3][k % 3] if kind == 4
                                                                                else 1.0)
        near = rng.random(n) < 0.15
        points[near] = xy[near] + rng.uniform(-0.03, 0.03, (int(near.sum()), 2))
        seen = rng.random(n) < (1.0 if k % 4 == 0 else 0.85)
        pose = np.where(seen[:, None], np.c_[xy, rng.uniform(-math.pi, math.pi, n)], 0.0)
        nxt = points + (0.0 if k % 3 == 0 else rng.normal(0.0, 0.005, (n, 2)))
        margin = 0.015 if k % 4 else float(rng.uniform(0.0, 0.03))
        radii = np.full(n, radius) if k % 7 else rng.uniform(0.0, 0.08, n)
        out.append(("assembly_targets", [float(n), margin, *radii, *pose.ravel(), *seen.astype(float),
                                         *points.ravel(), *nxt.ravel()]))
    return out
