"""simfleet physics and the simulated tracker, without transport (counted clocks)."""

import math

import numpy as np
import pytest

from vsfleet.simfleet.main import Fleet
from vsfleet.simfleet.physics import Fault, RobotState, step_robot
from vsfleet.tracker.sim import SimTracker
from vsfleet.geometry import Pose2
from vsfleet.scenario import SimRobot, TrackerParams
from vsfleet.wire import CmdMsg, FaultMsg, Keys, TruthMsg, encode
from vsfleet.zglue.scenario_file import load_scenario
from pathlib import Path

ROBOT = SimRobot("r1", (0.0, 0.0, 0.0), wheel_base=0.1, wheel_speed_max=0.3, wheel_accel_max=1.0,
                 gain=(1.0, 0.9))
DT = 0.005


def drive(cmd, steps, fault=Fault(), fresh=True, state=None):
    s = state or RobotState(Pose2(0, 0, 0))
    for k in range(steps):
        s = step_robot(s, ROBOT, cmd[0], cmd[1], fresh, fault, k * DT, DT)
    return s


def test_wheels_ramp_at_the_acceleration_limit_and_apply_the_gain_mismatch():
    s = drive((0.2, 0.2), 1)
    assert (s.vl, s.vr) == pytest.approx((1.0 * DT, 1.0 * DT))
    s = drive((0.2, 0.2), 200)
    assert (s.vl, s.vr) == pytest.approx((0.2, 0.18))  # right wheel 10% weak
    assert s.pose.th > 0.0 or s.pose.th < 0.0  # mismatch curves the path


def test_wheel_speeds_are_clipped_to_the_speed_limit():
    s = drive((5.0, -5.0), 400)
    assert (s.vl, s.vr) == pytest.approx((0.3, -0.3))


def test_a_stale_command_brakes_the_robot_to_rest():
    moving = drive((0.2, 0.2), 200)
    s = drive((0.2, 0.2), 200, fresh=False, state=moving)
    assert (s.vl, s.vr) == (0.0, 0.0)


@pytest.mark.parametrize("fault, expect", [
    (Fault("stop", 0.0), (0.0, 0.0)),
    (Fault("stall", 0.0, until_t=10.0), (0.0, 0.0)),
    (Fault("slow", 0.5), (0.1, 0.09)),
    (Fault("wheel", 0.0), (0.0, 0.18)),
    (Fault("none", 0.0), (0.2, 0.18)),
])
def test_each_fault_kind_changes_the_applied_wheel_speeds(fault, expect):
    s = drive((0.2, 0.2), 400, fault=fault)
    assert (s.vl, s.vr) == pytest.approx(expect)


def test_a_stall_ends_after_its_duration():
    s = drive((0.2, 0.2), 400, fault=Fault("stall", 0.0, until_t=1.0))  # 400 steps = 2 s
    assert (s.vl, s.vr) == pytest.approx((0.2, 0.18))


def test_the_fleet_obeys_ttl_faults_and_rejects_bad_messages():
    sc = load_scenario(Path(__file__).parent / "data" / "e2e-triangle.toml")
    keys = Keys(sc.fleet)
    fleet = Fleet(sc, keys, t0=1000.0)
    fleet.on_cmd(keys.cmd("r1"), encode(CmdMsg(1000.0, 1, 0.2, 0.2, 0.3)), now=1000.0)
    for _ in range(40):  # 0.2 s < ttl
        fleet.step()
    assert fleet.states["r1"].vl > 0.1
    for _ in range(80):  # ttl (0.3 s after arrival), then braking at 0.8 m/s^2 (0.25 s)
        fleet.step()
    assert fleet.states["r1"].vl == 0.0
    # an older command never replaces a newer one
    fleet.on_cmd(keys.cmd("r2"), encode(CmdMsg(1000.5, 9, 0.1, 0.1, 5.0)), now=fleet.t)
    fleet.on_cmd(keys.cmd("r2"), encode(CmdMsg(1000.4, 8, -0.1, -0.1, 5.0)), now=fleet.t)
    assert fleet.cmds["r2"].seq == 9
    # a fault on the key space stops the robot although commands keep coming
    fleet.on_fault(keys.fault("r2"), encode(FaultMsg("stop", 0.0, 0.0)), now=fleet.t)
    for _ in range(10):
        fleet.step()
    assert (fleet.states["r2"].vl, fleet.states["r2"].vr) == (0.0, 0.0)
    before = fleet.rejections.count
    fleet.on_cmd(keys.cmd("r1"), b"\x93garbage", now=fleet.t)
    fleet.on_cmd(keys.cmd("nobody"), encode(CmdMsg(1.0, 1, 0.1, 0.1, 1.0)), now=fleet.t)
    fleet.on_fault(keys.fault("r1"), encode(FaultMsg("stop", 0.0, 0.0))[:-2], now=fleet.t)
    assert fleet.rejections.count == before + 3
    assert {m.rejected for m in fleet.truth().values()} == {before + 3}  # told on truth/<robot>


