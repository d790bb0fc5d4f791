"""vsfleet bridge ros2-poses: mocap PoseStamped / Odometry topics over rmw_zenoh -> vsfleet frames.

``--map r1:/vicon/r1/pose`` reads that topic (geometry_msgs/PoseStamped or nav_msgs/Odometry,
told apart by the type chunk of each sample's key) and publishes frames on
``vs/<fleet>/frame/<src>``. A frame's t is the header stamp [s since the epoch: the tracker
clock convention], (x, y) the position [m, the mocap's world frame] and th the yaw of the
orientation [rad, CCW from +x]. Messages of one mocap instant (stamps within
``--stamp-tolerance``) go into one frame, sent as soon as every mapped robot is in it, when a
newer instant begins, or ``--hold`` after its first message. A malformed message is counted,
logged (rate-limited) and never becomes a frame.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

import zenoh

from vsfleet.wire import FrameMsg, Keys, PoseMsg, check_name, encode, encode_frame

from . import rmw_zenoh as rz
from .bridge_ros2 import open_session, ros_client_config
from vsfleet.zglue.lifecycle import Rejections, StopFlag
from vsfleet.zglue.program import common_flags, program
from vsfleet.zglue.zconf import BURST_QOS, STREAM_QOS, zenoh_config

log = logging.getLogger("vsfleet.bridge.ros2-poses")

TICK_S = 0.005
STATS_PERIOD_S = 30.0


class MapError(ValueError):
    """A --map entry that is not ROBOT:/absolute/topic, or a robot or topic mapped twice."""


def parse_map(entries: list[str]) -> dict[str, str]:
    """``["r1:/vicon/r1/pose", ...]`` -> {topic: robot}; MapError on a bad or repeated entry."""
    out: dict[str, str] = {}
    robots: set[str] = set()
    for entry in entries:
        robot, sep, topic = entry.partition(":")
        if not sep:
            raise MapError(f"--map expects ROBOT:/topic, got {entry!r}")
        try:
            check_name(robot, "robot")
            rz.check_name(topic, "topic")
        except ValueError as exc:
            raise MapError(f"--map {entry!r}: {exc}") from None
        if topic in out or robot in robots:
            raise MapError(f"--map {entry!r}: robot or topic already mapped")
        out[topic] = robot
        robots.add(robot)
    if not out:
        raise MapError("at least one --map ROBOT:/topic is needed")
    return out


@dataclass
class PoseStats:
    """Frames sent, messages taken, and messages refused by reason."""

    frames: int = 0
    messages: int = 0
    malformed: int = 0
    stale: int = 0
    wrong_frame_id: int = 0
    wrong_type: int = 0
    partial: int = 0
    duplicate: int = 0


@dataclass
class _Pending:
    t: float
    since: float
    poses: dict[str, tuple[float, float, float]] = field(default_factory=dict)


class FrameAssembler:
    """Pose messages in, frames out, on an injected monotonic clock [s] for the hold.

    ``emit(frame)`` gets each FrameMsg. Frames never go back in time: a message older than the
    last frame sent (or its instant already sent) is counted stale and dropped.
    """

    def __init__(self, robots: set[str], src: str, emit: Callable[[FrameMsg], None],
                 clock: Callable[[], float] = time.monotonic, tolerance_s: float = 0.002,
                 hold_s: float = 0.02) -> None:
        self.robots, self.src, self.emit, self.clock = set(robots), check_name(src, "src"), emit, clock
        self.tolerance_s, self.hold_s = tolerance_s, hold_s
        self.pending: _Pending | None = None
        self.last_t = -float("inf")
        self.seq = 0
        self.stats = PoseStats()
        self._lock = threading.RLock()

    def _flush(self) -> None:
        p, self.pending = self.pending, None
        if p is None or not p.poses:
            return
        if len(p.poses) < len(self.robots):
            self.stats.partial += 1
        self.seq += 1
        self.last_t = p.t
        self.stats.frames += 1
        self.emit(FrameMsg(t=p.t, seq=self.seq, src=self.src, poses=dict(p.poses)))

    def add(self, robot: str, pose: rz.StampedPose) -> None:
        """One robot's pose at its header stamp."""
        with self._lock:
            if pose.t <= self.last_t + self.tolerance_s:
                self.stats.stale += 1
                return
            self.stats.messages += 1
            p = self.pending
            if p is not None:
                if pose.t > p.t + self.tolerance_s:
                    self._flush()  # a newer instant: the gathered one is as complete as it gets
                elif pose.t < p.t - self.tolerance_s:
                    self.stats.stale += 1  # older than the instant being gathered
                    return
                elif robot in p.poses:
                    self.stats.duplicate += 1  # the same instant again: the newer message wins
            if self.pending is None:
                self.pending = _Pending(t=pose.t, since=self.clock())
            self.pending.poses[robot] = (pose.x, pose.y, pose.th)
            if len(self.pending.poses) == len(self.robots):
                self._flush()

    def tick(self) -> None:
        """Send a frame that has waited ``hold_s`` for robots that did not report."""
        with self._lock:
            if self.pending is not None and self.clock() - self.pending.since >= self.hold_s:
                self._flush()


