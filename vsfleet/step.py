"""The agent's decision at one frame, as one pure function: ``agent_step``.

``agent_step(state, mission, frame, now_s, config) -> (state, StepOutput)`` is
everything an agent decides per frame: the frame's age (a stale frame is not
run), gaps and resynchronisation, the fit and the advance, its own command and
every robot's predicted command, and the failure rule. The agent process
(agent/main.py), the offline fleet (simfleet.offline), the benches and the
tests drive this same function.

Robots are rows of numpy arrays in the mission's sorted id order; a robot's id
turns into its row once, when the frame's poses are read (``frame_arrays``).
The structure part (``structure_step``) depends only on (mission, frame, the
robots dropped), so duplicated agents that saw the same frames compute
bit-identical structure poses: the paper's "distributed duplication". The
controller runs on every robot at once, so the predicted commands the failure
rule judges by are the very commands each robot's own agent sends.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field, fields, replace
from functools import cached_property, lru_cache
from itertools import chain, repeat
from typing import Callable, Mapping

import numpy as np

from .advance import Goal, GoalPath, GoalPose, GoalTwist, StructureLimits
from . import _core
from .assembly import assembly_targets, assembly_targets_reference  # noqa: F401 (re-exported: the step's names)
from .coreconst import (AGENT_CONTROLLERS, AGENT_SCRATCH_F64_PER_ROBOT, AGENT_SCRATCH_U8_PER_ROBOT, AGENT_STALL_MOVE_M,
                        AGENT_STALL_S, AGENT_STALL_TURN_RAD, DECISION_KINDS, FAILURE_MODES, GOAL_PATH, GOAL_POSE,
                        GOAL_TWIST, LIMIT_FIELDS, METRIC_CODES)
from .control import (DEFAULT_CONTROLLER, Arc, ControlInput, Held, Precision, PrecisionState, Tracking, TurnThenGo,
                      make_controller)
from .envelope import Envelope, Envelopes
from .failure import Decision, FailurePolicy, FailureState, Health, restart_timers, with_health
from .frames import Frame
from .geometry import Pose2, angle_diff
from .field import Field, build_field, follow_field
from .impl import Impl, choose as choose_impl, core as core_impl
from .safety import SafetyParams
from .structure import MISSION_ARGS, PLAN_MARGIN_M, Structure, make_structure, room_field  # noqa: F401 (re-exported)
from .wire import CmdMsg, EventMsg, HealthMsg, Mission, StateMsg

Controller = Callable  # vsfleet.control: controller(state, ControlInput) -> (state, wheels (n, 2))


def mission_goal(mission: Mission) -> Goal:
    """The advance goal named by a mission (pose, path or twist)."""
    if mission.goal is not None:
        return GoalPose(Pose2(*mission.goal))
    if mission.path is not None:
        return GoalPath(tuple(Pose2(*w) for w in mission.path))
    assert mission.twist is not None
    return GoalTwist(*mission.twist)


def mission_envelopes(mission: Mission) -> list[Envelope]:
    return [Envelope(s.wheel_base, s.wheel_speed_max, s.wheel_accel_max) for _, s in mission.robots]


def mission_envelope_arrays(mission: Mission) -> Envelopes:
    """The mission's envelopes as (n,) arrays, in its sorted robot order."""
    return Envelopes.of(mission_envelopes(mission))


def mission_template(mission: Mission) -> np.ndarray:
    """Template points (n, 2) [m; structure frame], in the mission's sorted robot order."""
    return np.array([s.p for _, s in mission.robots], dtype=float)


#: reshape: the template's smaller scales, SCALE_STEP apart at most, SCALE_COUNT of them at most (down to scale_min)
SCALE_STEP = 0.1
SCALE_COUNT = 4


def mission_scales(scale_min: float | None) -> tuple[float, ...]:
    """The scales below 1 the template may take, largest first, the last scale_min itself: () for None or 1."""
    if scale_min is None or scale_min >= 1.0:
        return ()
    k = min(SCALE_COUNT, math.ceil((1.0 - scale_min) / SCALE_STEP - 1e-9))
    return tuple(1.0 - (1.0 - scale_min) * j / k for j in range(1, k)) + (scale_min,)


def mission_shapes(mission: Mission) -> tuple[tuple[str, np.ndarray], ...]:
    """The shapes the structure may take beyond its template, in the order they are tried (docs/planning.md,
    "Shapes"): the template at each of its smaller scales (named "scale 0.8"), then the alternative templates;
    each (name, points (n, 2) [m; structure frame]); () in a mission without obstacles."""
    if not mission.obstacles:
        return ()
    template = mission_template(mission)
    return (tuple((f"scale {s:g}", template * s) for s in mission_scales(mission.scale_min))
            + tuple((name, np.array(pts, dtype=float)) for name, pts in mission.shapes))


@dataclass(frozen=True)
class MissionArrays:
    """What a mission fixes for every frame, as arrays over its robots (sorted id order)."""

    ids: tuple[str, ...]
    index: Mapping[str, int]
    template: np.ndarray          # (n, 2) [m; structure frame]
    envelopes: Envelopes
    goal: Goal
    limits: StructureLimits
    policy: FailurePolicy          # the failure rule's mode and thresholds
    radii: np.ndarray = field(default_factory=lambda: np.zeros(0))      # (n,) body radii [m] (0: a point)
    obstacles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (k, 3) (x, y, r) [m; world]
    core: tuple = ()
    field: Field | None = None     # the room's navigation function (vsfleet.field), built once per mission
    # reshape: the shapes beyond the template, in the order tried ((name, points (n, 2)), mission_shapes), and
    # each one's field (built once per mission; none without the template's field)
    shapes: tuple = ()
    shape_fields: tuple = ()

    @cached_property
    def room(self) -> bool:
        """The mission knows robot bodies or obstacles: commands go through the safety filter (once per mission)."""
        return bool(self.radii.any()) or len(self.obstacles) > 0               # the same, packed for vsfleet._core.structure_step (core_mission)


