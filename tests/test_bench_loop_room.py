"""bench/loop.py --room: the mission every agent of the bench fleet gets in a room (issue 28: the control loop
keeps 30 Hz in every case, rooms included): bodies, 64 pillars beside the way (clear of the bodies at the start and
the goal), and a way to the goal from where the fleet starts."""

from __future__ import annotations

import numpy as np
import pytest

from bench.loop import ROOM_BODY_M, ROOM_PILLARS, bench_mission, circle_template
from vsfleet.geometry import Pose2
from vsfleet.step import planned_way
from vsfleet.wire import decode_mission, encode_mission


@pytest.mark.parametrize("n", [3, 10, 30])
def test_the_room_mission_has_bodies_pillars_clear_of_them_and_a_way_to_its_goal(n):
    m = bench_mission(n, 0.0, room=True)
    assert decode_mission(encode_mission(m)) == m                 # a mission the agents take
    assert len(m.obstacles) == ROOM_PILLARS and all(s.radius == ROOM_BODY_M for _, s in m.robots)
    start = np.array([p for _, p in circle_template(n)])
    goal = start + (m.goal[0], m.goal[1])
    obs = np.array(m.obstacles)
    for bodies in (start, goal):
        gaps = np.hypot(bodies[:, None, 0] - obs[None, :, 0], bodies[:, None, 1] - obs[None, :, 1])
        assert (gaps - obs[None, :, 2] - ROOM_BODY_M).min() >= 0.25
    way, blocked = planned_way(m, Pose2(0.0, 0.0, 0.0))
    assert not blocked and tuple(way[-1]) == m.goal
    assert bench_mission(n, 0.0).obstacles == () and bench_mission(n, 0.0, room=True) == m   # seeded: the same
