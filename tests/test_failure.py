"""The failure rule (vsfleet.failure): same frames in, same decisions out, per policy."""

import math

import pytest

import numpy as np

from vsfleet.failure import FailurePolicy, FailureState, Health, failure_step, to_health, with_health
from vsfleet.wire import EventMsg, WireError, decode_event, encode_event

from tests import failure_reference as ref

ROBOTS = ("r1", "r2", "r3")


def step(policy, state, robots, t, deviations, progress_xy=None, expected=None, fresh=None, step_s=None,
         max_gap_s=math.inf):
    """One frame through the array form from dicts: deviations {robot: m} (absent = unseen)."""
    n = len(robots)
    seen = np.array([r in deviations for r in robots])
    xy = np.array([progress_xy.get(r, (0.0, 0.0)) if progress_xy else (0.0, 0.0) for r in robots], dtype=float)
    exp_m = np.array([expected.get(r, (0.0, 0.0)) if expected else (0.0, 0.0) for r in robots], dtype=float)
    fr = np.array([r in fresh for r in robots]) if fresh is not None else np.zeros(n, dtype=bool)
    dev = np.array([deviations.get(r, math.inf) for r in robots], dtype=float)
    return failure_step(policy, state, robots, t, seen, fr, xy, dev, exp_m, step_s, max_gap_s)


def update_health(policy, health, deviations, robots, t):
    """The dict-form call the tests were written against, through the array form."""
    state = with_health(FailureState.initial(len(robots), policy, 1 / 30), health, robots)
    state, made = step(policy, state, robots, t, deviations)
    return to_health(state, robots), made


def feed(policy, frames):
    """frames: list of (t, {robot: deviation}); returns (final health, all decisions)."""
    state, out = FailureState.initial(len(ROBOTS), policy, 0.1), []
    for t, devs in frames:
        state, made = step(policy, state, ROBOTS, t, devs)
        out.extend(made)
    return to_health(state, ROBOTS), out


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


def test_a_blocked_event_carries_why_and_no_other_event_does():
    import msgpack

    for why in ("no_path", "stuck"):
        msg = EventMsg(t=3.0, seq=90, robot="r1", kind="blocked", dev=1.25, by="r1", why=why)
        assert decode_event(encode_event(msg)) == msg
        assert msgpack.unpackb(encode_event(msg))["why"] == why
    for kind in ("fail", "drop", "rejoin", "recover", "unblocked"):
        assert "why" not in msgpack.unpackb(encode_event(EventMsg(3.0, 90, "r1", kind, 0.5, "r1")))
    base = {"t": 3.0, "seq": 90, "robot": "r1", "dev": 1.25, "by": "r1", "v": 1}
    # an older agent's blocked event, without why, is read with why ""
    assert decode_event(msgpack.packb({**base, "kind": "blocked"})).why == ""
    for kind, why in (("blocked", "nope"), ("blocked", 3), ("unblocked", "stuck"), ("fail", "no_path")):
        with pytest.raises(WireError, match="field 'why'"):
            decode_event(msgpack.packb({**base, "kind": kind, "why": why}))


def test_an_agent_that_missed_a_frame_fails_the_robot_on_the_same_frame():
    policy = FailurePolicy("drop")
    dt = 1.0 / 30.0
    step_m = (0.1 * dt, 0.0)           # commanded 0.1 m/s along +x, every frame

    def run(skip):
        state, x, out = FailureState.initial(1, policy, dt), 0.0, []
        for k in range(200):
            t = 100.0 + k * dt + (0.004 if k % 3 else 0.0)   # jittered frame times
            # moving, then halted for good between two frames: the ratio then crosses 0.3 between two frames
            # too (halted on a frame, it would cross exactly on one, and rounding would pick the frame)
            x = 0.1 * min(t - 100.0, 2.015)
            if k in skip:
                continue
            state, decisions = step(policy, state, ("r1",), t, {"r1": 0.0}, {"r1": (x, 0.0)}, {"r1": step_m},
                                    fresh={"r1"}, step_s=dt, max_gap_s=0.3)
            out.append((k, [d.kind for d in decisions]))
        return out
    full, missed = run(set()), run({95, 96, 97, 98, 99, 110, 111, 120})
    decided = lambda rows: next(k for k, kinds in rows if "drop" in kinds)   # noqa: E731
    assert decided(full) == decided(missed)


