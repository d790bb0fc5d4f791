"""vsfleet monitor: a live terminal view of a running fleet, from its key space alone.

Per robot: age and rate of its tracker pose, its commanded wheel speeds, its
deviation from the structure (the agent's ``err``), whether its agent is alive
(liveliness token ``vs/<fleet>/alive/agent/<robot>``) and how many bad
messages the agent rejected. For the fleet: the fitted structure pose and the
mission version the agents use, their agreement (the largest difference
between agents' structure poses on the newest frame that every live agent
ran complete, as agents agree bit for bit only there; failing that, the newest
frame they all reported, flagged), and the latest events (``vs/<fleet>/event/<robot>`` maps, and faults).
In a room (a mission with obstacles or robot bodies): each robot's body radius and its gap, the
clearance between its body and the nearest other body or obstacle at the latest poses (negative:
touching), and the mission's obstacles.

:class:`FleetModel` holds the state; it ingests (receive time, key, payload)
and produces plain rows (:class:`FleetView`), so it runs as well on a
recorded log as on live samples. Rendering (rich) is separate.
"""

from __future__ import annotations

import argparse
import logging
import math
import threading
import time
from collections import OrderedDict, deque
from dataclasses import dataclass, field

import zenoh

from vsfleet.analysis import pose_spread
from vsfleet.geometry import Pose2
from vsfleet.step import mission_arrays, planned_way, shape_name
from vsfleet.wire import (
    Mission,
    WireError,
    check_name,
    decode_cmd,
    decode_fault,
    decode_mission,
    decode_frame,
    decode_pose,
    decode_state,
    unpack_map,
)

from vsfleet.zglue.lifecycle import StopFlag
from vsfleet.zglue.peers import current_missions
from vsfleet.zglue.program import common_flags, program, refusing
from .foxglove_views import swept_poses
from .record import split_key, structure_points
from vsfleet.zglue.zconf import open_session, zenoh_config

log = logging.getLogger("vsfleet.monitor")

RATE_WINDOW_S = 2.0      # pose rate: poses received over the last window
STALE_S = 2.0            # an agent whose last state is older than this is left out of the agreement
SEQ_HISTORY = 256        # frames kept per agent for the agreement
EVENTS_KEPT = 5


@dataclass(frozen=True)
class RobotRow:
    """One robot as the key space shows it; None where nothing was received."""

    robot: str
    pose_age_s: float | None
    pose_rate_hz: float
    vl_m_s: float | None
    vr_m_s: float | None
    err_m: float | None
    alive: bool | None          # agent's liveliness token; None: never seen
    rejected: int | None
    state_seq: int | None
    radius_m: float | None = None   # its body radius in the mission; None: a point robot (or no mission)
    gap_m: float | None = None      # clearance [m] to the nearest other body or obstacle; < 0: touching


@dataclass(frozen=True)
class FleetView:
    now_s: float
    fleet: str | None
    robots: list[RobotRow]
    structure: tuple[float, float, float] | None   # fitted (x [m], y [m], th [rad])
    structure_seq: int | None
    mission_version: int | None
    agreement_seq: int | None        # newest frame every live agent ran whole, else newest they reported
    agreement_complete: bool | None  # every agent ran agreement_seq with every pose of the frame
    agreement_pos_m: float | None
    agreement_th_rad: float | None
    agents_compared: int
    events: list[tuple[float, str, dict]]   # (receive time [s], key suffix, map), newest last
    bad_messages: int
    obstacles: tuple[tuple[float, float, float], ...] = ()  # the mission's (x, y, r) [m; world]
    # the room's plan from the structure pose above (vsfleet.step.planned_way): its length [m], whether it is
    # blocked (it ends at the closest safe pose), and its end (x, y, th); None without a room
    plan: tuple[float, bool, tuple[float, float, float]] | None = None
    shape: str | None = None   # in a room with reshapes: the shape the newest state reports (vsfleet.step.shape_name)
    room_map: tuple[str, ...] = ()   # in a room: the plan and the bodies swept along it, drawn in characters (room_map)


