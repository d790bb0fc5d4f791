"""Layered, versioned fleet files: schema = 1, then [defaults] -> [robot_types.NAME] -> [robots.ID].

The more specific layer wins; [failure] and [controller] travel in the mission; every table
rejects a misspelt key with the key named, and so do the programs that read fleet files.
"""

from __future__ import annotations

import copy
import json
import tomllib
from pathlib import Path

import pytest

from vsfleet.fleetctl import deploy
from vsfleet.fleetctl.mission_cmd import load_mission
from vsfleet.zglue.scenario_file import load_scenario
from vsfleet.control import make_controller
from vsfleet.failure import FailurePolicy
from vsfleet.scenario import ROBOT_DEFAULTS, ScenarioError, UnknownKeyError, scenario_from_dict
from vsfleet.wire import WireError, decode_mission, encode_mission

ROOT = Path(__file__).parent.parent
FILES = sorted((ROOT / "scenarios").glob("*.toml")) + [ROOT / "deploy" / "fleet.toml"]

BASE = {
    "schema": 1,
    "fleet": {"name": "lab"},
    "mission": {"metric": "linf", "speed_max": 0.08, "turn_rate_max": 0.3, "goal": {"x": 1.0, "y": 0.5, "th": 0.0},
                "controller": "tracking"},
    "failure": {"fail_deviation_m": 0.04, "fail_after_s": 3},
    "controller": {"along_gain_per_s": 1.5, "deadband_m": 0.003},
    "defaults": {"wheel_base": 0.10, "wheel_speed_max": 0.30, "wheel_accel_max": 1.0, "gain": [1.0, 0.99],
                 "type": "big"},
    "robot_types": {"big": {"wheel_base": 0.20, "wheel_speed_max": 0.40},
                    "small": {"wheel_base": 0.08}},
    "robots": {"a": {"p": [0.0, 0.0]},                                        # defaults' type: big
               "b": {"p": [0.3, 0.0], "type": "small", "wheel_accel_max": 2.0},
               "c": {"p": [0.6, 0.0], "type": "big", "wheel_speed_max": 0.25, "gain": [0.9, 1.0]}},
}


def doc(**change):
    d = copy.deepcopy(BASE)
    d.update(change)
    return d


def robots(scenario):
    return {r.robot: r for r in scenario.robots}


def test_the_more_specific_layer_wins_key_by_key():
    sc = scenario_from_dict(doc())
    a, b, c = (robots(sc)[r] for r in "abc")
    # a: big (from [defaults] type) over defaults
    assert (a.wheel_base, a.wheel_speed_max, a.wheel_accel_max, a.gain) == (0.20, 0.40, 1.0, (1.0, 0.99))
    # b: its own type (small) replaces the defaults' type; its own key over both
    assert (b.wheel_base, b.wheel_speed_max, b.wheel_accel_max) == (0.08, 0.30, 2.0)
    # c: its own keys over its type's, the type's over the defaults
    assert (c.wheel_base, c.wheel_speed_max, c.gain) == (0.20, 0.25, (0.9, 1.0))
    # the mission carries the resolved envelope of each robot
    assert {r: s.wheel_speed_max for r, s in sc.mission.robots} == {"a": 0.40, "b": 0.30, "c": 0.25}
    assert sc.mission.spec("b").wheel_accel_max == 2.0


def test_without_defaults_or_types_the_codes_defaults_apply():
    sc = scenario_from_dict(doc(defaults={}, robot_types={}, robots={"a": {"p": [0.0, 0.0]}}))
    a = robots(sc)["a"]
    assert (a.wheel_base, a.wheel_speed_max, a.wheel_accel_max, list(a.gain)) == (
        ROBOT_DEFAULTS["wheel_base"], ROBOT_DEFAULTS["wheel_speed_max"], ROBOT_DEFAULTS["wheel_accel_max"],
        ROBOT_DEFAULTS["gain"])