def core_mission(metric: str, template: np.ndarray, envelopes: Envelopes, goal: Goal,
                 limits: StructureLimits, radii=None, obstacles=(), field: Field | None = None,
                 shapes: tuple = (), shape_fields: tuple = ()) -> tuple:
    """The mission's constants as the compiled core takes them (vs_mission in vs_step.h), in structure_step's
    argument order (vsfleet.structure.MISSION_ARGS: those before the frame's, then those after them)."""
    if isinstance(goal, GoalPose):
        kind, poses = GOAL_POSE, [goal.pose.as_tuple()]
    elif isinstance(goal, GoalPath):
        kind, poses = GOAL_PATH, [w.as_tuple() for w in goal.waypoints]
    else:
        kind, poses = GOAL_TWIST, [(goal.vx_m_s, goal.vy_m_s, goal.w_rad_s)]
    packed = {"template_xy": np.ascontiguousarray(template, dtype=float),
              "wheel_base_m": np.ascontiguousarray(envelopes.wheel_base_m),
              "wheel_speed_max_m_s": np.ascontiguousarray(envelopes.wheel_speed_max_m_s),
              "wheel_accel_max_m_s2": np.ascontiguousarray(envelopes.wheel_accel_max_m_s2),
              "metric": METRIC_CODES[metric], "goal_kind": kind, "goal": np.array(poses, dtype=float).ravel(),
              "limits": np.array([getattr(limits, f) for f in LIMIT_FIELDS], dtype=float),
              "radius_m": np.zeros(len(template)) if radii is None else np.array(radii, dtype=float),
              "obstacles": np.array(obstacles, dtype=float).reshape(-1), "margin_m": PLAN_MARGIN_M,
              "field": None if field is None else field.handle,
              "shapes_xy": np.ascontiguousarray(np.array([p for _, p in shapes], dtype=float).reshape(-1)),
              "shape_fields": tuple(f.handle for f in shape_fields)}
    return tuple(packed[a] for a in MISSION_ARGS)   # in the core's order (vsfleet.structure.MISSION_ARGS)


_ARRAYS: dict[int, tuple[Mission, MissionArrays]] = {}


def mission_arrays(mission: Mission) -> MissionArrays:
    """The arrays of a mission, built once per mission object (memoised: a pure function)."""
    hit = _ARRAYS.get(id(mission))
    if hit is not None and hit[0] is mission:
        return hit[1]
    ids = mission.robot_ids
    template, envelopes, goal = mission_template(mission), mission_envelope_arrays(mission), mission_goal(mission)
    limits = StructureLimits(speed_max_m_s=mission.speed_max, turn_rate_max_rad_s=mission.turn_rate_max)
    obstacles = np.array(mission.obstacles, dtype=float).reshape(-1, 3)
    field = room_field(template, mission.radii, obstacles, goal, build_field)   # the core's build
    shapes = mission_shapes(mission) if field is not None else ()
    shape_fields = tuple(room_field(p, mission.radii, obstacles, goal, build_field) for _, p in shapes)
    arrays = MissionArrays(ids=ids, index={r: i for i, r in enumerate(ids)}, template=template,
                           envelopes=envelopes, goal=goal, limits=limits, policy=mission_policy(mission),
                           radii=np.array(mission.radii, dtype=float), obstacles=obstacles,
                           core=core_mission(mission.metric, template, envelopes, goal, limits, mission.radii,
                                             mission.obstacles, field, shapes, shape_fields), field=field,
                           shapes=shapes, shape_fields=shape_fields)
    if len(_ARRAYS) >= 16:
        _ARRAYS.clear()
    _ARRAYS[id(mission)] = (mission, arrays)
    return arrays


_UNSEEN = (math.nan, math.nan, math.nan)


def frame_arrays(ids: tuple[str, ...], poses: Mapping[str, tuple[float, float, float]],
                 fresh: frozenset[str] = frozenset()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pose_world (n, 3) [m, m, rad], seen (n,), fresh (n,)) of a frame's poses; NaN rows unseen."""
    n = len(ids)
    pose = np.fromiter(chain.from_iterable(map(poses.get, ids, repeat(_UNSEEN))), dtype=float, count=3 * n)
    pose = pose.reshape(n, 3)
    seen = ~np.isnan(pose[:, 0])
    if fresh.issuperset(ids):   # every robot listed by the frame itself: the common case
        return pose, seen, seen.copy()
    return pose, seen, seen & np.fromiter(map(fresh.__contains__, ids), dtype=bool, count=n)


def structure_step(arrays: MissionArrays, metric: str, pose_world: np.ndarray, seen: np.ndarray,
                   excluded: np.ndarray, judged_apart: np.ndarray, elapsed_s: float, dt_s: float,
                   impl: Impl = core_impl) -> Structure | None:
    """Fit the structure to the robots seen and not excluded, advance it one dt_s toward the goal, in the
    implementation ``impl`` (vsfleet.impl: the compiled core, or the numpy reference for tests).

    Robots absent or excluded are left out of the fit but still bound the advance. The
    deviations are measured on the structure fitted without the ``judged_apart`` robots (when two
    or more others remain): under hold a failed robot bends the structure the robots follow, and
    the healthy robots it bends must not look non-compliant for it. None if no robot is usable.
    """
    return impl.structure_step(arrays, metric, pose_world, seen, excluded, judged_apart, elapsed_s, dt_s)

def planned_way(mission: Mission, pose: Pose2, cap: int = 100_000,
                shape: int = 0) -> tuple[np.ndarray, bool] | None:
    """The whole way the room's field gives from a structure pose [m, rad; world] to the goal (or the closest
    safe pose: blocked True), as (k, 3) poses; None without a field (no obstacles, or a twist goal). For tools
    that draw the plan (vsfleet plot, the Foxglove scene); agents follow 2 m of it a frame. shape: the
    structure's (a state's ``shape``: 0 the template, k the mission's k-th reshape), whose field it follows."""
    arrays = mission_arrays(mission)
    field = arrays.field
    if 0 < shape <= len(arrays.shape_fields):
        field = arrays.shape_fields[shape - 1]
    if field is None:
        return None
    way, blocked, _left = follow_field(field, pose, path_m=1e9, cap=cap)
    return way, blocked


