"""vsfleet plot: the paper's Figures 9, 10 and 12 from a log (synthetic fleet, exact geometry)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from vsfleet.fleetctl import plot
from vsfleet.fleetctl.plot import FaultMark, add_timeline, extract, write_plots
from vsfleet.fleetctl.record import LogRecord, publish_time_ns, seconds_to_ns, structure_points, write_log
from vsfleet.scenario import FaultEvent
from vsfleet.wire import (FaultMsg, Mission, PoseMsg, RobotSpec, StateMsg, TruthMsg, encode,
                          encode_mission)

T0 = 1795378500.0
ROBOTS = ("r1", "r2", "r3")
MISSION = Mission(version=1, metric="l2", speed_max=0.1, turn_rate_max=0.3, effective_t=T0, goal=(0.5, 0.0, 0.0),
                  robots=(("r1", RobotSpec((0.3, 0.0), 0.12, 0.3, 0.8)),
                          ("r2", RobotSpec((-0.15, 0.26), 0.12, 0.3, 0.8)),
                          ("r3", RobotSpec((-0.15, -0.26), 0.12, 0.3, 0.8))))
PNG = b"\x89PNG\r\n\x1a\n"


def rec(key: str, payload: bytes, t_s: float) -> LogRecord:
    log_ns = seconds_to_ns(t_s)
    return LogRecord(log_ns, publish_time_ns(payload, None, log_ns), key, payload)


def synthetic_log(fleet: str = "demo", truth: bool = True, mission: bool = True, fault_at_s: float | None = None,
                  frames: int = 200) -> list[LogRecord]:
    """A structure sliding along +x at 0.1 m/s; r1 wobbles off its point by up to 4 mm; 50 Hz."""
    out = [rec(f"vs/{fleet}/mission", encode_mission(MISSION), T0 - 0.5)] if mission else []
    for k in range(frames):
        t = T0 + k * 0.02
        sx = 0.1 * (t - T0)
        pts = structure_points(MISSION, sx, 0.0, 0.0)
        for i, r in enumerate(ROBOTS):
            x, y, _ = pts[i]
            if r == "r1":
                y += 0.004 * math.sin(k / 10)
            if truth:
                out.append(rec(f"vs/{fleet}/truth/{r}", encode(TruthMsg(t=t, x=x, y=y, th=0.0, vl=0.1, vr=0.1)), t))
            out.append(rec(f"vs/{fleet}/pose/{r}", encode(PoseMsg(t=t, seq=k, x=x, y=y, th=0.0, src="s")), t))
            out.append(rec(f"vs/{fleet}/state/{r}", encode(StateMsg(
                t=t, seq=k, x=sx, y=0.0, th=0.0, gx=sx, gy=0.0, gth=0.0, cost=0.001, err=0.001 * (i + 1),
                used=ROBOTS, rejected=0)), t + 0.005))
        if fault_at_s is not None and abs(t - T0 - fault_at_s) < 1e-9:
            out.append(rec(f"vs/{fleet}/fault/r2", encode(FaultMsg("stop", 0.0, 0.0)), t))
    return out


def lines_by_label(fig):
    return [line.get_label() for ax in fig.axes for line in ax.get_lines()]


def test_the_trajectory_plot_has_one_line_per_robot_plus_the_structure_and_the_goal_with_labelled_axes():
    data = extract(synthetic_log())
    fig = plot.trajectory_figure(data)
    labels = lines_by_label(fig)
    for r in ROBOTS:
        assert labels.count(r) == 1
    assert "goal" in labels and any(label.startswith("structure") for label in labels)
    ax = fig.axes[0]
    assert ax.get_xlabel() == "x [m]" and ax.get_ylabel() == "y [m]"
    (r1,) = [line for line in ax.get_lines() if line.get_label() == "r1"]
    assert r1.get_xdata()[0] == pytest.approx(0.3) and r1.get_xdata()[-1] == pytest.approx(0.3 + 0.1 * 199 * 0.02)


def test_without_truth_the_robots_paths_come_from_the_tracker_poses():
    data = extract(synthetic_log(truth=False))
    fig = plot.trajectory_figure(data)
    assert "tracker poses" in fig.axes[0].get_title()
    assert sorted(label for label in lines_by_label(fig) if label in ROBOTS) == list(ROBOTS)


def test_the_deviation_plot_has_one_line_per_robot_annotated_with_its_mean_sigma_and_max():
    fig = plot.deviation_figure(extract(synthetic_log()))
    ax = fig.axes[0]
    assert ax.get_xlabel() == "time [s]" and ax.get_ylabel() == "deviation from structure [cm]"
    lines = ax.get_lines()
    assert [line.get_label().split(":")[0] for line in lines] == list(ROBOTS)
    for line in lines:
        y = np.asarray(line.get_ydata())
        mean, sigma, peak = map(float, re.findall(r"([0-9.]+) cm", line.get_label()))
        assert (mean, sigma, peak) == (round(y.mean(), 2), round(y.std(), 2), round(y.max(), 2))
    r1 = np.asarray(lines[0].get_ydata())
    assert 0.1 < r1.max() < 0.4  # r1 wobbles by up to 0.4 cm; the fit shares part of it


def test_without_a_mission_the_deviation_falls_back_to_the_agents_err():
    fig = plot.deviation_figure(extract(synthetic_log(mission=False)))
    assert "err" in fig.axes[0].get_title()
    assert [float(np.max(line.get_ydata())) for line in fig.axes[0].get_lines()] == pytest.approx([0.1, 0.2, 0.3])


def test_the_fault_plot_marks_the_time_of_a_fault_message_and_draws_one_line_per_robot():
    data = extract(synthetic_log(fault_at_s=2.0))
    assert data.faults == [FaultMark(T0 + 2.0, "r2", "stop", "fault message")]
    fig = plot.fault_figure(data)
    ax = fig.axes[0]
    (mark,) = [line for line in ax.get_lines() if line.get_label().startswith("fault:")]
    assert list(mark.get_xdata()) == pytest.approx([2.0, 2.0])
    assert "r2 stop" in mark.get_label()
    assert [line.get_label() for line in ax.get_lines() if line is not mark] == list(ROBOTS)
    assert ax.get_xlabel() == "time [s]" and "[cm]" in ax.get_ylabel()


def test_a_fault_event_or_a_scenario_timeline_also_marks_the_fault():
    assert plot.fault_from_event({"kind": "fault", "robot": "r3", "fault": "slow", "t": T0 + 1}, 0.0) == \
        FaultMark(T0 + 1, "r3", "slow", "event")
    assert plot.fault_from_event({"kind": "mission", "version": 2}, 0.0) is None
    data = extract(synthetic_log())
    add_timeline(data, [FaultEvent(robot="r1", at_s=1.5, kind="wheel", factor=0.0, duration=0.0)])
    assert data.faults == [FaultMark(T0 + 1.5, "r1", "wheel", "scenario")]
    assert plot.fault_figure(data) is not None


def test_without_fault_information_fault_png_is_skipped_and_the_notes_say_so(tmp_path):
    result = write_plots(extract(synthetic_log()), tmp_path)
    assert sorted(p.name for p in result.written) == ["deviation.png", "trajectories.png"]
    assert any("fault.png skipped" in note for note in result.notes)
    for p in result.written:
        assert p.read_bytes()[:8] == PNG


def test_a_log_with_several_fleets_needs_a_fleet_choice():
    log = synthetic_log("a", frames=3) + synthetic_log("b", frames=3)
    with pytest.raises(ValueError, match="--fleet"):
        extract(log)
    assert extract(log, fleet="b").fleet == "b"


def test_vsfleet_plot_writes_the_three_pngs_of_an_mcap_file(tmp_path, capsys):
    path = tmp_path / "run.mcap"
    write_log(path, synthetic_log(fault_at_s=2.0))
    assert plot.main([str(path), "--out", str(tmp_path / "png")]) == 0
    for name in ("trajectories.png", "deviation.png", "fault.png"):
        assert (tmp_path / "png" / name).read_bytes()[:8] == PNG
    assert "wrote" in capsys.readouterr().out


def test_in_a_room_obstacles_are_filled_circles_and_bodies_circles_at_the_robots_first_and_last_positions():
    import dataclasses

    from matplotlib.patches import Circle

    room = dataclasses.replace(MISSION, obstacles=((0.4, 0.6, 0.1), (-0.5, -0.5, 0.05)), robots=tuple(
        (r, dataclasses.replace(s, radius=0.05) if r != "r3" else s) for r, s in MISSION.robots))
    log = [rec("vs/demo/mission", encode_mission(room), T0 - 0.5), *synthetic_log(mission=False)]
    data = extract(log)
    ax = plot.trajectory_figure(data).axes[0]
    circles = {p.get_gid(): p for p in ax.patches if isinstance(p, Circle)}
    assert [(circles[f"obstacle {i}"].center, circles[f"obstacle {i}"].radius) for i in (0, 1)] == \
        [((0.4, 0.6), 0.1), ((-0.5, -0.5), 0.05)]
    assert all(circles[f"obstacle {i}"].get_fill() for i in (0, 1))
    bodies = [p for p in ax.patches if isinstance(p, Circle) and p.get_gid() == "body r1"]
    assert [b.center for b in bodies] == [(data.truth["r1"][0].x, data.truth["r1"][0].y),
                                          (data.truth["r1"][-1].x, data.truth["r1"][-1].y)]
    assert all(b.radius == 0.05 and not b.get_fill() for b in bodies)
    assert not any(p.get_gid() == "body r3" for p in ax.patches)      # a point robot has no body
    assert "obstacles" in [h.get_label() for h in ax.get_legend().legend_handles]


def test_without_a_room_no_circles_are_drawn():
    from matplotlib.patches import Circle

    ax = plot.trajectory_figure(extract(synthetic_log())).axes[0]
    assert not [p for p in ax.patches if isinstance(p, Circle)]


def test_in_a_room_the_plan_from_the_first_fitted_pose_and_the_bodies_swept_along_it_are_drawn():
    import dataclasses

    from matplotlib.patches import Circle

    from vsfleet.geometry import Pose2
    from vsfleet.step import planned_way

    room = dataclasses.replace(MISSION, goal=(1.6, 0.0, 0.0), obstacles=((0.8, 0.0, 0.2),), robots=tuple(
        (r, dataclasses.replace(s, radius=0.05)) for r, s in MISSION.robots))
    log = [rec("vs/demo/mission", encode_mission(room), T0 - 0.5), *synthetic_log(mission=False)]
    ax = plot.trajectory_figure(extract(log)).axes[0]
    plan = [line for line in ax.get_lines() if line.get_label().startswith("plan from the start")]
    way, blocked = planned_way(room, Pose2(0.0, 0.0, 0.0))
    assert len(plan) == 1 and not blocked
    assert np.array_equal(plan[0].get_xdata(), way[:, 0]) and np.array_equal(plan[0].get_ydata(), way[:, 1])
    assert tuple(way[-1]) == (1.6, 0.0, 0.0)
    assert np.hypot(way[:, 0] - 0.8, way[:, 1]).min() > 0.2           # around the pillar, not through it
    swept = [p for p in ax.patches if isinstance(p, Circle) and p.get_gid() == "swept body"]
    assert len(swept) >= 3 * 10 and all(p.radius == 0.05 for p in swept)
    for p in swept:                                                     # no swept body touches the pillar
        assert math.hypot(p.center[0] - 0.8, p.center[1]) >= 0.2 + 0.05


def test_a_reshape_draws_the_plan_of_each_shape_taken_from_where_it_was_taken():
    """The structure changes shape (its states say so): the plan of the new shape is drawn from the state where
    it took it, and the bodies swept along it are at that shape's points (before, only the template's plan from
    the start was drawn, whatever shape the structure took)."""
    import dataclasses

    from matplotlib.patches import Circle

    from vsfleet.geometry import Pose2
    from vsfleet.step import planned_way

    column = ("column", ((0.3, 0.0), (0.0, 0.0), (-0.3, 0.0)))
    room = dataclasses.replace(MISSION, goal=(1.6, 0.0, 0.0), obstacles=((0.8, 0.0, 0.2),), shapes=(column,),
                               robots=tuple((r, dataclasses.replace(s, radius=0.05)) for r, s in MISSION.robots))
    log = [rec("vs/demo/mission", encode_mission(room), T0 - 0.5)]
    for k in range(100):   # the structure slides along +x, and takes the column (shape 1) from frame 50 on
        t, sx = T0 + k * 0.02, 0.002 * k
        out = encode(StateMsg(t=t, seq=k, x=sx, y=0.0, th=0.0, gx=sx, gy=0.0, gth=0.0, cost=0.001, err=0.001,
                              used=ROBOTS, rejected=0, shape=1 if k >= 50 else 0))
        log.append(rec("vs/demo/state/r1", out, t + 0.005))
    ax = plot.trajectory_figure(extract(log)).axes[0]
    plans = {line.get_label(): line for line in ax.get_lines() if line.get_label().startswith("plan from")}
    assert sorted(plans) == ["plan from 1.0 s (shape 1 (column))", "plan from the start"], sorted(plans)
    way, _ = planned_way(room, Pose2(0.1, 0.0, 0.0), shape=1)
    later = plans["plan from 1.0 s (shape 1 (column))"]
    assert np.array_equal(later.get_xdata(), way[:, 0]) and np.array_equal(later.get_ydata(), way[:, 1])
    first_column = structure_points(room, *way[0], shape=1)      # the column's bodies where that plan begins
    centres = {tuple(np.round(p.center, 9)) for p in ax.patches
               if isinstance(p, Circle) and p.get_gid() == "swept body"}
    assert all(tuple(np.round((x, y), 9)) in centres for x, y, _ in first_column)
    assert tuple(np.round(structure_points(room, *way[0])[1][:2], 9)) not in centres   # not the template's r2 there


def test_the_swept_bodies_are_drawn_at_the_plans_first_pose_every_spacing_and_its_last():
    from vsfleet.fleetctl.foxglove_views import swept_poses

    way = [(0.05 * k, 0.0, 0.0) for k in range(11)]               # 0.5 m along x, every 5 cm
    assert [round(p[0], 9) for p in swept_poses(way, 0.14)] == [0.0, 0.15, 0.3, 0.45, 0.5]   # 3 steps a set
    assert swept_poses(way[:1], 0.15) == [(0.0, 0.0, 0.0)] and swept_poses([], 0.15) == []
