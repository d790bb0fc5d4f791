"""The per-frame glue around the core kernels (issue 29): each shortcut gives what the plain code gives, bit for bit.

frame_arrays reads poses without a Python loop, the core's Structure is filled without the dataclasses'
__init__s, wire.encode takes each class's fields once (and a field's other value without
dataclasses.replace), Mission.robot_ids and MissionArrays.room are computed once, and MissionBook.active
has a one-mission path. Each is held here to the plain version it replaced.
"""

from __future__ import annotations

import dataclasses
import math
import random
import struct

import msgpack
import numpy as np
import pytest

from vsfleet.advance import Twist2
from vsfleet.frames import MissionBook
from vsfleet.geometry import Pose2
import vsfleet.structure as structure_module
from vsfleet.step import Structure, frame_arrays, mission_arrays, structure_step
from vsfleet.wire import (
    CmdMsg,
    EventMsg,
    FaultMsg,
    Mission,
    PoseMsg,
    RobotSpec,
    StateMsg,
    TruthMsg,
    encode,
    encode_event,
    message_fields,
)

_UNSEEN = (math.nan, math.nan, math.nan)


def plain_frame_arrays(ids, poses, fresh=frozenset()):
    """frame_arrays as it was: one list of tuples per frame."""
    pose = np.array([poses.get(r, _UNSEEN) for r in ids], dtype=float).reshape(len(ids), 3)
    seen = ~np.isnan(pose[:, 0])
    return pose, seen, seen & np.array([r in fresh for r in ids], dtype=bool)


@pytest.mark.parametrize("seed", range(30))
def test_frame_arrays_give_the_plain_arrays_bit_for_bit(seed):
    rng = random.Random(seed)
    ids = tuple(f"r{i:03d}" for i in range(rng.choice([0, 1, 3, 10, 100])))
    poses = {r: (rng.uniform(-5, 5), rng.choice([0.0, -0.0, 5e-324, 1e6]), rng.randint(-3, 3))
             for r in ids if rng.random() < 0.8}
    poses["not-in-mission"] = (1.0, 2.0, 3.0)
    for fresh in (frozenset(), frozenset(ids), frozenset(poses), frozenset(r for r in poses if rng.random() < 0.5)):
        got, want = frame_arrays(ids, poses, fresh), plain_frame_arrays(ids, poses, fresh)
        for g, w in zip(got, want):
            assert g.dtype == w.dtype and g.shape == w.shape and g.tobytes() == w.tobytes()
        assert not np.shares_memory(got[1], got[2])


def plain_encode(msg) -> bytes:
    """wire.encode as it was: dataclasses.fields walked per message, tuples made lists."""
    out = {}
    for f in dataclasses.fields(msg):
        v = getattr(msg, f.name)
        out[f.name] = list(v) if isinstance(v, tuple) else v
    return msgpack.packb(out, use_bin_type=True)


MESSAGES = [
    PoseMsg(1.7e9 + 0.123456789, 42, 1.5, -2.25, 3.0, "cam1"),
    CmdMsg(1.7e9, 42, 0.1, -0.2, 0.3),
    StateMsg(1.7e9, 42, 1.0, 2.0, 0.1, 1.1, 2.1, 0.2, 0.004, 0.002, ("r1", "r2"), 7, complete=False, mission=3),
    StateMsg(1.7e9, 42, 1.0, 2.0, 0.1, 1.1, 2.1, 0.2, 0.004, 0.002, (), 7),
    TruthMsg(1.7e9, 1.0, 2.0, -3.1, 0.1, 0.2, why="expired", why_t=1.0, expired_t=1.0, rejected=3),
    FaultMsg("slow", 0.5, 2.0),
    EventMsg(t=1.0, seq=3, robot="r2", kind="fail", dev=0.05, by="r1"),
]


@pytest.mark.parametrize("msg", MESSAGES, ids=lambda m: type(m).__name__)
def test_encode_gives_the_plain_bytes_and_a_changed_field_as_replace_would(msg):
    assert encode(msg) == plain_encode(msg)
    names, values = message_fields(type(msg))
    assert names == tuple(f.name for f in dataclasses.fields(msg)) and len(values(msg)) == len(names)
    name = "seq" if "seq" in names else names[-1]
    other = 12345 if name == "seq" else getattr(msg, name)
    assert encode(msg, **{name: other}) == plain_encode(dataclasses.replace(msg, **{name: other}))
    with pytest.raises(TypeError, match="no field"):
        encode(msg, not_a_field=1)


def test_an_agents_state_message_with_the_processs_rejection_count_is_encoded_as_before():
    msg = MESSAGES[2]
    assert encode(msg, rejected=99) == plain_encode(dataclasses.replace(msg, rejected=99))


