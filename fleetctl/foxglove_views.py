"""Foxglove views of a fleet's messages, built with the foxglove-sdk's message types (protobuf schemas).

One builder serves both ``vsfleet foxglove`` (live WebSocket) and ``vsfleet
record`` (MCAP), so a recording and the live view show the same panels. Every
drawable is in frame ``world`` (metres, z = 0, heading about +z); timestamps
are the tracker's clock. Topics for fleet ``F`` (see docs/foxglove.md):

* ``/foxglove/vs/F/pose/<robot>``, ``.../truth/<robot>``, ``.../state/<robot>``:
  foxglove.PoseInFrame (the tracker's pose, simfleet's truth, an agent's fitted
  structure pose);
* ``/foxglove/vs/F/scene``: foxglove.SceneUpdate with entities ``robots`` (one
  arrow and label per robot, red when failed, grey when dropped, and a flat disc of
  its body radius when the mission gives it one), ``fitted``
  and ``advanced`` (the structure pose and its template points, one sphere per
  robot), ``targets`` (a line from each robot to its point on the advanced
  structure) and ``mission`` (goal or path, and the obstacles as cylinders of their radius);
* ``/foxglove/vs/F/tf``: foxglove.FrameTransforms, world -> ``F/<robot>`` (each frame) and
  world -> ``F/structure``, ``F/structure_advanced`` (each structure update);
* ``/foxglove/vs/F/goal`` foxglove.PoseInFrame, ``/foxglove/vs/F/path`` foxglove.PosesInFrame;
* ``/foxglove/vs/F/log``: foxglove.Log for failure-policy events, agents'
  rejection counts going up, missions, and messages this builder turned away.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, NamedTuple

import foxglove.messages as fm

from vsfleet.geometry import Pose2
from vsfleet.step import mission_arrays, planned_way
from vsfleet.wire import (
    MAX_ROBOTS,
    FrameMsg,
    Mission,
    WireError,
    check_name,
    decode_event,
    decode_frame,
    decode_mission,
    decode_pose,
    decode_state,
    decode_truth,
)

FRAME_ID = "world"
LOG_NAME = "vsfleet"
REJECT_LOG_EVERY_NS = 1_000_000_000  # at most one "turned away" line per key per second of tracker time
MISSION_REDRAW_NS = 1_000_000_000    # the mission entity rides along with a structure update once a second
MAX_KEYS = 4096                      # keys remembered for rate-limiting "turned away" lines

GREEN = fm.Color(r=0.1, g=0.75, b=0.3, a=1.0)
ORANGE = fm.Color(r=1.0, g=0.55, b=0.0, a=1.0)
BLUE = fm.Color(r=0.15, g=0.45, b=0.95, a=1.0)
RED = fm.Color(r=0.95, g=0.1, b=0.1, a=1.0)
GREY = fm.Color(r=0.55, g=0.55, b=0.55, a=0.8)
WHITE = fm.Color(r=1.0, g=1.0, b=1.0, a=1.0)
PURPLE = fm.Color(r=0.6, g=0.3, b=0.9, a=1.0)
OBSTACLE = fm.Color(r=0.45, g=0.3, b=0.2, a=0.6)
OBSTACLE_HEIGHT_M = 0.2   # an obstacle's cylinder (only its footprint, a disc of radius r, matters)
BODY_HEIGHT_M = 0.01      # a robot's body: a flat disc of its radius on the ground
BODY_BLUE = fm.Color(r=0.15, g=0.45, b=0.95, a=0.35)   # the robot's arrow colour, translucent
BODY_RED = fm.Color(r=0.95, g=0.1, b=0.1, a=0.35)
BODY_GREY = fm.Color(r=0.55, g=0.55, b=0.55, a=0.35)
PLAN_SWEPT = fm.Color(r=0.1, g=0.75, b=0.3, a=0.2)      # the plan's swept bodies (GREEN, faint) ...
PLAN_SWEPT_BLOCKED = fm.Color(r=0.45, g=0.3, b=0.2, a=0.2)  # ... on a blocked plan (OBSTACLE, faint)

# one level for every kind an event may carry (vsfleet.wire.EVENT_KINDS; tests/test_foxglove_live.py checks it):
# 'blocked' was missing, and the first run to record one (a loaded CI rehearsal, 2026-12-05) crashed writing its MCAP
EVENT_LEVEL = {"fail": fm.LogLevel.Warning, "drop": fm.LogLevel.Warning,
               "recover": fm.LogLevel.Info, "rejoin": fm.LogLevel.Info,
               "blocked": fm.LogLevel.Warning, "unblocked": fm.LogLevel.Info}


class View(NamedTuple):
    """One Foxglove message: topic, SDK message (PoseInFrame, SceneUpdate, ...), its time [ns, tracker clock]."""

    topic: str
    message: Any
    t_ns: int


def seconds_to_ns(t_s: float) -> int:
    """UNIX seconds -> integer nanoseconds, exact to the nanosecond for float64 times near now."""
    whole = math.floor(t_s)
    return int(whole) * 1_000_000_000 + round((t_s - whole) * 1e9)


MAX_STAMP_NS = (2**32) * 1_000_000_000  # foxglove.Timestamp holds uint32 seconds


def stamp_ns(t_s: float) -> int:
    """A message's t [s] as ns; WireError when a Foxglove timestamp cannot hold it."""
    t_ns = seconds_to_ns(t_s)
    fox_time(t_ns)
    return t_ns


