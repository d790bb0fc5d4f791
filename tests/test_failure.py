"""The failure rule (vsfleet.failure): same frames in, same decisions out, per policy."""

import math

import pytest

from vsfleet.failure import FailurePolicy, Health, update_health
from vsfleet.wire import EventMsg, WireError, decode_event, encode_event

ROBOTS = ("r1", "r2", "r3")


def feed(policy, frames):
    """frames: list of (t, {robot: deviation}); returns (final health, all decisions)."""
    health, out = Health(), []
    for t, devs in frames:
        health, made = update_health(policy, health, devs, ROBOTS, t)
        out.extend(made)
    return health, out


def frames(bad_r2, t_end=5.0, dt=0.1, ok=0.01):
    return [(k * dt, {"r1": ok, "r2": bad_r2(k * dt), "r3": ok}) for k in range(int(t_end / dt) + 1)]


def test_a_robot_fails_only_after_being_non_compliant_for_the_whole_time_threshold():
    policy = FailurePolicy("hold", fail_deviation_m=0.05, fail_after_s=2.0)
    health, made = feed(policy, frames(lambda t: 0.2 if t >= 1.0 else 0.0))
    assert [(round(d.t, 6), d.robot, d.kind) for d in made] == [(3.0, "r2", "fail")]
    assert health.failed == {"r2"} and health.dropped == frozenset()


def test_a_transient_excursion_shorter_than_the_threshold_is_forgiven():
    policy = FailurePolicy("drop", fail_deviation_m=0.05, fail_after_s=2.0)
    health, made = feed(policy, frames(lambda t: 0.2 if 1.0 <= t < 2.5 else 0.0))
    assert made == [] and health.dropped == frozenset()


def test_drop_takes_the_robot_out_and_it_stays_out():
    policy = FailurePolicy("drop", fail_deviation_m=0.05, fail_after_s=1.0)
    health, made = feed(policy, frames(lambda t: 0.2 if t < 2.0 else 0.0))
    assert [d.kind for d in made] == ["fail", "drop"]
    assert health.dropped == {"r2"}


def test_rejoin_takes_a_dropped_robot_back_once_it_complies_long_enough():
    policy = FailurePolicy("rejoin", fail_deviation_m=0.05, fail_after_s=1.0,
                           rejoin_deviation_m=0.02, rejoin_after_s=1.0)
    health, made = feed(policy, frames(lambda t: 0.2 if t < 2.0 else 0.0, t_end=4.0))
    assert [(d.kind, round(d.t, 6)) for d in made] == [("fail", 1.0), ("drop", 1.0), ("rejoin", 3.0)]
    assert health.dropped == frozenset() and health.failed == frozenset()


def test_a_robot_missing_from_frames_counts_as_non_compliant():
    policy = FailurePolicy("hold", fail_after_s=1.0)
    fr = [(k * 0.1, {"r1": 0.0, "r3": 0.0}) for k in range(12)]
    _, made = feed(policy, fr)
    assert [(d.robot, d.kind) for d in made] == [("r2", "fail")] and math.isinf(made[0].deviation_m)


def test_two_agents_fed_the_same_frames_decide_on_the_same_frame():
    policy = FailurePolicy("drop", fail_after_s=1.5)
    fr = frames(lambda t: 0.3 * t)
    assert feed(policy, fr) == feed(policy, fr)


def test_bad_policies_are_refused():
    with pytest.raises(ValueError):
        FailurePolicy("panic")
    with pytest.raises(ValueError):
        FailurePolicy("hold", fail_after_s=-1.0)


def test_events_round_trip_including_an_unseen_robots_infinite_deviation():
    for dev in (0.07, math.inf):
        msg = EventMsg(t=12.5, seq=40, robot="r2", kind="drop", dev=dev, by="r1")
        assert decode_event(encode_event(msg)) == msg
    with pytest.raises(WireError):
        decode_event(encode_event(EventMsg(1.0, 1, "r2", "drop", 0.1, "r1")).replace(b"drop", b"boom"))


def test_an_agent_that_missed_a_frame_reaches_the_same_progress_ratio_and_fails_the_robot_on_the_same_frame():
    from vsfleet.failure import FailurePolicy, Health, Motion, update_health, update_motion

    policy = FailurePolicy("drop")
    dt = 1.0 / 30.0
    step = (0.1 * dt, 0.0)           # commanded 0.1 m/s along +x, every frame
    def run(skip):
        motion, health, x, out = Motion(), Health(), 0.0, []
        for k in range(200):
            t = 100.0 + k * dt + (0.004 if k % 3 else 0.0)   # jittered frame times
            if k < 60:
                x = 0.1 * (t - 100.0)                          # moving, then halted for good
            if k in skip:
                continue
            motion, ratios = update_motion(policy, motion, {"r1": (x, 0.0, 0.0)}, {"r1": step}, t,
                                           step_s=dt, max_gap_s=0.3)
            health, decisions = update_health(policy, health, {"r1": 0.0}, ("r1",), t, ratios)
            out.append((k, ratios.get("r1"), [d.kind for d in decisions]))
        return out
    full, missed = run(set()), run({95, 96, 97, 98, 99, 110, 111, 120})
    decided = lambda rows: next(k for k, _, kinds in rows if "drop" in kinds)   # noqa: E731
    assert decided(full) == decided(missed)
    ratios = dict((k, r) for k, r, _ in full)
    diffs = [abs(r - ratios[k]) for k, r, _ in missed if r is not None and ratios[k] is not None]
    assert max(diffs) < 1e-2


def test_when_every_robot_in_the_fit_is_off_the_structure_is_blamed_not_a_robot():
    from vsfleet.failure import FailurePolicy, Health, update_health

    policy = FailurePolicy("drop")
    health, made = Health(), []
    for k in range(100):                                    # 3.3 s, everyone 7 cm off
        health, d = update_health(policy, health, {"r1": 0.07, "r2": 0.07, "r3": 0.07},
                                  ("r1", "r2", "r3"), 100.0 + k / 30)
        made += d
    assert made == []
    for k in range(100, 200):                               # now only r2 is off
        health, d = update_health(policy, health, {"r1": 0.01, "r2": 0.07, "r3": 0.01},
                                  ("r1", "r2", "r3"), 100.0 + k / 30)
        made += d
    assert [(x.robot, x.kind) for x in made] == [("r2", "fail"), ("r2", "drop")]
    assert abs(made[0].t - (100.0 + 100 / 30 + 2.0)) < 0.05


def test_under_hold_a_failed_robot_recovers_only_after_complying_for_recover_after_s():
    policy = FailurePolicy("hold", fail_deviation_m=0.05, fail_after_s=1.0, recover_after_s=0.5)

    def r2(t):
        if t < 2.0 - 1e-9:
            return 0.2                                   # off: fails at t = 1.0
        if t < 3.0 - 1e-9:
            return 0.06 if round(t * 10) % 2 else 0.04   # at the threshold: complies every other frame
        return 0.0                                       # back on its point
    health, made = feed(policy, frames(r2, t_end=5.0))
    assert [(round(d.t, 6), d.robot, d.kind) for d in made] == [(1.0, "r2", "fail"), (3.5, "r2", "recover")]
    assert health.failed == frozenset()


def test_recover_after_s_must_be_finite_and_not_negative():
    with pytest.raises(ValueError, match="recover_after_s"):
        FailurePolicy("hold", recover_after_s=-1.0)
