"""The ROS 2 bridges against an independent rmw_zenoh implementation (zenoh-ros2-sdk), multi-process.

A `vsfleet router` child on a free loopback port (multicast scouting off), the two bridges as
`vsfleet bridge ...` children; the test's side of ROS 2 is zenoh-ros2-sdk (its own attachment,
key and token code, its own .msg parser and type hash), fed the message definitions in
tests/data/ros2_msgs so that it needs no network.
"""

from __future__ import annotations

import math
import os
import queue
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from vsfleet.fleetctl.mission_cmd import stamp
from vsfleet.zglue.scenario_file import load_scenario
from vsfleet.fleetctl import rmw_zenoh as rz
from tests.integration.conftest import LoopbackFleet
from vsfleet.wire import CmdMsg, decode_frame, decode_pose, encode, encode_mission

pytestmark = pytest.mark.integration
ROOT = Path(__file__).resolve().parents[2]
MSGS = ROOT / "tests" / "data" / "ros2_msgs"
SCENARIO = ROOT / "tests" / "data" / "e2e-triangle.toml"


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    f = LoopbackFleet(SCENARIO, tmp_path_factory.mktemp("ros2"), router_process=True)
    yield f
    f.close()


@pytest.fixture(scope="module")
def sdk(fleet):
    """zenoh-ros2-sdk's session, a client of the fleet's router, scouting off."""
    import zenoh_ros2_sdk as zr  # the dev extra installs it: a missing one fails the test
    from zenoh_ros2_sdk import message_registry, session as sdk_session

    old = os.environ.get("ZENOH_CONFIG_OVERRIDE")
    os.environ["ZENOH_CONFIG_OVERRIDE"] = (
        'mode="client";scouting/multicast/enabled=false;'
        f'connect/endpoints=["{fleet.endpoint}"]')
    message_registry._registry = None
    zr.get_registry(str(MSGS))
    s = sdk_session.ZenohSession.get_instance("127.0.0.1", fleet.router_port)
    yield zr
    s.close()
    message_registry._registry = None
    if old is None:
        os.environ.pop("ZENOH_CONFIG_OVERRIDE", None)
    else:
        os.environ["ZENOH_CONFIG_OVERRIDE"] = old


def wait_until(pred, timeout_s: float, what: str, poll: threading.Event | None = None):
    """Wait for ``pred()`` to be truthy, re-checking when ``poll`` is set or every 50 ms."""
    ev = poll or threading.Event()
    deadline = time.monotonic() + timeout_s
    while True:
        got = pred()
        if got:
            return got
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        ev.wait(0.05)
        ev.clear()


