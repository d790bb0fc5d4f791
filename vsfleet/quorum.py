"""Majority of peers: which answer to a query an agent may believe (docs/protocol.md).

Any one login can answer a query with false content; the router's access
control only guarantees that agent ``rN`` answers under its own key. So an
agent that asks its peers (for the mission, or for their failure state) takes
an answer only if a strict majority of the distinct peers that replied gave
it. A peer that replied several times (two sessions with one login) supports
each answer it gave; if that leaves more than one answer with a majority,
none is taken.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Hashable, Iterable


@dataclass(frozen=True)
class Verdict:
    """The answer a strict majority of ``peers`` gave (None if there is none) and, if none, why."""

    answer: Hashable | None
    supporters: tuple[str, ...]
    peers: tuple[str, ...]
    why: str = ""


def majority(answers: Iterable[tuple[str, Hashable | None]]) -> Verdict:
    """``answers``: (peer id, answer) pairs; an answer of None is an invalid one and never wins.

    Returns the answer given by more than half of the distinct peers that replied.
    """
    by_peer: dict[str, set] = {}
    for peer, answer in answers:
        by_peer.setdefault(peer, set()).add(answer)
    peers = tuple(sorted(by_peer))
    if not peers:
        return Verdict(None, (), (), "no peer answered")
    support: dict[Hashable, list[str]] = {}
    for peer in peers:
        for answer in by_peer[peer]:
            if answer is not None:
                support.setdefault(answer, []).append(peer)
    winners = [(a, s) for a, s in support.items() if 2 * len(s) > len(peers)]
    if len(winners) == 1:
        return Verdict(winners[0][0], tuple(winners[0][1]), peers)
    several = sorted(p for p in peers if len(by_peer[p]) > 1)
    invalid = sorted(p for p in peers if None in by_peer[p])
    if winners:
        why = f"peers {several} gave conflicting answers, so {len(winners)} answers have a majority"
    else:
        best = max((len(s) for s in support.values()), default=0)
        why = (f"no answer has a strict majority of the {len(peers)} peers that replied {list(peers)} "
               f"(at most {best} agree; {len(support)} different answers")
        why += f"; invalid from {invalid})" if invalid else ")"
        if several:
            why += f"; peers {several} answered more than once, differently"
    return Verdict(None, (), peers, why)
