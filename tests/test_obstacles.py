"""Missions in a real room (issue 22): round obstacles and robot bodies in the mission.

``obstacles`` ((x, y, r) [m; world]) and a robot's ``radius`` [m] are optional, closed and
checked like every other field; a mission without them encodes byte for byte as before; a
goal or waypoint that puts a body inside an obstacle is refused, naming the obstacle and the
robot; the layered config carries both.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import random
import tomllib
from pathlib import Path

import msgpack
import pytest

from vsfleet.scenario import ScenarioError, UnknownKeyError, scenario_from_dict
from vsfleet.wire import (
    MAX_OBSTACLES,
    Mission,
    RobotSpec,
    UnknownFieldError,
    WireError,
    check_clear_of_obstacles,
    decode_mission,
    encode_mission,
)
from vsfleet.zglue.scenario_file import load_scenario

ROOT = Path(__file__).parent.parent
ROBOTS = (("r1", RobotSpec((0.3, 0.0), 0.12, 0.3, 0.8, radius=0.05)),
          ("r2", RobotSpec((-0.15, 0.26), 0.12, 0.3, 0.8)),                 # a point robot
          ("r3", RobotSpec((-0.15, -0.26), 0.12, 0.25, 0.8, radius=0.07)))
ROOM = Mission(4, "linf", ROBOTS, 0.08, 0.3, 1.7e9, goal=(1.6, 1.0, 0.3),
               obstacles=((0.8, 0.5, 0.3), (-1.0, 2.0, 0.05), (3.0, -1.0, 1.5)))


def as_map(mission: Mission = ROOM) -> dict:
    return msgpack.unpackb(encode_mission(mission), raw=False)


def pack(m) -> bytes:
    return msgpack.packb(m, use_bin_type=True)


# ---------------------------------------------------------------- the wire


@pytest.mark.parametrize("mission", [
    ROOM,
    dataclasses.replace(ROOM, goal=None, path=((0.0, 0.0, 0.0), (1.6, 1.0, 0.3))),
    dataclasses.replace(ROOM, goal=None, twist=(0.1, 0.0, 0.0)),
    dataclasses.replace(ROOM, obstacles=()),
    dataclasses.replace(ROOM, obstacles=tuple((float(i), 50.0, 0.1) for i in range(MAX_OBSTACLES))),
])
def test_a_mission_with_obstacles_and_radii_survives_a_round_trip_bit_for_bit(mission):
    payload = encode_mission(mission)
    got = decode_mission(payload)
    assert got == mission
    assert encode_mission(got) == payload
    assert [o for o in got.obstacles] == [o for o in mission.obstacles]
    assert got.spec("r1").radius == 0.05 and got.spec("r2").radius is None


def test_the_api_gives_obstacles_as_x_y_r_tuples_and_radii_in_fit_order():
    assert ROOM.obstacles[0] == (0.8, 0.5, 0.3)
    assert all(isinstance(o, tuple) and len(o) == 3 for o in ROOM.obstacles)
    assert ROOM.radii == (0.05, 0.0, 0.07)            # sorted robot ids; 0.0 for a point robot
    assert [r for r, _ in ROOM.robots] == ["r1", "r2", "r3"]


def test_obstacles_and_radius_are_sent_only_when_set():
    m = as_map()
    assert m["obstacles"] == [[0.8, 0.5, 0.3], [-1.0, 2.0, 0.05], [3.0, -1.0, 1.5]]
    assert m["robots"]["r1"]["radius"] == 0.05 and "radius" not in m["robots"]["r2"]
    plain = as_map(dataclasses.replace(ROOM, obstacles=(), robots=tuple(
        (r, dataclasses.replace(s, radius=None)) for r, s in ROBOTS)))
    assert "obstacles" not in plain and not any("radius" in s for s in plain["robots"].values())


def test_a_mission_without_them_encodes_byte_for_byte_as_the_golden_recording_made_before_them():
    golden = json.loads((ROOT / "tests" / "data" / "golden-step.json").read_text())
    recorded = bytes.fromhex(golden["mission"])
    got = decode_mission(recorded)
    assert got.obstacles == () and all(s.radius is None for _, s in got.robots)
    assert encode_mission(got) == recorded
    # ... and the scenario it was recorded from still loads into the same bytes
    sc = load_scenario(ROOT / "scenarios" / "paper-failure.toml")
    assert encode_mission(dataclasses.replace(sc.mission, on_failure="drop", effective_t=0.0)) == recorded


def test_an_empty_or_nil_obstacle_list_is_no_obstacles():
    for v in ([], None):
        assert decode_mission(pack({**as_map(), "obstacles": v})).obstacles == ()


BAD_OBSTACLES = [
    ([[0.8, 0.5, math.nan]], "obstacle 0: field 'r' must be finite"),
    ([[0.8, math.inf, 0.1]], "obstacle 0: field 'y' must be finite"),
    ([[-math.inf, 0.5, 0.1]], "obstacle 0: field 'x' must be finite"),
    ([[9.0, 9.0, 0.1], [0.8, 0.5, 0.0]], "obstacle 1: field 'r' must be > 0"),
    ([[0.8, 0.5, -0.1]], "obstacle 0: field 'r' must be > 0"),
    ([[0.8, 0.5, 2e6]], "obstacle 0: field 'r' out of range"),
    ([[float(i), 50.0, 0.1] for i in range(MAX_OBSTACLES + 1)], "257 obstacles exceed the limit of 256"),
    ([[0.8, 0.5]], "obstacle 0 must be [x, y, r]"),
    ([[0.8, 0.5, 0.1, 0.0]], "obstacle 0 must be [x, y, r]"),
    ([{"x": 0.8, "y": 0.5, "r": 0.1}], "obstacle 0 must be [x, y, r]"),  # the wire's form is a list
    ([0.8, 0.5, 0.1], "obstacle 0 must be [x, y, r]"),                    # not nested
    ([[0.8, "0.5", 0.1]], "field 'y' must be a number"),
    ([[0.8, 0.5, True]], "field 'r' must be a number"),
    ({"x": 0.8, "y": 0.5, "r": 0.1}, "field 'obstacles' must be a list"),
    ("pillar", "field 'obstacles' must be a list"),
    (3, "field 'obstacles' must be a list"),
]


@pytest.mark.parametrize("obstacles, words", BAD_OBSTACLES, ids=[w for _, w in BAD_OBSTACLES])
def test_each_bad_obstacle_list_is_refused_with_a_clear_wire_error(obstacles, words):
    with pytest.raises(WireError) as err:
        decode_mission(pack({**as_map(), "obstacles": obstacles}))
    assert words in str(err.value)


BAD_RADII = [(math.nan, "must be finite"), (math.inf, "must be finite"), (-math.inf, "must be finite"),
             (0.0, "must be > 0"), (-0.05, "must be > 0"), (2e6, "out of range"), ("0.05", "must be a number"),
             (True, "must be a number"), (None, "must be a number"), ([0.05], "must be a number")]


@pytest.mark.parametrize("radius, words", BAD_RADII, ids=[repr(r) for r, _ in BAD_RADII])
def test_each_bad_radius_is_refused_naming_the_robot(radius, words):
    m = as_map()
    m["robots"]["r3"]["radius"] = radius
    with pytest.raises(WireError, match="robot 'r3'") as err:
        decode_mission(pack(m))
    assert words in str(err.value) and "'radius'" in str(err.value)


def test_an_unknown_key_in_a_robot_spec_is_refused_and_a_close_one_suggested():
    m = as_map()
    m["robots"]["r1"]["raduis"] = m["robots"]["r1"].pop("radius")
    with pytest.raises(UnknownFieldError, match=r"'raduis' \(did you mean 'radius'\?\) in robot 'r1'"):
        decode_mission(pack(m))
    m = as_map()
    m["obstacle"] = m.pop("obstacles")
    with pytest.raises(UnknownFieldError, match=r"'obstacle' \(did you mean 'obstacles'\?\)"):
        decode_mission(pack(m))


# ---------------------------------------------------------------- goals inside obstacles


def test_a_goal_that_puts_a_body_inside_an_obstacle_is_refused_naming_the_obstacle_and_the_robot():
    # r1's point at the goal (1.6, 1.0, 0) is (1.9, 1.0); an obstacle 0.1 m off it, r 0.06:
    # the point is outside (0.1 > 0.06), the body (0.05) is not (0.1 < 0.11)
    m = as_map()
    m["goal"] = {"x": 1.6, "y": 1.0, "th": 0.0}
    m["obstacles"] = [[5.0, 5.0, 0.5], [1.9, 1.1, 0.06]]
    with pytest.raises(WireError) as err:
        decode_mission(pack(m))
    text = str(err.value)
    assert "the goal" in text and "robot 'r1'" in text and "body radius 0.05 m" in text
    assert "inside obstacle 1 (x 1.9, y 1.1, r 0.06)" in text
    m["robots"]["r1"].pop("radius")  # a point robot there is clear of it
    assert decode_mission(pack(m)).obstacles[1] == (1.9, 1.1, 0.06)


def test_a_point_robot_is_refused_only_when_its_point_is_inside():
    m = as_map()
    m["goal"] = {"x": 0.15, "y": -0.26, "th": 0.0}   # r2 (a point) at (0, 0) exactly
    m["obstacles"] = [[0.25, 0.0, 0.2500001]]
    with pytest.raises(WireError, match=r"robot 'r2' \(a point robot\) inside obstacle 0 \(x 0.25, y 0, r 0.25"):
        decode_mission(pack(m))
    m["obstacles"] = [[0.25, 0.0, 0.25]]             # exactly touching (0.25 away, r 0.25): not inside
    assert decode_mission(pack(m)).obstacles == ((0.25, 0.0, 0.25),)


def test_the_structure_may_straddle_an_obstacle_that_no_body_touches():
    m = as_map()
    m["goal"] = {"x": 1.0, "y": 1.0, "th": 0.0}
    m["obstacles"] = [[1.0, 1.0, 0.2]]             # inside the triangle; every body clear of it
    assert decode_mission(pack(m)).goal == (1.0, 1.0, 0.0)


def test_a_path_waypoint_inside_an_obstacle_is_refused_naming_the_waypoint_and_the_obstacle():
    m = as_map()
    del m["goal"]
    m["path"] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, math.pi / 2], [3.0, 0.0, 0.0]]
    m["obstacles"] = [[2.0, 0.3, 0.05]]            # r1 at waypoint 2 is at (2.0, 0.3)
    with pytest.raises(WireError, match=r"path waypoint 2 puts robot 'r1' .* inside obstacle 0 \(x 2, y 0.3, r 0.05\)"):
        decode_mission(pack(m))


def test_a_twist_mission_is_not_checked_against_obstacles():
    m = as_map()
    del m["goal"]
    m["twist"] = {"vx": 0.1, "vy": 0.0, "w": 0.0}
    m["obstacles"] = [[0.3, 0.0, 1.0]]
    assert decode_mission(pack(m)).obstacles == ((0.3, 0.0, 1.0),)


def test_the_check_holds_far_from_the_origin_and_on_long_paths():
    robots = (("a", RobotSpec((0.0, 0.0), 0.1, 0.3, 1.0, radius=0.1)),)
    check_clear_of_obstacles(robots, ((1e5, -1e5, 0.15),), ((1e5 + 0.25, -1e5, 0.0),))  # r + radius: touching
    with pytest.raises(WireError, match="pose 0"):
        check_clear_of_obstacles(robots, ((1e5, -1e5, 0.16),), ((1e5 + 0.25, -1e5, 0.0),))
    path = tuple((0.01 * k, 0.0, 0.0) for k in range(10000))
    obstacles = tuple((0.5 * k, 1.0, 0.1) for k in range(MAX_OBSTACLES - 1)) + ((77.7049, 0.0, 0.01),)
    with pytest.raises(WireError, match=r"pose 7760 .* obstacle 255"):  # (77.6, 0): 0.1049 from it, < 0.11
        check_clear_of_obstacles(robots, obstacles, path)


# ---------------------------------------------------------------- the layered config

BASE = {
    "schema": 1,
    "fleet": {"name": "room"},
    "mission": {"metric": "l2", "speed_max": 0.08, "turn_rate_max": 0.3, "goal": {"x": 1.0, "y": 0.5, "th": 0.0},
                "obstacles": [[0.5, -1.0, 0.2], {"x": 2.0, "y": 2.0, "r": 0.1}]},
    "defaults": {"wheel_base": 0.1, "wheel_speed_max": 0.3, "wheel_accel_max": 1.0, "radius": 0.04, "type": "big"},
    "robot_types": {"big": {"radius": 0.09}, "plain": {"wheel_base": 0.08}},
    "robots": {"a": {"p": [0.0, 0.0]},                                  # [defaults] type big: 0.09
               "b": {"p": [0.3, 0.0], "type": "plain"},                 # plain sets none: [defaults] 0.04
               "c": {"p": [0.6, 0.0], "radius": 0.05},                  # its own over its type's
               "d": {"p": [0.9, 0.0], "type": "plain", "radius": 0.03}},
}


def doc(**change):
    d = copy.deepcopy(BASE)
    for k, v in change.items():
        d[k] = v
    return d


def test_radius_layers_like_wheel_base_defaults_then_type_then_robot():
    sc = scenario_from_dict(doc())
    assert {r.robot: r.radius for r in sc.robots} == {"a": 0.09, "b": 0.04, "c": 0.05, "d": 0.03}
    assert {r: s.radius for r, s in sc.mission.robots} == {"a": 0.09, "b": 0.04, "c": 0.05, "d": 0.03}
    assert sc.mission.obstacles == ((0.5, -1.0, 0.2), (2.0, 2.0, 0.1))  # [x, y, r] and {x, y, r} alike


def test_without_radius_in_any_layer_a_robot_is_a_point_and_the_mission_has_no_obstacles():
    d = doc()
    del d["defaults"]["radius"], d["robot_types"]["big"]["radius"], d["robots"]["c"]["radius"]
    del d["robots"]["d"]["radius"], d["mission"]["obstacles"]
    sc = scenario_from_dict(d)
    assert all(r.radius is None for r in sc.robots) and sc.mission.obstacles == ()
    assert "obstacles" not in sc.mission.to_dict()


@pytest.mark.parametrize("where, radius", [("defaults", 0.0), ("defaults", -0.1), ("defaults", math.nan),
                                           ("robot_types", math.inf), ("robots", "0.05"), ("robots", True)])
def test_a_bad_radius_in_any_layer_is_refused_naming_the_robot(where, radius):
    d = doc()
    {"defaults": d["defaults"], "robot_types": d["robot_types"]["big"], "robots": d["robots"]["a"]}[where]["radius"] = radius
    who = "b" if where == "defaults" else "a"  # a's type sets its own radius; b takes [defaults]
    with pytest.raises(ScenarioError, match=rf"\[robots.{who}\] 'radius' must be a finite number > 0"):
        scenario_from_dict(d)


@pytest.mark.parametrize("table", ["defaults", "robot_types", "robots"])
def test_a_misspelt_radius_is_refused_in_every_layer_with_the_key_named(table):
    d = doc()
    target = {"defaults": d["defaults"], "robot_types": d["robot_types"]["big"], "robots": d["robots"]["a"]}[table]
    target["raduis"] = 0.05
    with pytest.raises(UnknownKeyError) as err:
        scenario_from_dict(d)
    assert err.value.keys == ("raduis",) and "did you mean 'radius'" in str(err.value)


def test_an_unknown_key_in_an_obstacle_table_is_refused_and_named():
    d = doc()
    d["mission"]["obstacles"][1] = {"x": 2.0, "y": 2.0, "radius": 0.1}
    with pytest.raises(UnknownKeyError) as err:
        scenario_from_dict(d)
    assert err.value.keys == ("radius",) and "[mission.obstacles[1]]" in str(err.value)
    d["mission"]["obstacles"][1] = {"x": 2.0, "y": 2.0}
    with pytest.raises(ScenarioError, match=r"\[mission.obstacles\[1\]\] needs 'r'"):
        scenario_from_dict(d)


@pytest.mark.parametrize("obstacles, words", [
    ([[0.5, -1.0]], "obstacle 0 must be [x, y, r]"),
    ([[0.5, -1.0, 0.0]], "obstacle 0: field 'r' must be > 0"),
    ([[0.5, -1.0, math.nan]], "obstacle 0: field 'r' must be finite"),
    ([[0.5, -1.0, 0.1]] * 257, "257 obstacles exceed the limit of 256"),
    ("pillar", "obstacles must be a list"),
    ({"x": 1.0, "y": 1.0, "r": 0.1}, "obstacles must be a list"),
])
def test_a_malformed_obstacle_list_in_a_scenario_is_refused(obstacles, words):
    d = doc()
    d["mission"]["obstacles"] = obstacles
    with pytest.raises(ScenarioError) as err:
        scenario_from_dict(d)
    assert words in str(err.value)


def test_a_scenario_whose_goal_puts_a_body_inside_an_obstacle_is_refused_naming_both():
    d = doc()
    d["mission"]["obstacles"].append([1.3, 0.5, 0.05])   # robot b's point at the goal: (1.3, 0.5)
    with pytest.raises(ScenarioError, match=r"\[mission\] the goal puts robot 'b' .* inside obstacle 2 \(x 1.3, y 0.5"):
        scenario_from_dict(d)


def test_a_robot_starting_inside_an_obstacle_or_overlapping_another_is_refused():
    d = doc()
    d["robots"]["c"]["start"] = [0.5, -0.9, 0.0]
    with pytest.raises(ScenarioError, match=r"\[robots.c\] start puts it inside obstacle 0"):
        scenario_from_dict(d)
    d = doc()
    d["robots"]["a"]["start"], d["robots"]["b"]["start"] = [0.0, 0.0, 0.0], [0.12, 0.0, 0.0]  # 0.09 + 0.04 > 0.12
    with pytest.raises(ScenarioError, match=r"\[robots.a\] and \[robots.b\] start with their bodies overlapping"):
        scenario_from_dict(d)


def test_the_lab_fleet_file_carries_radius_in_its_robot_type_and_can_carry_obstacles(tmp_path):
    path = ROOT / "deploy" / "fleet.toml"
    sc = load_scenario(path)
    assert sc.mission.radii == (0.08, 0.08, 0.08) and sc.mission.obstacles == ()
    assert "radius" in tomllib.loads(path.read_text())["robot_types"]["r3"]
    text = path.read_text()
    assert "# obstacles = [[0.8, 0.5, 0.1]]" in text
    room = tmp_path / "fleet.toml"
    room.write_text(text.replace("# obstacles = [[0.8, 0.5, 0.1]]", "obstacles = [[0.8, 0.5, 0.1]]"))
    assert load_scenario(room).mission.obstacles == ((0.8, 0.5, 0.1),)


def test_the_room_scenarios_say_what_the_issue_asks():
    ob = load_scenario(ROOT / "scenarios" / "paper-triangle-obstacle.toml")
    plain = load_scenario(ROOT / "scenarios" / "paper-triangle.toml")
    assert ob.mission.radii == (0.05, 0.05, 0.05) and len(ob.mission.obstacles) == 1
    assert dataclasses.replace(ob.mission, obstacles=(), robots=plain.mission.robots) == plain.mission
    assert [r.start for r in ob.robots] == [r.start for r in plain.robots]
    (ox, oy, r), = ob.mission.obstacles
    gx, gy, _ = ob.mission.goal
    assert abs(ox * gy - oy * gx) < 1e-12 and 0.0 < ox < gx       # on the straight line from (0, 0) to the goal
    assert r + 0.05 > max(math.hypot(*s.p) for _, s in ob.mission.robots)  # too wide to straddle

    row = load_scenario(ROOT / "scenarios" / "tight-row.toml")
    assert row.mission.goal == plain.mission.goal and row.mission.robots == ob.mission.robots
    starts = sorted(r.start[1] for r in row.robots)
    assert len({r.start[0] for r in row.robots}) == 1                 # in a row
    gaps = [b - a - 2 * 0.05 for a, b in zip(starts, starts[1:])]
    assert gaps == pytest.approx([0.02, 0.02])                        # 2 cm between bodies


def test_the_check_finds_the_first_pose_obstacle_and_robot_that_every_pair_checked_in_turn_finds():
    """The grids of check_clear_of_obstacles (obstacles by pose, points by obstacle) only skip pairs that cannot
    touch: on random rooms its verdict and message are those of checking every pose, obstacle and robot in turn."""
    rng = random.Random(7)

    def brute(robots, obstacles, poses):
        for w, (x, y, th) in enumerate(poses):
            cw, sw = math.cos(th), math.sin(th)
            for j, (ox, oy, r) in enumerate(obstacles):
                for i, (_rid, s) in enumerate(robots):
                    px, py = x + cw * s.p[0] - sw * s.p[1], y + sw * s.p[0] + cw * s.p[1]
                    if math.hypot(px - ox, py - oy) < r + (s.radius or 0.0):
                        return f"pose {w} puts robot {robots[i][0]!r}", f"inside obstacle {j} "
        return None

    verdicts = []
    for _ in range(300):
        n = rng.randint(1, 12)
        robots = tuple((f"r{i}", RobotSpec((rng.uniform(-2, 2), rng.uniform(-2, 2)), 0.1, 0.3, 1.0,
                                           radius=rng.choice([None, rng.uniform(0.01, 0.2)]))) for i in range(n))
        obstacles = tuple((rng.uniform(-6, 6), rng.uniform(-6, 6), rng.uniform(0.01, 0.5))
                          for _ in range(rng.randint(1, 30)))
        poses = tuple((rng.uniform(-6, 6), rng.uniform(-6, 6), rng.uniform(-4, 4)) for _ in range(rng.randint(1, 20)))
        want = brute(robots, obstacles, poses)
        verdicts.append(want is not None)
        if want is None:
            check_clear_of_obstacles(robots, obstacles, poses)
        else:
            with pytest.raises(WireError) as err:
                check_clear_of_obstacles(robots, obstacles, poses)
            assert want[0] in str(err.value) and want[1] in str(err.value)
    assert 50 < sum(verdicts) < 250   # both verdicts, many times
