"""The leader-follower (l-psi) baseline of bench/leader_follower.py behaves as the textbook says."""

import dataclasses
import math
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parent.parent
sys.path.insert(0, str(ROOT))  # bench/ is not an installed package

from bench.leader_follower import (  # noqa: E402
    BROKEN_M,
    LFGains,
    fault_cases,
    lpsi_command,
    lpsi_measure,
    run_leader_follower,
    slot_for,
)
from vsfleet.zglue.scenario_file import load_scenario  # noqa: E402
from vsfleet.geometry import Pose2  # noqa: E402
from vsfleet.kinematics import integrate_arc, wheels_from_twist  # noqa: E402

TRIANGLE = load_scenario(ROOT / "scenarios" / "paper-triangle.toml")
D_M = 0.05


def _drive(pose: Pose2, v: float, w: float, dt: float) -> Pose2:
    vl, vr = wheels_from_twist(v, w, 0.12)
    return integrate_arc(pose, vl, vr, dt, 0.12)


def test_a_follower_on_its_slot_with_the_leaders_heading_measures_the_slot():
    offset = (-0.45, 0.26)
    l_d, psi_d = slot_for(offset, D_M)
    leader = Pose2(1.0, -2.0, 0.7)
    c, s = math.cos(leader.th), math.sin(leader.th)
    follower = Pose2(leader.x + c * offset[0] - s * offset[1], leader.y + s * offset[0] + c * offset[1], leader.th)
    l, psi, gamma = lpsi_measure(leader, follower, D_M)
    assert l == pytest.approx(l_d, abs=1e-12)
    assert psi == pytest.approx(psi_d, abs=1e-12)


@pytest.mark.parametrize("follower", [Pose2(-0.2, 0.5, 0.0), Pose2(-0.6, -0.1, 2.5), Pose2(0.3, 0.3, -1.0)])
def test_the_law_sets_the_rates_of_l_and_psi_to_the_chosen_first_order_dynamics(follower):
    leader, twist = Pose2(0.0, 0.0, 0.4), (0.08, 0.2)
    l_d, psi_d, a_l, a_psi = 0.5, 2.6, 1.5, 0.7
    v, w = lpsi_command(leader, twist, follower, l_d, psi_d, D_M, a_l, a_psi)
    h = 1e-6
    l0, psi0, _ = lpsi_measure(leader, follower, D_M)
    l1, psi1, _ = lpsi_measure(_drive(leader, *twist, h), _drive(follower, v, w, h), D_M)
    assert (l1 - l0) / h == pytest.approx(a_l * (l_d - l0), abs=1e-4)
    assert math.remainder(psi1 - psi0, 2 * math.pi) / h == pytest.approx(a_psi * (psi_d - psi0), abs=1e-4)


def test_a_follower_converges_to_its_slot_behind_a_turning_leader():
    leader, follower = Pose2(0.0, 0.0, 0.0), Pose2(-1.0, 0.8, 1.0)
    l_d, psi_d = slot_for((-0.45, -0.26), D_M)
    dt = 1 / 30
    for _ in range(30 * 20):
        v, w = lpsi_command(leader, (0.08, 0.1), follower, l_d, psi_d, D_M, 1.0, 1.0)
        leader, follower = _drive(leader, 0.08, 0.1, dt), _drive(follower, v, w, dt)
    l, psi, _ = lpsi_measure(leader, follower, D_M)
    assert l == pytest.approx(l_d, abs=1e-3)
    assert psi == pytest.approx(psi_d, abs=1e-3)


def test_with_no_fault_the_formation_reaches_the_goal_in_shape():
    run = run_leader_follower(TRIANGLE, 45.0, seed=1)
    assert float(run.errors_m.max()) < 0.03
    leader_goal = Pose2(*TRIANGLE.mission.goal).apply([TRIANGLE.mission.spec("r1").p])[0]
    assert math.hypot(run.final_xy["r1"][0] - leader_goal[0], run.final_xy["r1"][1] - leader_goal[1]) < 0.01


def test_a_stopped_follower_is_left_behind_and_the_formation_breaks():
    case = fault_cases("r1", "r2", 8.0)["follower r2 stopped"]
    run = run_leader_follower(dataclasses.replace(TRIANGLE, faults=case), 45.0, gains=LFGains(), seed=1)
    assert float(run.errors_m[: 7 * 30].max()) < 0.03  # in shape before the fault
    assert float(run.errors_m[-1].max()) > BROKEN_M
