"""vsfleet agent: one identical process per robot; fits, advances, commands its own wheels.

The process is an adapter around the pure step (vsfleet.step.agent_step):
decode -> step -> publish and log. Startup: subscribe to mission updates and
to frames (``vs/<fleet>/frame/*``), then declare the liveliness token (alive
means listening), answer mission and health queries under its own key
``vs/<fleet>/peer/<robot>/`` (so
late joiners and restarted agents get the mission and the failure-policy state
from their peers), and ask for both with a get. An answer is taken only if a
strict majority of the peers that replied gave it (vsfleet.quorum); the
operator's mission (its put, or its answer on ``vs/<fleet>/mission``) is taken
as it is. Joining costs a bounded number of messages, not one per peer: once the
operator has answered (or the agent holds a mission) it asks only the
PEERS_ASKED robots after its own in the mission's sorted ids (peers_to_ask), so
a fleet of N agents starting together exchanges O(N) queries, not N^2. Frames
land in a latest-frame slot per source: a newer frame replaces one not yet run
(counted). On any exit it publishes a zero command.
"""

from __future__ import annotations

import argparse
import bisect
import collections
import functools
import math
import logging
import queue
import threading
from typing import Callable

import zenoh

from vsfleet.zglue.lifecycle import Rejections, StopFlag, wall_clock
from vsfleet.zglue.program import Refused, common_flags, program, refusing
from vsfleet.zglue.zconf import (
    RELIABLE_QOS,
    COMMAND_QOS,
    TELEMETRY_QOS,
    open_session,
    zenoh_config,
)
from vsfleet.errors import VsfleetValueError
from vsfleet.failure import Decision
from vsfleet.frames import MAX_AGE_S, Frame, FrameMerger, MissionBook
from vsfleet.quorum import majority
from vsfleet.agentcore import (  # the agent's step, in the core and without numpy (issue 29)
    AgentState,
    Controller,
    StepConfig,
    SyncPhase,
    adopt_health,
    agent_payload_step,
    agent_step,
    core_mission_of,
    first_plan,
    in_first_plan,
    stop_command,
)
from vsfleet.wire import (
    HealthMsg,
    Mission,
    FrameMsg,
    Keys,
    WireError,
    check_name,
    decode_health,
    decode_mission,
    encode,
    encode_event,
    encode_health,
    encode_mission,
)

log = logging.getLogger("vsfleet.agent")

DEFAULT_TTL_S = 0.3
FETCH_PERIOD_S = 1.0  # without a mission, ask again this often
DEFAULT_DT_S = 1.0 / 30.0
INBOX_MAX = 256       # missions and query replies (frames go to the latest-frame slot)
DECISIONS_KEPT = 1000  # the newest failure-policy decisions an agent keeps (Agent.decisions)
# How many peers a joining agent asks, once it knows the mission's robots (peers_to_ask): a bounded number, so a
# fleet's start costs O(N) queries. Asking every peer made it N^2: at N = 100, 2 x 9,900 queries, each one a Python
# callback in the agent that received it (bench/loop.py's start-up, docs/benchmarks.md, issue 29).
PEERS_ASKED = 5


def peers_to_ask(robot_ids, robot: str, k: int = PEERS_ASKED) -> tuple[str, ...]:
    """The ``k`` robots after ``robot`` in sorted id order, wrapping round (``robot`` itself left out): whom a
    joining agent asks. Each robot is asked by the ``k`` before it, so no agent answers more than ``k`` joiners
    of one fleet start, and every agent that holds the same mission asks the same peers whatever it heard."""
    ids = sorted(set(robot_ids) - {robot})
    if not ids:
        return ()
    start = bisect.bisect_right(ids, robot)
    return tuple(ids[(start + i) % len(ids)] for i in range(min(k, len(ids))))


def discard(payload: bytes) -> None:
    """An Agent's put_event when none is given: its events go nowhere."""


