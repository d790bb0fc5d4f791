"""What every multi-process test shares: a loopback fleet, what the test's session observed, and the
waits on it. Every test here is marked ``integration`` (tests/conftest.py).

The processes are real `vsfleet` children on a free loopback port, multicast scouting off; the test
observes through its own zenoh session, never through log text:

- ``truth/<robot>`` says what simfleet applies and why (``why``: idle, commanded, expired, fault, since
  ``why_t``): halts, command expiries and resumptions are read there;
- ``state/<robot>``, ``cmd/<robot>`` and ``event/<robot>`` say what each agent computed and decided.

Every wait is on a condition over what was observed, with a timeout. :func:`start_fleet` returns only
once the fleet is up (every robot commanded, every agent's state seen), so a test injects its fault
into a running fleet. Inputs a test feeds the agents itself go through :func:`pose_input`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest
import zenoh

from vsfleet.fleetctl.mission_cmd import stamp
from vsfleet.failure import FailurePolicy
from vsfleet.fleetctl.router import free_loopback_port, open_loopback_router
from vsfleet.fleetctl.router import wait_listening as wait_port
from vsfleet.fleetctl.run import child_command
from vsfleet.zglue.scenario_file import load_scenario
from vsfleet.zglue.zconf import RECONNECT_RETRY, RELIABLE_QOS, zenoh_flags
from vsfleet.wire import (
    FrameMsg,
    Keys,
    WireError,
    decode_cmd,
    decode_event,
    decode_pose,
    decode_state,
    decode_truth,
    encode_frame,
    encode_mission,
)

__all__ = ["free_loopback_port", "wait_port"]  # the port helpers, re-exported for the tests

DATA = Path(__file__).parent.parent / "data"
E2E = DATA / "e2e-triangle.toml"
ROBOTS = ("r1", "r2", "r3")
TTL_S = 0.3


# ---------------------------------------------------------------- what the test's session observed


class Observed:
    """Every decoded truth/state/cmd/event message with its arrival time [s, this host], and each robot's
    truth reasons as they changed; waits with a condition."""

    def __init__(self, keys: Keys) -> None:
        self.keys = keys
        self.cond = threading.Condition()
        self.truth: list[tuple[float, str, object]] = []
        self.state: list[tuple[float, str, object]] = []
        self.cmd: list[tuple[float, str, object]] = []
        self.event: list[tuple[float, str, object]] = []  # (arrival, deciding agent, EventMsg) from event/<agent>
        self.why: dict[str, list[tuple[str, float]]] = {}  # robot -> [(why, why_t [s, sim clock])] in time order
        self.pose_seqs: set[int] = set()  # frame numbers the trackers published on pose/<robot>
        self._told: set[tuple[str, str, float]] = set()  # (robot, why, why_t) already in self.why
        self.alive: set[str] = set()
        self.alive_t: dict[str, float] = {}  # when each token last appeared [s, this host]

    def on_liveliness(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        with self.cond:
            if sample.kind == zenoh.SampleKind.PUT:
                self.alive.add(key)
                self.alive_t[key] = time.time()
            else:
                self.alive.discard(key)
            self.cond.notify_all()

    def on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        now = time.time()
        if key.startswith(f"{self.keys.prefix}/event/"):
            try:  # the key names the deciding agent (only its login may put there)
                by = self.keys.robot_of(key, "event")
                msg = decode_event(sample.payload.to_bytes())
            except WireError:
                return
            if msg.by != by:
                return  # not the agent the key says it is from
            with self.cond:
                self.event.append((now, by, msg))
                self.cond.notify_all()
            return
        if key.startswith(f"{self.keys.prefix}/pose/"):
            try:
                seq = decode_pose(sample.payload.to_bytes()).seq
            except WireError:
                return
            with self.cond:
                self.pose_seqs.add(seq)
            return
        for kind, decode, store in (("truth", decode_truth, self.truth), ("state", decode_state, self.state),
                                    ("cmd", decode_cmd, self.cmd)):
            if key.startswith(f"{self.keys.prefix}/{kind}/"):
                try:
                    robot, msg = self.keys.robot_of(key, kind), decode(sample.payload.to_bytes())
                except WireError:
                    return
                with self.cond:
                    store.append((now, robot, msg))
                    if kind == "truth" and msg.why:
                        self._reasons(robot, msg)
                    self.cond.notify_all()
                return

    def _reasons(self, robot: str, msg) -> None:
        """Record a change of ``robot``'s reason, and an expiry this message tells of that was not seen
        as a reason (it happened while this session was cut off from simfleet); kept in sim-time order."""
        reasons = self.why.setdefault(robot, [])
        for entry in ((msg.why, msg.why_t), ("expired", msg.expired_t)):
            if entry[1] > 0.0 and (robot, *entry) not in self._told:
                self._told.add((robot, *entry))
                reasons.append(entry)
                reasons.sort(key=lambda e: e[1])

    def wait_for(self, predicate, timeout_s: float):
        """Wait until predicate(self) returns a truthy value; returns it (or raises TimeoutError)."""
        with self.cond:
            result = self.cond.wait_for(lambda: predicate(self), timeout=timeout_s)
        if not result:
            raise TimeoutError(f"condition not met within {timeout_s} s")
        return result


# ---------------------------------------------------------------- predicates over what was observed


def moving(robot: str, after_t: float = 0.0):
    """The newest truth message of ``robot`` stamped after ``after_t`` with its wheels turning, else None."""
    def pred(obs: Observed):
        return next((m for _, r, m in reversed(obs.truth[-90:])
                     if r == robot and m.t > after_t and abs(m.vl) + abs(m.vr) > 0.02), None)
    return pred


def halts(obs: Observed, after_t: float, ttl_s: float | None = None) -> dict[str, float]:
    """Each robot's halt in force after ``after_t`` [s]: the sim time its command expired (truth ``why``).

    A robot commanded at ``after_t`` halts at its first expiry after it. A robot whose command had
    already expired (its agent starved of CPU just before, say) and which was not commanded again
    halted at that expiry, returned as it is (<= after_t), if that was at most ``ttl_s`` before
    (any time, with None). Robots with neither (never commanded, or no expiry yet) are absent.
    """
    out: dict[str, float] = {}
    for robot, reasons in obs.why.items():
        before = [(why, t) for why, t in reasons if t <= after_t]
        if before and before[-1][0] == "expired":
            if ttl_s is None or before[-1][1] >= after_t - ttl_s:
                out[robot] = before[-1][1]
            continue
        first = next((t for why, t in reasons if t > after_t and why == "expired"), None)
        if first is not None:
            out[robot] = first
    return out


def all_halted(after_t: float, robots=ROBOTS, ttl_s: float | None = None):
    """Predicate: :func:`halts` after ``after_t`` covers every one of ``robots`` (returns it)."""
    def pred(obs: Observed):
        found = halts(obs, after_t, ttl_s)
        return found if set(robots) <= set(found) else None
    return pred


def commanded_again(robot: str, after_t: float):
    """Predicate: the sim time [s] ``robot`` was first commanded again after ``after_t`` (truth ``why``)."""
    def pred(obs: Observed):
        return next((t for why, t in obs.why.get(robot, ()) if why == "commanded" and t > after_t), None)
    return pred


def at_rest_after(t0: float, robots=ROBOTS):
    """Predicate: the first truth time after t0 by which every robot's wheels had come to rest, else None."""
    def pred(obs: Observed):
        zero_since: dict[str, float] = {}
        for _, r, m in obs.truth:
            if m.t > t0 and m.vl == 0.0 and m.vr == 0.0:
                zero_since.setdefault(r, m.t)
        return max(zero_since.values()) if set(robots) <= set(zero_since) else None
    return pred


