"""What an agent holds and decides with, without numpy (issue 29): the mission packed for the compiled core, the
agent's state, its step's configuration and outputs, and the small helpers both ways of running a frame share.

vsfleet.agentcore runs frames in the core with these; vsfleet.glue runs them in numpy glue (the reference, and
what the core's agent step does not run); vsfleet.step is the one name every caller uses for both.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field, fields
from dataclasses import field as dataclass_field   # CoreMission has a member named field
from functools import lru_cache
from itertools import chain
from typing import Callable, Mapping

from .advance import Goal, GoalError, GoalPath, GoalPose, GoalTwist, StructureLimits, structure_limits
from .buffers import f64, filled
from .control import DEFAULT_CONTROLLER, PrecisionState, make_controller
from .coreconst import AGENT_RESULT, AGENT_STALL_MOVE_M, AGENT_STALL_S, AGENT_STALL_TURN_RAD, GOAL_PATH, GOAL_POSE, \
    GOAL_TWIST, LIMIT_FIELDS, METRIC_CODES
from .errors import VsfleetValueError
from .failure import FailurePolicy, FailureState, Health
from .field import Field, build_field_deferred
from .geometry import Pose2
from .impl import Impl, choose as choose_impl, core as core_impl
from .safety import SafetyParams
from .structure import FIRST_PLAN_S, MISSION_ARGS, PLAN_MARGIN_M, has_first_plan, room_field
from .wire import CmdMsg, EventMsg, HealthMsg, Mission, StateMsg

#: agent_step's answer, its names' places (vsfleet.coreconst.AGENT_RESULT, py_agent.c)
RESULT_AT = {name: k for k, name in enumerate(AGENT_RESULT)}


def answer(r: tuple, *names: str) -> tuple:
    """The values named so (AGENT_RESULT's names) of agent_step's answer r: a full one, or (resynced,) alone for
    "resynced" (the answer of a frame no robot was usable in)."""
    return tuple(r[RESULT_AT[name]] for name in names)


Controller = Callable  # vsfleet.control: controller(state, ControlInput) -> (state, wheels (n, 2))


# ---------------------------------------------------------------- the mission, for the core


def mission_goal(mission: Mission) -> Goal:
    """The advance goal named by a mission (pose, path or twist)."""
    if mission.goal is not None:
        return GoalPose(Pose2(*mission.goal))
    if mission.path is not None:
        return GoalPath(tuple(Pose2(*w) for w in mission.path))
    assert mission.twist is not None
    return GoalTwist(*mission.twist)


#: reshape: the template's smaller scales, SCALE_STEP apart at most, SCALE_COUNT of them at most (down to scale_min)
SCALE_STEP = 0.1
SCALE_COUNT = 4


def mission_scales(scale_min: float | None) -> tuple[float, ...]:
    """The scales below 1 the template may take, largest first, the last scale_min itself: () for None or 1."""
    if scale_min is None or scale_min >= 1.0:
        return ()
    k = min(SCALE_COUNT, math.ceil((1.0 - scale_min) / SCALE_STEP - 1e-9))
    return tuple(1.0 - (1.0 - scale_min) * j / k for j in range(1, k)) + (scale_min,)


def mission_shape_points(mission: Mission) -> tuple[tuple[str, tuple[tuple[float, float], ...]], ...]:
    """The shapes the structure may take beyond its template, in the order they are tried (docs/planning.md,
    "Shapes"): the template at each of its smaller scales (named "scale 0.8"), then the alternative templates;
    each (name, points ((x, y), ...) [m; structure frame]); () in a mission without obstacles."""
    if not mission.obstacles:
        return ()
    template = [s.p for _, s in mission.robots]
    return (tuple((f"scale {s:g}", tuple((x * s, y * s) for x, y in template))
                  for s in mission_scales(mission.scale_min))
            + tuple((name, tuple(pts)) for name, pts in mission.shapes))


def pack_mission(metric: str, template_xy, wheel_base_m, wheel_speed_max_m_s, wheel_accel_max_m_s2, goal: Goal,
                 limits: StructureLimits, radius_m, obstacles=(), field: Field | None = None, shapes: tuple = (),
                 shape_fields: tuple = ()) -> tuple:
    """The mission's constants as the compiled core takes them (vs_mission in vs_step.h), in structure_step's
    argument order (vsfleet.structure.MISSION_ARGS): float64 buffers of the points (n, 2), the envelopes (n,),
    the goal's poses, the limits (LIMIT_FIELDS' order), the radii, the obstacles (k, 3) and the shapes' points;
    the metric's and the goal kind's codes, the plan's margin, the fields' handles. Any sequences or arrays."""
    if isinstance(goal, GoalPose):
        kind, poses = GOAL_POSE, [goal.pose.as_tuple()]
    elif isinstance(goal, GoalPath):
        if goal.synced:   # the step's own goal on a room's plan (vs_step.c), never a mission's
            raise GoalError("a mission's path turns on its own profile: GoalPath(synced=True) is the step's plan")
        kind, poses = GOAL_PATH, [w.as_tuple() for w in goal.waypoints]
    else:
        kind, poses = GOAL_TWIST, [(goal.vx_m_s, goal.vy_m_s, goal.w_rad_s)]
    packed = {"template_xy": f64(template_xy), "wheel_base_m": f64(wheel_base_m),
              "wheel_speed_max_m_s": f64(wheel_speed_max_m_s), "wheel_accel_max_m_s2": f64(wheel_accel_max_m_s2),
              "metric": METRIC_CODES[metric], "goal_kind": kind, "goal": f64(poses),
              "limits": f64([getattr(limits, f) for f in LIMIT_FIELDS]), "radius_m": f64(radius_m),
              "obstacles": f64(obstacles), "margin_m": PLAN_MARGIN_M,
              "field": None if field is None else field.handle,
              "shapes_xy": f64(chain.from_iterable(f64(p) for _, p in shapes)),
              "shape_fields": tuple(f.handle for f in shape_fields)}
    return tuple(packed[a] for a in MISSION_ARGS)


@dataclass(frozen=True, eq=False)
class CoreMission:
    """What a mission fixes for every frame of the core's step: its robots (sorted id order), the failure policy,
    whether commands go through the safety filter (room: bodies or obstacles) and with bodies, the constants packed
    for the core (pack_mission), and the room's fields (the template's, then each shape's)."""

    ids: tuple[str, ...]
    index: Mapping[str, int]
    goal: Goal
    policy: FailurePolicy
    room: bool
    bodies: bool
    core: tuple
    limits: StructureLimits    # structure_limits for the mission's robot count: the one source of the glue's too
    field: Field | None = None
    shapes: tuple = ()         # ((name, points), ...): mission_shape_points, when the template has a field
    shape_fields: tuple = ()
    # the agent steps built on it (vsfleet.agentcore.agent_kernel), one per robot (its latest controller and
    # timing): they live as long as the mission is held
    kernels: dict = dataclass_field(default_factory=dict, repr=False)