def fox_time(t_ns: int) -> fm.Timestamp:
    """A Foxglove timestamp; WireError for a time before the UNIX epoch or after 2106 (uint32 seconds)."""
    if not 0 <= t_ns < MAX_STAMP_NS:
        raise WireError(f"time {t_ns * 1e-9:.9g} s is outside what a Foxglove timestamp holds (0 to 2**32 s)")
    return fm.Timestamp(sec=t_ns // 1_000_000_000, nsec=t_ns % 1_000_000_000)


def yaw(th: float) -> fm.Quaternion:
    """The rotation by th [rad] about +z."""
    return fm.Quaternion(x=0.0, y=0.0, z=math.sin(th / 2.0), w=math.cos(th / 2.0))


def fox_pose(x: float, y: float, th: float, z: float = 0.0) -> fm.Pose:
    """A pose on the ground plane (z [m]), heading th [rad] about +z."""
    return fm.Pose(position=fm.Vector3(x=x, y=y, z=z), orientation=yaw(th))


def pose_in_frame(t_ns: int, x: float, y: float, th: float) -> fm.PoseInFrame:
    return fm.PoseInFrame(timestamp=fox_time(t_ns), frame_id=FRAME_ID, pose=fox_pose(x, y, th))


def poses_in_frame(t_ns: int, poses: Iterable[tuple[float, float, float]]) -> fm.PosesInFrame:
    return fm.PosesInFrame(timestamp=fox_time(t_ns), frame_id=FRAME_ID, poses=[fox_pose(*p) for p in poses])


def structure_points(mission: Mission, x: float, y: float, th: float,
                     shape: int = 0) -> list[tuple[float, float, float]]:
    """Each robot's point of the structure at pose (x, y, th) [m, rad; world], heading th, in mission order;
    shape: the structure's (a state's ``shape``: 0 the template, k the mission's k-th reshape)."""
    c, s = math.cos(th), math.sin(th)
    points = [sp.p for _, sp in mission.robots]
    if shape > 0:
        shapes = mission_arrays(mission).shapes
        if shape <= len(shapes):
            points = [tuple(p) for p in shapes[shape - 1][1].tolist()]
    return [(x + c * px - s * py, y + s * px + c * py, th) for px, py in points]


def _p3(x: float, y: float, z: float = 0.0) -> fm.Point3:
    return fm.Point3(x=x, y=y, z=z)


def _sphere(x: float, y: float, d_m: float, color: fm.Color) -> fm.SpherePrimitive:
    return fm.SpherePrimitive(pose=fox_pose(x, y, 0.0), size=fm.Vector3(x=d_m, y=d_m, z=d_m), color=color)


def _arrow(x: float, y: float, th: float, length_m: float, color: fm.Color) -> fm.ArrowPrimitive:
    return fm.ArrowPrimitive(pose=fox_pose(x, y, th), shaft_length=0.7 * length_m, shaft_diameter=0.1 * length_m,
                             head_length=0.3 * length_m, head_diameter=0.25 * length_m, color=color)


def _entity(t_ns: int, ident: str, meta: dict[str, str], **prims) -> fm.SceneEntity:
    return fm.SceneEntity(timestamp=fox_time(t_ns), frame_id=FRAME_ID, id=ident,
                          metadata=[fm.KeyValuePair(key=k, value=v) for k, v in meta.items()], **prims)


def structure_entity(t_ns: int, ident: str, mission: Mission, pose: tuple[float, float, float],
                     color: fm.Color, meta: dict[str, str], shape: int = 0) -> fm.SceneEntity:
    """The structure at ``pose`` [m, rad; world] in ``shape``: an arrow, its points (spheres, mission order),
    and an outline through them."""
    pts = structure_points(mission, *pose, shape=shape)
    lines = [fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineLoop, thickness=0.005, color=color,
                              points=[_p3(px, py) for px, py, _ in pts])] if len(pts) > 1 else []
    return _entity(t_ns, ident, meta, arrows=[_arrow(*pose, 0.1, color)],
                   spheres=[_sphere(px, py, 0.03, color) for px, py, _ in pts], lines=lines)