@pytest.mark.parametrize("distro", ["jazzy", "humble"])
def test_sdk_subscriber_receives_and_decodes_the_bridge_twist_then_a_zero_within_ttl(fleet, sdk, distro):
    robot = "r1"
    ns = f"/{distro}_{robot}"
    # humble: the ROS side through a session of its own (--ros-connect; here the same router)
    split = ["--ros-connect", fleet.endpoint] if distro == "humble" else []
    fleet.start(f"bridge-{distro}", "bridge", "ros2", "--robot", robot, "--fleet", fleet.keys.fleet,
                "--namespace", ns, "--distro", distro, *split)
    twists: queue.Queue = queue.Queue()
    type_hash = rz.type_hash(rz.TWIST, distro)
    sub = sdk.ROS2Subscriber(f"{ns}/cmd_vel", rz.TWIST, lambda m: twists.put((time.monotonic(), m)),
                             router_port=fleet.router_port, type_hash=type_hash)
    attachments: queue.Queue = queue.Queue()
    raw = fleet.router.declare_subscriber(
        rz.data_keyexpr(0, f"{ns}/cmd_vel", rz.TWIST, distro),
        lambda s: attachments.put(s.attachment.to_bytes() if s.attachment is not None else None))
    # rmw_zenoh_cpp's subscriptions are zenoh-ext advanced subscribers: default options for a
    # volatile one, history with late-publisher detection for a transient-local one.
    import zenoh.ext as zext
    advanced: dict[str, queue.Queue] = {"volatile": queue.Queue(), "transient_local": queue.Queue()}
    adv = [zext.declare_advanced_subscriber(
               fleet.router, rz.data_keyexpr(0, f"{ns}/cmd_vel", rz.TWIST, distro),
               lambda s, q=advanced[kind]: q.put(s.attachment.to_bytes() if s.attachment is not None else None),
               **opts)
           for kind, opts in (("volatile", {}),
                              ("transient_local", {"history": zext.HistoryConfig(detect_late_publishers=True,
                                                                                  max_samples=10),
                                                   "subscriber_detection": True}))]
    try:
        # The bridge shows in the SDK's `ros2 topic list` (its liveliness token parser).
        from zenoh_ros2_sdk.discovery import get_topic_names_and_types
        wait_until(lambda: (f"{ns}/cmd_vel", [rz.TWIST]) in get_topic_names_and_types(
            domain_id=0, router_port=fleet.router_port), 20.0, "the bridge's topic in the SDK's topic list")
        mission = stamp(load_scenario(SCENARIO).mission, time.time(), 0.0, version=1)
        wheel_base = mission.spec(robot).wheel_base
        # A command before the mission moves nothing (unit-tested); then the mission.
        t0 = time.time()
        fleet.router.put(fleet.keys.cmd(robot), encode(CmdMsg(t=t0, seq=1, vl=0.1, vr=0.2, ttl=0.5)))
        fleet.router.put(fleet.keys.mission, encode_mission(mission))
        ttl = 0.4
        sent = {}

        def got_motion():
            # commands repeat until one arrives after the mission did (puts race the subscriber)
            n = len(sent) + 2
            fleet.router.put(fleet.keys.mission, encode_mission(mission))  # idempotent (one version)
            sent[n] = time.monotonic()
            fleet.router.put(fleet.keys.cmd(robot), encode(CmdMsg(t=t0 + n, seq=n, vl=0.1, vr=0.2, ttl=ttl)))
            try:
                while True:
                    at, m = twists.get(timeout=0.2)
                    if m.linear.x != 0.0:
                        return at, m
            except queue.Empty:
                return None

        at, moving = wait_until(got_motion, 20.0, "a moving Twist")
        assert moving.linear.x == pytest.approx(0.15, abs=1e-12)
        assert moving.angular.z == pytest.approx(0.1 / wheel_base, abs=1e-12)
        assert (moving.linear.y, moving.linear.z, moving.angular.x, moving.angular.y) == (0.0, 0.0, 0.0, 0.0)
        last_put = max(sent.values())
        zero_at, zero = twists.get(timeout=5.0)
        while zero.linear.x != 0.0:
            zero_at, zero = twists.get(timeout=5.0)
        assert zero.angular.z == 0.0
        # The zero follows the last command within its ttl, plus the bridge's tick, the transit both ways
        # and this process's SDK thread: 0.25 s for those (a busy-loop rehearsal measured 0.525 s in all)
        assert zero_at - last_put <= ttl + 0.25
        # Every sample carried a current-layout attachment the SDK parses; sequence numbers rise.
        from zenoh_ros2_sdk.attachment import Attachment
        seqs, gids = [], set()
        while not attachments.empty():
            a = attachments.get_nowait()
            assert a is not None and len(a) == 33
            parsed = Attachment.from_bytes(a)
            assert len(parsed.gid) == 16 and abs(parsed.timestamp_ns - time.time_ns()) < 60e9
            seqs.append(parsed.sequence_id)
            gids.add(parsed.gid)
        assert len(seqs) >= 2 and seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
        # The GID is rmw_zenoh's: XXH3-128 of the publisher's liveliness token, as the graph sees it.
        tokens = [str(r.ok.key_expr) for r in fleet.router.liveliness().get("@ros2_lv/0/**", timeout=5.0)
                  if r.ok is not None]
        mp = [t for t in tokens if f"/MP/%/{rz.mangle(ns)}/" in t]
        assert len(mp) == 1 and mp[0].endswith(f"/{type_hash}/::,10:,:,:,,")
        assert gids == {rz.gid_of(mp[0])}
        for kind, q in advanced.items():  # the advanced subscribers got the samples, attachment and all
            got = [q.get_nowait() for _ in range(q.qsize())]
            assert len(got) >= 2 and all(a is not None and len(a) == 33 for a in got), kind
        # Stopping the bridge (SIGTERM) sends a zero at once, long before a 5 s ttl would run out.
        fleet.router.put(fleet.keys.cmd(robot), encode(CmdMsg(t=t0 + 1000, seq=1000, vl=0.2, vr=0.2, ttl=5.0)))
        m = twists.get(timeout=5.0)[1]
        assert m.linear.x == pytest.approx(0.2)
        stopped_at = time.monotonic()
        fleet.kill(f"bridge-{distro}", 15)
        last_at, last = twists.get(timeout=5.0)
        assert (last.linear.x, last.angular.z) == (0.0, 0.0) and last_at - stopped_at < 2.0
        assert fleet.procs[f"bridge-{distro}"].wait(timeout=10) == 0
    finally:
        for a in adv:
            a.undeclare()
        raw.undeclare()
        sub.close()
        fleet.kill(f"bridge-{distro}", 15)
        fleet.procs[f"bridge-{distro}"].wait(timeout=10)


