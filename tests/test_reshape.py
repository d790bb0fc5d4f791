"""Reshape (issue 28): a mission's smaller scales and alternative templates, validated at the boundary, chosen by
every agent alike from the frame alone, and taken where the template cannot pass (docs/planning.md, "Shapes").

The rooms: a closed box split by a thick wall (discs of radius 0.25 m, 0.2 m apart) with one gap. The paper
triangle with its bodies of 0.09 m is 0.61 m across its narrow side, and the wall is too deep for a disc of it to
pass between two robots, so the triangle has no way through a gap narrower than that."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from vsfleet.fit import fit_structure
from vsfleet.simfleet.offline import run_offline
from vsfleet.step import mission_arrays, mission_scales, mission_shapes, structure_step
from vsfleet.structure import structure_step_reference
from vsfleet.wire import StateMsg, WireError, decode_mission, decode_state, encode, encode_mission, mission_from_dict
from vsfleet.zglue.scenario_file import load_scenario

ROOT = Path(__file__).resolve().parent.parent
COLUMN = {"r1": [0.3, 0.0], "r2": [0.0, 0.0], "r3": [-0.3, 0.0]}


def box_room(gap_lo_m: float, gap_hi_m: float) -> tuple[tuple[float, float, float], ...]:
    """The box (x -1..3 m, y -1.2..3.2 m) and its dividing wall at x = 1 m with a gap from gap_lo_m to gap_hi_m."""
    obs = []
    y = gap_lo_m - 0.25
    while y > -1.0:
        obs.append((1.0, round(y, 4), 0.25))
        y -= 0.2
    y = gap_hi_m + 0.25
    while y < 3.0:
        obs.append((1.0, round(y, 4), 0.25))
        y += 0.2
    for x in np.arange(-1.0, 3.0001, 0.15):
        obs += [(round(float(x), 4), -1.2, 0.1), (round(float(x), 4), 3.2, 0.1)]
    for y in np.arange(-1.05, 3.0501, 0.15):
        obs += [(-1.0, round(float(y), 4), 0.1), (3.0, round(float(y), 4), 0.1)]
    return tuple(obs)


def scenario_with(**changes):
    """scenarios/room-column-switch.toml (gap 0.40 m, a column allowed) with mission fields changed, validated
    again as a mission from the wire is."""
    scenario = load_scenario(ROOT / "scenarios" / "room-column-switch.toml")
    d = {**dataclasses.replace(scenario.mission).to_dict(), **changes}
    d = {k: v for k, v in d.items() if v is not None}
    return dataclasses.replace(scenario, mission=mission_from_dict(d))


def obstacle_gap_m(scenario, run) -> float:
    obs = np.array(scenario.mission.obstacles)
    rad = np.array(scenario.mission.radii)
    pos = run.positions_m
    d = np.hypot(pos[:, :, None, 0] - obs[None, None, :, 0], pos[:, :, None, 1] - obs[None, None, :, 1])
    return float((d - obs[None, None, :, 2] - rad[None, :, None]).min())


def assembled_m(scenario, run) -> float:
    """How far the robots' final positions are from the template fitted to them (the largest, [m])."""
    tpl = np.array([s.p for _, s in scenario.mission.robots])
    return float(fit_structure(tpl, run.positions_m[-1], metric="l2").residuals_m.max())


# ------------------------------------------------------------------------------------------ the mission


