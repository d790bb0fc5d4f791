"""simfleet's MuJoCo engine (simfleet/engine_mujoco.py) without processes: straight runs, a wheel-radius
mismatch, a pillar and a robot that stop a body (reported as contacts), faults and expiry on the
actuators, determinism, and the engine chosen through the scenario, Fleet and the offline runner.
Skipped where MuJoCo is not installed (the optional extra vsfleet[mujoco]), except what needs no engine."""

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from vsfleet.scenario import ScenarioError, SimRobot, scenario_from_dict
from vsfleet.simfleet.engine import EngineUnavailable, check_engine, make_engine
from vsfleet.simfleet.physics import Fault, FaultArrays
from vsfleet.wire import CmdMsg, FaultMsg, Keys, decode_truth, encode
from vsfleet.zglue.scenario_file import load_scenario

DT = 0.005
E2E = Path(__file__).parent / "data" / "e2e-triangle.toml"
ROBOT = SimRobot("r1", (0.0, 0.0, 0.0), wheel_base=0.12, wheel_speed_max=0.3, wheel_accel_max=0.8, gain=(1.0, 1.0))

try:
    import mujoco  # noqa: F401
    HAVE_MUJOCO = True
except ImportError:
    HAVE_MUJOCO = False
needs_mujoco = pytest.mark.skipif(not HAVE_MUJOCO, reason="mujoco is not installed (pip install 'vsfleet[mujoco]')")


def drive(engine, cmd, steps, faults=None, fresh=True, t0=0.0):
    """Step ``engine`` ``steps`` times with the same commands (n, 2); returns the poses (steps, n, 3) and
    every contact that began."""
    n = len(engine.pose)
    cmd = np.broadcast_to(np.asarray(cmd, dtype=float), (n, 2))
    arrays = FaultArrays.of(faults or [Fault()] * n)
    poses, contacts = [], []
    for k in range(steps):
        contacts += engine.step(cmd, np.full(n, fresh), arrays, t0 + k * DT)
        poses.append(engine.pose.copy())
    return np.array(poses), contacts


@needs_mujoco
def test_a_robot_commanded_straight_goes_straight_at_the_commanded_speed_after_accelerating():
    e = make_engine("mujoco", [ROBOT], [], DT)
    assert e.pose.tolist() == [[0.0, 0.0, 0.0]]  # exactly at its start, settled on the floor
    poses, contacts = drive(e, (0.2, 0.2), 600)  # 3 s; the ramp to 0.2 m/s at 0.8 m/s^2 takes 0.25 s
    speed = (poses[-1, 0, 0] - poses[200, 0, 0]) / (399 * DT)  # from 1 s on
    assert speed == pytest.approx(0.2, rel=0.01)
    assert np.abs(poses[:, 0, 1]).max() < 1e-4 and np.abs(poses[:, 0, 2]).max() < 1e-3
    assert e.wheels[0] == pytest.approx((0.2, 0.2), abs=1e-3)  # the rims, measured
    # the kinematic engine's distance within 1 %: 0.025 m of ramp, then 0.2 m/s
    assert poses[-1, 0, 0] == pytest.approx(0.025 + 0.2 * 550 * DT, rel=0.01)
    assert contacts == []


@needs_mujoco
def test_a_wheel_radius_mismatch_curves_the_robot_as_the_gains_say():
    r = dataclasses.replace(ROBOT, gain=(1.0, 0.97))  # the right wheel 3 % smaller: it turns clockwise
    e = make_engine("mujoco", [r], [], DT)
    poses, _ = drive(e, (0.2, 0.2), 600)
    rate = (poses[-1, 0, 2] - poses[200, 0, 2]) / (399 * DT)
    assert rate == pytest.approx((0.2 * 0.97 - 0.2) / r.wheel_base, rel=0.05)  # -0.05 rad/s
    assert poses[-1, 0, 1] < -0.01