def test_the_array_form_decides_as_the_per_robot_reference_on_random_frames():
    rng = np.random.default_rng(8)
    robots = tuple(f"r{i}" for i in range(6))
    dt = 1.0 / 30.0
    for mode in ("hold", "drop", "rejoin"):
        policy = FailurePolicy(mode, fail_after_s=1.0, rejoin_after_s=0.5, recover_after_s=0.3,
                               min_expected_m=0.02)
        state = FailureState.initial(len(robots), policy, dt)
        health, motion = ref.Health(), ref.Motion()
        xy = np.zeros((len(robots), 2))
        mine, theirs = [], []
        for k in range(400):
            t = k * dt
            moving = rng.random(len(robots)) < (0.3 if (k // 60) % 2 else 0.95)   # phases of halting
            expected = np.where(rng.random((len(robots), 1)) < 0.9, 0.1 * dt, 0.0) * np.array([[1.0, 0.0]])
            xy = xy + np.where(moving[:, None], expected, 0.0) + rng.normal(0, 1e-4, xy.shape)
            seen = rng.random(len(robots)) < 0.97
            fresh = seen & (rng.random(len(robots)) < 0.95)
            dev = np.where(rng.random(len(robots)) < 0.05, 0.2, rng.uniform(0, 0.03, len(robots)))
            held = rng.random(len(robots)) < 0.1       # the safety filter cut these robots' commands
            state, made = failure_step(policy, state, robots, t, seen, fresh, xy, np.where(seen, dev, np.inf),
                                       expected, dt, 0.3, held=held)
            mine += [(d.t, d.robot, d.kind) for d in made]
            poses = {r: (xy[i, 0], xy[i, 1], 0.0) for i, r in enumerate(robots) if fresh[i]}
            motion, ratios, approaching = ref.update_motion(
                policy, motion, poses, {r: tuple(expected[i]) for i, r in enumerate(robots) if fresh[i]}, t, dt, 0.3,
                deviations_m={r: dev[i] for i, r in enumerate(robots) if seen[i]})
            health, made = ref.update_health(policy, health, {r: dev[i] for i, r in enumerate(robots) if seen[i]},
                                             robots, t, ratios,
                                             on_way=approaching | {r for i, r in enumerate(robots) if held[i]})
            theirs += [(d.t, d.robot, d.kind) for d in made]
        assert mine == theirs and len(mine) > 3, mode
        mine_h = to_health(state, robots)
        assert (mine_h.since_t, mine_h.failed, mine_h.dropped) == (health.since_t, health.failed, health.dropped)


def test_health_converts_to_and_from_the_wire_form():
    policy = FailurePolicy("rejoin")
    h = Health(since_t={"r3": 99.5, "unknown": 1.0}, failed=frozenset({"r2"}), dropped=frozenset({"r2"}))
    state = with_health(FailureState.initial(3, policy, 1 / 30), h, ROBOTS)
    assert to_health(state, ROBOTS) == Health(since_t={"r3": 99.5}, failed=frozenset({"r2"}),
                                              dropped=frozenset({"r2"}))
    no_timers = with_health(FailureState.initial(3, policy, 1 / 30), h, ROBOTS, timers=False)
    assert to_health(no_timers, ROBOTS).since_t == {}


def test_when_every_robot_in_the_fit_is_off_the_structure_is_blamed_not_a_robot():
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


# ---------------------------------------------------------------- the assembly phase (issue 28, Crowds)

def assembly_run(policy, speed_m_s, commanded_m_s, held=False, seconds=8.0, start_m=0.4):
    """r1 and r3 on their points; r2 starts start_m from its point (along -x) and moves at speed_m_s
    [m/s] towards it while its predicted command is commanded_m_s [m/s] (the same direction);
    held: the safety filter cuts r2's command in every frame. Returns the decisions as (t, robot, kind)."""
    dt = 1.0 / 30.0
    state, out, x = FailureState.initial(3, policy, dt), [], -start_m
    for k in range(int(seconds / dt)):
        t = 50.0 + k * dt
        x = min(x + speed_m_s * dt, 0.0)
        xy = np.array([[1.0, 0.0], [x, 0.5], [2.0, 0.0]])
        expected = np.array([[0.0, 0.0], [commanded_m_s * dt if x < 0.0 else 0.0, 0.0], [0.0, 0.0]])
        state, made = failure_step(policy, state, ROBOTS, t, np.ones(3, bool), np.ones(3, bool), xy,
                                   np.array([0.003, -x, 0.004]), expected, dt, 0.3,
                                   held=np.array([False, held, False]))
        out += [(round(d.t - 50.0, 3), d.robot, d.kind) for d in made]
    return out


def test_a_robot_on_its_way_to_its_point_is_not_judged_failed_by_the_deviation_test():
    # 0.4 m at 0.03 m/s: more than 13 s off by more than fail_deviation_m while the others are on their points
    assert assembly_run(FailurePolicy("drop"), 0.03, 0.03, seconds=16.0) == []


def test_a_robot_held_back_by_the_safety_filter_is_on_its_way():
    # still, told to stay still (its command cut to zero by the safety filter), 0.4 m off its point
    assert assembly_run(FailurePolicy("drop"), 0.0, 0.0, held=True) == []


def test_a_still_robot_off_its_point_and_not_held_still_fails_by_the_deviation_test():
    assert [(r, kind) for _, r, kind in assembly_run(FailurePolicy("drop"), 0.0, 0.0)] == [("r2", "fail"),
                                                                                         ("r2", "drop")]


def test_a_robot_that_approaches_too_slowly_to_count_still_fails():
    # 0.5 cm/s: it shrinks its deviation by 0.8 cm over the 1.6 s a window must span, not more than 2 cm
    made = assembly_run(FailurePolicy("drop"), 0.005, 0.005)
    assert [(r, kind) for _, r, kind in made] == [("r2", "fail"), ("r2", "drop")]
    assert made[0][0] == pytest.approx(2.0, abs=0.05)


def test_a_halted_robot_fails_the_progress_test_whether_or_not_it_is_held():
    # told to move at 0.1 m/s (through the filter or not), it does not move at all
    for held in (False, True):
        made = assembly_run(FailurePolicy("drop"), 0.0, 0.1, held=held)
        assert [(r, kind) for _, r, kind in made] == [("r2", "fail"), ("r2", "drop")], held
        assert made[0][0] <= 2.0 + 1e-9, held    # held: as soon as the window has settled (1.6 s)


def test_a_robot_slowed_to_a_fifth_fails_the_progress_test_though_its_deviation_shrinks():
    made = assembly_run(FailurePolicy("drop"), 0.02, 0.1)
    assert [(r, kind) for _, r, kind in made] == [("r2", "fail"), ("r2", "drop")]


def test_an_unseen_robot_is_never_on_its_way():
    policy = FailurePolicy("drop")
    state, made = FailureState.initial(3, policy, 0.1), []
    for k in range(40):
        state, m = failure_step(policy, state, ROBOTS, k * 0.1, np.array([True, False, True]), np.ones(3, bool),
                                np.zeros((3, 2)), np.array([0.0, np.inf, 0.0]), np.zeros((3, 2)), 0.1, 0.3,
                                held=np.ones(3, bool))
        made += [(d.robot, d.kind) for d in m]
    assert made == [("r2", "fail"), ("r2", "drop")]