class PoseBridge:
    """Samples from rmw_zenoh topics -> StampedPose -> the assembler, every refusal counted."""

    def __init__(self, topics: dict[str, str], assembler: FrameAssembler, distro: str,
                 frame_id: str | None = None, rejections: Rejections | None = None) -> None:
        self.topics, self.assembler, self.distro, self.frame_id = topics, assembler, distro, frame_id
        self.rejections = rejections or Rejections(log)
        self.hashes = {t: rz.type_hash(t, distro) for t in rz.POSE_TYPES}

    @property
    def stats(self) -> PoseStats:
        return self.assembler.stats

    def on_sample(self, topic: str, key: str, payload: bytes) -> None:
        """One sample on ``key``, a data key of the mapped ``topic``."""
        st = self.assembler.stats
        try:
            ros_type, hash_chunk = rz.ros_type_of_key(key)
            if ros_type not in self.hashes or hash_chunk != self.hashes[ros_type]:
                st.wrong_type += 1
                self.rejections.reject(key, f"not a {self.distro} PoseStamped or Odometry key")
                return
            pose = rz.decode_pose(payload, ros_type, self.distro)
        except rz.RosMessageError as exc:
            st.malformed += 1
            self.rejections.reject(key, str(exc))
            return
        if self.frame_id is not None and pose.frame_id != self.frame_id:
            st.wrong_frame_id += 1
            self.rejections.reject(key, f"frame_id {pose.frame_id!r}, expected {self.frame_id!r}")
            return
        self.assembler.add(self.topics[topic], pose)


