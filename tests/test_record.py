"""The MCAP record: raw channels per key, times, JSON and Foxglove views (the SDK's schemas);
replay's schedule, keys and frames."""

from __future__ import annotations

import io
import json
import math
import re
from datetime import datetime, timezone
from fractions import Fraction
from pathlib import Path

import foxglove.messages
import msgpack
import pytest
from mcap.reader import make_reader

from vsfleet.fleetctl.foxglove_live import layout
from vsfleet.fleetctl.foxglove_views import FleetViews

from vsfleet.fleetctl.record import (
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
from vsfleet.fleetctl.replay import Progress, offsets_s, remap_key, with_frames
from vsfleet.wire import (
    CmdMsg,
    EventMsg,
    FrameMsg,
    Mission,
    PoseMsg,
    RobotSpec,
    StateMsg,
    TruthMsg,
    decode_frame,
    encode,
    encode_event,
    encode_frame,
    encode_mission,
)

from tests.foxglove_support import decode_protobuf, protobuf_class

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


def fox_messages(path, topic):
    """The messages of a Foxglove view, decoded with the schema stored in the file, which must be the SDK's."""
    out = []
    with open(path, "rb") as f:
        for schema, channel, m in make_reader(f).iter_messages(topics=[topic]):
            sdk = getattr(foxglove.messages, schema.name.removeprefix("foxglove.")).get_schema()
            assert (schema.encoding, channel.message_encoding) == ("protobuf", "protobuf")
            assert (schema.name, schema.data) == (sdk.name, sdk.data)  # byte for byte the SDK's schema
            out.append(decode_protobuf(schema.name, schema.data, m.data))
    return out


def test_poses_truth_and_states_are_drawable_as_foxglove_poses_with_the_sdks_schema(tmp_path):
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
                   "/foxglove/vs/demo/state/r2": "foxglove.PoseInFrame",
                   "/foxglove/vs/demo/scene": "foxglove.SceneUpdate",  # the robots, from the pose
                   "/foxglove/vs/demo/tf": "foxglove.FrameTransforms"}  # world -> demo/r1
    (tf,) = fox_messages(path, "/foxglove/vs/demo/tf")
    (tr,) = tf["transforms"]
    assert (tr["parent_frame_id"], tr["child_frame_id"]) == ("world", "demo/r1")
    assert tr["translation"] == {"x": 0.5, "y": -0.25, "z": 0.0}
    assert tr["rotation"]["z"] == pytest.approx(math.sqrt(0.5))
    (pose,) = fox_messages(path, "/foxglove/vs/demo/pose/r1")
    assert pose["frame_id"] == "world"
    sec, nsec = divmod(seconds_to_ns(T0), 10**9)  # T0 to the nanosecond (protobuf JSON writes RFC 3339)
    day_time = datetime.fromtimestamp(sec, timezone.utc).strftime("%Y-%m-%dT%H:%M:%S")
    assert pose["timestamp"] == f"{day_time}.{nsec:09d}Z"
    assert pose["pose"]["position"] == {"x": 0.5, "y": -0.25, "z": 0.0}
    q = pose["pose"]["orientation"]
    assert q["x"] == 0.0 and q["y"] == 0.0
    assert q["z"] == pytest.approx(math.sqrt(0.5)) and q["w"] == pytest.approx(math.sqrt(0.5))
    (truth,) = fox_messages(path, "/foxglove/vs/demo/truth/r1")
    assert truth["pose"]["orientation"]["w"] == 1.0


def entity(update, ident):
    (e,) = [e for e in update["entities"] if e["id"] == ident]
    return e


def xy(p):
    return (p["pose"]["position"]["x"], p["pose"]["position"]["y"])


