"""vsfleet sim: the simulated fleet. Obeys cmd/<robot> (with ttl) and fault/<robot>; publishes truth.

Physics runs at a fixed rate (200 Hz by default). Simulation time is counted:
step k is at ``t0 + k / rate_hz`` on the tracker's clock (UNIX seconds); the
loop is paced to the wall clock so that agents see real time. Each truth
message says why the wheels do what they do (``why``: idle, commanded,
expired, fault), since when (``why_t``, sim time of the step it began) and
when the robot's command last expired (``expired_t``).

The engine under the robots is the scenario's ``[sim] engine`` or ``--engine``: ``kinematic`` (exact
arcs, the default) or ``mujoco`` (rigid bodies with mass, friction and contacts; the optional extra
vsfleet[mujoco]; docs/engine.md). Each contact between bodies (robot-robot, robot-obstacle) that an
engine reports is logged as it begins and counted in the final log line.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import threading
from dataclasses import dataclass
from typing import Callable

import numpy as np
import zenoh

from vsfleet.zglue.lifecycle import Rejections, StopFlag, pace, wall_clock
from vsfleet.zglue.scenario_file import load_scenario
from vsfleet.zglue.program import common_flags, program, refusing
from vsfleet.zglue.zconf import BURST_QOS, RELIABLE_QOS, open_session, zenoh_config
from vsfleet.geometry import Pose2
from vsfleet.scenario import Scenario
from vsfleet.wire import ContactMsg, Keys, TruthMsg, decode_cmd, decode_fault, encode

from .engine import ENGINES, check_engine, make_engine
from .physics import Fault, FaultArrays, FleetParams, RobotState

log = logging.getLogger("vsfleet.sim")


@dataclass
class _Cmd:
    vl: float
    vr: float
    seq: int
    t: float
    arrived_t: float  # [s, sim clock]
    ttl: float


class Fleet:
    """The simulated robots and their inputs. Thread-safe inputs, single-threaded step().

    engine: the physics engine's name (simfleet.engine.ENGINES; None: the scenario's [sim] engine)."""

    def __init__(self, scenario: Scenario, keys: Keys, t0: float, engine: str | None = None) -> None:
        self.scenario = scenario
        self.keys = keys
        self.robots = {r.robot: r for r in scenario.robots}
        self.ids = tuple(self.robots)
        self.row = {r: i for i, r in enumerate(self.ids)}
        n = len(self.ids)
        self.params = FleetParams.of(list(self.robots.values()))
        self.dt_s = 1.0 / scenario.sim.rate_hz
        self.engine = make_engine(engine or scenario.sim.engine, scenario.robots, scenario.mission.obstacles,
                                  self.dt_s)
        self.pose, self.wheels = self.engine.pose, self.engine.wheels
        self.contacts = 0  # contacts between bodies that began, as the engine reported them
        self.new_contacts: list = []  # the ones not yet published (run_sim puts each on contact/<robot>)
        self.cmds: dict[str, _Cmd] = {}
        self.cmd = np.zeros((n, 2))                  # the latest command's wheels [m/s] ...
        self.cmd_arrived_t = np.full(n, -math.inf)   # ... when it arrived [s, sim clock] ...
        self.cmd_ttl_s = np.zeros(n)                 # ... and its ttl [s]
        self.faults: dict[str, Fault] = {r: Fault() for r in self.robots}
        self.fault_arrays = FaultArrays.of(self.faults.values())
        self.timeline = list(scenario.faults)
        self.t0 = t0
        self.k = 0
        self.lock = threading.Lock()
        self.rejections = Rejections(log)
        self.fresh = np.zeros(n, dtype=bool)  # has a fresh command (within its ttl)
        self.expiries = 0
        self.why_code = np.zeros(n, dtype=int)  # WHY index: see truth()
        self.why_t = np.full(n, float(t0))      # sim time [s] the reason began
        self.expired_at = np.zeros(n)           # sim time [s] of each robot's latest expiry

    def start_at(self, t0: float) -> None:
        """Start the sim clock at t0 [s] instead (before the first step): once the engine is built, so that
        building it (MuJoCo: importing, compiling the scene, settling the bodies) leaves no lag to catch up."""
        assert self.k == 0, "the sim clock starts before the first step"
        self.t0 = t0
        self.why_t = np.full(len(self.ids), float(t0))

    @property
    def states(self) -> dict[str, RobotState]:
        """Each robot's pose [m, rad; world] and applied wheel speeds [m/s], by id."""
        return {r: RobotState(Pose2(*self.pose[i]), float(self.wheels[i, 0]), float(self.wheels[i, 1]))
                for i, r in enumerate(self.ids)}

    @property
    def why(self) -> dict[str, tuple[str, float]]:
        return {r: (WHY[self.why_code[i]], float(self.why_t[i])) for i, r in enumerate(self.ids)}

    @property
    def expired_t(self) -> dict[str, float]:
        return {r: float(self.expired_at[i]) for i, r in enumerate(self.ids)}

    @property
    def t(self) -> float:
        return self.t0 + self.k * self.dt_s

    def _decode(self, key: str, kind: str, decode, payload: bytes):
        """(robot, message) for one of our robots, or None after a counted rejection."""
        try:
            robot = self.keys.robot_of(key, kind)
            msg = decode(payload)
        except Exception as exc:  # noqa: BLE001 - WireError, or anything else: counted, never fatal
            self.rejections.reject(key, str(exc))
            return None
        if robot not in self.robots:
            self.rejections.reject(key, f"unknown robot {robot!r}")
            return None
        return robot, msg

    def on_cmd(self, key: str, payload: bytes, now: float) -> None:
        got = self._decode(key, "cmd", decode_cmd, payload)
        if got is None:
            return
        robot, msg = got
        with self.lock:
            held = self.cmds.get(robot)
            if held is not None and (msg.t, msg.seq) < (held.t, held.seq):
                return  # out of order: a newer frame's command is already applied
            self.cmds[robot] = _Cmd(msg.vl, msg.vr, msg.seq, msg.t, now, msg.ttl)
            i = self.row[robot]
            self.cmd[i] = (msg.vl, msg.vr)
            self.cmd_arrived_t[i], self.cmd_ttl_s[i] = now, msg.ttl

    def on_fault(self, key: str, payload: bytes, now: float) -> None:
        got = self._decode(key, "fault", decode_fault, payload)
        if got is not None:
            robot, msg = got
            self.set_fault(robot, msg.kind, msg.factor, msg.duration, now)

    def set_fault(self, robot: str, kind: str, factor: float, duration: float, now: float) -> None:
        until = now + duration if duration > 0 else math.inf
        with self.lock:
            self.faults[robot] = Fault(kind, factor, until)
            self.fault_arrays = FaultArrays.of(self.faults.values())
        log.info("fault on %s: %s factor=%.2f duration=%.2fs", robot, kind, factor, duration)

    def step(self) -> None:
        """One physics step for every robot at once, at sim time self.t."""
        t = self.t
        while self.timeline and self.t0 + self.timeline[0].at_s <= t:
            ev = self.timeline.pop(0)
            self.set_fault(ev.robot, ev.kind, ev.factor, ev.duration, t)
        with self.lock:
            cmd, arrived, ttl, faults = self.cmd.copy(), self.cmd_arrived_t.copy(), self.cmd_ttl_s.copy(), \
                self.fault_arrays
        fresh = t - arrived <= ttl
        changed = fresh != self.fresh
        if changed.any():
            for i in np.flatnonzero(changed):  # rare: a command stream starts or stops
                rid, c = self.ids[i], self.cmds.get(self.ids[i])
                if not fresh[i]:
                    self.expiries += 1
                    log.info("%s: command expired at t=%.3f (last seq %d, arrived %.3f, ttl %.3f): halting",
                             rid, t, c.seq, c.arrived_t, c.ttl)
                else:
                    log.info("%s: commanded again at t=%.3f (seq %d)", rid, t, c.seq)
            self.fresh = fresh
        faulted = (faults.kind != 0) & (t < faults.until_t)
        why = np.where(np.isfinite(arrived), np.where(~fresh, EXPIRED, np.where(faulted, FAULT, COMMANDED)), IDLE)
        moved = why != self.why_code
        if moved.any():
            self.why_t = np.where(moved, t, self.why_t)
            self.expired_at = np.where(moved & (why == EXPIRED), t, self.expired_at)
            self.why_code = why
        for contact in self.engine.step(cmd, fresh, faults, t):
            self.contacts += 1
            self.new_contacts.append(contact)
            log.warning("%s", contact.describe())
        self.pose, self.wheels = self.engine.pose, self.engine.wheels
        self.k += 1

    def truth(self) -> dict[str, TruthMsg]:
        """Every robot's pose and applied wheel speeds after the last step, stamped self.t, with
        the reason for its wheels (as of that step), the sim time that reason began, the sim
        time of its latest command expiry, and the bad messages counted so far."""
        t, n_rejected = self.t, self.rejections.count
        pose, wheels = self.pose.tolist(), self.wheels.tolist()
        why, why_t, expired = self.why_code.tolist(), self.why_t.tolist(), self.expired_at.tolist()
        return {rid: TruthMsg(t=t, x=pose[i][0], y=pose[i][1], th=pose[i][2], vl=wheels[i][0], vr=wheels[i][1],
                              why=WHY[why[i]], why_t=why_t[i], expired_t=expired[i], rejected=n_rejected)
                for i, rid in enumerate(self.ids)}