def test_the_reshape_fields_are_validated_and_round_trip_and_absent_they_encode_as_before():
    base = scenario_with().mission
    assert base.shapes == (("column", ((0.3, 0.0), (0.0, 0.0), (-0.3, 0.0))),) and base.scale_min is None
    assert decode_mission(encode_mission(base)) == base
    scaled = dataclasses.replace(base, scale_min=0.7, shapes=())
    assert decode_mission(encode_mission(scaled)) == scaled
    plain = dataclasses.replace(base, shapes=())
    assert not {"shapes", "scale_min"} & plain.to_dict().keys()
    d = base.to_dict()
    bad = [
        ({"scale_min": 0.0}, "scale_min"), ({"scale_min": 1.5}, "scale_min"), ({"scale_min": "x"}, "scale_min"),
        ({"scale_min": 0.3}, "overlap"),   # 0.5 m apart at 0.3: 0.15 m, less than two bodies of 0.09 m
        ({"shapes": []}, "shapes"), ({"shapes": [{"name": "c", "points": COLUMN, "speed": 1}]}, "unknown"),
        ({"shapes": [{"name": "c", "points": {"r1": [0, 0], "r2": [0.3, 0]}}]}, "every robot"),
        ({"shapes": [{"name": "c", "points": {**COLUMN, "r9": [1, 1]}}]}, "every robot"),
        ({"shapes": [{"name": "c", "points": {**COLUMN, "r3": [0.1, 0.0]}}]}, "overlap"),
        ({"shapes": [{"name": "c", "points": {**COLUMN, "r3": [0.1]}}]}, "[x, y]"),
        ({"shapes": [{"name": "c", "points": {**COLUMN, "r3": [math.nan, 0.0]}}]}, "finite"),
        ({"shapes": [{"name": "c", "points": COLUMN}, {"name": "c", "points": COLUMN}]}, "twice"),
        ({"shapes": [{"name": f"c{k}", "points": COLUMN} for k in range(5)]}, "limit"),
        ({"shapes": [{"name": "a/b", "points": COLUMN}]}, "name"),
    ]
    for change, words in bad:
        with pytest.raises(WireError, match=words):
            mission_from_dict({**d, **change})


def test_the_scales_run_down_to_scale_min_in_at_most_four_steps_largest_first():
    assert mission_scales(None) == () and mission_scales(1.0) == ()
    assert mission_scales(0.9) == (0.9,)
    assert mission_scales(0.7) == pytest.approx((0.9, 0.8, 0.7)) and mission_scales(0.7)[-1] == 0.7
    assert mission_scales(0.5) == (0.875, 0.75, 0.625, 0.5)
    m = scenario_with(scale_min=0.5).mission
    names = [n for n, _ in mission_shapes(m)]
    assert names == ["scale 0.875", "scale 0.75", "scale 0.625", "scale 0.5", "column"]
    tpl = np.array([s.p for _, s in m.robots])
    assert np.array_equal(mission_shapes(m)[1][1], tpl * 0.75)
    # without obstacles there is no room, and no shape
    assert mission_shapes(dataclasses.replace(m, obstacles=())) == ()


def test_the_state_reports_the_shape_and_an_older_state_without_it_is_the_template():
    msg = StateMsg(t=1.0, seq=2, x=0.0, y=0.0, th=0.0, gx=0.0, gy=0.0, gth=0.0, cost=0.0, err=0.0, used=("r1",),
                   rejected=0, mission=1, shape=1)
    assert decode_state(encode(msg)).shape == 1
    assert decode_state(encode(msg, shape=0)).shape == 0
    import msgpack
    older = msgpack.unpackb(encode(msg))
    del older["shape"]
    assert decode_state(msgpack.packb(older)).shape == 0


# --------------------------------------------------------------------------------------- the choice


