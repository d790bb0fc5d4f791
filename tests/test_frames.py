"""Merging frames and choosing the mission (vsfleet.frames: no transport; the clock is passed in)."""

import math
import random

import pytest

from tests import frames_reference as ref
from vsfleet.frames import FrameMerger, MissionBook
from vsfleet.wire import FrameMsg, Mission, RobotSpec


def frame(seq, t, robots=("r1", "r2"), x=0.0, src="sim"):
    return FrameMsg(t=t, seq=seq, src=src, poses={r: (x, 0.0, 0.0) for r in robots})


def test_a_frame_listing_every_robot_runs_at_once_and_only_once():
    fm = FrameMerger(("r1", "r2"), deadline_s=0.02)
    assert fm.offer(frame(1, 10.0), now=10.0)
    out = fm.ready(now=10.0)
    assert out is not None and out.complete and out.seq == 1 and out.fresh == {"r1", "r2"}
    assert set(out.poses) == {"r1", "r2"}
    assert fm.ready(now=11.0) is None


def test_a_frame_missing_a_robot_from_the_only_source_runs_at_once_and_the_robot_is_left_out_when_old():
    fm = FrameMerger(("r1", "r2"), deadline_s=0.02, max_age_s=0.25)
    fm.offer(frame(1, 10.0), 10.0)
    fm.ready(10.0)
    fm.offer(frame(2, 10.033, robots=("r1",), x=1.0), 10.05)
    out = fm.ready(10.05)                               # one source: nothing else to wait for
    assert out is not None and out.seq == 2 and out.poses["r1"][0] == 1.0
    assert "r2" in out.poses and out.fresh == {"r1"}    # 33 ms old: held over, not fresh
    fm.offer(frame(3, 10.3, robots=("r1",)), 10.3)
    out = fm.ready(10.3)
    assert set(out.poses) == {"r1"} and not out.complete  # r2's pose is 0.3 s old: missing


def test_a_pose_held_over_from_the_same_sources_earlier_frame_is_never_of_the_instant_so_copies_agree():
    # a stalled truth feed: frame 2 is 5 ms after frame 1 and lacks r2. Agent a ran frame 1, agent b
    # never saw it (a newer frame replaced it in b's slot). Were r2's pose from frame 1 "of the
    # instant" (5 ms < half the deadline), a would run frame 2 complete with it and b incomplete with
    # frame 0's: both call it incomplete, and fresh is only what frame 2 lists
    a, b = (FrameMerger(("r1", "r2"), deadline_s=0.033) for _ in range(2))
    for fm in (a, b):
        fm.offer(frame(0, 9.967, x=0.0), 9.97)
        fm.ready(9.97)
    a.offer(frame(1, 10.0, x=1.0), 10.0)
    a.ready(10.0)
    runs = []
    for fm in (a, b):
        fm.offer(frame(2, 10.005, robots=("r1",), x=2.0), 10.01)
        runs.append(fm.ready(10.01))
    assert [r.seq for r in runs] == [2, 2] and not any(r.complete for r in runs)
    assert all(r.fresh == {"r1"} for r in runs)
    assert runs[0].poses["r2"][0] == 1.0 and runs[1].poses["r2"][0] == 0.0   # held over: in the fit only


def test_duplicate_and_out_of_order_frames_are_dropped_and_counted():
    fm = FrameMerger(("r1",), deadline_s=0.02)
    assert fm.offer(frame(5, 10.0, ("r1",)), 10.0)
    assert fm.ready(10.0).seq == 5
    assert not fm.offer(frame(5, 10.0, ("r1",)), 10.0)   # duplicate
    assert not fm.offer(frame(4, 9.9, ("r1",)), 10.0)    # out of order
    assert fm.dropped_old == 2 and fm.ready(10.0) is None
    fm.offer(frame(6, 10.1, ("r1",)), 10.1)
    assert fm.ready(10.1).seq == 6


