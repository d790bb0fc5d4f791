"""Scenario and fleet files (TOML): the fleet, its robots, the mission, tracker and fault timeline.

Parsing is pure: ``scenario_from_dict`` takes the loaded TOML table. Unknown
keys are errors (a misspelt key must not be silently ignored), named in the
message. The file is versioned (``schema = 1``, required). A robot's keys are
layered: ``[defaults]``, then its type's ``[robot_types.NAME]``, then its own
``[robots.ID]``; the more specific layer wins. ``[failure]`` and ``[controller]``
set the failure thresholds and the controller's gains; both travel in the
mission, so every agent uses the same numbers.

Example::

    schema = 1

    [fleet]
    name = "demo"
    duration_s = 40.0

    [mission]
    metric = "linf"            # l1 | l2 | linf
    speed_max = 0.08           # [m/s] structure origin
    turn_rate_max = 0.3        # [rad/s]
    goal = { x = 1.6, y = 1.0, th = 0.3 }   # or path = [[x, y, th], ...] or twist = {vx, vy, w}
    obstacles = [[0.8, 0.5, 0.1]]           # optional: round obstacles [x, y, r] [m; world], at most 256
    scale_min = 0.7            # optional, in a room: the template may shrink to this scale to pass a gap
    shapes = [{ name = "row", points = { r1 = [0.0, 0.25] } }]
                               # optional, in a room: alternative templates (every robot a point) taken, in
                               # this order, where the template cannot pass (docs/planning.md, "Shapes")
    controller = "tracking"    # optional (default: vsfleet.control.DEFAULT_CONTROLLER)
    on_failure = "hold"        # hold | drop | rejoin

    [failure]                  # optional: vsfleet.failure.FailurePolicy thresholds [m, s]
    fail_deviation_m = 0.05
    fail_after_s = 2.0

    [controller]               # optional: the gains of the mission's controller (its factory's keywords)
    along_gain_per_s = 2.0
    deadband_m = 0.004

    [tracker]
    kind = "sim"               # sim | camera (render -> detect; `vsfleet run --tracker` overrides)
    # camera = "../deploy/camera/overhead.toml"   # kind camera: its config, relative to this file
    rate_hz = 30.0
    noise_xy_m = 0.001         # the simulated tracker's noise, latency and drops (kind sim only)
    noise_th_rad = 0.005
    latency_s = 0.005
    drop_prob = 0.0

    [sim]
    rate_hz = 200.0
    truth_rate_hz = 100.0
    engine = "kinematic"       # kinematic | mujoco (physics engine; `vsfleet sim --engine` overrides)

    [defaults]                 # every robot (wheel_base, wheel_speed_max, wheel_accel_max, radius, gain, type)
    wheel_base = 0.1           # [m]
    radius = 0.05              # [m] optional: the robot's body, a disc about its tracked point
    wheel_speed_max = 0.3      # [m/s]
    wheel_accel_max = 1.0      # [m/s^2]
    mass = 0.5                 # [kg] the physics engine's body (engine = "mujoco"; the kinematic one ignores them)
    wheel_radius = 0.02        # [m] nominal; gain scales each wheel's true radius
    friction = 0.8             # wheel-floor sliding friction coefficient

    [robot_types.slow]         # robots of this type (the same keys but type)
    wheel_speed_max = 0.25

    [robots.r1]
    type = "slow"              # optional: one of [robot_types]
    p = [0.25, 0.0]            # [m; structure frame]
    start = [0.0, 0.0, 0.0]    # [m, m, rad; world]
    gain = [1.0, 0.97]         # true/commanded wheel speed, left and right (simulation)

    [[faults]]
    robot = "r1"
    at_s = 10.0                # after the simulation starts
    kind = "stop"              # stop | slow | stall | wheel | none
    factor = 0.0
    duration = 0.0             # [s], 0 = until cleared
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping

from .control import DEFAULT_CONTROLLER
from .errors import VsfleetValueError
from .wire import (
    FAULT_KINDS,
    Mission,
    UnknownFieldError,
    WireError,
    check_known,
    check_name,
    controller_gain_names,
    controller_gains_from_dict,
    failure_from_dict,
    failure_names,
    mission_from_dict,
)

SCHEMA = 1  # the fleet-file format this code reads
PHYSICAL_KEYS = ("mass", "wheel_radius", "friction")  # a robot's body in a physics engine ([sim] engine)
ROBOT_LAYER_KEYS = ("wheel_base", "wheel_speed_max", "wheel_accel_max", "radius", "gain",
                    *PHYSICAL_KEYS)  # defaults and types
OBSTACLE_KEYS = ("x", "y", "r")  # an obstacle written as a table {x, y, r} rather than [x, y, r]
ROBOT_KEYS = ("type", "p", "start", *ROBOT_LAYER_KEYS)
ROBOT_DEFAULTS: dict[str, Any] = {"wheel_base": 0.1, "wheel_speed_max": 0.3, "wheel_accel_max": 1.0,
                                  "gain": [1.0, 1.0], "mass": 0.5, "wheel_radius": 0.02, "friction": 0.8}
ENGINES = ("kinematic", "mujoco")  # [sim] engine: simfleet's physics (mujoco: the optional extra vsfleet[mujoco])


class ScenarioError(VsfleetValueError):
    """A scenario file that is malformed or names unknown keys."""


class UnknownKeyError(ScenarioError):
    """A table of a scenario file with a key the format does not define; ``keys`` names them."""

    def __init__(self, message: str, keys: tuple[str, ...]) -> None:
        super().__init__(message)
        self.keys = keys


@dataclass(frozen=True)
class SimRobot:
    """A simulated robot: start pose [m, rad; world], true envelope, wheel gains (left, right).

    radius [m]: its body (a disc about its tracked point), as in its mission spec; None: a point.
    mass [kg], wheel_radius [m] (nominal: the true one is wheel_radius * gain, per wheel) and friction
    (wheel-floor sliding coefficient): its body in a physics engine ([sim] engine = "mujoco").
    """

    robot: str
    start: tuple[float, float, float]
    wheel_base: float
    wheel_speed_max: float
    wheel_accel_max: float
    gain: tuple[float, float]
    radius: float | None = None
    mass: float = 0.5
    wheel_radius: float = 0.02
    friction: float = 0.8


@dataclass(frozen=True)
class FaultEvent:
    robot: str
    at_s: float
    kind: str
    factor: float
    duration: float


TRACKER_KINDS = ("sim", "camera")
SIM_TRACKER_KEYS = ("noise_xy_m", "noise_th_rad", "latency_s", "drop_prob")


@dataclass(frozen=True)
class TrackerParams:
    """kind sim: the simulated tracker, with its noise [m, rad], latency [s] and drop probability.
    kind camera: the synthetic camera of ``camera`` (a camera config path, relative to the scenario
    file; None: the default one), rendered at rate_hz [Hz] and detected."""

    rate_hz: float = 30.0
    noise_xy_m: float = 0.001
    noise_th_rad: float = 0.005
    latency_s: float = 0.005
    drop_prob: float = 0.0
    kind: str = "sim"
    camera: str | None = None


@dataclass(frozen=True)
class SimParams:
    rate_hz: float = 200.0
    truth_rate_hz: float = 100.0
    engine: str = "kinematic"  # one of ENGINES


@dataclass(frozen=True)
class Scenario:
    name: str
    fleet: str
    duration_s: float
    mission: Mission           # version 1, effective_t 0: the launcher stamps both
    robots: tuple[SimRobot, ...]
    tracker: TrackerParams
    sim: SimParams
    faults: tuple[FaultEvent, ...]


def _only(table: Any, allowed, where: str) -> None:
    """UnknownKeyError naming every key of ``table`` outside ``allowed``; ScenarioError if not a table."""
    if not isinstance(table, Mapping):
        raise ScenarioError(f"[{where}] must be a table, got {type(table).__name__}")
    try:
        check_known(table, allowed, f"[{where}]")
    except UnknownFieldError as exc:
        raise UnknownKeyError(str(exc).replace("unknown field", "unknown key"), exc.fields) from None


def _table(doc: Mapping[str, Any], key: str) -> Mapping[str, Any]:
    v = doc.get(key, {})
    if not isinstance(v, Mapping):
        raise ScenarioError(f"[{key}] must be a table, got {type(v).__name__}")
    return v


def resolve_robot(rid: str, own: Mapping[str, Any], defaults: Mapping[str, Any],
                  types: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """Robot ``rid``'s keys: the code's defaults, then [defaults], its type's table, its own; the last wins.

    Its type is its own ``type``, else the one of [defaults], else none.
    """
    kind = own.get("type", defaults.get("type"))
    if kind is not None and (not isinstance(kind, str) or kind not in types):
        raise ScenarioError(f"[robots.{rid}] type must be one of the [robot_types] "
                            f"{sorted(types) or '(none defined)'}, got {kind!r}")
    layers = (ROBOT_DEFAULTS, {k: v for k, v in defaults.items() if k != "type"},
              types.get(kind, {}) if kind is not None else {}, {k: v for k, v in own.items() if k != "type"})
    out: dict[str, Any] = {}
    for layer in layers:
        out.update(layer)
    return out


def _float(table: Mapping[str, Any], key: str, where: str, default: float | None = None,
           lo: float = -math.inf) -> float:
    if key not in table:
        if default is None:
            raise ScenarioError(f"[{where}] needs {key!r}")
        return default
    v = table[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < lo:
        raise ScenarioError(f"[{where}] {key!r} must be a finite number >= {lo}, got {v!r}")
    return float(v)


def _floats(v: Any, n: int, what: str) -> tuple[float, ...]:
    if (not isinstance(v, list) or len(v) != n
            or not all(isinstance(a, (int, float)) and not isinstance(a, bool) and math.isfinite(a) for a in v)):
        raise ScenarioError(f"{what} must be a list of {n} finite numbers, got {v!r}")
    return tuple(float(a) for a in v)


def _radius(table: Mapping[str, Any], where: str) -> float | None:
    """A robot's body radius [m] (finite, > 0), or None when no layer sets it (a point robot)."""
    if "radius" not in table:
        return None
    v = table["radius"]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0.0:
        raise ScenarioError(f"[{where}] 'radius' must be a finite number > 0 [m], got {v!r}")
    return float(v)


