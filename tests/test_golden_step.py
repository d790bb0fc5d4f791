"""The agent step reproduces its recorded outputs bit for bit (tests/golden_step.py records them)."""

import pytest

from golden_step import load, replay

MISSION, FRAMES, CONFIG, RECORDED = load()


@pytest.mark.parametrize("robot", sorted(RECORDED))
def test_every_agent_reproduces_its_recorded_outputs_bit_for_bit(robot):
    got = replay(MISSION, FRAMES, CONFIG, robot)
    first = next((k for k, (g, w) in enumerate(zip(got, RECORDED[robot])) if g != w), None)
    assert first is None, f"frame {first}: got {got[first]}, recorded {RECORDED[robot][first]}"
    assert len(got) == len(RECORDED[robot])


def test_the_recording_holds_a_drop_decision_and_frames_with_a_robot_missing():
    events = [e for out in RECORDED["r1"] for e in out["events"]]
    assert [(r, k) for r, k, *_ in events][:2] == [("r2", "fail"), ("r2", "drop")]
    assert any(len(f[0].poses) < 3 for f in FRAMES)


def test_all_agents_agree_on_the_structure_and_the_decisions_at_every_frame():
    for k in range(len(FRAMES)):
        views = {r: (RECORDED[r][k].get("state", [None] * 9)[:6], RECORDED[r][k]["events"],
                     RECORDED[r][k].get("wheels")) for r in RECORDED}
        states = [v[0] for v in views.values() if v[0][0] is not None]
        assert all(s == states[0] for s in states), k
        assert len({str(v[1]) for v in views.values()}) == 1, k
        assert len({str(v[2]) for v in views.values()}) == 1, k
