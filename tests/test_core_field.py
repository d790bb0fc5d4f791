"""The room's navigation function (vsfleet.field): the compiled core (vs_field.c) against the readable
reference (numpy + scipy), bit for bit; what its states promise (every body clear of every obstacle by the
margin plus the inflation); the descent reaches the goal, or the closest safe pose when the goal is shut off;
and its inputs are checked."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vsfleet import _core
from vsfleet.coreconst import FIELD_UNRESOLVED as UNRESOLVED
from vsfleet.errors import NonFiniteError, VsfleetValueError
from vsfleet.field import (
    BLOCKED_BIT,
    COST_MASK,
    TIGHT_BIT,
    WALL,
    build_field,
    build_field_reference,
    follow_field,
    follow_field_reference,
)
from vsfleet.geometry import Pose2

COARSE = dict(cell_m=0.08, n_headings=12, max_states=60000)


def random_room(rng):
    n = int(rng.integers(2, 6))
    tpl = rng.uniform(-0.4, 0.4, (n, 2))
    rad = rng.uniform(0.02, 0.1, n)
    m = int(rng.integers(0, 8))
    obs = np.c_[rng.uniform(-1.5, 1.5, (m, 2)), rng.uniform(0.05, 0.3, m)]
    goal = Pose2(*rng.uniform(-1.0, 1.0, 2), float(rng.uniform(-3.0, 3.0)))
    return tpl, rad, obs, goal


def bodies_at(tpl, x, y, th):
    c, s = math.cos(th), math.sin(th)
    return np.c_[x + c * tpl[:, 0] - s * tpl[:, 1], y + s * tpl[:, 0] + c * tpl[:, 1]]


def clearance(tpl, rad, obs, x, y, th) -> float:
    """The smallest gap [m] between a robot body and an obstacle with the structure at (x, y, th)."""
    if len(obs) == 0:
        return math.inf
    b = bodies_at(tpl, x, y, th)
    d = np.hypot(b[:, None, 0] - obs[None, :, 0], b[:, None, 1] - obs[None, :, 1])
    return float((d - rad[:, None] - obs[None, :, 2]).min())


def clearances(tpl, rad, obs, xs, ys, ths) -> np.ndarray:
    """clearance at each pose (xs[i], ys[i], ths[i]) in one pass: the same operations in the same order on each
    element (cos and sin by math's, as bodies_at), so the same bits as calling clearance for each pose."""
    xs, ys = np.asarray(xs, dtype=float), np.asarray(ys, dtype=float)
    if len(obs) == 0:
        return np.full(len(xs), math.inf)
    c = np.array([math.cos(th) for th in ths])[:, None]
    s = np.array([math.sin(th) for th in ths])[:, None]
    bx = xs[:, None] + c * tpl[:, 0] - s * tpl[:, 1]
    by = ys[:, None] + s * tpl[:, 0] + c * tpl[:, 1]
    d = np.hypot(bx[:, :, None] - obs[:, 0], by[:, :, None] - obs[:, 1])
    return (d - rad[:, None] - obs[None, :, 2]).min(axis=(1, 2))


@pytest.mark.parametrize("seed", range(8))
def test_the_core_and_the_reference_build_the_same_field_and_follow_it_the_same_way(seed):
    rng = np.random.default_rng(seed)
    tpl, rad, obs, goal = random_room(rng)
    core = build_field(tpl, rad, 0.02, obs, goal, **COARSE)
    ref = build_field_reference(tpl, rad, 0.02, obs, goal, **COARSE)
    assert core.lattice == ref.lattice
    assert np.array_equal(np.asarray(core.costs), ref.costs)
    for _ in range(25):
        pose = Pose2(*rng.uniform(-2.5, 2.5, 2), float(rng.uniform(-3.0, 3.0)))
        w_core, b_core, l_core = follow_field(core, pose)
        w_ref, b_ref, l_ref = follow_field_reference(ref, pose)
        assert np.array_equal(w_core, w_ref) and b_core == b_ref and l_core == l_ref


def wall_bound_m(tpl, rad, obs, margin_m, lat):
    """(n, m): the clearance [m] body i must keep from obstacle j at a free state (vs_field.h): the larger of a
    move's bound sqrt(need^2 + h^2 / 2) and a turn's sqrt((need + arm dth^2 / 8)^2 + (arm dth)^2 / 4), less the
    radii (need = the radii plus the margin; arm = |p_i|)."""
    need = rad[:, None] + obs[None, :, 2] + margin_m
    arm = np.hypot(tpl[:, 0], tpl[:, 1])[:, None]
    h, dth = lat.cell_m, lat.dth_rad
    move = np.sqrt(need * need + h * h / 2.0)
    turn = np.sqrt((need + arm * dth * dth / 8.0) ** 2 + (arm * dth) ** 2 / 4.0)
    return np.maximum(move, turn) - (rad[:, None] + obs[None, :, 2])


@pytest.mark.parametrize("seed", range(4))
def test_a_free_state_keeps_every_body_its_edges_bound_from_every_obstacle_and_a_wall_does_not(seed):
    rng = np.random.default_rng(100 + seed)
    tpl, rad, obs, goal = random_room(rng)
    obs = np.r_[obs, [[goal.x + 0.7, goal.y, 0.2]]]
    f = build_field(tpl, rad, 0.02, obs, goal, **COARSE)
    lat, costs = f.lattice, np.asarray(f.costs)
    bound = wall_bound_m(tpl, rad, obs, 0.02, lat)          # (n, m)
    assert bound.max() < 0.02 + lat.inflation_m              # never more than the old margin plus inflation
    picks = rng.integers(0, costs.size, 3000)
    k, rem = np.divmod(picks, lat.nx * lat.ny)
    row, col = np.divmod(rem, lat.nx)
    xs = lat.gx + (col + lat.ix_lo) * lat.cell_m
    ys = lat.gy + (row + lat.iy_lo) * lat.cell_m
    walls = frees = 0
    for s, x, y, j in zip(picks, xs, ys, k):
        th = lat.gth + int(j) * lat.dth_rad
        bodies = bodies_at(tpl, x, y, th)
        gap = np.hypot(bodies[:, None, 0] - obs[None, :, 0], bodies[:, None, 1] - obs[None, :, 1]) \
            - (rad[:, None] + obs[None, :, 2])                  # (n, m)
        spare = float((gap - bound).min())
        if costs.flat[s] == WALL:
            walls += 1
            assert spare < 1e-9
        else:
            frees += 1
            assert spare >= -1e-9
    assert walls > 0 and frees > 0


@pytest.mark.parametrize("seed", range(4))
def test_every_pose_on_an_edge_between_two_free_states_keeps_the_margin(seed):
    """Moves and turns out of free states into free states,
    sampled every 1/20 of the edge (a turn as the rotation it is, about the structure's centre), keep every body
    the margin from every obstacle (the inflation of vs_field.h is what the states keep beyond it)."""
    rng = np.random.default_rng(200 + seed)
    tpl, rad, obs, goal = random_room(rng)
    obs = np.r_[obs, [[goal.x + 0.7, goal.y, 0.2]]]
    f = build_field(tpl, rad, 0.02, obs, goal, **COARSE)
    lat, costs = f.lattice, np.asarray(f.costs)
    plane = lat.nx * lat.ny
    moves = [(1, 0, 0), (0, 1, 0), (1, 1, 0), (1, -1, 0), (0, 0, 1)]
    checked = 0
    for s in rng.integers(0, costs.size, 800):
        k, rem = divmod(int(s), plane)
        row, col = divmod(rem, lat.nx)
        if costs.flat[s] == WALL:
            continue
        for dc, dr, dk in moves:
            c2, r2, k2 = col + dc, row + dr, (k + dk) % lat.n_headings
            if not (0 <= c2 < lat.nx and 0 <= r2 < lat.ny) or costs.flat[(k2 * lat.ny + r2) * lat.nx + c2] == WALL:
                continue
            x0, y0 = lat.gx + (col + lat.ix_lo) * lat.cell_m, lat.gy + (row + lat.iy_lo) * lat.cell_m
            th0 = lat.gth + k * lat.dth_rad
            t = np.linspace(0.0, 1.0, 21)
            gaps = clearances(tpl, rad, obs, x0 + t * dc * lat.cell_m, y0 + t * dr * lat.cell_m,
                              th0 + t * dk * lat.dth_rad)
            assert gaps.min() >= 0.02 - 1e-9
            checked += 1
    assert checked > 100


def test_the_descent_from_anywhere_in_the_goals_component_ends_at_the_goal_pose_and_keeps_the_margin():
    rng = np.random.default_rng(7)
    tpl = np.array([[0.2887, 0.0], [-0.1443, 0.25], [-0.1443, -0.25]])
    rad = np.full(3, 0.09)
    obs = np.array([[1.0, 0.75, 0.15], [0.4, 1.2, 0.2], [1.6, 0.3, 0.25]])
    goal = Pose2(2.0, 1.5, 0.4)
    f = build_field(tpl, rad, 0.02, obs, goal, cell_m=0.05, n_headings=24)
    for _ in range(20):
        x, y = rng.uniform(-0.5, 2.5, 2)
        th = float(rng.uniform(-3.0, 3.0))
        if clearance(tpl, rad, obs, x, y, th) < 0.1:
            continue
        way, blocked, left = follow_field(f, Pose2(x, y, th), path_m=50.0, cap=4000)
        assert not blocked and left == 0.0
        assert tuple(way[-1]) == goal.as_tuple()  # the goal pose exactly
        # every pose on the lattice part of the way (from waypoint 1 on), interpolated finely, keeps the margin
        for a, b in zip(way[1:-1], way[2:]):
            for t in np.linspace(0.0, 1.0, 5):
                th_t = a[2] + t * math.remainder(b[2] - a[2], 2 * math.pi)
                assert clearance(tpl, rad, obs, a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), th_t) >= 0.02 - 1e-9


