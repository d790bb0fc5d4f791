"""The structure's clearance barrier in a room (vsfleet.clear; vs_clear.c): the compiled core against the plain
Python reference, bit for bit, on random rooms; and what it promises: no row, no change; a point closing on an
obstacle is slowed to the barrier's rate; a point inside the clearance is moved out even when the structure is
held; the nearest twist is found (against a brute-force search of the same rows)."""

from __future__ import annotations

import itertools
import math

import numpy as np

from vsfleet.clear import clearance_barrier, clearance_barrier_reference
from vsfleet.coreconst import CLEAR_BAND_M, CLEAR_GAMMA_PER_S, CLEAR_M, CLEAR_ROWS


def random_case(rng):
    n = int(rng.integers(1, 9))
    fx, fy = (float(v) for v in rng.uniform(-2.0, 2.0, 2))
    pts = np.c_[fx + rng.uniform(-0.6, 0.6, n), fy + rng.uniform(-0.6, 0.6, n)]
    rad = rng.uniform(0.0, 0.1, n)
    m = int(rng.integers(0, 12))
    # obstacles near the points: most cases have rows
    near = pts[rng.integers(0, n, m)] if m else np.zeros((0, 2))
    obs = np.c_[near + rng.uniform(-0.35, 0.35, (m, 2)), rng.uniform(0.02, 0.2, m)] if m else np.zeros((0, 3))
    reach = float(rng.choice([0.0, rng.uniform(0.05, 1.0)])) if rng.random() < 0.05 else float(rng.uniform(0.05, 1.0))
    twist = tuple(float(v) for v in (rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(-1.0, 1.0)))
    if rng.random() < 0.2:
        twist = (0.0, 0.0, 0.0)
    return pts, fx, fy, rad, obs, reach, twist


def test_core_and_reference_agree_bit_for_bit_on_random_rooms():
    rng = np.random.default_rng(20261205)
    changed = 0
    for _ in range(3000):
        case = random_case(rng)
        got, ref = clearance_barrier(*case), clearance_barrier_reference(*case)
        assert got[1] == ref[1]
        assert [v.hex() for v in got[0]] == [v.hex() for v in ref[0]], case
        changed += ref[1]
    assert changed > 500   # the cases exercise the enumeration, not only the unchanged path


def rows_of(pts, fx, fy, rad, obs, reach):
    """The barrier's rows as the header states them (all of them, for the brute-force check)."""
    rows = []
    for i, (px, py) in enumerate(pts):
        d = np.hypot(px - obs[:, 0], py - obs[:, 1])
        clr = d - (rad[i] + obs[:, 2])
        j = int(np.argmin(clr))
        if clr[j] < CLEAR_M + CLEAR_BAND_M:
            nx, ny = (px - obs[j, 0]) / d[j], (py - obs[j, 1]) / d[j]
            rows.append((clr[j], (nx, ny, (nx * -(py - fy) + ny * (px - fx)) / reach),
                         -CLEAR_GAMMA_PER_S * (clr[j] - CLEAR_M)))
    rows.sort(key=lambda r: r[0])
    return rows[:CLEAR_ROWS]


def test_the_result_meets_every_row_and_is_the_nearest_twist():
    """Where some twist meets every row and the answer is not shortened, the answer meets them and no twist on a
    fine grid around it that meets them is nearer; where none does, the answer holds (rows clamped to <= 0) or
    stops; it is never longer than the twist given or the push-out."""
    rng = np.random.default_rng(7)
    checked = held = 0
    for _ in range(600):
        pts, fx, fy, rad, obs, reach, twist = random_case(rng)
        if len(obs) == 0 or reach <= 0.0:
            continue
        (vx, vy, w), changed = clearance_barrier(pts, fx, fy, rad, obs, reach, twist)
        rows = rows_of(pts, fx, fy, rad, obs, reach)
        td = np.array([twist[0], twist[1], twist[2] * reach])
        t = np.array([vx, vy, w * reach])
        assert np.linalg.norm(t) <= max(np.linalg.norm(td), CLEAR_GAMMA_PER_S * CLEAR_M) * (1 + 1e-12)
        if not changed:
            assert all(np.dot(a, td) >= b - 1e-9 for _c, a, b in rows)
            continue
        if not all(np.dot(a, t) >= b - 1e-9 for _c, a, b in rows):
            # no twist met every row: the answer holds every point (no row's clearance shrinks), or stops
            assert all(np.dot(a, t) >= min(b, 0.0) - 1e-9 for _c, a, b in rows)
            held += 1
            continue
        if np.linalg.norm(t) < max(np.linalg.norm(td), CLEAR_GAMMA_PER_S * CLEAR_M) - 1e-12:   # not shortened
            best = float(np.sum((t - td) ** 2))
            for step in itertools.product((-1, 0, 1), repeat=3):
                u = t + 1e-3 * np.array(step)
                if all(np.dot(a, u) >= b for _c, a, b in rows):
                    assert float(np.sum((u - td) ** 2)) >= best - 1e-12
            checked += 1
    assert checked > 100 and held > 0


