"""The two ROS 2 bridges' logic, without zenoh: a fake clock, and lists in place of publishers."""

from __future__ import annotations

import logging
import math
import struct

import msgpack
import pytest

from vsfleet.fleetctl import rmw_zenoh as rz
from vsfleet.fleetctl.bridge_ros2 import CmdBridge, build_parser as cmd_parser, main as cmd_main
from vsfleet.fleetctl.bridge_ros2_poses import FrameAssembler, MapError, PoseBridge, main as poses_main, parse_map
from vsfleet.zglue.lifecycle import Rejections
from vsfleet.wire import CmdMsg, Mission, RobotSpec, encode, encode_mission


class Clock:
    def __init__(self, t: float = 100.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def mission(version=1, effective_t=0.0, robots=("r1", "r2"), wheel_base=0.2, vmax=0.5) -> Mission:
    specs = tuple((r, RobotSpec(p=(float(i), 0.0), wheel_base=wheel_base, wheel_speed_max=vmax,
                                wheel_accel_max=1.0)) for i, r in enumerate(sorted(robots)))
    return Mission(version=version, metric="l2", robots=specs, speed_max=0.3, turn_rate_max=1.0,
                   effective_t=effective_t, goal=(0.0, 0.0, 0.0))


def cmd(t, vl, vr, ttl=0.3, seq=1) -> bytes:
    return encode(CmdMsg(t=t, seq=seq, vl=vl, vr=vr, ttl=ttl))


@pytest.fixture
def bridge():
    clock = Clock()
    sent: list[tuple[float, float, str]] = []
    b = CmdBridge("r1", lambda v, w, why: sent.append((v, w, why)), clock=clock,
                  rejections=Rejections(logging.getLogger("test")))
    return b, sent, clock


def test_before_any_mission_only_zero_twists_go_out(bridge):
    b, sent, clock = bridge
    b.zero("start")
    for i in range(5):
        b.on_cmd("k", cmd(10.0 + i, 0.2, 0.3))
    assert all(v == 0.0 and w == 0.0 for v, w, _ in sent)
    assert b.stats.no_mission == 5 and b.stats.commands == 0


def test_wheel_speeds_become_v_and_w_with_the_missions_wheel_base(bridge):
    b, sent, clock = bridge
    assert b.on_mission("vs/demo/mission", encode_mission(mission(wheel_base=0.16)))
    b.on_cmd("k", cmd(10.0, 0.1, 0.3))
    v, w, why = sent[-1]
    assert why == "cmd" and v == pytest.approx(0.2) and w == pytest.approx(0.2 / 0.16)
    b.on_cmd("k", cmd(10.1, 0.3, -0.3))  # spin in place, clockwise
    assert sent[-1][:2] == (pytest.approx(0.0), pytest.approx(-0.6 / 0.16))


def test_each_wheel_is_clamped_to_the_missions_wheel_speed_max(bridge):
    b, sent, clock = bridge
    b.on_mission("m", encode_mission(mission(wheel_base=0.2, vmax=0.5)))
    b.on_cmd("k", cmd(10.0, 2.0, 0.9))
    assert sent[-1][:2] == (pytest.approx(0.5), pytest.approx(0.0))


def test_a_zero_twist_follows_when_the_command_ttl_runs_out(bridge):
    b, sent, clock = bridge
    b.on_mission("m", encode_mission(mission()))
    b.on_cmd("k", cmd(10.0, 0.2, 0.2, ttl=0.3))
    assert b.expire() == pytest.approx(100.3)
    clock.t = 100.299
    b.expire()
    assert sent[-1][2] == "cmd"
    clock.t = 100.3
    assert b.expire() is None
    assert sent[-1] == (0.0, 0.0, "expired") and b.stats.expired == 1
    clock.t = 105.0
    b.expire()
    assert len(sent) == 2  # one zero, not one per tick


def test_after_shutdown_the_last_twist_is_the_zero_whatever_arrives(bridge):
    b, sent, clock = bridge
    b.on_mission("m", encode_mission(mission()))
    b.on_cmd("k", cmd(10.0, 0.2, 0.2))
    b.shutdown()
    b.on_cmd("k", cmd(10.1, 0.2, 0.2))  # a callback still running as the bridge stops
    b.expire()
    assert sent[-1] == (0.0, 0.0, "stop") and len(sent) == 2


def test_a_newer_command_extends_and_a_shorter_ttl_shortens_the_deadline(bridge):
    b, sent, clock = bridge
    b.on_mission("m", encode_mission(mission()))
    b.on_cmd("k", cmd(10.0, 0.2, 0.2, ttl=2.0))
    clock.t = 100.1
    b.on_cmd("k", cmd(10.1, 0.2, 0.2, ttl=0.1))
    assert b.expire() == pytest.approx(100.2)


def test_stale_and_malformed_commands_are_counted_and_move_nothing(bridge):
    b, sent, clock = bridge
    b.on_mission("m", encode_mission(mission()))
    b.on_cmd("k", cmd(10.0, 0.2, 0.2))
    n = len(sent)
    b.on_cmd("k", cmd(9.0, 0.4, 0.4))                 # older than the last one
    b.on_cmd("k", b"\x93\x01\x02")                     # not a map
    b.on_cmd("k", cmd(11.0, 0.4, 0.4, ttl=60.0))       # ttl beyond MAX_TTL_S
    b.on_cmd("k", msgpack.packb({"t": 11.0, "seq": 1, "vl": float("nan"), "vr": 0.0, "ttl": 0.1}))
    assert len(sent) == n
    assert b.stats.stale == 1 and b.rejections.count == 4


def test_a_mission_that_drops_the_robot_stops_it(bridge):
    b, sent, clock = bridge
    b.on_mission("m", encode_mission(mission()))
    b.on_cmd("k", cmd(10.0, 0.2, 0.2))
    b.on_mission("m", encode_mission(mission(version=2, robots=("r2", "r3"))))
    assert sent[-1] == (0.0, 0.0, "unlisted") and b.deadline is None
    b.on_cmd("k", cmd(11.0, 0.2, 0.2))
    assert sent[-1][:2] == (0.0, 0.0)


def test_the_mission_in_force_at_the_commands_time_gives_the_wheel_base(bridge):
    b, sent, clock = bridge
    b.on_mission("m", encode_mission(mission(version=1, effective_t=0.0, wheel_base=0.1)))
    b.on_mission("m", encode_mission(mission(version=2, effective_t=50.0, wheel_base=0.2)))
    b.on_cmd("k", cmd(49.0, 0.0, 0.1))
    assert sent[-1][1] == pytest.approx(1.0)
    b.on_cmd("k", cmd(50.0, 0.0, 0.1))
    assert sent[-1][1] == pytest.approx(0.5)
    assert not b.on_mission("m", encode_mission(mission(version=2)))  # known version: not new
    b.on_mission("m", b"junk")
    assert b.rejections.count == 1


def test_startup_replies_take_the_operator_or_a_strict_majority_of_peers(bridge):
    b, sent, clock = bridge
    m1, m2 = encode_mission(mission(version=1)), encode_mission(mission(version=2))
    peer = "vs/demo/peer/{}/mission".format
    assert not b.on_mission_replies("vs/demo/mission", [(peer("r2"), m1), (peer("r3"), m2)])
    assert not b.missions
    assert b.on_mission_replies("vs/demo/mission", [(peer("r2"), m1), (peer("r3"), m1), (peer("r4"), m2)])
    assert set(b.missions) == {1}
    assert b.on_mission_replies("vs/demo/mission", [("vs/demo/mission", m2)])
    assert set(b.missions) == {1, 2}


def test_cli_refuses_bad_names_and_domains_before_opening_anything(capsys):
    assert cmd_main(["--robot", "r/1"]) == 2
    assert cmd_main(["--robot", "r1", "--namespace", "r1"]) == 2
    assert cmd_main(["--robot", "r1", "--domain", "300"]) == 2
    assert cmd_parser().parse_args(["--robot", "r1"]).distro == "jazzy"
    assert poses_main(["--map", "r1"]) == 2
    assert poses_main(["--map", "r1:/a", "--hold", "0"]) == 2


# ---------------------------------------------------------------- poses -> frames


def posestamped(t: float, x: float, y: float, yaw: float, frame_id: str = "world", distro: str = "jazzy") -> bytes:
    ts = rz.typestore(distro)
    T = ts.types
    sec = int(t)
    msg = T[rz.POSE_STAMPED](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=round((t - sec) * 1e9)),
                                       frame_id=frame_id),
        pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.3),
                                         orientation=T["geometry_msgs/msg/Quaternion"](
                                             x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))))
    return bytes(ts.serialize_cdr(msg, rz.POSE_STAMPED))


