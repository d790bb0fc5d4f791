"""Missions in a room, offline (simfleet.offline: the real agents on counted frames, simfleet's physics):
the structure goes around an obstacle, a crowded start assembles, and no two bodies touch."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

import vsfleet.agentcore as agentcore
from vsfleet.agentstate import STALL_S
from vsfleet.analysis import min_gap_m
from vsfleet.geometry import Pose2
from vsfleet.simfleet.offline import run_offline
from vsfleet.wire import Mission, RobotSpec, TruthMsg
from vsfleet.zglue.scenario_file import load_scenario

ROOT = Path(__file__).resolve().parent.parent


def gap_of(scenario, run) -> float:
    frames = [(k, {r: TruthMsg(t=float(k), x=float(p[0]), y=float(p[1]), th=0.0, vl=0.0, vr=0.0, why="idle")
                   for r, p in zip(run.robots, pos)}) for k, pos in enumerate(run.positions_m)]
    return min_gap_m(scenario.mission, frames)


@pytest.mark.parametrize("name", ["paper-triangle-obstacle", "tight-row"])
def test_the_fleet_reaches_its_goal_without_any_body_touching_another_or_an_obstacle(name):
    scenario = load_scenario(ROOT / "scenarios" / f"{name}.toml")
    run = run_offline(scenario, 90.0, seed=1)
    assert run.t_goal_s is not None
    assert gap_of(scenario, run) > 0.005  # at least 5 mm apart at every frame


def test_the_structure_passes_the_pillar_instead_of_crossing_it():
    scenario = load_scenario(ROOT / "scenarios" / "paper-triangle-obstacle.toml")
    run = run_offline(scenario, 90.0, seed=2)
    (x, y, r), = scenario.mission.obstacles
    centre = np.array([[p.x, p.y] for _, p in run.trace])
    assert np.hypot(centre[:, 0] - x, centre[:, 1] - y).min() > r  # the structure's origin went round it
    assert run.t_goal_s is not None


def walled_in():
    """The paper triangle's obstacle scenario with its goal walled in: a closed ring of 20 pillars 0.75 m round it."""
    scenario = load_scenario(ROOT / "scenarios" / "paper-triangle-obstacle.toml")
    gx, gy, _ = scenario.mission.goal
    ring = tuple((gx + 0.75 * math.cos(2 * math.pi * k / 20), gy + 0.75 * math.sin(2 * math.pi * k / 20), 0.14)
                 for k in range(20))
    return dataclasses.replace(scenario, mission=dataclasses.replace(scenario.mission, obstacles=ring))


def test_a_goal_walled_in_stops_the_structure_short_and_every_agent_says_so_once():
    scenario = walled_in()
    gx, gy, _ = scenario.mission.goal
    run = run_offline(scenario, 40.0, seed=1)
    assert run.t_goal_s is None
    assert gap_of(scenario, run) > 0.005
    for robot, decisions in run.decisions.items():
        assert [d.kind for d in decisions] == ["blocked"], robot
    last = run.trace[-1][1]
    assert math.hypot(last.x - gx, last.y - gy) > 0.89  # stopped outside the ring
    assert math.hypot(last.x - gx, last.y - gy) < 1.5   # but came as close as it safely could


def test_min_gap_is_the_smallest_clearance_between_bodies_and_obstacles():
    robots = tuple((r, RobotSpec(p=p, wheel_base=0.1, wheel_speed_max=0.3, wheel_accel_max=1.0, radius=0.05))
                   for r, p in (("a", (0.0, 0.0)), ("b", (1.0, 0.0))))
    mission = Mission(version=1, metric="l2", robots=robots, speed_max=0.1, turn_rate_max=0.1, effective_t=0.0,
                      goal=(0.0, 0.0, 0.0), obstacles=((0.0, 1.0, 0.2),))
    t = {"a": TruthMsg(t=0.0, x=0.0, y=0.0, th=0.0, vl=0.0, vr=0.0, why="idle"),
         "b": TruthMsg(t=0.0, x=0.12, y=0.0, th=0.0, vl=0.0, vr=0.0, why="idle")}
    assert min_gap_m(mission, [(0.0, t)]) == pytest.approx(0.02)
    t["a"] = TruthMsg(t=0.0, x=0.0, y=0.76, th=0.0, vl=0.0, vr=0.0, why="idle")
    assert min_gap_m(mission, [(0.0, t)]) == pytest.approx(-0.01)  # a body inside the obstacle's edge


