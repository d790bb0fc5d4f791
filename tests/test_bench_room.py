"""bench/room.py's rooms and bench/ompl_ref.py's reference planner (unit tier: a few seconds, no fleet runs)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench import ompl_ref
from bench.room import (CLEAR_M, FLEETS, KINDS, MAX_OBSTACLES, assembled_starts, has_way, make_room, obs_gap_m, pooled,
                        summary, to_scenario)
from vsfleet.field import build_field, follow_field
from vsfleet.fit import fit_structure
from vsfleet.geometry import Pose2
from vsfleet.step import PLAN_MARGIN_M

needs_ompl = pytest.mark.skipif(not ompl_ref.available(), reason="OMPL's Python bindings (pip install 'ompl>=2.0')")

TRIANGLE = [(0.5 / math.sqrt(3.0) * math.cos(a), 0.5 / math.sqrt(3.0) * math.sin(a))
            for a in (0.0, 2 * math.pi / 3, 4 * math.pi / 3)]


def test_a_room_is_the_same_for_the_same_seed_and_another_for_another():
    for seed in (0, 5, 17):
        a, b = make_room(seed), make_room(seed)
        assert (a.kind, a.shape, a.start, a.goal) == (b.kind, b.shape, b.start, b.goal)
        for name in ("template", "radii", "wheel_base", "gains", "obstacles"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert not np.array_equal(make_room(4).obstacles, make_room(8).obstacles)


def test_the_fleets_and_kinds_are_the_issues():
    rooms = [make_room(seed) for seed in range(40)]
    assert [r.n for r in rooms[:4]] == list(FLEETS)
    assert {r.kind for r in rooms} == set(KINDS)
    for r in rooms:
        assert np.allclose(r.template.mean(axis=0), 0.0, atol=1e-12)         # centred on the centroid
        assert 0.05 <= r.radii.min() and r.radii.max() <= 0.09
        assert 0.12 <= r.wheel_base.min() and r.wheel_base.max() <= 0.16
        assert np.abs(r.gains - 1.0).max() <= 0.04
        assert 1 <= len(r.obstacles) <= MAX_OBSTACLES


@pytest.mark.parametrize("kind", KINDS)
def test_start_and_goal_poses_are_clear_of_every_obstacle(kind):
    for seed in range(12):
        r = make_room(seed, kind=kind)
        for pose in (r.start, r.goal):
            assert ompl_ref.clearance_m(r.template, r.radii, r.obstacles, pose) >= CLEAR_M, (seed, pose)
            assert -math.pi <= pose[2] < math.pi


def test_the_fleet_starts_assembled_on_its_template_at_the_start_pose():
    r = make_room(1)
    sc = to_scenario(r, 60.0)
    starts = np.array([s.start for s in sc.robots])
    assert np.allclose(starts, assembled_starts(r))
    assert np.allclose(starts[:, 2], r.start[2])                            # every robot heads the structure's way
    fit = fit_structure(np.array([s.p for _, s in sc.mission.robots]), starts[:, :2], metric="l2")
    assert fit.pose.x == pytest.approx(r.start[0], abs=1e-9) and fit.pose.y == pytest.approx(r.start[1], abs=1e-9)
    assert math.remainder(fit.pose.th - r.start[2], 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    assert fit.residuals_m.max() < 1e-9
    assert sc.mission.speed_max == 0.1 and sc.mission.turn_rate_max == 0.5 and sc.mission.metric == "l2"


def sealed_rooms():
    return [make_room(seed, kind="sealed") for seed in (0, 1, 2)]          # 3, 4 and 10 robots


def test_a_sealed_ring_has_no_gap_a_body_fits_through_and_our_field_says_blocked_from_the_start():
    for r in sealed_rooms():
        gx, gy, _ = r.goal
        ring = r.obstacles[np.abs(np.hypot(r.obstacles[:, 0] - gx, r.obstacles[:, 1] - gy) - r.notes["ring_m"]) < 1e-3]
        assert len(ring) >= 8
        assert max(obs_gap_m(ring, (gx, gy))) < 2 * r.radii.min()             # narrower than any body
        # the goal's footprint inside the ring, the start's outside it
        assert r.notes["ring_m"] - ring[0, 2] > ompl_ref.footprint(r.template, r.radii)[2]
        assert math.hypot(r.start[0] - gx, r.start[1] - gy) > r.notes["ring_m"] + ring[0, 2]
        fld = build_field(r.template, r.radii, PLAN_MARGIN_M, r.obstacles, Pose2(*r.goal))
        _, blocked, left = follow_field(fld, Pose2(*r.start), path_m=1e9, cap=100000)
        assert blocked and left > 0.0


@needs_ompl
def test_ompl_finds_no_way_into_a_sealed_room():
    for r in sealed_rooms()[:2]:
        res = ompl_ref.plan_ompl(r.template, r.radii, r.obstacles, r.start, r.goal, max_checks=20_000)
        assert not res.success and math.isnan(res.length_m) and len(res.path) == 0
        assert res.checks >= 20_000


@needs_ompl
def test_ompl_goes_round_a_single_pillar_on_the_straight_path():
    pillar = [(1.0, 0.75, 0.25)]
    res = ompl_ref.plan_ompl(TRIANGLE, 0.09, pillar, (0.0, 0.0, 0.0), (2.0, 1.5, 0.0))
    assert res.success and res.status == "Exact solution"
    assert np.allclose(res.path[0], (0.0, 0.0, 0.0)) and np.allclose(res.path[-1], (2.0, 1.5, 0.0), atol=1e-9)
    assert 2.5 < res.length_m < 1.5 * 2.5                                    # the straight line is 2.5 m
    valid = ompl_ref.validity_fn(TRIANGLE, 0.09, pillar, PLAN_MARGIN_M)
    _, _, rho = ompl_ref.footprint(TRIANGLE, 0.09)
    for a, b in zip(res.path, res.path[1:]):                                 # every pose between: margin kept
        assert ompl_ref.motion_valid(valid, a, b, 0.002, rho)
    # the origin cannot cross the pillar: the footprint's bodies would touch it
    assert min(ompl_ref.clearance_m(TRIANGLE, 0.09, pillar, p) for p in res.path) >= PLAN_MARGIN_M
    again = ompl_ref.plan_ompl(TRIANGLE, 0.09, pillar, (0.0, 0.0, 0.0), (2.0, 1.5, 0.0))
    assert again.length_m == res.length_m                                    # the same seed, the same path


@needs_ompl
def test_ompl_finds_no_way_into_a_closed_ring():
    ring = [(2.0 + 0.8 * math.cos(a), 1.5 + 0.8 * math.sin(a), 0.1) for a in np.linspace(0, 2 * math.pi, 40, endpoint=False)]
    res = ompl_ref.plan_ompl(TRIANGLE, 0.09, ring, (0.0, 0.0, 0.0), (2.0, 1.5, 0.0), max_checks=20_000)
    assert not res.success
    # a start or goal in collision is no way at once
    res = ompl_ref.plan_ompl(TRIANGLE, 0.09, [(0.0, 0.0, 0.5)], (0.0, 0.0, 0.0), (2.0, 1.5, 0.0))
    assert not res.success and res.status == "invalid start or goal"


def test_the_validity_test_is_the_margin_from_every_body():
    valid = ompl_ref.validity_fn([(0.0, 0.0), (1.0, 0.0)], [0.05, 0.1], [(1.0, 0.5, 0.2)], 0.02)
    # body 2 (r 0.1) at (1, 0): 0.5 - 0.1 - 0.2 = 0.2 from the obstacle's edge
    assert valid(0.0, 0.0, 0.0)
    assert valid(0.0, 0.179, 0.0) and not valid(0.0, 0.181, 0.0)          # 0.2 - 0.18 = 0.02: the margin
    assert ompl_ref.path_length_m([(0, 0, 0), (3, 4, 1), (3, 4, 2)]) == pytest.approx(5.0)


def fake_evaluate(seed: int, ompl_checks: int, cap_s: float) -> dict:
    """evaluate()'s stand-in for the jobs test: who ran which seed with which arguments."""
    import os
    return {"seed": seed, "args": (ompl_checks, cap_s), "pid": os.getpid()}


