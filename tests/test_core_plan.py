"""The structure planner: the compiled core (vsfleet/_core/vs_plan.c) against its reference, and
the planner's promises (docs/planning.md).

plan_structure runs the core; plan_structure_reference is the readable original.  They must give
the same status and the same number of waypoints, and waypoints within 1e-9 (m, rad).
"""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from vsfleet.advance import GoalPath
from vsfleet.errors import NonFiniteError, ShapeError, VsfleetValueError
from vsfleet.geometry import Pose2, angle_diff, wrap_angle
from vsfleet.plan import (
    MAX_OBSTACLES,
    PLAN_BLOCKED,
    PLAN_OK,
    StructurePlan,
    enclosing_radius,
    plan_structure,
    plan_structure_reference,
)

TOL = 1e-9
TRIANGLE = np.array([[0.3, 0.0], [-0.15, 0.26], [-0.15, -0.26]])
RADII = np.array([0.05, 0.05, 0.05])
MARGIN = 0.02


def both(start, goal, tpl, rad, margin, obs) -> StructurePlan:
    core = plan_structure(start, goal, tpl, rad, margin, obs)
    ref = plan_structure_reference(start, goal, tpl, rad, margin, obs)
    assert core.status == ref.status
    a, b = core.as_array(), ref.as_array()
    assert a.shape == b.shape, (a, b)
    assert np.all(np.abs(a[:, :2] - b[:, :2]) <= TOL), np.abs(a - b).max()
    for x, y in zip(a[:, 2], b[:, 2]):
        assert abs(angle_diff(x, y)) <= TOL
    return core


def min_clearance(plan: StructurePlan, tpl, rad, obs, samples_per_m: float = 400.0) -> float:
    """Smallest gap [m] between any robot body and any obstacle, the robots placed at poses
    sampled along every segment (heading interpolated as the advance's carrot does)."""
    obs = np.asarray(obs, dtype=float).reshape(-1, 3)
    if len(obs) == 0:
        return math.inf
    wps = plan.waypoints
    # the poses, as Pose2(x, y, th).apply(tpl) places the robots at each, every pose at once: the same operations
    # on each element (numpy's elementwise ones; the heading wrapped, its cos and sin by math's, one at a time)
    xs, ys, ths = [np.array([wps[0].x])], [np.array([wps[0].y])], [wps[0].th]
    for a, b in zip(wps[:-1], wps[1:]):
        k = max(2, int(math.hypot(b.x - a.x, b.y - a.y) * samples_per_m) + 2)
        u = np.linspace(0.0, 1.0, k)[1:]
        xs.append(a.x + u * (b.x - a.x))
        ys.append(a.y + u * (b.y - a.y))
        ths += [wrap_angle(th) for th in a.th + u * angle_diff(b.th, a.th)]
    x, y = np.concatenate(xs)[:, None], np.concatenate(ys)[:, None]
    c, s = np.array([math.cos(th) for th in ths])[:, None], np.array([math.sin(th) for th in ths])[:, None]
    p = np.asarray(tpl, dtype=float)
    pts = np.stack([c * p[:, 0] - s * p[:, 1] + x, s * p[:, 0] + c * p[:, 1] + y], axis=-1)   # (poses, n, 2)
    d = np.hypot(pts[:, :, None, 0] - obs[None, None, :, 0], pts[:, :, None, 1] - obs[None, None, :, 1])
    return float(np.min(d - obs[None, None, :, 2] - np.asarray(rad)[None, :, None]))


def disc_clear(xy, big_r, obs) -> bool:
    obs = np.asarray(obs, dtype=float).reshape(-1, 3)
    return bool(np.all(np.hypot(obs[:, 0] - xy[0], obs[:, 1] - xy[1]) >= obs[:, 2] + big_r))


coord = st.floats(-3.0, 3.0, allow_nan=False)
templates = st.integers(1, 5).flatmap(lambda n: st.tuples(
    st.lists(st.tuples(st.floats(-0.4, 0.4), st.floats(-0.4, 0.4)), min_size=n, max_size=n),
    st.lists(st.floats(0.0, 0.1), min_size=n, max_size=n)))
obstacle_sets = st.lists(st.tuples(coord, coord, st.floats(0.01, 0.6)), min_size=0, max_size=6)
poses = st.tuples(coord, coord, st.floats(-10.0, 10.0))