# ------------------------------------------------------------------ issue 28: bodies planned in SE(2)

SIDE_M, BODY_M = 0.5, 0.09      # the paper triangle of side 0.5 m with bodies of 0.09 m (issue 28)


def triangle_in_a_room(obstacles, phi_rad: float = 0.0, goal=(2.0, 1.5, 0.0)):
    """The issue's fleet: the triangle (a vertex at phi_rad), bodies 0.09 m, wheel base 0.16 m, 0.25 m/s, 1 m/s^2,
    mission 0.1 m/s and 0.5 rad/s, l2, from the origin to (2, 1.5); 2 mm noise, wheel gains 0.96-1.04."""
    sc = load_scenario(ROOT / "scenarios" / "paper-triangle-obstacle.toml")
    rc = SIDE_M / math.sqrt(3.0)
    pts = [(rc * math.cos(phi_rad + a), rc * math.sin(phi_rad + a)) for a in (0.0, 2 * math.pi / 3, 4 * math.pi / 3)]
    robots = tuple((rid, dataclasses.replace(spec, p=pts[i], wheel_base=0.16, wheel_speed_max=0.25,
                                             wheel_accel_max=1.0, radius=BODY_M))
                   for i, (rid, spec) in enumerate(sc.mission.robots))
    mission = dataclasses.replace(sc.mission, robots=robots, speed_max=0.1, turn_rate_max=0.5, metric="l2",
                                  goal=goal, obstacles=tuple(obstacles))
    sims = tuple(dataclasses.replace(s, start=(pts[i][0], pts[i][1], 0.0), gain=(1.0 + 0.04 * (-1) ** i, 1.0),
                                     wheel_base=0.16, wheel_speed_max=0.25, wheel_accel_max=1.0, radius=BODY_M)
                 for i, s in enumerate(sc.robots))
    return dataclasses.replace(sc, mission=mission, robots=sims,
                               tracker=dataclasses.replace(sc.tracker, noise_xy_m=0.002))


def thin_wall(gap_m: float, x: float = 1.0, centre_y: float = 0.765, r: float = 0.1):
    """A wall of overlapping discs (radius r, 0.15 m apart) along x, from y = -1.7 to 3.2, with one gap of
    gap_m [m] between the discs' edges, centred at centre_y."""
    above = [(x, centre_y + gap_m / 2 + r + 0.15 * k, r) for k in range(int((3.2 - centre_y) / 0.15))]
    below = [(x, centre_y - gap_m / 2 - r - 0.15 * k, r) for k in range(int((centre_y + 1.7) / 0.15))]
    return above + below


def ring_with_gap(gap_m: float, centre=(2.0, 1.5), radius: float = 0.8, r: float = 0.1):
    """A closed ring of overlapping discs (radius r) around centre, with one gap of gap_m [m] between two
    discs' edges, facing the origin (the fleet's start)."""
    facing = math.atan2(-centre[1], -centre[0])
    half = math.asin((gap_m / 2 + r) / radius)        # the gap's two discs at facing -/+ half
    count = int((2 * math.pi - 2 * half) / (0.15 / radius)) + 1
    angles = np.linspace(facing + half, facing + 2 * math.pi - half, count)
    return [(centre[0] + radius * math.cos(a), centre[1] + radius * math.sin(a), r) for a in angles]


