"""vsfleet foxglove in one process: a loopback zenoh router, the live server, and a protocol client.

The client (tests/foxglove_support.py) speaks the Foxglove WebSocket protocol
from its spec; it checks the server's info, the SDK schemas it advertises, the
scene, the log and the time it broadcasts (the tracker's clock).
"""

from __future__ import annotations

import base64
import json
import threading
import time

import foxglove.messages
import pytest
import zenoh

from vsfleet.fleetctl.foxglove_live import LiveServer
from vsfleet.fleetctl.foxglove_views import seconds_to_ns, structure_points
from vsfleet.fleetctl.router import open_loopback_router
from tests.foxglove_support import FoxgloveClient
from vsfleet.wire import FrameMsg, Mission, RobotSpec, StateMsg, encode, encode_frame, encode_mission

T0 = time.time()
MISSION = Mission(version=1, metric="linf", speed_max=0.08, turn_rate_max=0.3, effective_t=T0,
                  goal=(1.0, 0.5, 0.2),
                  robots=(("r1", RobotSpec((0.3, 0.0), 0.12, 0.3, 0.8)),
                          ("r2", RobotSpec((-0.15, 0.26), 0.12, 0.3, 0.8))))


def client_conf(endpoint: str) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


@pytest.fixture
def live():
    router, endpoint = open_loopback_router()
    payload = encode_mission(MISSION)  # the operator answers mission queries, as vsfleet run does
    queryable = router.declare_queryable("vs/lab/mission", lambda q: q.reply("vs/lab/mission", payload))
    server = LiveServer(client_conf(endpoint), "lab", "127.0.0.1", 0)
    client = FoxgloveClient(f"ws://127.0.0.1:{server.port}")
    yield router, server, client
    client.close()
    server.close()
    queryable.undeclare()
    router.close()


def frame(seq: int) -> FrameMsg:
    return FrameMsg(t=T0 + seq / 30, seq=seq, src="cam0", poses={"r1": (0.3 + 0.01 * seq, 0.0, 0.1),
                                                                 "r2": (-0.15, 0.26, 0.2)})


