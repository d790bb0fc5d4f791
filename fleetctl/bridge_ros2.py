"""vsfleet bridge ros2: one robot's vsfleet commands -> geometry_msgs/Twist on <namespace>/cmd_vel over rmw_zenoh.

Wheel speeds (vl, vr) [m/s] from ``vs/<fleet>/cmd/<robot>`` become v = (vl + vr) / 2 [m/s]
(linear.x) and w = (vr - vl) / wheel_base [rad/s, CCW] (angular.z), wheel_base from the
mission in force at the command's time. Each wheel is first clamped to the mission's
wheel_speed_max. A zero Twist goes out at start, when a command's ttl runs out with no newer
command, when the mission no longer lists the robot, and when the bridge stops. Before any
mission is known nothing but zero is sent.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

import zenoh

from vsfleet.kinematics import twist_from_wheels
from vsfleet.quorum import majority
from vsfleet.wire import Keys, Mission, WireError, check_name, decode_cmd, decode_mission

from . import rmw_zenoh as rz
from vsfleet.zglue import zconf
from vsfleet.zglue.lifecycle import Rejections, StopFlag
from vsfleet.zglue.program import common_flags, program
from vsfleet.zglue.zconf import zenoh_config

log = logging.getLogger("vsfleet.bridge.ros2")

FETCH_PERIOD_S = 1.0  # without a mission, ask again this often
TICK_S = 0.01         # the expiry check runs at least this often: a zero follows a ttl within it
STATS_PERIOD_S = 30.0


@dataclass
class BridgeStats:
    """What the bridge did: Twists sent (moving and zero), commands taken and refused."""

    sent: int = 0
    zeros: int = 0
    commands: int = 0
    expired: int = 0
    no_mission: int = 0
    unlisted: int = 0
    stale: int = 0
    reasons: dict[str, int] = field(default_factory=dict)


class CmdBridge:
    """Commands and missions in, Twists out, on an injected monotonic clock [s].

    ``send(v_m_s, w_rad_s, reason)`` publishes one Twist. Thread-safe: zenoh callbacks and
    the expiry loop call in from different threads.
    """

    def __init__(self, robot: str, send: Callable[[float, float, str], None],
                 clock: Callable[[], float] = time.monotonic, rejections: Rejections | None = None) -> None:
        self.robot = check_name(robot, "robot")
        self.send = send
        self.clock = clock
        self.rejections = rejections or Rejections(log)
        self.stats = BridgeStats()
        self.missions: dict[int, Mission] = {}
        self.deadline: float | None = None  # local time the running command expires; None = stopped
        self.last_t = -float("inf")          # tracker time of the newest command taken
        self.moving = False                  # the last Twist sent was not zero
        self.closed = False                  # after shutdown() nothing but that zero goes out
        self._lock = threading.RLock()

    # ------------------------------------------------------------ output
    def _twist(self, v: float, w: float, reason: str) -> None:
        self.send(v, w, reason)
        self.stats.sent += 1
        self.moving = (v != 0.0 or w != 0.0)
        if not self.moving:
            self.stats.zeros += 1
        self.stats.reasons[reason] = self.stats.reasons.get(reason, 0) + 1

    def zero(self, reason: str) -> None:
        """Publish a zero Twist and forget the running command."""
        with self._lock:
            self.deadline = None
            self._twist(0.0, 0.0, reason)

    def shutdown(self) -> None:
        """The last Twist: a zero. A command still in a callback after it is dropped."""
        with self._lock:
            self.closed = True
            self.zero("stop")

    # ------------------------------------------------------------ missions
    def on_mission(self, key: str, payload: bytes) -> bool:
        """Take a mission (its put, or a reply); True if it is new. A bad one is counted and refused."""
        try:
            mission = decode_mission(payload)
        except WireError as exc:
            self.rejections.reject(key, str(exc))
            return False
        with self._lock:
            if mission.version in self.missions:
                return False
            self.missions[mission.version] = mission
            listed = self.robot in mission.robot_ids
            log.info("mission v%d (effective_t %.3f): robot %s %s", mission.version, mission.effective_t,
                     self.robot, "wheel_base %.3f m" % mission.spec(self.robot).wheel_base if listed
                     else "not listed")
            if not listed and max(self.missions) == mission.version:
                self.stats.unlisted += 1
                self.zero("unlisted")
            return True

    def on_mission_replies(self, mission_key: str, replies: list[tuple[str, bytes]]) -> bool:
        """Replies to the start-up query: the operator's answer on ``mission_key`` is taken;
        otherwise the answer a strict majority of the agents' queryables gave."""
        taken = False
        peers = []
        for key, payload in replies:
            if key == mission_key:
                taken = self.on_mission(key, payload) or taken
            else:
                peers.append((key.rsplit("/", 2)[-2], payload))
        if taken:
            return True
        verdict = majority(peers)
        if verdict.answer is not None:
            return self.on_mission(f"{mission_key} (peers {','.join(verdict.supporters)})", verdict.answer)
        return False

    def mission_for(self, t: float) -> Mission | None:
        """The newest mission in force at tracker time t [s]; the earliest known if none is yet."""
        if not self.missions:
            return None
        live = [m for m in self.missions.values() if m.effective_t <= t]
        return max(live, key=lambda m: m.version) if live else self.missions[min(self.missions)]

    # ------------------------------------------------------------ commands
    def on_cmd(self, key: str, payload: bytes) -> None:
        """One vsfleet command: a Twist valid for its ttl, or (no mission, robot unlisted) a zero."""
        try:
            cmd = decode_cmd(payload)
        except WireError as exc:
            self.rejections.reject(key, str(exc))
            return
        with self._lock:
            if self.closed:
                return
            now = self.clock()
            if cmd.t < self.last_t:
                self.stats.stale += 1
                self.rejections.reject(key, f"command t {cmd.t:.3f} older than {self.last_t:.3f}")
                return
            mission = self.mission_for(cmd.t)
            if mission is None or self.robot not in mission.robot_ids:
                if mission is None:
                    self.stats.no_mission += 1
                else:
                    self.stats.unlisted += 1
                if self.moving or self.deadline is not None:
                    self.zero("no-mission" if mission is None else "unlisted")
                return
            spec = mission.spec(self.robot)
            lim = spec.wheel_speed_max
            vl, vr = (min(max(cmd.vl, -lim), lim), min(max(cmd.vr, -lim), lim))
            v, w = twist_from_wheels(vl, vr, spec.wheel_base)
            self.last_t = cmd.t
            self.stats.commands += 1
            self.deadline = now + cmd.ttl
            self._twist(v, w, "cmd")

    def expire(self) -> float | None:
        """Send the zero if the running command's ttl has run out; returns the pending deadline."""
        with self._lock:
            if self.deadline is not None and self.clock() >= self.deadline:
                self.stats.expired += 1
                self.zero("expired")
            return self.deadline