class Agent:
    """The agent's transport-facing side: its state, a latest-frame slot, and what it publishes.

    Transport is injected (put functions) and so is the clock; every decision is agent_step's.
    """

    def __init__(self, robot: str, keys: Keys, put_cmd: Callable[[bytes], None],
                 put_state: Callable[[bytes], None], dt_s: float = DEFAULT_DT_S,
                 ttl_s: float = DEFAULT_TTL_S, deadline_s: float | None = None, max_age_s: float = MAX_AGE_S,
                 clock: Callable[[], float] = wall_clock,
                 put_event: Callable[[bytes], None] = discard,
                 controller: Controller | None = None, command_age_s: float | None = None,
                 shared_structures: dict | None = None, reference: bool = False,
                 prepare: Callable[[Mission], threading.Thread | None] | None = None,
                 log_notes: bool = True) -> None:
        self.robot = check_name(robot, "robot")
        # log_notes: its frames' notes (decisions, blocked, shape) go to the log; the offline runner, which runs a
        # whole fleet of copies in one process, logs one copy's, since every copy computes the same
        self.log_notes = log_notes
        # prepare(mission): called with every new mission before it takes effect (run_agent: its arrays and its
        # room's field built on a thread of their own, so a plan never stalls the frames; None: at its first frame).
        # The thread it returns is kept until a frame first runs that mission (await_prepared)
        self.prepare = prepare
        self._preparing: dict[int, threading.Thread] = {}   # mission version -> the thread building its arrays
        self.following: frozenset[str] = frozenset()   # the tracker sources of the last frame run
        self.keys = keys
        self._frame_head = keys.frame("")   # "vs/<fleet>/frame/": a frame's key is this and its src
        self.put_cmd, self.put_state, self.put_event = put_cmd, put_state, put_event
        self.clock = clock
        self.config = StepConfig(dt_s=dt_s, ttl_s=ttl_s, controller=controller, command_age_s=command_age_s,
                                 shared_structures=shared_structures, reference=reference,
                                 outputs=False)   # cmd, state, health, events: what an agent publishes
        self.state = AgentState(robot)
        self.missions = MissionBook()
        self.merger = FrameMerger((), dt_s if deadline_s is None else deadline_s, max_age_s)
        self.rejections = Rejections(log)
        # the newest DECISIONS_KEPT decisions and blocked/unblocked events, in order (a look at what the agent
        # decided lately): bounded, as the agent runs for ever; every one is published through put_event,
        # where a caller that needs all of them collects them (simfleet.offline does)
        self.decisions: collections.deque[Decision] = collections.deque(maxlen=DECISIONS_KEPT)
        self.mission_payload: bytes | None = None  # answers mission queries; one assignment per change
        self._health_msg: HealthMsg | None = None   # answers health queries; swapped in after each tick
        self._health_encoded: tuple[HealthMsg | None, bytes | None] = (None, None)
        self.no_quorum = 0        # queries whose replies had no majority answer
        self.waiting = 0          # frames that came before any mission
        self.frames_replaced = 0  # frames replaced in the slot before they were run (a flood, or a slow host)
        self._slot: dict[str, FrameMsg] = {}  # src -> the newest frame not yet run
        # the last frame run in one pass (fast_frame), not yet shown to the merger: (key, payload); the merger takes
        # it before the next frame it is offered, so its held poses are those it would hold had it merged that one
        self._fast_last: tuple[str, bytes] | None = None
        self._slot_lock = threading.Lock()
        self.wake = threading.Event()  # set when a frame lands in the slot

    @property
    def health_payload(self) -> bytes | None:
        """The answer to peers' health queries: the last tick's health, encoded on the first ask
        (any thread: the message is swapped in whole, and the cache is one tuple)."""
        msg = self._health_msg
        if msg is None:
            return None
        cached_msg, payload = self._health_encoded
        if cached_msg is not msg:
            payload = encode_health(msg)
            self._health_encoded = (msg, payload)
        return payload

    @property
    def ticks(self) -> int:
        return self.state.ticks

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
            self.merger.set_robots(latest.robot_ids, self.missions.robots())
            if self.prepare is not None:
                thread = self.prepare(mission)
                if thread is not None:
                    for version in [v for v, th in self._preparing.items() if not th.is_alive()]:
                        del self._preparing[version]   # built, and no frame has needed it yet
                    self._preparing[mission.version] = thread
            return True
        return False

    def await_prepared(self, mission: Mission, t: float) -> None:
        """A frame at time t [s] is about to run ``mission``: if its prepare thread is still building the arrays
        it needs, wait for that build rather than start a second one beside it (the frame would build the same bits;
        it took the CPU the thread needed and finished no sooner). A frame of the mission's first plan
        (in_first_plan) waits for that plan's arrays only (PrepareThread.first_built), and the thread is kept for
        the frames after it; any other waits for the whole build, and the thread is forgotten. Only the long way
        (tick) calls it: a mission's first frame never goes in one pass (vsfleet.agentcore.agent_payload_step), nor
        does a frame while the mission's prepare thread builds what that frame may need (fast_frame). The caller holds
        the agent."""
        thread = self._preparing.get(mission.version)
        if thread is None:
            return
        first_built = getattr(thread, "first_built", None)
        if first_built is not None and in_first_plan(mission, t):
            first_built.wait()
            return
        del self._preparing[mission.version]
        thread.join()

    def on_frame(self, key: str, payload: bytes, wake: bool = True) -> None:
        """Decode a frame (any thread) into the latest-frame slot of its source: a newer one replaces
        one not yet run (counted in frames_replaced); an invalid one is rejected (counted, logged).
        wake: wake the main loop for it (False: the caller runs poll itself)."""
        try:
            if not key.startswith(self._frame_head):
                raise WireError(f"key {key!r} is not under {self._frame_head}")
            # the core's decoder (a reference agent: the readable one); either checks that src is the key's last chunk
            msg = self.config.impl.decode_frame(payload, key[len(self._frame_head):])
        except (WireError, UnicodeEncodeError) as exc:  # UnicodeEncodeError: a key that is not UTF-8
            self.rejections.reject(key, str(exc))
            return
        with self._slot_lock:
            if msg.src not in self._slot and len(self._slot) >= FrameMerger.MAX_SOURCES:
                self.rejections.reject(key, "too many frame sources")
                return
            if msg.src in self._slot:
                self.frames_replaced += 1
            self._slot[msg.src] = msg
        if wake:
            self.wake.set()

    def fast_frame(self, key: str, payload: bytes) -> bool:
        """Run a frame in one pass from its payload to the command's and the state's (vsfleet.step.agent_payload_step)
        when it is the common case: one source, which this agent already follows (no other heard within the merger's
        max_age_s), every robot of the one mission held in it, and nothing waiting in the slot or the merger. False:
        the frame was not run (nothing changed); the caller hands it to on_frame and poll, which decide the same bits
        the long way. The caller holds the agent."""
        head = self._frame_head
        merger = self.merger
        if merger.pending is not None or self._slot or not key.startswith(head):
            return False
        src = key[len(head):]
        if self.following != frozenset((src,)) or src not in merger.heard:
            return False
        others_t = max((t for s, t in merger.heard.items() if s != src), default=-math.inf)
        missions = self.missions.by_version
        if len(missions) != 1:
            return False
        (mission,) = missions.values()
        now = self.clock()   # one reading for the test below and the step
        thread = self._preparing.get(mission.version)
        if thread is not None and thread.is_alive():
            # its prepare thread still builds: a frame that may follow the room's own field goes the long way, which
            # waits for the build (await_prepared) instead of building the same field beside it
            first_built = getattr(thread, "first_built", None)
            if (first_built is None or not first_built.is_set()
                    or not in_first_plan(mission, now + merger.max_future_s)):
                return False
        got = agent_payload_step(self.state, mission, payload, src, now, self.config, merger.done,
                                 merger.max_future_s, self.rejections.count, merger.max_age_s, others_t)
        if got is None:
            return False
        self.state, out = got
        merger.done = (out.t, out.seq)
        merger.heard[src] = max(out.t, merger.heard[src])
        self._fast_last = (key, payload)
        if out.cmd is not None:   # None: no robot usable (every one dropped): no command, as the long way
            self.put_cmd(out.cmd)
            self.put_state(out.state)
        self.emit(out.notes, out.events, out.health)
        return True

    def run_frame(self, key: str, payload: bytes) -> None:
        """Run a frame now: in one pass from its payload to the command's when it can (fast_frame), else the long
        way (on_frame, poll), which decides the same bits. The frame callback runs frames so, and so does the offline
        runner. The caller holds the agent."""
        if not self.fast_frame(key, payload):
            self.on_frame(key, payload, wake=False)
            self.poll()

    def take_frames(self) -> None:
        """Hand what the slot holds to the merger (the main thread)."""
        with self._slot_lock:
            items, self._slot = list(self._slot.values()), {}
            self.wake.clear()
        now = self.clock()
        if items and self._fast_last is not None:   # the last frame run in one pass: its poses, held as the merger
            key, payload = self._fast_last          # would hold them (only once a frame goes the long way: the
                                                    # main loop's idle wake-ups, 20 a second, decoded it each time)
            self._fast_last = None
            items.insert(0, self.config.impl.decode_frame(payload, key[len(self._frame_head):]))
        for msg in items:
            if self.missions.latest() is None:
                self.waiting += 1  # no mission yet: nothing to do with frames
                continue
            before = self.merger.refused_future
            self.merger.offer(msg, now)
            n = self.merger.refused_future
            if n > before and (n <= 10 or n % 100 == 0):
                log.warning("frame #%d from the future refused: t %.3f is more than %.2f s ahead of this "
                            "host's clock (clock skew?)", n, msg.t, self.merger.max_future_s)

    def on_health(self, key: str, payload: bytes, timers: bool = True) -> bool:
        """Adopt the peers' failure-policy state (agreed by a majority, see on_query_replies) once,
        at (re)start, so decisions agree at once; after a gap (or with ``timers`` False), only
        which robots are failed or dropped. True if adopted."""
        try:
            msg = decode_health(payload)
        except WireError as exc:
            self.rejections.reject(key, str(exc))
            return False
        if self.state.phase is SyncPhase.SYNCED or msg.mission not in self.missions.by_version:
            return False
        self.state = adopt_health(self.state, msg, timers, self.missions.by_version[msg.mission], self.config)
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
            resyncing = self.state.phase is SyncPhase.RESYNCING
            for timers in ((False,) if resyncing else (True, False)):
                votes = [(peer, self.health_vote(payload, timers), key, payload) for peer, key, payload in peers]
                verdict = majority((peer, vote) for peer, vote, _, _ in votes)
                if verdict.answer is not None:
                    key, payload = next((k, p) for _, v, k, p in votes if v == verdict.answer)
                    if not timers and not resyncing:
                        log.info("health query: peers %s agree on the decisions, not on the failure timers; "
                                 "adopting the decisions with this agent's own timers", list(verdict.supporters))
                    adopted = self.on_health(key, payload, timers=timers)
                    if not adopted and self.state.phase is not SyncPhase.SYNCED:
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
        try:
            if kind == "mission":
                self.on_mission(key, payload)
            elif kind == "mission-replies":
                self.on_query_replies("mission", payload)
            elif kind == "health-replies":
                self.health_replies(payload)
            else:
                raise KeyError(kind)
        except Exception as exc:  # noqa: BLE001 - counted and logged, never fatal
            self.rejections.reject(key, f"unexpected {type(exc).__name__}: {exc}")

    def health_replies(self, replies: list[tuple[str, bytes]]) -> bool:
        """The peers' answers to a health query: adopt the agreed state, else decide alone from now on."""
        adopted = self.on_query_replies("health", replies)
        if not adopted:
            self.state = adopt_health(self.state, None)
        return adopted

    # ------------------------------------------------------------ control
    def poll(self) -> Frame | None:
        """Run the frame that is due now, if any; returns it."""
        self.take_frames()
        frame = self.merger.ready(self.clock())
        if frame is not None:
            if frame.sources != self.following:   # which trackers this agent follows (every agent: the same)
                self.following = frame.sources
                log.info("following tracker source(s) %s (%d poses of other sources shadowed so far: a source "
                         "first in sort order sees the same robots)", sorted(frame.sources), self.merger.shadowed)
            self.tick(frame)
        return frame

    def tick(self, frame: Frame) -> None:
        """decode -> step -> publish and log: one frame through the pure step."""
        mission = self.missions.active(frame.t)
        if self._preparing and mission is not None:
            self.await_prepared(mission, frame.t)
        try:
            self.state, out = agent_step(self.state, mission, frame, self.clock(), self.config)
        except (VsfleetValueError, ArithmeticError, ValueError, MemoryError) as exc:
            self.rejections.reject(self.keys.frame(frame.src or "*"), f"frame {frame.seq} unusable: {exc!r}")
            return
        if out.cmd is not None:
            self.put_cmd(encode(out.cmd))
        if out.state is not None:
            self.put_state(encode(out.state, rejected=self.rejections.count))
        self.emit(out.notes, out.events, out.health)

    def emit(self, notes, events, health) -> None:
        """A frame's log lines, its events (published, and the newest kept), and the health answer from now on."""
        for note in notes if self.log_notes else ():
            log.log(logging.WARNING if note.level == "warning" else logging.INFO, "%s", note.text)
        if health is not None:
            self._health_msg = health  # encoded only when a peer asks (health_payload)
        for ev in events:
            self.decisions.append(Decision(ev.t, ev.robot, ev.kind, ev.dev))
            self.put_event(encode_event(ev))

    def stop_command(self) -> bytes:
        return encode(stop_command(self.state, self.clock(), self.config.ttl_s))