# CoreMissions held: by the mission object (the fast path, one dict lookup a frame) and by its content, so that
# equal missions share one (the agents of an offline run each decode their own copy: 30 or 100 of them used to
# rebuild theirs every frame, past the 16 held). Every CoreMission alive is in _BY_VALUE: both are cleared together,
# so at most MISSIONS_HELD are held (each holds its room's fields, up to 8 MB each, 32 MB once a field has built its
# finer lattice: vsfleet.field.field_refinement).
# The first plans' CoreMissions (first=True) are held alike, and counted among them.
MISSIONS_HELD = 16
_MISSIONS: dict[tuple[int, bool], tuple[Mission, CoreMission]] = {}
_BY_VALUE: dict[tuple[Mission, bool], CoreMission] = {}
_FIRST: dict[int, tuple[Mission, bool]] = {}   # has_first_plan by mission object


def first_plan(mission: Mission) -> bool:
    """Whether a mission's room has a first plan (vsfleet.structure.has_first_plan: its template's and every shape's
    room has a first lattice), memoised by mission object: plain arithmetic on the mission, no field built."""
    hit = _FIRST.get(id(mission))
    if hit is not None and hit[0] is mission:
        return hit[1]
    goal = mission_goal(mission)
    shapes = tuple(p for _, p in mission_shape_points(mission))
    got = has_first_plan([s.p for _, s in mission.robots], mission.radii, mission.obstacles, goal, shapes)
    if len(_FIRST) >= 64 * MISSIONS_HELD:
        _FIRST.clear()
    _FIRST[id(mission)] = (mission, got)
    return got


