"""Pure physics of simulated robots, every robot a row: commanded -> applied wheel speeds -> exact arcs.

Per physics step: a command older than its ttl counts as zero; the wheel gains
(the paper's robots "differ in performance") scale the command; a fault
modifies it; the result is clipped to the wheel speed limit and slewed by the
wheel acceleration limit; the pose is integrated exactly over the step
(vsfleet.kinematics.integrate_arcs). ``step_robots`` does this for arrays of
all robots at once; ``step_robot`` and ``step_fleet`` are the same rule for one
robot and for a dict of robots.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vsfleet.geometry import Pose2
from vsfleet.kinematics import integrate_arcs, wrap_angles
from vsfleet.scenario import SimRobot
from vsfleet.wire import FAULT_KINDS

try:   # np.clip's own ufunc, without the Python layers np.clip goes through to it (~2 us a call)
    from numpy._core.umath import clip as _clip
except ImportError:   # pragma: no cover - another numpy
    _clip = np.clip

FAULT_CODES = {kind: code for code, kind in enumerate(FAULT_KINDS)}  # the wire's order: none 0, stop 1, ...
_STOP, _SLOW, _STALL, _WHEEL = (FAULT_CODES[k] for k in ("stop", "slow", "stall", "wheel"))


@dataclass(frozen=True)
class Fault:
    """An active fault: kind (none/stop/slow/stall/wheel), factor, and end time [s, sim clock; inf = until cleared]."""

    kind: str = "none"
    factor: float = 1.0
    until_t: float = float("inf")

    def active(self, t: float) -> bool:
        return self.kind != "none" and t < self.until_t


@dataclass(frozen=True)
class RobotState:
    """Pose [m, rad; world] and applied wheel speeds [m/s]."""

    pose: Pose2
    vl: float = 0.0
    vr: float = 0.0


@dataclass(frozen=True)
class FleetParams:
    """Each robot's wheel gains (n, 2), speed limit (n,) [m/s], acceleration limit (n,) [m/s^2] and
    wheel base (n,) [m], rows in the order given."""

    gain: np.ndarray
    speed_max_m_s: np.ndarray
    accel_max_m_s2: np.ndarray
    wheel_base_m: np.ndarray

    @classmethod
    def of(cls, robots) -> "FleetParams":
        return cls(np.array([r.gain for r in robots], dtype=float).reshape(-1, 2),
                   np.array([r.wheel_speed_max for r in robots], dtype=float),
                   np.array([r.wheel_accel_max for r in robots], dtype=float),
                   np.array([r.wheel_base for r in robots], dtype=float))


@dataclass(frozen=True)
class FaultArrays:
    """Every robot's fault as arrays: kind code (n,) (FAULT_CODES), factor (n,), until_t (n,) [s]."""

    kind: np.ndarray
    factor: np.ndarray
    until_t: np.ndarray

    @classmethod
    def of(cls, faults) -> "FaultArrays":
        return cls(np.array([FAULT_CODES[f.kind] for f in faults], dtype=int),
                   np.array([f.factor for f in faults], dtype=float),
                   np.array([f.until_t for f in faults], dtype=float))


def applied_wheels(wheels_m_s: np.ndarray, cmd_m_s: np.ndarray, cmd_fresh: np.ndarray, faults: FaultArrays,
                   params: FleetParams, t: float, dt_s: float) -> np.ndarray:
    """The wheel speeds [m/s] (n, 2) the motors apply over the step of dt_s [s] at sim time t [s].

    wheels_m_s (n, 2): those of the previous step; cmd_m_s (n, 2) the commanded ones, cmd_fresh (n,)
    within their ttl. The true/commanded gains, the faults, the speed limit and the acceleration limit
    (a stop or stall cuts at once). Every engine's actuators follow this rule.
    """
    u, dv = _wheel_targets(cmd_m_s, cmd_fresh, faults, params, t, dt_s)
    return wheels_m_s + _clip(u - wheels_m_s, -dv, dv)