def at_goal(fleet: "LoopbackFleet", tol_m: float = 0.01, robots=ROBOTS):
    """Predicate: every agent's newest state puts the structure within ``tol_m`` of the goal."""
    gx, gy, _ = fleet.mission.goal

    def pred(obs: Observed):
        latest = {}
        for _, r, m in obs.state:
            latest[r] = m
        return set(latest) >= set(robots) and all(math.hypot(m.x - gx, m.y - gy) < tol_m for m in latest.values())
    return pred


def fleet_up(robots=ROBOTS, after_t: float = 0.0):
    """Predicate: simfleet says every robot is commanded and every agent's state was seen (after ``after_t``)."""
    def pred(obs: Observed):
        commanded = {r for r in robots if any(why == "commanded" for why, _ in obs.why.get(r, ()))}
        states = {r for t, r, _ in obs.state[-30 * len(robots):] if t > after_t}
        return commanded == set(robots) and states >= set(robots)
    return pred


def fleet_judging(mission, robots=ROBOTS):
    """Predicate: every agent has run ``mission`` (its version) for a whole failure window, so that each
    can judge a robot stuck (vsfleet/failure.py: a window settles after FAILURE_SETTLED_RATIO of
    fail_after_s, and an agent that joined later cannot judge before). Read from the agents' states: the
    frame times [s] each agent stamped under that version span fail_after_s. An agent that starts late on
    a loaded host (CI rehearsal, 2026-12-05: one switched to the mission 32 frames after the others)
    otherwise decides on a fault injected at once up to a window after its peers."""
    window_s = FailurePolicy(mission.on_failure, **dict(mission.failure)).fail_after_s

    def pred(obs: Observed):
        span: dict[str, list[float]] = {}
        for _, r, m in obs.state:
            if m.mission == mission.version:
                lo_hi = span.setdefault(r, [m.t, m.t])
                lo_hi[0], lo_hi[1] = min(lo_hi[0], m.t), max(lo_hi[1], m.t)
        return all(r in span and span[r][1] - span[r][0] >= window_s for r in robots)
    return pred