def test_failure_and_controller_tables_travel_in_the_mission_bit_for_bit():
    sc = scenario_from_dict(doc())
    m = sc.mission
    assert m.failure == (("fail_after_s", 3.0), ("fail_deviation_m", 0.04))
    assert m.controller_gains == (("along_gain_per_s", 1.5), ("deadband_m", 0.003))
    again = decode_mission(encode_mission(m))
    assert again == m and encode_mission(again) == encode_mission(m)
    policy = FailurePolicy(mode=again.on_failure, **dict(again.failure))
    assert (policy.fail_after_s, policy.fail_deviation_m) == (3.0, 0.04)
    make_controller(again.controller, **dict(again.controller_gains))


@pytest.mark.parametrize("schema, words", [(None, "schema = 1"), (2, "schema 2"), ("1", "schema '1'"),
                                           (True, "schema True")])
def test_the_file_must_say_it_is_schema_1(schema, words):
    d = doc()
    if schema is None:
        del d["schema"]
    else:
        d["schema"] = schema
    with pytest.raises(ScenarioError, match=words):
        scenario_from_dict(d)


def misspell(d, path, key, bad):
    t = d
    for p in path:
        t = t[p]
    t[bad] = t.pop(key)
    return d


MISSPELT = [
    ((), "robots", "robot"),
    (("fleet",), "name", "nmae"),
    (("mission",), "controller", "controler"),
    (("failure",), "fail_after_s", "fail_after"),
    (("controller",), "along_gain_per_s", "along_gain"),
    (("defaults",), "wheel_base", "wheelbase"),
    (("robot_types", "big"), "wheel_speed_max", "wheel_speed_mx"),
    (("robots", "c"), "wheel_speed_max", "wheel_sped_max"),
]


@pytest.mark.parametrize("path, key, bad", MISSPELT, ids=[b for *_, b in MISSPELT])
def test_a_misspelt_key_in_any_table_is_rejected_with_the_key_and_its_table_named(path, key, bad):
    with pytest.raises(UnknownKeyError) as err:
        scenario_from_dict(misspell(doc(), path, key, bad))
    assert bad in err.value.keys
    assert repr(bad) in str(err.value)
    where = "top level" if not path else ".".join(path)
    assert f"[{where}]" in str(err.value)


@pytest.mark.parametrize("table, key", [("tracker", "rate"), ("sim", "rate"), ("defaults", "p"),
                                        ("defaults", "start")])
def test_keys_of_another_table_are_unknown_here(table, key):
    d = doc()
    d.setdefault(table, {})[key] = [0.0, 0.0]
    with pytest.raises(UnknownKeyError, match=f"'{key}'"):
        scenario_from_dict(d)


def test_a_robot_type_may_not_set_a_type_or_a_template_point():
    for key in ("type", "p"):
        d = doc()
        d["robot_types"]["big"][key] = "small" if key == "type" else [0.0, 0.0]
        with pytest.raises(UnknownKeyError, match=rf"'{key}' in \[robot_types.big\]"):
            scenario_from_dict(d)


def test_a_robot_of_an_undefined_type_is_rejected():
    d = doc()
    d["robots"]["a"]["type"] = "huge"
    with pytest.raises(ScenarioError, match=r"\[robots.a\] type must be one of .*'big', 'small'.*'huge'"):
        scenario_from_dict(d)


def test_the_controller_table_takes_the_gains_of_the_missions_controller_only():
    d = doc(controller={"horizon_s": 0.5})  # arc's gain; this mission's controller is tracking
    with pytest.raises(UnknownKeyError, match=r"'horizon_s' in \[controller\].*controller 'tracking'"):
        scenario_from_dict(d)
    d["mission"]["controller"] = "arc"
    assert scenario_from_dict(d).mission.controller_gains == (("horizon_s", 0.5),)