def _shared_structure_step(shared: dict | None, mission: Mission, arrays: MissionArrays, pose_world: np.ndarray,
                           seen: np.ndarray, excluded: np.ndarray, judged_apart: np.ndarray, elapsed_s: float,
                           dt_s: float, impl: Impl = core_impl) -> Structure | None:
    """structure_step, taken from ``shared`` when another agent of an offline run computed it on the
    very same inputs (an equal mission, whose arrays these are, and the arrays' bytes, NaN rows of
    unseen robots included); its arrays are then read-only, as they are shared."""
    metric = mission.metric
    if shared is None:
        return structure_step(arrays, metric, pose_world, seen, excluded, judged_apart, elapsed_s, dt_s, impl)
    key = (mission, pose_world.tobytes(), seen.tobytes(), excluded.tobytes(), judged_apart.tobytes(),
           elapsed_s, dt_s, impl.name)
    if key in shared:
        return shared[key]
    s = structure_step(arrays, metric, pose_world, seen, excluded, judged_apart, elapsed_s, dt_s, impl)
    if s is not None:
        for a in (s.used, s.points_now, s.points_next, s.deviations_m):
            a.flags.writeable = False
    if len(shared) >= 64:  # the newest frames only: agents of one run step the same frame in turn
        shared.clear()
    shared[key] = s
    return s


def expected_steps_m(pose_world: np.ndarray, wheels_m_s: np.ndarray, dt_s: float,
                     wheel_base_m: np.ndarray, impl: Impl = core_impl) -> np.ndarray:
    """Displacement (n, 2) [m; world] each robot makes in dt_s at its command (paper eqs 17-18)."""
    return impl.integrate_arcs(pose_world, wheels_m_s, dt_s, wheel_base_m)[:, :2] - pose_world[:, :2]


# ---------------------------------------------------------------- the agent step


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
    # the implementation reference selects (vsfleet.impl), chosen once here: the step calls impl.<name>
    impl: Impl = field(default=core_impl, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "impl", choose_impl(self.reference))

    @property
    def age_s(self) -> float:
        return 0.5 * self.dt_s if self.command_age_s is None else self.command_age_s


@dataclass(frozen=True)
class AgentState:
    """Everything an agent carries from one frame to the next; replaced, never mutated.

    For the mission in force (``mission_version``), rows in its sorted id order: wheels_m_s (n, 2)
    every robot's last command [m/s] (its own robot's as sent, the others' as predicted; zero rows
    for robots not commanded), ctrl the controller's state, failure the failure rule's state. stale and
    too_old count the frames this agent did not run by its own clock (command_ttl_s).
    health: the failure state in the peers' wire form (kept for health answers and adoption).
    Times [s] are on the tracker's clock.
    """

    robot: str
    phase: SyncPhase = SyncPhase.JOINING
    mission_version: int = -1
    ids: tuple[str, ...] = ()
    health: Health = field(default_factory=Health)
    failure: FailureState | None = None
    wheels_m_s: np.ndarray | None = None
    ctrl: object = None
    last_frame_t: float = -math.inf
    last_cmd_t: float = -math.inf
    last_seq: int = 0
    ticks: int = 0
    stale: int = 0
    too_old: int = 0       # frames not run in a room: older than the safety filter's horizon (command_ttl_s)
    unnamed: frozenset[int] = frozenset()  # mission versions that do not name this robot (noted once)
    blocked: bool = False  # the structure has no path to the goal around the obstacles (evented on change)
    # the room's stall watch (stall_state): since when [s] the fleet has looked stuck and from which structure
    # pose, and whether it is taken as stuck (evented as blocked / unblocked with the plan's own)
    stall_since_t: float = math.nan
    stall_pose: tuple | None = None   # (x, y, th [m, rad; world] where the watch began, filter seen since)
    stalled: bool = False
    shape: int = 0   # reshape: the shape the structure took at the last frame (0: the template; noted on change)

    @property
    def predicted_m_s(self) -> dict[str, tuple[float, float]]:
        """Every commanded robot's last command (vl, vr) [m/s], by id."""
        if self.wheels_m_s is None:
            return {}
        return {r: (float(w[0]), float(w[1])) for r, w in zip(self.ids, self.wheels_m_s) if w[0] or w[1]}

    @property
    def wheels_prev_m_s(self) -> tuple[float, float]:
        """Its own robot's last command (vl, vr) [m/s]."""
        if self.wheels_m_s is None or self.robot not in self.ids:
            return (0.0, 0.0)
        w = self.wheels_m_s[self.ids.index(self.robot)]
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
    others predicted), for offline runs, benches and tests.
    """

    cmd: CmdMsg | None = None
    state: StateMsg | None = None        # its ``rejected`` count is the process's to fill in
    health: HealthMsg | None = None      # the answer to peers' health queries from now on
    events: tuple[EventMsg, ...] = ()
    notes: tuple[Note, ...] = ()
    structure: Structure | None = None
    wheels_m_s: np.ndarray | None = None


@lru_cache(maxsize=16)
def mission_controller(name: str | None, gains: tuple[tuple[str, float], ...] = ()) -> Controller:
    """The controller a mission names (the default if none), with its gains: one object per kind."""
    return make_controller(name or DEFAULT_CONTROLLER, **dict(gains))


def mission_policy(mission: Mission) -> FailurePolicy:
    """The mission's failure policy: its on_failure mode and thresholds."""
    return FailurePolicy(mission.on_failure, **dict(mission.failure))


def _enter_mission(state: AgentState, mission: Mission, policy: FailurePolicy, config: StepConfig) -> AgentState:
    """The state re-rowed for a new mission: decisions and timers carried by robot id, motion and
    commands afresh (the controller restarts)."""
    ids = mission.robot_ids
    health = _health(state.failure, state.ids) if state.failure is not None else state.health
    health = Health(since_t={r: t for r, t in health.since_t.items() if r in ids},
                    failed=frozenset(r for r in health.failed if r in ids),
                    dropped=frozenset(r for r in health.dropped if r in ids))
    failure = with_health(FailureState.initial(len(ids), policy, config.dt_s), health, ids)
    return replace(state, mission_version=mission.version, ids=ids, health=health, failure=failure,
                   wheels_m_s=np.zeros((len(ids), 2)), ctrl=None, stall_since_t=math.nan, stall_pose=None)


