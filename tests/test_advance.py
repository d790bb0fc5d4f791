"""Advancing the structure: envelope respected, goal reached without overshoot."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vsfleet.advance import (
    GoalError,
    GoalPath,
    GoalPose,
    GoalTwist,
    StructureLimits,
    Twist2,
    _ln,
    advance_structure,
    compliance_scale,
    structure_limits,
    structure_points,
)
from vsfleet.envelope import Envelope
from vsfleet.errors import ShapeError
from vsfleet.geometry import Pose2, angle_diff

TRIANGLE = np.array([[0.3, 0.0], [-0.15, 0.26], [-0.15, -0.26]])
ENV = [Envelope(0.1, 0.3, 1.0), Envelope(0.12, 0.2, 0.8), Envelope(0.1, 0.3, 0.5)]
LIMITS = StructureLimits(speed_max_m_s=0.5, turn_rate_max_rad_s=1.0)
DT = 1.0 / 30.0


def wheel_needs(prev: Twist2, nxt: Twist2, pose: Pose2):
    """Per robot: wheel speed bound and wheel speed change implied by riding the structure."""
    rho = structure_points(Pose2(0, 0, pose.th), TRIANGLE)
    out = []
    for i, e in enumerate(ENV):
        def demand(vx, vy, w):
            ux, uy = vx - w * rho[i, 1], vy + w * rho[i, 0]
            return math.hypot(ux, uy) + abs(w) * e.wheel_base_m / 2

        speed = demand(nxt.vx_m_s, nxt.vy_m_s, nxt.w_rad_s)
        change = demand(nxt.vx_m_s - prev.vx_m_s, nxt.vy_m_s - prev.vy_m_s, nxt.w_rad_s - prev.w_rad_s)
        out.append((speed, change, e))
    return out


finite = st.floats(-5, 5, allow_nan=False)


@settings(max_examples=150, deadline=None)
@given(x=finite, y=finite, th=st.floats(-4, 4), gx=finite, gy=finite, gth=st.floats(-4, 4),
       pvx=st.floats(-0.005, 0.005), pvy=st.floats(-0.005, 0.005), pw=st.floats(-0.01, 0.01))
def test_the_advance_never_asks_a_robot_for_more_than_its_envelope(x, y, th, gx, gy, gth, pvx, pvy, pw):
    pose = Pose2(x, y, th)
    prev = Twist2(pvx, pvy, pw)
    res = advance_structure(pose, GoalPose(Pose2(gx, gy, gth)), DT, LIMITS, TRIANGLE, ENV, prev)
    assert 0.0 <= res.scale <= 1.0
    for speed, change, e in wheel_needs(prev, res.twist, pose):
        assert speed <= e.wheel_speed_max_m_s * (1 + 1e-9)
        # the previous twist is small enough (<= 0.011 m/s at any wheel) that braking from it
        # is always feasible, so the acceleration bound must hold exactly
        assert change <= e.wheel_accel_max_m_s2 * DT * (1 + 1e-9) + 1e-12


def run_to_goal(goal, start: Pose2, steps: int):
    pose, twist = start, Twist2()
    trace = [pose]
    for _ in range(steps):
        res = advance_structure(pose, goal, DT, LIMITS, TRIANGLE, ENV, twist)
        pose, twist = res.pose, res.twist
        trace.append(pose)
    return trace, res


def test_the_structure_stops_at_a_pose_goal_without_overshoot_or_oscillation():
    goal = Pose2(2.0, 1.0, 1.2)
    trace, res = run_to_goal(GoalPose(goal), Pose2(0, 0, 0), 1200)
    dists = [math.hypot(goal.x - p.x, goal.y - p.y) for p in trace]
    angs = [abs(angle_diff(goal.th, p.th)) for p in trace]
    # it stops inside the arrival tolerance (set above tracker noise, see StructureLimits)
    assert dists[-1] <= LIMITS.position_tolerance_m and angs[-1] <= LIMITS.heading_tolerance_rad
    assert res.at_goal
    # monotone approach: distance and heading error never grow (no overshoot, no oscillation)
    assert all(b <= a + 1e-12 for a, b in zip(dists, dists[1:]))
    assert all(b <= a + 1e-12 for a, b in zip(angs, angs[1:]))
    # once there it stays there
    assert trace[-1] == trace[-2]


def test_the_structure_follows_a_waypoint_path_and_stops_at_its_end():
    wps = (Pose2(0, 0, 0), Pose2(1.0, 0.0, 0.0), Pose2(1.0, 1.0, math.pi / 2))
    trace, res = run_to_goal(GoalPath(wps), Pose2(0, 0, 0), 1500)
    end = wps[-1]
    assert math.hypot(trace[-1].x - end.x, trace[-1].y - end.y) <= LIMITS.position_tolerance_m
    assert res.at_goal
    # it passes near the corner waypoint (within the lookahead) rather than cutting straight across
    d_corner = min(math.hypot(p.x - 1.0, p.y) for p in trace)
    assert d_corner < LIMITS.path_lookahead_m


def test_a_constant_twist_goal_moves_at_that_twist_once_accelerated():
    goal = GoalTwist(0.1, 0.0, 0.0)
    trace, res = run_to_goal(goal, Pose2(0, 0, math.pi / 2), 120)
    assert res.scale == pytest.approx(1.0)
    assert res.twist.vx_m_s == pytest.approx(0.0, abs=1e-12)
    assert res.twist.vy_m_s == pytest.approx(0.1)


def test_a_slow_robot_slows_the_whole_structure():
    slow = [Envelope(0.1, 0.3, 1.0), Envelope(0.1, 0.02, 1.0), Envelope(0.1, 0.3, 1.0)]
    res = advance_structure(Pose2(0, 0, 0), GoalTwist(0.2, 0, 0), DT, LIMITS, TRIANGLE, slow,
                            Twist2(0.02, 0, 0))
    assert res.twist.vx_m_s == pytest.approx(0.02)


def test_bad_arguments_raise_typed_value_errors():
    with pytest.raises(ShapeError):
        advance_structure(Pose2(0, 0, 0), GoalTwist(0, 0, 0), DT, LIMITS, TRIANGLE, ENV[:2])
    with pytest.raises(ValueError):
        advance_structure(Pose2(0, 0, 0), GoalTwist(0, 0, 0), 0.0, LIMITS, TRIANGLE, ENV)
    with pytest.raises(GoalError):
        GoalPath(())
    with pytest.raises(ValueError):
        StructureLimits(float("nan"), 1.0)


def test_with_elapsed_time_the_advance_ramps_up_and_is_a_pure_function_of_its_inputs():
    goal = GoalPose(Pose2(2.0, 0.0, 0.0))
    a = advance_structure(Pose2(0, 0, 0), goal, DT, LIMITS, TRIANGLE, ENV, elapsed_s=0.0)
    assert a.twist == Twist2(0.0, 0.0, 0.0)
    speeds = [math.hypot(*[(r := advance_structure(Pose2(0, 0, 0), goal, DT, LIMITS, TRIANGLE, ENV,
                                                   elapsed_s=t)).twist.vx_m_s, r.twist.vy_m_s])
              for t in (0.1, 0.2, 0.4, 5.0)]
    accel = 0.5 * min(e.wheel_accel_max_m_s2 for e in ENV)
    assert speeds[0] == pytest.approx(accel * 0.1) and speeds[1] == pytest.approx(accel * 0.2)
    assert speeds == sorted(speeds) and speeds[-1] <= min(e.wheel_speed_max_m_s for e in ENV)
    again = advance_structure(Pose2(0, 0, 0), goal, DT, LIMITS, TRIANGLE, ENV, elapsed_s=0.2)
    assert again == advance_structure(Pose2(0, 0, 0), goal, DT, LIMITS, TRIANGLE, ENV, elapsed_s=0.2)


def test_robots_facing_across_their_path_slow_the_structure_but_never_stop_it():
    from vsfleet.advance import ALIGN_FLOOR

    goal = GoalTwist(0.05, 0.0, 0.0)  # along +x in the structure frame
    aligned = advance_structure(Pose2(0, 0, 0), goal, DT, LIMITS, TRIANGLE, ENV, headings_rad=[0.0, 0.0, 0.0])
    reversed_ok = advance_structure(Pose2(0, 0, 0), goal, DT, LIMITS, TRIANGLE, ENV,
                                    headings_rad=[math.pi, 0.0, None])
    across = advance_structure(Pose2(0, 0, 0), goal, DT, LIMITS, TRIANGLE, ENV,
                               headings_rad=[0.0, math.pi / 2, 0.0])
    assert aligned.twist.vx_m_s == pytest.approx(0.05)
    assert reversed_ok.twist.vx_m_s == pytest.approx(0.05)   # driving backwards is allowed
    assert across.twist.vx_m_s == pytest.approx(0.05 * ALIGN_FLOOR)  # creeps so the robot can turn


@pytest.mark.parametrize("advance", ["core", "reference"])
def test_on_a_rooms_plan_the_alignment_throttle_is_the_softer_power(advance):
    """|cos d|**ALIGN_POWER_PLAN following a plan (GoalPath synced: VS_GOAL_PLAN), **ALIGN_POWER on a mission's path."""
    from vsfleet.advance import advance_structure_reference
    from vsfleet.coreconst import ALIGN_POWER, ALIGN_POWER_PLAN

    step = advance_structure if advance == "core" else advance_structure_reference
    slow = StructureLimits(speed_max_m_s=0.05, turn_rate_max_rad_s=1.0)
    cos_d = 0.9                                    # robot 1 faces acos(0.9) off its point's velocity (+x)
    for synced, power in ((True, ALIGN_POWER_PLAN), (False, ALIGN_POWER)):
        goal = GoalPath((Pose2(2.0, 0.0, 0.0),), synced=synced)
        vx = [step(Pose2(0, 0, 0), goal, DT, slow, TRIANGLE, ENV, elapsed_s=5.0, headings_rad=h).twist.vx_m_s
              for h in ([0.0, 0.0, 0.0], [0.0, math.acos(cos_d), 0.0])]
        assert vx[0] == pytest.approx(0.05)
        assert vx[1] / vx[0] == pytest.approx(cos_d ** power, rel=1e-12), synced
    assert ALIGN_POWER_PLAN < ALIGN_POWER


