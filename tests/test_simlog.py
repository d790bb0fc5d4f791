"""The test harness's reading of simfleet's command log (tests/integration/simlog.py)."""

from tests.integration.simlog import halts

TTL_S = 0.3
LOG = """\
10:00:00 INFO r1: commanded again at t=100.000 (seq 1)
10:00:00 INFO r2: commanded again at t=100.000 (seq 1)
10:00:00 INFO r3: commanded again at t=100.000 (seq 1)
10:00:00 INFO robot-4: commanded again at t=100.000 (seq 1)
10:00:00 INFO robot-4: command expired at t=101.000 (last seq 20, arrived 100.700, ttl 0.300): halting
10:00:01 INFO r2: command expired at t=104.900 (last seq 140, arrived 104.600, ttl 0.300): halting
10:00:01 INFO r3: command expired at t=104.000 (last seq 110, arrived 103.700, ttl 0.300): halting
10:00:01 INFO r3: commanded again at t=104.100 (seq 113)
10:00:02 INFO r1: command expired at t=105.290 (last seq 150, arrived 104.990, ttl 0.300): halting
10:00:02 INFO r3: command expired at t=105.291 (last seq 150, arrived 104.991, ttl 0.300): halting
"""


def test_a_robot_commanded_at_the_fault_halts_at_its_next_expiry():
    h = halts(LOG, 105.0, TTL_S)
    assert h["r1"] == 105.290
    assert h["r3"] == 105.291  # its earlier expiry was followed by a fresh command


def test_a_robot_whose_command_expired_within_a_ttl_before_the_fault_keeps_that_expiry():
    assert halts(LOG, 105.0, TTL_S)["r2"] == 104.900


def test_a_robot_halted_longer_before_was_not_moving_and_is_absent():
    assert "robot-4" not in halts(LOG, 105.0, TTL_S)     # expired 4 s before
    assert "r2" not in halts(LOG, 105.3, 0.1)            # 0.4 s before, with a 0.1 s ttl


def test_the_first_expiry_after_the_time_counts_and_a_robot_that_never_expired_is_absent():
    assert halts(LOG, 103.0, TTL_S) == {"r1": 105.290, "r2": 104.900, "r3": 104.000}  # robot-4: at 101
    assert halts(LOG.replace("r1: command expired", "r1: x"), 105.0, TTL_S).keys() == {"r2", "r3"}


def test_a_half_written_line_is_not_read():
    assert halts("r1: commanded again at t=100.000 (seq 1)\nr1: command expired at t=105.2", 105.0, TTL_S) == {}


def test_without_a_ttl_window_any_earlier_expiry_not_renewed_counts():
    assert halts(LOG, 105.0)["robot-4"] == 101.000
    assert halts(LOG, 105.0)["r3"] == 105.291