def fetch_mission(session: zenoh.Session, keys: Keys, bridge: CmdBridge, timeout_s: float) -> bool:
    """Ask the operator's key and the agents' queryables for the mission, as agents do at start."""
    replies: list[tuple[str, bytes]] = []
    for selector in (keys.mission, keys.peer_mission("*")):
        for reply in session.get(selector, timeout=timeout_s, target=zenoh.QueryTarget.ALL,
                                 consolidation=zenoh.ConsolidationMode.NONE):
            if reply.ok is not None:
                replies.append((str(reply.ok.key_expr), reply.ok.payload.to_bytes()))
    return bridge.on_mission_replies(keys.mission, replies)


class TwistPublisher:
    """A ROS 2 publisher as rmw_zenoh makes one: data key, attachment, node and MP liveliness tokens."""

    def __init__(self, session: zenoh.Session, *, node: rz.Node, topic: str, distro: str,
                 layout: rz.Attachment = rz.Attachment.CURRENT, eid: int = 1) -> None:
        self.distro, self.layout = distro, layout
        self.key = rz.data_keyexpr(node.domain, topic, rz.TWIST, distro)
        self.node_token = node.token()
        self.pub_token = node.endpoint_token("MP", eid, topic, rz.TWIST, distro)
        self.gid = rz.gid_of(self.pub_token)
        self.seq = 0
        self._session = session
        self._tokens: list = []
        self._pub = session.declare_publisher(self.key, encoding=zenoh.Encoding.APPLICATION_CDR,
                                              congestion_control=zenoh.CongestionControl.BLOCK,
                                              priority=zenoh.Priority.REAL_TIME, express=True,
                                              reliability=zenoh.Reliability.RELIABLE)

    def declare_tokens(self) -> None:
        """Make the publisher visible in the ROS graph (``ros2 topic list``): its NN and MP tokens."""
        self._tokens = [self._session.liveliness().declare_token(t) for t in (self.node_token, self.pub_token)]

    def send(self, v_m_s: float, w_rad_s: float, reason: str) -> None:
        self.seq += 1
        self._pub.put(rz.encode_twist(v_m_s, w_rad_s, self.distro),
                      attachment=rz.encode_attachment(self.seq, time.time_ns(), self.gid, self.layout))
        log.debug("twist #%d v=%.3f w=%.3f (%s)", self.seq, v_m_s, w_rad_s, reason)

    def close(self) -> None:
        self._pub.undeclare()
        for t in self._tokens:
            t.undeclare()


def open_session(conf: zenoh.Config) -> zenoh.Session:
    """The programs' common opener (``zconf.open_session``: a one-line error without a router)
    where this checkout has it, else zenoh's own."""
    return getattr(zconf, "open_session", zenoh.open)(conf)