#: simfleet's session keeps 16 batches (zenoh's most; 2 by default) in its transmit queue of priority data, which
#: carries the truth/<robot> bursts. Lazily allocated, 64 KiB each, only while the link is behind. Measured with
#: tests/integration/test_truth_burst.py run twice at once beside a busy loop (2026-12-06): with 2 batches, 9
#: ticks of 1,834 reached the test in part, 5 of 322 in one run, and a second subscriber of truth alone lost the
#: same robots of the same ticks (so they were dropped before the router fanned them out); with 16, 0 of 2,440.
SIM_ZENOH_DEFAULTS = (("transport/link/tx/queue/size/data", "16"),)

WHY = ("idle", "commanded", "expired", "fault")  # what sets a robot's wheels (truth's ``why``):
IDLE, COMMANDED, EXPIRED, FAULT = range(4)       # never commanded / fresh / outlived its ttl / a fault alters it


def contact_msg(c) -> ContactMsg:
    """The wire form (vsfleet.wire.ContactMsg, key contact/<robot>) of an engine's Contact."""
    return ContactMsg(t=c.t, robot=c.robot, kind=c.kind, other=str(c.other), x=c.x, y=c.y, depth=c.depth_m)


def run_sim(conf: zenoh.Config, scenario: Scenario, stop: StopFlag | None = None,
            clock: Callable[[], float] = wall_clock) -> Fleet:
    stop = stop or StopFlag()
    keys = Keys(scenario.fleet)
    fleet = Fleet(scenario, keys, t0=clock())
    truth_every = max(1, round(scenario.sim.rate_hz / scenario.sim.truth_rate_hz))
    with open_session(conf) as session:
        pubs = {r: session.declare_publisher(keys.truth(r), **BURST_QOS) for r in fleet.robots}
        fleet.start_at(clock())  # the engine built, the session open: simulated time starts now (before any input)
        subs = [
            session.declare_subscriber(keys.cmd(), lambda s: fleet.on_cmd(
                str(s.key_expr), s.payload.to_bytes(), fleet.t)),
            session.declare_subscriber(keys.fault(), lambda s: fleet.on_fault(
                str(s.key_expr), s.payload.to_bytes(), fleet.t)),
        ]
        # alive only once it listens (as the agent): a fault or command sent on seeing the token is not missed
        token = session.liveliness().declare_token(keys.alive("sim", "simfleet"))
        log.info("simfleet up: %d robots at %.0f Hz, engine %s", len(fleet.robots), scenario.sim.rate_hz,
                 fleet.engine.name)
        late = 0
        try:
            while not stop.is_set():
                if fleet.k % truth_every == 0:
                    for rid, msg in fleet.truth().items():
                        pubs[rid].put(encode(msg))
                fleet.step()
                for c in fleet.new_contacts:   # reliable puts, from this loop only: every contact reaches the tools
                    session.put(keys.contact(c.robot), encode(contact_msg(c)), **RELIABLE_QOS)
                fleet.new_contacts.clear()
                if clock() > fleet.t + 0.1:
                    late += 1
                pace(fleet.t, stop, clock)
        finally:
            log.info("simfleet stopping at step %d (%d steps over 100 ms late), %d rejected, %d contacts (engine %s)",
                     fleet.k, late, fleet.rejections.count, fleet.contacts, fleet.engine.name)
            for s in subs:
                s.undeclare()
            token.undeclare()
    return fleet


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet sim", description=__doc__.splitlines()[0])
    p.add_argument("scenario", help="scenario TOML file (robots, start poses, faults)")
    p.add_argument("--fleet", default=None, help="override the scenario's fleet name")
    p.add_argument("--engine", choices=ENGINES, default=None,
                   help="physics engine (default: the scenario's [sim] engine, else kinematic); mujoco needs "
                        "pip install 'vsfleet[mujoco]'")
    return common_flags(p)


@program(build_parser, log, prefix="cannot load scenario: ")
def main(args: argparse.Namespace) -> int:
    with refusing(OSError, ValueError):
        scenario = load_scenario(args.scenario, fleet=args.fleet)
        if args.engine is not None:
            scenario = dataclasses.replace(scenario, sim=dataclasses.replace(scenario.sim, engine=args.engine))
        check_engine(scenario.sim.engine)  # its package is there (else one line: how to install it)
    run_sim(zenoh_config(args, SIM_ZENOH_DEFAULTS), scenario)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