def filter_changes(monkeypatch) -> list[float]:
    """Record, per frame stepped, how much the safety filter changed any robot's command [m/s]."""
    import vsfleet.glue as glue
    changes: list[float] = []
    original = glue._safe_wheels

    def recording(arrays, pose, seen, active, wheels, wheels_prev, config):
        out = original(arrays, pose, seen, active, wheels, wheels_prev, config)
        changes.append(float(np.abs(out - wheels).max()))
        return out

    monkeypatch.setattr(glue, "_safe_wheels", recording)
    monkeypatch.setattr(agentcore, "agent_kernel", lambda *args: None)   # the numpy glue, where _safe_wheels is
    return changes


@pytest.mark.parametrize("radius_m", [0.15, 0.25])
def test_a_vertex_facing_the_pillar_no_longer_deadlocks_the_fleet_and_the_safety_filter_stays_idle(radius_m, monkeypatch):
    """Issue 28's deadlock: with a vertex at 60 degrees the disc planner's path brought the nearest body to
    11.8-12.8 mm of the pillar, inside the safety filter's 15 mm: the filter held that robot off its point, the
    compliance throttle halted the structure, and no agent said 'blocked'; it stopped 1.3 m short."""
    changes = filter_changes(monkeypatch)
    scenario = triangle_in_a_room([(1.0, 0.75, radius_m)], phi_rad=1.05)
    run = run_offline(scenario, 45.0, seed=1, share_structures=False)
    assert run.t_goal_s is not None and run.t_goal_s < 1.5 * 25.0   # the straight path takes 25 s
    assert gap_of(scenario, run) > 0.05
    assert max(changes) == 0.0                                      # the plan keeps the filter idle
    assert all(not d for d in run.decisions.values())               # no failure, no 'blocked'


def test_the_structure_turns_to_pass_a_gap_narrower_than_its_enclosing_disc():
    gap = 0.70
    disc = 2 * (SIDE_M / math.sqrt(3.0) + BODY_M)
    assert disc > gap + 0.05                                         # the disc planner could not pass it
    scenario = triangle_in_a_room(thin_wall(gap), phi_rad=0.5)
    run = run_offline(scenario, 60.0, seed=1)
    assert run.t_goal_s is not None and run.t_goal_s < 1.5 * 25.0
    assert gap_of(scenario, run) > 0.015
    headings = np.array([p.th for _, p in run.trace])
    assert np.ptp(headings) > 0.2                                   # it turned on the way


def test_a_goal_ringed_with_a_gap_narrower_than_a_body_is_no_way_and_every_agent_says_blocked_once():
    scenario = triangle_in_a_room(ring_with_gap(0.15))
    run = run_offline(scenario, 40.0, seed=1)
    assert run.t_goal_s is None
    assert gap_of(scenario, run) > 0.015
    for robot, decisions in run.decisions.items():
        assert [d.kind for d in decisions] == ["blocked"], robot
    bodies = run.positions_m[-1]                                          # it stopped outside the ring: every
    assert (np.hypot(bodies[:, 0] - 2.0, bodies[:, 1] - 1.5) > 0.8).all()  # body beyond the discs' centre line


def room_4():
    """bench/room.py's room 4: the triangle (bodies 0.05-0.09 m) and a thin wall whose gap the field threads close to
    the wall, where the fitted pose falls between lattice states beside it."""
    import sys
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # bench/
    from bench.room import make_room, to_scenario

    return to_scenario(make_room(4), 30.0)


# Room 4's fitted pose at 7.4 s (seed 4), beside the wall: its nearest lattice state is a wall, and the cheapest
# free state of the ring around it (cost 0) lies in a sliver of the lattice the goal cannot be reached from
ROOM_4_BESIDE_THE_WALL = Pose2(-0.4356030621094763, -0.03817834273497153, -3.00632020631871)