@dataclass
class _Robot:
    pose_times: deque = field(default_factory=deque)
    last_pose_s: float | None = None
    xy: tuple[float, float] | None = None  # latest tracked position [m; world]
    cmd: tuple[float, float] | None = None
    state_t_recv_s: float | None = None
    err_m: float | None = None
    rejected: int | None = None
    state_seq: int | None = None
    mission: int | None = None
    shape: int = 0                                            # the shape its newest state reports (0: the template)
    frames: OrderedDict = field(default_factory=OrderedDict)  # seq -> (x, y, th)
    whole: set = field(default_factory=set)                   # seqs of frames the agent ran complete


class FleetModel:
    """Fleet state from (receive time [s], key, payload) samples and liveliness changes. Not thread-safe."""

    def __init__(self, fleet: str | None = None, rate_window_s: float = RATE_WINDOW_S,
                 stale_s: float = STALE_S, events_kept: int = EVENTS_KEPT) -> None:
        self.fleet = check_name(fleet, "fleet") if fleet is not None else None
        self.rate_window_s = rate_window_s
        self.stale_s = stale_s
        self.robots: dict[str, _Robot] = {}
        self.alive: dict[str, bool] = {}           # agent id -> token alive
        self.mission_robots: tuple[str, ...] = ()
        self.mission_version: int | None = None
        self.radii: dict[str, float] = {}     # robot -> body radius [m] (robots with a body)
        self.obstacles: tuple[tuple[float, float, float], ...] = ()
        self.mission: Mission | None = None
        self.events: deque = deque(maxlen=events_kept)
        self.bad = 0
        self.frames_seen = False  # pose rates from frames once any frame came
        self.last_t_s = -math.inf

    def _robot(self, rid: str) -> _Robot:
        r = self.robots.get(rid)
        if r is None:
            r = self.robots[rid] = _Robot()
        return r

    def _parts(self, key: str):
        parts = split_key(key)
        if parts is None or (self.fleet is not None and parts[0] != self.fleet):
            return None
        if self.fleet is None:
            self.fleet = parts[0]  # the first fleet seen; others are ignored
        return parts if parts[0] == self.fleet else None

    def _seen(self, robot: str, t_recv_s: float, xy: tuple[float, float] | None = None) -> None:
        r = self._robot(robot)
        if xy is not None:
            r.xy = xy
        r.last_pose_s = t_recv_s
        r.pose_times.append(t_recv_s)
        while r.pose_times and r.pose_times[0] < t_recv_s - self.rate_window_s:
            r.pose_times.popleft()

    def ingest(self, t_recv_s: float, key: str, payload: bytes) -> None:
        """One data sample."""
        self.last_t_s = max(self.last_t_s, t_recv_s)
        parts = self._parts(key)
        if parts is None:
            return
        _, kind, rid = parts
        try:
            if kind == "frame" and rid:  # the agents' input: every robot a tracker saw in one frame
                for robot, (x, y, _) in decode_frame(payload).poses.items():
                    self._seen(robot, t_recv_s, (x, y))
                self.frames_seen = True
            elif kind == "pose" and rid:
                pose = decode_pose(payload)
                if not self.frames_seen:  # a tracker that sends frames sends these too: count once
                    self._seen(check_name(rid, "robot"), t_recv_s, (pose.x, pose.y))
            elif kind == "cmd" and rid:
                m = decode_cmd(payload)
                self._robot(check_name(rid, "robot")).cmd = (m.vl, m.vr)
            elif kind == "state" and rid:
                m = decode_state(payload)
                r = self._robot(check_name(rid, "robot"))
                r.state_t_recv_s, r.err_m, r.rejected, r.state_seq = t_recv_s, m.err, m.rejected, m.seq
                r.mission = m.mission if m.mission >= 0 else None
                r.shape = m.shape
                r.frames[m.seq] = (m.x, m.y, m.th)
                if m.complete:
                    r.whole.add(m.seq)
                else:
                    r.whole.discard(m.seq)
                while len(r.frames) > SEQ_HISTORY:
                    r.whole.discard(r.frames.popitem(last=False)[0])
            elif kind == "mission" and rid is None:
                mission = decode_mission(payload)
                self.mission_robots = mission.robot_ids
                self.mission_version = mission.version
                self.radii = {r: s.radius for r, s in mission.robots if s.radius is not None}
                self.obstacles = mission.obstacles
                self.mission = mission
            elif kind == "fault" and rid:
                f = decode_fault(payload)
                self.events.append((t_recv_s, f"fault/{rid}",
                                    {"kind": f.kind, "factor": f.factor, "duration": f.duration}))
            elif kind == "event" and rid:  # event/<robot>: a decision by that robot's agent
                self.events.append((t_recv_s, f"event/{check_name(rid, 'robot')}", unpack_map(payload)))
        except WireError:
            self.bad += 1

    def ingest_liveliness(self, t_recv_s: float, key: str, alive: bool) -> None:
        """A liveliness token under vs/<fleet>/alive/<role>/<id> appeared (True) or went away (False)."""
        self.last_t_s = max(self.last_t_s, t_recv_s)
        parts = self._parts(key)
        if parts is None or parts[1] != "alive" or not parts[2]:
            return
        role, _, ident = parts[2].partition("/")
        if role == "agent" and ident:
            self.alive[ident] = alive

    # ------------------------------------------------------------ view

    def _agreement(self, now_s: float):
        """(seq, position spread [m], heading spread [rad], complete, agents compared).

        Agents agree bit for bit only on frames they all ran complete (docs/protocol.md), so the
        newest such frame is compared; failing that, the newest frame they all reported."""
        live = [rid for rid, r in sorted(self.robots.items())
                if r.state_t_recv_s is not None and now_s - r.state_t_recv_s <= self.stale_s
                and self.alive.get(rid, True)]
        if len(live) < 2:
            return None, None, None, None, len(live)
        common = set.intersection(*(set(self.robots[rid].frames) for rid in live))
        if not common:
            return None, None, None, None, len(live)
        whole = common.intersection(*(self.robots[rid].whole for rid in live))
        seq = max(whole or common)
        poses = [self.robots[rid].frames[seq] for rid in live]
        pos, th = pose_spread(poses)
        return seq, pos, th, bool(whole), len(live)

    def _gap(self, rid: str) -> float | None:
        """Robot ``rid``'s clearance [m]: from its body to the nearest other body or obstacle, at the
        latest poses; None without its pose, or with nothing else to measure against."""
        me = self.robots.get(rid)
        if me is None or me.xy is None or not (self.radii or self.obstacles):
            return None
        x, y = me.xy
        mine = self.radii.get(rid, 0.0)
        gaps = [math.hypot(x - ox, y - oy) - r - mine for ox, oy, r in self.obstacles]
        gaps += [math.hypot(x - o.xy[0], y - o.xy[1]) - mine - self.radii.get(other, 0.0)
                 for other, o in self.robots.items() if other != rid and o.xy is not None]
        return min(gaps, default=None)

    def view(self, now_s: float | None = None) -> FleetView:
        """The table as plain data; ``now_s`` defaults to the latest receive time ingested."""
        now = self.last_t_s if now_s is None else now_s
        ids = sorted(set(self.mission_robots) | set(self.robots) | set(self.alive))
        rows = []
        for rid in ids:
            r = self.robots.get(rid, _Robot())
            n = sum(1 for t in r.pose_times if now - self.rate_window_s < t <= now)
            rows.append(RobotRow(
                robot=rid,
                pose_age_s=None if r.last_pose_s is None else now - r.last_pose_s,
                pose_rate_hz=n / self.rate_window_s,
                vl_m_s=r.cmd[0] if r.cmd else None, vr_m_s=r.cmd[1] if r.cmd else None,
                err_m=r.err_m, alive=self.alive.get(rid), rejected=r.rejected, state_seq=r.state_seq,
                radius_m=self.radii.get(rid), gap_m=self._gap(rid)))
        seq, pos, th, complete, n = self._agreement(now)
        newest = max((r for r in self.robots.values() if r.state_seq is not None),
                     key=lambda r: r.state_seq, default=None)
        structure = structure_seq = None
        if seq is not None:
            structure_seq = seq
            structure = next(r.frames[seq] for _, r in sorted(self.robots.items()) if seq in r.frames)
        elif newest is not None:
            structure_seq, structure = newest.state_seq, newest.frames[newest.state_seq]
        version = newest.mission if newest is not None and newest.mission is not None else self.mission_version
        shape = newest.shape if newest is not None else 0
        plan, drawn = self._plan(structure, shape)
        return FleetView(now_s=now, fleet=self.fleet, robots=rows, structure=structure,
                         structure_seq=structure_seq, mission_version=version, agreement_seq=seq,
                         agreement_complete=complete,
                         agreement_pos_m=pos, agreement_th_rad=th, agents_compared=n,
                         events=list(self.events), bad_messages=self.bad, obstacles=self.obstacles,
                         plan=plan, shape=self._shape_name(shape), room_map=drawn)

    def _shape_name(self, shape: int) -> str | None:
        """The shape's name, in a mission that allows reshapes; None otherwise (or for an unknown index)."""
        if self.mission is None:
            return None
        arrays = mission_arrays(self.mission)
        if not arrays.shapes or shape > len(arrays.shapes):
            return None
        return shape_name(arrays, shape)

    def _plan(self, structure: tuple[float, float, float] | None, shape: int = 0):
        """The room's plan from the structure pose: ((length [m], blocked, end pose), its room_map), or (None, ())."""
        if structure is None or self.mission is None:
            return None, ()
        planned = planned_way(self.mission, Pose2(*structure), shape=shape)
        if planned is None:
            return None, ()
        way, blocked = planned
        length = float(sum(math.hypot(b[0] - a[0], b[1] - a[1]) for a, b in zip(way[:-1], way[1:])))
        radii = self.mission.radii
        swept = [(x, y, r) for pose in swept_poses(way, SWEEP_M) for (x, y, _), r in
                 zip(structure_points(self.mission, *pose, shape), radii)]
        robots = [r.xy for _, r in sorted(self.robots.items()) if r.xy is not None]
        drawn = room_map(self.obstacles, way, swept, robots, blocked)
        return (length, blocked, (float(way[-1][0]), float(way[-1][1]), float(way[-1][2]))), drawn


