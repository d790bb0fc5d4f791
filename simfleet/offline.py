"""The whole fleet in one process, with no transport: agents, tracker and physics on a counted clock.

Each frame is observed with Gaussian noise, encoded once as the tracker's frame
message, and handed to one real ``Agent`` per robot (the agent process's slot,
frame merger and pure step, vsfleet.step.agent_step, with transport and clock
injected);
their commands take effect
``latency_frames`` frames later. ``Overload`` models a loaded host: frames that reach the agents late,
agents that stall, and robots that hold each command for its ttl. Used by the tests (controller choice, faults)
and by the benchmarks. It does the same job as the multi-process fleet, minus
zenoh.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import msgpack
import numpy as np

from vsfleet.analysis import goal_distance
from vsfleet.control import DEFAULT_CONTROLLER, make_controller
from vsfleet.failure import Decision
from vsfleet.fit import fit_structure
from vsfleet.geometry import Pose2
from vsfleet.scenario import Scenario
from vsfleet.step import mission_template
from vsfleet.wire import EventMsg, FrameMsg, Keys, decode_cmd, decode_event, encode_frame, encode_mission

from vsfleet.agent.main import Agent

from .engine import make_engine, step_engine_fleet
from .physics import Contact, Fault, RobotState, step_fleet


@dataclass(frozen=True)
class Overload:
    """A loaded host, offline. Frames reach every agent frame_delay_frames frames after they were taken (the agents'
    clock reads the time they arrive, so they see the age). With probability stall_p at each frame, every agent
    stalls for stall_frames frames, and runs the newest frame after. The robots hold each command from its arrival
    (latency_frames after it was sent) for its ttl, as simfleet does, and halt after it (not on the next frame).
    The hold is checked once a frame, so a command acts for up to a frame more than its ttl: the stricter case.
    stall_seed: the stalls' own draws (the tracker's noise keeps the run's seed)."""

    frame_delay_frames: int = 0
    stall_p: float = 0.0
    stall_frames: int = 0
    stall_seed: int = 0

    def __post_init__(self) -> None:
        if self.frame_delay_frames < 0 or not 0.0 <= self.stall_p <= 1.0 or self.stall_frames < 0 \
                or (self.stall_p > 0.0 and self.stall_frames < 1):
            raise ValueError(f"Overload: delay >= 0 frames, 0 <= stall_p <= 1, and stalls of >= 1 frame when "
                             f"stall_p > 0 (got {self})")


@dataclass(frozen=True)
class OfflineRun:
    """Deviation of each robot from the truth-fitted structure [m], per frame until the goal.

    t_goal_s is the first time the truth-fitted structure came within goal_tol_m of the
    goal (None if never); wheel_tv_m_s2 is each robot's wheel-command total variation per
    second until then (a chatter measure); trace holds (t, fitted pose) per frame.
    """

    deviations_m: np.ndarray      # (frames, n)
    robots: tuple[str, ...]
    t_goal_s: float | None
    wheel_tv_m_s2: float
    trace: tuple[tuple[float, Pose2], ...]
    final_poses: dict
    decisions: dict  # robot -> the failure-policy decisions its agent made, in order
    positions_m: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 0, 2)))  # (frames, n, 2) truth
    commands_m_s: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 0, 2)))  # (frames, n, 2) sent
    engine: str = "kinematic"     # the physics engine under the robots (simfleet.engine)
    contacts: tuple[Contact, ...] = ()  # contacts between bodies that began, as the engine reported them
    # reshape: robot -> [(frame seq, shape)], each change of the shape its agent's state reports (from 0, the template)
    shapes: dict = dataclasses.field(default_factory=dict)
    # robot -> every event its agent published, in order, as decoded from the wire (decisions holds the same, shorter)
    events: dict = dataclasses.field(default_factory=dict)