def odometry(t: float, x: float, y: float, yaw: float) -> bytes:
    import numpy as np
    ts = rz.typestore("jazzy")
    T = ts.types
    sec = int(t)
    vec = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    msg = T[rz.ODOMETRY](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=round((t - sec) * 1e9)),
                                       frame_id="odom"),
        child_frame_id="base_link",
        pose=T["geometry_msgs/msg/PoseWithCovariance"](
            pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                                             orientation=T["geometry_msgs/msg/Quaternion"](
                                                 x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))),
            covariance=np.zeros(36)),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=T[rz.TWIST](linear=vec, angular=vec),
                                                         covariance=np.zeros(36)))
    return bytes(ts.serialize_cdr(msg, rz.ODOMETRY))


T0 = 1_796_000_000.0
KEY1 = rz.data_keyexpr(0, "/vicon/r1/pose", rz.POSE_STAMPED, "jazzy")
KEY2 = rz.data_keyexpr(0, "/r2/odom", rz.ODOMETRY, "jazzy")


@pytest.fixture
def poses():
    clock = Clock()
    frames = []
    topics = {"/vicon/r1/pose": "r1", "/r2/odom": "r2"}
    asm = FrameAssembler(set(topics.values()), "mocap", frames.append, clock=clock, tolerance_s=0.002, hold_s=0.02)
    return PoseBridge(topics, asm, "jazzy", rejections=Rejections(logging.getLogger("test"))), frames, clock