@needs_mujoco
def test_a_robot_driven_into_a_pillar_stops_at_it_and_the_contact_is_reported():
    r = dataclasses.replace(ROBOT, radius=0.08)
    pillar = (0.4, 0.0, 0.05)
    e = make_engine("mujoco", [r], [pillar], DT)
    poses, contacts = drive(e, (0.2, 0.2), 500)  # 2.5 s: 0.47 m of travel, the pillar at 0.27 m
    reach = pillar[0] - pillar[2] - r.radius
    assert poses[:, 0, 0].max() < reach + 0.003  # the soft contact gives a few mm at most
    assert poses[-1, 0, 0] > reach - 0.005  # it went as far as the pillar
    assert [(c.robot, c.kind, c.other) for c in contacts] == [("r1", "obstacle", 0)]  # one contact, held
    c = contacts[0]
    assert c.x == pytest.approx(pillar[0] - pillar[2], abs=0.003) and abs(c.y) < 1e-3
    assert 1.2 < c.t < 1.6 and e.contacts == contacts
    # the kinematic engine drives through it
    k = make_engine("kinematic", [r], [pillar], DT)
    kp, kc = drive(k, (0.2, 0.2), 500)
    assert kp[-1, 0, 0] > pillar[0] + pillar[2] and kc == []


@needs_mujoco
def test_two_robots_driven_at_each_other_stop_and_one_robot_contact_is_reported():
    a = dataclasses.replace(ROBOT, robot="a", radius=0.06)
    b = dataclasses.replace(ROBOT, robot="b", radius=0.06, start=(0.5, 0.0, math.pi))
    e = make_engine("mujoco", [a, b], [], DT)
    poses, contacts = drive(e, (0.15, 0.15), 400)
    assert [(c.robot, c.kind, c.other) for c in contacts] == [("a", "robot", "b")]
    gap = np.hypot(*(poses[:, 1, :2] - poses[:, 0, :2]).T) - 0.12
    assert gap.min() > -0.004


@needs_mujoco
@pytest.mark.parametrize("fault, expect", [
    (Fault("stop", 0.0), (0.0, 0.0)),
    (Fault("stall", 0.0), (0.0, 0.0)),
    (Fault("slow", 0.5), (0.1, 0.1)),
    (Fault("wheel", 0.0), (0.0, 0.2)),
])
def test_faults_act_on_the_wheel_actuators(fault, expect):
    e = make_engine("mujoco", [ROBOT], [], DT)
    drive(e, (0.2, 0.2), 200)
    drive(e, (0.2, 0.2), 200, faults=[fault], t0=1.0)
    assert e.wheels[0] == pytest.approx(expect, abs=2e-3)
    if fault.kind in ("stop", "stall"):  # the motors cut at once: the set point, not a ramp
        assert e.setpoint.tolist() == [[0.0, 0.0]]
        before, _ = drive(e, (0.2, 0.2), 2, faults=[fault], t0=2.0)
        assert abs(before[1, 0, 0] - before[0, 0, 0]) < 1e-6  # at rest


@needs_mujoco
def test_a_stale_command_brakes_the_robot_to_rest_at_the_acceleration_limit():
    runs, engines = {}, {}
    for name in ("mujoco", "kinematic"):
        engines[name] = e = make_engine(name, [ROBOT], [], DT)
        drive(e, (0.2, 0.2), 200)
        runs[name], _ = drive(e, (0.2, 0.2), 100, fresh=False, t0=1.0)  # 0.25 s of braking, then at rest
    assert engines["mujoco"].setpoint.tolist() == [[0.0, 0.0]] and np.abs(engines["mujoco"].wheels).max() < 1e-3
    poses = runs["mujoco"]
    assert np.abs(poses[60:, 0, 0] - poses[60, 0, 0]).max() < 1e-4  # at rest after 0.3 s
    braked = poses[-1, 0, 0] - poses[0, 0, 0]
    assert braked == pytest.approx(runs["kinematic"][-1, 0, 0] - runs["kinematic"][0, 0, 0], abs=1e-3)


@needs_mujoco
def test_the_engine_is_deterministic_for_the_same_inputs():
    robots = [dataclasses.replace(ROBOT, radius=0.08, gain=(1.0, 0.98)),
              dataclasses.replace(ROBOT, robot="r2", radius=0.08, start=(0.0, 0.3, 0.1))]
    runs = []
    for _ in range(2):
        e = make_engine("mujoco", robots, [(0.35, 0.0, 0.05)], DT)
        poses, contacts = drive(e, [(0.2, 0.2), (0.25, 0.2)], 400)
        runs.append((poses.tobytes(), e.wheels.tobytes(), contacts))
    assert runs[0] == runs[1]


