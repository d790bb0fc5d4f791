"""Loop latency and scale: real `vsfleet agent` processes against a scripted tracker and fleet.

This process plays the tracker and simfleet's receiving side: it starts a
`vsfleet router` process on a free loopback port (as on a deployment), connects
client sessions to it (a "tracker" that publishes one message per frame on
vs/<fleet>/frame/bench and a "sim" that subscribes to vs/<fleet>/cmd/** and state/**), and starts N real
agent processes as clients of that router, as `vsfleet run` starts them (fleetctl.run.Children.start_agent:
forked from a fork server that imported the agent once; ``--spawn exec``: each its own python). So a
frame goes tracker client -> router -> N agents -> router -> sim client, the
same path as in `vsfleet run`.

Each frame is one message with every robot's pose; the robots
move by a kinematic model (each robot integrates its latest fresh command
exactly, vsfleet.kinematics.integrate_arc, over one frame period), observed
with 1 mm / 5 mrad Gaussian noise. The mission: robots on a circle, metric l2,
the default controller, goal 1 km ahead, so every robot keeps moving.

Latency of a (frame, robot) = receipt of that robot's cmd with the frame's
``seq`` - the moment just before the frame is put (one clock,
time.perf_counter, in this process). A (frame, robot) with no cmd for that
``seq`` is missed. Agents' ``state`` messages say whether they ran the frame
complete, and whether their copies of the structure (fitted and advanced
poses) agree bit for bit on the frames every agent ran.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import msgpack
import numpy as np
import zenoh

from vsfleet.fleetctl.mission_cmd import stamp
from vsfleet.fleetctl.router import client_config, open_loopback_router, start_router_child
from vsfleet.fleetctl.run import SPAWN_MODES, Children, child_command
from vsfleet.zglue.zconf import RELIABLE_QOS, STREAM_QOS, zenoh_flags
from vsfleet.geometry import Pose2
from vsfleet.kinematics import integrate_arc
from vsfleet.wire import (
    FrameMsg,
    Keys,
    Mission,
    PoseMsg,
    RobotSpec,
    WireError,
    decode_cmd,
    decode_state,
    encode,
    encode_frame,
    encode_mission,
)

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # bench.outputs, also when run as a script

from bench.outputs import DOCS, add_output_flags  # noqa: E402

VS_TRIVIAL = "vs-trivial"  # --compare's outputs: vs-trivial.json and vs-trivial.png
CLK_TCK = os.sysconf("SC_CLK_TCK")
WHEEL_BASE_M = 0.12
NOISE_XY_M = 0.001
NOISE_TH_RAD = 0.005
CMD_TTL_S = 0.3   # the agents' default ttl: an older command counts as zero
SPACING_M = 0.3   # neighbours on the template circle are at least this far apart


# ---------------------------------------------------------------- pure helpers


def circle_template(n: int, spacing_m: float = SPACING_M) -> list[tuple[str, tuple[float, float]]]:
    """Robots r1..rn evenly on a circle whose neighbours are >= spacing_m apart (radius >= 0.3 m)."""
    radius = max(0.3, spacing_m / (2.0 * math.sin(math.pi / n))) if n > 1 else 0.0
    return [(f"r{i + 1}", (radius * math.cos(2 * math.pi * i / n), radius * math.sin(2 * math.pi * i / n)))
            for i in range(n)]


ROOM_PILLARS = 64        # --room: pillars scattered ahead of the circle (issue 28's 3 robots among 64 obstacles)
ROOM_BODY_M = 0.05       # --room: every robot's body radius [m]
ROOM_GOAL_AHEAD_M = 4.0  # --room: the goal this far ahead of the circle's edge [m]


def room_obstacles(n: int, seed: int = 28) -> tuple[tuple[float, float, float], ...]:
    """--room's pillars (x, y, r) [m; world]: ROOM_PILLARS of radius 0.05-0.12 m, drawn (seeded) from the circle's
    start to ROOM_GOAL_AHEAD_M beyond it and 1 m either side of it, each at least 0.25 m clear of every robot's body
    as the structure sweeps straight from its start to its goal: the pillars stand beside the way, not on it."""
    pts = np.array([p for _, p in circle_template(n)])
    radius = float(np.hypot(pts[:, 0], pts[:, 1]).max())
    ahead = radius + ROOM_GOAL_AHEAD_M
    rng = np.random.default_rng([seed, n])
    out: list[tuple[float, float, float]] = []
    while len(out) < ROOM_PILLARS:
        x, y = rng.uniform(-radius, ahead + radius), rng.uniform(-radius - 1.0, radius + 1.0)
        r = rng.uniform(0.05, 0.12)
        along = np.clip(x - pts[:, 0], 0.0, ahead)      # each body's nearest place on its straight sweep
        if np.all(np.hypot(pts[:, 0] + along - x, pts[:, 1] - y) - r - ROOM_BODY_M >= 0.25):
            out.append((float(x), float(y), float(r)))
    return tuple(out)



def bench_mission(n: int, now_s: float, room: bool = False) -> Mission:
    """The bench's mission: robots on a circle heading for a goal 1 km ahead; room: with bodies (ROOM_BODY_M) and
    room_obstacles, the goal ROOM_GOAL_AHEAD_M beyond the circle, so every agent follows its room's field, runs the
    clearance barrier and the safety filter with bodies (the measured frames end long before the goal)."""
    radius = 0.05 if room else None
    robots = tuple(sorted((r, RobotSpec(p, WHEEL_BASE_M, 0.3, 0.8, radius=radius)) for r, p in circle_template(n)))
    if room:
        edge = max(math.hypot(*p) for _, p in circle_template(n))
        m = Mission(version=1, metric="l2", robots=robots, speed_max=0.08, turn_rate_max=0.3, effective_t=0.0,
                    goal=(edge + ROOM_GOAL_AHEAD_M, 0.0, 0.0), obstacles=room_obstacles(n))
    else:
        m = Mission(version=1, metric="l2", robots=robots, speed_max=0.08, turn_rate_max=0.3, effective_t=0.0,
                    goal=(1000.0, 0.0, 0.0))
    return stamp(m, now_s, 0.0, version=1)


def percentiles_s(x: np.ndarray) -> dict[str, float]:
    """p50, p99 and max [s] of a sample (NaN when empty)."""
    if x.size == 0:
        return {"p50": math.nan, "p99": math.nan, "max": math.nan}
    return {"p50": float(np.percentile(x, 50)), "p99": float(np.percentile(x, 99)), "max": float(x.max())}


def messages_per_frame(n: int, state_subscribed: bool = True) -> dict[str, int]:
    """Messages per tracker frame for n robots: published, and delivered by the router.

    One frame message goes to every agent (fan-out n); cmd goes to the fleet (simfleet),
    state to whoever records or monitors.
    """
    published = 1 + 2 * n  # one frame, n cmds, n states
    delivered = n + n + (n if state_subscribed else 0)
    return {"published": published, "delivered": delivered}


def proc_cpu_s(pid: int | str) -> float:
    """User + system CPU time [s] of a process (all its threads), from /proc/<pid>/stat."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    rest = stat[stat.rfind(")") + 2:].split()
    return (int(rest[11]) + int(rest[12])) / CLK_TCK