def _disc(x: float, y: float, r_m: float, height_m: float, color: fm.Color) -> fm.CylinderPrimitive:
    """A vertical cylinder of radius r_m [m] standing on the ground at (x, y) [m; world]."""
    return fm.CylinderPrimitive(pose=fox_pose(x, y, 0.0, height_m / 2.0),
                                size=fm.Vector3(x=2.0 * r_m, y=2.0 * r_m, z=height_m),
                                bottom_scale=1.0, top_scale=1.0, color=color)


def frame_transforms(t_ns: int, children: dict[str, tuple[float, float, float]]) -> fm.FrameTransforms:
    """world -> child frame at each pose (x, y, th) [m, rad; world]."""
    out = []
    for child, (x, y, th) in children.items():
        out.append(fm.FrameTransform(timestamp=fox_time(t_ns), parent_frame_id=FRAME_ID, child_frame_id=child,
                                     translation=fm.Vector3(x=x, y=y, z=0.0), rotation=yaw(th)))
    return fm.FrameTransforms(transforms=out)


def mission_entity(t_ns: int, mission: Mission) -> fm.SceneEntity:
    """The mission's goal (an arrow) or path (a line through its waypoints) [m, rad; world], and its
    obstacles (cylinders of their radius, in mission order)."""
    goal = mission.goal or (mission.path[-1] if mission.path else None)
    prims: dict[str, list] = {}
    if mission.obstacles:
        prims["cylinders"] = [_disc(x, y, r, OBSTACLE_HEIGHT_M, OBSTACLE) for x, y, r in mission.obstacles]
    if goal is not None:
        prims["arrows"] = [_arrow(*goal, 0.15, PURPLE)]
    if mission.path:
        prims["lines"] = [fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, thickness=0.004,
                                           color=PURPLE, points=[_p3(x, y) for x, y, _ in mission.path])]
    return _entity(t_ns, "mission", {"version": str(mission.version)}, **prims)


PLAN_SWEEP_M = 0.3          # the plan's swept bodies: one set every this far along it [m]
PLAN_MAX_DISCS = 2000       # ... at most this many discs in all (a long way for a large fleet: fewer sets)


def swept_poses(way, spacing_m: float) -> list[tuple[float, float, float]]:
    """Where a plan's bodies are drawn swept along it (the Foxglove scene, vsfleet plot, vsfleet monitor): its
    first pose, each pose once the way has run spacing_m [m] since the last one kept, and its last pose."""
    out: list[tuple[float, float, float]] = []
    run, last = 0.0, None
    for x, y, th in way:
        if last is not None:
            run += math.hypot(x - last[0], y - last[1])
        if last is None or run >= spacing_m:
            out.append((float(x), float(y), float(th)))
            run = 0.0
        last = (x, y)
    if len(way) and out[-1] != tuple(float(v) for v in way[-1]):
        out.append(tuple(float(v) for v in way[-1]))
    return out


def plan_entity(t_ns: int, mission: Mission, pose: tuple[float, float, float], meta: dict[str, str],
                shape: int = 0) -> fm.SceneEntity | None:
    """The room's plan from a fitted structure pose (vsfleet.step.planned_way: the field's whole descent of the
    structure's shape), a line, and the robots' bodies swept along it (thin discs of their radius); None
    without a room's field."""
    planned = planned_way(mission, Pose2(*pose), shape=shape)
    if planned is None:
        return None
    way, blocked = planned
    color = OBSTACLE if blocked else GREEN
    line = fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, thickness=0.004, color=color,
                            points=[_p3(x, y) for x, y, _ in way])
    bodies = [r for r in mission.radii if r > 0.0]
    sets = swept_poses(way, PLAN_SWEEP_M)
    if bodies:
        sets = sets[:: max(1, math.ceil(len(sets) * len(bodies) / PLAN_MAX_DISCS))]
    swept = [_disc(px, py, r, 0.002, PLAN_SWEPT_BLOCKED if blocked else PLAN_SWEPT)
             for x, y, th in sets for (px, py, _), r in zip(structure_points(mission, x, y, th, shape), mission.radii)
             if r > 0.0]
    return _entity(t_ns, "plan", {**meta, "blocked": str(blocked).lower()}, lines=[line], cylinders=swept)


