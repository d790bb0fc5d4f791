"""What the agent step holds per mission: equal missions share one CoreMission, each robot's agent step (kernel) is
built once per mission, not once per frame, and at most MISSIONS_HELD missions (and their rooms' fields) are held."""

import dataclasses

import vsfleet.agentstate as agentstate
from vsfleet import _core
from vsfleet.simfleet.offline import run_offline
from vsfleet.wire import decode_mission, encode_mission
from vsfleet.zglue.scenario_file import load_scenario


def test_equal_missions_decoded_apart_share_one_core_mission():
    mission = load_scenario("scenarios/room-wall-gap.toml").mission
    a, b = decode_mission(encode_mission(mission)), decode_mission(encode_mission(mission))
    assert a is not b and a == b
    assert agentstate.core_mission_of(a) is agentstate.core_mission_of(b)
    other = dataclasses.replace(a, version=a.version + 1)
    assert agentstate.core_mission_of(other) is not agentstate.core_mission_of(a)


def test_an_offline_fleet_of_100_builds_each_robots_step_once(monkeypatch):
    """ring-100 offline: 100 agents, each with its own decoded mission. Before, the step's caches held 16 missions
    and 16 kernels, and every agent rebuilt both at every frame (984 us a frame an agent, 172 us since)."""
    sc = load_scenario("scenarios/ring-100.toml")
    built = []
    make = _core.agent_config
    monkeypatch.setattr(_core, "agent_config", lambda *a: built.append(a[1]) or make(*a))
    run = run_offline(sc, 0.3)
    assert len(run.trace) >= 8   # frames ran
    assert sorted(built) == list(range(100))   # one kernel per robot (its index), over every frame


def test_at_most_missions_held_core_missions_are_alive():
    base = load_scenario("scenarios/paper-triangle.toml").mission
    kept = []
    for v in range(3 * agentstate.MISSIONS_HELD + 5):
        m = decode_mission(encode_mission(dataclasses.replace(base, version=1000 + v)))
        kept.append(m)   # every mission object stays alive: only the step's own holding is bounded
        agentstate.core_mission_of(m)
    held = {id(cm) for cm in agentstate._BY_VALUE.values()}
    assert 1 <= len(held) <= agentstate.MISSIONS_HELD
    assert {id(cm) for _, cm in agentstate._MISSIONS.values()} <= held   # nothing held beside them
