"""bench/soak.py without processes: the schedule of injected faults, what is left out of the agreement, and the
report's computations on synthetic data."""

from __future__ import annotations

import math
from collections import Counter

import pytest

from bench import soak
from vsfleet.wire import Keys, StateMsg, TruthMsg
from vsfleet.zglue.scenario_file import load_scenario


def test_a_30_minute_soak_injects_what_the_issue_asks_spaced_apart():
    plan = soak.schedule(1800.0)
    kinds = Counter(i.kind for i in plan)
    assert kinds == {"agent_kill": 15, "mission": 12, "blackout": 10, "router": 3}
    assert all(soak.WARMUP_S < i.t <= 1800.0 - soak.TAIL_S for i in plan)
    assert [i.t for i in plan] == sorted(i.t for i in plan)
    assert min(b.t - a.t for a, b in zip(plan, plan[1:])) >= soak.MIN_SPACING_S
    kills = [i for i in plan if i.kind == "agent_kill"]
    assert [i.target for i in kills] == ["r1", "r2", "r3"] * 5            # rotating robots
    assert [i.t for i in kills] == [75.0 + 120.0 * k for k in range(15)]  # every 2 minutes
    assert [i.t for i in plan if i.kind == "router"] == [100.0, 700.0, 1300.0]  # every 10 minutes
    blackouts = [i.t for i in plan if i.kind == "blackout"]
    assert all(175.0 <= b - a <= 185.0 for a, b in zip(blackouts, blackouts[1:]))  # every 3 minutes
    missions = [i for i in plan if i.kind == "mission"]
    assert [i.target for i in missions] == ["1", "0"] * 6                  # alternating goals
    assert all(b.t - a.t <= 150.0 + soak.MIN_SPACING_S + 5.0 for a, b in zip(missions, missions[1:]))


def test_a_2_minute_soak_has_one_injection_of_each_kind():
    plan = soak.schedule(120.0)
    assert [(i.kind, i.target) for i in plan] == [("mission", "1"), ("blackout", "tracker"),
                                                  ("agent_kill", "r1"), ("router", "router")]


def test_a_pushed_injection_keeps_its_distance():
    plan = soak.schedule(600.0, kill_every_s=20.0, blackout_every_s=20.0, router_every_s=0, mission_every_s=0)
    assert min(b.t - a.t for a, b in zip(plan, plan[1:])) >= soak.MIN_SPACING_S


def test_frames_near_a_fault_are_left_out_and_mission_changes_are_not():
    done = [{"kind": "blackout", "start": 100.0, "end": 101.0}, {"kind": "mission", "start": 200.0, "end": 200.0},
            {"kind": "agent_kill", "start": 300.0, "end": None}]
    w = soak.fault_windows(done)
    assert w == [(100.0, 101.0), (300.0, None)]
    assert not soak.excluded(99.4, w, 5.0)
    assert soak.excluded(99.6, w, 5.0) and soak.excluded(106.0, w, 5.0)
    assert not soak.excluded(106.1, w, 5.0)
    assert not soak.excluded(200.5, w, 5.0)      # a mission change is not a fault
    assert soak.excluded(1e6, w, 5.0)            # a fault still on leaves out everything after it


def _inst(name, index, first, last, started=0.0, **kw):
    return {"name": name, "index": index, "started": started, "ended": None, "first_rss": first, "last_rss": last,
            "first_at": started + 30.0, "last_at": 1800.0, **kw}


def test_rss_shows_the_newest_instance_and_the_largest_growth_of_any():
    rows = soak.rss_rows([_inst("sim", 1, 60.0, 61.5), _inst("agent-r1", 1, 70.0, 75.0),
                          _inst("agent-r1", 2, 70.0, 70.5, started=400.0), _inst("router", 1, 50.0, 50.1)])
    by = {r["process"]: r for r in rows}
    assert [r["process"] for r in rows] == ["router", "sim", "agent-r1"]
    assert by["sim"]["holds"] and by["sim"]["growth_mib"] == pytest.approx(1.5)
    assert by["agent-r1"]["growth_mib"] == pytest.approx(0.5)
    assert by["agent-r1"]["max_growth_mib"] == pytest.approx(5.0) and not by["agent-r1"]["holds"]
    assert by["agent-r1"]["instance"] == "instance 2 of 2, from 6:40"


def test_cpu_per_frame_sums_over_an_agents_instances():
    rows = soak.cpu_rows([
        {"name": "agent-r1", "first_cpu": 1.0, "last_cpu": 2.0, "first_states": 100, "last_states": 600},
        {"name": "agent-r1", "first_cpu": 1.0, "last_cpu": 1.5, "first_states": 0, "last_states": 500},
        {"name": "sim", "first_cpu": 1.0, "last_cpu": 9.0, "first_states": 0, "last_states": 0}])
    assert rows == [{"agent": "agent-r1", "cpu_ms_per_frame": pytest.approx(1.5), "frames": 1000, "instances": 2}]