def proc_rss_mib(pid: int | str) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return math.nan


def machine_busy_s() -> tuple[float, float]:
    """(busy, total) CPU seconds of the whole machine since boot, from /proc/stat."""
    v = [int(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:9]]
    total = sum(v)
    return (total - v[3] - v[4]) / CLK_TCK, total / CLK_TCK


# ---------------------------------------------------------------- the fleet


@dataclass(frozen=True)
class LoopRun:
    """One run: n agents at rate_hz for `frames` measured frames."""

    robots: int
    rate_hz: float
    frames: int
    latency_s: np.ndarray          # per answered (frame, robot)
    frame_latency_s: np.ndarray    # per fully answered frame: its last cmd's latency
    publish_s: np.ndarray          # per frame: time to put all n poses
    missed: int                    # (frame, robot) pairs never answered
    frames_missed: int             # frames with at least one robot unanswered
    late: int                      # answered pairs with latency > one period
    incomplete: int                # agent states of measured frames run on the deadline (complete false)
    states: int
    agreed_frames: int             # measured frames every agent ran whose structure copies agree bit for bit
    all_ran_frames: int            # measured frames every agent published a state for
    agent_cpu_s_per_tick: np.ndarray   # per agent: CPU time / measured frames
    agent_cpu_s_per_answer: np.ndarray # per agent: CPU time / frames it answered
    agent_rss_mib: np.ndarray          # per agent, at the end
    bench_cpu_s_per_frame: float       # this process (tracker, sim side) and the router process
    others_cores: float                # CPU cores busy with other processes of the machine meanwhile
    wall_s: float
    startup_s: float = math.nan        # from starting the agents to every agent's first command
    agent_kind: str = "vsfleet"
    # start-up's parts: from starting the agents to every agent's liveliness token (processes up: interpreter,
    # imports, session), and the agents' CPU time [s] from their start to every agent's first command, per agent
    alive_s: float = math.nan
    startup_cpu_s_per_agent: float = math.nan
    # after the measured frames: agents whose process still runs and whose liveliness token is still up
    alive_end: int = -1
    # how far the fitted structure moved [m] from the first to the last measured frame every agent ran (its copies
    # agreeing): in a room (--room), that it went its way among the pillars while it was timed
    moved_m: float = math.nan

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def missed_share(self) -> float:
        return self.missed / max(1, self.frames * self.robots)

    @property
    def holds(self) -> bool:
        """Every frame answered by every agent, and p99 latency within one period."""
        return self.missed == 0 and self.latency_s.size > 0 and percentiles_s(self.latency_s)["p99"] < self.period_s

    @property
    def nearly_holds(self) -> bool:
        """At most 0.1% of (frame, robot) pairs missed, and p99 latency within one period."""
        return (self.missed_share <= 0.001 and self.latency_s.size > 0
                and percentiles_s(self.latency_s)["p99"] < self.period_s)