def _obstacles(v: Any) -> Any:
    """[mission] obstacles: each [x, y, r] or a table {x, y, r} (closed), as the wire's [x, y, r] lists."""
    if not isinstance(v, list):
        raise ScenarioError(f"[mission] obstacles must be a list of [x, y, r], got {v!r}")
    out = []
    for i, o in enumerate(v):
        if isinstance(o, Mapping):
            _only(o, OBSTACLE_KEYS, f"mission.obstacles[{i}]")
            missing = [k for k in OBSTACLE_KEYS if k not in o]
            if missing:
                raise ScenarioError(f"[mission.obstacles[{i}]] needs {', '.join(map(repr, missing))}")
            o = [o[k] for k in OBSTACLE_KEYS]
        out.append(o)
    return out


def _check_starts(robots: list[SimRobot], obstacles) -> None:
    """ScenarioError when a robot starts with its body inside an obstacle or overlapping another's body."""
    for s in robots:
        rad = s.radius or 0.0
        for j, (ox, oy, r) in enumerate(obstacles):
            d = math.hypot(s.start[0] - ox, s.start[1] - oy)
            if d < r + rad:
                raise ScenarioError(f"[robots.{s.robot}] start puts it inside obstacle {j} (x {ox:g}, y {oy:g}, "
                                    f"r {r:g}): {d:.4g} m from its centre, less than {r + rad:.4g} m")
    bodies = [s for s in robots if s.radius is not None]
    for a in range(len(bodies)):
        for b in range(a + 1, len(bodies)):
            p, q = bodies[a], bodies[b]
            d = math.hypot(p.start[0] - q.start[0], p.start[1] - q.start[1])
            if d < p.radius + q.radius:
                raise ScenarioError(f"[robots.{p.robot}] and [robots.{q.robot}] start with their bodies "
                                    f"overlapping: {d:.4g} m apart, less than {p.radius + q.radius:.4g} m")