def test_a_newer_frame_replaces_one_not_yet_run():
    fm = FrameMerger(("r1", "r2"), deadline_s=0.02)
    fm.offer(frame(1, 10.0, x=1.0), 10.0)
    fm.offer(frame(2, 10.033, x=2.0), 10.033)
    out = fm.ready(10.04)
    assert out.seq == 2 and out.poses["r1"][0] == 2.0 and fm.ready(10.04) is None


def test_a_tracker_that_restarts_its_seq_is_followed_at_once_and_a_huge_seq_does_no_harm():
    fm = FrameMerger(("r1", "r2"), deadline_s=0.02)
    fm.offer(frame(2**62, 10.0), 10.0)                 # a bogus frame number
    assert fm.ready(10.0).seq == 2**62
    fm.offer(frame(1, 10.01), 10.01)                   # newer by time, small seq
    assert fm.ready(10.01).seq == 1


def test_a_frame_from_the_future_is_refused_and_does_not_block_the_next():
    fm = FrameMerger(("r1",), deadline_s=0.02, max_future_s=1.0)
    assert not fm.offer(frame(1, 1e9, ("r1",)), now=10.0)
    assert fm.refused_future == 1 and fm.ready(10.0) is None
    assert fm.offer(frame(2, 10.5, ("r1",)), now=10.0)
    assert fm.ready(10.0).seq == 2


def test_objects_no_mission_names_are_ignored_not_held():
    fm = FrameMerger(("r1",), deadline_s=0.02)
    fm.offer(FrameMsg(10.0, 1, "sim", {"r1": (0.0, 0.0, 0.0), "forklift": (1.0, 1.0, 0.0)}), 10.0)
    assert fm.ignored == 1 and set(fm.ready(10.0).poses) == {"r1"} and "forklift" not in fm.held


def test_two_cameras_whose_views_overlap_take_the_shared_robot_from_the_first_camera_whatever_the_arrival_order():
    """Once both have been heard (max_age_s), a robot both see comes from the camera first in sort order, so every
    agent merges the same frame whichever camera's frame reaches it first."""
    before = [FrameMsg(t=9.967, seq=6, src="cam1", poses={"r1": (0.0, 0.0, 0.0), "r2": (4.9, 0.0, 0.0)}),
              FrameMsg(t=9.968, seq=6, src="cam2", poses={"r2": (0.9, 0.0, 0.0)})]
    a = FrameMsg(t=10.0, seq=7, src="cam1", poses={"r1": (0.0, 0.0, 0.0), "r2": (5.0, 0.0, 0.0)})
    b = FrameMsg(t=10.001, seq=7, src="cam2", poses={"r2": (1.0, 0.0, 0.0)})
    runs = []
    for order in ((a, b), (b, a)):
        fm = FrameMerger(("r1", "r2"), deadline_s=0.02)
        for m in before:
            fm.offer(m, 9.97)
        fm.ready(9.97)
        for m in order:
            fm.offer(m, 10.002)
        runs.append(fm.ready(10.002))                 # every robot seen at this instant: at once
    assert runs[0] == runs[1]                          # the same frame, bit for bit
    assert runs[0].poses == {"r1": (0.0, 0.0, 0.0), "r2": (5.0, 0.0, 0.0)} and runs[0].src == "cam1"
    assert runs[0].fresh == {"r1", "r2"} and runs[0].sources == {"cam1"}