class _Sink:
    """The sim side: every cmd and state with its arrival time, and each robot's latest wheels."""

    def __init__(self, keys: Keys) -> None:
        self.cmd_head = f"{keys.prefix}/cmd/"
        self.cmds: list[tuple[float, str, bytes]] = []
        self.states: list[tuple[str, bytes]] = []
        self.wheels: dict[str, tuple[float, float, float]] = {}  # robot -> (vl, vr, arrival)

    def on_cmd(self, sample: zenoh.Sample) -> None:
        t = time.perf_counter()
        key, payload = str(sample.key_expr), sample.payload.to_bytes()
        self.cmds.append((t, key, payload))
        try:
            m = msgpack.unpackb(payload)
            self.wheels[key[len(self.cmd_head):]] = (float(m["vl"]), float(m["vr"]), t)
        except Exception:  # noqa: BLE001 - validated after the run
            pass

    def on_state(self, sample: zenoh.Sample) -> None:
        self.states.append((str(sample.key_expr), sample.payload.to_bytes()))


def _wait(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what} not within {timeout_s:.0f} s")
        time.sleep(0.05)


def _pace_until(t: float) -> None:
    dt = t - time.perf_counter()
    if dt > 0:
        time.sleep(dt)


TRIVIAL_EXPRESS = {"trivial": "agent", "trivial-express": "on", "trivial-batched": "off"}


def agent_args(kind: str, robot: str, fleet: str, period_s: float, endpoint: str,
               deadline_s: float | None = None) -> list[str]:
    """The arguments of one agent of the bench fleet (``vsfleet agent ARGS``, or bench/trivial_agent.py's)."""
    if kind in TRIVIAL_EXPRESS:  # trivial-express / -batched: the commands' and states' QoS forced (fan-in runs)
        return ["--robot", robot, "--fleet", fleet, "--express", TRIVIAL_EXPRESS[kind], *zenoh_flags(endpoint)]
    if kind != "vsfleet":
        raise ValueError(f"agent kind must be 'vsfleet' or 'trivial[-express|-batched]', got {kind!r}")
    return ["--robot", robot, "--fleet", fleet, "--dt", repr(period_s),
            *(["--deadline", repr(deadline_s)] if deadline_s else []), *zenoh_flags(endpoint)]


def agent_command(kind: str, robot: str, fleet: str, period_s: float, endpoint: str,
                  deadline_s: float | None = None) -> list[str]:
    """The command line of one agent of the bench fleet: ``vsfleet`` (the real agent) or ``trivial``
    (bench/trivial_agent.py: decode the frame, answer a command and a state; the floor)."""
    args = agent_args(kind, robot, fleet, period_s, endpoint, deadline_s)
    if kind in TRIVIAL_EXPRESS:
        return [sys.executable, "-m", "bench.trivial_agent", *args]
    return child_command("agent", *args)