def test_on_a_plan_a_robot_whose_point_moves_slower_than_the_missions_speed_holds_the_structure_back_by_that_share():
    """alignment_scale with speed_ref_m_s: a robot whose point moves at u < speed_ref holds back by u / speed_ref of
    its factor's shortfall (1 - (1 - k) u / speed_ref); at speed_ref or faster, and without it, by all of it."""
    from vsfleet.advance import ALIGN_FLOOR, Twist2, alignment_scale

    rho = np.array([[0.2, 0.0], [-0.1, 0.17], [-0.1, -0.17]])
    across = [0.0, math.pi / 2, 0.0]          # robot 1 faces across its point's velocity (+x): factor ALIGN_FLOOR
    half = Twist2(0.05, 0.0, 0.0)
    assert alignment_scale(half, rho, across, power=4) == ALIGN_FLOOR
    assert alignment_scale(half, rho, across, power=4, speed_ref_m_s=0.05) == ALIGN_FLOOR
    assert alignment_scale(half, rho, across, power=4, speed_ref_m_s=0.1) == \
        pytest.approx(1.0 - (1.0 - ALIGN_FLOOR) * 0.5)
    assert alignment_scale(Twist2(0.0, 0.0, 0.0), rho, across, power=4, speed_ref_m_s=0.1) == 1.0   # no motion
    # turning about a point 1 cm from robot 0's: its point moves at 3 mm/s, across its heading; the others face
    # their points' motion. Without the share it holds the structure at the floor; with it, hardly at all
    turn = Twist2(0.0, 0.0, 0.3)
    about = rho - rho[0] + np.array([0.01, 0.0])
    faced = [math.atan2(about[i, 0], -about[i, 1]) for i in range(3)]
    heads = [faced[0] + math.pi / 2] + faced[1:]
    assert alignment_scale(turn, about, heads, power=4) == pytest.approx(ALIGN_FLOOR)
    assert alignment_scale(turn, about, heads, power=4, speed_ref_m_s=0.1) == \
        pytest.approx(1.0 - (1.0 - ALIGN_FLOOR) * 0.03)