def test_two_trackers_of_the_same_robots_only_the_first_in_sort_order_is_followed_until_it_falls_silent():
    fm = FrameMerger(("r1", "r2"), deadline_s=0.02, max_age_s=0.25)
    poses = {"r1": (0.0, 0.0, 0.0), "r2": (1.0, 0.0, 0.0)}
    run = []
    for k in range(30):                                 # "alpha" at 30 Hz, "beta" 10 ms later, arriving first half the time
        ta, tb = 10.0 + k / 30, 10.0 + k / 30 + 0.01
        a, b = FrameMsg(ta, k, "alpha", poses), FrameMsg(tb, 1000 + k, "beta", poses)
        for m in ((a, b) if k % 2 else (b, a)):
            fm.offer(m, tb + 0.001)
            f = fm.ready(tb + 0.001)
            if f is not None:
                run.append((f.src, f.sources))
    assert run[0][0] == "beta"                         # before alpha was ever heard: beta's first frame ran
    assert all(r == ("alpha", frozenset({"alpha"})) for r in run[1:])   # from then on alpha only
    assert fm.shadowed >= 2 * 28
    t = 10.0 + 30 / 30 + 0.01                           # alpha falls silent; beta takes over after max_age_s
    assert fm.offer(FrameMsg(t, 2000, "beta", poses), t) is False and fm.ready(t) is None
    t2 = 10.0 + 29 / 30 + 0.26
    assert fm.offer(FrameMsg(t2, 2001, "beta", poses), t2) and fm.ready(t2).sources == {"beta"}


def test_two_cameras_of_different_robots_are_both_followed():
    fm = FrameMerger(("r1", "r2"), deadline_s=0.02)
    fm.offer(FrameMsg(10.0, 1, "camR", {"r2": (1.0, 0.0, 0.0)}), 10.0)
    fm.offer(FrameMsg(10.0, 1, "camL", {"r1": (0.0, 0.0, 0.0)}), 10.0)
    out = fm.ready(10.0)
    assert out.complete and out.sources == {"camL", "camR"} and fm.shadowed == 0


def test_with_two_cameras_a_frame_missing_robots_waits_for_its_deadline():
    fm = FrameMerger(("r1", "r2"), deadline_s=0.02)
    fm.offer(FrameMsg(10.0, 1, "cam1", {"r1": (0.0, 0.0, 0.0)}), 10.0)
    fm.offer(FrameMsg(10.0, 1, "cam2", {"r2": (1.0, 0.0, 0.0)}), 10.0)
    assert fm.ready(10.0).complete                     # the same instant from both: every robot held
    fm.offer(FrameMsg(10.033, 2, "cam1", {"r1": (0.1, 0.0, 0.0)}), 10.034)
    assert fm.ready(10.04) is None                     # cam2's frame of this instant may still come
    fm.offer(FrameMsg(10.034, 2, "cam2", {"r2": (1.1, 0.0, 0.0)}), 10.045)
    out = fm.ready(10.045)
    assert out.poses == {"r1": (0.1, 0.0, 0.0), "r2": (1.1, 0.0, 0.0)} and out.src == "cam2"
    fm.offer(FrameMsg(10.066, 3, "cam1", {"r1": (0.2, 0.0, 0.0)}), 10.067)
    assert fm.ready(10.08) is None and fm.ready(10.088).seq == 3   # cam2 silent: run on the deadline


def mission(version, effective_t):
    return Mission(version, "l2", (("r1", RobotSpec((0.0, 0.0), 0.1, 0.3, 1.0)),), 0.1, 0.3,
                   effective_t, goal=(1.0, 0.0, 0.0))


def test_the_active_mission_is_the_newest_version_already_effective_at_the_frame_time():
    book = MissionBook()
    assert book.active(100.0) is None
    book.add(mission(1, 0.0))
    book.add(mission(2, 50.0))
    assert not book.add(mission(2, 50.0))
    assert book.active(49.999).version == 1
    assert book.active(50.0).version == 2
    assert book.latest().version == 2
    assert list(book.by_version) == [2]  # older versions are forgotten once superseded


def test_the_mission_book_holds_a_bounded_number_of_pending_versions():
    book = MissionBook()
    for v in range(200):
        book.add(mission(v, 1e12))
    assert len(book.by_version) == MissionBook.MAX_PENDING


COUNTS = ("dropped_old", "refused_sources", "refused_future", "ignored", "shadowed")