# ---------------------------------------------------------------- the room in characters

SWEEP_M = 0.15                # the bodies drawn along the plan every this far [m] (as vsfleet plot)
MAP_COLS, MAP_ROWS = 72, 18   # the room map's size in characters (a character is about twice as tall as wide)
MAP_KEY = "O obstacle, . the plan (the structure's origin), : the bodies swept along it, # a robot now, G the goal " \
          "(B: the closest safe pose, blocked)"


def room_map(obstacles, way, swept, robots, blocked: bool = False, cols: int = MAP_COLS,
             rows: int = MAP_ROWS) -> tuple[str, ...]:
    """The room drawn in rows x cols characters, x to the right and y up, the scale the same both ways (a
    character twice as tall as wide): obstacles (x, y, r) as 'O', the bodies swept along the plan (x, y, r) as
    ':', the plan's poses (x, y, th) as '.', the robots' tracked positions (x, y) as '#', the plan's end as 'G'
    ('B' when blocked). A disc marks every character whose centre it covers, and at least the one at its centre."""
    pts = [(x, y, r) for x, y, r in obstacles] + [(x, y, r) for x, y, r in swept] \
        + [(p[0], p[1], 0.0) for p in way] + [(x, y, 0.0) for x, y in robots]
    if not pts:
        return ()
    x0, x1 = min(x - r for x, _, r in pts), max(x + r for x, _, r in pts)
    y0, y1 = min(y - r for _, y, r in pts), max(y + r for _, y, r in pts)
    s = max((x1 - x0) / cols, (y1 - y0) / (2 * rows), 1e-6)   # metres per column; a row is 2 s
    grid = [[" "] * cols for _ in range(rows)]

    def cell(x, y):
        return min(rows - 1, max(0, int((y1 - y) / (2 * s)))), min(cols - 1, max(0, int((x - x0) / s)))

    def disc(x, y, r, ch):
        r0, c0 = cell(x, y)
        grid[r0][c0] = ch
        for i in range(max(0, int((y1 - y - r) / (2 * s))), min(rows, int((y1 - y + r) / (2 * s)) + 1)):
            for j in range(max(0, int((x - r - x0) / s)), min(cols, int((x + r - x0) / s) + 1)):
                if math.hypot(x0 + (j + 0.5) * s - x, y1 - (i + 0.5) * 2 * s - y) <= r:
                    grid[i][j] = ch

    for x, y, r in swept:
        disc(x, y, r, ":")
    for p in way:
        i, j = cell(p[0], p[1])
        grid[i][j] = "."
    for x, y, r in obstacles:
        disc(x, y, r, "O")
    for x, y in robots:
        i, j = cell(x, y)
        grid[i][j] = "#"
    if len(way):
        i, j = cell(way[-1][0], way[-1][1])
        grid[i][j] = "B" if blocked else "G"
    return tuple("".join(row).rstrip() for row in grid)