def test_one_frame_per_mocap_instant_with_stamp_time_and_yaw(poses):
    pb, frames, clock = poses
    pb.on_sample("/vicon/r1/pose", KEY1, posestamped(T0 + 0.5, 1.0, 2.0, 0.4))
    assert frames == []  # r2 not in yet
    pb.on_sample("/r2/odom", KEY2, odometry(T0 + 0.5005, -1.0, 0.5, -2.0))
    (f,) = frames
    assert f.t == pytest.approx(T0 + 0.5, abs=1e-6) and f.seq == 1 and f.src == "mocap"
    assert f.poses["r1"] == pytest.approx((1.0, 2.0, 0.4))
    assert f.poses["r2"] == pytest.approx((-1.0, 0.5, -2.0))


def test_a_robot_that_does_not_report_delays_its_frame_by_the_hold_only(poses):
    pb, frames, clock = poses
    pb.on_sample("/vicon/r1/pose", KEY1, posestamped(T0 + 1.0, 1.0, 2.0, 0.0))
    clock.t += 0.019
    pb.assembler.tick()
    assert frames == []
    clock.t += 0.001
    pb.assembler.tick()
    assert [set(f.poses) for f in frames] == [{"r1"}] and pb.stats.partial == 1
    # a newer instant also flushes the gathered one at once
    pb.on_sample("/vicon/r1/pose", KEY1, posestamped(T0 + 1.01, 1.0, 2.0, 0.0))
    pb.on_sample("/vicon/r1/pose", KEY1, posestamped(T0 + 1.02, 1.0, 2.0, 0.0))
    assert [f.seq for f in frames] == [1, 2] and frames[-1].t == pytest.approx(T0 + 1.01, abs=1e-6)


def test_a_repeated_message_of_one_instant_replaces_the_pose_and_makes_no_second_frame(poses):
    pb, frames, clock = poses
    pb.on_sample("/vicon/r1/pose", KEY1, posestamped(T0 + 3.0, 1.0, 1.0, 0.0))
    pb.on_sample("/vicon/r1/pose", KEY1, posestamped(T0 + 3.0, 2.0, 2.0, 0.0))
    pb.on_sample("/r2/odom", KEY2, odometry(T0 + 3.0, 0.0, 0.0, 0.0))
    clock.t += 1.0
    pb.assembler.tick()
    assert len(frames) == 1 and frames[0].poses["r1"][:2] == (2.0, 2.0) and pb.stats.duplicate == 1