def test_rejections_are_compared_only_where_they_can_be_exact():
    sent = {"frame": 100, "mission": 100, "cmd": 100, "fault": 100}
    segs = [{"index": 1, "sent": sent, "router_outage": False, "why": {"r2": "the agent was killed"},
             "counted": {"r1": 200, "r2": None, "r3": 199, "simfleet": 200}},
            {"index": 2, "sent": sent, "router_outage": True, "why": {},
             "counted": {"r1": 150, "r2": 150, "r3": 150, "simfleet": 150}}]
    rows = {r["receiver"]: r for r in soak.rejection_rows(segs)}
    assert rows["agent r1"]["segments"] == 1 and rows["agent r1"]["exact"] == 1
    assert rows["agent r1"]["not_compared"] == {"a router restart in the segment": 1}
    assert rows["agent r2"]["segments"] == 0 and rows["agent r2"]["sent_all"] == 400
    assert rows["agent r3"]["mismatches"] == [{"segment": 1, "sent": 200, "counted": 199}]
    assert rows["simfleet"]["kinds"] == "cmd+fault" and rows["simfleet"]["exact"] == 1


def _state(t, seq, x, complete=True):
    return StateMsg(t=t, seq=seq, x=x, y=0.0, th=0.0, gx=x, gy=0.0, gth=0.0, cost=0.0, err=0.0,
                    used=("r1", "r2", "r3"), rejected=0, complete=complete)


def _truth(t, x, y):
    return TruthMsg(t=t, x=x, y=y, th=0.0, vl=0.0, vr=0.0)


def test_agreement_and_contacts_are_tallied_from_what_was_observed(tmp_path):
    path = tmp_path / "soak.toml"
    path.write_text(soak.SCENARIO.format(fleet="soak", duration_s=60, gx=1.0, gy=0.0, gth=0.0))
    tally = soak.Tally(Keys("soak"), load_scenario(path).mission)
    groups = {1: {"r1": _state(10.0, 1, 0.5), "r2": _state(10.0, 1, 0.5), "r3": _state(10.0, 1, 0.5)},
              2: {"r1": _state(10.1, 2, 0.5), "r2": _state(10.1, 2, 0.5 + 1e-12)},       # differs, outside
              3: {"r1": _state(20.5, 3, 0.5), "r2": _state(20.5, 3, 0.6)},                # differs, within a fault
              4: {"r1": _state(10.2, 4, 0.5)},                                            # one agent: not compared
              5: {"r1": _state(10.3, 5, 0.5), "r2": _state(10.3, 5, 0.5, complete=False)}}  # on its deadline
    tally.state_groups = groups
    tally.state_first = {s: 0.0 for s in groups}
    tally.truth_groups = {10.0: {"r1": _truth(10.0, 0.0, 0.0), "r2": _truth(10.0, 0.5, 0.0)},
                          10.01: {"r1": _truth(10.01, 0.0, 0.0), "r2": _truth(10.01, 0.09, 0.0)}}  # radii 0.05: overlap
    tally.truth_first = {t: 0.0 for t in tally.truth_groups}
    tally.finalize([(20.0, 21.0)], settle_s=5.0, older_than_s=-1.0, t0=0.0)
    assert tally.outside == [2, 1] and tally.inside == [1, 0]
    assert tally.all3 == 1 and tally.skipped == 2
    assert [(d["seq"], d["outside"]) for d in tally.disagreements] == [(2, True), (3, False)]
    assert tally.truth_frames == 2 and tally.contacts == 1
    assert tally.min_gap == pytest.approx(-0.01)
    assert not tally.state_groups and not tally.truth_groups


def test_the_targets_are_reported_as_measured():
    rep = {"rss": soak.rss_rows([_inst("sim", 1, 60.0, 63.0)]), "crashes": [],
           "contacts": {"frames": 0, "truth_frames": 100, "min_gap_m": 0.4},
           "agreement": {"outside": {"frames": 10000, "identical": 9990}}}
    got = {t["target"]: t for t in soak.targets(rep)}
    assert got["0 crashes"]["holds"] and got["0 contacts"]["holds"]
    assert not got["RSS growth <= 2 MiB per process"]["holds"]
    assert "+3.00 MiB (sim)" in got["RSS growth <= 2 MiB per process"]["value"]
    assert got[">= 99.9% of frames bit-identical outside injected faults"]["holds"]   # exactly 99.9%
    rep["agreement"]["outside"]["identical"] = 9989
    assert not soak.targets(rep)[3]["holds"]


def test_moving_fraction():
    assert soak.moving_fraction([(0, 0.0, 0.0), (5, 0.4, 0.0), (10, 0.4, 0.0)]) == 0.5
    assert math.isnan(soak.moving_fraction([]))