def run_pose_bridge(conf: zenoh.Config, topics: dict[str, str], fleet: str = "demo", src: str = "ros2",
                    domain: int = 0, distro: str = "jazzy", frame_id: str | None = None,
                    tolerance_s: float = 0.002, hold_s: float = 0.02, node_name: str = "vsfleet_poses",
                    ros_conf: zenoh.Config | None = None, poses: bool = True, stop: StopFlag | None = None,
                    ready: threading.Event | None = None) -> PoseStats:
    """Run until ``stop``; returns the counters. ``ros_conf``: a session of its own for ROS 2.
    With ``poses``, each robot of a frame also goes out on ``pose/<robot>``, as trackers do."""
    stop = stop or StopFlag()
    keys = Keys(fleet)
    with contextlib.ExitStack() as stack:
        session = stack.enter_context(open_session(conf))
        ros = stack.enter_context(open_session(ros_conf)) if ros_conf is not None else session
        pub = session.declare_publisher(keys.frame(src), **STREAM_QOS)
        pose_pubs = {r: session.declare_publisher(keys.pose(r), **BURST_QOS) for r in topics.values()} \
            if poses else {}

        def emit(frame: FrameMsg) -> None:
            pub.put(encode_frame(frame))
            for robot, (x, y, th) in frame.poses.items():  # for tools, as trackers do
                if robot in pose_pubs:
                    pose_pubs[robot].put(encode(PoseMsg(t=frame.t, seq=frame.seq, x=x, y=y, th=th, src=src)))

        assembler = FrameAssembler(set(topics.values()), src, emit, tolerance_s=tolerance_s, hold_s=hold_s)
        bridge = PoseBridge(topics, assembler, distro, frame_id)
        node = rz.Node(domain=domain, zid=str(ros.info.zid()), nid=0, namespace="/", name=node_name)
        tokens = [ros.liveliness().declare_token(node.token())]
        subs = []
        for eid, (topic, robot) in enumerate(sorted(topics.items()), start=1):
            for ros_type in rz.POSE_TYPES:
                tokens.append(ros.liveliness().declare_token(
                    node.endpoint_token("MS", eid, topic, ros_type, distro)))
            selector = f"{domain}/{topic.strip('/')}/*/*"  # PoseStamped or Odometry, told by the key
            subs.append(ros.declare_subscriber(
                selector, lambda s, _t=topic: bridge.on_sample(_t, str(s.key_expr), s.payload.to_bytes())))
            log.info("%s (%s) -> %s robot %s", selector, distro, keys.frame(src), robot)
        if ready is not None:
            ready.set()
        next_stats = time.monotonic() + STATS_PERIOD_S
        try:
            while not stop.is_set():
                assembler.tick()
                stop.wait(TICK_S)
                if time.monotonic() >= next_stats:
                    log.info("stats %s", assembler.stats)
                    next_stats += STATS_PERIOD_S
        finally:
            for s in subs:
                s.undeclare()
            for t in tokens:
                t.undeclare()
            assembler.tick()
            log.info("stopped: %s", assembler.stats)
    return assembler.stats


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet bridge ros2-poses", description=__doc__.splitlines()[0])
    p.add_argument("--map", action="append", default=[], metavar="ROBOT:/TOPIC", required=True,
                   help="a robot and its pose topic, e.g. r1:/vicon/r1/pose (repeatable)")
    p.add_argument("--fleet", default="demo")
    p.add_argument("--src", default="ros2", help="the frame source id: vs/<fleet>/frame/<src>")
    p.add_argument("--domain", type=int, default=0, help="ROS_DOMAIN_ID")
    p.add_argument("--distro", choices=rz.DISTROS, default="jazzy")
    p.add_argument("--frame-id", default=None, help="refuse messages whose header.frame_id differs")
    p.add_argument("--stamp-tolerance", type=float, default=0.002, metavar="S",
                   help="stamps this close [s] are one mocap instant (default 0.002)")
    p.add_argument("--hold", type=float, default=0.02, metavar="S",
                   help="send an incomplete frame this long [s] after its first pose (default 0.02)")
    p.add_argument("--no-poses", action="store_true",
                   help="publish frames only, not also pose/<robot> for tools (as trackers do)")
    p.add_argument("--node-name", default="vsfleet_poses", help="ROS node name of the subscriptions")
    p.add_argument("--ros-connect", default=None, metavar="ENDPOINT",
                   help="reach ROS 2 through this router in a session of its own; the zenoh flags "
                        "below are then for the vsfleet side only")
    return common_flags(p)


@program(build_parser, log)
def main(args: argparse.Namespace) -> int:
    try:  # refused flags: one line on stdout, exit code 2
        topics = parse_map(args.map)
        check_name(args.src, "src")
        if not 0 <= args.domain <= 232:
            raise ValueError(f"--domain must be 0..232, got {args.domain}")
        if not (0 < args.hold <= 1.0 and 0 <= args.stamp_tolerance <= 0.1):
            raise ValueError("--hold must be in (0, 1] s and --stamp-tolerance in [0, 0.1] s")
    except ValueError as exc:
        print(f"vsfleet bridge ros2-poses: {exc}", flush=True)
        return 2
    run_pose_bridge(zenoh_config(args), topics, args.fleet, args.src, args.domain, args.distro,
                    args.frame_id, args.stamp_tolerance, args.hold, args.node_name,
                    ros_client_config(args.ros_connect) if args.ros_connect else None, not args.no_poses)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