def random_pose_in(lat, rng) -> Pose2:
    """A pose anywhere on the lattice's extent (most such poses lie in components the goal cannot reach)."""
    x0, y0 = lat.gx + lat.ix_lo * lat.cell_m, lat.gy + lat.iy_lo * lat.cell_m
    return Pose2(float(rng.uniform(x0, x0 + lat.nx * lat.cell_m)), float(rng.uniform(y0, y0 + lat.ny * lat.cell_m)),
                 float(rng.uniform(-3.2, 3.2)))


def sealed_room(rng):
    """A random room whose goal sits in a ring of obstacles (a component of its own), with pillars outside."""
    tpl, rad, obs, goal = random_room(rng)
    ring = [(goal.x + math.cos(a) * 1.1, goal.y + math.sin(a) * 1.1, 0.2)
            for a in np.linspace(0.0, 2 * math.pi, 28, endpoint=False)]
    return tpl, rad, np.vstack([obs, ring]), goal


@pytest.mark.parametrize("seed", range(12))
def test_a_deferred_field_descends_bit_for_bit_as_the_whole_build_and_resolves_to_the_same_costs(seed):
    """vs_field_build_deferred leaves the components the goal cannot reach for later; each descent (and each
    open test) resolves the ones it reads. Every answer is the whole build's, bit for bit, on poses all over the
    lattice (in the goal's component, in pockets, outside a sealed ring); what is left unresolved is resolved to
    the whole build's costs."""
    rng = np.random.default_rng(seed)
    tpl, rad, obs, goal = sealed_room(rng) if seed % 2 else random_room(rng)
    whole = build_field(tpl, rad, 0.02, obs, goal, **COARSE)
    deferred = build_field(tpl, rad, 0.02, obs, goal, **COARSE, deferred=True)
    assert deferred.lattice == whole.lattice
    costs = np.asarray(whole.costs)
    left = np.frombuffer(_core.field_costs(deferred.handle), dtype=np.uint32).reshape(costs.shape)
    blocked = (costs != WALL) & ((costs & BLOCKED_BIT) > 0)
    # the goal's component and the walls as the whole build has them; every other free state unresolved, its bits kept
    assert np.array_equal(left[~blocked], costs[~blocked])
    assert ((left[blocked] & COST_MASK) == UNRESOLVED).all()
    flags = np.uint32(BLOCKED_BIT | TIGHT_BIT)
    assert np.array_equal(left[blocked] & flags, costs[blocked] & flags)
    if seed % 2:
        assert blocked.any()
    n_blocked = 0
    for _ in range(60):
        pose = random_pose_in(whole.lattice, rng)
        a, b = follow_field(whole, pose, path_m=5.0, cap=600), follow_field(deferred, pose, path_m=5.0, cap=600)
        assert np.array_equal(a[0], b[0]) and a[1] == b[1] and a[2] == b[2], pose
        n_blocked += bool(a[1])
    if seed % 2:
        assert n_blocked > 0
    _core.field_resolve_all(deferred.handle)
    assert np.array_equal(np.frombuffer(_core.field_costs(deferred.handle), dtype=np.uint32).reshape(costs.shape),
                          costs)