def test_an_event_of_a_robot_not_seen_still_sends_its_deviation_as_inf():
    ev = EventMsg(t=1.0, seq=3, robot="r2", kind="fail", dev=math.inf, by="r1")
    assert msgpack.unpackb(encode_event(ev))["dev"] == "inf"
    plain = msgpack.unpackb(plain_encode(MESSAGES[-1]))
    assert MESSAGES[-1].why == "" and plain.pop("why") == ""
    assert msgpack.unpackb(encode_event(MESSAGES[-1])) == plain   # why is sent with blocked only
    blocked = dataclasses.replace(MESSAGES[-1], kind="blocked", why="stuck")
    assert encode_event(blocked) == plain_encode(blocked)


def test_a_message_class_of_one_field_or_of_none_encodes_too():
    @dataclasses.dataclass(frozen=True)
    class One:
        x: float

    @dataclasses.dataclass(frozen=True)
    class Empty:
        pass

    assert encode(One(1.5)) == plain_encode(One(1.5)) and encode(Empty()) == plain_encode(Empty())
    assert encode(One(2.0), x=3.0) == plain_encode(One(3.0))


MISSION = Mission(1, "linf", (("r1", RobotSpec((0.3, 0.0), 0.12, 0.3, 0.8)),
                              ("r2", RobotSpec((-0.15, 0.26), 0.12, 0.3, 0.8)),
                              ("r3", RobotSpec((-0.15, -0.26), 0.12, 0.3, 0.8))),
                  0.08, 0.3, 0.0, goal=(1.0, 0.5, 0.0))


def test_the_cores_structure_is_the_one_its_dataclasses_init_would_build(monkeypatch):
    """structure_step_core fills Structure, Pose2 and Twist2 without their __init__s: every field is there,
    with the values the __init__s give from the core's result (th wrapped by Pose2's wrap_angle)."""
    results = []

    class Core:   # vsfleet._core, recording what structure_step returns
        def __getattr__(self, name):
            return getattr(structure_module._core_module, name)

        @staticmethod
        def structure_step(*args):
            results.append(structure_module._core_module.structure_step(*args))
            return results[-1]

    monkeypatch.setattr(structure_module, "_core_module", structure_module._core, raising=False)
    monkeypatch.setattr(structure_module, "_core", Core())
    arrays = mission_arrays(MISSION)
    rng = np.random.default_rng(1)
    for k in range(50):
        pose = np.array([[0.3, 0.0, 3.2], [-0.15, 0.26, -3.3], [-0.16, -0.26, 0.1]]) + rng.normal(0, 0.05, (3, 3))
        pose[:, 2] += rng.choice([0.0, math.pi, -math.pi, 2 * math.pi])
        n = len(pose)
        s = structure_step(arrays, MISSION.metric, pose, np.ones(n, bool), np.zeros(n, bool), np.zeros(n, bool),
                           0.1 * k, 1 / 30)
        fx, fy, fth, gx, gy, gth, vx, vy, w, cost, at_goal, blocked, left_m, shape, cleared, held = results[-1]
        built = Structure(fit_pose=Pose2(fx, fy, fth), goal_pose=Pose2(gx, gy, gth), twist=Twist2(vx, vy, w),
                          cost=cost, at_goal=at_goal, used=s.used, points_now=s.points_now,
                          points_next=s.points_next, deviations_m=s.deviations_m, blocked=blocked, left_m=left_m,
                          shape=shape, cleared=cleared, held=held)
        for obj, ref in ((s, built), (s.fit_pose, built.fit_pose), (s.goal_pose, built.goal_pose),
                         (s.twist, built.twist)):
            assert list(vars(obj)) == [f.name for f in dataclasses.fields(ref)]
            assert all(type(getattr(obj, f.name)) is type(getattr(ref, f.name)) for f in dataclasses.fields(ref))
        assert [struct.pack("<d", v) for v in (*s.fit_pose.as_tuple(), *s.goal_pose.as_tuple(), s.cost, s.left_m)] == \
            [struct.pack("<d", v) for v in (*built.fit_pose.as_tuple(), *built.goal_pose.as_tuple(), built.cost,
                                            built.left_m)]
        assert s == built
    assert len(results) == 50


def test_robot_ids_and_room_are_computed_once_and_are_what_they_were():
    assert MISSION.robot_ids == ("r1", "r2", "r3") and MISSION.robot_ids is MISSION.robot_ids
    assert dataclasses.replace(MISSION, robots=MISSION.robots[:2]).robot_ids == ("r1", "r2")
    assert MISSION == dataclasses.replace(MISSION) and hash(MISSION) == hash(dataclasses.replace(MISSION))
    arrays = mission_arrays(MISSION)
    assert arrays.room is False
    roomy = dataclasses.replace(MISSION, obstacles=((5.0, 5.0, 0.2),))
    assert mission_arrays(roomy).room is True


def test_the_active_mission_of_a_book_of_one_mission_is_the_plain_rule():
    book = MissionBook()
    assert book.active(0.0) is None
    book.add(dataclasses.replace(MISSION, effective_t=5.0))
    assert book.active(4.999) is None and book.active(5.0).version == 1 and list(book.by_version) == [1]
    book.add(dataclasses.replace(MISSION, version=2, effective_t=6.0))
    assert book.active(5.5).version == 1 and book.active(6.0).version == 2 and list(book.by_version) == [2]