def scenario_from_dict(doc: Mapping[str, Any], name: str = "scenario") -> Scenario:
    """Validate a loaded TOML scenario into a Scenario."""
    _only(doc, {"schema", "fleet", "mission", "failure", "controller", "tracker", "sim", "defaults",
                "robot_types", "robots", "faults"}, "top level")
    schema = doc.get("schema")
    if schema is None:
        raise ScenarioError(f"the file has no schema version: put `schema = {SCHEMA}` at its top")
    if isinstance(schema, bool) or not isinstance(schema, int) or schema != SCHEMA:
        raise ScenarioError(f"schema {schema!r} is not one this vsfleet reads (it reads schema = {SCHEMA})")
    fleet_t = _table(doc, "fleet")
    _only(fleet_t, {"name", "duration_s"}, "fleet")
    fleet = fleet_t.get("name", "demo")
    try:
        check_name(fleet, "fleet name")
    except WireError as exc:
        raise ScenarioError(str(exc)) from None
    duration = _float(fleet_t, "duration_s", "fleet", 30.0, lo=0.0)

    defaults = _table(doc, "defaults")
    _only(defaults, {"type", *ROBOT_LAYER_KEYS}, "defaults")
    types = _table(doc, "robot_types")
    for kind, table in types.items():
        _only(table, ROBOT_LAYER_KEYS, f"robot_types.{kind}")
    robots_t = doc.get("robots")
    if not isinstance(robots_t, Mapping) or not robots_t:
        raise ScenarioError("[robots] must define at least one robot, e.g. [robots.r1]")
    sim_robots, mission_robots = [], {}
    for rid in sorted(robots_t):
        where = f"robots.{rid}"
        _only(robots_t[rid], ROBOT_KEYS, where)
        try:
            check_name(rid, "robot id")
        except WireError as exc:
            raise ScenarioError(str(exc)) from None
        r = resolve_robot(rid, robots_t[rid], defaults, types)
        p = _floats(r.get("p"), 2, f"[{where}] p")
        sim_robots.append(SimRobot(
            robot=rid, start=_floats(r.get("start", [p[0], p[1], 0.0]), 3, f"[{where}] start"),
            wheel_base=_float(r, "wheel_base", where, lo=1e-6),
            wheel_speed_max=_float(r, "wheel_speed_max", where, lo=1e-6),
            wheel_accel_max=_float(r, "wheel_accel_max", where, lo=1e-6),
            gain=_floats(r["gain"], 2, f"[{where}] gain"), radius=_radius(r, where),
            mass=_float(r, "mass", where, lo=1e-6), wheel_radius=_float(r, "wheel_radius", where, lo=1e-6),
            friction=_float(r, "friction", where, lo=1e-6)))
        s = sim_robots[-1]
        mission_robots[rid] = {"p": list(p), "wheel_base": s.wheel_base,
                               "wheel_speed_max": s.wheel_speed_max, "wheel_accel_max": s.wheel_accel_max}
        if s.radius is not None:
            mission_robots[rid]["radius"] = s.radius

    mission_t = dict(_table(doc, "mission"))
    _only(mission_t, {"metric", "speed_max", "turn_rate_max", "goal", "path", "twist", "controller",
                      "on_failure", "obstacles", "scale_min", "shapes"}, "mission")
    if "obstacles" in mission_t:
        mission_t["obstacles"] = _obstacles(mission_t["obstacles"])
    mission_t.update(version=1, effective_t=0.0, robots=mission_robots)
    mission_t.setdefault("metric", "l2")
    try:
        mission = mission_from_dict(mission_t)
    except WireError as exc:
        raise ScenarioError(f"[mission] {exc}") from None
    failure_t = _table(doc, "failure")
    _only(failure_t, failure_names(), "failure")
    controller_t = _table(doc, "controller")
    try:
        _only(controller_t, controller_gain_names(mission.controller), "controller")
    except UnknownKeyError as exc:
        raise UnknownKeyError(f"{exc} (the gains of the mission's controller "
                              f"{mission.controller or DEFAULT_CONTROLLER!r})", exc.keys) from None
    try:
        failure = failure_from_dict(failure_t)
    except WireError as exc:
        raise ScenarioError(f"[failure] {exc}") from None
    try:
        gains = controller_gains_from_dict(controller_t, mission.controller)
    except WireError as exc:
        raise ScenarioError(f"[controller] {exc}") from None
    mission = dataclasses.replace(mission, failure=failure, controller_gains=gains)
    _check_starts(sim_robots, mission.obstacles)

    tr = _table(doc, "tracker")
    _only(tr, {"kind", "camera", "rate_hz", *SIM_TRACKER_KEYS}, "tracker")
    kind = tr.get("kind", "sim")
    if kind not in TRACKER_KINDS:
        raise ScenarioError(f"[tracker] kind must be one of {TRACKER_KINDS}, got {kind!r}")
    if kind == "camera" and set(SIM_TRACKER_KEYS) & set(tr):
        raise ScenarioError(f"[tracker] {sorted(set(SIM_TRACKER_KEYS) & set(tr))} are the simulated tracker's; "
                            "a camera's noise and latency come from its frames")
    camera = tr.get("camera")
    if camera is not None and (kind != "camera" or not isinstance(camera, str) or not camera):
        raise ScenarioError("[tracker] camera (a camera config path) goes with kind = \"camera\"")
    tracker = TrackerParams(
        kind=kind, camera=camera,
        rate_hz=_float(tr, "rate_hz", "tracker", 30.0, lo=1e-3),
        noise_xy_m=_float(tr, "noise_xy_m", "tracker", 0.001, lo=0.0),
        noise_th_rad=_float(tr, "noise_th_rad", "tracker", 0.005, lo=0.0),
        latency_s=_float(tr, "latency_s", "tracker", 0.005, lo=0.0),
        drop_prob=_float(tr, "drop_prob", "tracker", 0.0, lo=0.0))
    if tracker.drop_prob > 1.0:
        raise ScenarioError("[tracker] drop_prob must be in [0, 1]")

    sm = _table(doc, "sim")
    _only(sm, {"rate_hz", "truth_rate_hz", "engine"}, "sim")
    engine = sm.get("engine", "kinematic")
    if engine not in ENGINES:
        raise ScenarioError(f"[sim] engine must be one of {ENGINES}, got {engine!r}")
    sim = SimParams(rate_hz=_float(sm, "rate_hz", "sim", 200.0, lo=1.0),
                    truth_rate_hz=_float(sm, "truth_rate_hz", "sim", 100.0, lo=1e-3), engine=engine)

    faults = []
    for i, f in enumerate(doc.get("faults", [])):
        where = f"faults[{i}]"
        _only(f, {"robot", "at_s", "kind", "factor", "duration"}, where)
        if f.get("robot") not in robots_t:
            raise ScenarioError(f"[{where}] robot must be one of {sorted(robots_t)}")
        if f.get("kind") not in FAULT_KINDS:
            raise ScenarioError(f"[{where}] kind must be one of {FAULT_KINDS}")
        faults.append(FaultEvent(robot=f["robot"], at_s=_float(f, "at_s", where, lo=0.0), kind=f["kind"],
                                 factor=_float(f, "factor", where, 0.0, lo=0.0),
                                 duration=_float(f, "duration", where, 0.0, lo=0.0)))
    return Scenario(name=name, fleet=fleet, duration_s=duration, mission=mission,
                    robots=tuple(sim_robots), tracker=tracker, sim=sim,
                    faults=tuple(sorted(faults, key=lambda e: e.at_s)))