def _wheel_targets(cmd_m_s: np.ndarray, cmd_fresh: np.ndarray, faults: FaultArrays, params: FleetParams, t: float,
                   dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """applied_wheels' (u, dv): the wheel speeds (n, 2) [m/s] the motors head for over the step at sim time t [s]
    (gains, faults, speed limit) and how far (n, 1) [m/s] each may move toward them. Where ``faults`` has no
    fault at all, the same at every t."""
    u = np.where(np.asarray(cmd_fresh, dtype=bool)[:, None], cmd_m_s, 0.0) * params.gain
    dv = params.accel_max_m_s2 * dt_s
    if faults.kind.any():   # else no fault acts, and each np.where below would give u back as it is
        active = (faults.kind != 0) & (t < faults.until_t)
        halted = active & ((faults.kind == _STOP) | (faults.kind == _STALL))
        u = np.where(halted[:, None], 0.0, u)
        u = np.where((active & (faults.kind == _SLOW))[:, None], u * faults.factor[:, None], u)
        u[:, 0] = np.where(active & (faults.kind == _WHEEL), u[:, 0] * faults.factor, u[:, 0])
        dv = np.where(halted, np.inf, dv)   # a halted robot halts now (motor cut), not after a ramp
    vmax = params.speed_max_m_s[:, None]
    return _clip(u, -vmax, vmax), dv[:, None]


def step_robots(pose_world: np.ndarray, wheels_m_s: np.ndarray, cmd_m_s: np.ndarray, cmd_fresh: np.ndarray,
                faults: FaultArrays, params: FleetParams, t: float, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Advance every robot by one physics step of dt_s [s] at sim time t [s].

    pose_world (n, 3) [m, m, rad], wheels_m_s (n, 2) the applied wheel speeds, cmd_m_s (n, 2) the
    commanded ones, cmd_fresh (n,) within their ttl. Returns the new poses (heading wrapped) and
    applied wheel speeds (applied_wheels), the pose integrated exactly over the step.
    """
    wheels = applied_wheels(wheels_m_s, cmd_m_s, cmd_fresh, faults, params, t, dt_s)
    pose = integrate_arcs(pose_world, wheels, dt_s, params.wheel_base_m)
    pose[:, 2] = wrap_angles(pose[:, 2])
    return pose, wheels


def step_robot(state: RobotState, robot: SimRobot, cmd_vl: float, cmd_vr: float, cmd_fresh: bool,
               fault: Fault, t: float, dt_s: float) -> RobotState:
    """Advance one robot by one physics step of ``dt_s`` at sim time ``t`` (step_robots on one row)."""
    pose, wheels = step_robots(np.array([state.pose.as_tuple()]), np.array([[state.vl, state.vr]]),
                               np.array([[cmd_vl, cmd_vr]]), np.array([cmd_fresh]), FaultArrays.of([fault]),
                               FleetParams.of([robot]), t, dt_s)
    return RobotState(Pose2(*pose[0]), float(wheels[0, 0]), float(wheels[0, 1]))


def step_fleet(states: dict[str, RobotState], robots: dict[str, SimRobot],
               cmds: dict[str, tuple[float, float]], faults: dict[str, Fault], timeline: list,
               t: float, dt_s: float, substeps: int) -> float:
    """Advance every robot by ``substeps`` physics steps of ``dt_s`` from sim time ``t`` [s],
    starting the timeline's faults (FaultEvent, ordered by at_s) when they are due; returns the
    new time. ``states``, ``faults`` and ``timeline`` are updated in place; commands are fresh.
    The kinematic engine from ``states``, stepped by step_engine_fleet (the same rule as any engine)."""
    ids = list(robots)
    engine = KinematicEngine([robots[r] for r in ids], (), dt_s)
    engine.pose = np.array([states[r].pose.as_tuple() for r in ids], dtype=float)
    engine.wheels = np.array([(states[r].vl, states[r].vr) for r in ids], dtype=float)
    return step_engine_fleet(engine, states, robots, cmds, faults, timeline, t, dt_s, substeps)


def step_engine_fleet(engine, states: dict[str, RobotState], robots: dict, cmds: dict[str, tuple[float, float]],
                      faults: dict[str, Fault], timeline: list, t: float, dt_s: float, substeps: int) -> float:
    """step_fleet on an engine (its rows in the order of ``robots``): ``substeps`` steps from sim time t [s],
    starting the timeline's faults when due; ``states`` (from the engine), ``faults`` and ``timeline``
    updated in place, commands fresh; returns the new time."""
    ids = list(robots)
    cmd = np.array([cmds[r] for r in ids], dtype=float)
    fresh = np.ones(len(ids), dtype=bool)
    arrays = FaultArrays.of([faults[r] for r in ids])
    times, t_end = [], t   # the steps' sim times, each dt_s after the last
    for _ in range(substeps):
        times.append(t_end)
        t_end += dt_s
    steps = getattr(engine, "steps", None)
    if steps is not None and times and not (timeline and timeline[0].at_s <= max(times)) \
            and _settled(arrays, min(times), max(times)):
        steps(cmd, fresh, arrays, t, substeps)   # no fault starts or ends: the same steps in one call
    else:
        for t in times:
            if timeline and timeline[0].at_s <= t:
                while timeline and timeline[0].at_s <= t:
                    ev = timeline.pop(0)
                    faults[ev.robot] = Fault(ev.kind, ev.factor, t + ev.duration if ev.duration > 0 else float("inf"))
                arrays = FaultArrays.of([faults[r] for r in ids])
            engine.step(cmd, fresh, arrays, t)
    for r, pose, (vl, vr) in zip(ids, engine.pose.tolist(), engine.wheels.tolist()):   # Python floats: the same values
        states[r] = RobotState(Pose2(*pose), vl, vr)
    return t_end


def _settled(faults: FaultArrays, t0: float, t1: float) -> bool:
    """Whether each fault acts alike at every sim time from t0 to t1 [s] (a fault acts while t < until_t: alike at
    both ends, alike between)."""
    return not faults.kind.any() or np.array_equal(t0 < faults.until_t, t1 < faults.until_t)


@dataclass(frozen=True)
class Contact:
    """A contact that began: robot ``robot`` touched ``other`` (a robot id, kind "robot", or an obstacle's
    index in the mission, kind "obstacle") at sim time t [s], at (x, y) [m; world], ``depth_m`` [m] into
    each other (the engine's soft contact) when it was first seen."""

    t: float
    robot: str
    other: str | int
    kind: str
    x: float
    y: float
    depth_m: float

    def describe(self) -> str:
        what = f"robot {self.other}" if self.kind == "robot" else f"obstacle {self.other}"
        return (f"contact: {self.robot} with {what} at t={self.t:.3f} ({self.x:+.4f}, {self.y:+.4f}) m, "
                f"depth {1000 * self.depth_m:.2f} mm")


class KinematicEngine:
    """The kinematic engine as an object (simfleet/engine.py's interface): every robot's pose (n, 3) and
    applied wheel speeds (n, 2), advanced by step_robots; no body stops another, so no contacts."""

    name = "kinematic"

    def __init__(self, robots, obstacles, dt_s: float) -> None:
        self.params = FleetParams.of(list(robots))
        self.pose = np.array([r.start for r in robots], dtype=float).reshape(len(robots), 3)
        self.wheels = np.zeros((len(robots), 2))
        self.dt_s = dt_s
        self.contacts: list = []

    def step(self, cmd_m_s: np.ndarray, cmd_fresh: np.ndarray, faults: FaultArrays, t: float) -> list:
        """One physics step at sim time t [s] (step_robots); returns the new contacts (none)."""
        self.pose, self.wheels = step_robots(self.pose, self.wheels, cmd_m_s, cmd_fresh, faults, self.params, t,
                                             self.dt_s)
        return []

    def steps(self, cmd_m_s: np.ndarray, cmd_fresh: np.ndarray, faults: FaultArrays, t: float, count: int) -> None:
        """``count`` steps from sim time t [s] over which each fault acts alike (none starts or ends): each as step
        does (step_robots), the wheels' targets (the same at every one of those t) worked out once."""
        u, dv = _wheel_targets(cmd_m_s, cmd_fresh, faults, self.params, t, self.dt_s)
        lo = -dv
        pose, wheels, base = self.pose, self.wheels, self.params.wheel_base_m
        for _ in range(count):
            wheels = wheels + _clip(u - wheels, lo, dv)
            pose = integrate_arcs(pose, wheels, self.dt_s, base)
            pose[:, 2] = wrap_angles(pose[:, 2])
        self.pose, self.wheels = pose, wheels