def command_ttl_s(room: bool, frame_t: float, now_s: float, config: StepConfig) -> float:
    """The ttl [s] of the command answering a frame taken at frame_t [s, tracker clock] and sent at now_s [s, this
    host's clock]: config.ttl_s, cut in a room (the safety filter runs) where the filter's guarantee for that
    command ends, 1 / gamma_per_s after the poses were taken (docs/safety.md, "Stale poses and held commands").
    <= 0: the frame is too old to move on; the agent does not run it. The core's vs_agent_command_ttl."""
    if not room:
        return config.ttl_s
    return min(config.ttl_s, frame_t + 1.0 / _safety_params(config.dt_s).gamma_per_s - now_s)


def agent_step(state: AgentState, mission: Mission | None, frame: Frame, now_s: float,
               config: StepConfig = StepConfig()) -> tuple[AgentState, StepOutput]:
    """Decide one frame at local clock reading now_s [s]; see the module docstring.

    mission is the one active at frame.t (vsfleet.frames.MissionBook.active), None if none is.
    In a room the command's ttl ends where the safety filter's guarantee for it ends (command_ttl_s), and a frame
    older than that is not run, as a stale frame: no command answers it, and the robot halts when the last one
    runs out. It is counted (too_old) and logged.
    """
    if mission is None or state.robot not in mission.robot_ids or frame.t < now_s - config.max_stale_s:
        return _decide(state, mission, frame, now_s, config)
    ttl = command_ttl_s(mission_arrays(mission).room, frame.t, now_s, config)
    if not ttl > 0.0:
        n = state.too_old + 1
        note = Note("warning", f"frame {frame.seq} skipped, too old to move on: {now_s - frame.t:.3f} s behind this "
                               f"host's clock, more than the safety filter's horizon of "
                               f"{1.0 / _safety_params(config.dt_s).gamma_per_s:.2f} s (#{n}; a loaded host, a "
                               "stalled link or clock skew); the robot halts")
        return replace(state, too_old=n), StepOutput(notes=(note,) if n <= 10 or n % 100 == 0 else ())
    state, out = _decide(state, mission, frame, now_s, config)
    if out.cmd is not None and out.cmd.ttl != ttl:
        out = replace(out, cmd=replace(out.cmd, ttl=ttl))
    return state, out


