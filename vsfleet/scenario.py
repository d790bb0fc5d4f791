"""Scenario files (TOML): the fleet, its robots, the mission, tracker and fault timeline.

Parsing is pure: ``scenario_from_dict`` takes the loaded TOML table. Unknown
keys are errors (a misspelt key must not be silently ignored).

Example::

    [fleet]
    name = "demo"
    duration_s = 40.0

    [mission]
    metric = "linf"            # l1 | l2 | linf
    speed_max = 0.08           # [m/s] structure origin
    turn_rate_max = 0.3        # [rad/s]
    goal = { x = 1.6, y = 1.0, th = 0.3 }   # or path = [[x, y, th], ...] or twist = {vx, vy, w}
    controller = "tracking"    # optional
    on_failure = "hold"        # hold | drop | rejoin

    [tracker]
    rate_hz = 30.0
    noise_xy_m = 0.001
    noise_th_rad = 0.005
    latency_s = 0.005
    drop_prob = 0.0

    [sim]
    rate_hz = 200.0
    truth_rate_hz = 100.0

    [robots.r1]
    p = [0.25, 0.0]            # [m; structure frame]
    start = [0.0, 0.0, 0.0]    # [m, m, rad; world]
    wheel_base = 0.1
    wheel_speed_max = 0.3
    wheel_accel_max = 1.0
    gain = [1.0, 0.97]         # true/commanded wheel speed, left and right

    [[faults]]
    robot = "r2"
    at_s = 10.0                # after the simulation starts
    kind = "stop"              # stop | slow | stall | wheel | none
    factor = 0.0
    duration = 0.0             # [s], 0 = until cleared
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

from .errors import VsfleetValueError
from .wire import FAULT_KINDS, Mission, WireError, check_name, mission_from_dict


class ScenarioError(VsfleetValueError):
    """A scenario file that is malformed or names unknown keys."""


@dataclass(frozen=True)
class SimRobot:
    """A simulated robot: start pose [m, rad; world], true envelope, wheel gains (left, right)."""

    robot: str
    start: tuple[float, float, float]
    wheel_base: float
    wheel_speed_max: float
    wheel_accel_max: float
    gain: tuple[float, float]


@dataclass(frozen=True)
class FaultEvent:
    robot: str
    at_s: float
    kind: str
    factor: float
    duration: float


@dataclass(frozen=True)
class TrackerParams:
    rate_hz: float = 30.0
    noise_xy_m: float = 0.001
    noise_th_rad: float = 0.005
    latency_s: float = 0.005
    drop_prob: float = 0.0


@dataclass(frozen=True)
class SimParams:
    rate_hz: float = 200.0
    truth_rate_hz: float = 100.0


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


def _only(table: Mapping[str, Any], allowed: set[str], where: str) -> None:
    extra = set(table) - allowed
    if extra:
        raise ScenarioError(f"[{where}] has unknown keys {sorted(extra)}; allowed: {sorted(allowed)}")


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


def scenario_from_dict(doc: Mapping[str, Any], name: str = "scenario") -> Scenario:
    """Validate a loaded TOML scenario into a Scenario."""
    _only(doc, {"fleet", "mission", "tracker", "sim", "robots", "faults"}, "top level")
    fleet_t = doc.get("fleet", {})
    _only(fleet_t, {"name", "duration_s"}, "fleet")
    fleet = fleet_t.get("name", "demo")
    try:
        check_name(fleet, "fleet name")
    except WireError as exc:
        raise ScenarioError(str(exc)) from None
    duration = _float(fleet_t, "duration_s", "fleet", 30.0, lo=0.0)

    robots_t = doc.get("robots")
    if not isinstance(robots_t, Mapping) or not robots_t:
        raise ScenarioError("[robots] must define at least one robot, e.g. [robots.r1]")
    sim_robots, mission_robots = [], {}
    for rid in sorted(robots_t):
        r = robots_t[rid]
        where = f"robots.{rid}"
        _only(r, {"p", "start", "wheel_base", "wheel_speed_max", "wheel_accel_max", "gain"}, where)
        try:
            check_name(rid, "robot id")
        except WireError as exc:
            raise ScenarioError(str(exc)) from None
        p = _floats(r.get("p"), 2, f"[{where}] p")
        sim_robots.append(SimRobot(
            robot=rid, start=_floats(r.get("start", [p[0], p[1], 0.0]), 3, f"[{where}] start"),
            wheel_base=_float(r, "wheel_base", where, 0.1, lo=1e-6),
            wheel_speed_max=_float(r, "wheel_speed_max", where, 0.3, lo=1e-6),
            wheel_accel_max=_float(r, "wheel_accel_max", where, 1.0, lo=1e-6),
            gain=_floats(r.get("gain", [1.0, 1.0]), 2, f"[{where}] gain")))
        s = sim_robots[-1]
        mission_robots[rid] = {"p": list(p), "wheel_base": s.wheel_base,
                               "wheel_speed_max": s.wheel_speed_max, "wheel_accel_max": s.wheel_accel_max}

    mission_t = dict(doc.get("mission", {}))
    _only(mission_t, {"metric", "speed_max", "turn_rate_max", "goal", "path", "twist", "controller",
                      "on_failure"}, "mission")
    mission_t.update(version=1, effective_t=0.0, robots=mission_robots)
    mission_t.setdefault("metric", "l2")
    try:
        mission = mission_from_dict(mission_t)
    except WireError as exc:
        raise ScenarioError(f"[mission] {exc}") from None

    tr = doc.get("tracker", {})
    _only(tr, {"rate_hz", "noise_xy_m", "noise_th_rad", "latency_s", "drop_prob"}, "tracker")
    tracker = TrackerParams(
        rate_hz=_float(tr, "rate_hz", "tracker", 30.0, lo=1e-3),
        noise_xy_m=_float(tr, "noise_xy_m", "tracker", 0.001, lo=0.0),
        noise_th_rad=_float(tr, "noise_th_rad", "tracker", 0.005, lo=0.0),
        latency_s=_float(tr, "latency_s", "tracker", 0.005, lo=0.0),
        drop_prob=_float(tr, "drop_prob", "tracker", 0.0, lo=0.0))
    if tracker.drop_prob > 1.0:
        raise ScenarioError("[tracker] drop_prob must be in [0, 1]")

    sm = doc.get("sim", {})
    _only(sm, {"rate_hz", "truth_rate_hz"}, "sim")
    sim = SimParams(rate_hz=_float(sm, "rate_hz", "sim", 200.0, lo=1.0),
                    truth_rate_hz=_float(sm, "truth_rate_hz", "sim", 100.0, lo=1e-3))

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
