"""`vsfleet sim --engine mujoco` among real processes (loopback router, free port, multicast off).

- A robot driven into a pillar with no safety filter in the way (the test itself commands it on
  cmd/<robot>: no agent, so no filter) stops at the pillar: truth/<robot> shows it there, still
  commanded, its wheels turning, never through it. The contact is published on ``contact/r1`` (one reliable
  message, seen through the key space) and counted in simfleet's last log line.
- The agents' traffic is the same with either engine: the same keys, the same message kinds with the
  same fields, the same liveliness tokens, every message decoding under the wire's own rules.
- The camera loop runs on MuJoCo's truth: `vsfleet run scenarios/camera-triangle.toml --engine mujoco`
  (the synthetic camera renders the engine's truth, the ArUco tracker detects it, the agents follow its
  frames) settles at the goal in formation, with no contact.
"""

from __future__ import annotations

import math
import re
import signal
import threading
import time

import msgpack
import pytest

from vsfleet.wire import DECODERS, CmdMsg, WireError, decode_contact, encode
from vsfleet.zglue.zconf import RELIABLE_QOS

from .conftest import E2E, ROBOTS, LoopbackFleet, closing, start_fleet
from .test_camera_run import run_camera_triangle

pytestmark = pytest.mark.integration

try:
    import mujoco  # noqa: F401
except ImportError:
    pytest.skip("mujoco is not installed (pip install 'vsfleet[mujoco]')", allow_module_level=True)

PILLAR = (0.4, 0.0, 0.05)
RADIUS = 0.08
PILLAR_SCENARIO = f"""schema = 1
[fleet]
name = "pillar"
duration_s = 20.0
[mission]
metric = "l2"
speed_max = 0.05
turn_rate_max = 0.3
goal = {{ x = 1.0, y = 0.0, th = 0.0 }}
obstacles = [[{PILLAR[0]}, {PILLAR[1]}, {PILLAR[2]}]]
[sim]
engine = "mujoco"
[defaults]
wheel_base = 0.12
wheel_speed_max = 0.3
wheel_accel_max = 0.8
radius = {RADIUS}
[robots.r1]
p = [0.0, 0.0]
start = [0.0, 0.0, 0.0]
"""


@pytest.fixture
def pillar_fleet(tmp_path, request):
    path = tmp_path / "pillar.toml"
    path.write_text(PILLAR_SCENARIO)
    f = LoopbackFleet(path, tmp_path)
    yield f
    closing(f, request)


def test_a_robot_driven_into_a_pillar_stops_at_it_and_the_contact_is_reported(pillar_fleet):
    fleet = pillar_fleet
    keys = fleet.keys
    contacts = []

    def on_contact(sample):
        with fleet.observed.cond:
            contacts.append((str(sample.key_expr), decode_contact(sample.payload.to_bytes())))
            fleet.observed.cond.notify_all()

    contact_sub = fleet.router.declare_subscriber(keys.contact(), on_contact)
    fleet.start("sim", "sim", fleet.scenario_path)  # [sim] engine = "mujoco" from the scenario
    fleet.wait_alive("sim", ("simfleet",))
    reach = PILLAR[0] - PILLAR[2] - RADIUS  # where its body touches the pillar: 0.27 m

    seq = 0

    def commanded(obs):
        return any(why == "commanded" for why, _ in obs.why.get("r1", ()))

    while not commanded(fleet.observed):  # one command of 5 s (the longest ttl), sent until simfleet says it applies it
        seq += 1
        fleet.router.put(keys.cmd("r1"), encode(CmdMsg(time.time(), seq, 0.2, 0.2, 5.0)), **RELIABLE_QOS)
        try:
            fleet.observed.wait_for(commanded, 2.0)
        except TimeoutError:
            assert seq < 5, fleet.logs()

    def at_pillar(obs):
        return next((m.t for _, r, m in obs.truth if r == "r1" and m.x > reach - 0.005), None)
    t_touch = fleet.observed.wait_for(at_pillar, 20.0)
    # pressed against it for another 0.6 s of sim time: still commanded, still there (head-on it is an
    # unstable balance: after a second or so it slides round the pillar, as a real one would)
    fleet.observed.wait_for(lambda o: any(m.t > t_touch + 0.6 for _, _, m in o.truth), 20.0)
    with fleet.observed.cond:
        truth = [m for _, r, m in fleet.observed.truth if r == "r1"]
    assert max(m.x for m in truth) < reach + 0.003  # never through it (the soft contact: mm at most)
    held = [m for m in truth if t_touch + 0.2 < m.t < t_touch + 0.6]
    assert held and all(m.why == "commanded" and reach - 0.01 < m.x < reach + 0.003 for m in held)
    assert all(math.hypot(m.x - held[-1].x, m.y - held[-1].y) < 0.005 for m in held)
    assert max(abs(m.vl) for m in held) > 0.05  # its wheels turn on (slip) against the pillar

    # the contact, through the key space: one message on contact/r1 (reliable), the pillar, where r1 met it
    (key, c), = fleet.observed.wait_for(lambda o: list(contacts) or None, 10.0)
    contact_sub.undeclare()
    assert key == keys.contact("r1") and (c.robot, c.kind, c.other) == ("r1", "obstacle", "0")
    assert abs(c.x - (PILLAR[0] - PILLAR[2])) < 0.01 and abs(c.t - t_touch) < 0.5 and c.depth < 0.005
    fleet.procs["sim"].send_signal(signal.SIGTERM)
    assert fleet.procs["sim"].wait(timeout=10) == 0
    log = (fleet.log_dir / "sim.log").read_text()
    assert len(contacts) == 1
    assert len(re.findall(r"contact: r1 with obstacle 0 at t=", log)) == 1, log[-2000:]
    assert re.search(r"simfleet stopping at step \d+ .*, 1 contacts \(engine mujoco\)", log), log[-2000:]


