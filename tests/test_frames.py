"""Frame assembly and mission selection in the agent (no transport; the clock is passed in)."""

from agent.frames import FrameAssembler, MissionBook
from vsfleet.wire import Mission, PoseMsg, RobotSpec


def pose(seq, t, x=0.0):
    return PoseMsg(t=t, seq=seq, x=x, y=0.0, th=0.0, src="sim")


def test_a_complete_frame_is_processed_at_once_and_only_once():
    fa = FrameAssembler(("r1", "r2"), deadline_s=0.02)
    fa.offer("r1", pose(1, 10.0), now=10.0)
    assert fa.ready(now=10.0) is None
    fa.offer("r2", pose(1, 10.0), now=10.001)
    frame = fa.ready(now=10.001)
    assert frame is not None and frame.complete and frame.seq == 1
    assert set(frame.poses) == {"r1", "r2"}
    assert fa.ready(now=11.0) is None


def test_an_incomplete_frame_runs_after_the_deadline_with_the_freshest_poses():
    fa = FrameAssembler(("r1", "r2"), deadline_s=0.02, max_age_s=0.25)
    fa.offer("r1", pose(1, 10.0), 10.0)
    fa.offer("r2", pose(1, 10.0), 10.0)
    fa.ready(10.0)
    fa.offer("r1", pose(2, 10.033, x=1.0), 10.05)
    assert fa.ready(10.069) is None
    frame = fa.ready(10.071)
    assert frame is not None and not frame.complete and frame.seq == 2
    assert frame.poses["r1"][0] == 1.0
    assert "r2" in frame.poses  # 33 ms old: still within max_age


def test_poses_older_than_the_age_limit_are_left_out_of_the_frame():
    fa = FrameAssembler(("r1", "r2"), deadline_s=0.02, max_age_s=0.25)
    fa.offer("r2", pose(1, 10.0), 10.3)
    fa.offer("r1", pose(9, 10.3), 10.3)
    frame = fa.ready(10.35)
    assert set(frame.poses) == {"r1"}


def test_duplicate_and_out_of_order_poses_are_dropped_and_counted():
    fa = FrameAssembler(("r1",), deadline_s=0.02)
    assert fa.offer("r1", pose(5, 10.0), 10.0)
    assert not fa.offer("r1", pose(5, 10.0), 10.0)      # duplicate
    assert not fa.offer("r1", pose(4, 9.9), 10.0)       # out of order
    assert fa.dropped_old == 2
    assert fa.ready(10.0).seq == 5
    # an older frame is never processed after a newer one
    fa.offer("r1", pose(6, 10.1), 10.1)
    assert fa.ready(10.1).seq == 6


def test_a_tracker_that_restarts_its_seq_is_followed_at_once_and_a_huge_seq_does_no_harm():
    fa = FrameAssembler(("r1", "r2"), deadline_s=0.02)
    fa.offer("r1", pose(2**62, 10.0), 10.0)           # a bogus frame number
    fa.offer("r2", pose(1, 10.01), 10.01)              # newer by time, small seq
    assert fa.ready(10.01) is None                     # not complete: waits for its deadline
    frame = fa.ready(10.04)
    assert frame.seq == 1 and frame.t == 10.01 and not frame.complete
    for r in ("r1", "r2"):                             # the restarted tracker's next frame
        fa.offer(r, pose(2, 10.05), 10.05)
    assert fa.ready(10.05).seq == 2


def test_a_pose_from_the_future_is_refused():
    fa = FrameAssembler(("r1",), deadline_s=0.02, max_future_s=1.0)
    assert not fa.offer("r1", pose(1, 1e9), now=10.0)
    assert fa.refused_future == 1 and fa.ready(10.0) is None
    assert fa.offer("r1", pose(2, 10.5), now=10.0)


def test_a_stale_frame_is_not_run_and_is_counted():
    fa = FrameAssembler(("r1",), deadline_s=0.02, max_stale_s=0.5)
    fa.offer("r1", pose(1, 10.0), now=10.6)            # 0.6 s old on arrival (clock skew or a stalled link)
    assert fa.ready(10.6) is None
    assert fa.stale == 1
    fa.offer("r1", pose(2, 10.2), now=10.6)            # 0.4 s old: run
    assert fa.ready(10.6).seq == 2 and fa.stale == 1


def test_frames_from_two_cameras_are_complete_only_within_one_source():
    fa = FrameAssembler(("r1", "r2"), deadline_s=0.02)
    fa.offer("r1", PoseMsg(t=10.0, seq=7, x=0.0, y=0.0, th=0.0, src="cam1"), 10.0)
    fa.offer("r2", PoseMsg(t=10.001, seq=7, x=1.0, y=0.0, th=0.0, src="cam2"), 10.001)
    assert fa.ready(10.002) is None                    # same seq, other source: not complete
    frame = fa.ready(10.03)                            # the deadline: freshest pose of each robot
    assert not frame.complete and set(frame.poses) == {"r1", "r2"}
    for r in ("r1", "r2"):
        fa.offer(r, PoseMsg(t=10.04, seq=8, x=0.0, y=0.0, th=0.0, src="cam1"), 10.04)
    assert fa.ready(10.04).complete


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
