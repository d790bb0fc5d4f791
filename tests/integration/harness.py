"""A loopback fleet for multi-process tests: embedded router on a free port, no multicast.

Processes are real `vsfleet` subprocesses; the test observes through its own
client session. Every wait is on an event or a condition with a timeout.
"""

from __future__ import annotations

import json
import signal
import subprocess
import threading
import time
from pathlib import Path

import zenoh

from fleetctl.mission_cmd import stamp
from fleetctl.router import free_loopback_port, open_loopback_router
from fleetctl.router import wait_listening as wait_port
from fleetctl.run import child_command
from fleetctl.scenario_file import load_scenario
from fleetctl.zconf import RELIABLE_QOS, zenoh_flags
from vsfleet.wire import Keys, WireError, decode_cmd, decode_event, decode_state, decode_truth, encode_mission


class Observed:
    """Every decoded truth/state/cmd message, with its arrival time; waits with a condition."""

    def __init__(self, keys: Keys) -> None:
        self.keys = keys
        self.cond = threading.Condition()
        self.truth: list[tuple[float, str, object]] = []
        self.state: list[tuple[float, str, object]] = []
        self.cmd: list[tuple[float, str, object]] = []
        self.event: list[tuple[float, str, object]] = []  # (arrival, deciding agent, EventMsg) from event/<agent>
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
        for kind, decode, store in (("truth", decode_truth, self.truth), ("state", decode_state, self.state),
                                    ("cmd", decode_cmd, self.cmd)):
            if key.startswith(f"{self.keys.prefix}/{kind}/"):
                try:
                    msg = decode(sample.payload.to_bytes())
                except WireError:
                    return
                with self.cond:
                    store.append((now, self.keys.robot_of(key, kind), msg))
                    self.cond.notify_all()

    def wait_for(self, predicate, timeout_s: float):
        """Wait until predicate(self) returns a truthy value; returns it (or raises TimeoutError)."""
        with self.cond:
            result = self.cond.wait_for(lambda: predicate(self), timeout=timeout_s)
        if not result:
            raise TimeoutError(f"condition not met within {timeout_s} s")
        return result


def open_client(endpoint: str) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


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

    def start(self, name: str, *args: str) -> subprocess.Popen:
        flags = [] if name == "router" else self.flags
        with (self.log_dir / f"{name}.log").open("ab") as out:
            p = subprocess.Popen(child_command(*args, *flags), stdout=out, stderr=subprocess.STDOUT,
                                 stdin=subprocess.DEVNULL, start_new_session=True)
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

    def start_agent(self, robot: str, *extra: str) -> subprocess.Popen:
        return self.start(f"agent-{robot}", "agent", "--robot", robot, "--fleet", self.scenario.fleet, *extra)

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
