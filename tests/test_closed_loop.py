"""The whole loop in one process (simfleet.offline): controller choice, determinism, a halted robot.

An offline run is a pure function of its scenario, duration and seed, and nothing in it depends on
the duration but where it stops: runs are cached (functools.cache) so that tests asking for the
same run share one, and a test that needs the first seconds of a longer run reads its prefix.
"""

import dataclasses
import functools
from pathlib import Path

import numpy as np
import pytest

from vsfleet.zglue.scenario_file import load_scenario
from vsfleet.simfleet.offline import run_offline
from vsfleet.control import CONTROLLERS, DEFAULT_CONTROLLER
from vsfleet.scenario import FaultEvent
from vsfleet.step import frame_arrays, mission_arrays, structure_step

ROOT = Path(__file__).parent.parent
E2E = load_scenario(ROOT / "tests" / "data" / "e2e-triangle.toml")
FAILURE = load_scenario(ROOT / "scenarios" / "paper-failure.toml")


def test_the_default_controller_measures_best_in_the_closed_loop():
    runs = {name: run_offline(E2E, 30.0, controller=name, seed=1) for name in CONTROLLERS}
    table = {n: (r.t_goal_s, round(100 * float(r.deviations_m.mean()), 3), round(r.wheel_tv_m_s2, 3))
             for n, r in runs.items()}
    print("controller: (time to goal s, mean deviation cm, wheel TV m/s per s)", table)
    best = runs[DEFAULT_CONTROLLER]
    assert best.t_goal_s is not None, table
    assert float(best.deviations_m.max()) < 0.02, table
    # it reaches the goal first, with wheel-command chatter within 10% of the calmest
    for name, r in runs.items():
        assert r.t_goal_s is None or best.t_goal_s <= r.t_goal_s, table
        assert best.wheel_tv_m_s2 <= 1.1 * r.wheel_tv_m_s2, table


def structure(mission, poses, judged_apart=(), excluded=()):
    arrays = mission_arrays(mission)
    pose, seen, _ = frame_arrays(arrays.ids, poses)
    rows = lambda names: np.array([r in names for r in arrays.ids])  # noqa: E731
    return structure_step(arrays, mission.metric, pose, seen, rows(excluded), rows(judged_apart), 2.5, 1 / 30)


def test_the_structure_part_of_a_step_is_a_pure_function_of_mission_and_frame():
    mission = E2E.mission
    poses = {"r1": (0.31, 0.01, 0.1), "r2": (-0.14, 0.26, 0.3), "r3": (-0.16, -0.25, 0.0)}
    a = structure(mission, poses)
    c = structure(mission, dict(reversed(list(poses.items()))))
    assert (c.fit_pose, c.goal_pose) == (a.fit_pose, a.goal_pose)  # arrival order does not matter
    d = structure(mission, {**poses, "r2": (-0.14, 0.2601, 0.3)})
    assert d.fit_pose != a.fit_pose
    e = structure(mission, poses, excluded=("r2",))
    assert e.fit_pose != a.fit_pose and list(e.used) == [True, False, True]


def test_a_halted_robot_bends_the_structure_which_halts_instead_of_leaving_it_behind():
    # paper-failure.toml as it stands is the hold/stop run below: its first 30 s, seed 2
    assert FAILURE.mission.on_failure == "hold" and FAILURE.faults == (FaultEvent("r2", 8.0, "stop", 0.0, 0.0),)
    run = failure_run("hold", "stop", 0.0, 0.0, seconds=60.0)
    frames = int(round(30.0 * FAILURE.tracker.rate_hz))
    trace, deviations_m = run.trace[:frames], run.deviations_m[:frames]
    i_fault = int(FAILURE.faults[0].at_s * FAILURE.tracker.rate_hz)
    t, before = trace[i_fault]
    _, end = trace[-1]
    # the structure moved before the fault, then stopped well short of the goal
    start = trace[0][1]
    assert np.hypot(before.x - start.x, before.y - start.y) > 0.2
    assert np.hypot(end.x - trace[-30][1].x, end.y - trace[-30][1].y) < 0.005
    goal = FAILURE.mission.goal
    assert np.hypot(goal[0] - end.x, goal[1] - end.y) > 0.5
    # and the formation error stays bounded: nobody is left behind
    worst = float(deviations_m[i_fault:].max())
    print(f"deviation after the fault: max {100 * worst:.2f} cm")
    assert worst < 0.10