def start_agent(children: Children, kind: str, robot: str, fleet: str, period_s: float, endpoint: str,
                deadline_s: float | None = None, spawn: str = "fork"):
    """Start one agent of the bench fleet as ``vsfleet run`` does (spawn "fork": forked from the fleet's fork
    server, vsfleet.zglue.forks.ForkServer), or as its own python (spawn "exec")."""
    name, args = f"agent-{robot}", agent_args(kind, robot, fleet, period_s, endpoint, deadline_s)
    if kind not in TRIVIAL_EXPRESS:
        return children.start_agent(name, args, spawn=spawn, cwd=ROOT)
    if spawn == "exec":
        return children.start(name, agent_command(kind, robot, fleet, period_s, endpoint, deadline_s), cwd=ROOT)
    return children.start_forked(name, "bench.trivial_agent", args, ["bench.trivial_agent"], cwd=ROOT,
                                 title=[sys.executable, "-m", "bench.trivial_agent", *args])


def run_loop(n: int, rate_hz: float, frames: int, log=print, warmup_s: float = 2.0, seed: int = 0,
             label: str = "loop", router_process: bool = True, deadline_s: float | None = None,
             agent_kind: str = "vsfleet", spawn: str = "fork", room: bool = False) -> LoopRun:
    """Start n agents (``agent_kind``: see agent_command), warm up, then measure `frames` frames at rate_hz.

    The router is its own `vsfleet router` process, as on a deployment (or, with router_process=False,
    embedded in this process's session, whose Python callbacks then share zenoh's threads with routing).
    spawn: how the agents start (fleetctl.run.SPAWN_MODES): forked from a fork server that imported them once,
    as `vsfleet run` starts them, or each its own python. room: the mission of bench_mission(room=True)."""
    fleet = "bench"
    keys = Keys(fleet)
    period = 1.0 / rate_hz
    rng = np.random.default_rng(seed)
    procs: dict = {}  # the agents (subprocess.Popen or fleetctl.run.ForkedChild), by robot
    log_dir = Path(tempfile.mkdtemp(prefix=f"vsfleet-bench-{n}-"))
    children = Children(log_dir)
    if router_process:
        endpoint = start_router_child(children, cwd=ROOT)
        router = zenoh.open(client_config(endpoint))
    else:
        router, endpoint = open_loopback_router()
    sessions = []
    alive: set[str] = set()

    def on_alive(sample: zenoh.Sample) -> None:
        (alive.add if sample.kind == zenoh.SampleKind.PUT else alive.discard)(str(sample.key_expr))

    try:
        alive_sub = router.liveliness().declare_subscriber(keys.alive("agent"), on_alive, history=True)
        mission = bench_mission(n, time.time(), room)
        payload = encode_mission(mission)
        queryable = router.declare_queryable(keys.mission, lambda q: q.reply(keys.mission, payload),
                                             complete=True)
        tracker_s = zenoh.open(client_config(endpoint))
        sim_s = zenoh.open(client_config(endpoint))
        sessions += [tracker_s, sim_s]
        sink = _Sink(keys)
        subs = [sim_s.declare_subscriber(keys.cmd(), sink.on_cmd),
                sim_s.declare_subscriber(keys.state(), sink.on_state)]
        ids = mission.robot_ids
        frame_pub = tracker_s.declare_publisher(keys.frame("bench"), **STREAM_QOS)
        t_spawn = time.monotonic()
        for r in ids:
            procs[r] = start_agent(children, agent_kind, r, fleet, period, endpoint, deadline_s, spawn)
        t_start = time.monotonic()
        want = {keys.alive("agent", r) for r in ids}
        _wait(lambda: want <= alive or any(p.poll() is not None for p in procs.values()),
              60.0 + 4.0 * n, f"{n} agents alive")
        alive_s = time.monotonic() - t_spawn
        dead = [r for r, p in procs.items() if p.poll() is not None]
        if dead:
            raise RuntimeError(f"agents exited at start: {dead}; logs in {log_dir}")
        router.put(keys.mission, payload, **RELIABLE_QOS)
        log(f"[{label}] {n} agents up in {time.monotonic() - t_start:.0f} s; warming up")

        poses = {r: Pose2(*mission.spec(r).p, 0.0) for r in ids}
        seq = 0
        t_pub: dict[int, float] = {}
        publish: list[float] = []

        def frame(next_t: float) -> float:
            nonlocal seq
            _pace_until(next_t)
            now = time.perf_counter()
            for r in ids:  # kinematics: each robot drives its latest fresh command for one period
                w = sink.wheels.get(r)
                if w is not None and now - w[2] <= CMD_TTL_S:
                    poses[r] = integrate_arc(poses[r], w[0], w[1], period, WHEEL_BASE_M)
            seq += 1
            noise = rng.normal(0.0, 1.0, (len(ids), 3)) * (NOISE_XY_M, NOISE_XY_M, NOISE_TH_RAD)
            tw = time.time()
            t0 = time.perf_counter()
            frame_pub.put(encode_frame(FrameMsg(t=tw, seq=seq, src="bench", poses={
                r: (poses[r].x + noise[i, 0], poses[r].y + noise[i, 1], poses[r].th + noise[i, 2])
                for i, r in enumerate(ids)})))
            t1 = time.perf_counter()
            t_pub[seq] = t0
            publish.append(t1 - t0)
            nxt = next_t + period
            return nxt if nxt > t1 else t1 + period  # fell behind: skip rather than burst

        # warm-up: until every agent has answered, then warmup_s more
        next_t = time.perf_counter()
        deadline = time.monotonic() + 60.0 + 2.0 * n
        while len(sink.wheels) < n:
            next_t = frame(next_t)
            if time.monotonic() > deadline:
                raise TimeoutError(f"only {len(sink.wheels)}/{n} agents answered; logs in {log_dir}")
        startup_s = time.monotonic() - t_spawn
        forks = children.forks  # the fork server's own CPU (its imports, its forks) is the agents' too
        startup_cpu = (sum(proc_cpu_s(p.pid) for p in procs.values())
                       + (proc_cpu_s(forks.proc.pid) if forks is not None else 0.0)) / n
        log(f"[{label}] every agent answered {startup_s:.1f} s after they were started (all alive at {alive_s:.1f} s; "
            f"{1e3 * startup_cpu:.0f} ms CPU per agent so far; load {os.getloadavg()[0]:.2f})")
        for _ in range(int(warmup_s * rate_hz)):
            next_t = frame(next_t)

        # measurement
        first = seq + 1
        publish.clear()
        cpu0 = {r: proc_cpu_s(p.pid) for r, p in procs.items()}
        router_pid = children.procs["router"].pid if router_process else None
        bench0 = time.process_time() + (proc_cpu_s(router_pid) if router_pid else 0.0)
        busy0, tot0 = machine_busy_s()
        w0 = time.perf_counter()
        report_every = max(1, int(10 * rate_hz))
        for k in range(frames):
            next_t = frame(next_t)
            if (k + 1) % report_every == 0:
                el = time.perf_counter() - w0
                log(f"[{label}] frame {k + 1}/{frames}, {len(sink.cmds)} cmds received, "
                    f"ETA {el / (k + 1) * (frames - k - 1):.0f} s")
        _pace_until(next_t + 0.5)  # stragglers
        wall = time.perf_counter() - w0
        cpu1 = {r: proc_cpu_s(p.pid) for r, p in procs.items()}
        bench_cpu = time.process_time() + (proc_cpu_s(router_pid) if router_pid else 0.0) - bench0
        busy1, tot1 = machine_busy_s()
        rss = np.array([proc_rss_mib(p.pid) for p in procs.values()])
        alive_end = sum(1 for r, p in procs.items() if p.poll() is None and keys.alive("agent", r) in alive)
        last = seq
        for s in subs:
            s.undeclare()
        cmds, states = list(sink.cmds), list(sink.states)
        queryable.undeclare()
        alive_sub.undeclare()
    finally:
        children.stop([f"agent-{r}" for r in procs], grace_s=10.0)  # the agents first, then the router
        for s in sessions:
            s.close()
        router.close()
        children.stop(grace_s=10.0)

    shutil.rmtree(log_dir, ignore_errors=True)  # kept only when the run failed

    # ---- analysis (pure from here on)
    answered: dict[tuple[int, str], float] = {}
    head = keys.cmd("")
    for t, key, payload in cmds:
        try:
            msg = decode_cmd(payload)
        except WireError:
            continue
        robot = key[len(head):]
        if first <= msg.seq <= last and (msg.seq, robot) not in answered:
            answered[(msg.seq, robot)] = t - t_pub[msg.seq]
    lat = np.array(list(answered.values()))
    per_robot = {r: 0 for r in procs}
    for _, robot in answered:
        per_robot[robot] = per_robot.get(robot, 0) + 1
    per_frame: dict[int, list[float]] = {}
    for (s, _), v in answered.items():
        per_frame.setdefault(s, []).append(v)
    frame_lat = np.array([max(v) for v in per_frame.values() if len(v) == n])
    measured = last - first + 1
    incomplete = n_states = 0
    copies: dict[int, dict[str, tuple]] = {}  # seq -> agent -> its structure poses
    for key, payload in states:
        try:
            st = decode_state(payload)
        except WireError:
            continue
        if first <= st.seq <= last:
            n_states += 1
            incomplete += not st.complete
            copies.setdefault(st.seq, {})[key] = (st.x, st.y, st.th, st.gx, st.gy, st.gth, st.used)
    all_ran = [c for c in copies.values() if len(c) == n]
    agreed = sum(1 for c in all_ran if len(set(c.values())) == 1)
    same = [next(iter(copies[s].values())) for s in sorted(copies) if len(copies[s]) == n
            and len(set(copies[s].values())) == 1]
    moved_m = math.hypot(same[-1][0] - same[0][0], same[-1][1] - same[0][1]) if len(same) > 1 else math.nan
    wall_cores = (tot1 - tot0) / os.cpu_count() if tot1 > tot0 else wall
    own = sum(cpu1[r] - cpu0[r] for r in procs) + bench_cpu
    return LoopRun(
        robots=n, rate_hz=rate_hz, frames=measured, latency_s=lat, frame_latency_s=frame_lat,
        publish_s=np.array(publish), missed=measured * n - len(answered),
        frames_missed=measured - len(frame_lat), late=int((lat > period).sum()), incomplete=incomplete,
        states=n_states, agreed_frames=agreed, all_ran_frames=len(all_ran), agent_cpu_s_per_tick=np.array([(cpu1[r] - cpu0[r]) / measured for r in procs]),
        agent_cpu_s_per_answer=np.array([(cpu1[r] - cpu0[r]) / max(1, per_robot[r]) for r in procs]),
        agent_rss_mib=rss, bench_cpu_s_per_frame=bench_cpu / measured,
        others_cores=max(0.0, (busy1 - busy0) - own) / max(wall_cores, 1e-9), wall_s=wall,
        startup_s=startup_s, agent_kind=agent_kind, alive_s=alive_s, startup_cpu_s_per_agent=startup_cpu,
        alive_end=alive_end, moved_m=moved_m)