def test_a_deferred_fields_shape_test_answers_as_the_whole_builds():
    """vs_field_open (whether a shape can take its way from the fitted pose: vs_step.c chooses a mission's shape by
    it) answers on a deferred field (the agent's) as on the whole build, open or not, tight or not, from poses in
    sealed rooms inside and out."""
    rng = np.random.default_rng(5)
    n_open = n_shut = 0
    for _ in range(40):
        tpl, rad, obs, goal = sealed_room(rng)
        whole = build_field(tpl, rad, 0.02, obs, goal, **COARSE)
        deferred = build_field(tpl, rad, 0.02, obs, goal, **COARSE, deferred=True)
        for _ in range(10):
            pose = np.array(random_pose_in(whole.lattice, rng).as_tuple())
            answers = (_core.field_open(whole.handle, pose), _core.field_open(deferred.handle, pose))
            assert answers[0] == answers[1], pose
            n_open += answers[0][0]
            n_shut += not answers[0][0]
    assert n_open > 0 and n_shut > 0


def test_a_goal_walled_in_is_blocked_from_outside_and_the_descent_stops_at_the_closest_safe_pose():
    tpl = np.array([[0.2, 0.0], [-0.1, 0.17], [-0.1, -0.17]])
    rad = np.full(3, 0.05)
    ring = np.array([[math.cos(a) * 0.9, math.sin(a) * 0.9, 0.15] for a in np.linspace(0, 2 * math.pi, 24, endpoint=False)])
    goal = Pose2(0.0, 0.0, 0.0)
    f = build_field(tpl, rad, 0.02, ring, goal, cell_m=0.05, n_headings=16)
    way, blocked, left = follow_field(f, Pose2(2.5, 0.3, 1.0), path_m=50.0, cap=4000)
    assert blocked
    end = way[-1]
    assert left == pytest.approx(math.hypot(end[0], end[1]))
    assert 0.9 < left < 1.6             # outside the ring, as close as the bodies allow
    inside, blocked_in, _ = follow_field(f, Pose2(0.05, -0.05, 0.2), path_m=50.0, cap=4000)
    assert not blocked_in and tuple(inside[-1]) == (0.0, 0.0, 0.0)
    costs = np.asarray(f.costs)
    free = costs != WALL
    assert ((costs[free] & BLOCKED_BIT) > 0).any() and ((costs[free] & BLOCKED_BIT) == 0).any()
    assert ((costs[free] & TIGHT_BIT) > 0).any()
    assert (costs[free] & COST_MASK).min() == 0