def ask(session: zenoh.Session, selectors: tuple[str, ...], timeout_s: float) -> list[tuple[str, bytes]]:
    """Get ``selectors`` at once and collect every reply, unconsolidated, until the gets end: (key, payload)."""
    gets = [session.get(s, timeout=timeout_s, target=zenoh.QueryTarget.ALL,
                        consolidation=zenoh.ConsolidationMode.NONE, allowed_destination=zenoh.Locality.REMOTE)
            for s in selectors]
    replies: list[tuple[str, bytes]] = []
    for handler in gets:
        for reply in handler:
            if reply.ok is not None:
                replies.append((str(reply.ok.key_expr), reply.ok.payload.to_bytes()))
    return replies


def mission_followup(keys: Keys, robot: str, replies: list[tuple[str, bytes]]) -> tuple[str, ...]:
    """What a mission query asks after the operator's key, given its replies: the PEERS_ASKED peers after
    ``robot`` in the operator's mission (peers may run a newer version than the operator's answer), or, if the
    operator gave no mission, every peer (``peer/*/mission``: only then does one join cost a query per peer).
    fetch takes it bound to the agent's keys and robot (functools.partial)."""
    for key, payload in replies:
        if key == keys.mission:
            try:
                ids = decode_mission(payload).robot_ids
            except WireError:
                continue  # rejected (and counted) when the agent takes the replies
            return tuple(keys.peer_mission(p) for p in peers_to_ask(ids, robot))
    return (keys.peer_mission(),)