def test_the_core_and_the_reference_choose_the_same_shape_and_structure_bit_for_bit():
    scenario = scenario_with(scale_min=0.7)
    arrays = mission_arrays(scenario.mission)
    assert len(arrays.shapes) == 4 and len(arrays.shape_fields) == 4
    tri = arrays.template
    col = np.array(list(COLUMN.values()))
    rng = np.random.default_rng(5)
    seen_shapes = set()
    # the robots as the triangle or the column, at places before, in and after the gap, and in between
    for k in range(60):
        mix = rng.choice([0.0, 1.0, rng.uniform()])
        pts = (1 - mix) * tri + mix * col
        th = rng.uniform(-math.pi, math.pi) if k % 3 else rng.choice([0.0, math.pi])
        x, y = rng.choice([(0.0, 0.0), (0.6, 1.25), (1.0, 1.25), (1.3, 1.25), (1.9, 1.4), (0.5, 0.5)])
        c, s = math.cos(th), math.sin(th)
        xy = np.stack([c * pts[:, 0] - s * pts[:, 1] + x, s * pts[:, 0] + c * pts[:, 1] + y], axis=1)
        pose = np.column_stack([xy + rng.normal(0, 0.01, xy.shape), rng.uniform(-3, 3, 3)])
        n = len(pose)
        args = (arrays, scenario.mission.metric, pose, np.ones(n, bool), np.zeros(n, bool), np.zeros(n, bool),
                0.1 * k, 1 / 30)
        core = structure_step(*args)
        ref = structure_step_reference(*args)
        assert core.shape == ref.shape, k
        for a, b in ((core.fit_pose, ref.fit_pose), (core.goal_pose, ref.goal_pose)):
            assert a.as_tuple() == b.as_tuple(), k
        assert np.array_equal(core.points_next, ref.points_next) and core.blocked == ref.blocked, k
        seen_shapes.add(core.shape)
    assert {0, 4} <= seen_shapes   # the template, and the column, were both taken


def test_without_a_shape_that_passes_the_structure_is_blocked_as_before():
    scenario = scenario_with(shapes=None)
    run = run_offline(scenario, 8.0, seed=1)
    assert run.t_goal_s is None
    for robot, decisions in run.decisions.items():
        assert [d.kind for d in decisions] == ["blocked"], robot
    assert all(not c for c in run.shapes.values())   # never another shape than the template


# --------------------------------------------------------------------------------- through the gap


def test_a_column_passes_a_gap_narrower_than_the_triangle_and_the_triangle_comes_back_after():
    scenario = scenario_with()
    run = run_offline(scenario, 60.0, seed=1)
    assert run.t_goal_s is not None and run.t_goal_s < 45.0   # 39.0 s measured (2026-12-04)
    changes = list(run.shapes.values())
    assert all(c == changes[0] for c in changes)   # every agent switched at the same frames
    assert [shape for _, shape in changes[0]] == [1, 0]   # to the column, and back to the triangle
    assert all(not [d for d in ds if d.kind != "unblocked"] for ds in run.decisions.values())  # none failed, blocked
    assert obstacle_gap_m(scenario, run) > 0.015   # the safety filter's margin: 45.7 mm measured
    assert assembled_m(scenario, run) < 0.01       # the triangle again at the goal


def test_a_smaller_scale_passes_a_gap_the_full_triangle_cannot_and_grows_back_after():
    # 0.55 m: closed to the full triangle (0.60 m was, until the lattice's walls took the edges' exact bound on
    # 2026-12-05: the triangle now passes it, its bodies crossing the gap one by one)
    scenario = scenario_with(shapes=None, scale_min=0.6, obstacles=[list(o) for o in box_room(1.0, 1.55)])
    full = run_offline(dataclasses.replace(scenario, mission=dataclasses.replace(scenario.mission, scale_min=None)),
                       5.0, seed=1)
    assert [d.kind for d in full.decisions["r1"]] == ["blocked"]
    run = run_offline(scenario, 60.0, seed=1)
    assert run.t_goal_s is not None
    changes = list(run.shapes.values())
    assert all(c == changes[0] for c in changes)
    taken = [shape for _, shape in changes[0]]
    # shrank at once (to scale 0.8: at 0.9 the gap is still closed), then grew back. While the robots grow, the
    # template's start state lies at the edge of the comfort band, and tracker noise flips the choice between
    # the template and scale 0.9 for about 1 s (measured: 10 changes in frames 792-822); docs/planning.md
    assert changes[0][0] == (1, 2) and taken[-1] == 0 and set(taken) <= {0, 1, 2}
    assert all(not [d for d in ds if d.kind != "unblocked"] for ds in run.decisions.values())
    assert obstacle_gap_m(scenario, run) > 0.015
    assert assembled_m(scenario, run) < 0.01