@pytest.mark.integration   # worker processes
def test_rooms_run_in_worker_processes_give_every_seed_once_with_its_arguments(monkeypatch, tmp_path):
    import os

    import bench.room as room
    monkeypatch.setattr(room, "evaluate", fake_evaluate)
    serial = list(room._evaluated(range(3, 9), 7, 11.0, jobs=1))
    assert [r["seed"] for r in serial] == list(range(3, 9)) and {r["pid"] for r in serial} == {os.getpid()}
    pooled = list(room._evaluated(range(3, 9), 7, 11.0, jobs=2))
    assert sorted(r["seed"] for r in pooled) == list(range(3, 9))
    assert {r["args"] for r in pooled} == {(7, 11.0)} and os.getpid() not in {r["pid"] for r in pooled}
    with pytest.raises(SystemExit):
        room.main(["--rooms", "1", "--jobs", "0", "--out", str(tmp_path / "out")])
    assert not (tmp_path / "out").exists()


def test_a_room_our_fleet_drove_through_without_contact_has_a_way_even_where_ompl_found_none():
    def row(ompl, t_goal, gap, blocked=False):
        return {"ompl": {"success": ompl, "length_m": 2.0 if ompl else None, "time_s": 1.0},
                "ours": {"success": True, "length_m": 2.0, "build_s": 0.01}, "t_goal_s": t_goal, "gap_m": gap,
                "in_time": t_goal is not None, "ended_blocked": blocked, "ref_s": 20.0}

    driven, touched = row(False, 30.0, 0.02), row(False, 30.0, -0.001)
    stuck, ompl_only = row(False, None, 0.02, True), row(True, None, 0.02, True)
    assert [has_way(r) for r in (driven, touched, stuck, ompl_only)] == [True, False, False, True]
    p = pooled([driven, touched, stuck, ompl_only])
    assert (p["way"], p["ompl_way"], p["noway"], p["noway_blocked"], p["way_blocked"]) == (2, 1, 2, 1, 1)
    assert p["ompl_s_way"] == [1.0]   # OMPL's time over the rooms where it found its way
    rows = []
    for k, r in enumerate((driven, touched, stuck, ompl_only)):
        rows.append({**r, "seed": k, "kind": "wall", "shape": "line", "n": 10, "obstacles": 5,
                     "t_position_s": r["t_goal_s"], "end_goal_m": 0.0, "ours": {**r["ours"], "build_whole_s": 0.02}})
    rows[0]["ref_s"] = None   # neither planner's length (as rooms.json stores NaN)
    text = summary(rows)
    assert "| 0 | wall |" not in text and "| 2 | wall |" not in text   # in time, and without a way: not listed late
    assert "| 3 | wall | line (10) | 5 | 2.00 m | yes / 2.00 m | - | 20.00 s | yes |" in text