def in_first_plan(mission: Mission, t: float) -> bool:
    """Whether a frame at time t [s; tracker clock] follows its mission's first plan: the room has one (first_plan)
    and t is less than FIRST_PLAN_S after the mission's effective_t. The same for every agent: a function of the
    mission and the frame."""
    return t - mission.effective_t < FIRST_PLAN_S and first_plan(mission)


def core_mission_of(mission: Mission, first: bool = False) -> CoreMission:
    """A mission's CoreMission, built once per mission (memoised: a pure function of the mission's content, so equal
    missions share one). Building it builds the room's fields (a plan: run_agent does it on a thread of its own when
    the mission arrives). first: its first plan's (the fields of vsfleet.field.first_lattice), for a mission that
    has one (first_plan); the frames of its first FIRST_PLAN_S run on it (in_first_plan)."""
    hit = _MISSIONS.get((id(mission), first))
    if hit is not None and hit[0] is mission:
        return hit[1]
    try:
        cm = _BY_VALUE.get((mission, first))
    except TypeError:   # a mission that cannot be hashed (none can be decoded so): built for this object alone
        cm = None
    if cm is None:
        cm = _build_core_mission(mission, first)
        if len(_BY_VALUE) >= MISSIONS_HELD:
            _BY_VALUE.clear()
            _MISSIONS.clear()
        try:
            _BY_VALUE[(mission, first)] = cm
        except TypeError:
            return cm
    if len(_MISSIONS) >= 64 * MISSIONS_HELD:
        _MISSIONS.clear()
    _MISSIONS[(id(mission), first)] = (mission, cm)
    return cm


def _build_core_mission(mission: Mission, first: bool = False) -> CoreMission:
    ids = mission.robot_ids
    specs = [s for _, s in mission.robots]
    template = [s.p for s in specs]
    radii = mission.radii
    goal = mission_goal(mission)
    limits = structure_limits(mission.speed_max, mission.turn_rate_max, len(mission.robots))
    if first and not first_plan(mission):
        raise VsfleetValueError(f"mission v{mission.version} has no first plan")
    # the core's build, its blocked components resolved when a descent first needs one (vs_field_build_deferred)
    fld = room_field(template, radii, mission.obstacles, goal, build_field_deferred, first)
    shapes = mission_shape_points(mission) if fld is not None else ()
    shape_fields = tuple(room_field(p, radii, mission.obstacles, goal, build_field_deferred, first) for _, p in shapes)
    packed = pack_mission(mission.metric, template, [s.wheel_base for s in specs],
                          [s.wheel_speed_max for s in specs], [s.wheel_accel_max for s in specs], goal, limits,
                          radii, mission.obstacles, fld, shapes, shape_fields)
    bodies = any(r != 0.0 for r in radii)
    return CoreMission(ids=ids, index={r: i for i, r in enumerate(ids)}, goal=goal, policy=mission_policy(mission),
                       room=bodies or len(mission.obstacles) > 0, bodies=bodies, core=packed, limits=limits,
                       field=fld, shapes=shapes, shape_fields=shape_fields)


