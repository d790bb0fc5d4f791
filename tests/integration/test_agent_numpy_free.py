"""The agent process does not load numpy (issue 29): its frames run in the compiled core with its state in plain
buffers (vsfleet.agentcore, vsfleet.buffers), and numpy stays the reference's and the tools'.

tests/numpy_free_agent.py drives an Agent through two missions (fast and long-way frames, a second source, a
gap and a resync, the peers' health adopted, a room with bodies and an obstacle, failures and drops, the stop)
in a process where importing numpy or scipy raises. What it sends must be what an agent whose frames go through
vsfleet.step's numpy glue (the core's kernels one by one) sends on the same frames, byte for byte. And the agents of a live fleet (real processes over loopback zenoh) have
no numpy mapped once they drive their robots."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from numpy_free_agent import drive
from vsfleet.wire import decode_event

from .conftest import start_fleet

pytestmark = pytest.mark.integration

HERE = Path(__file__).resolve().parent.parent


def test_an_agent_runs_missions_without_numpy_and_sends_the_bytes_of_the_numpy_glue():
    run = subprocess.run([sys.executable, str(HERE / "numpy_free_agent.py")], capture_output=True, text=True,
                         timeout=120, cwd=HERE)
    assert run.returncode == 0, run.stderr[-3000:]
    got = json.loads(run.stdout)
    assert not got["numpy"] and not got["scipy"]
    assert got["ways"]["fast"] > 100 and got["ways"]["long"] > 20, got["ways"]
    assert got["phase"] == "synced" and got["rejected"] == 0
    want = drive(glue=True)   # every frame the long way, through the numpy glue
    assert want["ways"]["fast"] == 0
    assert got["ticks"] == want["ticks"] > 250
    for kind in ("cmd", "state", "event", "stop"):
        assert got["sent"][kind] == want["sent"][kind], kind
    # the adopted failure's recovery, then the robot standing still in the room failed and dropped
    kinds = [(e.robot, e.kind) for e in (decode_event(bytes.fromhex(h)) for h in got["sent"]["event"])]
    assert kinds[0] == ("r2", "recover") and ("r3", "fail") in kinds and ("r3", "drop") in kinds, kinds


def test_the_agent_processes_of_a_live_fleet_have_no_numpy_mapped(fleet):
    start_fleet(fleet)
    t0 = fleet.observed.wait_for(lambda obs: obs.state[-1][0] if obs.state else None, timeout_s=10)
    # a second's frames more: every agent has run frames of the mission in both of its ways by then
    fleet.observed.wait_for(lambda obs: sum(1 for t, _r, _m in obs.state if t > t0 + 1.0) >= 3, timeout_s=10)
    for name, proc in fleet.procs.items():
        if not name.startswith("agent-"):
            continue
        assert proc.poll() is None, name
        maps = Path(f"/proc/{proc.pid}/maps").read_text()
        assert "_core" in maps                      # the compiled core is there: the maps are the agent's
        assert "numpy" not in maps and "scipy" not in maps, name


def test_the_fork_server_of_vsfleet_run_imports_what_it_preloads_for_agents_without_numpy():
    """`vsfleet run` forks its agents from a server that imported AGENT_PRELOAD first: a forked agent holds what
    the server imported, so that must not be numpy either."""
    from vsfleet.fleetctl.run import AGENT_PRELOAD
    code = ("import importlib, sys, numpy_free_agent\n"
            "sys.meta_path.insert(0, numpy_free_agent._Refuse())\n"
            f"for m in {list(AGENT_PRELOAD)!r}:\n    importlib.import_module(m)\n"
            "print('numpy' in sys.modules, 'scipy' in sys.modules)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=HERE)
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.split() == ["False", "False"]