def max_state_err_m(obs: Observed, after_t: float = 0.0) -> float:
    """The largest own-robot error [m] any agent reported on a frame stamped after ``after_t``."""
    return max((m.err for _, _, m in obs.state if m.t > after_t), default=0.0)


def halt_bound_s(fleet: "LoopbackFleet", ttl_s: float = TTL_S) -> float:
    """ttl, then braking at the wheel acceleration limit from full speed, plus one truth period [s]."""
    return ttl_s + max(r.wheel_speed_max / r.wheel_accel_max for r in fleet.scenario.robots) + 0.02


# ---------------------------------------------------------------- inputs the test feeds the agents


def pose_input(keys: Keys, robot: str, t: float, seq: int, x: float, y: float, th: float,
               src: str = "test") -> tuple[str, bytes]:
    """(key, payload) of one observed pose as the agents take it in, a frame of one robot on
    frame/<src> (issue 12: agents read frames only): the one place that knows the agents' input."""
    return keys.frame(src), encode_frame(FrameMsg(t=t, seq=seq, src=src, poses={robot: (x, y, th)}))


# ---------------------------------------------------------------- the fleet's processes


def open_client(endpoint: str) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    # as our programs: back within 0.5 s of a restarted router (zenoh's default retries 1 s, 2 s, 4 s after)
    conf.insert_json5("connect/retry", RECONNECT_RETRY)
    return zenoh.open(conf)


#: a line that reports an error: zenoh's log level (possibly in colour), our programs' logging format
#: ("<time> <logger> ERROR <message>"), or a Python traceback
ERROR_LINE = re.compile(r"\bERROR\b|\bCRITICAL\b|^Traceback \(most recent call last\)")
ANSI = re.compile(r"\x1b\[[0-9;]*m")   # zenoh colours its level ("\x1b[31mERROR"): no word boundary before it
# zenoh's close race (docs/reliability.md): a session that closes can log this for a sample still on its way, even with
# its subscriptions undeclared first (CI, 2026-12-05: agent r3 as the fleet stopped at the end of `vsfleet run`;
# 2 lines in one 8 s run of sessions closing one after another beside a 2 kHz stream, 0 in two 30 s runs). Allowed only in a log
# after the process said it was stopping (STOP_LINE): it never excuses the line in a running process.
ZENOH_CLOSING = re.compile(r"zenoh::api::session\S*: Received Data for unknown key_expr: Remote resource \d+ not found")
# The same race one layer down, in the routing tables of a session that closes with samples still queued on its input:
# the sim tracker behind on its truth when stopped (test_zenoh_errors, two copies at once beside a busy loop,
# 2026-12-06: in 12 of 80 runs, 55-292 lines; in the four logs kept, every line after the tracker's stopping lines;
# with simfleet's transmit queue at zenoh's default (2 batches) 4 of 30 runs, at 16 batches 8 of 50). Allowed as
# ZENOH_CLOSING is.
ZENOH_ROUTE_CLOSING = re.compile(r"zenoh::net::routing::dispatcher::pubsub\S*: \S+ Route data with unknown scope \d+!")
# zglue.lifecycle's line on SIGTERM or SIGINT, or a program's own stopping line, as our logging formats them (an INFO
# line; a rejection that quotes a payload is a WARNING). Per log file: a process restarted under the same name after a
# SIGTERM would have its running lines excused too (no test does that: restarts follow a SIGKILL). Tools that end by
# --duration (monitor, record, fuzz) and a camera tracker at the end of its video log no such line before they close.
STOP_LINE = re.compile(r"^\S+ \S+ \S+ INFO (signal SIG\w+: stopping$|\S+( \S+){0,2} stopping (after|at) )")