def fetch(session: zenoh.Session, selectors: tuple[str, ...], kind: str, inbox: queue.Queue,
          timeout_s: float, wake: threading.Event | None = None,
          then: Callable[[list[tuple[str, bytes]]], tuple[str, ...]] | None = None) -> None:
    """Ask ``selectors`` (for the mission or the peers' health), then, if ``then`` is given, what
    ``then(replies)`` names; collect every reply, unconsolidated, until the gets end; then the whole list goes
    to the agent's inbox as one item."""
    replies = ask(session, selectors, timeout_s)
    if then is not None:
        more = then(replies)
        replies += ask(session, more, timeout_s)
        selectors = (*selectors, *more)
    try:
        inbox.put((f"{kind}-replies", "|".join(selectors), replies), timeout=timeout_s)
    except queue.Full:
        log.warning("%s query: inbox full, %d replies dropped", kind, len(replies))
    if wake is not None:
        wake.set()


def build_mission_arrays(mission: Mission, first_built: threading.Event | None = None) -> None:
    """A mission's constants for the core and its room's field (vsfleet.agentcore.core_mission_of, memoised): those
    of its first plan first, where it has one (first_plan; first_built is set once they are built, or have
    failed), then its own; a failure is logged, and the frame that needs them builds them again and raises there."""
    try:
        try:
            if first_plan(mission):
                core_mission_of(mission, True)
        finally:
            if first_built is not None:
                first_built.set()
        core_mission_of(mission)
    except Exception:  # noqa: BLE001 - the frame that needs it builds it again and raises there
        log.exception("mission v%d: building its arrays failed", mission.version)