def test_frames_never_go_back_in_time(poses):
    pb, frames, clock = poses
    pb.on_sample("/vicon/r1/pose", KEY1, posestamped(T0 + 2.0, 0.0, 0.0, 0.0))
    pb.on_sample("/r2/odom", KEY2, odometry(T0 + 2.0, 0.0, 0.0, 0.0))
    pb.on_sample("/vicon/r1/pose", KEY1, posestamped(T0 + 1.0, 5.0, 5.0, 0.0))
    pb.on_sample("/r2/odom", KEY2, odometry(T0 + 2.0, 5.0, 5.0, 0.0))  # its instant was already sent
    clock.t += 1.0
    pb.assembler.tick()
    assert len(frames) == 1 and pb.stats.stale == 2


@pytest.mark.parametrize("key, payload, counter", [
    (KEY1, b"", "malformed"),
    (KEY1, b"\x00\x01\x00\x00" + b"\x01" * 12, "malformed"),
    (KEY1, posestamped(T0, 1.0, 2.0, 0.0)[:-9], "malformed"),
    (KEY1, struct.pack("<4B", 0, 1, 0, 0) + b"\xff" * 200, "malformed"),
    (KEY1, odometry(T0, 1.0, 2.0, 0.0), "malformed"),        # an Odometry on a PoseStamped key
    (KEY1.replace("RIHS01_1", "RIHS01_0"), posestamped(T0, 1.0, 2.0, 0.0), "wrong_type"),  # other definition
    (KEY1.rsplit("/", 1)[0] + "/TypeHashNotSupported", posestamped(T0, 1.0, 2.0, 0.0), "wrong_type"),  # humble
    (rz.data_keyexpr(0, "/vicon/r1/pose", rz.TWIST, "jazzy"), rz.encode_twist(1, 1, "jazzy"), "wrong_type"),
    (KEY1, posestamped(T0, 1.0, 2.0, 0.0, frame_id="map"), "wrong_frame_id"),
])
def test_a_bad_ros_message_is_counted_and_never_becomes_a_frame(key, payload, counter):
    clock = Clock()
    frames = []
    asm = FrameAssembler({"r1"}, "mocap", frames.append, clock=clock)
    pb = PoseBridge({"/vicon/r1/pose": "r1"}, asm, "jazzy", frame_id="world",
                    rejections=Rejections(logging.getLogger("test")))
    pb.on_sample("/vicon/r1/pose", key, payload)
    clock.t += 1.0
    asm.tick()
    assert frames == []
    assert getattr(pb.stats, counter) == 1 and pb.rejections.count == 1
    pb.on_sample("/vicon/r1/pose", KEY1, posestamped(T0 + 5.0, 1.0, 2.0, 0.0))  # the next good one goes
    assert len(frames) == 1


def test_humble_keys_and_payloads_decode_with_the_humble_typestore():
    frames = []
    asm = FrameAssembler({"r1"}, "mocap", frames.append)
    pb = PoseBridge({"/p": "r1"}, asm, "humble")
    pb.on_sample("/p", rz.data_keyexpr(0, "/p", rz.POSE_STAMPED, "humble"), posestamped(T0, 3.0, 4.0, 1.0, distro="humble"))
    assert frames[0].poses["r1"] == pytest.approx((3.0, 4.0, 1.0))


def test_parse_map_refuses_bad_and_repeated_entries():
    assert parse_map(["r1:/vicon/r1/pose", "r2:/r2/odom"]) == {"/vicon/r1/pose": "r1", "/r2/odom": "r2"}
    for bad in ([], ["r1"], ["r1:vicon"], ["r/1:/a"], ["r1:/a", "r1:/b"], ["r1:/a", "r2:/a"]):
        with pytest.raises(MapError):
            parse_map(bad)


# ---------------------------------------------------------------- deploy/ros2

DEPLOY = __import__("pathlib").Path(__file__).resolve().parents[1] / "deploy" / "ros2"


def test_the_shared_router_config_loads_and_matches_rmw_zenohs_router_defaults():
    import zenoh
    import json
    conf = zenoh.Config.from_file(str(DEPLOY / "router.json5"))

    def get(key):
        return json.loads(conf.get_json(key))
    assert get("mode") == "router"
    assert get("listen/endpoints") == ["tcp/[::]:7447"]  # where rmw_zenoh sessions connect by default
    assert get("scouting/multicast/enabled") is False
    assert get("timestamping/enabled")["router"] is True