def random_stream(rng: random.Random, steps: int):
    """Offers, polls and mission changes as an agent sees them: one to twenty sources (usually one or two)
    at about 30 Hz with jitter, robots some sources miss or see twice, objects no mission names, frames late,
    duplicated, replaced, from the future, sources falling silent, a tracker restarting its seq."""
    robots = [f"r{i}" for i in range(rng.choice([1, 2, 3, 5, 12]))]
    n_src = rng.choice([1, 1, 2, 2, 3, 4, 20])
    sources = [f"cam{k}" for k in rng.sample(range(40), n_src)]
    steps_s = [0.0, 0.001, 1 / 30, 1 / 30, 1 / 30, 0.1, 0.5] if n_src <= 16 else [0.0, 0.001, 0.001, 1 / 30]
    seqs = {s: rng.randrange(100) for s in sources}
    t, now, sent = 10.0, 10.0, []
    for _ in range(steps):
        op = rng.random()
        if op < 0.03:
            mission = tuple(sorted(rng.sample(robots, rng.randint(0, len(robots)))))
            yield "robots", mission, tuple(sorted(set(mission) | set(rng.sample(robots, rng.randint(0, len(robots))))))
            continue
        if op < 0.25:
            now += rng.choice([0.0, 0.001, 0.01, 0.02, 0.033, 0.3])
            yield "ready", now
            continue
        if op < 0.3 and sent:       # a late, duplicated or reordered frame
            yield "offer", rng.choice(sent), now
            continue
        src = rng.choice(sources[:1] * 3 + sources) if n_src <= 16 else rng.choice(sources)
        if rng.random() < 0.02:
            seqs[src] = 0                                 # a restarted tracker
        seqs[src] += rng.choice([1, 1, 1, 2, 0])
        t += rng.choice(steps_s)
        at = t + rng.choice([0.0, 0.0, -0.01, 0.005, -0.3, 2.0])   # jitter, a late or a future frame
        seen = [r for r in robots if rng.random() < 0.9] if rng.random() < 0.5 else list(robots)
        if rng.random() < 0.1:
            seen.append("forklift")
        rng.shuffle(seen) if rng.random() < 0.2 else None
        poses = {r: (rng.uniform(-1, 1), rng.choice([0.0, -0.0, 1.5]), rng.uniform(-3, 3)) for r in seen}
        msg = FrameMsg(t=at, seq=seqs[src], src=src, poses=poses)
        sent = (sent + [msg])[-20:]
        now = max(now, t + rng.choice([0.0, 0.001, 0.004]))
        yield "offer", msg, now


@pytest.mark.parametrize("seed", range(60))
def test_the_merger_gives_the_plain_mergers_frames_and_counts_on_random_streams(seed):
    """FrameMerger's fast paths (one source listing every robot) against the plain one-loop merger
    (tests/frames_reference.py): every offer's verdict, every frame (bit for bit: the same pose objects,
    fresh, sources, complete) and every count, after every step."""
    rng = random.Random(seed)
    deadline_s, max_age_s = rng.choice([(0.02, 0.25), (0.033, 0.25), (0.6, 0.25), (0.02, 0.0)])
    ours, plain = (cls((), deadline_s, max_age_s) for cls in (FrameMerger, ref.FrameMerger))
    frames = 0
    for step in random_stream(rng, 600):
        if step[0] == "robots":
            for m in (ours, plain):
                m.set_robots(step[1], step[2])
        elif step[0] == "offer":
            assert ours.offer(step[1], step[2]) == plain.offer(step[1], step[2])
        else:
            got, want = ours.ready(step[1]), plain.ready(step[1])
            assert got == want and (got is None or list(got.poses) == list(want.poses))
            if got is not None:
                frames += 1
                assert all(got.poses[r] is want.poses[r] for r in got.poses)
                assert [math.copysign(1, got.t)] == [math.copysign(1, want.t)]
        assert [getattr(ours, c) for c in COUNTS] == [getattr(plain, c) for c in COUNTS]
        assert (ours.pending, ours.deadline_at, ours.done) == (plain.pending, plain.deadline_at, plain.done)
        assert ours.heard == plain.heard
    assert frames > 0
