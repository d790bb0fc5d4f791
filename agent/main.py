"""vsfleet agent: one identical process per robot; fits, advances, commands its own wheels.

Startup: declare the liveliness token, subscribe to mission updates and poses,
answer mission and health queries under its own key ``vs/<fleet>/peer/<robot>/``
(so late joiners and restarted agents get the mission and the failure-policy
state from their peers), and ask for both with a get. An answer is taken only
if a strict majority of the peers that replied gave it (vsfleet.quorum); the
operator's mission (its put, or its answer on ``vs/<fleet>/mission``) is taken
as it is. Then, at every frame (see agent.frames), run
``vsfleet.step.control_step`` and publish ``cmd/<robot>``, ``state/<robot>`` and
``event/<robot>``. On any exit it publishes a zero command.
"""

from __future__ import annotations

import argparse
import logging
import math
import queue
import threading
from typing import Callable

import zenoh

from fleetctl.lifecycle import Rejections, StopFlag, wall_clock
from fleetctl.zconf import RELIABLE_QOS, STREAM_QOS, TELEMETRY_QOS, add_zenoh_args, init_logging, open_session, zenoh_config
from vsfleet.control import DEFAULT_CONTROLLER, make_controller
from vsfleet.errors import VsfleetValueError
from vsfleet.failure import Decision, FailurePolicy, Health, Motion, update_health, update_motion
from vsfleet.quorum import majority
from vsfleet.step import Controller, control_step, expected_steps
from vsfleet.wire import (
    CmdMsg,
    EventMsg,
    HealthMsg,
    Keys,
    Mission,
    StateMsg,
    WireError,
    check_name,
    decode_health,
    decode_mission,
    decode_pose,
    encode,
    encode_event,
    encode_health,
    encode_mission,
)

from .frames import Frame, FrameAssembler, MissionBook

log = logging.getLogger("vsfleet.agent")

DEFAULT_TTL_S = 0.3
RESYNC_GAP_S = 1.0  # a longer gap between frames run: this agent may have missed its peers' decisions
FETCH_PERIOD_S = 1.0  # without a mission, ask again this often
DEFAULT_DT_S = 1.0 / 30.0
QUEUE_MAX = 4096