@needs_mujoco
def test_the_fleet_runs_the_scenarios_engine_and_counts_contacts():
    sc = load_scenario(E2E)
    doc = dataclasses.replace(sc, sim=dataclasses.replace(sc.sim, engine="mujoco"))
    keys = Keys(sc.fleet)
    from vsfleet.simfleet.main import Fleet
    fleet = Fleet(doc, keys, t0=1000.0)
    assert fleet.engine.name == "mujoco"
    assert fleet.pose == pytest.approx(np.array([r.start for r in sc.robots]), abs=1e-12)
    fleet.on_cmd(keys.cmd("r1"), encode(CmdMsg(1000.0, 1, 0.2, 0.2, 0.3)), now=1000.0)
    fleet.on_fault(keys.fault("r2"), encode(FaultMsg("stop", 0.0, 0.0)), now=1000.0)
    for _ in range(40):
        fleet.step()
    m = decode_truth(encode(fleet.truth()["r1"]))
    assert m.why == "commanded" and m.vl > 0.1 and m.x > sc.robots[0].start[0]
    for _ in range(120):  # ttl 0.3 s, then braking
        fleet.step()
    m = decode_truth(encode(fleet.truth()["r1"]))
    assert m.why == "expired" and abs(m.vl) < 1e-3
    assert Fleet(sc, keys, t0=0.0, engine="mujoco").engine.name == "mujoco"
    assert Fleet(sc, keys, t0=0.0).engine.name == "kinematic" and fleet.contacts == 0


@needs_mujoco
def test_the_offline_runner_takes_the_engine_and_the_triangle_reaches_its_goal():
    sc = load_scenario(E2E)
    run = run_offline_e2e(sc, "mujoco")
    assert run.engine == "mujoco" and run.t_goal_s is not None and run.contacts == ()
    assert run.deviations_m.mean() < 0.001  # the paper's precision: < 0.1 cm mean


def run_offline_e2e(sc, engine):
    from vsfleet.simfleet.offline import run_offline
    return run_offline(sc, 25.0, engine=engine, seed=1)


def test_the_scenario_names_its_engine_and_the_robots_bodies_and_refuses_others():
    base = {"schema": 1, "mission": {"goal": {"x": 1.0, "y": 0.0, "th": 0.0}, "speed_max": 0.1,
                                     "turn_rate_max": 0.3},
            "robots": {"a": {"p": [0.0, 0.0]}}}
    sc = scenario_from_dict(base)
    a = sc.robots[0]
    assert sc.sim.engine == "kinematic" and (a.mass, a.wheel_radius, a.friction) == (0.5, 0.02, 0.8)
    sc = scenario_from_dict({**base, "sim": {"engine": "mujoco"},
                             "defaults": {"mass": 1.2, "friction": 0.5},
                             "robots": {"a": {"p": [0.0, 0.0], "wheel_radius": 0.03}}})
    a = sc.robots[0]
    assert sc.sim.engine == "mujoco" and (a.mass, a.wheel_radius, a.friction) == (1.2, 0.03, 0.5)
    with pytest.raises(ScenarioError, match="engine must be one of"):
        scenario_from_dict({**base, "sim": {"engine": "bullet"}})
    with pytest.raises(ScenarioError, match="'mass'"):
        scenario_from_dict({**base, "robots": {"a": {"p": [0.0, 0.0], "mass": 0.0}}})
    with pytest.raises(ScenarioError, match="'wheel_radius'"):
        scenario_from_dict({**base, "defaults": {"wheel_radius": -0.01}})


def test_without_mujoco_the_engine_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "mujoco", None)  # import mujoco raises ImportError
    with pytest.raises(EngineUnavailable, match=r"pip install 'vsfleet\[mujoco\]'"):
        check_engine("mujoco")
    check_engine("kinematic")
    with pytest.raises(ValueError, match="engine must be one of"):
        check_engine("bullet")