def log_message(t_ns: int, level: fm.LogLevel, name: str, text: str) -> fm.Log:
    return fm.Log(timestamp=fox_time(t_ns), level=level, message=text, name=name)


@dataclass
class _Fleet:
    """What the views remember of one fleet."""

    mission: Mission | None = None
    poses: dict[str, tuple[float, float, float]] = field(default_factory=dict)  # latest tracker pose per robot
    frame_srcs: set[str] = field(default_factory=set)     # sources seen publishing frame/<src>
    pose_group: dict[str, tuple[int, set[str]]] = field(default_factory=dict)  # src -> (seq, robots seen)
    structure_seq: int = -1
    failed: set[str] = field(default_factory=set)
    dropped: set[str] = field(default_factory=set)
    rejected: dict[str, int] = field(default_factory=dict)  # agent -> last `rejected` count in its state
    mission_drawn_ns: int = 0  # when the mission entity was last sent (re-sent each second for late viewers)


class FleetViews:
    """Turns wire messages (key, msgpack payload) into Foxglove views. Not thread-safe; one caller thread.

    ``now_ns`` is the newest tracker time seen (frames and poses) [ns], to broadcast as the server's time.
    """

    def __init__(self, wanted: Callable[[str], bool] | None = None) -> None:
        """wanted(topic): False to skip building a per-message view nobody watches (the state is still kept)."""
        self.wanted = wanted or (lambda topic: True)
        self.fleets: dict[str, _Fleet] = {}
        self.now_ns = 0
        self.turned_away = 0
        self._last_reject_log: dict[str, int] = {}

    def on_message(self, key: str, payload: bytes, t_ns: int) -> list[View]:
        """Views of one message; ``t_ns`` [ns] is used for messages without their own ``t``."""
        parts = _split_key(key)
        if parts is None:
            return []
        fleet, kind, rest = parts
        f = self.fleets.setdefault(fleet, _Fleet())
        base = f"/foxglove/vs/{fleet}"
        try:
            if rest is not None and kind in ("frame", "pose", "truth", "state", "event"):
                check_name(rest, "src" if kind == "frame" else "robot")  # one key chunk
            if kind == "frame" and rest:
                m = decode_frame(payload)
                if m.src != rest:
                    raise WireError(f"frame on frame/{rest} says it is from {m.src!r}")
                return self._frame(base, f, m)
            if kind == "pose" and rest:
                return self._pose(base, f, rest, payload)
            if kind == "truth" and rest:
                m = decode_truth(payload)
                t, topic = stamp_ns(m.t), f"{base}/truth/{rest}"
                return [View(topic, pose_in_frame(t, m.x, m.y, m.th), t)] if self.wanted(topic) else []
            if kind == "state" and rest:
                return self._state(base, f, rest, payload)
            if kind == "event" and rest:
                return self._event(base, f, rest, payload)
            if kind == "mission" and rest is None:
                return self._mission(base, f, payload, t_ns)
        except WireError as exc:
            return self._turned_away(base, key, str(exc), t_ns)
        return []

    # -- per kind
    def _clock(self, t_ns: int) -> None:
        self.now_ns = max(self.now_ns, t_ns)

    def _robots(self, base: str, f: _Fleet, t_ns: int, meta: dict[str, str]) -> list[View]:
        views = []
        if self.wanted(f"{base}/tf"):
            fleet = base.rsplit("/", 1)[1]
            children = {f"{fleet}/{r}": f.poses[r] for r in sorted(f.poses)}
            views.append(View(f"{base}/tf", frame_transforms(t_ns, children), t_ns))
        if not self.wanted(f"{base}/scene"):
            return views
        arrows, texts, bodies = [], [], []
        radii = {r: s.radius for r, s in f.mission.robots if s.radius is not None} if f.mission is not None else {}
        for robot in sorted(f.poses):
            x, y, th = f.poses[robot]
            color, body = ((RED, BODY_RED) if robot in f.failed else (GREY, BODY_GREY) if robot in f.dropped
                           else (BLUE, BODY_BLUE))
            arrows.append(_arrow(x, y, th, 0.12, color))
            if robot in radii:
                bodies.append(_disc(x, y, radii[robot], BODY_HEIGHT_M, body))
            texts.append(fm.TextPrimitive(pose=fox_pose(x, y, 0.0, 0.05), billboard=True, font_size=14.0,
                                          scale_invariant=True, color=WHITE, text=robot))
        entity = _entity(t_ns, "robots", meta, arrows=arrows, texts=texts, cylinders=bodies)
        views.insert(0, View(f"{base}/scene", fm.SceneUpdate(entities=[entity]), t_ns))
        return views

    def _frame(self, base: str, f: _Fleet, m: FrameMsg) -> list[View]:
        t = stamp_ns(m.t)
        if len(f.poses.keys() | m.poses.keys()) > MAX_ROBOTS:
            raise WireError(f"more than {MAX_ROBOTS} robots seen in all")
        self._clock(t)
        f.frame_srcs.add(m.src)
        f.poses.update(m.poses)
        return self._robots(base, f, t, {"src": m.src, "seq": str(m.seq)})

    def _pose(self, base: str, f: _Fleet, robot: str, payload: bytes) -> list[View]:
        m = decode_pose(payload)
        t = stamp_ns(m.t)
        self._clock(t)
        topic = f"{base}/pose/{robot}"
        views = [View(topic, pose_in_frame(t, m.x, m.y, m.th), t)] if self.wanted(topic) else []
        if m.src in f.frame_srcs:
            return views  # this tracker's frames draw the robots
        if robot not in f.poses and len(f.poses) >= MAX_ROBOTS:
            raise WireError(f"more than {MAX_ROBOTS} robots seen in all")
        f.poses[robot] = (m.x, m.y, m.th)
        seq, seen = f.pose_group.get(m.src, (None, set()))
        if seq != m.seq:
            seq, seen = m.seq, set()
        seen.add(robot)
        f.pose_group[m.src] = (seq, seen)
        want = set(f.mission.robot_ids) if f.mission is not None else None
        if want is None or want <= seen:  # the frame is complete (or no mission to say what complete is)
            views += self._robots(base, f, t, {"src": m.src, "seq": str(m.seq)})
        return views

    def _state(self, base: str, f: _Fleet, agent: str, payload: bytes) -> list[View]:
        m = decode_state(payload)
        t = stamp_ns(m.t)
        topic = f"{base}/state/{agent}"
        views = [View(topic, pose_in_frame(t, m.x, m.y, m.th), t)] if self.wanted(topic) else []
        if agent not in f.rejected and len(f.rejected) >= MAX_ROBOTS:
            raise WireError(f"more than {MAX_ROBOTS} agents seen in all")
        before = f.rejected.get(agent, 0)
        f.rejected[agent] = m.rejected
        if m.rejected > before:
            views.append(View(f"{base}/log", log_message(
                t, fm.LogLevel.Warning, f"agent {agent}",
                f"agent {agent} rejected {m.rejected - before} more message(s), {m.rejected} in all"), t))
        mission = f.mission
        if mission is not None and m.seq > f.structure_seq and self.wanted(f"{base}/scene"):
            f.structure_seq = m.seq
            meta = {"seq": str(m.seq), "by": agent, "cost_m": repr(m.cost), "mission": str(m.mission)}
            fitted = structure_entity(t, "fitted", mission, (m.x, m.y, m.th), GREEN, meta, m.shape)
            advanced = structure_entity(t, "advanced", mission, (m.gx, m.gy, m.gth), ORANGE, meta, m.shape)
            targets = structure_points(mission, m.gx, m.gy, m.gth, m.shape)
            pts = []
            for (robot, _), (tx, ty, _) in zip(mission.robots, targets):
                if robot in f.poses:
                    rx, ry, _ = f.poses[robot]
                    pts += [_p3(rx, ry), _p3(tx, ty)]
            lines = [fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineList, thickness=0.003, color=ORANGE,
                                      points=pts)] if pts else []
            entities = [fitted, advanced, _entity(t, "targets", meta, lines=lines)]
            if t - f.mission_drawn_ns >= MISSION_REDRAW_NS:
                entities.append(mission_entity(t, mission))
                plan = plan_entity(t, mission, (m.x, m.y, m.th), meta, m.shape)   # what the agents follow from here
                if plan is not None:
                    entities.append(plan)
                f.mission_drawn_ns = t
            views.append(View(f"{base}/scene", fm.SceneUpdate(entities=entities), t))
            if self.wanted(f"{base}/tf"):
                fleet = base.rsplit("/", 1)[1]
                views.append(View(f"{base}/tf", frame_transforms(t, {
                    f"{fleet}/structure": (m.x, m.y, m.th), f"{fleet}/structure_advanced": (m.gx, m.gy, m.gth)}), t))
        return views

    def _event(self, base: str, f: _Fleet, by: str, payload: bytes) -> list[View]:
        m = decode_event(payload)
        if m.by != by:
            raise WireError(f"event from {by!r} says it is by {m.by!r}")
        t = stamp_ns(m.t)
        if m.kind == "fail":
            f.failed.add(m.robot)
        elif m.kind == "recover":
            f.failed.discard(m.robot)
        elif m.kind == "drop":
            f.dropped.add(m.robot)
        elif m.kind == "rejoin":
            f.dropped.discard(m.robot)
            f.failed.discard(m.robot)
        if m.kind in ("blocked", "unblocked"):   # the structure's: dev is its distance to the goal
            dev = f"{m.dev:.3f} m from the goal" + (f", {m.why.replace('_', ' ')}" if m.why else "")
        else:
            dev = "unseen" if not math.isfinite(m.dev) else f"deviation {m.dev:.3f} m"
        text = f"{m.robot}: {m.kind} at frame {m.seq} ({dev}), decided by {m.by}"
        return [View(f"{base}/log", log_message(t, EVENT_LEVEL[m.kind], f"agent {by}", text), t)]

    def _mission(self, base: str, f: _Fleet, payload: bytes, t_ns: int) -> list[View]:
        mission = decode_mission(payload)
        if f.mission is not None and mission.version == f.mission.version and mission == f.mission:
            return []  # the same mission again (a query's answer, a republish)
        f.mission = mission
        f.structure_seq = -1
        t = min(max(t_ns, 0), MAX_STAMP_NS - 1)
        target = ("goal", mission.goal) if mission.goal is not None else \
            ("path", mission.path) if mission.path is not None else ("twist", mission.twist)
        text = (f"mission v{mission.version}: {target[0]} {_fmt(target[1])}, {len(mission.robots)} robots, "
                f"metric {mission.metric}, speed_max {mission.speed_max} m/s, on_failure {mission.on_failure}")
        if mission.obstacles:
            text += f", {len(mission.obstacles)} obstacle{'s' if len(mission.obstacles) > 1 else ''}"
        views = [View(f"{base}/log", log_message(t, fm.LogLevel.Info, LOG_NAME, text), t)]
        goal = mission.goal or (mission.path[-1] if mission.path else None)
        if goal is not None:
            views.append(View(f"{base}/goal", pose_in_frame(t, *goal), t))
        if mission.path:
            views.append(View(f"{base}/path", poses_in_frame(t, mission.path), t))
        views.append(View(f"{base}/scene", fm.SceneUpdate(entities=[mission_entity(t, mission)]), t))
        f.mission_drawn_ns = t
        return views

    def _turned_away(self, base: str, key: str, why: str, t_ns: int) -> list[View]:
        self.turned_away += 1
        t = min(max(t_ns, self.now_ns, 0), MAX_STAMP_NS - 1)
        if len(self._last_reject_log) > MAX_KEYS:
            self._last_reject_log.clear()
        last = self._last_reject_log.get(key)
        if last is not None and t - last < REJECT_LOG_EVERY_NS:
            return []
        self._last_reject_log[key] = t
        return [View(f"{base}/log", log_message(t, fm.LogLevel.Warning, LOG_NAME,
                                                 f"turned away a message on {key}: {why}"), t)]


def _fmt(v: Any) -> str:
    if isinstance(v, tuple) and v and isinstance(v[0], tuple):
        return f"of {len(v)} waypoints to {_fmt(v[-1])}"
    return "(" + ", ".join(f"{c:.3f}" for c in v) + ")" if v is not None else "-"


def _split_key(key: str) -> tuple[str, str, str | None] | None:
    """``vs/<fleet>/<kind>[/<rest>]`` -> (fleet, kind, rest or None); None for other keys."""
    parts = key.split("/", 3)
    if len(parts) < 3 or parts[0] != "vs" or not parts[1] or not parts[2]:
        return None
    return parts[1], parts[2], (parts[3] if len(parts) > 3 and parts[3] else None)