def test_pose_bridge_turns_sdk_posestamped_and_odometry_into_frames_and_drops_malformed(fleet, sdk):
    p = fleet.start("poses", "bridge", "ros2-poses", "--fleet", fleet.keys.fleet, "--src", "mocap",
                    "--map", "r1:/vicon/r1/pose", "--map", "r2:/r2/odom", "--hold", "0.2")
    frames: queue.Queue = queue.Queue()
    sub = fleet.router.declare_subscriber(fleet.keys.frame("mocap"), lambda s: frames.put(decode_frame(
        s.payload.to_bytes())))
    poses: queue.Queue = queue.Queue()
    pose_sub = fleet.router.declare_subscriber(fleet.keys.pose(), lambda s: poses.put(decode_pose(
        s.payload.to_bytes())))
    pose_pub = sdk.ROS2Publisher("/vicon/r1/pose", rz.POSE_STAMPED, router_port=fleet.router_port,
                                 type_hash=rz.type_hash(rz.POSE_STAMPED, "jazzy"))
    odom_pub = sdk.ROS2Publisher("/r2/odom", rz.ODOMETRY, router_port=fleet.router_port,
                                 type_hash=rz.type_hash(rz.ODOMETRY, "jazzy"))
    store = sdk.ZenohSession.get_instance().store
    T = store.types
    try:
        from zenoh_ros2_sdk.discovery import get_topic_info
        def subscribed(topic):
            info = get_topic_info(topic, router_port=fleet.router_port)
            return info is not None and info.subscriber_count >= 1
        wait_until(lambda: subscribed("/vicon/r1/pose") and subscribed("/r2/odom"), 20.0,
                   "the pose bridge's subscription tokens")
        th = 0.7

        def header(sec):
            return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=250_000_000),
                                           frame_id="world")

        def pose(x, y, yaw):
            return T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)))

        zero36 = np.zeros(36)
        sec = int(time.time())

        def publish_instant(k):
            pose_pub.publish(header=header(sec + k), pose=pose(1.0 + k, 2.0, th))
            odom_pub.publish(header=header(sec + k), child_frame_id="base_link",
                             pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose(-1.0, 0.5 - k, -th),
                                                                             covariance=zero36),
                             twist=T["geometry_msgs/msg/TwistWithCovariance"](
                                 twist=T["geometry_msgs/msg/Twist"](
                                     linear=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                                     angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)),
                                 covariance=zero36))

        k = [0]

        def complete_frame():
            # instants until one frame holds both robots (the SDK's routes come up one by one)
            k[0] += 1
            publish_instant(k[0])
            try:
                while True:
                    f = frames.get(timeout=0.5)
                    if set(f.poses) == {"r1", "r2"}:
                        return f
            except queue.Empty:
                return None

        f = wait_until(complete_frame, 20.0, "a frame with both robots")
        n = k[0]
        # Both robots in one frame, t from the header stamp, yaw from the quaternion.
        assert f.t == pytest.approx(sec + n + 0.25, abs=1e-6)
        assert f.poses["r1"] == pytest.approx((1.0 + n, 2.0, th), abs=1e-9)
        assert f.poses["r2"] == pytest.approx((-1.0, 0.5 - n, -th), abs=1e-9)
        # Malformed payloads on the same keys never become frames; the next good instant does.
        for bad in (b"", b"\x00\x01\x00\x00garbage", b"\x07" * 40):
            pose_pub.pub.put(bad, attachment=pose_pub._create_attachment(999, time.time_ns()))
        publish_instant(n + 1)
        f2 = frames.get(timeout=5.0)
        assert f2.t == pytest.approx(sec + n + 1.25, abs=1e-6) and set(f2.poses) == {"r1", "r2"}
        assert f2.seq == f.seq + 1
        assert frames.empty()
        # and each robot of each frame on pose/<robot>, for tools. Those go out best-effort (the
        # stream QoS drops under congestion, as a tracker's do), so a loaded host may lose one: a
        # further instant is published until one frame's two poses are both seen, matching it.
        seen = {}
        sent = {f2.seq: f2}
        last = [n + 1]

        def both_seen():
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:
                try:
                    m = poses.get(timeout=0.1)
                    seen[(m.seq, m.x, m.y)] = m
                except queue.Empty:
                    pass
                for seq, fr in sent.items():
                    if {(seq, *fr.poses[r][:2]) for r in ("r1", "r2")} <= set(seen):
                        return fr
            last[0] += 1
            publish_instant(last[0])
            try:
                fr = frames.get(timeout=2.0)
                sent[fr.seq] = fr
            except queue.Empty:
                pass
            return None
        wait_until(both_seen, 20.0, "both robots' poses of one frame")
        assert all(m.src == "mocap" for m in seen.values())
    finally:
        sub.undeclare()
        pose_sub.undeclare()
        pose_pub.close()
        odom_pub.close()
        fleet.kill("poses", 15)
        p.wait(timeout=10)