class PrepareThread(threading.Thread):
    """A mission's prepare thread (prepare_mission); first_built: set once its first plan's arrays are built."""

    def __init__(self, mission: Mission):
        self.first_built = threading.Event()
        super().__init__(target=build_mission_arrays, args=(mission, self.first_built),
                         name=f"prepare-v{mission.version}", daemon=True)


def prepare_mission(mission: Mission) -> threading.Thread:
    """Build a new mission's arrays (build_mission_arrays) on a thread of their own, while the frames of the
    mission in force go on: the field takes up to ~0.2 s for a large room, and the mission takes effect later
    (mission set: 0.5 s). A frame that needs it sooner waits for this thread (Agent.await_prepared): a frame of the
    mission's first plan (in_first_plan) only for that plan's arrays, which the thread builds first."""
    thread = PrepareThread(mission)
    thread.start()
    return thread


class AgentWiring:
    """One agent's zenoh side: its publishers, subscribers and queryables, and the loop that runs it.

    One thread at a time works on the agent (its inbox, slot, merger and step), holding ``work``. A frame
    runs in the zenoh thread that delivered it whenever that thread can have the agent at once and no
    mission or reply is waiting: no hand-off to the main loop, no second thread woken, which was most of an
    agent's CPU beyond the step. Otherwise the main loop runs it. An error a frame raises in a zenoh thread
    ends the agent as it would in the main loop (``crashed`` holds it for the main loop to raise), and no
    frame runs once the stop command is out (``stopped``). Events are reliable (blocking) puts: the main
    loop publishes them, never a zenoh thread.
    """

    def __init__(self, session: zenoh.Session, robot: str, keys: Keys, dt_s: float, ttl_s: float,
                 deadline_s: float | None) -> None:
        self.session, self.robot, self.keys = session, robot, keys
        self.inbox: queue.Queue = queue.Queue(maxsize=INBOX_MAX)
        self.overflow = 0
        self.work = threading.Lock()
        self.crashed: list[BaseException] = []
        self.stopped = False
        self.events_out: queue.SimpleQueue = queue.SimpleQueue()
        self.cmd_pub = session.declare_publisher(keys.cmd(robot), **COMMAND_QOS)
        self.state_pub = session.declare_publisher(keys.state(robot), **TELEMETRY_QOS)
        self.event_pub = session.declare_publisher(keys.event(robot), **RELIABLE_QOS)
        self.agent = Agent(robot, keys, self.cmd_pub.put, self.state_pub.put, dt_s=dt_s, ttl_s=ttl_s,
                           deadline_s=deadline_s, put_event=self.queue_event, prepare=prepare_mission)
        self.own_mission, self.own_health = keys.peer_mission(robot), keys.peer_health(robot)
        # every attribute a callback reads is set before the first subscriber or queryable is declared: zenoh may
        # call one at once, from its own thread (a peer's health query found no `answered` once, CI rehearsal
        # 2026-12-04, when the token's declaration came between the queryable and these lines)
        self.mission_queryable = None
        self.answered = collections.Counter()  # queries this agent was asked, by kind (logged at the end)
        self.fetcher: threading.Thread | None = None
        self.next_fetch = 0.0
        self.asked_health = False  # in this JOINING or RESYNCING phase
        self.mission_sub = session.declare_subscriber(keys.mission, self.on_mission_sample)
        self.frame_sub = session.declare_subscriber(keys.frame(), self.on_frame_sample)
        # the mission queryable is declared once the agent holds a mission (declare_mission_queryable): until then
        # a peer's ``peer/*/mission`` reaches only agents that can answer it, so a fleet waiting for its mission
        # costs no query per pair of agents each second
        self.queryables = [session.declare_queryable(self.own_health, self.answer_health, complete=False)]
        # alive only once it listens: an operator (or a test) that puts the mission when it sees the token must
        # not find the subscriber still undeclared. Declared first, the token let a loaded host's agent miss that
        # put and take the mission by its once-a-second get, 1 s late, while its peers judged its still robot
        # failed (tests/integration/test_engine_mujoco.py, CI rehearsal 2026-12-04: r2 fail at frame 53, recover
        # at frame 71)
        self.token = session.liveliness().declare_token(keys.alive("agent", robot))  # keep referenced

    # ---------------------------------------------------------------- zenoh threads
    def on_mission_sample(self, sample: zenoh.Sample) -> None:
        """A mission put: into the inbox for the main loop (a full inbox is a counted rejection)."""
        try:
            self.inbox.put_nowait(("mission", str(sample.key_expr), sample.payload.to_bytes()))
        except queue.Full:
            self.overflow += 1
            self.agent.rejections.reject(str(sample.key_expr), "inbox full (flood)")
        self.agent.wake.set()

    def on_frame_sample(self, sample: zenoh.Sample) -> None:
        """A frame: run here if the agent is free and nothing waits in the inbox, else left in the slot."""
        agent = self.agent
        key, payload = str(sample.key_expr), sample.payload.to_bytes()
        if self.inbox.empty() and self.work.acquire(blocking=False):
            try:
                if self.stopped or self.crashed:
                    return
                agent.run_frame(key, payload)
                if agent.merger.time_to_deadline(agent.clock()) is not None:
                    agent.wake.set()  # a frame waits for other sources: the main loop keeps its deadline
            except Exception as exc:  # noqa: BLE001 - handed to the main loop, which ends the agent
                self.crashed.append(exc)
                agent.wake.set()
            finally:
                self.work.release()
        elif not self.stopped:
            agent.on_frame(key, payload)

    def answer_mission(self, query: zenoh.Query) -> None:
        self.answered["mission"] += 1
        payload = self.agent.mission_payload  # a bytes object swapped in by the main thread
        if payload is not None:
            query.reply(self.own_mission, payload)

    def answer_health(self, query: zenoh.Query) -> None:
        self.answered["health"] += 1
        payload = self.agent.health_payload  # likewise
        if payload is not None:
            query.reply(self.own_health, payload)

    def queue_event(self, payload: bytes) -> None:
        self.events_out.put(payload)
        self.agent.wake.set()

    # ---------------------------------------------------------------- the main loop
    def flush_events(self) -> None:
        while True:
            try:
                self.event_pub.put(self.events_out.get_nowait())
            except queue.Empty:
                return

    def ask_peers(self, now: float) -> None:
        """Without a mission, ask the operator for it, then PEERS_ASKED peers (every peer if the operator gave
        none; mission_followup), every FETCH_PERIOD_S; with one, a (re)started or resynced agent asks the
        PEERS_ASKED peers after it (peers_to_ask) for their failure-policy state, once per such phase."""
        agent, keys = self.agent, self.keys
        idle = not (self.fetcher and self.fetcher.is_alive())
        if agent.state.phase is SyncPhase.SYNCED:
            self.asked_health = False
        latest = agent.missions.latest()
        if latest is None and now >= self.next_fetch and idle:
            self.fetcher = threading.Thread(target=fetch, args=(
                self.session, (keys.mission,), "mission", self.inbox, 1.0, agent.wake,
                functools.partial(mission_followup, keys, self.robot)), daemon=True)
            self.fetcher.start()
            self.next_fetch = now + FETCH_PERIOD_S
        elif latest is not None and not self.asked_health and idle and \
                agent.state.phase is not SyncPhase.SYNCED:
            self.asked_health = True
            selectors = tuple(keys.peer_health(p) for p in peers_to_ask(latest.robot_ids, self.robot))
            self.fetcher = threading.Thread(target=fetch, args=(
                self.session, selectors, "health", self.inbox, 1.0, agent.wake), daemon=True)
            self.fetcher.start()

    def run_once(self) -> None:
        """Wait for a wake-up or the merger's deadline, then run what came: missions and replies first (a
        frame may need the mission just arrived), then the frame due."""
        agent = self.agent
        now = agent.clock()
        self.ask_peers(now)
        with self.work:  # the merger's deadline is the agent's state too
            wait = agent.merger.time_to_deadline(now)
        agent.wake.wait(0.05 if wait is None else max(wait, 1e-4))
        with self.work:
            if self.crashed:
                raise self.crashed[0]
            while True:
                try:
                    kind, key, payload = self.inbox.get_nowait()
                except queue.Empty:
                    break
                agent.on_message(kind, key, payload)
            self.declare_mission_queryable()
            agent.poll()
        self.flush_events()

    def declare_mission_queryable(self) -> None:
        """Answer ``peer/<robot>/mission`` from the first mission this agent holds on (the main loop)."""
        if self.mission_queryable is None and self.agent.mission_payload is not None:
            self.mission_queryable = self.session.declare_queryable(self.own_mission, self.answer_mission,
                                                                    complete=False)
            self.queryables.append(self.mission_queryable)

    def close(self) -> None:
        """Stop frames, publish the zero command (no frame runs after it), log the counts, undeclare."""
        agent = self.agent
        self.frame_sub.undeclare()
        with self.work:  # no frame runs after the stop command, even in a callback undeclare did not wait for
            self.stopped = True
            self.cmd_pub.put(agent.stop_command())
        self.flush_events()
        log.info("agent %s stopping after %d ticks, %d rejected (%d on overflow), %d frames replaced "
                 "before they ran, %d stale frames, %d frames too old to move on; asked %d mission and %d health "
                 "queries", self.robot, agent.ticks, agent.rejections.count, self.overflow, agent.frames_replaced,
                 agent.state.stale, agent.state.too_old,
                 self.answered["mission"], self.answered["health"])
        self.mission_sub.undeclare()
        for q in self.queryables:
            q.undeclare()
        self.token.undeclare()
        if self.fetcher is not None:
            self.fetcher.join(timeout=2.0)


