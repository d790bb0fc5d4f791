"""vsfleet monitor's model: the table as plain data from (receive time, key, payload); and its rendering."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
from rich.console import Console

from vsfleet.fleetctl.monitor import FleetModel, render
from vsfleet.wire import CmdMsg, FaultMsg, PoseMsg, StateMsg, encode

T0 = 1795378500.0
ROBOTS = ("r1", "r2", "r3")


def state(seq: int, x: float = 0.1, th: float = 0.0, rejected: int = 0, mission: int = 4, err: float = 0.002,
          complete: bool = True):
    return encode(StateMsg(t=T0 + seq / 30, seq=seq, x=x, y=0.2, th=th, gx=x, gy=0.2, gth=th, cost=0.001,
                           err=err, used=ROBOTS, rejected=rejected, mission=mission, complete=complete))


def fed(fleet: str = "demo", seconds: float = 2.0) -> FleetModel:
    """Three robots, poses at 30 Hz, agents alive, every agent answering every frame identically."""
    m = FleetModel(fleet)
    for r in ROBOTS:
        m.ingest_liveliness(T0, f"vs/{fleet}/alive/agent/{r}", True)
    m.ingest_liveliness(T0, f"vs/{fleet}/alive/sim/simfleet", True)
    for k in range(int(seconds * 30)):
        t = T0 + k / 30
        for r in ROBOTS:
            m.ingest(t, f"vs/{fleet}/pose/{r}", encode(PoseMsg(t=t, seq=k, x=0.0, y=0.0, th=0.0, src="s")))
        for r in ROBOTS:
            m.ingest(t + 0.004, f"vs/{fleet}/state/{r}", state(k))
            m.ingest(t + 0.005, f"vs/{fleet}/cmd/{r}", encode(CmdMsg(t=t, seq=k, vl=0.01 * k, vr=-0.01, ttl=0.3)))
    return m


def test_each_robot_shows_pose_age_and_rate_wheel_speeds_err_liveliness_and_rejections():
    view = fed().view()
    assert [r.robot for r in view.robots] == list(ROBOTS)
    for row in view.robots:
        assert row.pose_rate_hz == pytest.approx(30.0, abs=0.6)
        assert row.pose_age_s == pytest.approx(0.005, abs=1e-5)
        assert (row.vl_m_s, row.vr_m_s) == (0.01 * 59, -0.01)
        assert row.err_m == 0.002 and row.alive is True and row.rejected == 0 and row.state_seq == 59


def test_the_pose_rate_falls_to_zero_and_the_age_grows_when_poses_stop():
    view = fed().view(now_s=T0 + 10.0)
    assert all(r.pose_rate_hz == 0.0 for r in view.robots)
    assert all(r.pose_age_s > 8.0 for r in view.robots)


def test_identical_agents_agree_to_zero_on_the_newest_frame_and_show_the_structure_and_mission_version():
    view = fed().view()
    assert view.agreement_seq == 59 and view.agents_compared == 3
    assert view.agreement_pos_m == 0.0 and view.agreement_th_rad == 0.0
    assert view.structure == (0.1, 0.2, 0.0) and view.structure_seq == 59
    assert view.mission_version == 4


def test_agreement_uses_the_newest_frame_every_agent_reported_and_measures_the_difference():
    m = fed()
    t = T0 + 2.0
    m.ingest(t, "vs/demo/state/r1", state(60, x=0.1))
    m.ingest(t, "vs/demo/state/r2", state(60, x=0.13, th=0.05))  # r3 has not answered frame 60 yet
    view = m.view()
    assert view.agreement_seq == 59 and view.agreement_pos_m == 0.0
    m.ingest(t + 0.01, "vs/demo/state/r3", state(60, x=0.1))
    view = m.view()
    assert view.agreement_seq == 60 and view.agreement_complete is True
    assert view.agreement_pos_m == pytest.approx(0.03) and view.agreement_th_rad == pytest.approx(0.05)


def test_agreement_is_taken_on_the_newest_frame_every_agent_ran_complete():
    m = fed()
    t = T0 + 2.0
    # frame 60: r2 ran it on its deadline without every pose, and so differs: not compared
    m.ingest(t, "vs/demo/state/r1", state(60, x=0.1))
    m.ingest(t, "vs/demo/state/r2", state(60, x=0.13, complete=False))
    m.ingest(t, "vs/demo/state/r3", state(60, x=0.1))
    view = m.view()
    assert view.agreement_seq == 59 and view.agreement_complete is True and view.agreement_pos_m == 0.0
    text = _text(view)
    assert "agreement on frame 59 (run complete) over 3 agents" in text


def test_with_no_frame_every_agent_ran_complete_the_newest_common_frame_is_compared_and_flagged():
    m = FleetModel("demo")
    for r in ROBOTS:
        m.ingest(T0, f"vs/demo/state/{r}", state(7, x=0.1 if r != "r2" else 0.12, complete=r != "r2"))
    view = m.view()
    assert view.agreement_seq == 7 and view.agreement_complete is False
    assert view.agreement_pos_m == pytest.approx(0.02)
    assert "agreement on frame 7 (none run complete by every agent)" in _text(view)


def test_a_dead_agent_shows_gone_and_is_left_out_of_the_agreement():
    m = fed()
    m.ingest_liveliness(T0 + 2.0, "vs/demo/alive/agent/r3", False)
    m.ingest(T0 + 2.01, "vs/demo/state/r1", state(60))
    m.ingest(T0 + 2.01, "vs/demo/state/r2", state(60))
    view = m.view()
    assert {r.robot: r.alive for r in view.robots} == {"r1": True, "r2": True, "r3": False}
    assert view.agreement_seq == 60 and view.agents_compared == 2


def test_rejections_come_from_the_agents_state():
    m = fed()
    m.ingest(T0 + 2.0, "vs/demo/state/r2", state(60, rejected=7))
    assert {r.robot: r.rejected for r in m.view().robots}["r2"] == 7


def test_events_and_faults_keep_the_latest_few_in_order():
    m = fed()
    for i in range(7):
        m.ingest(T0 + 3 + i, "vs/demo/event/r1", msgpack.packb({"kind": "note", "i": i}))
    m.ingest(T0 + 11, "vs/demo/fault/r2", encode(FaultMsg("stop", 0.0, 0.0)))
    events = m.view().events
    assert len(events) == 5
    assert [e[2].get("i") for e in events[:4]] == [3, 4, 5, 6]
    assert events[0][1] == "event/r1"  # the deciding agent, from the key
    assert events[-1][1:] == ("fault/r2", {"kind": "stop", "factor": 0.0, "duration": 0.0})


def test_bad_messages_are_counted_and_never_break_the_view():
    m = fed()
    m.ingest(T0 + 2, "vs/demo/pose/r1", b"\xc1")
    m.ingest(T0 + 2, "vs/demo/state/r2", msgpack.packb({"seq": "x"}))
    m.ingest(T0 + 2, "vs/demo/event/r1", msgpack.packb([1, 2]))
    view = m.view()
    assert view.bad_messages == 3 and len(view.robots) == 3


def test_other_fleets_are_ignored():
    m = fed()
    m.ingest(T0 + 2, "vs/other/pose/r9", encode(PoseMsg(t=T0, seq=1, x=0, y=0, th=0, src="s")))
    m.ingest_liveliness(T0 + 2, "vs/other/alive/agent/r9", True)
    assert [r.robot for r in m.view().robots] == list(ROBOTS)


def test_without_a_fleet_the_model_follows_the_first_fleet_it_sees():
    m = FleetModel()
    m.ingest(T0, "vs/lab/pose/r1", encode(PoseMsg(t=T0, seq=1, x=0, y=0, th=0, src="s")))
    m.ingest(T0, "vs/other/pose/r2", encode(PoseMsg(t=T0, seq=1, x=0, y=0, th=0, src="s")))
    view = m.view()
    assert view.fleet == "lab" and [r.robot for r in view.robots] == ["r1"]


def _text(view) -> str:
    console = Console(record=True, width=160)
    console.print(render(view))
    return console.export_text()


def test_the_rendered_table_names_every_robot_with_units_in_the_headers():
    text = _text(fed().view())
    for needle in ("r1", "r2", "r3", "alive", "pose age [s]", "pose rate [Hz]", "vl [m/s]", "err [cm]",
                   "rejected", "mission version: 4", "agreement on frame 59 (run complete) over 3 agents: 0 m"):
        assert needle in text


def test_pose_rates_come_from_frames_and_are_not_counted_twice_with_the_poses():
    from vsfleet.fleetctl.monitor import FleetModel
    from vsfleet.wire import FrameMsg, PoseMsg, encode, encode_frame

    view = FleetModel("demo")
    for k in range(30):
        t = 100.0 + k / 30
        view.ingest(t, "vs/demo/frame/sim", encode_frame(FrameMsg(t, k, "sim", {"r1": (0.0, 0.0, 0.0)})))
        view.ingest(t, "vs/demo/pose/r1", encode(PoseMsg(t, k, 0.0, 0.0, 0.0, "sim")))
    assert len(view._robot("r1").pose_times) == 30 and view.bad == 0


def _room_model() -> FleetModel:
    """A mission with bodies (r1 0.05 m, r2 0.04 m, r3 a point) and two obstacles; one frame of poses."""
    from vsfleet.wire import FrameMsg, Mission, RobotSpec, encode_frame, encode_mission

    mission = Mission(5, "l2", (("r1", RobotSpec((0.3, 0.0), 0.12, 0.3, 0.8, radius=0.05)),
                                ("r2", RobotSpec((-0.15, 0.26), 0.12, 0.3, 0.8, radius=0.04)),
                                ("r3", RobotSpec((-0.15, -0.26), 0.12, 0.3, 0.8))),
                      0.08, 0.3, 0.0, goal=(1.6, 1.0, 0.3), obstacles=((1.0, 0.0, 0.2), (5.0, 5.0, 0.5)))
    m = FleetModel("demo")
    m.ingest(T0, "vs/demo/mission", encode_mission(mission))
    poses = {"r1": (0.7, 0.0, 0.0), "r2": (0.0, 0.5, 0.0), "r3": (0.0, 0.41, 0.0)}
    m.ingest(T0, "vs/demo/frame/sim", encode_frame(FrameMsg(T0, 1, "sim", poses)))
    return m


def test_in_a_room_each_robot_shows_its_body_and_its_gap_to_the_nearest_body_or_obstacle():
    view = _room_model().view()
    rows = {r.robot: r for r in view.robots}
    assert (rows["r1"].radius_m, rows["r2"].radius_m, rows["r3"].radius_m) == (0.05, 0.04, None)
    assert rows["r1"].gap_m == pytest.approx(0.3 - 0.2 - 0.05)        # obstacle 0
    assert rows["r2"].gap_m == pytest.approx(0.09 - 0.04)             # r3, a point 9 cm away
    assert rows["r3"].gap_m == pytest.approx(0.09 - 0.04)
    assert view.obstacles == ((1.0, 0.0, 0.2), (5.0, 5.0, 0.5))
    text = _text(view)
    for needle in ("body r [cm]", "gap [cm]", "5.0", "+5.0", "obstacles (2, x y r [m]): 0: (+1.000, +0.000, 0.200)"):
        assert needle in text


def test_a_touching_body_shows_a_negative_gap_and_a_mission_without_a_room_adds_no_columns():
    from vsfleet.wire import FrameMsg, encode_frame

    m = _room_model()
    m.ingest(T0 + 0.1, "vs/demo/frame/sim", encode_frame(FrameMsg(T0 + 0.1, 2, "sim", {"r1": (0.78, 0.0, 0.0)})))
    assert {r.robot: r for r in m.view().robots}["r1"].gap_m == pytest.approx(-0.03)
    text = _text(fed().view())
    assert "gap [cm]" not in text and "body r" not in text and "obstacles" not in text


def _two_in_a_room(obstacles):
    """Two robots with bodies, 0.6 m apart, their goal 2 m ahead, among ``obstacles`` (mission version 6)."""
    from vsfleet.wire import Mission, RobotSpec

    return Mission(6, "l2", (("r1", RobotSpec((0.3, 0.0), 0.12, 0.3, 0.8, radius=0.05)),
                             ("r2", RobotSpec((-0.3, 0.0), 0.12, 0.3, 0.8, radius=0.05))),
                   0.08, 0.3, 0.0, goal=(2.0, 0.0, 0.0), obstacles=obstacles)


def test_in_a_room_the_monitor_shows_the_plans_length_and_end_from_the_structure_pose():
    from vsfleet.wire import FrameMsg, encode_frame, encode_mission

    room = _two_in_a_room
    m = FleetModel("demo")
    m.ingest(T0, "vs/demo/mission", encode_mission(room(((1.0, 0.0, 0.2),))))
    m.ingest(T0, "vs/demo/frame/sim", encode_frame(FrameMsg(T0, 1, "sim", {"r1": (0.3, 0.0, 0.0)})))
    m.ingest(T0 + 0.004, "vs/demo/state/r1", encode(StateMsg(t=T0, seq=1, x=0.0, y=0.0, th=0.0, gx=0.0, gy=0.0,
                                                             gth=0.0, cost=0.0, err=0.0, used=("r1", "r2"),
                                                             rejected=0, mission=6)))
    length, blocked, end = m.view().plan
    assert not blocked and end == (2.0, 0.0, 0.0) and 2.0 < length < 3.0   # round the pillar, to the goal
    assert "plan: " in _text(m.view()) and "to the goal at (+2.000, +0.000, +0.000)" in _text(m.view())
    ring = tuple((2.0 + 0.6 * math.cos(a), 0.6 * math.sin(a), 0.12) for a in [k * math.pi / 10 for k in range(20)])
    m.ingest(T0 + 0.1, "vs/demo/mission", encode_mission(room(ring)))   # the goal walled in
    length, blocked, end = m.view().plan
    assert blocked and math.hypot(end[0] - 2.0, end[1]) > 0.6
    assert "BLOCKED" in _text(m.view())
    assert fed().view().plan is None                                     # no room, no plan


def test_in_a_room_with_reshapes_the_monitor_names_the_shape_the_agents_take_and_plans_for_it():
    from vsfleet.wire import FrameMsg, Mission, RobotSpec, encode_frame, encode_mission

    robots = (("r1", RobotSpec((0.3, 0.0), 0.12, 0.3, 0.8, radius=0.05)),
              ("r2", RobotSpec((-0.3, 0.0), 0.12, 0.3, 0.8, radius=0.05)))
    mission = Mission(6, "l2", robots, 0.08, 0.3, 0.0, goal=(2.0, 0.0, 0.0), obstacles=((1.0, 0.0, 0.2),),
                      shapes=(("wide", ((0.5, 0.0), (-0.5, 0.0))),))
    m = FleetModel("demo")
    m.ingest(T0, "vs/demo/mission", encode_mission(mission))
    m.ingest(T0, "vs/demo/frame/sim", encode_frame(FrameMsg(T0, 1, "sim", {"r1": (0.3, 0.0, 0.0)})))

    def state_of(seq, shape):
        return encode(StateMsg(t=T0 + seq / 30, seq=seq, x=0.0, y=0.0, th=0.0, gx=0.0, gy=0.0, gth=0.0, cost=0.0,
                               err=0.0, used=("r1", "r2"), rejected=0, mission=6, shape=shape))

    m.ingest(T0 + 0.004, "vs/demo/state/r1", state_of(1, 0))
    assert m.view().shape == "the template" and "shape: the template" in _text(m.view())
    template_plan = m.view().plan
    m.ingest(T0 + 0.04, "vs/demo/state/r1", state_of(2, 1))
    assert m.view().shape == "shape 1 (wide)" and "shape: shape 1 (wide)" in _text(m.view())
    assert m.view().plan != template_plan   # the wide shape's own field: another way round the pillar
    assert fed().view().shape is None       # no reshapes, no shape line


def test_in_a_room_the_monitor_draws_the_plan_and_the_bodies_swept_along_it():
    from vsfleet.fleetctl.monitor import MAP_COLS, MAP_ROWS
    from vsfleet.geometry import Pose2
    from vsfleet.step import planned_way
    from vsfleet.wire import FrameMsg, encode_frame, encode_mission

    room = _two_in_a_room
    m = FleetModel("demo")
    m.ingest(T0, "vs/demo/mission", encode_mission(room(((1.0, 0.0, 0.2),))))
    m.ingest(T0, "vs/demo/frame/sim", encode_frame(FrameMsg(T0, 1, "sim", {"r1": (0.3, 0.0, 0.0),
                                                                        "r2": (-0.3, 0.0, 0.0)})))
    m.ingest(T0 + 0.004, "vs/demo/state/r1", encode(StateMsg(t=T0, seq=1, x=0.0, y=0.0, th=0.0, gx=0.0, gy=0.0,
                                                             gth=0.0, cost=0.0, err=0.0, used=("r1", "r2"),
                                                             rejected=0, mission=6)))
    drawn = m.view().room_map
    assert 0 < len(drawn) <= MAP_ROWS and max(map(len, drawn)) <= MAP_COLS
    text = "\n".join(drawn)
    assert all(text.count(ch) >= 1 for ch in "O.:G") and text.count("#") == 2 and "B" not in text
    cols = {ch: [line.index(ch) for line in drawn if ch in line] for ch in "OG#"}
    assert max(cols["#"]) < min(cols["O"]) <= max(cols["O"]) < min(cols["G"])   # start, the pillar, the goal
    way, _ = planned_way(m.mission, Pose2(0.0, 0.0, 0.0))
    o_rows = [k for k, line in enumerate(drawn) if "O" in line]
    plan_rows = {k for k, line in enumerate(drawn) if "." in line}
    assert plan_rows - set(o_rows) and np.abs(way[:, 1]).max() > 0.2             # round the pillar, not through it
    assert "room (O obstacle" in _text(m.view()) and drawn[0] in _text(m.view())
    ring = tuple((2.0 + 0.6 * math.cos(a), 0.6 * math.sin(a), 0.12) for a in [k * math.pi / 10 for k in range(20)])
    m.ingest(T0 + 0.1, "vs/demo/mission", encode_mission(room(ring)))          # the goal walled in
    assert "B" in "\n".join(m.view().room_map) and "G" not in "\n".join(m.view().room_map)
    assert fed().view().room_map == ()                                          # no room, no map


def test_the_room_map_puts_each_disc_where_it_is_at_one_scale_both_ways():
    from vsfleet.fleetctl.monitor import room_map

    drawn = room_map([(1.0, 0.0, 0.25)], [(0.0, 0.0, 0.0), (2.0, 0.0, 0.0)], [], [(0.0, 1.0)], cols=40, rows=10)
    # x from -0.25 m... 2 m and y from -0.25 to 1 m: 2.25 m over 40 columns, 1.25 m over 10 rows of two columns each
    assert len(drawn) == 10
    (robot_row,) = [k for k, line in enumerate(drawn) if "#" in line]
    o = [(k, j) for k, line in enumerate(drawn) for j, ch in enumerate(line) if ch == "O"]
    assert robot_row == 0 and drawn[robot_row].index("#") < min(j for _, j in o)
    width = max(j for _, j in o) - min(j for _, j in o) + 1
    height = max(k for k, _ in o) - min(k for k, _ in o) + 1
    assert 6 <= width <= 10 and 3 <= height <= 5 and abs(width - 2 * height) <= 2   # a disc, not an ellipse
    assert any(line.endswith("G") for line in drawn)                  # the plan's end, the room's right edge
