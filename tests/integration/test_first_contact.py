"""First contact: every `vsfleet` command without a router, with bad arguments, and waiting on purpose.

Each command runs as a real `vsfleet` child (python -m vsfleet.fleetctl.cli). "No router" is a free loopback
port nobody listens on, multicast scouting off, and a 500 ms connect timeout (zenoh retries for it),
so each attempt fails fast; the commands of one table run in parallel.
"""

from __future__ import annotations

import queue
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from vsfleet.fleetctl.router import free_loopback_port, wait_listening
from vsfleet.fleetctl.run import child_command
from vsfleet.zglue.zconf import CONNECT_HINT, START_ROUTER_HINT

from .conftest import Observed, open_client

pytestmark = pytest.mark.integration

ROOT = Path(__file__).parent.parent.parent
TRIANGLE = ROOT / "scenarios" / "paper-triangle.toml"
E2E = ROOT / "tests" / "data" / "e2e-triangle.toml"
CAMERA = ROOT / "deploy" / "camera" / "overhead.toml"


def run_all(commands: dict[str, list[str]], timeout_s: float = 60.0) -> dict[str, subprocess.CompletedProcess]:
    """Run every command at once as a `vsfleet` child; name -> its finished process (stdout, stderr as text)."""
    procs = {name: subprocess.Popen(child_command(*args), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                    stdin=subprocess.DEVNULL, text=True, cwd=ROOT, start_new_session=True)
             for name, args in commands.items()}
    done = {}
    try:
        for name, p in procs.items():
            out, err = p.communicate(timeout=timeout_s)
            done[name] = subprocess.CompletedProcess(p.args, p.returncode, out, err)
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
    return done


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """A floor calibration for the camera tracker and an (empty) recording for replay."""
    tmp = tmp_path_factory.mktemp("first-contact")
    out = {"calibration": tmp / "calibration.json", "mcap": tmp / "empty.mcap", "tmp": tmp}
    pytest.importorskip("cv2")
    sys.path.insert(0, str(ROOT / "tests"))
    from camera_support import save_calibration

    from vsfleet.fleetctl.record import LiveRecorder

    save_calibration(CAMERA, out["calibration"])
    LiveRecorder(out["mcap"]).close()
    return out


def session_commands(files: dict[str, Path]) -> dict[str, list[str]]:
    """Every command that opens a zenoh client session, with arguments that get it as far as opening it."""
    tmp = files["tmp"]
    return {
        "agent": ["agent", "--robot", "r1"],
        "sim": ["sim", str(TRIANGLE)],
        "tracker sim": ["tracker", "sim"],
        "tracker camera": ["tracker", "camera", "--camera", str(CAMERA), "--calibration",
                           str(files["calibration"]), "--source", "render"],
        "render": ["render", "--camera", str(CAMERA), "--out", str(tmp / "render.avi")],
        "monitor": ["monitor"],
        "record": ["record", "--out", str(tmp / "record.mcap")],
        "replay": ["replay", str(files["mcap"])],
        "mission set": ["mission", "set", str(TRIANGLE)],
        "fuzz": ["fuzz", "--duration", "1"],
    }


@pytest.fixture(scope="module")
def no_router(files):
    """Every session command run against a free port nobody listens on: (endpoint, name -> result)."""
    endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
    flags = ["--connect", endpoint, "--no-multicast-scouting", "--cfg", "connect/timeout_ms:500"]
    cmds = {name: [*args, *flags] for name, args in session_commands(files).items()}
    cmds["agent, no endpoint"] = ["agent", "--robot", "r1", "--no-multicast-scouting"]
    return endpoint, run_all(cmds)


NO_ROUTER_CASES = ["agent", "sim", "tracker sim", "tracker camera", "render", "monitor", "record", "replay",
                   "mission set", "fuzz"]


@pytest.mark.parametrize("name", NO_ROUTER_CASES)
def test_a_command_without_a_router_says_so_in_one_line_naming_the_endpoint_and_exits_2(no_router, name):
    endpoint, results = no_router
    r = results[name]
    output = r.stdout + r.stderr
    lines = [line for line in output.splitlines() if line.strip()]
    assert r.returncode == 2, output
    assert "Traceback" not in output
    assert len(lines) == 1, output
    line = lines[0]
    assert line.startswith(f"vsfleet {name}: no zenoh router reachable"), line
    assert f"mode client, tried {endpoint}" in line
    assert START_ROUTER_HINT in line and CONNECT_HINT in line and "--wait" in line


def test_a_client_with_no_endpoint_and_no_scouting_says_it_had_nowhere_to_look(no_router):
    _, results = no_router
    r = results["agent, no endpoint"]
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stdout + r.stderr
    assert r.stderr.strip().splitlines() == [
        f"vsfleet agent: no zenoh router reachable (mode client, no --connect endpoint and multicast scouting off); "
        f"{START_ROUTER_HINT}, {CONNECT_HINT}, or add --wait to wait for it"]