def mission_policy(mission: Mission) -> FailurePolicy:
    """The mission's failure policy: its on_failure mode and thresholds."""
    return FailurePolicy(mission.on_failure, **dict(mission.failure))


@lru_cache(maxsize=16)
def mission_controller(name: str | None, gains: tuple[tuple[str, float], ...] = ()) -> Controller:
    """The controller a mission names (the default if none), with its gains: one object per kind."""
    return make_controller(name or DEFAULT_CONTROLLER, **dict(gains))


# ---------------------------------------------------------------- the agent's state


class SyncPhase(enum.Enum):
    """Where an agent stands with its peers' failure-policy state."""

    JOINING = "joining"      # (re)started: take the peers' whole failure state (with timers) once
    RESYNCING = "resyncing"  # after a gap in frames: take only which robots are failed or dropped
    SYNCED = "synced"        # decides on its own


@dataclass(frozen=True)
class StepConfig:
    """What the agent process fixes at start: dt_s [s] (the structure's advance per frame), the
    command ttl_s [s], max_stale_s [s] (a frame further behind the local clock is not run),
    resync_gap_s [s] (a longer gap between frames run restarts the failure timers), command_age_s
    [s] (the nominal time from observation to command in effect, which the controller compensates;
    the same for every agent, so predictions agree) and a controller that overrides the mission's
    (offline runs, tests; None = the mission's)."""

    dt_s: float = 1.0 / 30.0
    ttl_s: float = 0.3
    max_stale_s: float = 0.5
    resync_gap_s: float = 1.0
    command_age_s: float | None = None   # None: half a dt_s
    controller: Controller | None = None
    # offline runs only (simfleet.offline): one dict that every agent of the run shares, holding the
    # structures of the newest frames by their inputs; an agent whose inputs equal another's takes
    # that agent's structure instead of computing the same pure function again. None: compute.
    shared_structures: dict | None = field(default=None, compare=False, repr=False)
    # the numpy reference implementations (fit, advance, controller, kinematics, failure rule) instead
    # of the compiled core: the readable reference the core is tested against (tests/test_core_step.py)
    reference: bool = False
    # StepOutput's structure and every robot's wheels, as numpy arrays (tools, tests, benches); the agent process
    # publishes neither and leaves them out (False), so that it never loads numpy
    outputs: bool = True
    # the implementation reference selects (vsfleet.impl), chosen once here: the step calls impl.<name>
    impl: Impl = field(default=core_impl, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "impl", choose_impl(self.reference))

    @property
    def age_s(self) -> float:
        return 0.5 * self.dt_s if self.command_age_s is None else self.command_age_s


