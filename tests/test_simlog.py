"""The test harness's reading of simfleet's command log (tests/integration/simlog.py)."""

from tests.integration.simlog import halts

LOG = """\
10:00:00 INFO r1: commanded again at t=100.000 (seq 1)
10:00:00 INFO r2: commanded again at t=100.000 (seq 1)
10:00:00 INFO r3: commanded again at t=100.000 (seq 1)
10:00:01 INFO r2: command expired at t=104.900 (last seq 140, arrived 104.600, ttl 0.300): halting
10:00:01 INFO r3: command expired at t=104.000 (last seq 110, arrived 103.700, ttl 0.300): halting
10:00:01 INFO r3: commanded again at t=104.100 (seq 113)
10:00:02 INFO r1: command expired at t=105.290 (last seq 150, arrived 104.990, ttl 0.300): halting
10:00:02 INFO r3: command expired at t=105.291 (last seq 150, arrived 104.991, ttl 0.300): halting
"""


def test_a_robot_commanded_at_the_fault_halts_at_its_next_expiry():
    h = halts(LOG, 105.0)
    assert h["r1"] == 105.290
    assert h["r3"] == 105.291  # its earlier expiry was followed by a fresh command


def test_a_robot_already_halted_at_the_fault_keeps_that_earlier_expiry():
    assert halts(LOG, 105.0)["r2"] == 104.900


def test_the_first_expiry_after_the_time_counts_and_a_robot_that_never_expired_is_absent():
    assert halts(LOG, 103.0) == {"r1": 105.290, "r2": 104.900, "r3": 104.000}
    assert halts(LOG.replace("r1: command expired", "r1: x"), 105.0).keys() == {"r2", "r3"}