class LoopbackFleet:
    """The fleet's processes on loopback. The router is embedded in the test's own session, or
    (router_process=True) a `vsfleet router` child that a test can kill and restart."""

    def __init__(self, scenario_path: str | Path, log_dir: Path, router_process: bool = False) -> None:
        self.scenario_path = str(scenario_path)
        self.scenario = load_scenario(scenario_path)
        self.keys = Keys(self.scenario.fleet)
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen] = {}
        if router_process:
            self.router_port = free_loopback_port()
            self.endpoint = f"tcp/127.0.0.1:{self.router_port}"
            self.start_router()
            self.router = self.open_observer()  # the observer's session (named for symmetry)
        else:
            self.router, self.endpoint = open_loopback_router()
        self.flags = zenoh_flags(self.endpoint)
        self.observed = Observed(self.keys)
        self.sub = self.router.declare_subscriber(self.keys.everything, self.observed.on_sample)
        self.alive_sub = self.router.liveliness().declare_subscriber(
            self.keys.alive(), self.observed.on_liveliness, history=True)
        self.mission = stamp(self.scenario.mission, time.time(), 0.0, version=1)
        self.expected_errors: list[re.Pattern] = []

    def expect_errors(self, *patterns: str) -> None:
        """Error lines this test provokes on purpose (regular expressions, searched in each line): the others
        fail the test when the fleet is closed."""
        self.expected_errors.extend(re.compile(p) for p in patterns)

    def start(self, name: str, *args: str, env: dict[str, str] | None = None) -> subprocess.Popen:
        """Start a child (env: variables added to this process's environment)."""
        flags = [] if name == "router" else self.flags
        with (self.log_dir / f"{name}.log").open("ab") as out:
            p = subprocess.Popen(child_command(*args, *flags), stdout=out, stderr=subprocess.STDOUT,
                                 stdin=subprocess.DEVNULL, start_new_session=True,
                                 env=None if env is None else {**os.environ, **env})
        self.procs[name] = p
        return p

    def open_observer(self) -> zenoh.Session:
        """The test's client session to the router child; subclasses may log in."""
        return open_client(self.endpoint)

    def start_router(self) -> subprocess.Popen:
        """Start (or restart) the `vsfleet router` child on this fleet's port; waits until it listens."""
        p = self.start("router", "router", "--listen", self.endpoint, "--no-multicast-scouting")
        wait_port(self.router_port, 20.0)
        return p

    def start_sim_and_tracker(self, *tracker_extra: str) -> None:
        tr = self.scenario.tracker
        self.start("sim", "sim", self.scenario_path)
        self.start("tracker", "tracker", "sim", "--fleet", self.scenario.fleet, "--rate", str(tr.rate_hz),
                   "--noise-xy", str(tr.noise_xy_m), "--noise-th", str(tr.noise_th_rad),
                   "--latency", str(tr.latency_s), *tracker_extra)

    def start_agent(self, robot: str, *extra: str, env: dict[str, str] | None = None) -> subprocess.Popen:
        name, args = f"agent-{robot}", ("agent", "--robot", robot, "--fleet", self.scenario.fleet, *extra)
        return self.start(name, *args) if env is None else self.start(name, *args, env=env)

    def wait_alive(self, role: str, ids, timeout_s: float = 20.0) -> None:
        want = {self.keys.alive(role, i) for i in ids}
        self.observed.wait_for(lambda o: want <= o.alive, timeout_s)

    def publish_mission(self) -> None:
        self.router.put(self.keys.mission, encode_mission(self.mission), **RELIABLE_QOS)

    def kill(self, name: str, sig: int = signal.SIGKILL) -> float:
        self.procs[name].send_signal(sig)
        return time.time()

    def close(self) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in self.procs.values():
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        self.sub.undeclare()
        self.alive_sub.undeclare()
        self.router.close()

    def logs(self) -> str:
        return "\n".join(f"--- {f.name}\n{f.read_text(errors='replace')[-3000:]}"
                         for f in sorted(self.log_dir.glob("*.log")))