@functools.cache
def failure_run(mode, kind, factor, duration, seed=2, seconds=60.0, stop_at_goal=False):
    """paper-failure.toml under on_failure ``mode``, r2's fault at 8 s (one run per arguments: cached)."""
    sc = dataclasses.replace(FAILURE, mission=dataclasses.replace(FAILURE.mission, on_failure=mode),
                             faults=(FaultEvent("r2", 8.0, kind, factor, duration),))
    return run_offline(sc, seconds, seed=seed, stop_at_goal=stop_at_goal)


def test_with_drop_a_halted_robot_is_dropped_by_every_agent_on_the_same_frame_and_the_rest_carry_on():
    run = failure_run("drop", "stop", 0.0, 0.0)
    made = run.decisions["r1"]
    assert all(v == made for v in run.decisions.values())  # agreement, frame for frame
    assert [(d.robot, d.kind) for d in made] == [("r2", "fail"), ("r2", "drop")]
    assert 8.0 < made[0].t < 8.0 + 3.0
    goal = FAILURE.mission.goal
    pts = {"r1": (0.3, 0.0), "r3": (-0.15, -0.26)}
    for r, (px, py) in pts.items():  # the others reach their goal points
        c, s = np.cos(goal[2]), np.sin(goal[2])
        target = (goal[0] + c * px - s * py, goal[1] + s * px + c * py)
        assert np.hypot(run.final_poses[r].x - target[0], run.final_poses[r].y - target[1]) < 0.02


def test_a_robot_slowed_to_half_speed_bends_the_structure_but_is_not_declared_failed():
    run = failure_run("drop", "slow", 0.5, 0.0, seconds=40.0)
    assert all(v == [] for v in run.decisions.values())
    assert float(run.deviations_m.max()) < 0.03


def test_after_a_transient_stall_under_hold_the_fleet_resumes_and_reaches_the_goal():
    hold = failure_run("hold", "stall", 0.0, 2.0, stop_at_goal=True)  # (the run ends at the goal)
    assert hold.t_goal_s is not None


def test_after_a_transient_stall_with_rejoin_the_robot_is_taken_back_and_the_fleet_reaches_the_goal():
    rejoin = failure_run("rejoin", "stall", 0.0, 4.0)
    kinds = [(d.robot, d.kind) for d in rejoin.decisions["r3"]]
    assert kinds == [("r2", "fail"), ("r2", "drop"), ("r2", "rejoin")]
    assert all(v == rejoin.decisions["r3"] for v in rejoin.decisions.values())
    assert rejoin.t_goal_s is not None


def test_a_robot_with_a_dead_wheel_is_declared_failed_and_with_hold_the_structure_waits_in_formation():
    hold = failure_run("hold", "wheel", 0.0, 0.0, seconds=30.0)
    made = hold.decisions["r1"]
    assert all(v == made for v in hold.decisions.values())
    assert [(d.robot, d.kind) for d in made][:1] == [("r2", "fail")]
    assert 8.0 < made[0].t < 8.0 + 3.0
    i_fault = int(8.0 * FAILURE.tracker.rate_hz)
    assert float(hold.deviations_m[i_fault:].max()) < 0.03      # bounded: nobody is left behind
    end, before_end = hold.trace[-1][1], hold.trace[-30][1]
    assert np.hypot(end.x - before_end.x, end.y - before_end.y) < 0.005   # the structure waits
    assert hold.t_goal_s is None


def test_under_hold_the_healthy_robots_a_failed_robot_bends_are_judged_without_it():
    mission = E2E.mission
    # r1 and r3 exactly on a structure at the origin; r2 8 cm off its point
    poses = {"r1": (0.3, 0.0, 0.0), "r2": (-0.15 - 0.08, 0.26, 0.0), "r3": (-0.15, -0.26, 0.0)}
    plain = structure(mission, poses)
    apart = structure(mission, poses, judged_apart=("r2",))
    # what the robots follow is unchanged: r2 still bends the structure they follow
    assert (apart.fit_pose, apart.goal_pose) == (plain.fit_pose, plain.goal_pose)
    assert np.array_equal(apart.points_next, plain.points_next)
    assert plain.deviations_m[0] > 0.01 and plain.deviations_m[2] > 0.01  # bent by r2
    # judged on the structure fitted to r1 and r3, the healthy robots are on their points
    assert apart.deviations_m[0] < 1e-9 and apart.deviations_m[2] < 1e-9
    assert apart.deviations_m[1] == pytest.approx(0.08, abs=1e-9)


def test_with_one_robot_left_to_judge_by_the_deviations_stay_those_of_the_fit_followed():
    mission = E2E.mission
    poses = {"r1": (0.3, 0.0, 0.0), "r2": (-0.23, 0.26, 0.0), "r3": (-0.15, -0.30, 0.0)}
    plain = structure(mission, poses)
    apart = structure(mission, poses, judged_apart=("r2", "r3"))
    assert np.array_equal(apart.deviations_m, plain.deviations_m)