@settings(max_examples=300, deadline=None)
@given(templates, st.floats(0.0, 0.05), obstacle_sets, poses, poses)
def test_the_core_plans_as_the_reference_does(tr, margin, obs, start, goal):
    tpl, rad = np.array(tr[0]).reshape(-1, 2), np.array(tr[1])
    both(start, goal, tpl, rad, margin, obs)


@settings(max_examples=150, deadline=None)
@given(templates, st.floats(0.0, 0.05), obstacle_sets, poses, poses)
def test_every_robot_keeps_the_margin_from_every_obstacle_along_the_path(tr, margin, obs, start, goal):
    tpl, rad = np.array(tr[0]).reshape(-1, 2), np.array(tr[1])
    big_r = enclosing_radius(tpl, rad, margin)
    assume(disc_clear(start, big_r, obs))
    plan = both(start, goal, tpl, rad, margin, obs)
    assert min_clearance(plan, tpl, rad, obs) >= margin - 1e-9
    assert plan.waypoints[0].x == start[0] and plan.waypoints[0].y == start[1]
    if plan.status == PLAN_OK:
        last = plan.waypoints[-1]
        assert (last.x, last.y) == (goal[0], goal[1]) and abs(angle_diff(last.th, goal[2])) <= 1e-12
    else:
        last = plan.waypoints[-1]
        # never nearer the goal than a blocked structure could be, never farther than it is now
        assert math.hypot(last.x - goal[0], last.y - goal[1]) <= math.hypot(start[0] - goal[0],
                                                                            start[1] - goal[1]) + 1e-9


def ring(cx, cy, radius, count, r):
    return [[cx + radius * math.cos(2 * math.pi * i / count), cy + radius * math.sin(2 * math.pi * i / count), r]
            for i in range(count)]


def test_without_obstacles_the_path_is_the_straight_line_to_the_goal():
    plan = both((0.0, 0.0, 0.3), (2.0, -1.0, -2.0), TRIANGLE, RADII, MARGIN, [])
    assert plan.status == PLAN_OK and not plan.blocked
    assert np.allclose(plan.as_array(), [[0.0, 0.0, 0.3], [2.0, -1.0, -2.0]], rtol=0.0, atol=1e-12)
    GoalPath(plan.waypoints)   # the advance takes it as is


def test_an_obstacle_off_the_line_leaves_the_straight_path_alone():
    plan = both((0.0, 0.0, 0.0), (3.0, 0.0, 0.0), TRIANGLE, RADII, MARGIN, [[1.5, 2.0, 0.3]])
    assert len(plan.waypoints) == 2


def test_an_obstacle_on_the_straight_path_is_passed_clockwise_with_the_margin_kept():
    obs = [[1.5, 0.0, 0.2]]
    plan = both((0.0, 0.0, 0.0), (3.0, 0.0, 0.5), TRIANGLE, RADII, MARGIN, obs)
    arr = plan.as_array()
    assert plan.status == PLAN_OK and np.all(arr[:, 1] >= 0.0)     # above: clockwise around it
    assert min_clearance(plan, TRIANGLE, RADII, obs) >= MARGIN
    assert np.allclose(arr[-1], [3.0, 0.0, 0.5], rtol=0.0, atol=1e-12)
    # headings turn monotonically from the start's to the goal's
    assert np.all(np.diff(arr[:, 2]) >= 0.0)


def test_a_long_way_out_of_a_horseshoe_returns_all_its_waypoints():
    obs = [o for o in ring(0.0, 0.0, 1.5, 24, 0.25) if o[0] > -1.2]     # open toward -x, goal at +x
    plan = both((0.0, 0.0, 0.0), (5.0, 0.0, 0.0), TRIANGLE, RADII, MARGIN, obs)
    assert plan.status == PLAN_OK and len(plan.waypoints) > 16
    assert min_clearance(plan, TRIANGLE, RADII, obs) >= MARGIN


def test_the_structure_passes_through_a_gap_where_its_disc_fits():
    big_r = enclosing_radius(TRIANGLE, RADII, MARGIN)
    gap = 2.0 * big_r * 1.05 + 0.1    # centres 0.1 + radii apart: fits with room for the slack
    obs = [[1.5, gap / 2, 0.05], [1.5, -gap / 2, 0.05]]
    plan = both((0.0, 0.0, 0.0), (3.0, 0.0, 0.0), TRIANGLE, RADII, MARGIN, obs)
    assert plan.status == PLAN_OK and len(plan.waypoints) == 2