# ---------------------------------------------------------------- rendering


def _fmt(v: float | None, spec: str, scale: float = 1.0) -> str:
    if v is None:
        return "-"
    return format(v * scale if scale != 1.0 else v, spec)


def render(view: FleetView):
    """A rich renderable (a table per robot, then the fleet's lines) for a FleetView."""
    from rich.console import Group
    from rich.markup import escape
    from rich.table import Table
    from rich.text import Text

    table = Table(title=f"vsfleet monitor: fleet {view.fleet or '?'}", title_justify="left")
    for name, justify in (("robot", "left"), ("agent", "center"), ("pose age [s]", "right"),
                          ("pose rate [Hz]", "right"), ("vl [m/s]", "right"), ("vr [m/s]", "right"),
                          ("err [cm]", "right"), ("rejected", "right"), ("seq", "right")):
        table.add_column(escape(name), justify=justify)
    room = view.obstacles or any(r.radius_m is not None for r in view.robots)
    if room:  # bodies and obstacles: each robot's body and its clearance to the nearest one
        table.add_column(escape("body r [cm]"), justify="right")
        table.add_column(escape("gap [cm]"), justify="right")
    for r in view.robots:
        alive = {True: Text("alive", "green"), False: Text("gone", "bold red"), None: Text("-")}[r.alive]
        cells = [Text(r.robot), alive, _fmt(r.pose_age_s, ".2f"), f"{r.pose_rate_hz:.1f}",
                 _fmt(r.vl_m_s, "+.3f"), _fmt(r.vr_m_s, "+.3f"), _fmt(r.err_m, ".2f", 100.0),
                 _fmt(r.rejected, "d"), _fmt(r.state_seq, "d")]
        if room:
            gap = Text(_fmt(r.gap_m, "+.1f", 100.0),
                       "bold red" if r.gap_m is not None and r.gap_m <= 0.0 else "")
            cells += [_fmt(r.radius_m, ".1f", 100.0), gap]
        table.add_row(*cells)
    lines = []
    if view.structure is not None:
        x, y, th = view.structure
        lines.append(f"structure (frame {view.structure_seq}): x {x:+.3f} m, y {y:+.3f} m, th {th:+.3f} rad")
    else:
        lines.append("structure: no agent state yet")
    lines.append(f"mission version: {view.mission_version if view.mission_version is not None else '-'}")
    if view.obstacles:
        lines.append(f"obstacles ({len(view.obstacles)}, x y r [m]): " + ", ".join(
            f"{i}: ({x:+.3f}, {y:+.3f}, {r:.3f})" for i, (x, y, r) in enumerate(view.obstacles[:8]))
            + (f", ... {len(view.obstacles) - 8} more" if len(view.obstacles) > 8 else ""))
    if view.shape is not None:
        lines.append(f"shape: {view.shape}")
    if view.plan is not None:
        length, blocked, (ex, ey, eth) = view.plan
        lines.append(f"plan: {length:.2f} m to " + ("the closest safe pose (BLOCKED: no way to the goal)" if blocked
                                                      else "the goal") + f" at ({ex:+.3f}, {ey:+.3f}, {eth:+.3f})")
    if view.room_map:
        lines.append(f"room ({MAP_KEY}):")
        lines.extend(view.room_map)
    if view.agreement_seq is not None:
        ran = "run complete" if view.agreement_complete else "none run complete by every agent"
        lines.append(f"agreement on frame {view.agreement_seq} ({ran}) over {view.agents_compared} agents: "
                     f"{view.agreement_pos_m:.3g} m, {view.agreement_th_rad:.3g} rad")
    else:
        lines.append(f"agreement: no frame reported by every live agent ({view.agents_compared} live)")
    texts = [Text(line) for line in lines]
    if view.bad_messages:
        texts.append(Text(f"{view.bad_messages} messages the monitor could not decode", "yellow"))
    for t, src, m in view.events:
        texts.append(Text(f"event {time.strftime('%H:%M:%S', time.localtime(t))} {src}: {m}"))
    return Group(table, *texts)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet monitor", description=__doc__.splitlines()[0])
    which = p.add_mutually_exclusive_group()
    which.add_argument("--fleet", default=None, help="watch vs/<fleet>/** (default fleet: demo)")
    which.add_argument("--key", default=None, help="watch this key expression instead (one fleet shown)")
    p.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: at Ctrl-C)")
    p.add_argument("--refresh", type=float, default=4.0, help="screen refreshes per second")
    return common_flags(p)


