"""A field's finer lattice (vs_field_set_refine, vsfleet.field.field_refinement): where the room's lattice has no way
from a pose, the finer lattice of the same room is asked, and its way is taken when it has one. The core against the
reference, bit for bit; the finer lattice built only when some pose needs it, and the answers the same whenever it is
built; the rule that arms it, a function of the mission alone; and the bench rooms it was made for."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from vsfleet import _core
from vsfleet.advance import GoalPose
from vsfleet.errors import VsfleetValueError
from vsfleet.field import (
    MAX_STATES,
    REFINE_MAX_STATES,
    build_field,
    build_field_reference,
    field_headings,
    field_open_reference,
    field_refinement,
    follow_field,
    follow_field_reference,
    lattice_inflation_m,
)
from vsfleet.geometry import Pose2

sys.path.insert(0, str(Path(__file__).resolve().parent))
import golden_core  # noqa: E402 - tests/: the golden records' rooms

# the coarse lattice grown to fit 1,500 states, the finer one of 60,000 at 16 headings (tests/golden_core.py's
# refine_records: rooms small enough for the reference)
COARSE = dict(cell_m=0.04, n_headings=8, max_states=1500)
FINE = (16, 60000)
MARGIN_M = 0.02


def gap_room(rng):
    """golden_core.gap_room's room, its goal a Pose2."""
    tpl, rad, obs, goal = golden_core.gap_room(rng)
    return tpl, rad, obs, Pose2(*goal)


def far_side(rng) -> Pose2:
    return Pose2(*golden_core.far_side(rng))


def test_the_core_and_the_reference_take_the_finer_lattices_way_where_the_coarse_one_has_none_bit_for_bit():
    rng = np.random.default_rng(3)
    refined = kept = coarse_open = 0
    for _ in range(12):
        tpl, rad, obs, goal = gap_room(rng)
        core = build_field(tpl, rad, MARGIN_M, obs, goal, **COARSE, deferred=True, refine=FINE)
        plain = build_field(tpl, rad, MARGIN_M, obs, goal, **COARSE, deferred=True)
        ref = build_field_reference(tpl, rad, MARGIN_M, obs, goal, **COARSE, refine=FINE)
        fine = build_field(tpl, rad, MARGIN_M, obs, goal, COARSE["cell_m"], *FINE)
        for _ in range(4):
            pose = far_side(rng)
            got, want = follow_field(core, pose), follow_field_reference(ref, pose)
            assert np.array_equal(got[0], want[0]) and got[1:] == want[1:], pose
            assert _core.field_open(core.handle, np.array(pose.as_tuple())) == field_open_reference(ref, pose)
            coarse_way, fine_way = follow_field(plain, pose), follow_field(fine, pose)
            if not coarse_way[1]:   # a way on the room's own lattice: that one, the finer lattice not asked
                expected, coarse_open = coarse_way, coarse_open + 1
            elif not fine_way[1]:   # none there, one on the finer lattice: the finer one's
                expected, refined = fine_way, refined + 1
            else:                   # none on either: the room's own lattice's answer stands
                expected, kept = coarse_way, kept + 1
            assert np.array_equal(got[0], expected[0]) and got[1:] == expected[1:]
    assert refined >= 3 and kept >= 2 and coarse_open >= 10, (refined, kept, coarse_open)


def test_the_finer_lattice_is_built_only_when_a_pose_needs_it_and_early_or_late_the_answers_are_the_same():
    """Built by the first descent with no way on the room's own lattice (lazy), or ahead of any (eager,
    field_refine_now): every answer the same. A field no pose of which needs it never builds it."""
    rng = np.random.default_rng(29)   # golden_core.refine_records' rooms and poses
    needed = unneeded = 0
    for _ in range(16):
        tpl, rad, obs, goal = gap_room(rng)
        lazy = build_field(tpl, rad, MARGIN_M, obs, goal, **COARSE, deferred=True, refine=FINE)
        eager = build_field(tpl, rad, MARGIN_M, obs, goal, **COARSE, deferred=True, refine=FINE)
        plain = build_field(tpl, rad, MARGIN_M, obs, goal, **COARSE, deferred=True)
        assert eager.refined is False and eager.refine_now() is True and eager.refined is True
        at_goal = build_field(tpl, rad, MARGIN_M, obs, goal, **COARSE, deferred=True, refine=FINE)
        follow_field(at_goal, goal)   # built only if the room's own lattice has no way even there
        assert at_goal.refined is follow_field(plain, goal)[1]
        unneeded += not at_goal.refined
        for _ in range(2):
            pose = far_side(rng)
            rng.choice([0.5, 2.0, 50.0])   # the record's path length
            before = lazy.refined
            a, b = follow_field(lazy, pose), follow_field(eager, pose)
            assert np.array_equal(a[0], b[0]) and a[1:] == b[1:]
            if not before:
                needs = follow_field(plain, pose)[1]
                assert lazy.refined is needs
                needed += needs
    assert needed >= 4 and unneeded >= 8, (needed, unneeded)
    assert build_field(tpl, rad, MARGIN_M, obs, goal, **COARSE, deferred=True).refine_now() is False


