"""vsfleet sim: the simulated fleet. Obeys cmd/<robot> (with ttl) and fault/<robot>; publishes truth.

Physics runs at a fixed rate (200 Hz by default). Simulation time is counted:
step k is at ``t0 + k / rate_hz`` on the tracker's clock (UNIX seconds); the
loop is paced to the wall clock so that agents see real time. Each truth
message says why the wheels do what they do (``why``: idle, commanded,
expired, fault), since when (``why_t``, sim time of the step it began) and
when the robot's command last expired (``expired_t``).
"""

from __future__ import annotations

import argparse
import logging
import math
import threading
from dataclasses import dataclass
from typing import Callable

import zenoh

from fleetctl.lifecycle import Rejections, StopFlag, pace, wall_clock
from fleetctl.scenario_file import load_scenario
from fleetctl.zconf import TELEMETRY_QOS, add_zenoh_args, init_logging, open_session, zenoh_config
from vsfleet.geometry import Pose2
from vsfleet.scenario import Scenario
from vsfleet.wire import Keys, TruthMsg, decode_cmd, decode_fault, encode

from .physics import Fault, RobotState, step_robot

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
    """The simulated robots and their inputs. Thread-safe inputs, single-threaded step()."""

    def __init__(self, scenario: Scenario, keys: Keys, t0: float) -> None:
        self.scenario = scenario
        self.keys = keys
        self.robots = {r.robot: r for r in scenario.robots}
        self.states = {r.robot: RobotState(Pose2(*r.start)) for r in scenario.robots}
        self.cmds: dict[str, _Cmd] = {}
        self.faults: dict[str, Fault] = {r: Fault() for r in self.robots}
        self.timeline = list(scenario.faults)
        self.t0 = t0
        self.k = 0
        self.dt_s = 1.0 / scenario.sim.rate_hz
        self.lock = threading.Lock()
        self.rejections = Rejections(log)
        self.commanded = {r: False for r in self.robots}  # has a fresh command (within its ttl)
        self.expiries = 0
        self.why = {r: ("idle", t0) for r in self.robots}  # (reason, sim time [s] it began): see truth()
        self.expired_t = {r: 0.0 for r in self.robots}  # sim time [s] of each robot's latest expiry

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

    def on_fault(self, key: str, payload: bytes, now: float) -> None:
        got = self._decode(key, "fault", decode_fault, payload)
        if got is not None:
            robot, msg = got
            self.set_fault(robot, msg.kind, msg.factor, msg.duration, now)

    def set_fault(self, robot: str, kind: str, factor: float, duration: float, now: float) -> None:
        until = now + duration if duration > 0 else math.inf
        with self.lock:
            self.faults[robot] = Fault(kind, factor, until)
        log.info("fault on %s: %s factor=%.2f duration=%.2fs", robot, kind, factor, duration)

    def step(self) -> None:
        """One physics step for every robot, at sim time self.t."""
        t = self.t
        while self.timeline and self.t0 + self.timeline[0].at_s <= t:
            ev = self.timeline.pop(0)
            self.set_fault(ev.robot, ev.kind, ev.factor, ev.duration, t)
        with self.lock:
            cmds = dict(self.cmds)
            faults = dict(self.faults)
        for rid, robot in self.robots.items():
            c = cmds.get(rid)
            fresh = c is not None and t - c.arrived_t <= c.ttl
            if fresh != self.commanded[rid]:
                self.commanded[rid] = fresh
                if not fresh:
                    self.expiries += 1
                    log.info("%s: command expired at t=%.3f (last seq %d, arrived %.3f, ttl %.3f): halting",
                             rid, t, c.seq, c.arrived_t, c.ttl)
                else:
                    log.info("%s: commanded again at t=%.3f (seq %d)", rid, t, c.seq)
            why = _why(c is not None, fresh, faults[rid], t)
            if why != self.why[rid][0]:
                self.why[rid] = (why, t)
                if why == "expired":
                    self.expired_t[rid] = t
            self.states[rid] = step_robot(self.states[rid], robot, c.vl if c else 0.0,
                                          c.vr if c else 0.0, fresh, faults[rid], t, self.dt_s)
        self.k += 1

    def truth(self) -> dict[str, TruthMsg]:
        """Every robot's pose and applied wheel speeds after the last step, stamped self.t, with
        the reason for its wheels (as of that step), the sim time that reason began, the sim
        time of its latest command expiry, and the bad messages counted so far."""
        t = self.t
        return {rid: TruthMsg(t=t, x=s.pose.x, y=s.pose.y, th=s.pose.th, vl=s.vl, vr=s.vr,
                              why=self.why[rid][0], why_t=self.why[rid][1], expired_t=self.expired_t[rid],
                              rejected=self.rejections.count)
                for rid, s in self.states.items()}


def _why(ever_commanded: bool, fresh: bool, fault: Fault, t: float) -> str:
    """What sets a robot's wheels at sim time t: idle (never commanded), expired (the last
    command outlived its ttl: braking to rest), fault (a fault alters a fresh command), commanded."""
    if not ever_commanded:
        return "idle"
    if not fresh:
        return "expired"
    if fault.kind != "none" and t < fault.until_t:
        return "fault"
    return "commanded"


def run_sim(conf: zenoh.Config, scenario: Scenario, stop: StopFlag | None = None,
            clock: Callable[[], float] = wall_clock) -> Fleet:
    stop = stop or StopFlag()
    keys = Keys(scenario.fleet)
    fleet = Fleet(scenario, keys, t0=clock())
    truth_every = max(1, round(scenario.sim.rate_hz / scenario.sim.truth_rate_hz))
    with open_session(conf) as session:
        pubs = {r: session.declare_publisher(keys.truth(r), **TELEMETRY_QOS) for r in fleet.robots}
        token = session.liveliness().declare_token(keys.alive("sim", "simfleet"))
        subs = [
            session.declare_subscriber(keys.cmd(), lambda s: fleet.on_cmd(
                str(s.key_expr), s.payload.to_bytes(), fleet.t)),
            session.declare_subscriber(keys.fault(), lambda s: fleet.on_fault(
                str(s.key_expr), s.payload.to_bytes(), fleet.t)),
        ]
        log.info("simfleet up: %d robots at %.0f Hz", len(fleet.robots), scenario.sim.rate_hz)
        late = 0
        try:
            while not stop.is_set():
                if fleet.k % truth_every == 0:
                    for rid, msg in fleet.truth().items():
                        pubs[rid].put(encode(msg))
                fleet.step()
                if clock() > fleet.t + 0.1:
                    late += 1
                pace(fleet.t, stop, clock)
        finally:
            log.info("simfleet stopping at step %d (%d steps over 100 ms late), %d rejected",
                     fleet.k, late, fleet.rejections.count)
            for s in subs:
                s.undeclare()
            token.undeclare()
    return fleet


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet sim", description=__doc__.splitlines()[0])
    p.add_argument("scenario", help="scenario TOML file (robots, start poses, faults)")
    p.add_argument("--fleet", default=None, help="override the scenario's fleet name")
    p.add_argument("--verbose", "-v", action="store_true")
    add_zenoh_args(p)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    init_logging(args.verbose)
    try:
        scenario = load_scenario(args.scenario, fleet=args.fleet)
    except (OSError, ValueError) as exc:
        log.error("cannot load scenario: %s", exc)
        return 2
    run_sim(zenoh_config(args), scenario)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