def test_the_server_serves_the_fleet_with_the_sdks_schemas_and_broadcasts_the_trackers_clock(live):
    router, server, client = live
    client.wait_for(lambda c: c.server_info is not None, 10)
    assert client.subprotocol in ("foxglove.sdk.v1", "foxglove.websocket.v1")
    assert "time" in client.server_info["capabilities"]
    router.put("vs/lab/frame/cam0", encode_frame(frame(1)))
    client.wait_for(lambda c: {"/foxglove/vs/lab/scene", "/json/vs/lab/mission", "/foxglove/vs/lab/log"}
                    <= set(c.topics()), 10)  # the mission came from the query at start
    ch = client.topics()["/foxglove/vs/lab/scene"]
    sdk = foxglove.messages.SceneUpdate.get_schema()
    assert (ch["encoding"], ch["schemaName"]) == ("protobuf", "foxglove.SceneUpdate")
    assert base64.b64decode(ch["schema"]) == sdk.data
    client.subscribe(["/foxglove/vs/lab/scene", "/foxglove/vs/lab/log"])
    seq = 1
    while not client.messages["/foxglove/vs/lab/scene"]:  # until the subscription is in place
        seq += 1
        router.put("vs/lab/frame/cam0", encode_frame(frame(seq)))
        try:
            client.wait_for(lambda c: c.messages["/foxglove/vs/lab/scene"], 0.2)
        except TimeoutError:
            assert seq < 100, "no scene after 100 frames"
    sent = {seconds_to_ns(frame(i).t): frame(i) for i in range(1, seq + 1)}
    t_ns, update = client.messages["/foxglove/vs/lab/scene"][0]
    (robots,) = update["entities"]
    assert robots["id"] == "robots" and t_ns in sent  # stamped with the frame's t
    assert [(a["pose"]["position"]["x"], a["pose"]["position"]["y"]) for a in robots["arrows"]] == \
        [sent[t_ns].poses[r][:2] for r in ("r1", "r2")]
    client.wait_for(lambda c: max(sent) in c.times, 5)
    assert set(client.times) <= set(sent)  # the server's time is the frames' t
    assert client.times == sorted(client.times)  # the tracker's clock only goes forward

    state = StateMsg(t=frame(seq).t + 0.004, seq=seq, x=0.01, y=0.02, th=0.1, gx=0.02, gy=0.02, gth=0.1, cost=0.003,
                     err=0.002, used=("r1", "r2"), rejected=2)
    router.put("vs/lab/state/r1", encode(state))
    router.put("vs/lab/state/r2", b"\xc1 not msgpack")
    client.wait_for(lambda c: len(c.messages["/foxglove/vs/lab/scene"]) >= 2 and
                    len(c.messages["/foxglove/vs/lab/log"]) >= 2 and "/json/vs/lab/state/r1" in c.topics(), 5)
    client.subscribe(["/json/vs/lab/state/r1"])
    state = StateMsg(t=state.t + 1 / 30, seq=seq + 1, x=0.01, y=0.02, th=0.1, gx=0.02, gy=0.02, gth=0.1,
                     cost=0.003, err=0.002, used=("r1", "r2"), rejected=2)
    while not client.messages["/json/vs/lab/state/r1"]:  # until the subscription is in place
        router.put("vs/lab/state/r1", encode(state))
        try:
            client.wait_for(lambda c: c.messages["/json/vs/lab/state/r1"], 0.2)
        except TimeoutError:
            pass
    _, update = client.messages["/foxglove/vs/lab/scene"][-1]
    fitted = next(e for e in update["entities"] if e["id"] == "fitted")
    assert [(s["pose"]["position"]["x"], s["pose"]["position"]["y"]) for s in fitted["spheres"]] == \
        [(x, y) for x, y, _ in structure_points(MISSION, 0.01, 0.02, 0.1)]
    t_json, mirror = client.messages["/json/vs/lab/state/r1"][0]
    assert mirror["err"] == 0.002 and mirror["cost"] == 0.003 and t_json == seconds_to_ns(state.t)
    lines = [m["message"] for _, m in client.messages["/foxglove/vs/lab/log"]]
    assert any("agent r1 rejected 2 more" in line for line in lines)
    assert any("vs/lab/state/r2" in line for line in lines)


def test_a_file_recorded_live_by_vsfleet_record_reads_back_with_the_sdks_schemas(tmp_path):
    from mcap.reader import make_reader

    from vsfleet.fleetctl.record import Recording
    from tests.foxglove_support import decode_protobuf

    router, endpoint = open_loopback_router()
    try:
        deadline = time.monotonic() + 20.0
        with Recording(client_conf(endpoint), tmp_path / "live.mcap", "vs/lab/**", query_mission=False) as rec:
            pubs = {k: router.declare_publisher(k) for k in ("vs/lab/mission", "vs/lab/frame/cam0", "vs/lab/state/r1")}
            # put only once the recorder's subscription has reached the router (a loaded host is slow to)
            ready = threading.Event()
            while not all(p.matching_status.matching for p in pubs.values()):
                assert not ready.wait(0.01) and time.monotonic() < deadline, "the recorder never subscribed"
            pubs["vs/lab/mission"].put(encode_mission(MISSION))
            pubs["vs/lab/frame/cam0"].put(encode_frame(frame(1)))
            pubs["vs/lab/state/r1"].put(encode(StateMsg(t=frame(1).t, seq=1, x=0.01, y=0.02, th=0.1, gx=0.02,
                                                        gy=0.02, gth=0.1, cost=0.0, err=0.0, used=(), rejected=0)))
            assert rec.wait_count(3, timeout_s=10), f"{rec.count} of 3 records"
    finally:
        router.close()
    seen = {}
    with open(tmp_path / "live.mcap", "rb") as f:
        for schema, channel, m in make_reader(f).iter_messages():
            if channel.metadata["vsfleet.role"] != "foxglove":
                continue
            sdk = getattr(foxglove.messages, schema.name.removeprefix("foxglove.")).get_schema()
            assert (schema.encoding, schema.data) == ("protobuf", sdk.data)
            seen.setdefault(channel.topic, []).append(decode_protobuf(schema.name, schema.data, m.data))
    assert set(seen) == {"/foxglove/vs/lab/scene", "/foxglove/vs/lab/goal", "/foxglove/vs/lab/log",
                         "/foxglove/vs/lab/state/r1", "/foxglove/vs/lab/tf"}
    frames = [[t["child_frame_id"] for t in m["transforms"]] for m in seen["/foxglove/vs/lab/tf"]]
    assert frames == [["lab/r1", "lab/r2"], ["lab/structure", "lab/structure_advanced"]]
    ids = [e["id"] for update in seen["/foxglove/vs/lab/scene"] for e in update["entities"]]
    assert ids == ["mission", "robots", "fitted", "advanced", "targets"]
    assert seen["/foxglove/vs/lab/goal"][0]["pose"]["position"] == {"x": 1.0, "y": 0.5, "z": 0.0}


