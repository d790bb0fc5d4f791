"""`vsfleet run` as a user runs it: progress, Ctrl-C, a child that dies, the run record."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import uuid
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration

E2E = Path(__file__).parent.parent / "data" / "e2e-triangle.toml"


def fleet_pids(fleet: str) -> dict[str, int]:
    """Processes of this fleet's children, by their role, from /proc (Linux)."""
    out = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            argv = (d / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        args = [a.decode(errors="replace") for a in argv if a]
        if "vsfleet.fleetctl.cli" in args and fleet in args and "run" not in args:
            role = args[args.index("vsfleet.fleetctl.cli") + 1]
            if role == "agent":
                role = "agent-" + args[args.index("--robot") + 1]
            out[role] = int(d.name)
    return out


class Launcher:
    def __init__(self, tmp_path: Path, *extra: str) -> None:
        self.fleet = "t" + uuid.uuid4().hex[:8]
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "vsfleet.fleetctl.cli", "run", str(E2E), "--fleet", self.fleet,
             "--out", str(tmp_path), *extra],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, stdin=subprocess.DEVNULL,
            env=dict(os.environ, PYTHONUNBUFFERED="1"))
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.put(line)

    def wait_line(self, needle: str, timeout_s: float) -> str:
        while True:
            line = self.lines.get(timeout=timeout_s)
            self.seen.append(line)
            if needle in line:
                return line

    def finish(self, timeout_s: float = 20.0) -> str:
        self.proc.wait(timeout=timeout_s)
        while not self.lines.empty():
            self.seen.append(self.lines.get())
        return "".join(self.seen)


@pytest.fixture
def launcher_factory(tmp_path):
    made = []

    def make(*extra):
        launcher = Launcher(tmp_path, *extra)
        made.append(launcher)
        return launcher

    yield make
    for launcher in made:
        if launcher.proc.poll() is None:
            launcher.proc.kill()
            launcher.proc.wait()
        for pid in fleet_pids(launcher.fleet).values():
            os.kill(pid, signal.SIGKILL)


def test_ctrl_c_stops_every_process_and_still_writes_the_run(launcher_factory, tmp_path):
    run = launcher_factory("--duration", "120")
    run.wait_line("structure (", timeout_s=30)  # a progress line: the fleet is moving
    children = fleet_pids(run.fleet)
    assert set(children) == {"sim", "tracker", "agent-r1", "agent-r2", "agent-r3"}
    run.proc.send_signal(signal.SIGINT)
    out = run.finish()
    assert run.proc.returncode == 0, out
    assert "run ended: interrupted" in out
    assert "paper, real R3 robots" in out
    assert fleet_pids(run.fleet) == {}
    assert list(tmp_path.glob("*/e2e-triangle/summary.json"))


def test_a_child_that_dies_ends_the_run_with_an_error_and_stops_the_rest(launcher_factory):
    run = launcher_factory("--duration", "120")
    run.wait_line("structure (", timeout_s=30)
    os.kill(fleet_pids(run.fleet)["sim"], signal.SIGKILL)
    out = run.finish()
    assert run.proc.returncode == 1, out
    assert "child exited early: sim" in out
    assert fleet_pids(run.fleet) == {}
