"""A bounded soak: `vsfleet fuzz` floods every subscribed key with invalid messages at 10x the
tracker's rate while the fleet runs. Nothing crashes, every rejection is counted, no robot moves
on an invalid command, and the fleet keeps formation."""

from __future__ import annotations

import json

import pytest

from .conftest import ROBOTS, LoopbackFleet, at_goal, max_state_err_m, moving, start_fleet

pytestmark = pytest.mark.integration


def fuzz(fleet: LoopbackFleet, kinds: str, duration_s: float) -> dict:
    """Run the fuzzer to the end; returns its summary line."""
    p = fleet.start("fuzz", "fuzz", "--fleet", fleet.keys.fleet, "--kinds", kinds, "--rate", "300",
                    "--duration", str(duration_s), "--robots", ",".join(ROBOTS))
    assert p.wait(timeout=duration_s + 60) == 0, fleet.logs()
    line = next(ln for ln in reversed((fleet.log_dir / "fuzz.log").read_text().splitlines())
                if ln.startswith("{"))
    summary = json.loads(line)
    assert summary["routed"] is True  # the router routed every put before the fuzzer closed
    return summary


def sim_rejected(fleet: LoopbackFleet, expected: int, timeout_s: float = 20.0) -> int:
    """simfleet's count of rejected messages as its truth tells it: waits until it reaches ``expected``
    (or the timeout), returns the newest count."""
    newest = lambda o: o.truth[-1][2].rejected if o.truth else -1  # noqa: E731
    try:
        fleet.observed.wait_for(lambda o: newest(o) >= expected, timeout_s)
    except TimeoutError:
        pass
    return newest(fleet.observed)


def test_a_fleet_under_a_flood_of_invalid_messages_counts_every_one_and_keeps_formation(fleet):
    start_fleet(fleet)
    fleet.observed.wait_for(moving("r1"), timeout_s=20)
    summary = fuzz(fleet, "frame,pose,mission,fault,cmd", duration_s=4.0)
    sent = summary["sent"]
    for_agents = summary["by_kind"]["frame"] + summary["by_kind"]["mission"]  # agents read no pose/<robot>
    for_sim = summary["by_kind"]["cmd"] + summary["by_kind"]["fault"]

    def counted(o):
        latest = {r: m.rejected for _, r, m in o.state}
        return latest if len(latest) == 3 and all(n == for_agents for n in latest.values()) else None

    try:
        fleet.observed.wait_for(counted, timeout_s=20)
    finally:
        latest = {r: m.rejected for _, r, m in fleet.observed.state}
        print(f"fuzzer sent {sum(sent.values())} invalid messages ({summary['by_kind']}); "
              f"agents counted {latest} of {for_agents}")
    fleet.observed.wait_for(at_goal(fleet), timeout_s=40)
    for name, p in fleet.procs.items():
        if name != "fuzz":
            assert p.poll() is None, f"{name} died:\n{fleet.logs()}"
    err = max_state_err_m(fleet.observed)
    got_sim = sim_rejected(fleet, for_sim)
    print(f"max error {err * 100:.2f} cm; simfleet counted {got_sim} of {for_sim}")
    assert got_sim == for_sim
    assert err < 0.025


def test_no_robot_moves_on_an_invalid_command(fleet):
    fleet.start_sim_and_tracker()
    fleet.wait_alive("sim", ("simfleet",))
    fleet.observed.wait_for(lambda o: len(o.truth) > 30, timeout_s=20)
    start = {r: (m.x, m.y, m.th) for _, r, m in fleet.observed.truth}
    n_before = len(fleet.observed.truth)
    summary = fuzz(fleet, "cmd,fault", duration_s=2.0)
    fleet.observed.wait_for(lambda o: len(o.truth) > n_before + 100, timeout_s=20)
    during = fleet.observed.truth[n_before:]
    assert all(m.vl == 0.0 and m.vr == 0.0 and m.why == "idle" for _, _, m in during)  # never commanded
    assert all((m.x, m.y, m.th) == start[r] for _, r, m in during)
    for_sim = summary["by_kind"]["cmd"] + summary["by_kind"]["fault"]
    assert sim_rejected(fleet, for_sim) == for_sim