class Agent:
    """The agent's state and its reaction to messages; transport is injected (put functions)."""

    def __init__(self, robot: str, keys: Keys, put_cmd: Callable[[bytes], None],
                 put_state: Callable[[bytes], None], dt_s: float = DEFAULT_DT_S,
                 ttl_s: float = DEFAULT_TTL_S, deadline_s: float | None = None, max_age_s: float = 0.25,
                 clock: Callable[[], float] = wall_clock,
                 put_event: Callable[[bytes], None] = lambda payload: None,
                 controller: Controller | None = None) -> None:
        self.robot = check_name(robot, "robot")
        self.put_event = put_event
        self.controller = controller  # overrides the mission's controller (offline runs, tests)
        self.decisions: list[Decision] = []  # every failure-policy decision, in order
        self.health = Health()
        self.motion = Motion()
        self.predicted: dict[str, tuple[float, float]] = {}  # every robot's last command, predicted
        self.keys = keys
        self.put_cmd = put_cmd
        self.put_state = put_state
        self.dt_s = dt_s
        self.ttl_s = ttl_s
        self.clock = clock
        self.missions = MissionBook()
        self.frames = FrameAssembler((), dt_s if deadline_s is None else deadline_s, max_age_s)
        self.rejections = Rejections(log)
        self.wheels_prev = (0.0, 0.0)
        self.mission_version = -1
        self.last_seq = 0
        self.last_cmd_t = float("-inf")
        self.ticks = 0
        self.waiting = 0
        self.ignored = 0
        self.mission_payload: bytes | None = None
        self.health_payload: bytes | None = None  # answers health queries; swapped in after each tick
        self.health_adopted = False
        self.want_health = True   # ask the peers for their failure state (at start, and after a gap)
        self.resyncing = False    # after a gap: adopt only which robots are failed or dropped
        self.last_frame_t = float("-inf")
        self.stale_logged = 0
        self.no_quorum = 0        # queries whose replies had no majority answer
        self.unnamed_logged: set[int] = set()
        self._controllers: dict[str, object] = {}

    # ------------------------------------------------------------ inputs
    def on_mission(self, key: str, payload: bytes) -> bool:
        """Take a mission from the operator (its put) or agreed by the peers; True if it is new."""
        try:
            mission = decode_mission(payload)
        except WireError as exc:
            self.rejections.reject(key, str(exc))
            return False
        if self.missions.add(mission):
            log.info("mission v%d (%s, %d robots, effective_t %.3f)", mission.version,
                     mission.metric, len(mission.robots), mission.effective_t)
            latest = self.missions.latest()
            self.mission_payload = encode_mission(latest)  # one assignment: read by the queryable
            self.frames.set_robots(latest.robot_ids)
            return True
        return False

    def on_pose(self, key: str, payload: bytes) -> None:
        try:
            robot = self.keys.robot_of(key, "pose")
            msg = decode_pose(payload)
        except WireError as exc:
            self.rejections.reject(key, str(exc))
            return
        if self.missions.latest() is None:
            self.waiting += 1  # no mission yet: nothing to do with poses
            return
        if not any(robot in m.robot_ids for m in self.missions.by_version.values()):
            self.ignored += 1  # a tracked object that no mission names: not an error
            return
        before = self.frames.refused_future
        self.frames.offer(robot, msg, self.clock())
        n = self.frames.refused_future
        if n > before and (n <= 10 or n % 100 == 0):
            log.warning("pose #%d from the future refused: t %.3f is more than %.2f s ahead of this "
                        "host's clock (clock skew?)", n, msg.t, self.frames.max_future_s)

    def on_health(self, key: str, payload: bytes, timers: bool = True) -> bool:
        """Adopt the peers' failure-policy state (agreed by a majority, see on_query_replies) once,
        at (re)start, so decisions agree at once; after a gap (or with ``timers`` False), only
        which robots are failed or dropped. True if adopted."""
        try:
            msg = decode_health(payload)
        except WireError as exc:
            self.rejections.reject(key, str(exc))
            return False
        if self.health_adopted or msg.mission not in self.missions.by_version:
            return False
        since = self.health.since_t if self.resyncing or not timers else dict(msg.since)
        self.health = Health(since_t=since, failed=frozenset(msg.failed), dropped=frozenset(msg.dropped))
        self.health_adopted = True
        log.info("adopted peers' failure state at frame %d: failed %s, dropped %s", msg.seq,
                 sorted(msg.failed), sorted(msg.dropped))
        return True

    @staticmethod
    def health_vote(payload: bytes, timers: bool) -> bytes | None:
        """What peers must agree on in a health reply: what this agent would adopt from it (the
        mission version, failed, dropped and, with ``timers``, since), canonically encoded.
        ``t`` and ``seq`` are left out: peers answer at whatever frame they are on. None if invalid."""
        try:
            msg = decode_health(payload)
        except WireError:
            return None
        return encode_health(HealthMsg(t=0.0, seq=0, mission=msg.mission, failed=tuple(sorted(set(msg.failed))),
                                       dropped=tuple(sorted(set(msg.dropped))), since=msg.since if timers else ()))

    def on_query_replies(self, kind: str, replies: list[tuple[str, bytes]]) -> bool:
        """Every reply to one ``kind`` query ("mission" or "health"), as (key, payload); True if
        something was taken.

        A reply on ``vs/<fleet>/mission`` is the operator's (only that login may answer there) and
        is taken like its put. A peer answers under ``vs/<fleet>/peer/<robot>/<kind>``; this
        agent's own replies are left out. A peer answer is taken only if a strict majority of the
        distinct peers that replied gave it (identical payloads; for health, identical
        ``health_vote``: if the majority agrees on the decisions but not on the failure timers,
        the decisions are adopted and this agent's timers start afresh, as after a gap).
        Otherwise nothing is taken and the reason is logged: without a mission the agent asks
        again a second later; without agreed health it keeps its own state.
        """
        taken = False
        peers: list[tuple[str, str, bytes]] = []  # (peer, key, payload)
        for key, payload in replies:
            if kind == "mission" and key == self.keys.mission:
                taken = self.on_mission(key, payload) or taken
                continue
            try:
                peer = self.keys.peer_of(key, kind)
            except WireError as exc:
                self.rejections.reject(key, str(exc))
                continue
            if peer == self.robot:
                continue
            if kind == "health" and self.health_vote(payload, timers=False) is None:
                self.rejections.reject(key, "not a valid health message")
            peers.append((peer, key, payload))
        if kind == "mission":
            verdict = majority((peer, payload) for peer, _, payload in peers)
            if verdict.answer is not None:
                return self.on_mission(self.keys.peer_mission(verdict.supporters[0]), verdict.answer) or taken
        else:
            for timers in ((False,) if self.resyncing else (True, False)):
                votes = [(peer, self.health_vote(payload, timers), key, payload) for peer, key, payload in peers]
                verdict = majority((peer, vote) for peer, vote, _, _ in votes)
                if verdict.answer is not None:
                    key, payload = next((k, p) for _, v, k, p in votes if v == verdict.answer)
                    if not timers and not self.resyncing:
                        log.info("health query: peers %s agree on the decisions, not on the failure timers; "
                                 "adopting the decisions with this agent's own timers", list(verdict.supporters))
                    adopted = self.on_health(key, payload, timers=timers)
                    if not adopted and not self.health_adopted:
                        log.warning("health query: peers %s agree on a mission this agent does not hold; "
                                    "keeping its own failure state", list(verdict.supporters))
                    return adopted
        if taken:
            return True
        if not verdict.peers:  # the first agent up, or its peers have nothing yet
            log.log(logging.INFO if kind == "health" else logging.DEBUG, "%s query: no peer answered%s", kind,
                    "; keeping this agent's own failure state" if kind == "health" else "")
            return False
        self.no_quorum += 1
        n = self.no_quorum
        if n <= 10 or n % 100 == 0:
            then = ("asking again in %.0f s" % FETCH_PERIOD_S if kind == "mission"
                    else "keeping this agent's own failure state")
            log.warning("%s query #%d: nothing taken: %s; %s", kind, n, verdict.why, then)
        return False

    def on_message(self, kind: str, key: str, payload) -> None:
        """Dispatch one message (or, for "mission-replies"/"health-replies", the list of replies
        to one query); nothing a peer sends may end the agent."""
        handlers = {"pose": self.on_pose, "mission": self.on_mission,
                    "mission-replies": lambda _key, replies: self.on_query_replies("mission", replies),
                    "health-replies": lambda _key, replies: self.on_query_replies("health", replies)}
        try:
            handlers[kind](key, payload)
        except Exception as exc:  # noqa: BLE001 - counted and logged, never fatal
            self.rejections.reject(key, f"unexpected {type(exc).__name__}: {exc}")

    # ------------------------------------------------------------ control
    def controller_for(self, mission: Mission) -> Controller:
        if self.controller is not None:
            return self.controller
        name = mission.controller or DEFAULT_CONTROLLER
        if name not in self._controllers:
            try:
                self._controllers[name] = make_controller(name)
            except VsfleetValueError as exc:
                log.error("mission v%d names %s; using %s", mission.version, exc, DEFAULT_CONTROLLER)
                self._controllers[name] = make_controller(DEFAULT_CONTROLLER)
        return self._controllers[name]

    def poll(self) -> Frame | None:
        """Process the frame that is due now, if any; returns it."""
        frame = self.frames.ready(self.clock())
        if frame is not None:
            self.tick(frame)
        elif self.frames.stale > self.stale_logged:
            n = self.stale_logged = self.frames.stale
            if n <= 10 or n % 100 == 0:
                log.warning("stale frame #%d skipped: tracker time more than %.2f s behind this host's "
                            "clock (clock skew or a stalled link); the robot halts", n,
                            self.frames.max_stale_s)
        return frame

    def tick(self, frame: Frame) -> None:
        mission = self.missions.active(frame.t)
        if mission is None or self.robot not in mission.robot_ids:
            self.wheels_prev = (0.0, 0.0)  # no command: the robot halts after ttl
            if mission is not None and mission.version not in self.unnamed_logged:
                self.unnamed_logged.add(mission.version)
                log.warning("mission v%d does not name robot %s: it stays stopped", mission.version,
                            self.robot)
            return
        if mission.version != self.mission_version:
            log.info("frame %d: switching to mission v%d", frame.seq, mission.version)
            self.mission_version = mission.version
        if frame.t - self.last_cmd_t > self.ttl_s:
            # a gap longer than ttl: every robot has halted since the last commands
            self.wheels_prev = (0.0, 0.0)
            self.predicted = {}
        if frame.t - self.last_frame_t > RESYNC_GAP_S and self.last_frame_t > float("-inf"):
            # this agent (or the whole fleet) saw no frame for a while: restart the failure
            # timers and the motion window, and ask the peers which robots they failed or dropped
            log.warning("frame %d: no frame for %.2f s; restarting failure timers and asking peers "
                        "for their failure state", frame.seq, frame.t - self.last_frame_t)
            self.motion = Motion()
            self.health = Health(failed=self.health.failed, dropped=self.health.dropped)
            self.health_adopted, self.want_health, self.resyncing = False, True, True
        self.last_frame_t = frame.t
        poses = {r: p for r, p in frame.poses.items() if r in mission.robot_ids}
        try:
            result = control_step(mission, poses, self.robot, frame.t, self.dt_s,
                                  self.wheels_prev, self.controller_for(mission),
                                  excluded=self.health.dropped,
                                  drive_excluded=mission.on_failure == "rejoin",
                                  others_wheels_prev=self.predicted,
                                  judged_apart=(self.health.failed - self.health.dropped
                                                if mission.on_failure == "hold" else frozenset()))
        except (VsfleetValueError, ArithmeticError, ValueError, MemoryError) as exc:
            self.rejections.reject(self.keys.pose(), f"frame {frame.seq} unusable: {exc!r}")
            return
        if result is None:
            return
        self.wheels_prev = (result.vl_m_s, result.vr_m_s)
        self.last_seq = frame.seq
        self.last_cmd_t = frame.t
        self.ticks += 1
        self.put_cmd(encode(CmdMsg(t=frame.t, seq=frame.seq, vl=result.vl_m_s, vr=result.vr_m_s,
                                   ttl=self.ttl_s)))
        if not math.isnan(result.err_m):
            f, g = result.fit_pose, result.goal_pose
            self.put_state(encode(StateMsg(
                t=frame.t, seq=frame.seq, x=f.x, y=f.y, th=f.th, gx=g.x, gy=g.y, gth=g.th,
                cost=result.cost, err=result.err_m, used=result.used,
                rejected=self.rejections.count, complete=frame.complete, mission=mission.version)))
        policy = FailurePolicy(mission.on_failure)
        self.predicted = dict(result.commands)
        # the motion test takes only poses of this very frame: a pose held over from an earlier
        # frame (run on the deadline) would count as "did not move" here and double next frame,
        # and agents that got that pose in time would disagree on the frame of a decision
        moved = {r: p for r, p in poses.items() if r in frame.fresh}
        self.motion, progress = update_motion(policy, self.motion, moved,
                                              expected_steps(mission, moved, {r: c for r, c in result.commands.items()
                                                                              if r in moved}, self.dt_s),
                                              frame.t, step_s=self.dt_s, max_gap_s=self.ttl_s)
        self.health, decisions = update_health(policy, self.health, result.deviations_m,
                                               mission.robot_ids, frame.t, progress)
        self.decisions.extend(decisions)
        h = self.health
        self.health_payload = encode_health(HealthMsg(
            t=frame.t, seq=frame.seq, mission=mission.version, failed=tuple(sorted(h.failed)),
            dropped=tuple(sorted(h.dropped)), since=tuple(sorted(h.since_t.items()))))
        for d in decisions:
            log.warning("frame %d: robot %s %s (deviation %.3f m, on_failure=%s)", frame.seq, d.robot,
                        d.kind, d.deviation_m, mission.on_failure)
            self.put_event(encode_event(EventMsg(t=d.t, seq=frame.seq, robot=d.robot, kind=d.kind,
                                                 dev=d.deviation_m, by=self.robot)))

    def stop_command(self) -> bytes:
        self.wheels_prev = (0.0, 0.0)
        return encode(CmdMsg(t=self.clock(), seq=self.last_seq, vl=0.0, vr=0.0, ttl=self.ttl_s))