def test_a_pose_beside_a_wall_starts_its_descent_on_the_way_to_the_goal_not_in_a_sliver_that_leads_nowhere():
    """Until 2026-12-05 the descent started on the cheapest free state of the nearest ring whatever its component:
    in room 4 that was a sliver's own end (cost 0, blocked), so at 7.4 s every agent said 'blocked, no path to the
    goal', 1.0 m short, and the fleet stood (the session before took this for a stall of the clearance barrier).
    A state the goal can be reached from now comes first, in the core and the reference alike; the fleet
    reaches its goal."""
    from vsfleet.field import build_field, build_field_reference, field_headings, field_open_reference, follow_field
    from vsfleet.field import follow_field_reference
    from vsfleet.structure import PLAN_MARGIN_M

    import sys
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from bench.room import make_room

    room = make_room(4)
    k = field_headings(room.template, room.radii, PLAN_MARGIN_M, room.obstacles, room.goal)
    core = build_field(room.template, room.radii, PLAN_MARGIN_M, room.obstacles, Pose2(*room.goal), n_headings=k)
    ref = build_field_reference(room.template, room.radii, PLAN_MARGIN_M, room.obstacles, Pose2(*room.goal),
                                n_headings=k)
    # the premise: the pose's own cell is a wall at every heading looked at, and the cheapest free state of the
    # ring around it is one the goal cannot be reached from (what the old rule took)
    from vsfleet.field import BLOCKED_BIT, COST_MASK, WALL, _cost_view, _nearest
    lat, cost = ref.lattice, _cost_view(ref)
    c0, r0, k0, _ = _nearest(lat, *ROOM_4_BESIDE_THE_WALL.as_tuple())
    plane = lat.nx * lat.ny
    heads = [(k0 + lat.n_headings + dk) % lat.n_headings for dk in (0, 1, -1, 2, -2)]
    assert all(int(cost[k * plane + r0 * lat.nx + c0]) == WALL for k in heads)
    ring = [int(cost[k * plane + (r0 + dr) * lat.nx + c0 + dc]) for k in heads for dr in (-1, 0, 1) for dc in (-1, 0, 1)
            if (dr, dc) != (0, 0) and int(cost[k * plane + (r0 + dr) * lat.nx + c0 + dc]) != WALL]
    assert min(ring, key=lambda v: v & COST_MASK) & BLOCKED_BIT
    way_core, blocked_core, _ = follow_field(core, ROOM_4_BESIDE_THE_WALL)
    way_ref, blocked_ref, _ = follow_field_reference(ref, ROOM_4_BESIDE_THE_WALL)
    assert not blocked_core and not blocked_ref
    assert field_open_reference(ref, ROOM_4_BESIDE_THE_WALL)[0]
    np.testing.assert_array_equal(way_core, way_ref)
    run = run_offline(room_4(), 30.0, seed=4)
    assert run.t_goal_s is not None and run.t_goal_s < 25.0
    assert all(ds == [] for ds in run.decisions.values()), run.decisions
    assert gap_of(room_4(), run) > 0.015


@pytest.mark.parametrize("gap_m, phi_rad", [(0.50, 0.0), (0.52, 0.0), (0.56, 0.5), (0.52, 0.5), (0.40, 0.5)])
def test_the_structure_threads_a_thin_wall_turning_in_step_with_its_move(gap_m, phi_rad):
    """Gaps of 0.40-0.56 m, narrower than the triangle with its bodies (0.61 m): the way threads the wall
    between the robots. The structure keeps to the plan in SE(2) (VS_GOAL_PLAN: it turns in step with its
    move toward the carrot) and gets through; when it turned on its own profile, ahead of the plan, it cut
    the lattice's corners, a body came within the safety filter's margin and the fleet stopped in the gap
    (0.52 m: 'blocked' at 22 s, never at the goal). Turned 0.5 rad, the triangle stopped so in the 0.46 and
    0.52 m gaps until 2026-12-05 ('blocked'); with the clearance barrier it passes them, and 0.40 m, in 38-40 s,
    its bodies 20 mm or more from the wall, clear of the safety filter's 15 mm."""
    scenario = triangle_in_a_room(thin_wall(gap_m), phi_rad=phi_rad)
    run = run_offline(scenario, 50.0, seed=1)
    assert run.t_goal_s is not None
    assert gap_of(scenario, run) > (0.018 if phi_rad else 0.01)
    assert all(not ds for ds in run.decisions.values())