ROOM = Mission(version=2, metric="linf", speed_max=0.08, turn_rate_max=0.3, effective_t=T0, goal=(1.0, 0.5, 0.2),
               robots=(("r1", RobotSpec((0.3, 0.0), 0.12, 0.3, 0.8, radius=0.05)),
                       ("r2", RobotSpec((-0.15, 0.26), 0.12, 0.3, 0.8))),          # r2: a point robot
               obstacles=((0.6, 0.3, 0.1), (-1.0, 2.0, 0.25)))


def scene_dict(message) -> dict:
    """An SDK SceneUpdate as a dict, through its protobuf schema (as a Foxglove client decodes it)."""
    from tests.foxglove_support import decode_protobuf

    schema = foxglove.messages.SceneUpdate.get_schema()
    return decode_protobuf(schema.name, schema.data, message.encode())


def scene_of(views) -> dict:
    return scene_dict(next(v.message for v in views if v.topic == "/foxglove/vs/lab/scene"))


def xy(prim) -> tuple[float, float]:
    return (prim["pose"]["position"]["x"], prim["pose"]["position"]["y"])


def test_the_scene_shows_obstacles_as_cylinders_and_robot_bodies_as_discs_of_their_radius():
    from vsfleet.fleetctl.foxglove_views import FleetViews

    views = FleetViews()
    out = views.on_message("vs/lab/mission", encode_mission(ROOM), seconds_to_ns(T0))
    (mission,) = scene_of(out)["entities"]
    assert mission["id"] == "mission"
    assert [(*xy(c), c["size"]["x"], c["size"]["y"]) for c in mission["cylinders"]] == \
        [(0.6, 0.3, 0.2, 0.2), (-1.0, 2.0, 0.5, 0.5)]                 # diameter 2 r, in mission order
    assert all(c["bottom_scale"] == c["top_scale"] == 1.0 and c["pose"]["position"]["z"] == c["size"]["z"] / 2
               for c in mission["cylinders"])
    assert any("2 obstacles" in v.message.encode().decode("utf-8", "replace")
               for v in out if v.topic == "/foxglove/vs/lab/log")
    out = views.on_message("vs/lab/frame/cam0", encode_frame(frame(1)), 0)
    (robots,) = scene_of(out)["entities"]
    (body,) = robots["cylinders"]                                       # r1 only: r2 has no body
    assert xy(body) == frame(1).poses["r1"][:2]
    assert body["size"]["x"] == body["size"]["y"] == 0.1 and body["color"]["a"] < 1.0