def ros_client_config(endpoint: str) -> zenoh.Config:
    """A client session to the ROS 2 host's own router (``--ros-connect``), multicast scouting off."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


def run_bridge(conf: zenoh.Config, robot: str, fleet: str = "demo", namespace: str = "/",
               topic: str = "cmd_vel", domain: int = 0, distro: str = "jazzy",
               layout: rz.Attachment = rz.Attachment.CURRENT, node_name: str | None = None,
               ros_conf: zenoh.Config | None = None, stop: StopFlag | None = None,
               ready: threading.Event | None = None) -> BridgeStats:
    """Run until ``stop``; returns the counters. The last thing it publishes is a zero Twist.

    With ``ros_conf`` the ROS 2 side gets a session of its own (the robot's router), and ``conf``
    is only for vsfleet (the lab router); otherwise one session serves both."""
    stop = stop or StopFlag()
    keys = Keys(fleet)
    full_topic = rz.resolve_topic(namespace, topic)
    with contextlib.ExitStack() as stack:
        session = stack.enter_context(open_session(conf))
        ros = stack.enter_context(open_session(ros_conf)) if ros_conf is not None else session
        node = rz.Node(domain=domain, zid=str(ros.info.zid()), nid=0, namespace=namespace,
                       name=node_name or f"vsfleet_bridge_{robot}")
        out = TwistPublisher(ros, node=node, topic=full_topic, distro=distro, layout=layout)
        bridge = CmdBridge(robot, out.send)
        log.info("robot %s: %s -> %s (%s, ROS domain %d)", robot, keys.cmd(robot), out.key, distro, domain)
        subs = [session.declare_subscriber(keys.mission, lambda s: bridge.on_mission(
                    str(s.key_expr), s.payload.to_bytes())),
                session.declare_subscriber(keys.cmd(robot), lambda s: bridge.on_cmd(
                    str(s.key_expr), s.payload.to_bytes()))]
        bridge.zero("start")
        out.declare_tokens()  # visible once it listens: a tool that sees the topic can command
        fetcher_stop = threading.Event()

        def fetch_until_known() -> None:
            while not (stop.is_set() or fetcher_stop.is_set()) and not bridge.missions:
                try:
                    fetch_mission(session, keys, bridge, FETCH_PERIOD_S)
                except zenoh.ZError as exc:
                    log.warning("mission query failed: %s", exc)
                if not bridge.missions:
                    stop.wait(FETCH_PERIOD_S)

        fetcher = threading.Thread(target=fetch_until_known, name="mission-fetch", daemon=True)
        fetcher.start()
        if ready is not None:
            ready.set()
        next_stats = time.monotonic() + STATS_PERIOD_S
        try:
            while not stop.is_set():
                deadline = bridge.expire()
                now = time.monotonic()
                wait = TICK_S if deadline is None else min(TICK_S, max(0.0, deadline - now))
                stop.wait(wait)
                if now >= next_stats:
                    log.info("stats %s", bridge.stats)
                    next_stats = now + STATS_PERIOD_S
        finally:
            for s in subs:
                s.undeclare()
            fetcher_stop.set()
            bridge.shutdown()
            log.info("stopped: %s", bridge.stats)
            out.close()
    return bridge.stats


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet bridge ros2", description=__doc__.splitlines()[0])
    p.add_argument("--robot", required=True, help="the robot id in the mission (vs/<fleet>/cmd/<robot>)")
    p.add_argument("--fleet", default="demo")
    p.add_argument("--namespace", default="/", help="the robot's ROS namespace, e.g. /r1 (default /)")
    p.add_argument("--topic", default="cmd_vel", help="relative to the namespace unless absolute")
    p.add_argument("--domain", type=int, default=0, help="ROS_DOMAIN_ID")
    p.add_argument("--distro", choices=rz.DISTROS, default="jazzy")
    p.add_argument("--attachment", choices=[a.value for a in rz.Attachment], default="current",
                   help="attachment layout: current (humble >= 0.1.2, jazzy >= 0.2.4) or keyed (older)")
    p.add_argument("--node-name", default=None, help="ROS node name (default vsfleet_bridge_<robot>)")
    p.add_argument("--ros-connect", default=None, metavar="ENDPOINT",
                   help="reach ROS 2 through this router (e.g. tcp/127.0.0.1:7447) in a session of its "
                        "own; the zenoh flags below are then for the vsfleet side only")
    return common_flags(p)


@program(build_parser, log)
def main(args: argparse.Namespace) -> int:
    try:  # refused flags: one line on stdout, exit code 2
        check_name(args.robot, "robot")
        rz.resolve_topic(args.namespace, args.topic)
        if not 0 <= args.domain <= 232:
            raise ValueError(f"--domain must be 0..232, got {args.domain}")
    except ValueError as exc:
        print(f"vsfleet bridge ros2: {exc}", flush=True)
        return 2
    run_bridge(zenoh_config(args), args.robot, args.fleet, args.namespace, args.topic, args.domain,
               args.distro, rz.Attachment(args.attachment), args.node_name,
               ros_client_config(args.ros_connect) if args.ros_connect else None)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