def test_a_wall_gap_the_fleet_passes_raises_no_stall():
    run = run_offline(triangle_in_a_room(thin_wall(0.62)), 45.0, seed=1)
    assert run.t_goal_s is not None
    assert all(not ds for ds in run.decisions.values())


# ------------------------------------------------------------------ issue 28: crowded starts (assembly)

def test_a_shuffled_crowd_assembles_without_any_robot_judged_failed_or_two_bodies_touching():
    """bench/crowd.py's shuffled crowd of 10 (seed 3): packed 2 cm apart, random headings, their points on a 2 x 5
    grid at 0.3 m in a shuffled order. Robots on their way to their points, or held back by the safety filter,
    are in the assembly phase: before it, the deviation test judged 9 of them failed at 6.4 s. Robots barred on
    their way go round (vsfleet.step.assembly_targets): before, two of them stayed locked head on for good."""
    from bench.crowd import ASSEMBLED_M, crowd_doc
    from vsfleet.scenario import scenario_from_dict

    scenario = scenario_from_dict(crowd_doc(10, 3, 20.0), name="crowd-10-shuffled")
    run = run_offline(scenario, 20.0, seed=3, stop_at_goal=False)
    assert [d for decisions in run.decisions.values() for d in decisions if d.kind == "fail"] == []
    assert gap_of(scenario, run) > 0.005
    assert np.any(run.deviations_m.max(axis=1) < ASSEMBLED_M)    # every robot within 1 cm of its point at once


def test_of_two_robots_head_on_the_later_id_goes_round_on_its_right_and_the_other_keeps_its_way():
    from vsfleet.step import assembly_targets
    radii = np.array([0.05, 0.05])
    pose = np.array([[0.0, 0.0, 0.0], [0.12, 0.0, math.pi]])     # face to face, 2 cm apart
    points = np.array([[0.5, 0.0], [-0.4, 0.0]])                  # each one's point behind the other
    now, nxt, detoured = assembly_targets(radii, pose, np.ones(2, bool), points, points, 0.015, 0.0)
    assert detoured.tolist() == [False, True]
    assert now[0].tolist() == [0.5, 0.0] and np.array_equal(nxt, now)
    # r2 heads -x: its right is +y; its waypoint does not bring it closer to r1 (they touch within the margin)
    assert now[1, 1] > 0.1 and now[1, 0] >= 0.12 - 1e-12
    # the rows, not the poses, decide: swapped, the other robot gives way
    now_s, _, detoured_s = assembly_targets(radii, pose[::-1], np.ones(2, bool), points[::-1], points[::-1], 0.015, 0.0)
    assert detoured_s.tolist() == [False, True]


def test_a_robot_barred_by_one_on_its_point_goes_round_it_on_the_side_it_is_on():
    from vsfleet.step import assembly_targets
    radii = np.full(2, 0.05)
    pose = np.array([[0.0, 0.0, 0.0], [0.2, -0.03, 0.0]])          # r2 on its point, a little right of r1's way
    points = np.array([[0.6, 0.0], [0.2, -0.03]])
    now, _, detoured = assembly_targets(radii, pose, np.ones(2, bool), points, points, 0.015, 0.0)
    assert detoured.tolist() == [True, False]
    assert now[0, 1] > 0.1                                          # round it on the left, the side r1 is on
    assert now[1].tolist() == [0.2, -0.03]


def test_robots_near_their_points_or_with_a_free_way_keep_their_targets():
    from vsfleet.step import assembly_targets
    radii = np.full(3, 0.05)
    pose = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [1.0, 1.0, 0.0]])
    points = np.array([[0.02, 0.0], [0.3, 0.3], [1.0, 1.5]])   # near it; a free way; a free way
    now, nxt, detoured = assembly_targets(radii, pose, np.ones(3, bool), points, points + 0.001, 0.015, 0.0)
    assert not detoured.any() and np.array_equal(now, points) and np.array_equal(nxt, points + 0.001)