class Traffic:
    """Every key seen under the fleet's prefix, with the fields of its messages, and every message that did
    not decode under the wire's rules."""

    def __init__(self, prefix: str) -> None:
        self.prefix = prefix
        self.lock = threading.Lock()
        self.fields: dict[str, set[tuple[str, ...]]] = {}  # key relative to the prefix -> field sets seen
        self.bad: list[str] = []

    def on_sample(self, sample) -> None:
        key = str(sample.key_expr)[len(self.prefix) + 1:]
        payload = sample.payload.to_bytes()
        kind = key.split("/")[0]
        try:
            DECODERS[kind](payload)
            fields = tuple(sorted(msgpack.unpackb(payload, raw=False)))
        except (KeyError, WireError, ValueError) as exc:
            with self.lock:
                self.bad.append(f"{key}: {exc}")
            return
        with self.lock:
            self.fields.setdefault(key, set()).add(fields)


class EngineFleet(LoopbackFleet):
    """The loopback fleet with simfleet started on ``engine`` (vsfleet sim --engine)."""

    def __init__(self, scenario_path, log_dir, engine: str) -> None:
        super().__init__(scenario_path, log_dir)
        self.engine = engine

    def start(self, name: str, *args: str, **kwargs):
        if name == "sim":
            args = (*args, "--engine", self.engine)
        return super().start(name, *args, **kwargs)


def traffic_of(engine: str, log_dir) -> tuple[dict, set, list]:
    """The e2e triangle (sim on ``engine``, tracker, three agents) observed until every agent has run 3 s
    of frames since it was up: (key -> field sets, liveliness tokens, messages that did not decode)."""
    log_dir.mkdir()
    fleet = EngineFleet(E2E, log_dir, engine)
    traffic = Traffic(fleet.keys.prefix)
    sub = fleet.router.declare_subscriber(fleet.keys.everything, traffic.on_sample)
    try:
        start_fleet(fleet)
        with fleet.observed.cond:
            t_up = max(m.t for _, _, m in fleet.observed.state)
        fleet.observed.wait_for(lambda o: {r for _, r, m in o.state[-30:] if m.t > t_up + 3.0} >= set(ROBOTS), 30.0)
        with traffic.lock:
            fields = {k: set(v) for k, v in traffic.fields.items()}
            bad = list(traffic.bad)
        with fleet.observed.cond:
            alive = set(fleet.observed.alive)
    finally:
        sub.undeclare()
        fleet.close()
    errors = [line for f in sorted(log_dir.glob("*.log")) for line in f.read_text(errors="replace").splitlines()
              if re.search(r"\bERROR\b|\bCRITICAL\b|^Traceback", line)]
    assert not errors, errors[:20]
    assert f"engine {engine}" in (log_dir / "sim.log").read_text()
    prefix = fleet.keys.prefix + "/"
    return fields, {a.replace(prefix, "") for a in alive}, bad


def test_the_agents_traffic_is_the_same_with_either_engine(tmp_path):
    kinematic = traffic_of("kinematic", tmp_path / "kinematic")
    mujoco_ = traffic_of("mujoco", tmp_path / "mujoco")
    assert kinematic[2] == [] and mujoco_[2] == []
    assert set(kinematic[0]) == set(mujoco_[0])  # the same keys
    assert set(kinematic[0]) >= {f"{kind}/{r}" for kind in ("truth", "cmd", "state", "pose") for r in ROBOTS}
    assert kinematic[0] == mujoco_[0]  # each with the same fields
    assert kinematic[1] == mujoco_[1]  # the same processes alive


def test_the_camera_loop_on_mujocos_truth_reaches_the_goal_in_formation(tmp_path):
    pytest.importorskip("cv2")
    _fleet, run_dir, summary, _out = run_camera_triangle(tmp_path, "--engine", "mujoco")
    assert summary["goal_distance_end_m"] <= 0.01  # vsfleet run's goal
    # the paper's real robots' bound (2.5 cm, as the kinematic camera loop's test); measured here 0.29 cm, at the start
    assert {d["robot"] for d in summary["deviation"]} == {"r1", "r2", "r3"}
    assert all(d["max_m"] < 0.025 for d in summary["deviation"]), summary["deviation"]
    a = summary["agreement"]
    assert a["frames"] > 0 and a["identical"] == a["frames"]
    sim_log = (run_dir / "sim.log").read_text()
    assert re.search(r"simfleet stopping at step \d+ .*, 0 contacts \(engine mujoco\)", sim_log), sim_log[-2000:]
    tracker_log = (run_dir / "tracker.log").read_text()  # the agents followed the camera's frames, not the sim tracker
    assert "camera tracker cam1 up: source render" in tracker_log, tracker_log[-2000:]
    poses = re.search(r"camera tracker cam1 stopping after \d+ frames .*?, (\d+) poses", tracker_log)
    assert poses and int(poses.group(1)) > 0, tracker_log[-2000:]