def test_a_pose_far_outside_the_lattice_heads_for_its_edge_and_a_room_without_obstacles_is_one_free_component():
    tpl = np.array([[0.3, 0.0], [-0.3, 0.0]])
    f = build_field(tpl, np.zeros(2), 0.02, np.zeros((0, 3)), Pose2(0.0, 0.0, 0.0), cell_m=0.05, n_headings=8)
    costs = np.asarray(f.costs)
    assert (costs != WALL).all() and ((costs & BLOCKED_BIT) == 0).all()
    way, blocked, _ = follow_field(f, Pose2(40.0, -3.0, 0.0), path_m=100.0, cap=4000)
    assert not blocked and tuple(way[-1]) == (0.0, 0.0, 0.0)


def test_a_lattice_too_big_for_max_states_grows_its_cells_the_same_way_in_core_and_reference():
    tpl, rad = np.array([[0.2, 0.0], [-0.2, 0.0]]), np.full(2, 0.05)
    obs = np.array([[3.0, 3.0, 0.2], [-3.0, -2.0, 0.3]])
    core = build_field(tpl, rad, 0.02, obs, Pose2(0.0, 0.0, 0.0), cell_m=0.02, n_headings=8, max_states=20000)
    ref = build_field_reference(tpl, rad, 0.02, obs, Pose2(0.0, 0.0, 0.0), cell_m=0.02, n_headings=8,
                                max_states=20000)
    assert core.lattice.cell_m > 0.02 and core.lattice == ref.lattice
    assert core.lattice.nx * core.lattice.ny * 8 <= 20000


