"""A room's lattice takes more headings where a large structure's turns inflate it (vsfleet.field.field_headings).

At 48 headings the farthest point of a 5 x 6 grid (0.96 m out) moves 6.3 cm in half a heading step, and the
lattice inflates every body by that much: gaps those bodies clear by less were closed to it. field_headings
predicts, by the core's own sizing, the inflation each of HEADING_CHOICES gives, and takes the first within
HEADING_GAIN_M of the least; a triangle or a square keeps 48.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from vsfleet.advance import GoalPose
from vsfleet.field import (HEADING_CHOICES, HEADING_GAIN_M, HEADINGS, build_field, field_headings,
                           lattice_inflation_m)
from vsfleet.geometry import Pose2
from vsfleet.structure import PLAN_MARGIN_M, room_field

from bench.room import make_room


@pytest.mark.parametrize("seed", [0, 3, 70])   # a triangle, a 5 x 6 grid, a line
@pytest.mark.parametrize("n_headings", HEADING_CHOICES)
def test_the_predicted_inflation_is_the_cores_to_the_bit(seed, n_headings):
    room = make_room(seed)
    field = build_field(room.template, room.radii, PLAN_MARGIN_M, room.obstacles, Pose2(*room.goal),
                        n_headings=n_headings)
    predicted = lattice_inflation_m(room.template, room.radii, PLAN_MARGIN_M, room.obstacles, room.goal, n_headings)
    assert predicted == field.lattice.inflation_m


@pytest.mark.parametrize("seed, shape, headings", [(0, "triangle", 48), (1, "square", 48), (3, "grid 5x6", 96),
                                                   (18, "grid 2x5", 64), (70, "line", 96)])
def test_a_small_structure_keeps_48_headings_and_a_large_one_takes_the_count_that_inflates_least(seed, shape,
                                                                                                    headings):
    room = make_room(seed)
    assert room.shape == shape
    k = field_headings(room.template, room.radii, PLAN_MARGIN_M, room.obstacles, room.goal)
    assert k == headings
    infl = {c: lattice_inflation_m(room.template, room.radii, PLAN_MARGIN_M, room.obstacles, room.goal, c)
            for c in HEADING_CHOICES}
    assert infl[k] <= min(infl.values()) + HEADING_GAIN_M
    assert all(infl[c] > min(infl.values()) + HEADING_GAIN_M for c in HEADING_CHOICES if c < k)


def test_the_agents_room_field_is_built_with_the_rooms_heading_count():
    room = make_room(3)   # a 5 x 6 grid: 96 headings
    field = room_field(room.template, room.radii, room.obstacles, GoalPose(Pose2(*room.goal)))
    assert field.lattice.n_headings == 96 != HEADINGS
    assert math.isclose(field.lattice.dth_rad, 2.0 * math.pi / 96)


def test_a_large_structure_finds_the_gap_that_48_headings_and_the_inflated_walls_closed():
    """Room 63 of bench/room.py: a 5 x 6 grid in a bend. When every state kept the margin plus the lattice's
    inflation (until 2026-12-05), its lattice had no way to the goal at 48 headings (6.3 cm of inflation) and one
    at 96 (4.1 cm). With walls at the exact bound of the edges, the states keep a few mm beyond the margin: both
    have a way, and the mission's lattice (96 headings) takes it."""
    from vsfleet.field import follow_field
    room = make_room(63)
    start, goal = Pose2(*room.start), Pose2(*room.goal)
    at_48 = build_field(room.template, room.radii, PLAN_MARGIN_M, room.obstacles, goal, n_headings=HEADINGS)
    assert not follow_field(at_48, start, path_m=1e9, cap=100_000)[1]      # a way, now
    field = room_field(room.template, room.radii, np.asarray(room.obstacles), GoalPose(goal))
    assert field.lattice.n_headings == 96
    assert not follow_field(field, start, path_m=1e9, cap=100_000)[1]       # a way
