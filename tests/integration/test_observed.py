"""The harness's reading of simfleet's truth (conftest.halts): which expiry is each robot's halt.

No process: the truth messages are made here (the module is under tests/integration/ with the harness)."""

from vsfleet.wire import Keys, TruthMsg

from .conftest import Observed, halts

TTL_S = 0.3


def observed(*messages) -> Observed:
    """An Observed fed (robot, why, why_t, expired_t) truth messages in order."""
    obs = Observed(Keys("t"))
    for robot, why, why_t, expired_t in messages:
        obs._reasons(robot, TruthMsg(why_t, 0.0, 0.0, 0.0, 0.0, 0.0, why=why, why_t=why_t, expired_t=expired_t))
    return obs


OBS = observed(
    ("r1", "commanded", 100.0, 0.0), ("r2", "commanded", 100.0, 0.0), ("r3", "commanded", 100.0, 0.0),
    ("robot-4", "commanded", 100.0, 0.0), ("robot-4", "expired", 101.0, 101.0),
    ("r2", "expired", 104.9, 104.9), ("r3", "expired", 104.0, 104.0), ("r3", "commanded", 104.1, 104.0),
    ("r1", "expired", 105.29, 105.29), ("r3", "expired", 105.291, 105.291),
)


def test_a_robot_commanded_at_the_fault_halts_at_its_next_expiry():
    h = halts(OBS, 105.0, TTL_S)
    assert h["r1"] == 105.29
    assert h["r3"] == 105.291  # its earlier expiry was followed by a fresh command


def test_a_robot_whose_command_expired_within_a_ttl_before_the_fault_keeps_that_expiry():
    assert halts(OBS, 105.0, TTL_S)["r2"] == 104.9


def test_a_robot_halted_longer_before_was_not_moving_and_is_absent_and_any_counts_without_a_window():
    assert "robot-4" not in halts(OBS, 105.0, TTL_S)  # expired 4 s before
    assert "r2" not in halts(OBS, 105.3, 0.1)  # 0.4 s before, with a 0.1 s ttl
    assert halts(OBS, 105.0)["robot-4"] == 101.0


def test_an_expiry_missed_while_cut_off_is_learnt_from_the_next_message_that_tells_of_it():
    # the test's session saw r1 commanded, then nothing until it was commanded again; expired_t says when it halted
    obs = observed(("r1", "commanded", 100.0, 0.0), ("r1", "commanded", 103.0, 101.3))
    assert halts(obs, 101.0, TTL_S) == {"r1": 101.3}
    assert obs.why["r1"] == [("commanded", 100.0), ("expired", 101.3), ("commanded", 103.0)]


def test_a_robot_never_commanded_or_not_yet_expired_is_absent():
    obs = observed(("r1", "idle", 100.0, 0.0), ("r2", "commanded", 100.0, 0.0))
    assert halts(obs, 99.0) == {}