def _decide(state: AgentState, mission: Mission | None, frame: Frame, now_s: float,
            config: StepConfig) -> tuple[AgentState, StepOutput]:
    """agent_step before the command's ttl."""
    notes: list[Note] = []
    if frame.t < now_s - config.max_stale_s:
        n = state.stale + 1
        if n <= 10 or n % 100 == 0:
            notes.append(Note("warning", f"stale frame #{n} skipped: tracker time {now_s - frame.t:.2f} s behind "
                                         f"this host's clock (more than {config.max_stale_s:.2f} s: clock skew "
                                         "or a stalled link); the robot halts"))
        return replace(state, stale=n), StepOutput(notes=tuple(notes))
    if mission is None:
        return state, StepOutput()
    if state.robot not in mission.robot_ids:
        if mission.version in state.unnamed:
            return state, StepOutput()
        return (replace(state, unnamed=state.unnamed | {mission.version}),
                StepOutput(notes=(Note("warning", f"mission v{mission.version} does not name robot "
                                                  f"{state.robot}: it stays stopped"),)))
    arrays = mission_arrays(mission)
    policy = arrays.policy
    controller = config.controller or mission_controller(mission.controller,
                                                         mission.controller_gains)
    if mission.version != state.mission_version:
        notes.append(Note("info", f"frame {frame.seq}: switching to mission v{mission.version}"))
        state = _enter_mission(state, mission, policy, config)
    n = len(arrays.ids)
    if config.impl is core_impl and config.shared_structures is None:
        kernel = _agent_kernel(arrays, mission, state.robot, controller, config)
        if kernel is not None:   # the rest of the frame in one call into the core (vs_agent_step)
            return _frame_in_core(kernel, state, mission, arrays, controller, frame, config, notes)
    wheels_prev, ctrl = state.wheels_m_s, state.ctrl
    if frame.t - state.last_cmd_t > config.ttl_s or ctrl is None:
        # a gap longer than ttl: every robot has halted since the last commands
        wheels_prev, ctrl = np.zeros((n, 2)), controller.initial(n)
    failure = state.failure
    if frame.t - state.last_frame_t > config.resync_gap_s and state.last_frame_t > -math.inf:
        # this agent (or the whole fleet) saw no frame for a while: restart the failure timers and
        # the motion window, and ask the peers which robots they failed or dropped
        notes.append(Note("warning", f"frame {frame.seq}: no frame for {frame.t - state.last_frame_t:.2f} s; "
                                     "restarting failure timers and asking peers for their failure state"))
        failure = restart_timers(failure)
        state = replace(state, phase=SyncPhase.RESYNCING)
    state = _evolve(state, last_frame_t=frame.t, failure=failure)

    pose, seen, fresh = frame_arrays(arrays.ids, frame.poses, frame.fresh)
    own = arrays.index[state.robot]
    hold = policy.mode == "hold"
    judged_apart = failure.failed & ~failure.dropped if hold else np.zeros(n, dtype=bool)
    s = _shared_structure_step(config.shared_structures, mission, arrays, pose, seen, failure.dropped,
                               judged_apart, frame.t - mission.effective_t, config.dt_s, config.impl)
    if s is None:
        return state, StepOutput(notes=tuple(notes))
    # every robot's command, as its own agent computes it: seen, and not dropped (rejoin: driven on)
    active = seen & (~failure.dropped if policy.mode != "rejoin" else True)
    pose_seen = np.where(seen[:, None], pose, 0.0)   # unseen rows zeroed: the controller, kinematics, failure rule
    points_now, points_next, detoured = s.points_now, s.points_next, None
    if arrays.radii.any():   # bodies: the assembly tie-break (robots barred on their way go round)
        points_now, points_next, detoured = config.impl.assembly_targets(
            arrays.radii, pose_seen, seen & active, s.points_now, s.points_next, _safety_params(config.dt_s).margin_m)
    ctrl, wheels = config.impl.control(controller, ctrl, ControlInput(
        pose_world=pose_seen, point_now_world=points_now,
        point_next_world=points_next, wheels_prev_m_s=wheels_prev, dt_s=config.dt_s, age_s=config.age_s,
        envelopes=arrays.envelopes, active=active))
    wheels = np.where(active[:, None], wheels, 0.0)
    filtered = False
    held = None      # the robots whose command the safety filter cut: on their way (the failure rule)
    if arrays.room:  # bodies or obstacles: every robot's command through the fleet-wide safety filter
        nominal = wheels
        wheels = _safe_wheels(arrays, pose, seen, active, wheels, wheels_prev, config)
        held = np.any(wheels != nominal, axis=1)
        filtered = bool(np.any(held))
        if detoured is not None:
            held = held | detoured                   # sent round another robot: on its way too
    vl, vr = float(wheels[own, 0]), float(wheels[own, 1])
    cmd = CmdMsg(t=frame.t, seq=frame.seq, vl=vl, vr=vr, ttl=config.ttl_s)
    state_msg = None
    if seen[own]:
        f, g = s.fit_pose, s.goal_pose
        err = _norm(float(pose[own, 0] - s.points_now[own, 0]), float(pose[own, 1] - s.points_now[own, 1]))
        state_msg = StateMsg(t=frame.t, seq=frame.seq, x=f.x, y=f.y, th=f.th, gx=g.x, gy=g.y, gth=g.th,
                             cost=s.cost, err=err, used=_used_ids(arrays.ids, s.used),
                             rejected=0, complete=frame.complete, mission=mission.version, shape=s.shape)
    # the motion test takes only poses of this very frame: a pose held over from an earlier frame
    # would count as "did not move" here and double next frame, and agents that got that pose in
    # time would disagree on the frame of a decision
    moved = fresh & active
    expected = np.where(moved[:, None], expected_steps_m(pose_seen, wheels, config.dt_s,
                                                         arrays.envelopes.wheel_base_m, config.impl), 0.0)
    failure, decisions = config.impl.failure_step(policy, failure, arrays.ids, frame.t, seen=seen, fresh=fresh,
                                                  xy_world=pose_seen[:, :2],
                                                  deviations_m=s.deviations_m, expected_step_m=expected,
                                                  step_s=config.dt_s, max_gap_s=config.ttl_s, held=held)
    health = _health(failure, arrays.ids)
    health_msg = HealthMsg(t=frame.t, seq=frame.seq, mission=mission.version, failed=tuple(sorted(health.failed)),
                           dropped=tuple(sorted(health.dropped)), since=tuple(sorted(health.since_t.items())))
    events = tuple(EventMsg(t=d.t, seq=frame.seq, robot=d.robot, kind=d.kind, dev=d.deviation_m, by=state.robot)
                   for d in decisions)
    failed_any = arrays.field is not None and bool(np.count_nonzero(failure.failed))  # (stall_state's only use)
    stall_since, stall_pose, stalled = stall_state(state, arrays, s, filtered, failed_any, frame.t)
    was, now = state.blocked or state.stalled, s.blocked or stalled
    if now != was:  # the room: no path to the goal (stopping short) or stuck on the way, or going again
        short = s.left_m if s.blocked else _goal_distance(arrays, s.fit_pose)
        events += (EventMsg(t=frame.t, seq=frame.seq, robot=state.robot, kind="blocked" if now else "unblocked",
                            dev=short, by=state.robot),)
        notes.append(_blocked_note(frame.seq, s.blocked, now, short))
    if s.shape != state.shape:   # reshape: every agent at the same frame (a function of the frame)
        notes.append(Note("info", f"frame {frame.seq}: the structure takes {shape_name(arrays, s.shape)}"))
    notes.extend(Note("warning", f"frame {frame.seq}: robot {d.robot} {d.kind} (deviation {d.deviation_m:.3f} m, "
                                 f"on_failure={mission.on_failure})") for d in decisions)
    state = _evolve(state, wheels_m_s=wheels, ctrl=ctrl, failure=failure, health=health, last_seq=frame.seq,
                    blocked=s.blocked, stall_since_t=stall_since, stall_pose=stall_pose, stalled=stalled,
                    shape=s.shape, last_cmd_t=frame.t, ticks=state.ticks + 1)
    return state, StepOutput(cmd=cmd, state=state_msg, health=health_msg, events=events, notes=tuple(notes),
                             structure=s, wheels_m_s=wheels)


@dataclass(frozen=True)
class _Kernel:
    """A mission's and an agent's constants for vs_agent_step (vsfleet._core.agent_config), and its scratch."""

    config: object              # the capsule
    scratch_f64: np.ndarray
    scratch_u8: np.ndarray
    stateless: tuple            # Precision's arrays standing in for a controller that keeps no state


_KERNELS: dict[tuple, tuple[MissionArrays, _Kernel]] = {}
PRECISION_STATE_FIELDS = tuple(f.name for f in fields(PrecisionState))
FAILURE_FIELDS = tuple(f.name for f in fields(FailureState))