def test_after_a_mission_the_fitted_and_advanced_structure_and_targets_are_drawn_once_per_frame(tmp_path):
    path = tmp_path / "structure.mcap"
    with McapLogWriter(path) as w:
        w.write("vs/demo/state/r1", state(1, T0), seconds_to_ns(T0))  # no mission yet: no structure
        w.write("vs/demo/mission", encode_mission(MISSION), seconds_to_ns(T0) + 1)
        w.write("vs/demo/frame/cam0", encode_frame(FrameMsg(t=T0 + 0.09, seq=2, src="cam0", poses={
            "r1": (0.4, 0.3, 0.5), "r2": (0.0, 0.5, 0.5), "r3": (0.0, 0.0, 0.5)})), seconds_to_ns(T0 + 0.09))
        for agent in ("r1", "r2", "r3"):  # three agents' states of one frame: drawn once
            w.write(f"vs/demo/state/{agent}", encode(StateMsg(
                t=T0 + 0.1, seq=2, x=0.1, y=0.2, th=0.5, gx=0.12, gy=0.21, gth=0.55, cost=0.004, err=0.001,
                used=("r1", "r2", "r3"), rejected=0)), seconds_to_ns(T0 + 0.1))
    (goal,) = fox_messages(path, "/foxglove/vs/demo/goal")
    assert goal["pose"]["position"] == {"x": 0.45, "y": 0.2, "z": 0.0}
    scenes = fox_messages(path, "/foxglove/vs/demo/scene")
    mission_e = entity(scenes[0], "mission")
    assert xy(mission_e["arrows"][0]) == (0.45, 0.2)
    robots = entity(scenes[1], "robots")
    assert [t["text"] for t in robots["texts"]] == ["r1", "r2", "r3"]
    assert [xy(a) for a in robots["arrows"]] == [(0.4, 0.3), (0.0, 0.5), (0.0, 0.0)]
    structures = [s for s in scenes if any(e["id"] == "fitted" for e in s["entities"])]
    assert len(structures) == 1
    fitted, advanced, targets = (entity(structures[0], i) for i in ("fitted", "advanced", "targets"))
    points = [xy(sp) for sp in fitted["spheres"]]
    assert points == [(x, y) for x, y, _ in structure_points(MISSION, 0.1, 0.2, 0.5)]
    assert points[0] == pytest.approx((0.1 + 0.3 * math.cos(0.5), 0.2 + 0.3 * math.sin(0.5)))
    # the structure's points keep the template's distances
    assert math.dist(points[0], points[1]) == pytest.approx(math.dist((0.3, 0.0), (-0.15, 0.26)))
    assert xy(fitted["arrows"][0]) == (0.1, 0.2)
    goal_pts = [(x, y) for x, y, _ in structure_points(MISSION, 0.12, 0.21, 0.55)]
    assert [xy(sp) for sp in advanced["spheres"]] == goal_pts
    # each robot's line runs from its tracked pose to its point on the advanced structure
    line = [(p["x"], p["y"]) for p in targets["lines"][0]["points"]]
    assert line == [(0.4, 0.3), goal_pts[0], (0.0, 0.5), goal_pts[1], (0.0, 0.0), goal_pts[2]]
    assert {kv["key"]: kv["value"] for kv in fitted["metadata"]}["seq"] == "2"


def test_events_and_rejections_become_log_lines_and_a_failed_robot_is_drawn_red(tmp_path):
    path = tmp_path / "events.mcap"
    with McapLogWriter(path) as w:
        w.write("vs/demo/mission", encode_mission(MISSION), seconds_to_ns(T0))
        w.write("vs/demo/event/r1", encode_event(EventMsg(t=T0 + 1, seq=30, robot="r2", kind="fail", dev=0.08,
                                                          by="r1")), seconds_to_ns(T0 + 1))
        w.write("vs/demo/frame/cam0", encode_frame(FrameMsg(t=T0 + 1.1, seq=33, src="cam0", poses={
            "r1": (0.4, 0.3, 0.5), "r2": (0.0, 0.5, 0.5)})), seconds_to_ns(T0 + 1.1))
        w.write("vs/demo/state/r3", encode(StateMsg(t=T0 + 1.2, seq=33, x=0, y=0, th=0, gx=0, gy=0, gth=0, cost=0,
                                                    err=0, used=("r1",), rejected=4)), seconds_to_ns(T0 + 1.2))
        w.write("vs/demo/event/r3", encode_event(EventMsg(t=T0 + 2, seq=60, robot="r2", kind="fail", dev=0.08,
                                                          by="r1")), seconds_to_ns(T0 + 2))  # not r3's to say
    logs = fox_messages(path, "/foxglove/vs/demo/log")
    assert [(entry["level"], entry["name"]) for entry in logs] == [
        ("INFO", "vsfleet"), ("WARNING", "agent r1"), ("WARNING", "agent r3"), ("WARNING", "vsfleet")]
    assert "mission v3" in logs[0]["message"] and "on_failure hold" in logs[0]["message"]
    assert logs[1]["message"] == "r2: fail at frame 30 (deviation 0.080 m), decided by r1"
    assert "4 more" in logs[2]["message"]
    assert "vs/demo/event/r3" in logs[3]["message"]
    (scene,) = [s for s in fox_messages(path, "/foxglove/vs/demo/scene") if s["entities"][0]["id"] == "robots"]
    robots = entity(scene, "robots")
    colours = {t["text"]: a["color"]["r"] for t, a in zip(robots["texts"], robots["arrows"])}
    assert colours["r2"] > 0.9 and colours["r1"] < 0.2