# ---------------------------------------------------------------- the zenoh floor


@dataclass(frozen=True)
class FloorRun:
    """Round trips [s] of a plain message: this process -> router -> pong process -> router -> here."""

    label: str
    rate_hz: float | None          # None = back to back
    rtt_s: np.ndarray
    lost: int


def run_floor(plans: list[tuple[str, float | None, int]], log=print, router_process: bool = True
              ) -> list[FloorRun]:
    """Ping-pong through a router, one plan (label, rate or None, count) at a time.

    The router is its own `vsfleet router` process, as in run_loop (or, with router_process=False,
    embedded in this process's session)."""
    fleet = "bench"
    keys = Keys(fleet)
    alive: set[str] = set()
    sessions, out = [], []
    children = Children(Path(tempfile.mkdtemp(prefix="vsfleet-bench-floor-")))
    router = None
    try:
        if router_process:
            endpoint = start_router_child(children, cwd=ROOT)
            router = zenoh.open(client_config(endpoint))
        else:
            router, endpoint = open_loopback_router()
        router.liveliness().declare_subscriber(keys.alive("pong"), lambda s: alive.add(str(s.key_expr)),
                                               history=True)
        children.start("pong", [sys.executable, "-m", "bench.zenoh_pong", "--fleet", fleet,
                                *zenoh_flags(endpoint)], cwd=ROOT)
        _wait(lambda: alive, 60.0, "pong process alive")
        sess = zenoh.open(client_config(endpoint))
        sessions.append(sess)
        got = threading.Event()
        box: list[float] = [0.0]

        def on_pong(sample: zenoh.Sample) -> None:
            box[0] = time.perf_counter()
            got.set()

        sess.declare_subscriber(f"{keys.prefix}/bench/pong", on_pong)
        pub = sess.declare_publisher(f"{keys.prefix}/bench/ping", **STREAM_QOS)
        payload = encode(PoseMsg(t=time.time(), seq=1, x=0.1, y=0.2, th=0.3, src="bench"))
        for _ in range(200):  # warm-up, until the route is up
            got.clear()
            pub.put(payload)
            got.wait(0.05)
        for label, rate, count in plans:
            rtt, lost = [], 0
            next_t = time.perf_counter()
            w0 = time.perf_counter()
            for i in range(count):
                if rate is not None:
                    _pace_until(next_t)
                    next_t += 1.0 / rate
                got.clear()
                t0 = time.perf_counter()
                pub.put(payload)
                if got.wait(1.0):
                    rtt.append(box[0] - t0)
                else:
                    lost += 1
                if rate is not None and (i + 1) % int(10 * rate) == 0:
                    el = time.perf_counter() - w0
                    log(f"[floor {label}] {i + 1}/{count}, ETA {el / (i + 1) * (count - i - 1):.0f} s")
            out.append(FloorRun(label, rate, np.array(rtt), lost))
    finally:
        children.stop([n for n in ("pong",) if n in children.procs], grace_s=10.0)
        for s in sessions:
            s.close()
        if router is not None:
            router.close()
        children.stop(grace_s=10.0)  # the router last
        shutil.rmtree(children.log_dir, ignore_errors=True)
    return out


