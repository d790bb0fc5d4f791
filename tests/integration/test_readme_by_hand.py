"""The README's "Running a fleet by hand" recipe, run as written (its commands are parsed from README.md).

The only change is the port: 7447 becomes a free loopback port, so the test cannot meet another router.
Each long-running command is started once the previous one is up (the router listens, the sim's, the
tracker's and each agent's liveliness token is seen), as a person at the terminals would; `mission set`
runs to completion. The test then waits until the truth-fitted structure settles at the mission's goal.
"""

from __future__ import annotations

import re
import shlex
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from vsfleet.fleetctl.router import free_loopback_port, wait_listening
from vsfleet.fleetctl.run import SETTLE_S, Recorder, child_command, settled_at_goal
from vsfleet.zglue.scenario_file import load_scenario
from vsfleet.wire import Keys

from .conftest import Observed, open_client

pytestmark = pytest.mark.integration

ROOT = Path(__file__).parent.parent.parent
README = ROOT / "README.md"
SECTION = "## Running a fleet by hand"


def recipe_commands(readme: str) -> list[list[str]]:
    """The `vsfleet ...` lines of the first code block in the README's by-hand section, split into words."""
    section = readme.split(SECTION, 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```\n(.*?)```", section, re.S).group(1)
    return [shlex.split(line, comments=True) for line in block.splitlines() if line.strip().startswith("vsfleet ")]


def test_the_recipe_names_a_router_sim_tracker_an_agent_per_robot_monitor_and_mission_set():
    cmds = recipe_commands(README.read_text())
    subcommands = [" ".join(c[1:3]) if c[1] in ("tracker", "mission") else c[1] for c in cmds]
    assert subcommands[:3] == ["router", "sim", "tracker sim"]
    scenario = load_scenario(ROOT / cmds[1][2])
    robots = [c[c.index("--robot") + 1] for c in cmds if c[1] == "agent"]
    assert sorted(robots) == sorted(scenario.mission.robot_ids)
    assert {"monitor", "mission set"} <= set(subcommands)
    for c in cmds[1:]:  # every client names the router's endpoint
        assert c[c.index("--connect") + 1] == cmds[0][cmds[0].index("--listen") + 1]


def executable(words: list[str]) -> list[str]:
    """``vsfleet ARGS`` as this venv's vsfleet script (else the same entry point through python -m)."""
    script = Path(sys.executable).with_name("vsfleet")
    return [str(script), *words[1:]] if script.exists() else child_command(*words[1:])


def test_the_readme_recipe_run_as_written_brings_the_structure_to_the_goal(tmp_path):
    port = free_loopback_port()
    cmds = [[w.replace(":7447", f":{port}") for w in c] for c in recipe_commands(README.read_text())]
    scenario = load_scenario(ROOT / cmds[1][2])
    keys = Keys(scenario.fleet)
    endpoint = f"tcp/127.0.0.1:{port}"
    procs: dict[str, subprocess.Popen] = {}
    observer, subs = None, []
    observed, recorder = Observed(keys), Recorder()

    def on_sample(sample) -> None:
        observed.on_sample(sample)
        recorder.on_sample(sample)

    try:
        for words in cmds:
            name = " ".join(words[1:4])
            if words[1:3] == ["mission", "set"]:
                r = subprocess.run(executable(words), capture_output=True, text=True, cwd=ROOT, timeout=60,
                                   stdin=subprocess.DEVNULL)
                assert r.returncode == 0, r.stdout + r.stderr
                continue
            out = (tmp_path / f"{len(procs)}-{words[1]}.log").open("wb")
            procs[name] = subprocess.Popen(executable(words), stdout=out, stderr=subprocess.STDOUT, cwd=ROOT,
                                           stdin=subprocess.DEVNULL, start_new_session=True)
            out.close()
            if words[1] == "router":
                wait_listening(port, 20.0)
                observer = open_client(endpoint)
                subs = [observer.declare_subscriber(keys.everything, on_sample),
                        observer.liveliness().declare_subscriber(keys.alive(), observed.on_liveliness,
                                                                 history=True)]
                continue
            role = {"sim": "sim", "tracker": "tracker", "agent": "agent"}.get(words[1])
            if role is not None:  # up when its liveliness token is seen
                ident = words[words.index("--robot") + 1] if role == "agent" else None
                prefix = keys.alive(role, ident) if ident else keys.alive(role, "")
                observed.wait_for(lambda o: any(k.startswith(prefix) for k in o.alive), timeout_s=30)
        assert all(p.poll() is None for p in procs.values()), {n: p.poll() for n, p in procs.items()}
        reached, deadline = threading.Event(), scenario.duration_s + 30
        for _ in range(int(deadline / 0.5)):  # check twice a second (pacing the check, not synchronising)
            if settled_at_goal(scenario.mission, recorder, keys, SETTLE_S):
                reached.set()
                break
            reached.wait(0.5)
        assert reached.is_set(), "the structure did not settle at the goal: " + "\n".join(
            f"--- {f.name}\n{f.read_text(errors='replace')[-1500:]}" for f in sorted(tmp_path.glob("*.log")))
        assert all(p.poll() is None for p in procs.values()), {n: p.poll() for n, p in procs.items()}
    finally:
        for s in subs:
            s.undeclare()
        if observer is not None:
            observer.close()
        for p in reversed(list(procs.values())):  # as Ctrl-C in each terminal, the router last
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
    monitor = next(n for n in procs if n.startswith("monitor"))
    assert procs[monitor].returncode == 0
    monitor_out = next(tmp_path.glob("*-monitor.log")).read_text(errors="replace")
    assert "Traceback" not in monitor_out
    assert all(r in monitor_out for r in scenario.mission.robot_ids), monitor_out[-2000:]
