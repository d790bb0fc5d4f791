"""vsfleet.quorum: an answer counts only if a strict majority of the distinct peers that replied gave it."""

import pytest

from vsfleet.quorum import majority


@pytest.mark.parametrize("answers, winner", [
    ([("r2", b"A")], b"A"),                                       # the only peer
    ([("r2", b"A"), ("r3", b"A")], b"A"),
    ([("r2", b"A"), ("r3", b"A"), ("r4", b"B")], b"A"),
    ([("r2", b"A"), ("r2", b"A"), ("r3", b"B"), ("r4", b"A")], b"A"),   # a repeated reply counts once
    ([("r2", b"A"), ("r3", b"A"), ("r3", b"B")], b"A"),          # r3 twice, differently: supports both
    ([("r2", b"A"), ("r3", None), ("r4", b"A")], b"A"),          # an invalid answer still counts as a peer
])
def test_the_answer_of_a_strict_majority_wins(answers, winner):
    v = majority(answers)
    assert v.answer == winner and v.why == ""


@pytest.mark.parametrize("answers, why", [
    ([], "no peer answered"),
    ([("r2", b"A"), ("r3", b"B")], "no answer has a strict majority of the 2 peers"),
    ([("r2", b"A"), ("r3", b"B"), ("r4", b"C")], "at most 1 agree"),
    ([("r2", b"A"), ("r3", b"B"), ("r3", b"B"), ("r3", b"B")], "no answer has a strict majority"),  # stuffing
    ([("r2", None)], "invalid from ['r2']"),
    ([("r2", b"A"), ("r2", b"B")], "gave conflicting answers"),  # one peer, two answers: neither
    ([("r2", b"A"), ("r2", b"B"), ("r3", b"A"), ("r3", b"B")], "gave conflicting answers"),
])
def test_without_a_single_majority_answer_nothing_is_taken_and_the_verdict_says_why(answers, why):
    v = majority(answers)
    assert v.answer is None and why in v.why
