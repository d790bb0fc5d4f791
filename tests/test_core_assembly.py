"""The assembly tie-break in the compiled core (vsfleet/_core/vs_assembly.c) against its numpy reference, bit for bit.

Random crowds (2-40 robots packed 1-5 cm apart, some unseen, random points), head-on pairs, collinear rows and
crowds on a dyadic grid whose blockers tie exactly in ``along``: the core's three outputs equal the reference's
(np.array_equal). Then the documented rule on a hand-built head-on pair, ties, the refusals, and the agent step:
it calls ``config.impl.assembly_targets``, and with the core's tie-break its outputs are the reference's bits.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from vsfleet import _core
from vsfleet.assembly import assembly_targets, assembly_targets_reference, priority_draw, rank
from vsfleet.coreconst import ASSEMBLING_M, DETOUR_CLEAR_M, ESCAPE_M, PRESSED_M, PRIORITY_S
from vsfleet.errors import NonFiniteError, ShapeError, VsfleetValueError
from vsfleet.frames import Frame
from vsfleet.impl import core as core_impl, reference as reference_impl
from vsfleet.step import AgentState, StepConfig, agent_step
from vsfleet.wire import Mission, RobotSpec

MARGIN = 0.015
KINDS = ("block", "row", "dyadic", "head_on", "scatter")
#: the mission's age [s]: the rows' own order (draw 0, negative ages too), draws 1 (at its first instant), 2 and 6,
#: and the saturated draw 2^32 - 1
ELAPSED = (0.0, -3.0, 9.5, PRIORITY_S, 27.3, 61.0, 5e10)


def crowd(rng: np.random.Generator, kind: str):
    """(radii, pose (n, 3), seen, points_now, points_next, margin, elapsed_s) of one random crowd of the given kind."""
    n = int(rng.integers(2, 41))
    radius = 0.05 if rng.random() < 0.6 else float(rng.uniform(0.0, 0.08))
    radii = np.full(n, radius) if rng.random() < 0.7 else rng.uniform(0.0, 0.08, n)
    gap = rng.uniform(0.01, 0.05)
    if kind == "block":                      # an n/5 x 5 block, bodies 1-5 cm apart, a little jitter
        pitch = 2.0 * radius + gap
        xy = np.array([(pitch * (k % 5), pitch * (k // 5)) for k in range(n)]) + rng.normal(0.0, 0.002, (n, 2))
    elif kind == "row":                      # collinear: one row along a random direction (or exactly along x)
        th = 0.0 if rng.random() < 0.5 else rng.uniform(-math.pi, math.pi)
        s = (2.0 * radius + gap) * np.arange(n)
        xy = np.c_[s * math.cos(th), s * math.sin(th)]
    elif kind == "dyadic":                   # a grid of 1/32 m, points along the axes: exact ties in along
        cells = rng.choice(64, size=n, replace=False)
        xy = np.c_[cells % 8, cells // 8] / 32.0
    elif kind == "head_on":                  # pairs face to face, each one's point behind the other
        xy = np.array([((k % 2) * (2.0 * radius + gap), 0.4 * (k // 2)) for k in range(n)])
    else:
        xy = rng.uniform(-0.3, 0.3, (n, 2)) * math.sqrt(n)
    pose = np.c_[xy, rng.uniform(-math.pi, math.pi, n)]
    if kind == "head_on":
        points = xy + np.c_[np.where(np.arange(n) % 2 == 0, 0.5, -0.5), rng.normal(0.0, 0.01, n) * (n % 3 == 0)]
    elif kind == "dyadic":
        axis = rng.integers(0, 4, n)
        step = np.array([(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)])[axis] * rng.integers(1, 9, (n, 1)) / 8.0
        points = xy + step
    else:
        points = rng.uniform(-0.6, 0.6, (n, 2)) * math.sqrt(n / 5.0)
    near = rng.random(n) < 0.15              # some robots at or near their points: not on their way
    points[near] = xy[near] + rng.uniform(-0.03, 0.03, (int(near.sum()), 2))
    seen = rng.random(n) < (1.0 if rng.random() < 0.3 else 0.85)
    nxt = points + (0.0 if rng.random() < 0.3 else rng.normal(0.0, 0.005, (n, 2)))
    margin = MARGIN if rng.random() < 0.6 else float(rng.choice([0.0, rng.uniform(0.0, 0.03)]))
    elapsed = float(rng.choice(ELAPSED))
    return radii, pose, seen, points, nxt, margin, elapsed


def test_the_core_reproduces_the_reference_bit_for_bit_on_random_crowds(monkeypatch):
    """800 random crowds (draws 0, 1, 2, 6 and the saturated one among them); the reference counts, as it runs, the
    escapes that took a way of the fan and the robots the third pass sent off (crossing targets), and the placed
    robots sent aside are counted from the outputs: every rule ran."""
    import vsfleet.assembly as assembly
    fan = crossing = 0
    way_out, first_on_target = assembly._way_out, assembly._first_on_target

    def counted_way_out(radii, xy, seen, margin, i, centroid, u, normal):
        nonlocal fan
        way = way_out(radii, xy, seen, margin, i, centroid, u, normal)
        back = [float(xy[i, 0]) - float(u[0]) * ESCAPE_M, float(xy[i, 1]) - float(u[1]) * ESCAPE_M]
        ox, oy = float(xy[i, 0]) - centroid[0], float(xy[i, 1]) - centroid[1]
        out = math.sqrt(ox * ox + oy * oy)
        outward = [float(xy[i, 0]) + (ox / out) * ESCAPE_M, float(xy[i, 1]) + (oy / out) * ESCAPE_M] if out else None
        fan += way.tolist() not in (back, outward, xy[i].tolist())
        return way

    def counted_first_on_target(radii, xy, seen, margin, targets, i, only=-1):
        nonlocal crossing
        k = first_on_target(radii, xy, seen, margin, targets, i, only)
        crossing += only >= 0 and k == only
        return k

    monkeypatch.setattr(assembly, "_way_out", counted_way_out)
    monkeypatch.setattr(assembly, "_first_on_target", counted_first_on_target)
    rng = np.random.default_rng(29)
    detoured = cases = aside = 0
    for k in range(800):
        args = crowd(rng, KINDS[k % len(KINDS)])
        got, want = assembly_targets(*args), assembly.assembly_targets_reference(*args)
        for g, w, name in zip(got, want, ("points_now", "points_next", "detoured")):
            assert np.array_equal(g, w), (k, KINDS[k % len(KINDS)], name)
            assert g.dtype == w.dtype and g.shape == w.shape
        detoured += int(want[2].sum())
        cases += bool(want[2].any())
        _, pose, seen, points = args[:4]
        placed = seen & (np.hypot(points[:, 0] - pose[:, 0], points[:, 1] - pose[:, 1]) <= ASSEMBLING_M)
        aside += int((want[2] & placed).sum())     # sent round while on its point: stepped aside
    assert cases > 300 and detoured > 1500, (cases, detoured)   # the tie-break did work in most crowds
    assert fan > 100 and crossing > 2 and aside > 50, (fan, crossing, aside)   # 589, 6 and 300 as written (seed 29)


def test_unseen_rows_are_not_read_and_their_points_pass_through_as_they_are():
    rng = np.random.default_rng(7)
    for k in range(100):
        radii, pose, seen, now, nxt, margin, elapsed = crowd(rng, KINDS[k % len(KINDS)])
        seen[0] = False
        pose[~seen, :2] = np.nan                      # as frame_arrays leaves them
        radii[~seen] = -1.0
        now[~seen] = np.inf
        got, want = assembly_targets(radii, pose, seen, now, nxt, margin, elapsed), \
            assembly_targets_reference(radii, pose, seen, now, nxt, margin, elapsed)
        for g, w in zip(got, want):
            assert np.array_equal(g, w, equal_nan=True), k
        assert not got[2][~seen].any() and np.array_equal(got[0][~seen], now[~seen])


def _head_on():
    radii = np.array([0.05, 0.05])
    pose = np.array([[0.0, 0.0, 0.0], [0.12, 0.0, math.pi]])    # face to face, 2 cm apart
    points = np.array([[0.5, 0.0], [-0.4, 0.0]])                 # each one's point behind the other
    return radii, pose, np.ones(2, bool), points, points + 0.01, MARGIN, 0.0


@pytest.mark.parametrize("fn", [assembly_targets, assembly_targets_reference], ids=["core", "reference"])
def test_of_a_head_on_pair_the_higher_row_passes_the_other_on_its_right_at_the_documented_waypoint(fn):
    """Docstring's rule: the later row gives way; its waypoint lies c = (r_i + r_j + margin) + DETOUR_CLEAR_M to
    its right of the line to the other and c short of it; the other keeps both its points."""
    radii, pose, seen, points, nxt, margin, elapsed = _head_on()
    now, next_, detoured = fn(radii, pose, seen, points, nxt, margin, elapsed)
    assert detoured.tolist() == [False, True]
    assert now[0].tolist() == points[0].tolist() and next_[0].tolist() == nxt[0].tolist()
    assert now[1].tolist() == next_[1].tolist()
    c = 0.05 + 0.05 + margin + DETOUR_CLEAR_M
    u = (pose[0, :2] - pose[1, :2]) / 0.12                      # from r2 towards r1: -x
    w = now[1] - pose[1, :2]
    assert w @ u == pytest.approx(0.12 - c, abs=1e-15)          # c short of r1 along the line
    assert u[0] * w[1] - u[1] * w[0] == pytest.approx(-c, abs=1e-15)   # c to the right of it (r2 heads -x: +y)
    # the rows decide, not the poses: swapped, the other robot gives way, to its own right
    now_s, _, detoured_s = fn(radii, pose[::-1].copy(), seen, points[::-1].copy(), nxt[::-1].copy(), margin, elapsed)
    assert detoured_s.tolist() == [False, True] and now_s[1, 1] < -0.1


@pytest.mark.parametrize("fn", [assembly_targets, assembly_targets_reference], ids=["core", "reference"])
def test_a_robot_barred_head_on_by_a_lower_and_a_higher_row_keeps_no_way(fn):
    """Robot 1's first blocker is robot 2 (head on, a higher row): alone with it, robot 1 would keep its way.
    Robot 0, a lower row, bars it head on too, farther along, so robot 1 passes robot 2 on its right."""
    radii = np.full(3, 0.05)
    pose = np.array([[0.5, 0.05, math.pi], [0.0, 0.0, 0.0], [0.25, 0.0, math.pi]])
    points = np.array([[-1.0, 0.05], [1.0, 0.0], [-1.0, 0.0]])
    seen = np.ones(3, bool)
    assert not fn(radii[1:], pose[1:], seen[1:], points[1:], points[1:], MARGIN, 0.0)[2][0]   # without robot 0: keeps
    now, nxt, detoured = fn(radii, pose, seen, points, points, MARGIN, 0.0)
    assert detoured[1]
    c = (0.05 + 0.05 + MARGIN) + DETOUR_CLEAR_M          # not pressed (0.25 - width > PRESSED_M): the plain detour
    assert now[1].tolist() == nxt[1].tolist() == pytest.approx([0.25 - c, -c], abs=1e-15)


def test_of_two_robots_that_bar_each_other_never_both_keep_their_way():
    """On random crowds: every pair that bars each other head on (the rule's definition, written out here)
    has at least one robot sent round."""
    rng = np.random.default_rng(28)
    pairs = 0
    for k in range(400):
        radii, pose, seen, points, nxt, margin, elapsed = crowd(rng, KINDS[k % len(KINDS)])
        detoured = assembly_targets(radii, pose, seen, points, nxt, margin, elapsed)[2]
        to = points - pose[:, :2]
        dist = np.sqrt(to[:, 0] * to[:, 0] + to[:, 1] * to[:, 1])
        n = len(radii)
        for i in range(n):
            for j in range(i + 1, n):
                if not (seen[i] and seen[j] and dist[i] > ASSEMBLING_M and dist[j] > ASSEMBLING_M):
                    continue
                if all(_ahead(radii, pose, margin, a, b, to[a] / dist[a], dist[a]) for a, b in ((i, j), (j, i))):
                    pairs += 1
                    assert detoured[i] or detoured[j], (k, i, j)
    assert pairs > 200, pairs


def _ahead(radii, pose, margin, a, b, d, dist):
    """Does robot b lie ahead on robot a's straight way (unit d, length dist), within the two bodies + margin?"""
    rel = pose[b, :2] - pose[a, :2]
    width = radii[a] + radii[b] + margin
    along, lateral = rel[0] * d[0] + rel[1] * d[1], d[0] * rel[1] - d[1] * rel[0]
    return 0.0 < along < dist + width and abs(lateral) < width


def test_of_blockers_tied_in_along_the_lower_row_is_the_one_gone_round():
    """numpy's argmin takes the first minimum: two robots mirrored about the way tie exactly."""
    radii = np.full(3, 0.05)   # the blockers 0.25 m ahead: robot 0 is not pressed against them (not boxed in)
    pose = np.array([[0.0, 0.0, 0.0], [0.25, 0.03125, 0.0], [0.25, -0.03125, 0.0]])
    points = np.array([[1.0, 0.0], [0.25, 0.03125], [0.25, -0.03125]])   # r2, r3 on their points
    for order in ([0, 1, 2], [0, 2, 1]):
        args = (radii, pose[order], np.ones(3, bool), points[order], points[order], MARGIN, 0.0)
        now, _, detoured = assembly_targets(*args)
        want = assembly_targets_reference(*args)
        assert all(np.array_equal(g, w) for g, w in zip((now, _, detoured), want))
        assert detoured.tolist() == [True, False, False]
        # round row 1 on the side robot 0 is on (row 1 to its left: pass it on its right, y < 0; else y > 0)
        assert (now[0, 1] < 0.0) == (pose[order][1, 1] > 0.0)


def _boxed_in(extra=()):
    """Robot 0 (point 1 m ahead) pressed against robot 1 (5 mm beyond touching + margin), which stands dead ahead
    on its point; robot 2 stands where robot 0's detour round robot 1 (to the right: -y) would go; extra robots
    stand on their points."""
    xy = [(0.0, 0.0), (0.12, 0.0), (0.0, -0.13), *extra]
    n = len(xy)
    pose = np.array([(x, y, 0.0) for x, y in xy])
    points = np.array([(1.0, 0.0), *xy[1:]])
    return np.full(n, 0.05), pose, np.ones(n, bool), points


def _both(radii, pose, seen, points):
    got = assembly_targets(radii, pose, seen, points, points, MARGIN, 0.0)
    want = assembly_targets_reference(radii, pose, seen, points, points, MARGIN, 0.0)
    assert all(np.array_equal(g, w) for g, w in zip(got, want))
    return got


def _aside(pose, k, i):
    """Where placed robot k steps aside to from boxed-in robot i: ESCAPE_M straight away from i (the rule's bits)."""
    rx, ry = float(pose[k, 0]) - float(pose[i, 0]), float(pose[k, 1]) - float(pose[i, 1])
    g = math.sqrt(rx * rx + ry * ry)
    return [float(pose[k, 0]) + rx / g * ESCAPE_M, float(pose[k, 1]) + ry / g * ESCAPE_M]


def test_a_boxed_in_robot_backs_away_from_its_blocker_and_the_placed_robot_on_its_way_round_steps_aside():
    radii, pose, seen, points = _boxed_in()
    detour = (-0.025, -0.145)   # c = 0.145 to the right of the line to robot 1, and c short of it
    assert assembly_targets(radii[:2], pose[:2], seen[:2], points[:2], points[:2], MARGIN, 0.0)[0][0] == \
        pytest.approx(detour, abs=1e-12)    # without robot 2: the plain detour
    now, nxt, detoured = _both(radii, pose, seen, points)
    assert detoured.tolist() == [True, False, True]
    assert now[0].tolist() == nxt[0].tolist() == [0.0 - 1.0 * ESCAPE_M, 0.0 - 0.0 * ESCAPE_M]
    # robot 2, on its point, bars robot 0's way to that detour: it steps aside, straight away from robot 0 (-y)
    assert now[2].tolist() == nxt[2].tolist() == _aside(pose, 2, 0) == pytest.approx([0.0, -0.13 - ESCAPE_M])
    pressed = (0.05 + 0.05 + MARGIN) + PRESSED_M + 1e-3   # robot 1 farther: not pressed, the plain detour
    radii, pose, seen, points = _boxed_in()
    pose[1, 0] = points[1, 0] = pressed
    now, _, detoured = _both(radii, pose, seen, points)
    assert now[0][1] < -0.1 and detoured.tolist() == [True, False, False]   # not boxed in: nobody steps aside


def test_a_placed_robot_steps_aside_only_from_a_boxed_in_robot_and_only_on_a_free_way():
    """Robot 2 steps aside from robot 0 (above) only while it is on its point, and only on a free way: straight away
    from robot 0, else 45 degrees off that to its left, then its right, then 90 degrees the same; robot 1, the blocker
    robot 0 would go round, never does (it does not bar that way)."""
    radii, pose, seen, points = _boxed_in()
    points[2] = (0.0, -0.13 - 0.06)     # robot 2 6 cm from its point: on its way, not placed (and not barred)
    now, _, detoured = _both(radii, pose, seen, points)
    assert detoured.tolist() == [True, False, False] and now[2].tolist() == points[2].tolist()
    radii, pose, seen, points = _boxed_in([(0.0, -0.3)])   # a robot on its point bars robot 2's way straight aside
    now, _, detoured = _both(radii, pose, seen, points)
    h = math.sqrt(0.5)      # so robot 2 takes the fan's next way: 45 degrees off it to the left (away: -y; left: +x)
    assert detoured.tolist() == [True, False, True, False]
    assert now[2].tolist() == [0.0 + h * (0.0 - -1.0) * ESCAPE_M, -0.13 + h * (-1.0 + 0.0) * ESCAPE_M]
    radii, pose, seen, points = _boxed_in([(0.03, -0.14)])   # robot 3, on its point, bars that way too
    seen[2] = False                     # unseen: not in the tie-break at all (its point passes through)
    now, _, detoured = _both(radii, pose, seen, points)
    assert detoured.tolist() == [True, False, False, True] and now[2].tolist() == points[2].tolist()
    assert now[3].tolist() == _aside(pose, 3, 0)    # robot 0 still boxed in (by robot 3): robot 3 steps aside


def test_a_boxed_in_robot_whose_way_back_is_barred_heads_out_of_the_crowd_away_from_the_centroid():
    extra = [(-0.2, 0.0)] + [(0.45, -1.5)] * 4   # one robot behind; four far down on the right pull the centroid
    radii, pose, seen, points = _boxed_in(extra)
    now, nxt, detoured = _both(radii, pose, seen, points)
    assert detoured.tolist() == [True, False, True] + [False] * 5    # robot 2 steps aside, as above
    cx = cy = 0.0
    for x, y, _ in pose:          # in row order, as the rule sums
        cx, cy = cx + x, cy + y
    cx, cy = cx / 8.0, cy / 8.0
    ox, oy = 0.0 - cx, 0.0 - cy
    out = math.sqrt(ox * ox + oy * oy)
    assert ox < 0.0 and oy > 0.0   # up and to the left, clear of robots 1 and 3
    assert now[0].tolist() == nxt[0].tolist() == [0.0 + (ox / out) * ESCAPE_M, 0.0 + (oy / out) * ESCAPE_M]


def test_a_boxed_in_robot_with_every_way_barred_waits_where_it_stands():
    radii, pose, seen, points = _boxed_in([(-0.12, 0.0), (0.0, 0.13), (-0.09, 0.09), (-0.09, -0.09)])
    now, nxt, detoured = _both(radii, pose, seen, points)
    assert detoured[0] and now[0].tolist() == nxt[0].tolist() == [0.0, 0.0]


def test_a_robot_that_keeps_its_way_into_a_robot_that_waits_gives_way_in_turn():
    """The waiting robot above, now on its way head on with robot 0 (a lower row, which keeps its way into it):
    robot 1 is boxed in with every way barred and waits; so robot 0 goes round it on its right (+y, heading -x).
    It is pressed against robot 1, but no third robot bars its way to the waypoint: the plain detour, c = 0.145 m
    aside and c short of robot 1."""
    xy = [(0.12, 0.0), (0.0, 0.0), (0.0, -0.13), (-0.12, 0.0), (0.0, 0.13), (-0.09, 0.09), (-0.09, -0.09)]
    pose = np.array([(x, y, 0.0) for x, y in xy])
    points = np.array([(-1.0, 0.0), (1.0, 0.0), *xy[2:]])
    radii, seen = np.full(7, 0.05), np.ones(7, bool)
    now, nxt, detoured = _both(radii, pose, seen, points)
    assert detoured[1] and now[1].tolist() == [0.0, 0.0]                    # robot 1 waits
    c = (0.05 + 0.05 + MARGIN) + DETOUR_CLEAR_M
    assert detoured[0] and now[0].tolist() == nxt[0].tolist() == pytest.approx([0.12 - (0.12 - c), c], abs=1e-15)
    # without the four robots behind robot 1, it backs away (boxed in, not waiting): robot 0 keeps its way
    now, _, detoured = _both(radii[:3], pose[:3], seen[:3], points[:3])
    assert detoured.tolist() == [False, True, True] and now[1].tolist() == [-ESCAPE_M, 0.0]
    assert now[2].tolist() == _aside(pose, 2, 1)    # robot 2, on robot 1's way round robot 0, steps aside


def test_a_boxed_in_robot_whose_ways_back_and_out_are_barred_heads_off_back_by_45_then_90_degrees():
    """Robot 0 boxed in against robot 1 (robot 2 bars its detour on the right, -y): its ways straight back and out of
    the crowd are barred too. It takes the first free way of the fan: 45 degrees off back towards its passing side
    (-y, barred by robot 2), then towards the other (+y); with that one barred too, 90 degrees off back towards its
    passing side (barred), then the other."""
    h = math.sqrt(0.5)
    radii, pose, seen, points = _boxed_in([(-0.2, 0.02), (0.22, 0.2)])
    now, nxt, detoured = _both(radii, pose, seen, points)
    assert detoured.tolist() == [True, False, True, False, False]   # robot 2 steps aside (-y, free)
    assert now[0].tolist() == nxt[0].tolist() == [h * (-0.0 - 1.0) * ESCAPE_M, h * (1.0 - 0.0) * ESCAPE_M]
    radii, pose, seen, points = _boxed_in([(-0.12, 0.0), (0.27, 0.2)])
    now, _, detoured = _both(radii, pose, seen, points)
    assert detoured[0] and now[0].tolist() == [0.0, ESCAPE_M]


def test_two_robots_pressed_together_whose_targets_cross_the_later_escapes():
    """Robot 1 goes round robot 3 (its first blocker, on its point) and robot 0 heads for its point past robot 2:
    neither bars the other's way to its *point*, but they stand pressed together and each bars the other's way
    to its target. Robot 1, the later row, escapes from robot 0: ESCAPE_M straight back from it (free). In the
    draw where robot 1 comes first (the mission's 10th second: rank 1133855410 against 1179680230), robot 0
    is the one that would escape, but the first robot on its way is robot 2: robot 1 keeps its detour."""
    xy = np.array([[0.14, 0.11], [0.04, 0.05], [0.16, -0.03], [-0.1, 0.11]])
    points = np.array([[-0.2, -0.3], [-0.3, 0.7], [0.2, 0.9], [-0.1, 0.11]])
    radii, pose, seen = np.full(4, 0.05), np.c_[xy, np.zeros(4)], np.ones(4, bool)
    rel = xy[0] - xy[1]
    u = rel / math.sqrt(rel[0] * rel[0] + rel[1] * rel[1])
    assert math.hypot(*rel) - (0.1 + MARGIN) < PRESSED_M                    # pressed together
    for elapsed, want in ((0.0, [xy[1, 0] - u[0] * ESCAPE_M, xy[1, 1] - u[1] * ESCAPE_M]), (PRIORITY_S, None)):
        args = (radii, pose, seen, points, points, MARGIN, elapsed)
        got, ref = assembly_targets(*args), assembly_targets_reference(*args)
        assert all(np.array_equal(g, w) for g, w in zip(got, ref))
        now, _, detoured = got
        assert detoured.tolist() == [False, True, True, False] and now[0].tolist() == points[0].tolist()
        if want is not None:
            assert now[1].tolist() == want
        else:    # robot 1's plain detour round robot 3: c aside of the line to it (its own side) and c short
            assert rank(1, 1) < rank(0, 1) and priority_draw(PRIORITY_S) == 1
            to, d = xy[3] - xy[1], points[1] - xy[1]
            gap, c = math.hypot(*to), (0.1 + MARGIN) + DETOUR_CLEAR_M
            left = 1.0 if d[0] * to[1] - d[1] * to[0] < 0.0 else -1.0
            w = to / gap
            assert now[1] == pytest.approx(xy[1] + np.array([-w[1], w[0]]) * left * c + w * (gap - c), abs=1e-15)


def test_the_priorities_are_the_rows_order_in_the_first_period_then_drawn_afresh_each_period():
    """priority_draw: 0 before PRIORITY_S (negative ages too), then whole periods, saturated at 2^32 - 1; rank: the
    row in draw 0, else the documented 32-bit mix. Of a head-on pair, the robot of the lower rank keeps its way, in
    the core and the reference alike; over 64 draws each robot keeps it in some of them."""
    assert [priority_draw(t) for t in (-5.0, 0.0, PRIORITY_S * 0.999, PRIORITY_S, 2.5 * PRIORITY_S)] == [0, 0, 0, 1, 2]
    assert priority_draw(1e300) == 0xFFFFFFFF and priority_draw(math.nan) == 0
    assert [rank(i, 0) for i in range(5)] == list(range(5))
    h = (3 * 0x9E3779B1 & 0xFFFFFFFF) ^ (7 * 0x85EBCA77 & 0xFFFFFFFF)
    for shift, mul in ((15, 0x2C1B3C6D), (12, 0x297A2D39), (15, None)):
        h ^= h >> shift
        h = h * mul & 0xFFFFFFFF if mul else h
    assert rank(3, 7) == h
    radii, pose, seen, points, nxt, margin, _ = _head_on()
    keeps = []
    for draw in range(64):
        elapsed = draw * PRIORITY_S + 0.5
        outs = [fn(radii, pose, seen, points, nxt, margin, elapsed) for fn in (assembly_targets,
                                                                              assembly_targets_reference)]
        assert all(np.array_equal(g, w) for g, w in zip(*outs))
        detoured = outs[0][2]
        assert detoured.sum() == 1
        keeper = int(np.flatnonzero(~detoured)[0])
        assert keeper == (0 if (rank(0, draw), 0) < (rank(1, draw), 1) else 1)
        keeps.append(keeper)
    assert keeps[0] == 0 and 16 < sum(keeps) < 48, sum(keeps)


def test_robots_near_their_points_a_single_robot_and_no_robots_keep_their_targets():
    radii, pose, seen, points, nxt, margin, elapsed = _head_on()
    near = pose[:, :2] + np.array([[ASSEMBLING_M, 0.0], [-ASSEMBLING_M, 0.0]])   # exactly ASSEMBLING_M: not on its way
    for args in ((radii, pose, seen, near, nxt, margin, elapsed),
                 (radii[:1], pose[:1], seen[:1], points[:1], nxt[:1], margin, elapsed),
                 (np.zeros(0), np.zeros((0, 3)), np.zeros(0, bool), np.zeros((0, 2)), np.zeros((0, 2)), margin, 0.0)):
        now, next_, detoured = assembly_targets(*args)
        assert not detoured.any() and np.array_equal(now, args[3]) and np.array_equal(next_, args[4])


def test_the_core_refuses_what_it_cannot_read():
    radii, pose, seen, points, nxt, margin, elapsed = _head_on()
    for bad in ("pose", "points", "next", "radius"):
        a = [radii.copy(), pose.copy(), seen, points.copy(), nxt.copy()]
        {"pose": lambda: a[1].__setitem__((1, 1), np.nan), "points": lambda: a[3].__setitem__((0, 0), np.inf),
         "next": lambda: a[4].__setitem__((1, 0), np.nan), "radius": lambda: a[0].__setitem__(0, np.inf)}[bad]()
        with pytest.raises(NonFiniteError):
            assembly_targets(*a, margin, elapsed)
    for bad_margin, bad_elapsed in ((math.nan, 0.0), (margin, math.nan), (margin, math.inf)):
        with pytest.raises(NonFiniteError):
            assembly_targets(radii, pose, seen, points, nxt, bad_margin, bad_elapsed)
    with pytest.raises(VsfleetValueError):
        assembly_targets(radii, pose, seen, points, nxt, -0.01, elapsed)
    with pytest.raises(VsfleetValueError):
        assembly_targets(np.array([0.05, -0.05]), pose, seen, points, nxt, margin, elapsed)
    with pytest.raises(ShapeError):
        assembly_targets(radii, pose[:, :2], seen, points, nxt, margin, elapsed)
    out = np.empty((2, 2))
    with pytest.raises(VsfleetValueError, match="shares memory"):   # the binding: outputs apart from the inputs
        _core.assembly_targets(radii, pose, seen, points, nxt, margin, elapsed, points, out, np.empty(2, bool))
    with pytest.raises(ValueError):
        _core.assembly_targets(radii, pose, seen, points, nxt, margin, elapsed, out, np.empty((3, 2)),
                               np.empty(2, bool))
    with pytest.raises(TypeError):
        _core.assembly_targets(radii, pose, seen, points, nxt, margin, out, np.empty((2, 2)), np.empty(2, bool))
    count = _core.assembly_targets(radii, pose, seen, points, nxt, margin, elapsed, out, np.empty((2, 2)),
                                   np.empty(2, bool))
    assert count == 1


def _crowd_mission(n: int = 8) -> tuple[Mission, np.ndarray]:
    """n robots of 5 cm packed 2 cm apart in a 2-row block, their points on a 0.3 m grid in a shuffled order."""
    rng = np.random.default_rng(3)
    order = rng.permutation(n)
    robots = tuple((f"r{i + 1:02d}", RobotSpec(p=(0.3 * (order[i] % (n // 2)), 0.3 * (order[i] // (n // 2))),
                                               wheel_base=0.12, wheel_speed_max=0.3, wheel_accel_max=0.8,
                                               radius=0.05)) for i in range(n))
    start = np.array([(0.12 * (i % (n // 2)), 0.12 * (i // (n // 2))) for i in range(n)])
    mission = Mission(version=1, metric="l2", robots=robots, speed_max=0.08, turn_rate_max=0.3, effective_t=0.0,
                      goal=(0.3, 0.1, 0.0))
    return mission, start


def test_the_step_calls_the_impls_tie_break_and_its_outputs_are_the_references_bits():
    mission, start = _crowd_mission()
    calls = []

    def recorded(fn):
        def call(*a):
            out = fn(*a)
            calls.append((fn.__name__, int(out[2].sum())))
            return out
        return call

    configs = []
    for fn in (assembly_targets, assembly_targets_reference):
        cfg = StepConfig(dt_s=1.0 / 30.0)
        object.__setattr__(cfg, "impl", dataclasses.replace(core_impl, assembly_targets=recorded(fn)))
        configs.append(cfg)
    assert core_impl.assembly_targets is assembly_targets
    assert reference_impl.assembly_targets is assembly_targets_reference
    rng = np.random.default_rng(5)
    states = [AgentState("r01"), AgentState("r01")]
    ids = mission.robot_ids
    for k in range(12):
        t = k / 30.0
        xy = start + rng.normal(0.0, 0.002, start.shape)
        poses = {r: (float(xy[i, 0]), float(xy[i, 1]), float(0.3 * i)) for i, r in enumerate(ids) if k % 5 or i != 3}
        frame = Frame(seq=k + 1, t=t, poses=poses, complete=len(poses) == len(ids), fresh=frozenset(poses))
        outs = []
        for j, cfg in enumerate(configs):
            states[j], out = agent_step(states[j], mission, frame, t + 0.001, cfg)
            outs.append(out)
        a, b = outs
        assert (a.cmd.vl, a.cmd.vr) == (b.cmd.vl, b.cmd.vr)
        assert a.wheels_m_s.tobytes() == b.wheels_m_s.tobytes()
        assert [(e.robot, e.kind, e.t, e.dev) for e in a.events] == [(e.robot, e.kind, e.t, e.dev) for e in b.events]
    core_calls = [c for c in calls if c[0] == "assembly_targets"]
    ref_calls = [c for c in calls if c[0] == "assembly_targets_reference"]
    assert len(core_calls) == len(ref_calls) == 12
    assert [c[1] for c in core_calls] == [c[1] for c in ref_calls] and sum(c[1] for c in core_calls) > 0


def test_the_numpy_reference_reproduces_the_cores_golden_records():
    """tests/data/golden-core.txt's assembly_targets records (replayed natively, at -O0/-O2/-O3 and on aarch64 by
    tests/test_core_golden.py) are the reference's bits too."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from golden_core import PATH, read

    records = [(i, w) for e, i, w in read(PATH) if e == "assembly_targets"]
    assert len(records) >= 150
    detoured = 0
    for inputs, want in records:
        n = int(inputs[0])
        a = np.asarray(inputs)
        radii, pose = a[3:3 + n], a[3 + n:3 + 4 * n].reshape(n, 3)
        seen, now = a[3 + 4 * n:3 + 5 * n] != 0.0, a[3 + 5 * n:3 + 7 * n].reshape(n, 2)
        nxt = a[3 + 7 * n:3 + 9 * n].reshape(n, 2)
        got_now, got_next, got_det = assembly_targets_reference(radii, pose, seen, now, nxt, float(a[1]), float(a[2]))
        got = [*got_now.ravel(), *got_next.ravel(), *got_det.astype(float), float(got_det.sum())]
        assert [v.hex() for v in got] == [v.hex() for v in want]
        detoured += int(got_det.sum())
    assert detoured > 300, detoured