def test_every_event_kind_becomes_a_log_line_blocked_and_unblocked_included():
    """A 'blocked' event crashed the MCAP writer of a loaded run (KeyError in EVENT_LEVEL, CI rehearsal 2026-12-05):
    every kind the wire allows is logged now."""
    from vsfleet.fleetctl.foxglove_views import FleetViews
    from vsfleet.wire import EVENT_KINDS, EventMsg, encode_event

    views = FleetViews()
    views.on_message("vs/lab/mission", encode_mission(ROOM), seconds_to_ns(T0))
    for seq, kind in enumerate(EVENT_KINDS, start=1):
        out = views.on_message("vs/lab/event/r1", encode_event(EventMsg(T0 + seq, seq, "r1", kind, 0.5, "r1")), 0)
        (log,) = [v for v in out if v.topic == "/foxglove/vs/lab/log"]
        assert f"r1: {kind} at frame {seq}" in log.message.encode().decode("utf-8", "replace")


def test_a_mission_without_a_room_draws_no_cylinders():
    from vsfleet.fleetctl.foxglove_views import FleetViews

    views = FleetViews()
    out = views.on_message("vs/lab/mission", encode_mission(MISSION), seconds_to_ns(T0))
    assert not scene_of(out)["entities"][0]["cylinders"]
    out = views.on_message("vs/lab/frame/cam0", encode_frame(frame(1)), 0)
    assert not scene_of(out)["entities"][0]["cylinders"]


def test_in_a_room_the_scene_shows_the_plan_from_the_fitted_pose_and_the_bodies_swept_along_it():
    from vsfleet.fleetctl.foxglove_views import FleetViews
    from vsfleet.geometry import Pose2
    from vsfleet.step import planned_way

    views = FleetViews()
    views.on_message("vs/lab/mission", encode_mission(ROOM), seconds_to_ns(T0))
    state = StateMsg(t=T0 + 1.0, seq=5, x=-0.2, y=-0.1, th=0.0, gx=-0.2, gy=-0.1, gth=0.0, cost=0.0, err=0.0,
                     used=("r1", "r2"), rejected=0)
    entities = {e["id"]: e for e in scene_of(views.on_message("vs/lab/state/r1", encode(state), 0))["entities"]}
    plan = entities["plan"]
    way, blocked = planned_way(ROOM, Pose2(-0.2, -0.1, 0.0))
    assert not blocked and plan["metadata"][-1] == {"key": "blocked", "value": "false"}
    (line,) = plan["lines"]
    assert [(p["x"], p["y"]) for p in line["points"]] == [(x, y) for x, y, _ in way]
    assert (way[-1][0], way[-1][1]) == (1.0, 0.5)
    swept = plan["cylinders"]
    assert swept and all(c["size"]["x"] == 0.1 for c in swept)         # r1's body only: r2 is a point robot


def test_in_a_room_with_reshapes_the_scene_draws_the_structure_and_plan_in_the_shape_the_agents_take():
    import dataclasses

    from vsfleet.fleetctl.foxglove_views import FleetViews
    from vsfleet.geometry import Pose2
    from vsfleet.step import planned_way

    shaped = dataclasses.replace(ROOM, shapes=(("wide", ((0.5, 0.0), (-0.5, 0.0))),))
    views = FleetViews()
    views.on_message("vs/lab/mission", encode_mission(shaped), seconds_to_ns(T0))
    state = StateMsg(t=T0 + 1.0, seq=5, x=-0.2, y=-0.1, th=0.0, gx=-0.2, gy=-0.1, gth=0.0, cost=0.0, err=0.0,
                     used=("r1", "r2"), rejected=0, shape=1)
    entities = {e["id"]: e for e in scene_of(views.on_message("vs/lab/state/r1", encode(state), 0))["entities"]}
    assert sorted(xy(s) for s in entities["fitted"]["spheres"]) == [(-0.7, -0.1), (0.3, -0.1)]   # the wide shape
    way, _blocked = planned_way(shaped, Pose2(-0.2, -0.1, 0.0), shape=1)
    assert [(p["x"], p["y"]) for p in entities["plan"]["lines"][0]["points"]] == [(x, y) for x, y, _ in way]
    assert structure_points(shaped, 0.0, 0.0, 0.0, shape=1)[0][:2] == (0.5, 0.0)
    assert structure_points(shaped, 0.0, 0.0, 0.0)[0][:2] == structure_points(ROOM, 0.0, 0.0, 0.0)[0][:2]