def test_a_goal_walled_in_is_blocked_and_the_structure_stops_at_the_nearest_safe_pose():
    obs = ring(3.0, 0.0, 1.0, 16, 0.2)    # overlapping discs: no gap
    start, goal = (0.0, 0.0, 0.4), (3.0, 0.0, 1.0)
    plan = both(start, goal, TRIANGLE, RADII, MARGIN, obs)
    assert plan.status == PLAN_BLOCKED and plan.blocked
    last = plan.waypoints[-1]
    assert math.hypot(last.x - 3.0, last.y) < 3.0            # it went toward the goal
    assert all(abs(angle_diff(w.th, 0.4)) <= 1e-12 for w in plan.waypoints)   # and does not turn
    assert min_clearance(plan, TRIANGLE, RADII, obs) >= MARGIN
    # replanned from where it stopped: it stays there (no oscillation)
    again = both(last.as_tuple(), goal, TRIANGLE, RADII, MARGIN, obs)
    assert again.status == PLAN_BLOCKED
    end = again.waypoints[-1]
    assert math.hypot(end.x - last.x, end.y - last.y) <= 1e-9


def test_a_start_walled_in_does_not_move_toward_a_worse_pose():
    obs = ring(0.0, 0.0, 1.5, 24, 0.25)
    start, goal = (0.0, 0.0, 0.0), (5.0, 0.0, 0.0)
    plan = both(start, goal, TRIANGLE, RADII, MARGIN, obs)
    assert plan.status == PLAN_BLOCKED
    last = plan.waypoints[-1]
    assert math.hypot(last.x - 5.0, last.y) <= 5.0
    assert min_clearance(plan, TRIANGLE, RADII, obs) >= MARGIN


def test_a_goal_inside_an_obstacle_is_blocked_at_the_obstacles_nearest_point():
    obs = [[3.0, 0.0, 0.3]]
    plan = both((0.0, 0.0, 0.0), (3.0, 0.1, 0.0), TRIANGLE, RADII, MARGIN, obs)
    assert plan.status == PLAN_BLOCKED
    last = plan.waypoints[-1]
    big_r = enclosing_radius(TRIANGLE, RADII, MARGIN)
    assert math.hypot(last.x - 3.0, last.y) == pytest.approx((0.3 + big_r) * 1.01, abs=1e-9)


def test_a_goal_where_the_robots_fit_but_the_disc_does_not_is_blocked():
    # the obstacle sits in the triangle's hole at the goal: no robot touches it, the disc does
    obs = [[3.0, 0.0, 0.02]]
    goal = (3.0, 0.0, 0.0)
    gap = min_clearance(StructurePlan((Pose2(*goal),), PLAN_OK), TRIANGLE, RADII, obs)
    assert gap > MARGIN
    plan = both((0.0, 0.0, 0.0), goal, TRIANGLE, RADII, MARGIN, obs)
    assert plan.status == PLAN_BLOCKED


def test_a_start_inside_an_inflated_obstacle_may_leave_it_but_not_go_deeper():
    big_r = enclosing_radius(TRIANGLE, RADII, MARGIN)
    obs = [[0.0, 0.0, 0.2]]
    start = (0.2 + big_r - 0.01, 0.0, 0.0)     # 1 cm inside the inflated disc
    plan = both(start, (3.0, 0.0, 0.0), TRIANGLE, RADII, MARGIN, obs)
    assert plan.status == PLAN_OK
    xy = plan.as_array()[:, :2]
    assert np.all(np.hypot(xy[:, 0], xy[:, 1]) >= start[0])


@settings(max_examples=100, deadline=None)
@given(st.floats(0.05, 0.8), st.floats(1.0, 4.0), st.floats(1.0, 4.0), st.floats(-3.0, 3.0),
       st.floats(-1e-3, 1e-3), st.floats(-math.pi, math.pi))