def test_a_payload_that_is_not_a_valid_message_is_recorded_raw_with_a_log_line_and_nothing_drawn(tmp_path):
    path = tmp_path / "bad.mcap"
    with McapLogWriter(path) as w:
        w.write("vs/demo/pose/r1", b"\xc1\xc1", 10)
        w.write("vs/demo/pose/r1", msgpack.packb({"x": "not a pose"}), 20)
    chans, _ = channels(path)
    assert {c.topic for c in chans.values() if c.metadata[ROLE] == FOXGLOVE} == {"/foxglove/vs/demo/log"}
    (line,) = fox_messages(path, "/foxglove/vs/demo/log")  # one line per key and second
    assert line["level"] == "WARNING" and "vs/demo/pose/r1" in line["message"]
    assert [r.payload for r in read_log(path)] == [b"\xc1\xc1", msgpack.packb({"x": "not a pose"})]


def test_the_shipped_layout_is_the_one_vsfleet_foxglove_writes_and_names_only_topics_that_exist(tmp_path):
    shipped = json.loads((Path(__file__).parent.parent / "docs" / "foxglove-layout.json").read_text())
    assert shipped == json.loads(layout("demo", ["r1", "r2", "r3"]).to_json())
    path = tmp_path / "all.mcap"
    with McapLogWriter(path) as w:
        w.write("vs/demo/mission", encode_mission(MISSION), seconds_to_ns(T0))
        for r in ("r1", "r2", "r3"):
            w.write(f"vs/demo/truth/{r}", encode(TruthMsg(t=T0, x=0, y=0, th=0, vl=0, vr=0)), seconds_to_ns(T0))
            w.write(f"vs/demo/cmd/{r}", encode(CmdMsg(t=T0, seq=1, vl=0.1, vr=0.1, ttl=0.3)), seconds_to_ns(T0))
            w.write(f"vs/demo/state/{r}", state(1, T0), seconds_to_ns(T0))
    chans, _ = channels(path)
    topics = {c.topic for c in chans.values()}
    text = json.dumps(shipped)
    named = set(re.findall(r'"(/(?:foxglove|json)/vs/demo/[^".]+)', text))
    assert named and named <= topics, named - topics
    for r in ("r1", "r2", "r3"):
        assert f"/json/vs/demo/state/{r}.err" in text and f"/json/vs/demo/cmd/{r}.vl" in text


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


def pose_rec(i: int, robot: str, seq: int, t: float, src: str = "cam0", x: float = 0.0) -> LogRecord:
    payload = encode(PoseMsg(t=t, seq=seq, x=x, y=0.5, th=0.25, src=src))
    return LogRecord(1000 + i, seconds_to_ns(t), f"vs/demo/pose/{robot}", payload)


def test_replay_of_a_pose_only_recording_adds_one_frame_per_src_and_seq_after_its_last_pose():
    recs = [pose_rec(0, "r1", 7, T0, x=0.1), pose_rec(1, "r2", 7, T0 + 0.001, x=0.2),
            LogRecord(1002, 1002, "vs/demo/cmd/r1", b"\x80"),
            pose_rec(3, "r3", 7, T0 + 0.002, x=0.3),
            pose_rec(4, "r1", 8, T0 + 0.033, x=0.4), pose_rec(5, "r1", 1, T0 + 0.05, src="cam1", x=0.5),
            pose_rec(6, "r2", 8, T0 + 0.034, x=0.6)]
    out = with_frames(recs)
    assert [r.key for r in out] == [
        "vs/demo/pose/r1", "vs/demo/pose/r2", "vs/demo/cmd/r1", "vs/demo/pose/r3", "vs/demo/frame/cam0",
        "vs/demo/pose/r1", "vs/demo/pose/r1", "vs/demo/frame/cam1", "vs/demo/pose/r2", "vs/demo/frame/cam0"]
    assert [r for r in out if "/frame/" not in r.key] == recs  # every recorded message, in its order
    f7, c1, f8 = (decode_frame(r.payload) for r in out if "/frame/" in r.key)
    assert (f7.seq, f7.src, f7.t) == (7, "cam0", T0 + 0.002)  # t: the newest pose of the frame
    assert f7.poses == {"r1": (0.1, 0.5, 0.25), "r2": (0.2, 0.5, 0.25), "r3": (0.3, 0.5, 0.25)}
    assert f8.poses == {"r1": (0.4, 0.5, 0.25), "r2": (0.6, 0.5, 0.25)} and c1.poses == {"r1": (0.5, 0.5, 0.25)}
    frame7 = out[4]
    assert frame7.log_time_ns == recs[3].log_time_ns and frame7.publish_time_ns == seconds_to_ns(T0 + 0.002)