@program(build_parser, log)
def main(args: argparse.Namespace) -> int:
    from rich.live import Live

    with refusing(ValueError, zenoh.ZError):
        fleet = check_name(args.fleet or "demo", "fleet") if args.key is None else None
        key_expr = args.key or f"vs/{fleet}/**"
        zenoh.KeyExpr(key_expr)
    model = FleetModel(fleet)
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            with lock:
                model.ingest(time.time(), str(sample.key_expr), sample.payload.to_bytes())

    def on_token(sample: zenoh.Sample) -> None:
        with lock:
            model.ingest_liveliness(time.time(), str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

    def current():
        with lock:
            return render(model.view(time.time()))

    stop = StopFlag()
    t_end = time.monotonic() + args.duration if args.duration > 0 else math.inf
    with open_session(zenoh_config(args)) as session:
        # kept and undeclared before the session closes: a callback subscription still declared at the close
        # gets samples the closing session no longer has the ids of ('Received Data for unknown key_expr:
        # Remote resource 1 not found', seen in a CI rehearsal's monitor.log)
        subs = [session.declare_subscriber(key_expr, on_sample),
                session.liveliness().declare_subscriber(key_expr, on_token, history=True)]
        try:
            for key, payload in current_missions(session, fleet, timeout_s=2.0):
                with lock:
                    model.ingest(time.time(), key, payload)
            with Live(current(), refresh_per_second=args.refresh, get_renderable=current, screen=False):
                while not stop.wait(min(0.25, max(0.0, t_end - time.monotonic()))):
                    if time.monotonic() >= t_end:
                        break
        finally:
            for sub in reversed(subs):
                sub.undeclare()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