def run_offline(scenario: Scenario, duration_s: float, controller: str | None = None,
                metric: str | None = None, noise_xy_m: float | None = None,
                noise_th_rad: float | None = None, latency_frames: int = 1, seed: int = 0,
                goal_tol_m: float = 0.005, stop_at_goal: bool = True, tracker_clock_ahead_s: float = 0.0,
                share_structures: bool = False, reference: bool = False, engine: str | None = None,
                overload: Overload | None = None, **gains: float) -> OfflineRun:
    """The fleet of ``scenario`` offline: one agent per robot on counted frames, simfleet's physics.

    reference: the agents run the numpy reference of the step instead of the compiled core (tests).
    share_structures: the agents share the structures they compute and step in the numpy glue of
    vsfleet.step.agent_step (the way offline runs went before the core had the whole step); by default each agent
    runs its frame as an agent process does (Agent.run_frame): in one pass from the frame's payload when it can, else
    in the core (vs_agent_step), the same bits either way (tests/test_core_agent_step.py).
    engine: the physics engine (simfleet.engine.ENGINES; None: the scenario's [sim] engine).
    overload: a loaded host (Overload); None: every frame reaches every agent at once, and a command holds for
    one frame."""
    mission = scenario.mission
    if metric is not None:
        mission = dataclasses.replace(mission, metric=metric)
    ctrl = make_controller(controller or mission.controller or DEFAULT_CONTROLLER,
                           **{**dict(mission.controller_gains), **gains})
    tr = scenario.tracker
    nxy = tr.noise_xy_m if noise_xy_m is None else noise_xy_m
    nth = tr.noise_th_rad if noise_th_rad is None else noise_th_rad
    rng = np.random.default_rng(seed)
    robots = {r.robot: r for r in scenario.robots}
    states = {r.robot: RobotState(Pose2(*r.start)) for r in scenario.robots}
    faults = {r: Fault() for r in robots}
    timeline = list(scenario.faults)
    ids = mission.robot_ids
    template = mission_template(mission)
    dt = 1.0 / tr.rate_hz
    substeps = max(1, round(scenario.sim.rate_hz / tr.rate_hz))
    dt_phys = dt / substeps
    cmds = {r: (0.0, 0.0) for r in robots}
    engine = engine or scenario.sim.engine
    # the kinematic engine through step_fleet as always; another through the same rule on its object
    phys = None if engine == "kinematic" else make_engine(engine, [robots[r] for r in robots],
                                                           mission.obstacles, dt_phys)
    pending: list[dict] = []
    t = 0.0
    tv = 0.0
    devs, trace, positions, sent_log = [], [], [], []
    t_goal = None
    keys = Keys(scenario.fleet)
    sent: dict[str, tuple[float, float]] = {}
    sent_ttl: dict[str, float] = {}
    held: dict[str, tuple[tuple[float, float], float]] = {r: ((0.0, 0.0), -np.inf) for r in robots}  # overload
    taken: list[bytes] = []          # overload: the frames taken, for the agents to get late
    stall_rng = np.random.default_rng(overload.stall_seed) if overload is not None else None
    stall_left = 0
    agents = {}
    # every decision (and blocked/unblocked event) each agent publishes, as the fleet's event/<robot> carries
    # it: the agent itself keeps only its newest ones
    decisions: dict[str, list[Decision]] = {r: [] for r in robots}
    events: dict[str, list[EventMsg]] = {r: [] for r in robots}
    shapes: dict[str, list[tuple[int, int]]] = {r: [] for r in robots}
    # share_structures: the agents share the structures they compute: an agent whose frame, mission and failure
    # masks equal another's takes that agent's structure (the same pure function of the same inputs) instead of
    # fitting again; everything else (controller, failure rule, state) each agent computes on its own
    shared: dict | None = {} if share_structures else None
    for r in robots:  # one agent per robot, each with its own state, as in the fleet
        agents[r] = Agent(r, keys, put_cmd=lambda b, r=r: _take_cmd(sent, sent_ttl, r, b),
                          put_state=lambda b, r=r: _note_shape(shapes[r], b),
                          put_event=lambda b, r=r: _take_event(decisions[r], events[r], b),
                          dt_s=dt, clock=lambda: t - tracker_clock_ahead_s, controller=ctrl,
                          command_age_s=latency_frames * dt, shared_structures=shared, reference=reference,
                          log_notes=r == ids[0])   # one copy's log: every copy decides the same (decisions holds all)
        agents[r].on_mission(keys.mission, encode_mission(mission))
    for k in range(int(round(duration_s / dt))):
        poses = {r: (s.pose.x + rng.normal(0.0, nxy), s.pose.y + rng.normal(0.0, nxy),
                     s.pose.th + rng.normal(0.0, nth)) for r, s in states.items()}
        sent.clear()
        frame = encode_frame(FrameMsg(t=t, seq=k + 1, src="offline", poses=poses))
        if overload is not None:   # the frame the agents get now, if they run one
            taken.append(frame)
            frame = taken[k - overload.frame_delay_frames] if k >= overload.frame_delay_frames else None
            if stall_left > 0:
                stall_left, frame = stall_left - 1, None
            elif overload.stall_p > 0.0 and stall_rng.random() < overload.stall_p:
                stall_left, frame = overload.stall_frames - 1, None
        sent_ttl.clear()
        if frame is not None:
            for agent in agents.values():  # as the agent process's frame callback runs it (Agent.run_frame)
                agent.run_frame(keys.frame("offline"), frame)
        new = {r: sent.get(r, (0.0, 0.0)) for r in robots}
        sent_log.append([new[r] for r in ids])
        pending.append(({r: (new[r], sent_ttl[r]) for r in sent_ttl}, new))
        if len(pending) > latency_frames:
            arrived, applied = pending.pop(0)
            if overload is not None:   # each robot holds its last command until its ttl runs out
                held.update({r: (c, t + ttl) for r, (c, ttl) in arrived.items()})
                applied = {r: held[r][0] if t <= held[r][1] else (0.0, 0.0) for r in robots}
            if t_goal is None:
                tv += sum(abs(applied[r][0] - cmds[r][0]) + abs(applied[r][1] - cmds[r][1]) for r in robots)
            cmds = applied
        if phys is None:
            t = step_fleet(states, robots, cmds, faults, timeline, t, dt_phys, substeps)
        else:
            t = step_engine_fleet(phys, states, robots, cmds, faults, timeline, t, dt_phys, substeps)
        xy = np.array([[states[r].pose.x, states[r].pose.y] for r in ids])
        positions.append(xy)
        fit = fit_structure(template, xy, metric=mission.metric)
        trace.append((t, fit.pose))
        devs.append(fit.residuals_m)
        if t_goal is None and goal_distance(mission, fit.pose) < goal_tol_m and (mission.goal or mission.path):
            t_goal = t
            if stop_at_goal:
                break
    span = t_goal if t_goal is not None else t
    return OfflineRun(deviations_m=np.array(devs), robots=ids, t_goal_s=t_goal,
                      wheel_tv_m_s2=tv / len(robots) / max(span, 1e-9), trace=tuple(trace),
                      final_poses={r: s.pose for r, s in states.items()},
                      decisions=decisions,
                      positions_m=np.array(positions), commands_m_s=np.array(sent_log, dtype=float),
                      engine=engine, contacts=tuple(phys.contacts) if phys is not None else (), shapes=shapes,
                      events=events)


def _note_shape(changes: list[tuple[int, int]], payload: bytes) -> None:
    """Note the shape an agent's state reports when it differs from the last noted (0, the template, at first)."""
    m = msgpack.unpackb(payload)
    shape = m.get("shape", 0)
    if shape != (changes[-1][1] if changes else 0):
        changes.append((m["seq"], shape))


def _take_cmd(sent: dict, sent_ttl: dict, robot: str, payload: bytes) -> None:
    """A robot's command as its agent sent it: its wheels, and its ttl [s]."""
    cmd = decode_cmd(payload)
    sent[robot], sent_ttl[robot] = (cmd.vl, cmd.vr), cmd.ttl


def _take_event(decisions: list[Decision], events: list[EventMsg], payload: bytes) -> None:
    """An event as its agent published it: decoded (events), and as a Decision (decisions)."""
    ev = decode_event(payload)
    events.append(ev)
    decisions.append(Decision(ev.t, ev.robot, ev.kind, ev.dev))
