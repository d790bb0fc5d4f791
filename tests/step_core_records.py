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
from vsfleet.coreconst import AGENT_STATE, METRICS
from vsfleet.step import core_mission, frame_arrays, mission_arrays

#: the room's field in these records: a coarse lattice (8 cm, 16 headings), so that the replay under
#: qemu builds its 240 fields in seconds; the agents' own lattice is vsfleet.field's
FIELD = (0.08, 16.0, 200000.0)

PILLAR = ((0.8, 0.5, 0.3),)
WALL = tuple((1.3 + 0.0 * k, -1.0 + 0.25 * k, 0.14) for k in range(13))  # x = 1.3 m, y from -1 to 2 m


def step_records(rooms_only: bool = False) -> list[tuple[str, list[float]]]:
    mission, frames, config, _ = load()
    out = []
    rooms = [(metric, (), None, 4) for metric in METRICS] + [("linf", PILLAR, 0.05, 8), ("linf", WALL, 0.05, 8)]
    if rooms_only:
        rooms = rooms[len(METRICS):]
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


def held_records() -> list[tuple[str, list[float]]]:
    """``structure_step_held``: every third room record above (the pillar, then the wall that blocks the way), the field
    provisional (vs_field_set_provisional, a first plan): where the wall's field has no way the structure holds,
    neither blocked nor at the goal; beside the pillar, the same as structure_step (recorded 2026-12-07)."""
    return [("structure_step_held", inputs) for _entry, inputs in step_records(rooms_only=True)[::3]]


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
        elapsed = [0.0, 9.99, 10.0, 37.2, 123.4, -3.0, 5e10][(k // 7) % 7]   # the priorities' draws (vs_assembly.h)
        out.append(("assembly_targets", [float(n), margin, elapsed, *radii, *pose.ravel(), *seen.astype(float),
                                         *points.ravel(), *nxt.ravel()]))
    return out


#: the agent's whole step (vs_golden.c's ``agent_step``): runs of real scenarios offline, one agent's frames each
#: (name, scenario, seconds, run_offline's keywords, robot, frames run before the record, the record's frames,
#: edits: frame index -> ("drop", robot ids missing), ("gap", frames skipped before it) or ("still", frames skipped
#: before it, the frame keeping the poses of the one before the gap: the whole fleet stood)
AGENT_RUNS = (
    ("paper-triangle precision", "paper-triangle", 5.0, {"seed": 3, "stop_at_goal": False, "controller": "precision"}, "r1", 0, 40,
     {12: ("drop", ("r2",)), 13: ("drop", ("r2", "r3")), 25: ("gap", 11)}),
    ("paper-triangle turn_then_go", "paper-triangle", 5.0, {"seed": 3, "stop_at_goal": False, "controller": "turn_then_go"}, "r2", 10, 40,
     {20: ("gap", 35), 30: ("drop", ("r1",))}),
    ("paper-triangle arc", "paper-triangle", 5.0, {"seed": 3, "stop_at_goal": False, "controller": "arc"}, "r3", 5, 40,
     {8: ("drop", ("r3",)), 9: ("drop", ("r3",)), 22: ("gap", 10)}),
    ("paper-triangle tracking", "paper-triangle", 5.0, {"seed": 3, "stop_at_goal": False, "controller": "tracking"}, "r1", 20, 40,
     {15: ("drop", ("r1", "r2", "r3")), 16: ("gap", 40)}),
    ("paper-failure hold", "paper-failure@hold", 14.0, {"seed": 2, "stop_at_goal": False}, "r1", 262, 60,
     {40: ("drop", ("r2",))}),
    ("paper-failure drop", "paper-failure@drop", 14.0, {"seed": 2, "stop_at_goal": False}, "r3", 262, 60,
     {45: ("gap", 11)}),
    ("paper-failure rejoin", "paper-failure@rejoin", 14.0, {"seed": 2, "stop_at_goal": False}, "r2", 262, 60,
     {50: ("gap", 33)}),
    ("room-pillar-facing", "room-pillar-facing", 6.0, {"seed": 1}, "r1", 100, 50, {30: ("drop", ("r2",))}),
    ("room-wall-gap", "room-wall-gap", 6.0, {"seed": 1}, "r2", 60, 50, {10: ("gap", 12)}),
    # a gap past the resync gap while the stall watch runs: the watch restarts with the failure timers (2026-12-05)
    ("room-wall-gap resync", "room-wall-gap", 8.0, {"seed": 1}, "r2", 60, 50, {49: ("still", 100)}),
    ("room-4", "room-4", 12.0, {"seed": 4}, "r01", 200, 40, {}),
    ("walled-in blocked", "walled-in", 3.0, {"seed": 1}, "r2", 0, 40, {20: ("drop", ("r3",))}),
    ("room-column-switch", "room-column-switch", 40.0, {"seed": 1}, "r1", 830, 40, {5: ("drop", ("r3",))}),
    ("crowd-10", "crowd-10", 3.0, {"seed": 3, "stop_at_goal": False}, "r03", 20, 30,
     {5: ("drop", ("r01", "r07")), 18: ("gap", 12)}),
)


def _scenario(name: str):
    from vsfleet.zglue.scenario_file import load_scenario
    if name.startswith("crowd-"):
        from bench.crowd import crowd_doc
        from vsfleet.scenario import scenario_from_dict
        return scenario_from_dict(crowd_doc(int(name.split("-")[1]), 3, 6.0), name=f"{name}-shuffled")
    if name == "room-4":   # tests/test_room.py: bench/room.py's room 4, a thin wall's gap threaded close to the
        from test_room import room_4   # wall (until 2026-12-05 the descent started in a sliver of the lattice there,
        return room_4()               # and every agent said 'blocked' at 7.4 s)
    if name == "walled-in":   # tests/test_room.py: a goal ringed with pillars, 'blocked' from the first frames
        from test_room import walled_in
        return walled_in()
    base, _, policy = name.partition("@")
    sc = load_scenario(Path(__file__).resolve().parent.parent / "scenarios" / f"{base}.toml")
    if policy:
        sc = dataclasses.replace(sc, mission=dataclasses.replace(sc.mission, on_failure=policy))
    return sc


def agent_run_frames(run) -> tuple:
    """One agent's frames of a run offline, as its agent_step took them: (robot, config, [(mission, frame, now_s)]
    run before the record, the record's [(mission, frame, now_s)]), the record's edited (robots missing, gaps)."""
    import sys
    root = str(Path(__file__).resolve().parent.parent)
    if root not in sys.path:
        sys.path.insert(0, root)   # bench/
    import vsfleet.agent.main as agent_main
    from vsfleet.frames import Frame
    from vsfleet.simfleet.offline import run_offline
    _name, scenario, seconds, kw, robot, warm, count, edits = run
    took, configs = [], []
    step_fn, payload_fn = agent_main.agent_step, agent_main.agent_payload_step

    def spy(state, mission, frame, now_s, config):
        if state.robot == robot and mission is not None:
            took.append((mission, frame, now_s))
            configs.append(config)
        return step_fn(state, mission, frame, now_s, config)

    agent_main.agent_step, agent_main.agent_payload_step = spy, lambda *a, **k: None   # every frame the long way
    try:
        run_offline(_scenario(scenario), seconds, share_structures=False, **kw)
    finally:
        agent_main.agent_step, agent_main.agent_payload_step = step_fn, payload_fn
    config = dataclasses.replace(configs[0], shared_structures=None)
    need = warm + count + sum(arg for what, arg in edits.values() if what in ("gap", "still"))
    assert len(took) >= need, f"{_name}: {len(took)} frames, {need} wanted"
    record, k = [], warm
    for j in range(count):
        what, arg = edits.get(j, (None, None))
        if what in ("gap", "still"):
            k += arg
        mission, frame, now_s = took[k]
        if what == "still":   # the whole fleet stood through the gap: the poses of the frame before it, at t
            before = record[-1][1] if record else took[k - arg - 1][1]
            frame = Frame(seq=frame.seq, t=frame.t, poses=before.poses, complete=before.complete, fresh=before.fresh,
                          src=frame.src, sources=frame.sources)
        if what == "drop":
            frame = Frame(seq=frame.seq, t=frame.t, poses={r: p for r, p in frame.poses.items() if r not in arg},
                          complete=False, fresh=frozenset(r for r in frame.fresh if r not in arg), src=frame.src,
                          sources=frame.sources)
        record.append((mission, frame, now_s))
        k += 1
    assert all(m.version == took[0][0].version for m, _, _ in took[:k]), "one mission per record"
    return robot, config, took[:warm], record


def agent_step_records(runs=AGENT_RUNS) -> list[tuple[str, list[float]]]:
    """vs_golden.c's ``agent_step`` on AGENT_RUNS: the agent's state after the frames run before the record (the
    core's path of vsfleet.step.agent_step), its mission and constants as vsfleet.step hands them to the core
    (vsfleet._core.agent_config's arguments), and the record's frames as frame_arrays gives them."""
    return [("agent_step", agent_step_inputs(*agent_run_frames(run))) for run in runs]


def agent_step_inputs(robot, config, warm, record) -> list[float]:
    import vsfleet.agentcore as agentcore
    import vsfleet.step as step
    from vsfleet import _core
    from vsfleet.field import CELL_M, HEADINGS, MAX_STATES
    from vsfleet.step import AgentState, agent_step
    mission = record[0][0]
    # the records pack the room's own field (vs_golden.c builds it): never a frame of a first plan
    assert not any(agentcore.in_first_plan(m, frame.t) for m, frame, _now in record), "a frame of the first plan"
    state = AgentState(robot=robot)
    for m, frame, now_s in warm:
        state, _ = agent_step(state, m, frame, now_s, config)
    arrays = mission_arrays(mission)
    controller = config.controller or step.mission_controller(mission.controller, mission.controller_gains)
    if state.mission_version != mission.version:
        state = step.enter_mission(state, mission, arrays.policy, config)
    got = []
    make = _core.agent_config
    agentcore.core_mission_of(mission).kernels.clear()
    _core.agent_config = lambda *a: got.append(a) or make(*a)
    try:
        kernel = agentcore.agent_kernel(agentcore.core_mission_of(mission), mission, robot, controller, config)
    finally:
        _core.agent_config = make
    (core, own, code, gains, deadband, still, policy, safety, times, room, bodies, _ids), = got
    (tpl, wb, vmax, amax, metric, kind, goal, limits, radii, obstacles, margin, _field, shapes_xy, _fields) = core
    tpl = np.asarray(tpl)
    n = len(arrays.ids)
    head = [float(n), float(metric), float(kind), float(len(goal) // 3), *goal, *limits, *tpl.ravel(), *wb, *vmax,
            *amax, margin, CELL_M, float(HEADINGS), float(MAX_STATES), float(len(obstacles) // 3), *radii,
            *obstacles, float(len(arrays.shapes)), *shapes_xy]
    gains = [*map(float, gains), *[0.0] * (17 - len(gains))]
    agent = [float(own), float(code), *gains, float(deadband), float(still), *map(float, policy), *map(float, safety),
             *map(float, times), float(room), float(bodies)]
    _ctrl, arrays_in, scalars = agentcore._core_inputs(kernel, state, controller, n)
    width = arrays_in[AGENT_STATE.index("window_t")].shape[1]
    packed = [float(width)] + [float(v) for a in arrays_in for v in np.asarray(a).ravel()] + [*map(float, scalars)]
    frames = []
    for _m, frame, _now in record:
        pose, seen, fresh = step.frame_arrays(arrays.ids, frame.poses, frame.fresh)
        frames += [float(frame.t), *pose.ravel(), *seen.astype(float), *fresh.astype(float)]
    return head + agent + packed + frames
