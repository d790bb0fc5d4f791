"""simfleet's physics engines behind one interface: the kinematic one (default) and MuJoCo (optional).

An engine is built from the scenario's robots (vsfleet.scenario.SimRobot, in the fleet's row order), the
mission's obstacles [(x, y, r)] and the physics step dt_s [s]. It holds every robot's pose ``pose`` (n, 3)
[m, m, rad; world, heading wrapped] and wheel speeds ``wheels`` (n, 2) [m/s, ground speed of each wheel's
rim], and ``step(cmd_m_s, cmd_fresh, faults, t)`` advances them by one step at sim time t [s] from the
commanded wheel speeds (n, 2), whether each command is within its ttl (n,) and the faults
(physics.FaultArrays). The actuators follow physics.applied_wheels in both (gains, faults, speed and
acceleration limits; a stale command brakes to rest). ``step`` returns the contacts that began in that
step (Contact), and ``contacts`` keeps them all.

- ``kinematic`` (physics.KinematicEngine): exact unicycle arcs; bodies pass through each other and
  through obstacles, so it never reports a contact.
- ``mujoco`` (engine_mujoco.MujocoEngine): each robot a rigid differential-drive body on a floor, with
  mass, wheels driven by velocity servos, friction and casters; obstacles are static cylinders, and
  bodies stop at each other and at obstacles (docs/engine.md). Needs ``pip install 'vsfleet[mujoco]'``.
"""

from __future__ import annotations

from vsfleet.errors import VsfleetValueError
from vsfleet.scenario import ENGINES

from .physics import Contact, KinematicEngine, step_engine_fleet  # noqa: F401 (re-exported)

__all__ = ["ENGINES", "Contact", "EngineUnavailable", "check_engine", "make_engine", "step_engine_fleet"]


class EngineUnavailable(VsfleetValueError):
    """An engine whose package is not installed (mujoco: the optional extra vsfleet[mujoco])."""


def check_engine(name: str) -> None:
    """EngineUnavailable if engine ``name``'s package is not installed; VsfleetValueError if no such engine."""
    if name not in ENGINES:
        raise VsfleetValueError(f"engine must be one of {ENGINES}, got {name!r}")
    if name == "mujoco":
        try:
            import mujoco  # noqa: F401
        except ImportError as exc:
            raise EngineUnavailable(f"the mujoco engine needs MuJoCo: pip install 'vsfleet[mujoco]' ({exc})") \
                from None


def make_engine(name: str, robots, obstacles, dt_s: float):
    """The engine ``name`` (one of ENGINES) for ``robots`` (SimRobot, rows in this order) among
    ``obstacles`` [(x, y, r)] at physics step dt_s [s]; EngineUnavailable if its package is missing."""
    if name == "kinematic":
        return KinematicEngine(robots, obstacles, dt_s)
    check_engine(name)
    from .engine_mujoco import MujocoEngine
    return MujocoEngine(robots, obstacles, dt_s)