def test_a_fleet_crawling_says_blocked_once_not_once_per_threshold_crossed():
    """The stall watch on a structure that crawls: 0.26 rad in 45 s with the safety filter holding a robot, as
    bench/room.py's room 149 did round a tight bend before the clearance barrier (it now reaches its goal:
    test_the_barrier_brings_room_149_round_its_bend). The watch took each 0.05 rad of crawl for going again and stuck
    again 0.1-3 s later: 20 blocked/unblocked events from every agent in 70 s. Going again now needs that much
    motion within STALL_S: one onset, never released. A turn of 0.1 rad in 1 s releases it."""
    from types import SimpleNamespace as NS

    from vsfleet.glue import stall_state

    arrays = NS(field=object(), policy=NS(fail_deviation_m=0.5))

    def run(rate_rad_s: float, seconds: float, crawl_from_s: float = 0.0):
        state = NS(stall_since_t=math.nan, stall_pose=None, stalled=False)
        flips = []
        for k in range(int(seconds * 30)):
            t = k / 30.0
            th = rate_rad_s * max(0.0, t - crawl_from_s)
            s = NS(deviations_m=np.array([0.01, 0.012, 0.011]), used=np.ones(3, bool), at_goal=False, blocked=False,
                   fit_pose=Pose2(1.0, 0.5, th))
            since, at, stalled = stall_state(state, arrays, s, True, False, t)
            if stalled != state.stalled:
                flips.append((round(t, 2), stalled))
            state = NS(stall_since_t=since, stall_pose=at, stalled=stalled)
        return flips

    crawl = run(0.26 / 45.0, 45.0)
    assert [f[1] for f in crawl] == [True], crawl          # stuck once, at STALL_S, and never 'going again'
    assert crawl[0][0] >= STALL_S
    fast = run(0.1, 8.0, crawl_from_s=5.0)                # still for 5 s, then a turn of 0.1 rad a second
    assert [f[1] for f in fast] == [True, False], fast


def test_the_barrier_brings_room_149_round_its_bend():
    """bench/room.py's room 149 (a square in a tight bend) crawled round it, a body held 13-16 mm from a wall disc,
    and ended 'blocked' 1.36 m short; with the clearance barrier it reaches its goal, nothing said."""
    import sys
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # bench/
    from bench.room import make_room, to_scenario

    room = make_room(149)
    run = run_offline(to_scenario(room, 45.0), 45.0, seed=149)
    assert run.t_goal_s is not None
    assert all(not ds for ds in run.decisions.values())


def test_a_line_of_10_takes_the_finer_lattices_way_out_of_room_70_in_time_and_says_nothing():
    """bench/room.py's room 70: a line of 10 robots in a bend. The room's own lattice (cells of 7.3 cm, to fit 2
    million states) has no way from the start, and every agent said 'blocked, no path' at its first frame
    (docs/benchmarks.md 8s); its finer lattice (vsfleet.field.field_refinement: 128 headings, 6 million states) has
    one. The fleet now reaches the goal within 1.5x the reference time (OMPL's path, 4.41 m at 0.1 m/s), no agent
    says blocked, and no body comes within the safety filter's 15 mm of another or of an obstacle."""
    import sys
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # bench/
    from bench.room import make_room, to_scenario

    room = make_room(70)
    scenario = to_scenario(room, 66.0)
    run = run_offline(scenario, 66.0, seed=70)
    assert run.t_goal_s is not None and run.t_goal_s <= 1.5 * 44.14
    assert all(e.kind not in ("blocked", "unblocked") for evs in run.events.values() for e in evs)
    assert gap_of(scenario, run) > 0.015


# Room 174's fitted pose at 47.17 s (seed 174, frame 1414; a line of 10 robots in a 0.25 m gap of a thin wall): the
# pose's own cell is free at one heading of the five looked at, a sliver of one state the goal cannot be reached
# from, and the way to the goal runs through the ring around it
ROOM_174_IN_THE_GAP = Pose2(-1.8578983101497388, -1.2903424725525297, 1.1937063168145752)