def _agent_kernel(arrays: MissionArrays, mission: Mission, robot: str, controller: Controller,
                  config: StepConfig) -> _Kernel | None:
    """The core's agent step for this mission, robot, controller and config (built once; None: a controller the
    core does not run, whose frames then go through the numpy glue below)."""
    key = (id(arrays), robot, id(controller), config.dt_s, config.ttl_s, config.age_s, config.resync_gap_s)
    hit = _KERNELS.get(key)
    if hit is not None and hit[0] is arrays:
        return hit[1]
    inner, deadband, still = controller, 0.0, 0.0
    if isinstance(controller, Held):
        inner, deadband, still = controller.inner, controller.deadband_m, controller.still_speed_m_s
    name = {Precision: "precision", TurnThenGo: "turn_then_go", Arc: "arc", Tracking: "tracking"}.get(type(inner))
    if name is None:
        return None
    gains = (inner.horizon_s,) if name == "arc" else tuple(float(g) for g in inner._core)
    p = arrays.policy
    policy = (FAILURE_MODES.index(p.mode), p.fail_deviation_m, p.fail_after_s, p.rejoin_deviation_m, p.rejoin_after_s,
              p.recover_after_s, p.min_progress_ratio, p.min_expected_m ** 2, p.min_approach_m)
    sp = _safety_params(config.dt_s)
    n = len(arrays.ids)
    capsule = _core.agent_config(arrays.core, arrays.index[robot], AGENT_CONTROLLERS.index(name), gains, deadband,
                                 still, policy, (sp.margin_m, sp.gamma_per_s, sp.offset_m, sp.dt_s),
                                 (config.dt_s, config.ttl_s, config.age_s, config.resync_gap_s, mission.effective_t),
                                 arrays.room, bool(arrays.radii.any()), arrays.ids)
    stateless = Precision().initial(n)
    kernel = _Kernel(capsule, np.zeros(AGENT_SCRATCH_F64_PER_ROBOT * n), np.zeros(AGENT_SCRATCH_U8_PER_ROBOT * n,
                                                                                  dtype=bool),
                     tuple(getattr(stateless, k).copy() for k in PRECISION_STATE_FIELDS))
    if len(_KERNELS) >= 16:
        _KERNELS.clear()
    _KERNELS[key] = (arrays, kernel)
    return kernel


def _core_inputs(kernel: _Kernel, state: AgentState, controller, n: int) -> tuple[object, tuple, np.ndarray]:
    """(the controller's state, the state's arrays, its numbers) as vsfleet._core.agent_step takes them."""
    ctrl = state.ctrl
    if ctrl is None:
        ctrl = controller.initial(n)
        if isinstance(ctrl, PrecisionState):   # arrays of its own each (initial shares one zeros array): the core
            ctrl = PrecisionState(*(getattr(ctrl, k).copy() for k in PRECISION_STATE_FIELDS))   # writes in place
    precision = tuple(getattr(ctrl, k) for k in PRECISION_STATE_FIELDS) if isinstance(ctrl, PrecisionState) \
        else kernel.stateless
    f = state.failure
    at = state.stall_pose
    scalars = np.array((state.last_frame_t, state.last_cmd_t, state.ctrl is not None, state.blocked,
                        state.stall_since_t, at is not None, *(at[:3] if at is not None else (0.0, 0.0, 0.0)),
                        bool(at[3]) if at is not None else False, state.stalled, state.shape), dtype=float)
    return ctrl, (state.wheels_m_s, *precision, *(getattr(f, k) for k in FAILURE_FIELDS)), scalars


def _core_outcome(state: AgentState, mission: Mission, arrays: MissionArrays, ctrl, t: float, seq: int, r: tuple,
                  scalars: np.ndarray, notes: list) -> tuple[AgentState, HealthMsg | None, tuple]:
    """The new state, the health answer and the events of a frame the core ran (r: vsfleet._core.agent_step's
    answer, scalars: the state's numbers it wrote back); its log lines are added to notes."""
    last_frame_t = float(scalars[0])
    if r[0]:   # resynced
        notes.append(Note("warning", f"frame {seq}: no frame for {t - state.last_frame_t:.2f} s; "
                                     "restarting failure timers and asking peers for their failure state"))
        state = replace(state, phase=SyncPhase.RESYNCING)
    if len(r) == 1:   # no robot usable
        return _evolve(state, last_frame_t=last_frame_t), None, ()
    blocked, shape, event, event_dev, shape_before, made = r[12], r[14], r[19], r[20], r[21], r[22]
    failure = state.failure
    health = _health(failure, arrays.ids)
    health_msg = HealthMsg(t=t, seq=seq, mission=mission.version, failed=tuple(sorted(health.failed)),
                           dropped=tuple(sorted(health.dropped)), since=tuple(sorted(health.since_t.items())))
    events: tuple = ()
    if made or event or shape != shape_before:
        ids = arrays.ids
        decisions = [Decision(td, ids[i], DECISION_KINDS[k], d) for i, k, td, d in made]
        events = tuple(EventMsg(t=d.t, seq=seq, robot=d.robot, kind=d.kind, dev=d.deviation_m, by=state.robot)
                       for d in decisions)
        if event:
            now_blocked = event == 1
            events += (EventMsg(t=t, seq=seq, robot=state.robot, kind="blocked" if now_blocked else "unblocked",
                                dev=event_dev, by=state.robot),)
            notes.append(_blocked_note(seq, blocked, now_blocked, event_dev))
        if shape != shape_before:
            notes.append(Note("info", f"frame {seq}: the structure takes {shape_name(arrays, shape)}"))
        notes.extend(Note("warning", f"frame {seq}: robot {d.robot} {d.kind} (deviation {d.deviation_m:.3f} m, "
                                     f"on_failure={mission.on_failure})") for d in decisions)
    stall_pose = (float(scalars[6]), float(scalars[7]), float(scalars[8]), bool(scalars[9])) if scalars[5] else None
    state = _evolve(state, last_frame_t=last_frame_t, ctrl=ctrl, health=health, last_seq=seq, blocked=bool(blocked),
                    stall_since_t=float(scalars[4]), stall_pose=stall_pose, stalled=bool(scalars[10]),
                    shape=int(shape), last_cmd_t=t, ticks=state.ticks + 1)
    return state, health_msg, events