@pytest.mark.parametrize("advance", ["core", "reference"])
def test_on_a_plan_the_alignment_share_follows_the_points_speed_and_off_a_plan_it_does_not(advance):
    """Through the advance: early in the ramp the structure's desired speed u is below the mission's; a robot facing
    acos(0.9) off its point's velocity then holds a plan back by 1 - (1 - 0.9**4) u / speed_max, a mission's own
    path by the whole 0.9**8 (as before)."""
    from vsfleet.advance import advance_structure_reference
    from vsfleet.coreconst import ALIGN_POWER, ALIGN_POWER_PLAN

    step = advance_structure if advance == "core" else advance_structure_reference
    lim = StructureLimits(speed_max_m_s=0.1, turn_rate_max_rad_s=1.0)
    cos_d = 0.9
    for synced in (True, False):
        goal = GoalPath((Pose2(2.0, 0.0, 0.0),), synced=synced)
        vx = [step(Pose2(0, 0, 0), goal, DT, lim, TRIANGLE, ENV, elapsed_s=0.2, headings_rad=h).twist.vx_m_s
              for h in ([0.0, 0.0, 0.0], [0.0, math.acos(cos_d), 0.0])]
        u = vx[0]
        assert 0.0 < u < 0.1                      # the premise: in the ramp, below the mission's speed
        want = 1.0 - (1.0 - cos_d ** ALIGN_POWER_PLAN) * (u / 0.1) if synced else cos_d ** ALIGN_POWER
        assert vx[1] / vx[0] == pytest.approx(want, rel=1e-9), synced