def test_a_sliver_in_the_poses_own_cell_does_not_hide_the_way_one_cell_away():
    """Until 2026-12-06 the descent started in the nearest ring that had any free state, and took a state the goal
    can be reached from only within that ring. In room 174 the pose's own cell held one free state, a sliver the goal
    cannot be reached from, so at 47.2 s every agent said 'blocked, no path to the goal', 2.2 m short, and the line
    stood in the gap for good (docs/benchmarks.md 8i). A state the goal can be reached from, in any ring within the
    search, now comes before a blocked one of a nearer ring, in the core and the reference alike."""
    from vsfleet.field import BLOCKED_BIT, WALL, _cost_view, _nearest, build_field, field_headings, follow_field
    from vsfleet.field import field_open_reference, follow_field_reference
    from vsfleet.structure import PLAN_MARGIN_M

    import sys
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from bench.room import make_room

    room = make_room(174)
    k = field_headings(room.template, room.radii, PLAN_MARGIN_M, room.obstacles, room.goal)
    core = build_field(room.template, room.radii, PLAN_MARGIN_M, room.obstacles, Pose2(*room.goal), n_headings=k)
    lat, cost = core.lattice, _cost_view(core)
    c0, r0, k0, _ = _nearest(lat, *ROOM_174_IN_THE_GAP.as_tuple())
    plane = lat.nx * lat.ny
    heads = [(k0 + lat.n_headings + dk) % lat.n_headings for dk in (0, 1, -1, 2, -2)]
    # the premise: ring 0 holds free states the goal cannot reach and none it can; ring 1 holds some it can
    own = [int(cost[kk * plane + r0 * lat.nx + c0]) for kk in heads]
    own_free = [v for v in own if v != WALL]
    assert own_free and all(v & BLOCKED_BIT for v in own_free)
    ring1 = [int(cost[kk * plane + (r0 + dr) * lat.nx + c0 + dc]) for kk in heads for dr in (-1, 0, 1)
             for dc in (-1, 0, 1) if (dr, dc) != (0, 0)]
    assert any(v != WALL and not v & BLOCKED_BIT for v in ring1)
    way_core, blocked_core, left_core = follow_field(core, ROOM_174_IN_THE_GAP)
    way_ref, blocked_ref, left_ref = follow_field_reference(core, ROOM_174_IN_THE_GAP)
    assert not blocked_core and not blocked_ref and left_core == left_ref == 0.0
    assert field_open_reference(core, ROOM_174_IN_THE_GAP)[0]
    np.testing.assert_array_equal(way_core, way_ref)
    # the way leads on toward the goal: the descent's end is nearer the goal than the pose
    gx, gy = room.goal[0], room.goal[1]
    assert np.hypot(way_core[-1][0] - gx, way_core[-1][1] - gy) < np.hypot(ROOM_174_IN_THE_GAP.x - gx,
                                                                            ROOM_174_IN_THE_GAP.y - gy) - 0.5


def test_a_stuck_structure_says_blocked_with_why_stuck(monkeypatch):
    """The stall watch's verdict on the wire: blocked, why stuck, dev the structure's distance to its goal; then
    unblocked without a why. The watch is scripted here (stuck from 1 s to 2 s of a pillar room; its rule has
    its own tests above), and the numpy glue's step turns its verdict into events as the core's binding does."""
    import vsfleet.glue as glue

    real = glue.stall_state

    def scripted(state, arrays, s, filtered, failed_any, t):
        since, at, _stalled = real(state, arrays, s, filtered, failed_any, t)
        return since, at, 1.0 <= t < 2.0

    monkeypatch.setattr(glue, "stall_state", scripted)
    sc = load_scenario(ROOT / "scenarios" / "room-pillar-facing.toml")
    run = run_offline(sc, 3.0, seed=1, share_structures=True, reference=False, stop_at_goal=False)
    for robot, evs in run.events.items():
        assert [(e.kind, e.why) for e in evs] == [("blocked", "stuck"), ("unblocked", "")], (robot, evs)
        assert 1.0 <= evs[0].t < 1.1 and evs[0].dev > 0.5 and evs[0].robot == evs[0].by == robot