# command -> (arguments, a fragment the error line must hold)
BAD_ARGUMENTS = {
    "agent": (["agent", "--robot", "bad/name"], "robot must match"),
    "agent, unknown flag": (["agent", "--robot", "r1", "--bogus"], "unrecognized arguments: --bogus"),
    "agent, bad --cfg": (["agent", "--robot", "r1", "--cfg", "no_such_key:1"], "--cfg no_such_key:1"),
    "agent, missing --config": (["agent", "--robot", "r1", "--config", "/nonexistent/robot.json5"],
                                "cannot read the zenoh config /nonexistent/robot.json5"),
    "sim": (["sim", "/nonexistent/scenario.toml"], "/nonexistent/scenario.toml"),
    "tracker sim": (["tracker", "sim", "--rate", "-1"], "rate must be > 0"),
    "tracker camera": (["tracker", "camera", "--camera", "/nonexistent/cam.toml", "--calibration", "c.json",
                        "--source", "render"], "/nonexistent/cam.toml"),
    "tracker calibrate": (["tracker", "calibrate", "--camera", "/nonexistent/cam.toml", "--source", "x.png",
                           "--out", "/nonexistent/c.json"], "/nonexistent/cam.toml"),
    "render": (["render", "--camera", "/nonexistent/cam.toml", "--out", "/nonexistent/x.avi"],
               "/nonexistent/cam.toml"),
    "run": (["run", "/nonexistent/scenario.toml"], "/nonexistent/scenario.toml"),
    "router": (["router", "--mode", "peer"], "runs a router"),
    "deploy config": (["deploy", "config", "/nonexistent/fleet.toml", "--router", "tcp/10.0.0.1:7447",
                       "--out", "/nonexistent/site"], "/nonexistent/fleet.toml"),
    "mission set": (["mission", "set", "/nonexistent/mission.toml"], "/nonexistent/mission.toml"),
    "record": (["record", "--out", "/nonexistent/r.mcap", "--key", "vs/a**"], "vs/a**"),
    "replay": (["replay", "/nonexistent/r.mcap"], "/nonexistent/r.mcap"),
    "plot": (["plot", "/nonexistent/r.mcap"], "/nonexistent/r.mcap"),
    "monitor": (["monitor", "--fleet", "bad/name"], "fleet must match"),
    "fuzz": (["fuzz", "--kinds", "bogus"], "--kinds must be"),
    "no such command": (["frobnicate"], "unknown command 'frobnicate'"),
}


@pytest.fixture(scope="module")
def bad_arguments():
    return run_all({name: args for name, (args, _) in BAD_ARGUMENTS.items()})


@pytest.mark.parametrize("name", list(BAD_ARGUMENTS))
def test_a_command_with_bad_arguments_exits_2_with_a_clear_line_and_no_traceback(bad_arguments, name):
    r = bad_arguments[name]
    output = r.stdout + r.stderr
    assert r.returncode == 2, output
    assert "Traceback" not in output
    fragment = BAD_ARGUMENTS[name][1]
    assert any(fragment in line for line in output.splitlines()), output


def test_a_router_whose_port_is_taken_says_so_in_one_line_and_exits_2(tmp_path):
    port = free_loopback_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    with (tmp_path / "router.log").open("wb") as log:
        first = subprocess.Popen(child_command("router", "--listen", endpoint, "--no-multicast-scouting"),
                                 stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                 start_new_session=True)
    try:
        wait_listening(port, 20.0)
        r = run_all({"second": ["router", "--listen", endpoint, "--no-multicast-scouting"]})["second"]
    finally:
        first.send_signal(signal.SIGTERM)
        first.wait(timeout=10)
    output = r.stdout + r.stderr
    assert r.returncode == 2, output
    assert "Traceback" not in output
    assert output.strip().splitlines() == [output.strip()], output
    assert f"cannot start a zenoh router (mode router, listening on {endpoint})" in output
    assert "Address already in use" in output