@pytest.mark.parametrize("bad, error", [
    (dict(margin_m=math.nan), NonFiniteError),
    (dict(margin_m=-0.01), VsfleetValueError),
    (dict(cell_m=0.0), VsfleetValueError),
    (dict(n_headings=2), VsfleetValueError),
    (dict(obstacles=np.array([[0.0, 0.0, -0.1]])), VsfleetValueError),
    (dict(obstacles=np.array([[0.0, math.inf, 0.1]])), NonFiniteError),
    (dict(radius_m=np.array([0.1, -0.1])), VsfleetValueError),
    (dict(max_states=10), VsfleetValueError),
])
def test_bad_inputs_are_refused_with_a_typed_error(bad, error):
    args = dict(template_xy=np.array([[0.2, 0.0], [-0.2, 0.0]]), radius_m=np.full(2, 0.05), margin_m=0.02,
                obstacles=np.array([[1.0, 0.0, 0.2]]), goal=Pose2(0.0, 0.0, 0.0), cell_m=0.05, n_headings=8,
                max_states=100000)
    args.update(bad)
    with pytest.raises(error):
        build_field(**args)


@pytest.mark.parametrize("far", [1e6, 1e300, -1e300])
def test_a_pose_at_any_finite_distance_is_taken_to_the_lattice_border_in_core_and_reference_alike(far):
    """The fuzz under UBSan found a pose at 1e300 m overflowing the integer conversion of its column; a pose
    outside the lattice now goes straight to its border state (no shortcut: nothing is out there)."""
    tpl, rad = np.array([[0.2, 0.0], [-0.2, 0.0]]), np.full(2, 0.05)
    obs = np.array([[1.0, 0.0, 0.2]])
    core = build_field(tpl, rad, 0.02, obs, Pose2(0.0, 0.0, 0.0), **COARSE)
    ref = build_field_reference(tpl, rad, 0.02, obs, Pose2(0.0, 0.0, 0.0), **COARSE)
    for pose in (Pose2(far, 0.5, 0.0), Pose2(0.3, far, 1.0), Pose2(far, -far, -2.0)):
        w_core, b_core, l_core = follow_field(core, pose)
        w_ref, b_ref, l_ref = follow_field_reference(ref, pose)
        assert np.array_equal(w_core, w_ref) and (b_core, l_core) == (b_ref, l_ref)
        assert not b_core and len(w_core) >= 2
        lat = core.lattice
        border_x = (lat.gx + lat.ix_lo * lat.cell_m, lat.gx + (lat.ix_lo + lat.nx - 1) * lat.cell_m)
        border_y = (lat.gy + lat.iy_lo * lat.cell_m, lat.gy + (lat.iy_lo + lat.ny - 1) * lat.cell_m)
        assert w_core[1][0] in border_x or w_core[1][1] in border_y


def test_the_agent_never_imports_scipy_for_the_field_only_the_reference_does():
    """scipy.sparse costs an agent 0.26 s of start-up and its memory; the core's field needs none of it."""
    import ast
    from pathlib import Path
    tree = ast.parse((Path(__file__).resolve().parent.parent / "vsfleet" / "field.py").read_text())
    top = [n for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))]
    names = [a.name for n in top if isinstance(n, ast.Import) for a in n.names] + \
            [n.module or "" for n in top if isinstance(n, ast.ImportFrom)]
    assert not any(name.split(".")[0] == "scipy" for name in names), names
