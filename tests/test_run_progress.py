"""`vsfleet run`'s progress line finds the structure among a large fleet's traffic (fleetctl.run.progress_line).

A tick of ring-100 puts about 400 messages on the key space (truth, pose, cmd and state for each robot). The line
used to fit the newest complete truth frame among the newest 400 records only, and printed "waiting for truth"
in 7 to 14 of the seconds of a ring-100 run whose fleet was moving (2026-12-05).
"""

from __future__ import annotations

import math
from pathlib import Path

from vsfleet.fleetctl.run import Recorder, progress_line
from vsfleet.wire import CmdMsg, Keys, TruthMsg, encode
from vsfleet.zglue.scenario_file import load_scenario

RING_100 = Path(__file__).resolve().parents[1] / "scenarios" / "ring-100.toml"


def test_the_progress_line_of_a_fleet_of_100_fits_a_truth_frame_older_than_its_last_400_messages():
    scenario = load_scenario(RING_100)
    mission, keys = scenario.mission, Keys(scenario.fleet)
    rec = Recorder()
    # one tick's truth, every robot on its template point shifted 0.25 m along x, then a tick's other traffic
    for robot, spec in mission.robots:
        truth = TruthMsg(t=10.0, x=spec.p[0] + 0.25, y=spec.p[1], th=0.0, vl=0.0, vr=0.0)
        rec.records.append((100.0, keys.truth(robot), encode(truth)))
    for k in range(4):
        for robot, _ in mission.robots:
            rec.records.append((100.01, keys.cmd(robot), encode(CmdMsg(t=10.0, seq=k, vl=0.0, vr=0.0, ttl=0.3))))
    assert len(rec.records) - len(mission.robots) >= 400   # the truth frame is not among the newest 400
    line = progress_line(mission, rec, keys, elapsed=3.0, duration=60.0)
    assert "waiting for truth" not in line
    assert "structure (+0.250, +0.000, +0.00)" in line, line
    goal = mission.goal
    assert f"to goal {math.hypot(goal[0] - 0.25, goal[1]):.3f} m" in line, line


def test_the_recorders_tail_is_its_newest_records_oldest_first():
    rec = Recorder()
    rec.records.extend((float(i), "k", b"") for i in range(10))
    assert [r[0] for r in rec.tail(3)] == [7.0, 8.0, 9.0]
    assert len(rec.tail(50)) == 10
    assert rec.tail(0) == [] and rec.tail(-1) == []