class Lines:
    """A child's stderr, line by line, on a reader thread; wait_for blocks until a line holds a fragment."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.lines: queue.Queue = queue.Queue()
        self.seen: list[str] = []
        threading.Thread(target=self._read, args=(proc.stderr,), daemon=True).start()

    def _read(self, stream) -> None:
        for line in stream:
            self.lines.put(line)
        self.lines.put(None)

    def wait_for(self, fragment: str, timeout_s: float) -> str:
        while True:
            line = self.lines.get(timeout=timeout_s)
            if line is None:
                raise EOFError(f"stream ended before {fragment!r}: {''.join(self.seen)}")
            self.seen.append(line)
            if fragment in line:
                return line


def start_waiting(*args: str) -> tuple[subprocess.Popen, Lines]:
    p = subprocess.Popen(child_command(*args), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         stdin=subprocess.DEVNULL, text=True, cwd=ROOT, start_new_session=True)
    return p, Lines(p)


def test_agents_started_with_wait_before_the_router_connect_when_it_comes_up_and_run_the_fleet(tmp_path):
    port = free_loopback_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    flags = ["--connect", endpoint, "--no-multicast-scouting"]
    procs: dict[str, subprocess.Popen] = {}
    observer = None
    try:
        for r in ("r1", "r2", "r3"):
            procs[r], lines = start_waiting("agent", "--robot", r, "--fleet", "e2e", "--wait", *flags)
            lines.wait_for("waiting for a zenoh router", timeout_s=30)  # it got to the session, and waits
        assert all(p.poll() is None for p in procs.values()), "an agent gave up waiting"
        with (tmp_path / "fleet.log").open("wb") as log:
            for name, args in (("router", ["router", "--listen", endpoint, "--no-multicast-scouting"]),
                               ("sim", ["sim", str(E2E), *flags]),
                               ("tracker", ["tracker", "sim", "--fleet", "e2e", *flags])):
                procs[name] = subprocess.Popen(child_command(*args), stdout=log, stderr=subprocess.STDOUT,
                                               stdin=subprocess.DEVNULL, start_new_session=True)
                if name == "router":
                    wait_listening(port, 20.0)
        from vsfleet.wire import Keys

        keys = Keys("e2e")
        observed = Observed(keys)
        observer = open_client(endpoint)
        subs = [observer.declare_subscriber(keys.everything, observed.on_sample),
                observer.liveliness().declare_subscriber(keys.alive(), observed.on_liveliness, history=True)]
        want = {keys.alive("agent", r) for r in ("r1", "r2", "r3")}
        observed.wait_for(lambda o: want <= o.alive, timeout_s=30)
        r = run_all({"mission": ["mission", "set", str(E2E), "--fleet", "e2e", *flags]})["mission"]
        assert r.returncode == 0, r.stderr

        def every_robot_driven(o: Observed) -> bool:  # each waiting agent now commands its robot, which moves
            driven = {robot for _, robot, m in o.cmd[-300:] if abs(m.vl) + abs(m.vr) > 0.02}
            moving = {robot for _, robot, m in o.truth[-300:] if abs(m.vl) + abs(m.vr) > 0.02}
            return driven == moving == {"r1", "r2", "r3"}

        observed.wait_for(every_robot_driven, timeout_s=30)
        for s in subs:
            s.undeclare()
    finally:
        if observer is not None:
            observer.close()
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs.values():
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
    assert [procs[r].returncode for r in ("r1", "r2", "r3")] == [0, 0, 0]


def test_a_waiting_agent_logs_every_few_seconds_and_sigterm_stops_it_with_code_0_in_one_line():
    endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
    p, lines = start_waiting("agent", "--robot", "r1", "--wait", "--connect", endpoint, "--no-multicast-scouting")
    try:
        lines.wait_for("waiting for a zenoh router", timeout_s=30)
        lines.wait_for("still waiting for a zenoh router", timeout_s=30)  # logged again 5 s later
        assert p.poll() is None
        p.send_signal(signal.SIGTERM)
        last = lines.wait_for("stopped by SIGTERM", timeout_s=10)
        assert p.wait(timeout=10) == 0
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
        print("".join(lines.seen))  # shown if the test fails
    assert last.strip() == f"vsfleet agent: stopped by SIGTERM while waiting for a zenoh router (mode client, at {endpoint})"
    assert not any("Traceback" in line for line in lines.seen)


def test_run_names_the_child_that_exited_early_with_its_one_line_error(tmp_path):
    from vsfleet.fleetctl.run import Children

    children = Children(tmp_path)
    p = children.start("agent-r1", [sys.executable, "-c",
                                    "print('starting'); print('vsfleet agent: no zenoh router reachable'); "
                                    "raise SystemExit(2)"])
    assert p.wait(timeout=30) == 2
    assert children.dead() == ["agent-r1"]
    assert children.last_line("agent-r1") == "vsfleet agent: no zenoh router reachable"


STOP_WHILE_LOCKED = """
import os, signal
from vsfleet.zglue.lifecycle import StopFlag
flag = StopFlag()
with flag.event._cond:  # as the main thread holds it inside Event.wait, between taking it and waiting
    os.kill(os.getpid(), signal.SIGTERM)
    for _ in range(100_000):  # the signal handler runs here, with the lock held
        pass
print("stopping" if flag.wait(5.0) else "not stopped", flush=True)
"""


def test_sigterm_while_the_main_thread_holds_the_stop_flags_lock_stops_the_program():
    # the handler used to set the event itself, taking the lock the main thread held: a deadlock
    out = subprocess.run([sys.executable, "-c", STOP_WHILE_LOCKED], capture_output=True, text=True, timeout=20)
    assert out.returncode == 0 and out.stdout.strip() == "stopping", out