def test_the_systemd_units_command_line_is_one_the_bridge_accepts():
    text = (DEPLOY / "vsfleet-bridge-ros2@.service").read_text().replace("\\\n", " ")
    line = next(line for line in text.splitlines() if line.startswith("ExecStart="))
    argv = line.split("=", 1)[1].split()
    assert argv[0].endswith("/vsfleet") and argv[1:3] == ["bridge", "ros2"]
    env = {"%i": "r1", "${VSFLEET_FLEET}": "lab", "${VSFLEET_ROS_NAMESPACE}": "/r1",
           "${VSFLEET_ROS_DISTRO}": "humble", "${ROS_DOMAIN_ID}": "0"}
    args = cmd_parser().parse_args([env.get(a, a) for a in argv[3:]])
    assert (args.robot, args.namespace, args.distro, args.domain, args.connect) == (
        "r1", "/r1", "humble", 0, ["tcp/127.0.0.1:7447"])
    assert args.no_multicast_scouting and args.mode == "client"


class FakeSession:
    """What TwistPublisher uses of a zenoh session: publishers and liveliness tokens, recorded."""

    class _Token:
        def __init__(self, owner, key):
            self.owner, self.key = owner, key
            owner.tokens.add(key)

        def undeclare(self):
            self.owner.tokens.discard(self.key)

    class _Pub:
        def __init__(self, owner, key, kw):
            self.owner, self.key, self.kw = owner, key, kw

        def put(self, payload, attachment=None):
            self.owner.puts.append((self.key, payload, attachment))

        def undeclare(self):
            self.owner.undeclared.append(self.key)

    def __init__(self):
        self.tokens, self.puts, self.undeclared = set(), [], []

    def liveliness(self):
        return type("L", (), {"declare_token": lambda _s, key: FakeSession._Token(self, key)})()

    def declare_publisher(self, key, **kw):
        return FakeSession._Pub(self, key, kw)


@pytest.mark.parametrize("distro, layout", [("jazzy", rz.Attachment.CURRENT), ("humble", rz.Attachment.KEYED)])
def test_twist_publisher_sends_cdr_with_a_rising_sequence_and_its_tokens_gid(distro, layout):
    from vsfleet.fleetctl.bridge_ros2 import TwistPublisher
    s = FakeSession()
    node = rz.Node(domain=5, zid="c0ffee", nid=0, namespace="/r1", name="vsfleet_bridge_r1")
    out = TwistPublisher(s, node=node, topic="/r1/cmd_vel", distro=distro, layout=layout)
    assert s.tokens == set()  # not visible until it says so (after its subscriptions exist)
    out.declare_tokens()
    assert s.tokens == {node.token(), node.endpoint_token("MP", 1, "/r1/cmd_vel", rz.TWIST, distro)}
    out.send(0.1, 0.0, "cmd")
    out.send(0.0, 0.0, "expired")
    (k1, p1, a1), (k2, p2, a2) = s.puts
    assert k1 == k2 == rz.data_keyexpr(5, "/r1/cmd_vel", rz.TWIST, distro)
    assert rz.decode_twist(p1, distro) == (0.1, 0.0) and rz.decode_twist(p2, distro) == (0.0, 0.0)
    (q1, t1, g1), (q2, t2, g2) = rz.decode_attachment(a1, layout), rz.decode_attachment(a2, layout)
    assert (q1, q2) == (1, 2) and t1 <= t2 and g1 == g2 == rz.gid_of(out.pub_token)
    out.close()
    assert s.tokens == set() and s.undeclared == [k1]


def test_startup_query_asks_the_operator_and_the_agents_and_takes_the_answer(bridge):
    from types import SimpleNamespace as NS

    from vsfleet.fleetctl.bridge_ros2 import fetch_mission
    from vsfleet.wire import Keys
    b, sent, clock = bridge
    keys = Keys("demo")
    m = encode_mission(mission(version=4))
    asked = []

    def get(selector, **kw):
        asked.append(selector)
        if selector == keys.peer_mission("*"):
            return [NS(ok=NS(key_expr=keys.peer_mission(r), payload=NS(to_bytes=lambda: m))) for r in ("r2", "r3")]
        return [NS(ok=None)]  # the operator does not answer (mission set only puts)
    assert fetch_mission(NS(get=get), keys, b, 1.0)
    assert asked == [keys.mission, keys.peer_mission("*")] and set(b.missions) == {4}