def test_a_threshold_or_gain_out_of_range_is_rejected_naming_its_table():
    with pytest.raises(ScenarioError, match=r"\[failure\].*fail_after_s"):
        scenario_from_dict(doc(failure={"fail_after_s": -2.0}))
    with pytest.raises(ScenarioError, match=r"\[controller\].*along_gain_per_s"):
        scenario_from_dict(doc(controller={"along_gain_per_s": 0.0}))


@pytest.mark.parametrize("path", FILES, ids=[p.name for p in FILES])
def test_every_shipped_fleet_file_is_schema_1_and_layered(path):
    raw = tomllib.loads(path.read_text())
    assert raw["schema"] == 1
    assert raw["defaults"] or raw["robot_types"]
    for rid, own in raw["robots"].items():  # no robot repeats what a layer below already says
        kind = own.get("type", raw.get("defaults", {}).get("type"))
        below = {**raw.get("defaults", {}), **raw.get("robot_types", {}).get(kind, {})}
        assert not {k for k, v in own.items() if k != "type" and below.get(k) == v}, rid
    load_scenario(path)


def test_the_lab_fleet_file_resolves_its_types_and_carries_thresholds_and_gains():
    sc = load_scenario(ROOT / "deploy" / "fleet.toml")
    assert {r.robot: (r.wheel_base, r.wheel_speed_max, r.wheel_accel_max) for r in sc.robots} == {
        "r1": (0.12, 0.3, 0.8), "r2": (0.12, 0.3, 0.8), "r3": (0.12, 0.25, 0.8)}
    assert dict(sc.mission.failure)["fail_deviation_m"] == 0.05
    assert dict(sc.mission.controller_gains)["horizon_s"] == 1.0


def test_deploy_config_refuses_a_fleet_file_with_a_misspelt_key_and_names_it(tmp_path, capsys):
    bad = tmp_path / "fleet.toml"
    bad.write_text((ROOT / "deploy" / "fleet.toml").read_text().replace("wheel_speed_max = 0.25",
                                                                        "wheel_sped_max = 0.25"))
    assert deploy.main([str(bad), "--router", "tcp/10.0.0.1:7447", "--out", str(tmp_path / "site")]) == 2
    err = capsys.readouterr().err
    assert "'wheel_sped_max'" in err and "[robots.r3]" in err
    assert not (tmp_path / "site").exists()


def test_mission_set_refuses_a_json_mission_with_a_misspelt_key_and_names_it(tmp_path):
    good = load_scenario(ROOT / "deploy" / "fleet.toml").mission.to_dict()
    path = tmp_path / "mission.json"
    path.write_text(json.dumps(good))
    assert load_mission(str(path)).on_failure == "drop"
    good["on_faliure"] = good.pop("on_failure")
    path.write_text(json.dumps(good))
    with pytest.raises(WireError, match="'on_faliure'"):
        load_mission(str(path))


def test_the_readmes_fleet_file_example_is_valid_and_layers_as_it_says():
    text = (ROOT / "README.md").read_text()
    block = text.split("```toml\n", 1)[1].split("```", 1)[0]
    sc = scenario_from_dict(tomllib.loads(block))
    (r3,) = sc.robots
    assert (r3.wheel_base, r3.wheel_speed_max, r3.wheel_accel_max) == (0.12, 0.25, 0.8)
    assert sc.mission.failure == (("fail_after_s", 2.0),) and sc.mission.controller_gains == (("horizon_s", 1.0),)


def test_the_format_example_in_vsfleet_scenario_is_valid():
    import textwrap

    import vsfleet.scenario

    example = textwrap.dedent(vsfleet.scenario.__doc__.split("Example::\n", 1)[1])
    sc = scenario_from_dict(tomllib.loads(example))
    (r1,) = sc.robots
    assert (r1.wheel_base, r1.wheel_speed_max) == (0.1, 0.25)  # [defaults], then robot type slow
    assert sc.mission.controller_gains == (("along_gain_per_s", 2.0), ("deadband_m", 0.004))
