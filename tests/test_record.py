"""The MCAP record: raw channels per key, times, JSON and Foxglove views; replay's schedule and keys."""

from __future__ import annotations

import io
import json
import math
from fractions import Fraction

import msgpack
import pytest
from mcap.reader import make_reader

from fleetctl.record import (
    FOXGLOVE,
    JSON_ROLE,
    LIVELINESS,
    RAW,
    ROLE,
    LogRecord,
    McapLogWriter,
    publish_time_ns,
    read_log,
    seconds_to_ns,
    structure_points,
)
from fleetctl.replay import Progress, offsets_s, remap_key
from vsfleet.wire import Mission, PoseMsg, RobotSpec, StateMsg, TruthMsg, encode, encode_mission

T0 = 1795378504.397066
MISSION = Mission(version=3, metric="linf", speed_max=0.08, turn_rate_max=0.3, effective_t=T0,
                  goal=(0.45, 0.2, 0.1),
                  robots=(("r1", RobotSpec((0.3, 0.0), 0.12, 0.3, 0.8)),
                          ("r2", RobotSpec((-0.15, 0.26), 0.12, 0.3, 0.8)),
                          ("r3", RobotSpec((-0.15, -0.26), 0.12, 0.3, 0.8))))


def state(seq: int, t: float, x: float = 0.1, y: float = 0.2, th: float = 0.5) -> bytes:
    return encode(StateMsg(t=t, seq=seq, x=x, y=y, th=th, gx=x, gy=y, gth=th, cost=0.0, err=0.001,
                           used=("r1", "r2", "r3"), rejected=0))


def channels(path):
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    return summary.channels, summary.schemas


def messages(path, topic):
    with open(path, "rb") as f:
        return [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=[topic])]


def test_seconds_become_the_nearest_nanosecond_of_the_float_for_times_near_now():
    assert seconds_to_ns(T0) == round(Fraction(T0) * 10**9)  # T0*1e9 in float64 would be off by up to 128 ns
    assert seconds_to_ns(1.5) == 1_500_000_000


def test_publish_time_is_the_payloads_t_else_the_zenoh_timestamp_else_the_receive_time():
    pose = encode(PoseMsg(t=T0, seq=1, x=0.0, y=0.0, th=0.0, src="s"))
    assert publish_time_ns(pose, 5, 7) == seconds_to_ns(T0)
    no_t = encode_mission(MISSION)
    assert publish_time_ns(no_t, 5, 7) == 5
    assert publish_time_ns(no_t, None, 7) == 7
    assert publish_time_ns(b"\xc1 not msgpack", None, 7) == 7
    assert publish_time_ns(msgpack.packb({"t": "yesterday"}), None, 7) == 7


def test_a_log_keeps_every_payload_byte_for_byte_with_its_key_and_times_in_receive_order(tmp_path):
    path = tmp_path / "log.mcap"
    sent = []
    with McapLogWriter(path) as w:
        for i in range(50):
            for r in ("r1", "r2"):
                payload = encode(PoseMsg(t=T0 + i / 30, seq=i, x=i * 0.01, y=-0.1, th=0.0, src="s"))
                sent.append(w.write(f"vs/demo/pose/{r}", payload, seconds_to_ns(T0 + i / 30) + 1000))
        sent.append(w.write("vs/demo/blob", b"\xc1 not msgpack at all", seconds_to_ns(T0 + 2)))
        sent.append(w.write_liveliness("vs/demo/alive/agent/r1", False, seconds_to_ns(T0 + 3)))
    got = read_log(path)
    assert got == sent
    assert [r.payload for r in got[:2]] == [s.payload for s in sent[:2]]
    assert got[0].publish_time_ns == seconds_to_ns(T0)
    assert got[-1].role == LIVELINESS and got[-1].alive is False


def test_log_times_strictly_increase_even_when_receive_times_tie(tmp_path):
    path = tmp_path / "tie.mcap"
    with McapLogWriter(path) as w:
        for i in range(5):
            w.write(f"vs/demo/cmd/r{i}", msgpack.packb({"i": i}), 1000)
    got = read_log(path)
    assert [r.log_time_ns for r in got] == [1000, 1001, 1002, 1003, 1004]
    assert [msgpack.unpackb(r.payload)["i"] for r in got] == [0, 1, 2, 3, 4]


def test_there_is_one_raw_msgpack_channel_per_key(tmp_path):
    path = tmp_path / "keys.mcap"
    with McapLogWriter(path) as w:
        for i in range(3):
            for key in ("vs/demo/pose/r1", "vs/demo/pose/r2", "vs/demo/truth/r1"):
                w.write(key, encode(TruthMsg(t=T0 + i, x=0, y=0, th=0, vl=0, vr=0)), seconds_to_ns(T0 + i))
    chans, _ = channels(path)
    raw = [c for c in chans.values() if c.metadata[ROLE] == RAW]
    assert sorted(c.topic for c in raw) == ["vs/demo/pose/r1", "vs/demo/pose/r2", "vs/demo/truth/r1"]
    assert {c.message_encoding for c in raw} == {"msgpack"} and {c.schema_id for c in raw} == {0}


def test_every_message_has_a_json_mirror_with_a_jsonschema(tmp_path):
    path = tmp_path / "json.mcap"
    payload = state(7, T0)
    with McapLogWriter(path) as w:
        w.write("vs/demo/state/r1", payload, seconds_to_ns(T0))
    chans, schemas = channels(path)
    (mirror,) = [c for c in chans.values() if c.metadata[ROLE] == JSON_ROLE]
    assert mirror.topic == "/json/vs/demo/state/r1" and mirror.message_encoding == "json"
    assert schemas[mirror.schema_id].encoding == "jsonschema"
    assert schemas[mirror.schema_id].name == "vsfleet.state"
    assert messages(path, mirror.topic) == [msgpack.unpackb(payload)]