def test_points_inside_the_clearance_on_both_sides_of_a_passage_still_move_along_it():
    """Two points 2 mm inside CLEAR_M of walls on opposite sides (a passage the field threads at its margin): no
    twist pushes both out, so the barrier holds them instead, and the move along the passage is kept."""
    c = CLEAR_M - 0.002
    pts = np.array([[0.0, 0.0], [0.0, 0.3]])
    obs = np.array([[0.0, -(0.09 + 0.1 + c), 0.1], [0.0, 0.3 + 0.09 + 0.1 + c, 0.1]])
    (vx, vy, w), changed = clearance_barrier(pts, 0.0, 0.15, np.array([0.09, 0.09]), obs, 0.15, (0.1, 0.0, 0.0))
    assert changed is False or (vx, vy, w) == (0.1, 0.0, 0.0)   # moving along both walls closes on neither
    (vx, vy, w), changed = clearance_barrier(pts, 0.0, 0.15, np.array([0.09, 0.09]), obs, 0.15, (0.1, 0.05, 0.0))
    assert changed and math.isclose(vx, 0.1) and abs(vy) < 1e-12 and abs(w) < 1e-9   # held across, moving along


def test_far_from_obstacles_the_twist_is_unchanged():
    pts = np.array([[0.0, 0.0], [0.5, 0.0]])
    obs = np.array([[3.0, 3.0, 0.2]])
    twist = (0.1, 0.05, 0.3)
    assert clearance_barrier(pts, 0.25, 0.0, np.array([0.09, 0.09]), obs, 0.25, twist) == (twist, False)


def test_a_point_closing_on_an_obstacle_is_slowed_to_the_barrier_rate():
    # one point 1 cm beyond CLEAR_M from a pillar straight ahead (+x): it may close at gamma (c - CLEAR_M) at most,
    # less than the 0.1 m/s asked
    c = CLEAR_M + 0.01
    assert CLEAR_GAMMA_PER_S * (c - CLEAR_M) < 0.1
    pts = np.array([[0.0, 0.0]])
    obs = np.array([[0.09 + 0.1 + c, 0.0, 0.1]])
    (vx, vy, w), changed = clearance_barrier(pts, 0.0, 0.0, np.array([0.09]), obs, 0.3, (0.1, 0.02, 0.0))
    assert changed
    assert math.isclose(vx, CLEAR_GAMMA_PER_S * (c - CLEAR_M), rel_tol=1e-12)
    assert vy == 0.02 and w == 0.0            # the motion along the obstacle is kept


def test_a_point_inside_the_clearance_is_moved_out_while_the_structure_is_held():
    c = 0.010   # the safety filter's 15 mm would hold this robot; its point moves out at gamma (CLEAR_M - c)
    pts = np.array([[0.0, 0.0]])
    obs = np.array([[0.0, -(0.09 + 0.2 + c), 0.2]])
    (vx, vy, w), changed = clearance_barrier(pts, 0.0, 0.3, np.array([0.09]), obs, 0.3, (0.0, 0.0, 0.0))
    assert changed
    # the nearest twist with n . (v + w x rho) >= gamma (CLEAR_M - c): n = +y, rho = (0, -0.3): w x rho = (0.3 w, 0)
    need = CLEAR_GAMMA_PER_S * (CLEAR_M - c)
    assert vy > 0.0 and math.isclose(vy, need, rel_tol=1e-9)
    assert vx == 0.0 and w == 0.0
