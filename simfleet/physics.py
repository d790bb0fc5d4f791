"""Pure physics of one simulated robot: commanded -> applied wheel speeds -> exact arc motion.

Per physics step: a command older than its ttl counts as zero; the wheel gains
(the paper's robots "differ in performance") scale the command; a fault
modifies it; the result is clipped to the wheel speed limit and slewed by the
wheel acceleration limit; the pose is integrated exactly over the step.
"""

from __future__ import annotations

from dataclasses import dataclass

from vsfleet.geometry import Pose2
from vsfleet.kinematics import integrate_arc
from vsfleet.scenario import SimRobot


@dataclass(frozen=True)
class Fault:
    """An active fault: kind (none/stop/slow/stall/wheel), factor, and end time [s, sim clock; inf = until cleared]."""

    kind: str = "none"
    factor: float = 1.0
    until_t: float = float("inf")

    def apply(self, vl: float, vr: float, t: float) -> tuple[float, float]:
        if self.kind == "none" or t >= self.until_t:
            return vl, vr
        if self.kind in ("stop", "stall"):
            return 0.0, 0.0
        if self.kind == "slow":
            return vl * self.factor, vr * self.factor
        if self.kind == "wheel":
            return vl * self.factor, vr
        return vl, vr


@dataclass(frozen=True)
class RobotState:
    """Pose [m, rad; world] and applied wheel speeds [m/s]."""

    pose: Pose2
    vl: float = 0.0
    vr: float = 0.0


def _slew(current: float, target: float, max_step: float) -> float:
    return current + max(-max_step, min(max_step, target - current))


def step_robot(state: RobotState, robot: SimRobot, cmd_vl: float, cmd_vr: float, cmd_fresh: bool,
               fault: Fault, t: float, dt_s: float) -> RobotState:
    """Advance one robot by one physics step of ``dt_s`` at sim time ``t``."""
    if not cmd_fresh:
        cmd_vl = cmd_vr = 0.0
    vl, vr = cmd_vl * robot.gain[0], cmd_vr * robot.gain[1]
    vl, vr = fault.apply(vl, vr, t)
    vmax = robot.wheel_speed_max
    vl, vr = max(-vmax, min(vmax, vl)), max(-vmax, min(vmax, vr))
    dv = robot.wheel_accel_max * dt_s
    if fault.kind in ("stop", "stall") and t < fault.until_t:
        dv = float("inf")  # a halted robot halts now (motor cut), not after a ramp
    vl, vr = _slew(state.vl, vl, dv), _slew(state.vr, vr, dv)
    pose = integrate_arc(state.pose, vl, vr, dt_s, robot.wheel_base)
    return RobotState(pose, vl, vr)


def step_fleet(states: dict[str, RobotState], robots: dict[str, SimRobot],
               cmds: dict[str, tuple[float, float]], faults: dict[str, Fault], timeline: list,
               t: float, dt_s: float, substeps: int) -> float:
    """Advance every robot by ``substeps`` physics steps of ``dt_s`` from sim time ``t`` [s],
    starting the timeline's faults (FaultEvent, ordered by at_s) when they are due; returns the
    new time. ``states``, ``faults`` and ``timeline`` are updated in place; commands are fresh."""
    for _ in range(substeps):
        while timeline and timeline[0].at_s <= t:
            ev = timeline.pop(0)
            faults[ev.robot] = Fault(ev.kind, ev.factor, t + ev.duration if ev.duration > 0 else float("inf"))
        for r in robots:
            states[r] = step_robot(states[r], robots[r], *cmds[r], True, faults[r], t, dt_s)
        t += dt_s
    return t
