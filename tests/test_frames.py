"""Frame assembly and mission selection in the agent (no transport; the clock is passed in)."""

from agent.frames import FrameAssembler, MissionBook
from vsfleet.wire import Mission, PoseMsg, RobotSpec


def pose(seq, t, x=0.0):
    return PoseMsg(t=t, seq=seq, x=x, y=0.0, th=0.0, src="sim")


def test_a_complete_frame_is_processed_at_once_and_only_once():
    fa = FrameAssembler(("r1", "r2"), deadline_s=0.02)
    fa.offer("r1", pose(1, 10.0), now=0.0)
    assert fa.ready(now=0.0) is None
    fa.offer("r2", pose(1, 10.0), now=0.001)
    frame = fa.ready(now=0.001)
    assert frame is not None and frame.complete and frame.seq == 1
    assert set(frame.poses) == {"r1", "r2"}
    assert fa.ready(now=1.0) is None


def test_an_incomplete_frame_runs_after_the_deadline_with_the_freshest_poses():
    fa = FrameAssembler(("r1", "r2"), deadline_s=0.02, max_age_s=0.25)
    fa.offer("r1", pose(1, 10.0), 0.0)
    fa.offer("r2", pose(1, 10.0), 0.0)
    fa.ready(0.0)
    fa.offer("r1", pose(2, 10.033, x=1.0), 1.0)
    assert fa.ready(1.019) is None
    frame = fa.ready(1.021)
    assert frame is not None and not frame.complete and frame.seq == 2
    assert frame.poses["r1"][0] == 1.0
    assert "r2" in frame.poses  # 33 ms old: still within max_age


def test_poses_older_than_the_age_limit_are_left_out_of_the_frame():
    fa = FrameAssembler(("r1", "r2"), deadline_s=0.02, max_age_s=0.25)
    fa.offer("r2", pose(1, 10.0), 0.0)
    fa.offer("r1", pose(9, 10.3), 0.0)
    frame = fa.ready(0.05)
    assert set(frame.poses) == {"r1"}


def test_duplicate_and_out_of_order_poses_are_dropped_and_counted():
    fa = FrameAssembler(("r1",), deadline_s=0.02)
    assert fa.offer("r1", pose(5, 10.0), 0.0)
    assert not fa.offer("r1", pose(5, 10.0), 0.0)      # duplicate
    assert not fa.offer("r1", pose(4, 9.9), 0.0)       # out of order
    assert fa.dropped_old == 2
    assert fa.ready(0.0).seq == 5
    # an older frame is never processed after a newer one
    fa.offer("r1", pose(6, 10.1), 0.0)
    assert fa.ready(0.0).seq == 6


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