def fetch(session: zenoh.Session, selectors: tuple[str, ...], kind: str, inbox: queue.Queue,
          timeout_s: float) -> None:
    """Ask ``selectors`` (for the mission or the peers' health) and collect every reply, unconsolidated,
    until the gets end; then the whole list goes to the agent's inbox as one item."""
    gets = [session.get(s, timeout=timeout_s, target=zenoh.QueryTarget.ALL,
                        consolidation=zenoh.ConsolidationMode.NONE, allowed_destination=zenoh.Locality.REMOTE)
            for s in selectors]
    replies: list[tuple[str, bytes]] = []
    for handler in gets:
        for reply in handler:
            if reply.ok is not None:
                replies.append((str(reply.ok.key_expr), reply.ok.payload.to_bytes()))
    try:
        inbox.put((f"{kind}-replies", "|".join(selectors), replies), timeout=timeout_s)
    except queue.Full:
        log.warning("%s query: inbox full, %d replies dropped", kind, len(replies))


def run_agent(conf: zenoh.Config, robot: str, fleet: str = "demo", stop: StopFlag | None = None,
              dt_s: float = DEFAULT_DT_S, ttl_s: float = DEFAULT_TTL_S,
              deadline_s: float | None = None) -> Agent:
    """Run one agent until ``stop`` is set; always ends with a zero command."""
    stop = stop or StopFlag()
    keys = Keys(fleet)
    inbox: queue.Queue = queue.Queue(maxsize=QUEUE_MAX)
    overflow = [0]

    def enqueue(kind: str):
        def cb(sample: zenoh.Sample) -> None:
            try:
                inbox.put_nowait((kind, str(sample.key_expr), sample.payload.to_bytes()))
            except queue.Full:
                overflow[0] += 1
                agent.rejections.reject(str(sample.key_expr), "inbox full (flood)")
        return cb

    with open_session(conf) as session:
        cmd_pub = session.declare_publisher(keys.cmd(robot), **STREAM_QOS)
        state_pub = session.declare_publisher(keys.state(robot), **TELEMETRY_QOS)
        event_pub = session.declare_publisher(keys.event(robot), **RELIABLE_QOS)
        agent = Agent(robot, keys, cmd_pub.put, state_pub.put, dt_s=dt_s, ttl_s=ttl_s,
                      deadline_s=deadline_s, put_event=event_pub.put)
        token = session.liveliness().declare_token(keys.alive("agent", robot))  # keep referenced

        own_mission, own_health = keys.peer_mission(robot), keys.peer_health(robot)

        def answer_mission(query: zenoh.Query) -> None:
            payload = agent.mission_payload  # a bytes object swapped in by the main thread
            if payload is not None:
                query.reply(own_mission, payload)

        def answer_health(query: zenoh.Query) -> None:
            payload = agent.health_payload  # likewise
            if payload is not None:
                query.reply(own_health, payload)

        subs = [
            session.declare_subscriber(keys.mission, enqueue("mission")),
            session.declare_subscriber(keys.pose(), enqueue("pose")),
        ]
        queryables = [session.declare_queryable(own_mission, answer_mission, complete=False),
                      session.declare_queryable(own_health, answer_health, complete=False)]
        log.info("agent %s up (fleet %s)", robot, fleet)
        next_fetch = 0.0
        fetcher: threading.Thread | None = None
        try:
            while not stop.is_set():
                now = agent.clock()
                idle = not (fetcher and fetcher.is_alive())
                if agent.missions.latest() is None and now >= next_fetch and idle:
                    # the operator's answer, if its tool is up, and every peer's
                    fetcher = threading.Thread(target=fetch, args=(
                        session, (keys.mission, keys.peer_mission()), "mission", inbox, 1.0), daemon=True)
                    fetcher.start()
                    next_fetch = now + FETCH_PERIOD_S
                elif agent.missions.latest() is not None and agent.want_health and idle:
                    agent.want_health = False  # a (re)started or resynced agent takes its peers' state
                    fetcher = threading.Thread(target=fetch, args=(
                        session, (keys.peer_health(),), "health", inbox, 1.0), daemon=True)
                    fetcher.start()
                wait = agent.frames.time_to_deadline(now)
                try:
                    kind, key, payload = inbox.get(timeout=0.05 if wait is None else max(wait, 1e-4))
                except queue.Empty:
                    pass
                else:
                    agent.on_message(kind, key, payload)
                    # drain what has already arrived before deciding on a frame
                    while True:
                        try:
                            kind, key, payload = inbox.get_nowait()
                        except queue.Empty:
                            break
                        agent.on_message(kind, key, payload)
                agent.poll()
        finally:
            cmd_pub.put(agent.stop_command())
            log.info("agent %s stopping after %d ticks, %d rejected (%d on overflow), %d stale frames",
                     robot, agent.ticks, agent.rejections.count, overflow[0], agent.frames.stale)
            for s in subs:
                s.undeclare()
            for q in queryables:
                q.undeclare()
            token.undeclare()
            if fetcher is not None:
                fetcher.join(timeout=2.0)
    return agent


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet agent", description=__doc__.splitlines()[0])
    p.add_argument("--robot", required=True, help="this agent's robot id")
    p.add_argument("--fleet", default="demo", help="fleet name (key prefix vs/<fleet>)")
    p.add_argument("--dt", type=float, default=DEFAULT_DT_S,
                   help="control step [s]: the structure is advanced by one dt per frame")
    p.add_argument("--ttl", type=float, default=DEFAULT_TTL_S, help="command time-to-live [s]")
    p.add_argument("--deadline", type=float, default=None,
                   help="run an incomplete frame this long [s] after its first pose (default: --dt)")
    p.add_argument("--verbose", "-v", action="store_true")
    add_zenoh_args(p)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    init_logging(args.verbose)
    try:
        check_name(args.robot, "robot")
        check_name(args.fleet, "fleet")
    except WireError as exc:
        log.error("%s", exc)
        return 2
    if args.deadline is not None and not 0.0 < args.deadline <= 1.0:
        log.error("--deadline must be in (0, 1] s")
        return 2
    run_agent(zenoh_config(args), args.robot, args.fleet, dt_s=args.dt, ttl_s=args.ttl,
              deadline_s=args.deadline)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