def start_fleet(fleet: LoopbackFleet, *tracker_extra: str, robots=ROBOTS, on_failure: str | None = None,
                ttl_s: float | None = TTL_S, timeout_s: float = 30.0, agent_env=None) -> float:
    """Start simfleet, the simulated tracker and one agent per robot, publish the mission (with
    ``on_failure`` if given), and wait until the fleet is up: every robot commanded (simfleet's
    truth says so) and every agent's state seen. Returns the time [s, this host] it was up."""
    if on_failure is not None:
        fleet.mission = dataclasses.replace(fleet.mission, on_failure=on_failure)
    fleet.start_sim_and_tracker(*tracker_extra)
    for r in robots:
        fleet.start_agent(r, *(("--ttl", str(ttl_s)) if ttl_s is not None else ()),
                          env=(agent_env or {}).get(r))
    fleet.wait_alive("agent", robots, timeout_s)
    fleet.wait_alive("tracker", ("sim",), timeout_s)
    fleet.wait_alive("sim", ("simfleet",), timeout_s)
    fleet.publish_mission()
    fleet.observed.wait_for(fleet_up(robots), timeout_s)
    return time.time()


# ---------------------------------------------------------------- fixtures


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if report.when == "call":
        item.failed_call = report.failed


def closing(fleet: LoopbackFleet, request) -> None:
    """Close the fleet; after a failed test, print its processes' logs (pytest shows them)."""
    if getattr(request.node, "failed_call", False):
        print(fleet.logs())
    fleet.close()


def error_lines(root: Path, allowed=(), closing=(ZENOH_CLOSING, ZENOH_ROUTE_CLOSING)) -> list[str]:
    """Every line of every *.log under root that reports an error (ERROR_LINE) and that no pattern of
    ``allowed`` (regular expressions, searched in the line) covers, nor one of ``closing`` once that log has said
    its process is stopping (STOP_LINE), as "<file>: <line>"."""
    patterns = [re.compile(p) if isinstance(p, str) else p for p in allowed]
    bad = []
    for f in sorted(root.rglob("*.log")):
        stopping = False
        for line in f.read_text(errors="replace").splitlines():
            plain = ANSI.sub("", line)
            stopping = stopping or bool(STOP_LINE.search(plain))
            if (ERROR_LINE.search(plain) and not any(p.search(plain) for p in patterns)
                    and not (stopping and any(p.search(plain) for p in closing))):
                bad.append(f"{f.relative_to(root)}: {line}")
    return bad


@pytest.fixture(autouse=True)
def no_unprovoked_errors(request, tmp_path):
    """Every multi-process test: once it (and its fleet) is done, no process it started (their logs under its
    tmp_path: LoopbackFleet's, and vsfleet run's out_dir) may have logged an error line the test did not
    provoke (mark: provokes_errors(*patterns); LoopbackFleet.expect_errors). Torn down last: after the
    fleets close, so their last lines are in."""
    yield
    if getattr(request.node, "failed_call", True):   # failed (or never ran): its own report says why
        return
    allowed = [p for m in request.node.iter_markers("provokes_errors") for p in m.args]
    allowed += [p for f in getattr(request.node, "fleets", ()) for p in f.expected_errors]
    bad = error_lines(tmp_path, allowed)
    if bad:
        pytest.fail(f"{len(bad)} error line(s) the test did not provoke:\n" + "\n".join(bad[:20]), pytrace=False)


@pytest.fixture
def fleet(tmp_path, request):
    """The e2e-triangle fleet with the router embedded in the test's session (nothing started yet)."""
    f = LoopbackFleet(E2E, tmp_path)
    request.node.fleets = [*getattr(request.node, "fleets", ()), f]
    yield f
    closing(f, request)


@pytest.fixture
def fleet_with_router_process(tmp_path, request):
    """The e2e-triangle fleet with `vsfleet router` as a child the test may kill and restart."""
    f = LoopbackFleet(E2E, tmp_path, router_process=True)
    request.node.fleets = [*getattr(request.node, "fleets", ()), f]
    yield f
    closing(f, request)