def _frame_in_core(kernel: _Kernel, state: AgentState, mission: Mission, arrays: MissionArrays, controller,
                   frame: Frame, config: StepConfig, notes: list) -> tuple[AgentState, StepOutput]:
    """agent_step from the frame's poses on, in the core (vs_agent_step): the same bits as the numpy glue below.
    The state's arrays (wheels, the controller's, the failure rule's) are advanced in place: the state passed in
    is consumed, and only the one returned is to be used."""
    n = len(arrays.ids)
    pose, seen, fresh = frame_arrays(arrays.ids, frame.poses, frame.fresh)
    ctrl, arrays_in, scalars = _core_inputs(kernel, state, controller, n)
    used = np.empty(n, dtype=bool)
    r = _core.agent_step(kernel.config, arrays_in, scalars, pose, seen, fresh, float(frame.t), used,
                         kernel.scratch_f64, kernel.scratch_u8)
    state, health_msg, events = _core_outcome(state, mission, arrays, ctrl, frame.t, frame.seq, r, scalars, notes)
    if len(r) == 1:
        return state, StepOutput(notes=tuple(notes))
    (_, fx, fy, fth, gx, gy, gth, vx, vy, w, cost, at_goal, blocked, left_m, shape, vl, vr, own_seen, err, *_) = r
    cmd = CmdMsg(t=frame.t, seq=frame.seq, vl=vl, vr=vr, ttl=config.ttl_s)
    state_msg = None
    if own_seen:
        state_msg = StateMsg(t=frame.t, seq=frame.seq, x=fx, y=fy, th=fth, gx=gx, gy=gy, gth=gth, cost=cost, err=err,
                             used=_used_ids(arrays.ids, used), rejected=0, complete=frame.complete,
                             mission=mission.version, shape=shape)
    sf = kernel.scratch_f64   # vs_agent_step's scratch begins with the poses seen, points_now, points_next, deviations
    structure = make_structure(fx, fy, fth, gx, gy, gth, vx, vy, w, cost, at_goal, used,
                               sf[3 * n:5 * n].reshape(n, 2).copy(), sf[5 * n:7 * n].reshape(n, 2).copy(),
                               sf[7 * n:8 * n].copy(), blocked, left_m, shape)
    return state, StepOutput(cmd=cmd, state=state_msg, health=health_msg, events=events, notes=tuple(notes),
                             structure=structure, wheels_m_s=state.wheels_m_s.copy())


@dataclass(frozen=True)
class PayloadStep:
    """What agent_payload_step gives for a frame it ran: the command's and the state's payloads (the state's
    ``rejected`` filled in), the frame's t and seq, the health answer, events and log lines (as StepOutput's)."""

    cmd: bytes
    state: bytes
    t: float
    seq: int
    health: HealthMsg | None
    events: tuple
    notes: tuple


def agent_payload_step(state: AgentState, mission: Mission | None, payload: bytes, src: str, now_s: float,
                       config: StepConfig, done: tuple[float, int], max_future_s: float, rejected: int,
                       max_age_s: float = 0.25, others_t: float = -math.inf) -> tuple[AgentState, PayloadStep] | None:
    """One pass from a frame's payload to the command's and the state's payloads (vsfleet._core.agent_frame), for
    the agent's common case: a frame of one source that lists exactly the robots of the mission in force, which
    this state already runs, newer than the last frame run (done: its (t, seq)), neither stale against now_s nor
    more than max_future_s ahead of it, with no other source heard within max_age_s before it (others_t: the
    newest frame time of any other source; the merger's rule, vsfleet.frames.FrameMerger). None otherwise, and nothing is changed: the frame then goes the long way
    (decode, merge, agent_step), which decides the same bits (tests/test_core_agent_step.py). The state passed in
    is consumed when a frame runs, as in agent_step."""
    if (mission is None or state.mission_version != mission.version or state.ctrl is None
            or config.impl is not core_impl or config.shared_structures is not None):
        return None
    arrays = mission_arrays(mission)
    if state.robot not in arrays.index:
        return None
    controller = config.controller or mission_controller(mission.controller, mission.controller_gains)
    kernel = _agent_kernel(arrays, mission, state.robot, controller, config)
    if kernel is None:
        return None
    ctrl, arrays_in, scalars = _core_inputs(kernel, state, controller, len(arrays.ids))
    got = _core.agent_frame(kernel.config, arrays_in, scalars, kernel.scratch_f64, kernel.scratch_u8, payload, src,
                            now_s, max_future_s, config.max_stale_s, done[0], done[1], mission.version, rejected,
                            max_age_s, others_t)
    if got is None:
        return None
    cmd, state_payload, t, seq, r = got
    notes: list = []
    state, health_msg, events = _core_outcome(state, mission, arrays, ctrl, t, seq, r, scalars, notes)
    return state, PayloadStep(cmd, state_payload, t, seq, health_msg, events, tuple(notes))


def _blocked_note(seq: int, blocked: bool, now: bool, short: float) -> Note:
    """The log line of the room's verdict changing (blocked: the plan's; now: blocked or stuck, else going on)."""
    if not now:
        return Note("info", f"frame {seq}: the structure is on its way to the goal again")
    if blocked:
        return Note("warning", f"frame {seq}: no path to the goal around the obstacles: the structure "
                               f"stops at the closest safe pose, {short:.3f} m short")
    return Note("warning", f"frame {seq}: stuck on the way, {short:.3f} m short: for {STALL_S:.0f} s "
                           "the safety filter has held robots back and the structure has not moved (a "
                           "passage tighter than the plan allowed for)")


def shape_name(arrays: MissionArrays, shape: int) -> str:
    """A shape's name for a log line: "the template", or the mission's reshape by name ("scale 0.8", "column")."""
    return "the template" if shape == 0 else f"shape {shape} ({arrays.shapes[shape - 1][0]})"


#: the stall watch (stall_state): stuck after STALL_S [s] of the safety filter changing commands while the
#: structure stays within STALL_MOVE_M [m] and STALL_TURN_RAD [rad] of where the watch began
STALL_S = AGENT_STALL_S
STALL_MOVE_M = AGENT_STALL_MOVE_M
STALL_TURN_RAD = AGENT_STALL_TURN_RAD