def test_under_hold_a_stopped_robot_never_gets_a_healthy_robot_flagged():
    run = failure_run("hold", "stop", 0.0, 0.0, seconds=60.0)
    made = run.decisions["r1"]
    print("hold, r2 stopped, 60 s:", [(d.robot, d.kind, round(d.t, 2)) for d in made])
    assert all(v == made for v in run.decisions.values())
    assert [(d.robot, d.kind) for d in made][:1] == [("r2", "fail")]
    assert not [d for d in made if d.robot != "r2"]


# --- issue 13: the issue's conditions (bench/conditions.py): sigma 2 mm / 0.01 rad, 30 Hz,
# commands one frame late, wheel gains within +-4%, a 2.5 m leg at 0.1 m/s; fixed seeds, counted clock


@functools.cache
def issue_run(seed, controller=None, fault=None, mode="hold", seconds=40.0, stop_at_goal=True, turn=False):
    """The issue's conditions for ``seed``; r2's ``fault`` at 8 s (one run per arguments: cached)."""
    from bench.conditions import issue_scenario

    sc = issue_scenario(seed, turn=turn)
    sc = dataclasses.replace(sc, mission=dataclasses.replace(sc.mission, on_failure=mode),
                             faults=(FaultEvent("r2", 8.0, *fault),) if fault else ())
    return sc, run_offline(sc, seconds, controller=controller, seed=seed, stop_at_goal=stop_at_goal)


@pytest.mark.parametrize("seed", [1, 2])
def test_the_default_controller_holds_the_triangle_within_a_millimetre_under_noise_and_wheel_mismatch(seed):
    from bench.conditions import ideal_time_s
    from bench.precision import command_smoothness

    sc, run = issue_run(seed, controller=DEFAULT_CONTROLLER, seconds=50.0)  # (it stops at the goal)
    ts = np.array([t for t, _ in run.trace])
    mean_cm, settled_max_cm = 100 * run.deviations_m.mean(), 100 * run.deviations_m[ts >= 3.0].max()
    jitter, _ = command_smoothness(run, 1 / 30)
    print(f"seed {seed}: mean {mean_cm:.3f} cm, max after 3 s {settled_max_cm:.3f} cm, "
          f"command change {jitter:.4f} m/s per frame, goal {run.t_goal_s}")
    assert mean_cm <= 0.07 and settled_max_cm <= 0.2
    assert jitter <= 0.005
    assert run.t_goal_s is not None and run.t_goal_s <= 1.1 * ideal_time_s(sc)


def test_under_5_mm_of_tracker_noise_the_default_controller_keeps_the_triangle_within_2_mm_on_average():
    """sigma 5 mm (a camera tracker's, say): the wheel-gain boost (issue 30) reads the offset's running mean, so the
    noise does not drive the gains about. With the boost on each frame's offset (gain_boost_mean_ratio 1, as from
    2026-12-04 to 12-07) seed 1 had 0.385 cm mean, 1.275 cm after 3 s, the goal at 32.1 s; now 0.123 / 0.350 cm,
    28.4 s (docs/benchmarks.md section 4)."""
    from bench.conditions import ideal_time_s, issue_scenario

    sc = issue_scenario(1, noise_xy_m=0.005)
    run = run_offline(sc, 50.0, seed=1)
    ts = np.array([t for t, _ in run.trace])
    mean_cm, settled_max_cm = 100 * run.deviations_m.mean(), 100 * run.deviations_m[ts >= 3.0].max()
    print(f"sigma 5 mm, seed 1: mean {mean_cm:.3f} cm, max after 3 s {settled_max_cm:.3f} cm, goal {run.t_goal_s}")
    assert mean_cm <= 0.2 and settled_max_cm <= 0.6
    assert run.t_goal_s is not None and run.t_goal_s <= 1.2 * ideal_time_s(sc)


@pytest.mark.parametrize("name", sorted(CONTROLLERS))
def test_every_controller_reaches_the_goal_under_the_issues_conditions(name):
    sc, run = issue_run(1, controller=name, seconds=50.0)
    assert run.t_goal_s is not None, name