@dataclass(frozen=True)
class AgentState:
    """Everything an agent carries from one frame to the next; replaced, never mutated (but see agent_step: the
    arrays of a state the core ran are advanced in place, and the state passed in is consumed).

    For the mission in force (``mission_version``), rows in its sorted id order: wheels_m_s (n, 2)
    every robot's last command [m/s] (its own robot's as sent, the others' as predicted; zero rows
    for robots not commanded), ctrl the controller's state, failure the failure rule's state: buffers
    (vsfleet.buffers; numpy arrays where the numpy glue ran the frame). stale and too_old count the frames this
    agent did not run by its own clock (command_ttl_s).
    health: the failure state in the peers' wire form (kept for health answers and adoption).
    Times [s] are on the tracker's clock.
    """

    robot: str
    phase: SyncPhase = SyncPhase.JOINING
    mission_version: int = -1
    ids: tuple[str, ...] = ()
    health: Health = field(default_factory=Health)
    failure: FailureState | None = None
    wheels_m_s: object = None
    ctrl: object = None
    last_frame_t: float = -math.inf
    last_cmd_t: float = -math.inf
    last_seq: int = 0
    ticks: int = 0
    stale: int = 0
    too_old: int = 0       # frames not run in a room: older than the safety filter's horizon (command_ttl_s)
    unnamed: frozenset[int] = frozenset()  # mission versions that do not name this robot (noted once)
    blocked: bool = False  # the structure has no path to the goal around the obstacles (evented on change)
    # the room's stall watch (vsfleet.step.stall_state): since when [s] the fleet has looked stuck and from which
    # structure pose, and whether it is taken as stuck (evented as blocked / unblocked with the plan's own)
    stall_since_t: float = math.nan
    stall_pose: tuple | None = None   # (x, y, th [m, rad; world] where the watch began, filter seen since)
    stalled: bool = False
    shape: int = 0   # reshape: the shape the structure took at the last frame (0: the template; noted on change)

    @property
    def predicted_m_s(self) -> dict[str, tuple[float, float]]:
        """Every commanded robot's last command (vl, vr) [m/s], by id."""
        if self.wheels_m_s is None:
            return {}
        rows = memoryview(self.wheels_m_s).tolist()
        return {r: (float(w[0]), float(w[1])) for r, w in zip(self.ids, rows) if w[0] or w[1]}

    @property
    def wheels_prev_m_s(self) -> tuple[float, float]:
        """Its own robot's last command (vl, vr) [m/s]."""
        if self.wheels_m_s is None or self.robot not in self.ids:
            return (0.0, 0.0)
        w = memoryview(self.wheels_m_s).tolist()[self.ids.index(self.robot)]
        return (float(w[0]), float(w[1]))


@dataclass(frozen=True)
class Note:
    """A line for the agent's log: level is "info" or "warning"."""

    level: str
    text: str


@dataclass(frozen=True)
class StepOutput:
    """What the agent publishes and logs for one frame (None / empty: nothing).

    structure and wheels_m_s (n, 2): the frame's structure and every robot's command (own row sent,
    others predicted), for offline runs, benches and tests (StepConfig.outputs; numpy arrays).
    """

    cmd: CmdMsg | None = None
    state: StateMsg | None = None        # its ``rejected`` count is the process's to fill in
    health: HealthMsg | None = None      # the answer to peers' health queries from now on
    events: tuple[EventMsg, ...] = ()
    notes: tuple[Note, ...] = ()
    structure: object = None             # vsfleet.structure.Structure
    wheels_m_s: object = None


def failure_initial(n: int, policy: FailurePolicy, step_s: float) -> FailureState:
    """The failure rule's state for n robots, as buffers: all healthy, nothing seen; the motion window holds
    fail_after_s of frames at step_s [s] (+ margin): vsfleet.failure.FailureState.initial, without numpy."""
    if not (math.isfinite(step_s) and step_s > 0.0):
        raise VsfleetValueError(f"step_s must be finite and > 0, got {step_s!r}")
    w = int(math.ceil(policy.fail_after_s / step_s)) + 4
    nan = math.nan
    return FailureState(filled("d", (n,), nan), filled("?", (n,)), filled("?", (n,)), filled("d", (n,), nan),
                        filled("d", (n, 2)), filled("d", (n, 2)), filled("d", (n, w), nan), filled("q", (n, w, 4)),
                        filled("q", (n,)), filled("?", (n, w)), filled("q", (n, 4)), filled("d", (n, w)))


def failure_with_health(state: FailureState, health: Health, robots, timers: bool = True) -> FailureState:
    """The state with a peer's health (dict form, as on the wire) adopted: failed, dropped and, with ``timers``,
    since_t (new buffers; the motion window kept). Robots not in ``robots`` are ignored (vsfleet.failure.with_health)."""
    n = len(robots)
    failed, dropped = filled("?", (n,)), filled("?", (n,))
    since = filled("d", (n,), math.nan) if timers else state.since_t
    for i, r in enumerate(robots):
        failed[i] = r in health.failed
        dropped[i] = r in health.dropped
        if timers:
            since[i] = health.since_t.get(r, math.nan)
    return FailureState(since, failed, dropped, state.last_t, state.last_xy, state.last_expected, state.window_t,
                        state.window_nm, state.head, state.in_window, state.sums_nm, state.window_dev_m)