# --- arrays over robots, compliance, the mission's speed ----------------------------------


def test_headings_and_deviations_are_arrays_with_nan_for_robots_not_seen():
    from vsfleet.envelope import Envelopes

    goal = GoalTwist(0.05, 0.0, 0.0)
    as_list = advance_structure(Pose2(0, 0, 0), goal, DT, LIMITS, TRIANGLE, ENV, headings_rad=[0.0, math.pi / 2, None])
    as_array = advance_structure(Pose2(0, 0, 0), goal, DT, LIMITS, TRIANGLE, Envelopes.of(ENV),
                                 headings_rad=np.array([0.0, math.pi / 2, np.nan]),
                                 deviations_m=np.array([0.001, np.nan, 0.002]))
    assert as_list == as_array
    with pytest.raises(ShapeError):
        advance_structure(Pose2(0, 0, 0), goal, DT, LIMITS, TRIANGLE, ENV, deviations_m=np.zeros(2))


def test_the_structure_slows_as_a_robot_falls_behind_and_halts_before_it_is_left_behind():
    goal = GoalTwist(0.05, 0.0, 0.0)
    full, stop = LIMITS.comply_full_m, LIMITS.comply_stop_m
    speeds = []
    for worst in (0.0, full, 0.5 * (full + stop), stop, 0.05):
        r = advance_structure(Pose2(0, 0, 0), goal, DT, LIMITS, TRIANGLE, ENV,
                              deviations_m=np.array([0.001, worst, np.nan]))
        speeds.append(r.twist.vx_m_s)
    assert speeds[0] == speeds[1] == pytest.approx(0.05)
    assert speeds[2] == pytest.approx(0.025)
    assert speeds[3] == speeds[4] == 0.0
    with pytest.raises(ValueError):
        StructureLimits(0.1, 0.3, comply_full_m=0.01, comply_stop_m=0.005)


def test_the_compliance_band_of_three_robots_or_fewer_is_the_default_and_widens_with_the_fleet():
    for n in (1, 2, 3):
        assert structure_limits(0.1, 0.5, n) == StructureLimits(0.1, 0.5)
    prev = StructureLimits(0.1, 0.5)
    for n in (4, 5, 10, 30, 100):
        lim = structure_limits(0.1, 0.5, n)
        # the band moves out by 2 mm (sqrt(2 ln n) - sqrt(2 ln 3)), as wide as before, and further for more robots
        shift = 0.002 * (math.sqrt(2 * math.log(n)) - math.sqrt(2 * math.log(3)))
        assert lim.comply_full_m - 0.006 == pytest.approx(shift, abs=1e-10)   # _ln: within 1e-8 of libm's log
        assert lim.comply_stop_m - lim.comply_full_m == pytest.approx(0.006, abs=1e-15)
        assert lim.comply_full_m > prev.comply_full_m
        assert (lim.speed_max_m_s, lim.turn_rate_max_rad_s) == (0.1, 0.5)
        prev = lim
    assert structure_limits(0.1, 0.5, 30).comply_full_m == pytest.approx(0.00825, abs=1e-5)
    for x in (1.0, 2.0, 3.0, 4.0, 30.0, 100.0, 1000.0):
        assert _ln(x) == pytest.approx(math.log(x), rel=1e-8, abs=1e-12)
    # the bits every host must pack (sqrt and IEEE operations alone; recorded on x86-64 on 2026-12-06): a libm log
    # in the path, or a changed order of operations, changes them
    for n, full, stop in ((4, "0x1.a12d3a5a631b8p-8", "0x1.9532431085859p-7"),
                          (30, "0x1.0e640bee30b2ap-7", "0x1.d2ffb1d184aa6p-7")):
        lim = structure_limits(0.08, 0.3, n)
        assert (lim.comply_full_m.hex(), lim.comply_stop_m.hex()) == (full, stop)