def test_a_large_structure_follows_its_plan_with_a_carrot_a_third_of_its_reach_ahead(monkeypatch):
    import vsfleet.structure as structure_module

    d = scenario_with(shapes=None).mission.to_dict()
    for spec in d["robots"].values():
        spec["p"] = [2.2 * v for v in spec["p"]]   # reach 0.64 m: the carrot 0.19 m ahead, not 0.15 m
    mission = mission_from_dict({**d, "obstacles": [[1.0, 0.4, 0.15]]})
    arrays = mission_arrays(mission)
    reach = float(np.sqrt(np.max((arrays.template ** 2).sum(axis=1))))
    assert 0.3 * reach > arrays.limits.path_lookahead_m
    rng = np.random.default_rng(3)
    differ = 0
    for k in range(12):
        xy = arrays.template + np.array([0.2 * k, 0.1 * k]) + rng.normal(0, 0.005, arrays.template.shape)
        pose = np.column_stack([xy, np.zeros(3)])
        args = (arrays, mission.metric, pose, np.ones(3, bool), np.zeros(3, bool), np.zeros(3, bool), 5.0, 1 / 30)
        core, ref = structure_step(*args), structure_step_reference(*args)
        assert core.goal_pose.as_tuple() == ref.goal_pose.as_tuple(), k   # the core and the reference alike
        with monkeypatch.context() as mp:
            mp.setattr(structure_module, "STEP_LOOKAHEAD_PER_REACH", 0.0)
            short = structure_step_reference(*args)
        differ += short.goal_pose.as_tuple() != ref.goal_pose.as_tuple()
    assert differ > 0   # where the way turns, the longer carrot changes where the structure heads (3 of 12 here)


def test_where_the_barrier_holds_a_large_structures_move_back_it_follows_with_the_missions_own_lookahead(monkeypatch):
    """vs_step.h: where the clearance barrier keeps less than HELD_BACK of the move the advance asked for, the
    advance runs again with the mission's own lookahead (a long carrot cut round the obstacle the plan goes round,
    and the barrier held a line of 10 head on against a wall's disc for 23 s: bench room 162). Poses beside a pillar,
    the core and the reference alike; where the rule acts, the step is the short carrot's, elsewhere the long one's
    (the rule acts at 2 of the 80 poses)."""
    import vsfleet.structure as structure_module

    d = scenario_with(shapes=None).mission.to_dict()
    for spec in d["robots"].values():
        spec["p"] = [2.2 * v for v in spec["p"]]   # reach 0.64 m: the carrot 0.19 m ahead, not 0.15 m
    mission = mission_from_dict({**d, "obstacles": [[1.0, 0.4, 0.15]]})
    arrays = mission_arrays(mission)
    rng = np.random.default_rng(7)
    acted = kept = 0
    for k in range(80):
        th = rng.uniform(-math.pi, math.pi)
        c, s = math.cos(th), math.sin(th)
        centre = np.array([1.0, 0.4]) + rng.uniform(0.45, 0.75) * np.array([math.cos(k), math.sin(k)])
        xy = centre + arrays.template @ np.array([[c, s], [-s, c]]) + rng.normal(0, 0.002, arrays.template.shape)
        pose = np.column_stack([xy, np.full(3, th)])
        args = (arrays, mission.metric, pose, np.ones(3, bool), np.zeros(3, bool), np.zeros(3, bool), 5.0, 1 / 30)
        core, ref = structure_step(*args), structure_step_reference(*args)
        if ref is None:
            continue
        # the core and the reference alike, within the advance's own agreement (advance_structure: 1e-9)
        assert np.allclose(core.goal_pose.as_tuple(), ref.goal_pose.as_tuple(), rtol=0.0, atol=1e-9), k
        with monkeypatch.context() as mp:
            mp.setattr(structure_module, "HELD_BACK", -math.inf)   # the rule off
            long_only = structure_step_reference(*args)
            mp.setattr(structure_module, "STEP_LOOKAHEAD_PER_REACH", 0.0)
            short = structure_step_reference(*args)
        if ref.goal_pose.as_tuple() != long_only.goal_pose.as_tuple():
            acted += 1
            assert ref.goal_pose.as_tuple() == short.goal_pose.as_tuple(), k
        else:
            kept += 1
    assert acted > 0 and kept > 0
