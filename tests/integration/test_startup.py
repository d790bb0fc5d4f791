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
