"""Start-up of a fleet of real agent processes (issue 29): they all start and join, and joining costs O(N)
queries, not one per pair of agents.

The test's session is the router and, like `vsfleet run`, the operator answering ``vs/<fleet>/mission``; a
queryable of its own on ``vs/<fleet>/peer/**`` (it never replies) sees every query an agent sends its peers,
so the test knows whom each one reached. Asking every peer (before issue 29) sent ``peer/*/mission`` and
``peer/*/health``, each reaching all N - 1 other agents. No timing is asserted: bench/loop.py measures
start-up (docs/benchmarks.md).
"""

from __future__ import annotations

import collections
import threading
from pathlib import Path

import pytest

from vsfleet.agent.main import PEERS_ASKED
from vsfleet.wire import encode_mission

from .conftest import DATA, LoopbackFleet, closing, start_fleet

N = 2 * PEERS_ASKED + 2   # each agent asked by 2 (N - 1) = 22 queries when every peer is asked; now by at most 10


def line_scenario(path: Path, n: int) -> Path:
    """tests/data/line-10.toml's fleet with ``n`` robots in a line, 0.3 m apart."""
    head = (DATA / "line-10.toml").read_text().split("[robots.r00]")[0]
    robots = "".join(
        f"[robots.r{i:02d}]\np = [{0.3 * (i - (n - 1) / 2):.3f}, 0.000]\n"
        f"start = [{0.3 * (i - (n - 1) / 2) + (0.01 if i % 2 else -0.01):.3f}, {0.01 if i % 2 else -0.01:.3f}, 1.571]\n\n"
        for i in range(n))
    path.write_text(head + robots)
    return path


@pytest.fixture
def fleet_n(tmp_path: Path, request):
    f = LoopbackFleet(line_scenario(tmp_path / f"line-{N}.toml", N), tmp_path)
    request.node.fleets = [f]
    yield f
    closing(f, request)


def test_agents_start_and_join_and_each_is_asked_a_bounded_number_of_queries(fleet_n):
    fleet, keys = fleet_n, fleet_n.keys
    robots = fleet.mission.robot_ids
    assert len(robots) == N
    lock = threading.Lock()
    peer_gets: list[str] = []           # every selector an agent asked its peers with
    operator_gets = collections.Counter()
    payload = encode_mission(fleet.mission)

    def on_peer_query(query) -> None:
        with lock:
            peer_gets.append(str(query.key_expr))

    def on_mission_query(query) -> None:
        with lock:
            operator_gets["mission"] += 1
        query.reply(keys.mission, payload)

    probes = [fleet.router.declare_queryable(f"{keys.peer()}/**", on_peer_query, complete=False),
              fleet.router.declare_queryable(keys.mission, on_mission_query, complete=True)]
    try:
        start_fleet(fleet, robots=robots, timeout_s=60.0)
        # every agent has run the mission and published its state: joined
        fleet.observed.wait_for(lambda o: {r for _, r, m in o.state if m.mission == 1} >= set(robots), 30.0)
    finally:
        for q in probes:
            q.undeclare()
    with lock:
        gets = list(peer_gets)
    reached = collections.Counter(g.split("/")[3] for g in gets)   # vs/<fleet>/peer/<robot>/<kind>
    print(f"{N} agents: {operator_gets['mission']} operator mission queries, {len(gets)} peer queries; "
          f"asked per agent {dict(sorted(reached.items()))} (every peer asked: {2 * (N - 1)} each, "
          f"{2 * N * (N - 1)} in all)")
    assert operator_gets["mission"] >= 1
    assert not [g for g in gets if "*" in g], gets         # with the operator answering, no get to every peer
    assert set(reached) <= set(robots)
    # each agent asked by the PEERS_ASKED before it, once per kind (a resync after a gap asks health again)
    assert max(reached.values(), default=0) <= 3 * PEERS_ASKED, reached
    assert len(gets) <= 3 * PEERS_ASKED * N < 2 * N * (N - 1)


@pytest.mark.parametrize("spawn", ["fork", "exec"])
def test_thirty_agents_started_as_vsfleet_run_starts_them_all_join_and_agree(spawn):
    """bench/loop.py's fleet of 30 real agents through a `vsfleet router` child, started as `vsfleet run` starts
    them: forked from the fleet's fork server (fleetctl.run.ForkServer), or each its own python. Every agent
    answers (run_loop raises otherwise), none misses a measured frame's command by more than a few, and the copies
    of every frame all ran agree bit for bit. The start-up's speed is bench/loop.py's to measure, not asserted."""
    import sys

    root = str(Path(__file__).resolve().parents[2])
    if root not in sys.path:
        sys.path.insert(0, root)
    from bench.loop import run_loop

    r = run_loop(30, 30.0, 60, log=print, warmup_s=0.5, label=f"startup {spawn}", spawn=spawn)
    print(f"spawn {spawn}: start-up {r.startup_s:.1f} s (all alive {r.alive_s:.1f} s), "
          f"{1e3 * r.startup_cpu_s_per_agent:.0f} ms CPU per agent; missed {r.missed}/{r.frames * r.robots}; "
          f"agree {r.agreed_frames}/{r.all_ran_frames}")
    assert r.robots == 30 and r.startup_cpu_s_per_agent > 0
    assert r.all_ran_frames > 0 and r.agreed_frames == r.all_ran_frames


@pytest.mark.provokes_errors(r"vsfleet\.agent ERROR robot must match")
def test_a_forked_agent_is_its_own_process_with_its_command_line_log_session_and_exit_code(tmp_path):
    """fleetctl.run.Children.start_agent (spawn "fork", vsfleet.zglue.forks): what an exec'd `vsfleet agent` would
    be, seen from outside: the command line in /proc, a session of its own, its output in its log, its exit code,
    SIGTERM handled by the agent; the fork server ends with the last child."""
    import os
    import signal

    from vsfleet.fleetctl.router import free_loopback_port
    from vsfleet.fleetctl.run import STOPPED_CODES, Children, child_command

    children = Children(tmp_path)
    try:
        bad = children.start_agent("agent-bad", ["--robot", "bad/id"])
        assert bad.wait(timeout=30) == 2
        assert "robot must match" in children.last_line("agent-bad")
        # an agent waiting for a router that is not there, until it is told to stop
        args = ["--robot", "r1", "--fleet", "forked", "--mode", "client", "--connect",
                f"tcp/127.0.0.1:{free_loopback_port()}", "--no-multicast-scouting", "--wait"]
        waiting = children.start_agent("agent-r1", args)
        cmdline = [a.decode() for a in Path(f"/proc/{waiting.pid}/cmdline").read_bytes().split(b"\0") if a]
        assert cmdline == child_command("agent", *args)
        assert os.getsid(waiting.pid) == waiting.pid and waiting.poll() is None
        server = children.forks.proc
        waiting.send_signal(signal.SIGTERM)
        assert waiting.wait(timeout=30) in STOPPED_CODES
        assert children.stop(["agent-r1"])  # every child has ended: so does the fork server
        assert children.forks is None and server.wait(timeout=10) == 0
    finally:   # a failed assertion leaves no agent behind (one waited for its router for good, 2026-12-07)
        children.stop()