def test_the_widened_band_answers_a_lagging_robot_not_the_noise_of_a_larger_fleet():
    """30 robots on their points under 2 mm tracker noise (each deviation Rayleigh, sigma 2 mm): the 3-robot band
    slows the structure in about a third of the frames, the 30-robot band in a few; a robot 15 mm behind still
    halts it, and one 12 mm behind still slows it."""
    rng = np.random.default_rng(7)
    dev = np.hypot(*rng.normal(0.0, 0.002, (2, 5000, 30)))
    narrow, wide = StructureLimits(0.1, 0.5), structure_limits(0.1, 0.5, 30)
    slowed_narrow = np.mean([compliance_scale(d, narrow) < 1.0 for d in dev])
    slowed_wide = np.mean([compliance_scale(d, wide) < 1.0 for d in dev])
    assert slowed_narrow > 0.25 and slowed_wide < 0.05
    lag = dev[0].copy()
    lag[4] = 0.015
    assert compliance_scale(lag, wide) == 0.0
    lag[4] = 0.012
    assert 0.0 < compliance_scale(lag, wide) < 0.5


def test_every_agent_packs_the_limits_of_its_fleets_size():
    """The core's packed mission and the numpy glue's arrays carry structure_limits for the mission's robot count
    (its bits on every host: the test above)."""
    from vsfleet.coreconst import LIMIT_FIELDS
    from vsfleet.step import core_mission_of, mission_arrays
    from vsfleet.structure import MISSION_ARGS
    from vsfleet.wire import Mission, RobotSpec
    for n in (3, 12):
        robots = tuple((f"r{i:02d}", RobotSpec((0.3 * math.cos(i), 0.3 * math.sin(i)), 0.12, 0.3, 0.8))
                       for i in range(n))
        mission = Mission(1, "l2", robots, 0.08, 0.3, 0.0, goal=(1.0, 0.5, 0.0))
        want = structure_limits(0.08, 0.3, n)
        assert mission_arrays(mission).limits == want
        packed = core_mission_of(mission).core[MISSION_ARGS.index("limits")]
        assert list(packed) == [getattr(want, f) for f in LIMIT_FIELDS]


def fly(goal, limits, seconds=40.0):
    """The structure advanced from its own previous pose (robots that follow perfectly)."""
    pose, t, path = Pose2(0.0, 0.0, 0.0), 0.0, []
    while t < seconds:
        r = advance_structure(pose, goal, DT, limits, TRIANGLE, ENV, elapsed_s=t)
        pose, t = r.pose, t + DT
        path.append((t, pose, r.at_goal))
    return path


@pytest.mark.parametrize("th", [0.0, math.pi / 2], ids=["straight", "turning 90 deg"])
def test_a_2_5_m_leg_at_0_1_m_s_arrives_within_10_percent_of_the_ideal_time_without_overshoot(th):
    limits = StructureLimits(speed_max_m_s=0.1, turn_rate_max_rad_s=0.3)
    path = fly(GoalPose(Pose2(2.5, 0.0, th)), limits)
    t_arrive = next(t for t, _, at in path if at)
    assert t_arrive <= 1.1 * 2.5 / 0.1, t_arrive
    assert max(p.x for _, p, _ in path) <= 2.5 + 1e-9                 # never past the goal
    assert all(abs(p.th) <= abs(th) + 1e-9 for _, p, _ in path)       # nor past its heading