def test_poses_truth_and_states_are_drawable_as_foxglove_poses_in_the_world_frame(tmp_path):
    path = tmp_path / "fox.mcap"
    with McapLogWriter(path) as w:
        w.write("vs/demo/pose/r1", encode(PoseMsg(t=T0, seq=1, x=0.5, y=-0.25, th=math.pi / 2, src="s")),
                seconds_to_ns(T0) + 5)
        w.write("vs/demo/truth/r1", encode(TruthMsg(t=T0, x=0.5, y=-0.25, th=0.0, vl=0, vr=0)), seconds_to_ns(T0) + 6)
        w.write("vs/demo/state/r2", state(1, T0), seconds_to_ns(T0) + 7)
    chans, schemas = channels(path)
    fox = {c.topic: schemas[c.schema_id].name for c in chans.values() if c.metadata[ROLE] == FOXGLOVE}
    assert fox == {"/foxglove/vs/demo/pose/r1": "foxglove.PoseInFrame",
                   "/foxglove/vs/demo/truth/r1": "foxglove.PoseInFrame",
                   "/foxglove/vs/demo/state/r2": "foxglove.PoseInFrame"}
    (pose,) = messages(path, "/foxglove/vs/demo/pose/r1")
    assert pose["frame_id"] == "world"
    assert pose["timestamp"] == {"sec": 1795378504, "nsec": seconds_to_ns(T0) - 1795378504 * 10**9}
    assert pose["pose"]["position"] == {"x": 0.5, "y": -0.25, "z": 0.0}
    q = pose["pose"]["orientation"]
    assert q["x"] == 0.0 and q["y"] == 0.0
    assert q["z"] == pytest.approx(math.sqrt(0.5)) and q["w"] == pytest.approx(math.sqrt(0.5))


def test_after_a_mission_the_structure_points_and_the_goal_are_drawn_once_per_frame(tmp_path):
    path = tmp_path / "structure.mcap"
    with McapLogWriter(path) as w:
        w.write("vs/demo/state/r1", state(1, T0), seconds_to_ns(T0))  # no mission yet: no structure
        w.write("vs/demo/mission", encode_mission(MISSION), seconds_to_ns(T0) + 1)
        for agent in ("r1", "r2", "r3"):
            w.write(f"vs/demo/state/{agent}", state(2, T0 + 0.1), seconds_to_ns(T0 + 0.1))
    (goal,) = messages(path, "/foxglove/vs/demo/goal")
    assert goal["pose"]["position"] == {"x": 0.45, "y": 0.2, "z": 0.0}
    (frame,) = messages(path, "/foxglove/vs/demo/structure")
    points = [(p["position"]["x"], p["position"]["y"]) for p in frame["poses"]]
    want = [(x, y) for x, y, _ in structure_points(MISSION, 0.1, 0.2, 0.5)]
    assert points == want
    assert points[0] == pytest.approx((0.1 + 0.3 * math.cos(0.5), 0.2 + 0.3 * math.sin(0.5)))
    # the structure's points keep the template's distances
    assert math.dist(points[0], points[1]) == pytest.approx(math.dist((0.3, 0.0), (-0.15, 0.26)))


def test_a_payload_that_is_not_msgpack_is_recorded_raw_without_derived_views(tmp_path):
    path = tmp_path / "bad.mcap"
    with McapLogWriter(path) as w:
        w.write("vs/demo/pose/r1", b"\xc1\xc1", 10)
        w.write("vs/demo/pose/r1", msgpack.packb({"x": "not a pose"}), 20)
    chans, _ = channels(path)
    assert {c.metadata[ROLE] for c in chans.values()} == {RAW, JSON_ROLE}
    assert [r.payload for r in read_log(path)] == [b"\xc1\xc1", msgpack.packb({"x": "not a pose"})]


def test_replay_moves_keys_to_another_fleet_and_leaves_other_keys_alone():
    assert remap_key("vs/demo/pose/r1", "lab") == "vs/lab/pose/r1"
    assert remap_key("vs/demo/mission", "lab") == "vs/lab/mission"
    assert remap_key("vs/demo/alive/agent/r1", "lab") == "vs/lab/alive/agent/r1"
    assert remap_key("other/key", "lab") == "other/key"
    assert remap_key("vs/demo/pose/r1", None) == "vs/demo/pose/r1"


def test_replay_sends_at_the_recorded_pace_divided_by_the_speed():
    recs = [LogRecord(t, t, "vs/d/pose/r1", b"") for t in (1_000_000_000, 1_500_000_000, 3_000_000_000)]
    assert offsets_s(recs, 1.0) == pytest.approx([0.0, 0.5, 2.0])
    assert offsets_s(recs, 4.0) == pytest.approx([0.0, 0.125, 0.5])
    with pytest.raises(ValueError):
        offsets_s(recs, 0.0)


def test_replay_progress_line_shows_position_count_and_eta():
    line = Progress.line(done_s=10.0, total_s=30.0, sent=100, n=300, speed=2.0)
    assert "10.0/30.0 s" in line and "100/300" in line and "ETA  10.0 s" in line


def test_replay_progress_prints_a_periodic_line_when_not_on_a_terminal():
    out = io.StringIO()
    bar = Progress(total_s=3.0, n=3, speed=1.0, enabled=True, every_s=1.0, out=out)
    bar.update(0.0, 1, now_s=100.0)
    bar.update(0.5, 2, now_s=100.5)   # within the period: no line
    bar.update(1.5, 3, now_s=101.2)
    bar.close(3.0, 3)
    assert out.getvalue().count("[replay]") == 3