def compare(sizes: list[int], rate_hz: float, frames: int, out: Path | None = None, log=print,
            spawn: str = "fork") -> list[dict]:
    """For each N, the trivial fleet then vsfleet's, back to back through the same kind of router: missed
    pairs, latency p50/p99/max and their ratio to the trivial fleet's, CPU per agent tick, agreement,
    start-up, total RSS. With ``out``: a JSON of the rows and a plot of latency against N beside it."""
    import json  # noqa: PLC0415 - the comparison's own outputs

    rows = []
    for n in sizes:
        runs = {kind: run_loop(n, rate_hz, frames, log=log, label=f"{kind} N={n}", agent_kind=kind, spawn=spawn)
                for kind in ("trivial", "vsfleet")}
        row = {"n": n, "spawn": spawn}
        for kind, r in runs.items():
            p = percentiles_s(r.latency_s) if r.latency_s.size else {"p50": math.nan, "p99": math.nan, "max": math.nan}
            row[kind] = {"missed": r.missed, "frames_missed": r.frames_missed, "late": r.late, "pairs": r.frames * n,
                         "p50_ms": 1e3 * p["p50"], "p99_ms": 1e3 * p["p99"],
                         "max_ms": 1e3 * p["max"], "cpu_ms_per_tick": 1e3 * float(r.agent_cpu_s_per_tick.mean()),
                         "agreed": r.agreed_frames, "all_ran": r.all_ran_frames, "startup_s": r.startup_s,
                         "alive_s": r.alive_s, "startup_cpu_ms_per_agent": 1e3 * r.startup_cpu_s_per_agent,
                         "alive_end": r.alive_end,
                         "load_1min": os.getloadavg()[0],
                         "rss_mib_total": float(r.agent_rss_mib.sum()), "others_cores": r.others_cores}
        t, v = row["trivial"], row["vsfleet"]
        row["ratio_p50"], row["ratio_p99"] = v["p50_ms"] / t["p50_ms"], v["p99_ms"] / t["p99_ms"]
        log(f"[compare] N={n}: vsfleet missed {v['missed']}/{v['pairs']} (in {v['frames_missed']} frames; the "
            f"trivial fleet {t['missed']} in {t['frames_missed']}), p50 {v['p50_ms']:.1f} ms "
            f"({row['ratio_p50']:.2f}x the trivial fleet's {t['p50_ms']:.1f}), p99 {v['p99_ms']:.1f} ms "
            f"({row['ratio_p99']:.2f}x {t['p99_ms']:.1f}), cpu/tick {v['cpu_ms_per_tick']:.2f} vs "
            f"{t['cpu_ms_per_tick']:.2f} ms, agree {v['agreed']}/{v['all_ran']}, start-up {v['startup_s']:.1f} s "
            f"(trivial {t['startup_s']:.1f} s; all alive at {v['alive_s']:.1f} / {t['alive_s']:.1f} s; CPU per agent "
            f"until every one answered {v['startup_cpu_ms_per_agent']:.0f} / {t['startup_cpu_ms_per_agent']:.0f} ms); "
            f"alive after the measured frames {v['alive_end']}/{n} (trivial {t['alive_end']}/{n})")
        rows.append(row)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.with_suffix(".json").write_text(json.dumps(rows, indent=1))
        import matplotlib  # noqa: PLC0415
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt  # noqa: PLC0415
        fig, ax = plt.subplots(figsize=(6, 4))
        ns = [r["n"] for r in rows]
        for kind, colour in (("trivial", "tab:gray"), ("vsfleet", "tab:blue")):
            ax.plot(ns, [r[kind]["p50_ms"] for r in rows], "o-", color=colour, label=f"{kind} p50")
            ax.plot(ns, [r[kind]["p99_ms"] for r in rows], "s--", color=colour, label=f"{kind} p99")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("agents N (30 Hz, one router)")
        ax.set_ylabel("frame publish -> command [ms]")
        ax.set_title("vsfleet agents against trivial agents, back to back")
        ax.legend()
        ax.grid(True, which="both", alpha=0.3)
        fig.tight_layout()
        fig.savefig(out.with_suffix(".png"), dpi=110)
        plt.close(fig)
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="one loop-latency run (development)")
    p.add_argument("--robots", type=int, default=3)
    p.add_argument("--rate", type=float, default=30.0)
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--room", action="store_true",
                   help="bodies and 64 pillars: every agent follows its room's field (issue 28: 30 Hz in a room)")
    p.add_argument("--floor", action="store_true", help="also measure the zenoh floor")
    p.add_argument("--compare", default=None, help="N,N,...: the trivial fleet and vsfleet's back to back at each N")
    add_output_flags(p, "loop", DOCS / "bench", f"--compare's {VS_TRIVIAL}.json and {VS_TRIVIAL}.png")
    p.add_argument("--agent", choices=("vsfleet", "trivial", "trivial-express", "trivial-batched"), default="vsfleet",
                   help="the agents: vsfleet's own, or the trivial floor (bench/trivial_agent.py)")
    p.add_argument("--spawn", choices=SPAWN_MODES, default="fork",
                   help="how the agents start: forked from a fork server that imported them once, as `vsfleet run` "
                        "starts them (default), or each its own python (exec)")
    a = p.parse_args(argv)
    if a.compare:
        compare([int(x) for x in a.compare.split(",")], a.rate, a.frames, a.out / VS_TRIVIAL, spawn=a.spawn)
        return 0
    if a.floor:
        for f in run_floor([("back to back", None, 2000), ("30 Hz", 30.0, 300)]):
            print(f.label, {k: round(v * 1e3, 3) for k, v in percentiles_s(f.rtt_s).items()}, "lost", f.lost)
    r = run_loop(a.robots, a.rate, a.frames, agent_kind=a.agent, spawn=a.spawn, room=a.room)
    print(a.agent, {k: round(v * 1e3, 3) for k, v in percentiles_s(r.latency_s).items()}, "ms; missed", r.missed,
          "late", r.late, "incomplete", r.incomplete, "/", r.states, "cpu/tick ms",
          round(1e3 * float(r.agent_cpu_s_per_tick.mean()), 3), "rss MiB", round(float(r.agent_rss_mib.mean()), 1),
          "bench cpu/frame ms", round(1e3 * r.bench_cpu_s_per_frame, 3), "others cores", round(r.others_cores, 2),
          "agree", f"{r.agreed_frames}/{r.all_ran_frames} of {r.frames}", "holds", r.holds, "startup s", round(r.startup_s, 1),
          "all alive s", round(r.alive_s, 1), "startup CPU ms/agent", round(1e3 * r.startup_cpu_s_per_agent),
          "alive at the end", f"{r.alive_end}/{a.robots}", "structure moved m", round(r.moved_m, 3))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