def test_a_scenario_fault_timeline_fires_at_its_time():
    sc = load_scenario(Path(__file__).parent.parent / "scenarios" / "paper-failure.toml")
    fleet = Fleet(sc, Keys(sc.fleet), t0=0.0)
    steps_to_fault = int(sc.faults[0].at_s * sc.sim.rate_hz)
    for _ in range(steps_to_fault - 1):
        fleet.step()
    assert fleet.faults["r2"].kind == "none"
    fleet.step()
    fleet.step()
    assert fleet.faults["r2"].kind == "stop"


def test_the_tracker_sends_one_frame_of_every_robot_adds_noise_and_drops_frames():
    keys = Keys("demo")
    tr = SimTracker(TrackerParams(noise_xy_m=0.01, noise_th_rad=0.02, drop_prob=0.0), src="cam", seed=3)
    for r, x in (("r1", 1.0), ("r2", 2.0)):
        tr.on_truth(keys, keys.truth(r), encode(TruthMsg(100.0, x, 0.0, 3.1, 0.0, 0.0)))
    frames = [tr.frame(now=100.01) for _ in range(400)]
    assert all(sorted(f.poses) == ["r1", "r2"] for f in frames)
    assert [f.seq for f in frames] == list(range(1, 401))
    xs = np.array([f.poses["r1"][0] for f in frames])
    assert abs(xs.mean() - 1.0) < 0.003 and 0.008 < xs.std() < 0.012
    assert all(-math.pi <= f.poses["r1"][2] < math.pi and f.t == 100.0 and f.src == "cam" for f in frames)
    # stale truth is not observed
    assert tr.frame(now=100.5) is None
    dropper = SimTracker(TrackerParams(drop_prob=0.3), seed=4)
    dropper.on_truth(keys, keys.truth("r1"), encode(TruthMsg(100.0, 0.0, 0.0, 0.0, 0.0, 0.0)))
    empty = sum(1 for _ in range(1000) if not dropper.frame(now=100.0))
    assert 250 < empty < 350


def truth_of(fleet, robot):
    """The truth message simfleet would publish now, through the codec."""
    from vsfleet.wire import decode_truth
    return decode_truth(encode(fleet.truth()[robot]))


def test_truth_says_why_the_wheels_move_and_since_which_step():
    sc = load_scenario(Path(__file__).parent / "data" / "e2e-triangle.toml")
    keys = Keys(sc.fleet)
    fleet = Fleet(sc, keys, t0=1000.0)
    step_t = [fleet.t0 + k * fleet.dt_s for k in range(400)]  # sim time of step k
    m = truth_of(fleet, "r1")
    assert (m.why, m.why_t, m.expired_t) == ("idle", 1000.0, 0.0)
    # ttl 0.2975 s: fresh on steps 0..59 (59 * 5 ms = 0.295 s), expired from step 60 (0.300 s)
    fleet.on_cmd(keys.cmd("r1"), encode(CmdMsg(1000.0, 1, 0.2, 0.2, 0.2975)), now=1000.0)
    fleet.step()
    m = truth_of(fleet, "r1")
    assert (m.why, m.why_t) == ("commanded", step_t[0]) and m.vl > 0.0
    assert truth_of(fleet, "r2").why == "idle"
    for _ in range(59):
        fleet.step()
    assert truth_of(fleet, "r1").why == "commanded" and fleet.k == 60
    fleet.step()  # step 60
    m = truth_of(fleet, "r1")
    assert (m.why, m.why_t, m.expired_t) == ("expired", step_t[60], step_t[60])
    while fleet.states["r1"].vl > 0.0:  # braking to rest at the wheel acceleration limit
        fleet.step()
    assert truth_of(fleet, "r1").why_t == step_t[60]  # still the same expiry
    # a fresh command: commanded again from the next step; a fault over it says fault
    fleet.on_cmd(keys.cmd("r1"), encode(CmdMsg(1000.5, 2, 0.2, 0.2, 5.0)), now=fleet.t)
    k_cmd = fleet.k
    fleet.step()
    m = truth_of(fleet, "r1")
    assert (m.why, m.why_t, m.expired_t) == ("commanded", step_t[k_cmd], step_t[60])  # the expiry stays told
    fleet.on_fault(keys.fault("r1"), encode(FaultMsg("slow", 0.5, 0.0)), now=fleet.t)
    k_fault = fleet.k
    fleet.step()
    assert (truth_of(fleet, "r1").why, truth_of(fleet, "r1").why_t) == ("fault", step_t[k_fault])
    fleet.on_fault(keys.fault("r1"), encode(FaultMsg("none", 1.0, 0.0)), now=fleet.t)
    fleet.step()
    assert truth_of(fleet, "r1").why == "commanded"