def test_a_refinement_is_refused_twice_or_with_bad_sizes_with_a_typed_error():
    rng = np.random.default_rng(2)
    tpl, rad, obs, goal = gap_room(rng)
    f = build_field(tpl, rad, MARGIN_M, obs, goal, **COARSE, deferred=True, refine=FINE)
    args = (np.ascontiguousarray(tpl, dtype=float).ravel(), np.ascontiguousarray(rad, dtype=float),
            np.ascontiguousarray(obs, dtype=float).ravel(), 0.04)
    with pytest.raises(VsfleetValueError):
        _core.field_set_refine(f.handle, *args, *FINE)   # armed already
    g = build_field(tpl, rad, MARGIN_M, obs, goal, **COARSE, deferred=True)
    for heads, states in ((3, 60000), (2000, 60000), (16, 100), (16, 2_000_000_000)):
        with pytest.raises(VsfleetValueError):
            _core.field_set_refine(g.handle, *args, heads, states)
    with pytest.raises(ValueError):
        _core.field_set_refine(g.handle, args[0], args[1][:1], args[2], 0.04, *FINE)   # radii of another template
    # what vs_field_build refuses is refused now, not by every descent that would ask the finer lattice
    far, flat, negative = args[0].copy(), args[2].copy(), args[1].copy()
    far[0], flat[2], negative[0] = 2e6, 0.0, -0.01
    for bad in ((far, args[1], args[2]), (args[0], args[1], flat), (args[0], negative, args[2])):
        with pytest.raises(VsfleetValueError):
            _core.field_set_refine(g.handle, *bad, 0.04, *FINE)
    assert follow_field(g, goal)[1] is False and g.refine is None


def test_the_rule_arms_a_finer_lattice_only_where_it_inflates_at_least_5_mm_less():
    """field_refinement: a function of the mission. The paper triangle in a room of 3 m keeps its 3 cm cells: no
    finer lattice. The same triangle with a pillar 5 m away: the room's lattice grows its cells to fit 2 million
    states, and 6 million give it its 3 cm back (5 mm or more less inflation): armed at 48 headings. A line of 10
    robots 0.3 m apart turns its ends 1.35 m from its centre: its finer lattice has more headings, and inflates at
    least 5 mm less."""
    side = 0.5
    r = side / np.sqrt(3)
    tri = np.array([[r, 0.0], [-r / 2, side / 2], [-r / 2, -side / 2]])
    rad = np.full(3, 0.09)
    small = np.array([[1.0, 0.75, 0.15], [-1.0, 0.5, 0.2]])
    goal = (2.0, 1.5)
    assert field_refinement(tri, rad, MARGIN_M, small, goal, field_headings(tri, rad, MARGIN_M, small, goal)) is None
    large = np.vstack([small, [[7.0, 6.0, 0.2], [-3.0, -3.5, 0.2]]])
    heads = field_headings(tri, rad, MARGIN_M, large, goal)
    assert heads == 48
    assert field_refinement(tri, rad, MARGIN_M, large, goal, heads) == (48, REFINE_MAX_STATES)
    line = np.c_[np.linspace(-1.35, 1.35, 10), np.zeros(10)]
    rad10 = np.full(10, 0.09)
    heads = field_headings(line, rad10, MARGIN_M, large, goal)
    fine_heads, fine_states = field_refinement(line, rad10, MARGIN_M, large, goal, heads)
    assert fine_heads > heads and fine_states == REFINE_MAX_STATES
    assert lattice_inflation_m(line, rad10, MARGIN_M, large, goal, fine_heads, max_states=fine_states) <= \
        lattice_inflation_m(line, rad10, MARGIN_M, large, goal, heads) - 0.005
    assert REFINE_MAX_STATES > MAX_STATES


@pytest.mark.parametrize("seed", [70, 130])
def test_the_bench_rooms_a_line_of_10_could_not_leave_now_have_a_way_from_its_start(seed):
    """bench/room.py rooms 70 and 130: a line of 10 robots, a way OMPL finds (4.41 and 6.06 m). The room's lattice
    (cells of 7.3 cm, to fit 2 million states) has none from the start; the finer one (128 headings, 6 million
    states, cells of 4.7 cm) has, and the agents' field takes it."""
    from bench.room import make_room   # noqa: PLC0415 - the bench's rooms
    from vsfleet.structure import PLAN_MARGIN_M, room_field   # noqa: PLC0415
    room = make_room(seed)
    start, goal = Pose2(*room.start), Pose2(*room.goal)
    heads = field_headings(room.template, room.radii, PLAN_MARGIN_M, room.obstacles, room.goal)
    coarse = build_field(room.template, room.radii, PLAN_MARGIN_M, room.obstacles, goal, n_headings=heads,
                         deferred=True)
    assert follow_field(coarse, start)[1] is True
    fld = room_field(room.template, room.radii, room.obstacles, GoalPose(goal), build_field)
    assert fld.refine == (128, REFINE_MAX_STATES)
    way, blocked, left = follow_field(fld, start, path_m=1e9, cap=100000)
    assert blocked is False and left == 0.0
    assert tuple(way[-1]) == goal.as_tuple()