#: the state's arrays in vs_agent_step's order (py_agent.c, get_state): Precision's, then the failure rule's
PRECISION_STATE_FIELDS = tuple(f.name for f in fields(PrecisionState))
FAILURE_FIELDS = tuple(f.name for f in fields(FailureState))

_HEALTHY = Health()


def health_of(failure: FailureState, ids: tuple[str, ...]) -> Health:
    """The failure state in the peers' wire form (vsfleet.failure.to_health) from buffers or arrays alike."""
    failed, dropped = memoryview(failure.failed).tobytes(), memoryview(failure.dropped).tobytes()
    since = memoryview(failure.since_t).tolist()
    n = len(ids)
    if failed.count(0) == n and dropped.count(0) == n and all(t != t for t in since):
        return _HEALTHY  # every robot healthy and compliant: the common case
    return Health(since_t={ids[i]: float(t) for i, t in enumerate(since) if t == t},
                  failed=frozenset(ids[i] for i, f in enumerate(failed) if f),
                  dropped=frozenset(ids[i] for i, d in enumerate(dropped) if d))


@lru_cache(maxsize=8)
def safety_params(dt_s: float) -> SafetyParams:
    return SafetyParams(dt_s=dt_s)



#: the stall watch (vsfleet.step.stall_state; vs_agent_step's): stuck after STALL_S [s] of the safety filter
#: changing commands while the structure stays within STALL_MOVE_M [m] and STALL_TURN_RAD [rad] of where the
#: watch began
STALL_S = AGENT_STALL_S
STALL_MOVE_M = AGENT_STALL_MOVE_M
STALL_TURN_RAD = AGENT_STALL_TURN_RAD


def blocked_why(now: bool, blocked: bool) -> str:
    """A blocked event's why (vsfleet.wire.BLOCKED_WHY; "" for unblocked): no_path when the plan itself has no way
    to the goal (blocked), stuck when the stall watch holds a structure whose plan goes on."""
    return ("no_path" if blocked else "stuck") if now else ""


def blocked_note(seq: int, blocked: bool, now: bool, short: float) -> Note:
    """The log line of the room's verdict changing (blocked: the plan's; now: blocked or stuck, else going on)."""
    if not now:
        return Note("info", f"frame {seq}: the structure is on its way to the goal again")
    if blocked:
        return Note("warning", f"frame {seq}: no path to the goal around the obstacles: the structure "
                               f"stops at the closest safe pose, {short:.3f} m short")
    return Note("warning", f"frame {seq}: stuck on the way, {short:.3f} m short: for {STALL_S:.0f} s "
                           "the safety filter has held robots back and the structure has not moved (a "
                           "passage tighter than the plan allowed for)")


def shape_name(mission_consts, shape: int) -> str:
    """A shape's name for a log line: "the template", or the mission's reshape by name ("scale 0.8", "column").
    mission_consts: a CoreMission or vsfleet.step.MissionArrays (their ``shapes``: (name, points) each)."""
    return "the template" if shape == 0 else f"shape {shape} ({mission_consts.shapes[shape - 1][0]})"


def used_ids(ids: tuple[str, ...], used) -> tuple[str, ...]:
    """The ids of the rows used (all of them, usually: no loop then); used: a bool buffer or array (n,)."""
    flags = memoryview(used).tobytes()
    return ids if flags.count(0) == 0 else tuple(ids[i] for i, u in enumerate(flags) if u)


def _evolve(state: AgentState, **changes) -> AgentState:
    """dataclasses.replace for the per-frame path: the same new frozen AgentState, without re-running
    __init__ over every field (AgentState has no __post_init__ and no validation to skip)."""
    new = object.__new__(AgentState)
    new.__dict__.update(state.__dict__)
    new.__dict__.update(changes)
    return new
