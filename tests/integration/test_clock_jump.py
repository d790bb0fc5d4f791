"""A robot host's own clock jumps 2 s forward, then back (issue 30): the agent's wall clock is moved under it
with libfaketime (Debian's faketime; .ci/run installs it), the only process so moved. The frames it gets are
then 2 s old by its clock: it runs none, says so, and its robot halts within the command ttl; when the clock
comes back it runs them again, and the fleet reaches its goal with the copies agreeing."""

from __future__ import annotations

import glob
import time

import pytest

from vsfleet.analysis import agreement

from .conftest import TTL_S, all_halted, at_goal, commanded_again, halt_bound_s, moving, start_fleet

pytestmark = pytest.mark.integration

LIBFAKETIME = next(iter(sorted(glob.glob("/usr/lib/*/faketime/libfaketime.so.1"))), None)


@pytest.mark.skipif(LIBFAKETIME is None, reason="needs libfaketime (apt-get install faketime)")
def test_an_agent_whose_host_clock_jumps_2_s_ahead_halts_its_robot_says_so_and_resumes_when_it_comes_back(
        fleet, tmp_path):
    offset = tmp_path / "faketime-r1"
    offset.write_text("+0\n")
    env = {"LD_PRELOAD": LIBFAKETIME, "FAKETIME_TIMESTAMP_FILE": str(offset), "FAKETIME_NO_CACHE": "1"}
    start_fleet(fleet, agent_env={"r1": env})
    fleet.observed.wait_for(moving("r1"), timeout_s=20)
    offset.write_text("+2\n")                                    # r1's host clock: 2 s ahead, at once
    t_jump = time.time()
    # its robot halts within the ttl (simfleet's truth: the command expired), and nothing commands it meanwhile
    halted = fleet.observed.wait_for(all_halted(t_jump, robots=("r1",)), timeout_s=halt_bound_s(fleet) + 5)
    n_cmd = sum(1 for _, r, _ in fleet.observed.cmd if r == "r1")
    fleet.observed.wait_for(lambda o: len(o.truth) > 0 and o.truth[-1][0] > t_jump + 2.0, timeout_s=10)
    assert sum(1 for _, r, _ in fleet.observed.cmd if r == "r1") == n_cmd   # no command for 2 s
    offset.write_text("+0\n")                                    # and back
    t_back = time.time()
    again = fleet.observed.wait_for(commanded_again("r1", t_back - 1.0), timeout_s=10)
    log = (fleet.log_dir / "agent-r1.log").read_text()
    assert "stale frame" in log and "clock skew" in log, log[-2000:]   # it said why its robot halted
    fleet.observed.wait_for(at_goal(fleet), timeout_s=60)
    a = agreement([(r, m) for t, r, m in fleet.observed.state if t > t_back + 1.0], min_agents=3)
    print(f"r1 halted at {halted['r1']:.2f} (jump at {t_jump:.2f}, ttl {TTL_S} s); commanded again at {again:.2f}; "
          f"agreement after {a.identical}/{a.frames}")
    assert halted["r1"] - t_jump <= TTL_S + 0.5                  # within the ttl (plus one loaded frame)
    assert a.frames > 30 and a.identical == a.frames