def run_agent(conf: zenoh.Config, robot: str, fleet: str = "demo", stop: StopFlag | None = None,
              dt_s: float = DEFAULT_DT_S, ttl_s: float = DEFAULT_TTL_S,
              deadline_s: float | None = None) -> Agent:
    """Run one agent until ``stop`` is set; always ends with a zero command."""
    stop = stop or StopFlag()
    with open_session(conf) as session:
        wiring = AgentWiring(session, robot, Keys(fleet), dt_s, ttl_s, deadline_s)
        log.info("agent %s up (fleet %s)", robot, fleet)
        try:
            while not stop.is_set():
                wiring.run_once()
        finally:
            wiring.close()
    return wiring.agent


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet agent", description=__doc__.splitlines()[0])
    p.add_argument("--robot", required=True, help="this agent's robot id")
    p.add_argument("--fleet", default="demo", help="fleet name (key prefix vs/<fleet>)")
    p.add_argument("--dt", type=float, default=DEFAULT_DT_S,
                   help="control step [s]: the structure is advanced by one dt per frame")
    p.add_argument("--ttl", type=float, default=DEFAULT_TTL_S, help="command time-to-live [s]")
    p.add_argument("--deadline", type=float, default=None,
                   help="with several frame sources, run a frame that misses robots this long [s] after it "
                        "arrived (default: --dt)")
    return common_flags(p)


@program(build_parser, log)
def main(args: argparse.Namespace) -> int:
    with refusing(WireError):
        check_name(args.robot, "robot")
        check_name(args.fleet, "fleet")
    if args.deadline is not None and not 0.0 < args.deadline <= 1.0:
        raise Refused("--deadline must be in (0, 1] s")
    run_agent(zenoh_config(args), args.robot, args.fleet, dt_s=args.dt, ttl_s=args.ttl,
              deadline_s=args.deadline)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