def test_replay_adds_no_frames_for_a_source_whose_frames_were_recorded_nor_for_bad_poses():
    frame = encode_frame(FrameMsg(t=T0, seq=7, src="cam0", poses={"r1": (0.1, 0.5, 0.25)}))
    recs = [pose_rec(0, "r1", 7, T0), LogRecord(1001, seconds_to_ns(T0), "vs/demo/frame/cam0", frame),
            LogRecord(1002, 1002, "vs/demo/pose/r2", b"\xc1 not a pose"),
            LogRecord(1003, 1003, "vs/demo/pose/r3", encode(PoseMsg(t=T0, seq=1, x=0, y=0, th=0, src="bad src")))]
    assert with_frames(recs) == recs


def test_the_mission_is_redrawn_once_a_second_with_the_structure_for_viewers_that_join_late():
    views = FleetViews()
    t0 = seconds_to_ns(T0)
    views.on_message("vs/demo/mission", encode_mission(MISSION), t0)

    def ids_at(seq: int, t: float) -> list[str]:
        out = views.on_message("vs/demo/state/r1", state(seq, t), 0)
        (scene,) = [v.message for v in out if v.topic == "/foxglove/vs/demo/scene"]
        return [e.id for e in decode_scene(scene).entities]

    assert ids_at(1, T0 + 0.5) == ["fitted", "advanced", "targets"]
    assert ids_at(2, T0 + 1.2) == ["fitted", "advanced", "targets", "mission"]
    assert ids_at(3, T0 + 1.5) == ["fitted", "advanced", "targets"]


def decode_scene(msg):
    schema = type(msg).get_schema()
    cls = protobuf_class(schema.name, schema.data)
    return cls.FromString(msg.encode())


def test_views_turn_away_times_a_foxglove_timestamp_cannot_hold_and_robots_beyond_the_limit():
    views = FleetViews()
    good = FrameMsg(t=T0, seq=1, src="cam0", poses={"r1": (0.0, 0.0, 0.0)})
    assert [v.topic for v in views.on_message("vs/demo/frame/cam0", encode_frame(good), 0)] == \
        ["/foxglove/vs/demo/scene", "/foxglove/vs/demo/tf"]
    for t in (-1.0, 2.0**32):  # before 1970, after 2106: the wire accepts them, foxglove.Timestamp cannot
        bad = FrameMsg(t=t, seq=2, src="cam0", poses={"r1": (1.0, 0.0, 0.0)})
        (line,) = views.on_message("vs/demo/frame/cam0", encode_frame(bad), seconds_to_ns(T0))
        assert line.topic == "/foxglove/vs/demo/log" and "Foxglove timestamp" in line.message.encode().decode("latin1")
        views._last_reject_log.clear()
    assert views.now_ns == seconds_to_ns(T0)  # the clock is not moved by a message turned away
    assert views.fleets["demo"].poses == {"r1": (0.0, 0.0, 0.0)}
    many = FrameMsg(t=T0 + 1, seq=3, src="cam0", poses={f"x{i}": (0.0, 0.0, 0.0) for i in range(1000)})
    (line,) = views.on_message("vs/demo/frame/cam0", encode_frame(many), 0)
    assert line.topic == "/foxglove/vs/demo/log" and len(views.fleets["demo"].poses) == 1


def test_views_turn_away_a_frame_whose_src_is_not_its_keys_and_keys_that_are_not_one_chunk():
    views = FleetViews()
    frame = encode_frame(FrameMsg(t=T0, seq=1, src="cam0", poses={"r1": (0.0, 0.0, 0.0)}))
    (line,) = views.on_message("vs/demo/frame/cam1", frame, seconds_to_ns(T0))
    assert line.topic == "/foxglove/vs/demo/log"
    pose = encode(PoseMsg(t=T0, seq=1, x=0, y=0, th=0, src="cam0"))
    assert [v.topic for v in views.on_message("vs/demo/pose/r1/extra", pose, seconds_to_ns(T0) + 1)] == \
        ["/foxglove/vs/demo/log"]
    assert views.fleets["demo"].poses == {} and views.turned_away == 2