def test_starts_a_millimetre_apart_give_nearly_the_same_path(r, before, after, th, dy, heading):
    big_r = enclosing_radius(TRIANGLE, RADII, MARGIN)
    assume(before > r + big_r + 0.05 and after > r + big_r + 0.05)
    c, s = math.cos(heading), math.sin(heading)
    obs = [[before * c, before * s, r]]                       # right on the straight line
    goal = ((before + after) * c, (before + after) * s, th)
    a = both((0.0, 0.0, 0.1), goal, TRIANGLE, RADII, MARGIN, obs)
    b = both((-dy * s, dy * c, 0.1), goal, TRIANGLE, RADII, MARGIN, obs)
    assert a.status == b.status == PLAN_OK
    wa, wb = a.waypoints[1], b.waypoints[1]
    assert math.hypot(wa.x - wb.x, wa.y - wb.y) <= 5e-3


def test_bad_input_is_refused_with_typed_errors():
    good = dict(start=(0.0, 0.0, 0.0), goal=(1.0, 0.0, 0.0), template_xy=TRIANGLE, radius_m=RADII,
                margin_m=MARGIN, obstacles=[[0.5, 2.0, 0.1]])
    cases = [
        (dict(start=(math.nan, 0.0, 0.0)), NonFiniteError),
        (dict(goal=(0.0, math.inf, 0.0)), NonFiniteError),
        (dict(obstacles=[[0.5, 2.0, math.nan]]), NonFiniteError),
        (dict(margin_m=math.inf), NonFiniteError),
        (dict(radius_m=[0.1, math.nan, 0.1]), NonFiniteError),
        (dict(goal=(1e300, 0.0, 0.0)), VsfleetValueError),
        (dict(template_xy=TRIANGLE * 1e300), VsfleetValueError),
        (dict(margin_m=-0.01), VsfleetValueError),
        (dict(radius_m=[0.1, -0.1, 0.1]), VsfleetValueError),
        (dict(obstacles=[[0.5, 2.0, 0.0]]), VsfleetValueError),
        (dict(obstacles=[[0.0, 50.0 + i, 0.1] for i in range(MAX_OBSTACLES + 1)]), VsfleetValueError),
        (dict(template_xy=np.zeros((0, 2)), radius_m=[]), ShapeError),
        (dict(radius_m=[0.1, 0.1]), ShapeError),
        (dict(obstacles=[[0.5, 2.0]]), ShapeError),
        (dict(start=(0.0, 0.0)), ShapeError),
    ]
    for change, err in cases:
        for f in (plan_structure, plan_structure_reference):
            with pytest.raises(err):
                f(**{**good, **change})


def test_the_core_refuses_bad_input_itself():
    from vsfleet import _core
    tpl, rad, s, g = TRIANGLE.copy(), RADII.copy(), np.zeros(3), np.ones(3)
    out = np.empty((4, 3))
    with pytest.raises(NonFiniteError):
        _core.plan_structure(tpl, rad, 0.0, np.array([0.0, 0.0, math.nan]), s, g, out)
    with pytest.raises(VsfleetValueError):
        _core.plan_structure(tpl, rad, -1.0, np.zeros(0), s, g, out)
    with pytest.raises(VsfleetValueError):
        _core.plan_structure(tpl, rad, 0.0, np.zeros(0), s, g, np.empty((0, 3)))
    assert _core.plan_structure(tpl, rad, 0.0, np.zeros(0), s, g, np.empty((1, 3))) == (2, None)


def test_degenerate_inputs_plan():
    # coincident obstacles, concentric ones, a start on the goal, a single point robot of radius 0
    obs = [[1.0, 0.0, 0.2], [1.0, 0.0, 0.2], [1.0, 0.0, 0.4], [2.0, 0.0, 0.1]]
    for start, goal in (((0.0, 0.0, 0.0), (3.0, 0.0, 1.0)), ((-1.0, 0.0, 0.0), (-1.0, 0.0, 2.0)),
                        ((1.0, 0.0, 0.0), (3.0, 0.0, 0.0))):
        both(start, goal, np.zeros((1, 2)), [0.0], 0.0, obs)
        both(start, goal, TRIANGLE, RADII, MARGIN, obs)
    plan = both((-1.0, 0.0, 0.0), (-1.0, 0.0, 2.0), TRIANGLE, RADII, MARGIN, obs)
    assert plan.status == PLAN_OK
    assert np.allclose(plan.as_array(), [[-1.0, 0.0, 0.0], [-1.0, 0.0, 2.0]], rtol=0.0, atol=1e-12)
