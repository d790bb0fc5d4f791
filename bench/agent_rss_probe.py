"""What grows an agent's memory (issue 30, RSS): the soak's fleet offline, one Agent per robot in this process,
with the soak's mission changes (accelerated), its RssAnon over frames.

The e2e triangle of bench/soak.py (its scenario), the agents fed counted frames as in
simfleet.offline (through on_frame/poll, physics by step_fleet), a new mission (the next version, the goal
alternating between the soak's two goals, effective 1.5 s later) every --mission-every frames, each new
mission prepared as `vsfleet agent` does: --prepare thread (agent.main.prepare_mission: its arrays built on a
thread of its own), inline (built by the first frame that needs it) or none. --distinct: every mission a new
goal (never seen before) instead of two alternating ones. --fuzz N: N invalid frames and N invalid missions
per frame (the fuzzer's payloads, vsfleet.fleetctl.fuzz.bad_payload) through the same entry points.

Prints one JSON line per --every frames (frame, missions so far, RssAnon, threads) and a summary; writes no file.
Run: .venv/bin/python -m bench.agent_rss_probe --frames 20000 --mission-every 900 --prepare thread
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import random
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def mem() -> dict[str, float]:
    out = {}
    for line in Path("/proc/self/status").read_text().splitlines():
        k, _, v = line.partition(":")
        if k in ("VmRSS", "RssAnon", "Threads"):
            out[k] = float(v.split()[0]) / (1024.0 if k != "Threads" else 1.0)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20000)
    ap.add_argument("--mission-every", type=int, default=900, help="frames between missions (0: never)")
    ap.add_argument("--prepare", choices=["thread", "inline", "none"], default="thread")
    ap.add_argument("--distinct", action="store_true")
    ap.add_argument("--fuzz", type=int, default=0)
    ap.add_argument("--every", type=int, default=1000)
    args = ap.parse_args(argv)

    import numpy as np
    from bench.soak import SCENARIO, goals
    from vsfleet.wire import FrameMsg, Keys, encode_frame, encode_mission
    from vsfleet.scenario import scenario_from_dict
    from vsfleet.agent.main import Agent, prepare_mission
    from vsfleet.simfleet.physics import Fault, RobotState, step_fleet
    from vsfleet.geometry import Pose2
    from vsfleet.control import make_controller, DEFAULT_CONTROLLER

    g = goals(5.5)
    sc = scenario_from_dict(tomllib.loads(SCENARIO.format(fleet="probe", duration_s=3600, gx=g[0][0], gy=g[0][1],
                                                          gth=g[0][2])), name="soak")
    mission0 = dataclasses.replace(sc.mission, version=1, effective_t=0.0)
    robots = {r.robot: r for r in sc.robots}
    states = {r.robot: RobotState(Pose2(*r.start)) for r in sc.robots}
    faults = {r: Fault() for r in robots}
    dt = 1.0 / sc.tracker.rate_hz
    substeps = max(1, round(sc.sim.rate_hz / sc.tracker.rate_hz))
    keys = Keys("probe")
    sent: dict = {}
    t = 0.0
    rng = np.random.default_rng(0)
    prep = {"thread": prepare_mission, "inline": None, "none": None}[args.prepare]
    agents = {}
    for r in robots:
        agents[r] = Agent(r, keys, put_cmd=lambda b, r=r: sent.__setitem__(r, b), put_state=lambda b: None,
                          dt_s=dt, clock=lambda: t, controller=make_controller(DEFAULT_CONTROLLER),
                          command_age_s=dt, shared_structures=None, prepare=prep)
        agents[r].on_mission(keys.mission, encode_mission(mission0))
    from vsfleet.simfleet.offline import _wheels
    from vsfleet.fleetctl.fuzz import bad_payload, CATEGORIES
    frng = random.Random(1)
    cmds = {r: (0.0, 0.0) for r in robots}
    version = 1
    rows = []
    for k in range(args.frames):
        if args.mission_every and k and k % args.mission_every == 0:
            version += 1
            goal = g[version % 2] if not args.distinct else (5.5 - 0.001 * version, 0.8, 0.3 * (-1) ** version)
            m = dataclasses.replace(sc.mission, goal=goal, version=version, effective_t=t + 1.5)
            payload = encode_mission(m)
            for a in agents.values():
                a.on_mission(keys.mission, payload)
        poses = {r: (s.pose.x + rng.normal(0, 0.001), s.pose.y + rng.normal(0, 0.001), s.pose.th + rng.normal(0, 0.005))
                 for r, s in states.items()}
        frame = encode_frame(FrameMsg(t=t, seq=k + 1, src="offline", poses=poses))
        sent.clear()
        for a in agents.values():
            for _ in range(args.fuzz):
                a.on_frame(keys.frame("fuzz"), bad_payload("frame", frng.choice(CATEGORIES), t, frng))
                cat = frng.choice([c for c in CATEGORIES if c != "oversized"])
                a.on_mission(keys.mission, bad_payload("mission", cat, t, frng))
            a.on_frame(keys.frame("offline"), frame)
            a.poll()
        cmds = {r: _wheels(sent[r]) if r in sent else (0.0, 0.0) for r in robots}
        t = step_fleet(states, robots, cmds, faults, [], t, dt / substeps, substeps)
        if k % args.every == 0 or k == args.frames - 1:
            row = {"frame": k, "missions": version, **{a: round(b, 3) for a, b in mem().items()},
                   "x": round(sum(s.pose.x for s in states.values()) / 3, 2)}
            rows.append(row)
            print(json.dumps(row), flush=True)
    print(json.dumps({"summary": True, "prepare": args.prepare, "distinct": args.distinct, "fuzz": args.fuzz,
                      "anon_first": rows[0]["RssAnon"], "anon_end": rows[-1]["RssAnon"],
                      "anon_peak": max(r["RssAnon"] for r in rows)}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