def stall_state(state: AgentState, arrays: MissionArrays, s: Structure, filtered: bool, failed_any: bool,
                t: float) -> tuple[float, tuple | None, bool]:
    """The stall watch of a room (its field): (stall_since_t, stall_watch, stalled) after a frame at t [s].

    Watched while the structure is neither at the goal nor blocked, no robot is failed (the failure rule
    speaks for those) and every robot used is within the failure rule's deviation of its point (so not a
    fleet still assembling). Stuck: watched for STALL_S, the fitted structure all the while within
    STALL_MOVE_M and STALL_TURN_RAD of where the watch began, and the safety filter changed some command on
    some frame of it. The plan said go, the filter said no: without this the fleet stood still and said
    nothing (issue 28). Going again: the structure moved more than that within STALL_S of the watch's pose; a
    structure that only crawls (less than that each STALL_S) stays stuck, the watch's pose moving on with it every
    STALL_S, so a crawl is one `blocked`, not a `blocked`/`unblocked` pair each time it crosses the threshold. stall_watch:
    (x, y, th, filter seen). A pure function of the frames run, as the failure rule is."""
    if arrays.field is None:
        return math.nan, None, False
    dev = s.deviations_m[s.used]
    watched = not s.at_goal and not s.blocked and not failed_any and dev.size > 0 and \
        float(dev.max()) < arrays.policy.fail_deviation_m
    p = s.fit_pose
    since, at, stalled = state.stall_since_t, state.stall_pose, state.stalled
    moved = at is None or (_norm(p.x - at[0], p.y - at[1]) > STALL_MOVE_M
                           or abs(angle_diff(p.th, at[2])) > STALL_TURN_RAD)
    if stalled:   # going again: moved past the thresholds within STALL_S of the watch's pose
        if not moved and t - since >= STALL_S:   # a crawl: the watch moves on with it
            return t, (p.x, p.y, p.th, at[3]), True
        return (since, at, not moved)
    if not watched:
        return math.nan, None, False
    if math.isnan(since) or moved:
        return t, (p.x, p.y, p.th, filtered), False
    at = (*at[:3], at[3] or filtered)
    return since, at, bool(at[3]) and t - since >= STALL_S


def _goal_distance(arrays: MissionArrays, pose: Pose2) -> float:
    """How far [m] a structure pose is from the mission's final goal position."""
    goal = arrays.goal
    target = goal.pose if isinstance(goal, GoalPose) else goal.waypoints[-1] if isinstance(goal, GoalPath) else None
    return 0.0 if target is None else _norm(target.x - pose.x, target.y - pose.y)


def _norm(dx: float, dy: float) -> float:
    """sqrt(dx*dx + dy*dy): + * sqrt only, as the core's vs_agent_step computes it (not math.hypot): the same bits."""
    return math.sqrt(dx * dx + dy * dy)


@lru_cache(maxsize=8)
def _safety_params(dt_s: float) -> SafetyParams:
    return SafetyParams(dt_s=dt_s)


def _safe_wheels(arrays: MissionArrays, pose: np.ndarray, seen: np.ndarray, active: np.ndarray, wheels: np.ndarray,
                 wheels_prev: np.ndarray, config: StepConfig) -> np.ndarray:
    """Every robot's command through the safety filter (vsfleet.safety): the robots seen are its rows
    (a seen robot not driven, dropped, is a fixed disk); a robot not seen in this frame is not in it.
    Every agent filters the same commands the same way, so the failure rule predicts the filtered
    command each robot's own agent sends."""
    rows = np.flatnonzero(seen)
    if rows.size == 0:
        return wheels
    env = arrays.envelopes
    safe, _info = config.impl.safety_filter(
        np.ascontiguousarray(pose[rows]), arrays.radii[rows], np.ascontiguousarray(wheels[rows]),
        wheel_base_m=env.wheel_base_m[rows], wheel_speed_max_m_s=env.wheel_speed_max_m_s[rows],
        obstacles=arrays.obstacles, active=active[rows], wheel_accel_max_m_s2=env.wheel_accel_max_m_s2[rows],
        wheels_prev_m_s=np.ascontiguousarray(wheels_prev[rows]), params=_safety_params(config.dt_s))
    out = wheels.copy()
    out[rows] = safe
    return out


def _evolve(state: AgentState, **changes) -> AgentState:
    """dataclasses.replace for the per-frame path: the same new frozen AgentState, without re-running
    __init__ over every field (AgentState has no __post_init__ and no validation to skip)."""
    new = object.__new__(AgentState)
    new.__dict__.update(state.__dict__)
    new.__dict__.update(changes)
    return new


def _used_ids(ids: tuple[str, ...], used: np.ndarray) -> tuple[str, ...]:
    """The ids of the rows used (all of them, usually: no loop then)."""
    return ids if np.count_nonzero(used) == len(ids) else tuple(ids[i] for i in np.flatnonzero(used))


_HEALTHY = Health()


def _health(failure: FailureState, ids: tuple[str, ...]) -> Health:
    """The failure state in the peers' wire form (as failure.to_health; rows visited only where set)."""
    since = failure.since_t
    if not (np.count_nonzero(failure.failed) or np.count_nonzero(failure.dropped)) \
            and np.count_nonzero(np.isnan(since)) == len(since):
        return _HEALTHY  # every robot healthy and compliant: the common case
    return Health(since_t={ids[i]: float(since[i]) for i in np.flatnonzero(~np.isnan(since))},
                  failed=frozenset(ids[i] for i in np.flatnonzero(failure.failed)),
                  dropped=frozenset(ids[i] for i in np.flatnonzero(failure.dropped)))


def adopt_health(state: AgentState, msg: HealthMsg | None, timers: bool = True,
                 mission: Mission | None = None, config: StepConfig = StepConfig()) -> AgentState:
    """Take the peers' agreed failure state (None: nothing agreed; keep this agent's own).

    Joining, with ``timers``, the failure timers are taken too; resyncing (or without timers) only
    which robots are failed or dropped. Either way the agent then decides on its own (SYNCED).
    ``mission`` (the one msg is for) lets an agent that has run no frame of it yet take it now.
    """
    if state.phase is SyncPhase.SYNCED:
        return state
    if msg is None:
        return replace(state, phase=SyncPhase.SYNCED)
    timers = timers and state.phase is SyncPhase.JOINING
    current = _health(state.failure, state.ids) if state.failure is not None else state.health
    health = Health(since_t=dict(msg.since) if timers else dict(current.since_t), failed=frozenset(msg.failed),
                    dropped=frozenset(msg.dropped))
    if mission is not None and mission.version != state.mission_version:
        state = _enter_mission(state, mission, mission_policy(mission), config)
    failure = state.failure
    if failure is not None:
        failure = with_health(failure, health, state.ids, timers=True)
    return replace(state, phase=SyncPhase.SYNCED, health=health, failure=failure)


def stop_command(state: AgentState, now_s: float, ttl_s: float) -> CmdMsg:
    """The zero command an agent sends on any exit."""
    return CmdMsg(t=now_s, seq=state.last_seq, vl=0.0, vr=0.0, ttl=ttl_s)