def test_under_hold_a_stopped_robot_halts_the_structure_with_every_robot_within_2_5_cm():
    from bench.faults import formation_errors

    sc, run = issue_run(2, fault=("stop", 0.0, 0.0), seconds=30.0, stop_at_goal=False)
    err = formation_errors(run, sc.mission)
    ts = np.array([t for t, _ in run.trace])
    assert err[ts >= 8.0].max() < 0.025
    # halted: the fit moves only with the noise the robots still correct; each 2 s window from 15 s on
    # (its median, and its worst). One window (the last, as this asserted before) is a sample of that
    # noise: 3 of seeds 1-10 exceed 2 mm there with either wheel limiter, in 16-19% of all windows
    xy = np.array([(p.x, p.y) for _, p in run.trace])
    moved = np.hypot(*(xy[60:] - xy[:-60]).T)[ts[60:] >= 15.0]
    assert np.median(moved) < 0.002 and moved.max() < 0.006
    made = run.decisions["r1"]
    assert all(v == made for v in run.decisions.values())           # the same frame in every agent
    assert {d.robot for d in made} == {"r2"} and made[0].kind == "fail"


def test_a_robot_slowed_to_half_stays_within_1_cm_is_not_flagged_and_after_recovery_the_fleet_reaches_the_goal():
    from bench.faults import formation_errors

    sc, run = issue_run(1, fault=("slow", 0.5, 8.0), seconds=45.0)
    err = formation_errors(run, sc.mission)
    print(f"slowed to 50% for 8 s: max formation error {100 * err.max():.2f} cm, goal {run.t_goal_s}")
    assert err[30:].max() < 0.01                                     # from 1 s on (the start placement)
    assert all(v == [] for v in run.decisions.values())
    assert run.t_goal_s is not None


# issue 30: an independent fleet (these conditions) measured a robot slowed to 50% bending the structure by
# 1.05 cm. Over seeds 1-40, each robot slowed for good at 3, 8, 13 and 18 s, the worst four were 1.03, 1.00,
# 0.98 and 0.98 cm (below), before the wheel-gain estimator adapted faster for a robot off its point
# (vsfleet.control.Precision, gain_boost_*): the gain estimate caught up too slowly. (seed, robot slowed, at [s],
# for [s]; 0 = for good.) Not yet within 1 cm: a robot slowed for 8 s that comes back to speed while its gains
# are estimated at half (up to 1.25 cm, was 1.31 cm; docs/benchmarks.md, faults).
SLOWED_WORST = [(5, "r3", 3.0, 0.0), (6, "r3", 3.0, 0.0), (25, "r1", 8.0, 0.0), (32, "r3", 18.0, 0.0)]


def faulted_run(seed, robot, at_s, kind, factor, for_s, seconds):
    """The issue's conditions for ``seed``, ``robot`` faulted at at_s; (formation error, times) from the fault on."""
    from bench.conditions import issue_scenario
    from bench.faults import formation_errors

    sc = issue_scenario(seed)
    sc = dataclasses.replace(sc, faults=(FaultEvent(robot, at_s, kind, factor, for_s),))
    run = run_offline(sc, seconds, seed=seed, stop_at_goal=False)
    err, ts = formation_errors(run, sc.mission), np.array([t for t, _ in run.trace])
    return err[ts >= at_s], run


@pytest.mark.parametrize("seed, robot, at_s, for_s", SLOWED_WORST)
def test_a_robot_slowed_to_half_bends_the_structure_by_at_most_1_cm_on_the_worst_seeds_found(seed, robot, at_s, for_s):
    # to 4 s after the slowing, or after the robot is back to speed (the worst comes within 0.7 s of either)
    err, run = faulted_run(seed, robot, at_s, "slow", 0.5, for_s, at_s + for_s + 4.0)
    print(f"seed {seed}, {robot} slowed at {at_s} s for {for_s or 'good'}: worst {100 * err.max():.3f} cm")
    assert err.max() <= 0.010
    assert all(v == [] for v in run.decisions.values())             # nobody flagged


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_stopped_robot_under_hold_bends_the_structure_by_at_most_1_5_cm(seed):
    err, run = faulted_run(seed, "r2", 8.0, "stop", 0.0, 0.0, 16.0)   # the worst comes within 1 s
    print(f"seed {seed}, r2 stopped at 8 s: worst {100 * err.max():.3f} cm")
    assert err.max() <= 0.015


@pytest.mark.parametrize("mode", ["drop", "rejoin"])
def test_a_stopped_robot_is_dropped_by_every_agent_on_the_same_frame_though_the_structure_waited_for_it(mode):
    sc, run = issue_run(3, fault=("stop", 0.0, 0.0), mode=mode, seconds=14.0, stop_at_goal=False)
    made = run.decisions["r1"]
    assert all(v == made for v in run.decisions.values())
    assert [(d.robot, d.kind) for d in made] == [("r2", "fail"), ("r2", "drop")]
    assert 8.0 < made[0].t < 8.0 + 3.0
