"""Drive an Agent (vsfleet.agent.main) through missions, with or without numpy importable
(tests/test_agent_numpy_free.py). Run as a script it makes numpy (and scipy) unimportable first, drives a
core agent, and prints what it sent as JSON: the agent process must not need numpy (issue 29).

The run: a mission of three point robots; frames in one pass (fast_frame) and frames the long way (a frame
without one robot, a second tracker source for a while, a gap past the command's ttl and the resync after it);
the peers' health adopted; a mission update with bodies and an obstacle (its room's field built on the prepare
thread) that fails a robot standing still; a path under turn_then_go with the l-infinity fit, a twist under tracking
with the l1 fit; the stop command."""

from __future__ import annotations

import importlib.abc
import json
import sys

BLOCKED = ("numpy", "scipy")


class _Refuse(importlib.abc.MetaPathFinder):
    """Makes numpy and scipy unimportable: any import of them raises, wherever it is."""

    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ImportError(f"{name} imported by the agent (issue 29: it must not be)")
        return None


def drive(glue: bool = False) -> dict:
    """Every payload the agent sent (hex), in order by kind, and the ways its frames went. glue: every frame through
    vsfleet.step's numpy glue around the core's kernels (as an offline run that shares structures), the long way."""
    from vsfleet.agent.main import Agent, prepare_mission
    from vsfleet.wire import FrameMsg, HealthMsg, Keys, Mission, RobotSpec, encode_frame, encode_health, \
        encode_mission

    keys = Keys("demo")
    specs = (("r1", RobotSpec((0.3, 0.0), 0.12, 0.3, 0.8)), ("r2", RobotSpec((-0.15, 0.26), 0.12, 0.3, 0.8)),
             ("r3", RobotSpec((-0.15, -0.26), 0.12, 0.3, 0.8)))
    mission = Mission(1, "l2", specs, 0.08, 0.3, 0.0, goal=(1.0, 0.5, 0.0))
    clock = [100.0]
    sent: dict[str, list[str]] = {"cmd": [], "state": [], "event": []}
    agent = Agent("r1", keys, lambda b: sent["cmd"].append(b.hex()), lambda b: sent["state"].append(b.hex()),
                  clock=lambda: clock[0], put_event=lambda b: sent["event"].append(b.hex()),
                  shared_structures={} if glue else None,
                  prepare=lambda m: prepare_mission(m).join(timeout=60.0))   # the room's field on its own thread
    agent.on_message("mission", keys.mission, encode_mission(mission))
    ways = {"fast": 0, "long": 0}
    pose = {"r1": [0.3, 0.0, 0.0], "r2": [-0.15, 0.26, 0.0], "r3": [-0.15, -0.26, 0.0]}

    def frame(seq: int, t: float, robots=("r1", "r2", "r3"), src: str = "sim") -> None:
        clock[0] = t
        for r in robots:   # the robots drift toward the goal, r3 standing still from seq 200 on
            if not (r == "r3" and seq >= 200):
                pose[r][0] += 0.002
                pose[r][1] += 0.001
        payload = encode_frame(FrameMsg(t, seq, src, {r: tuple(pose[r]) for r in robots}))
        if agent.fast_frame(keys.frame(src), payload):
            ways["fast"] += 1
        else:
            agent.on_frame(keys.frame(src), payload, wake=False)
            agent.poll()
            ways["long"] += 1

    seq, t = 0, 100.0
    for _ in range(40):
        seq, t = seq + 1, t + 1 / 30
        frame(seq, t)
    agent.on_query_replies("health", [(keys.peer_health(p), encode_health(HealthMsg(
        t=t, seq=seq, mission=1, failed=("r2",), dropped=(), since=(("r2", t - 0.5),)))) for p in ("r2", "r3")])
    for k in range(60):   # r2 missing from some frames, a second source for a while
        seq, t = seq + 1, t + 1 / 30
        frame(seq, t, ("r1", "r3") if k % 7 == 3 else ("r1", "r2", "r3"), "sim" if k < 30 or k > 45 else "cam")
    t += 1.5   # a gap past ttl and the resync gap
    room = Mission(2, "l2", tuple((r, RobotSpec(s.p, s.wheel_base, s.wheel_speed_max, s.wheel_accel_max,
                                                radius=0.05)) for r, s in specs), 0.08, 0.3, t + 0.5,
                   goal=(1.5, 0.8, 0.0), obstacles=((1.2, -0.6, 0.1),), on_failure="drop")
    agent.on_message("mission", keys.mission, encode_mission(room))
    for k in range(200):
        seq, t = seq + 1, t + 1 / 30
        frame(seq, t)
        if k == 5:   # resyncing since the gap: no peer answers, so the agent decides alone from now on
            agent.health_replies([])
    t += 0.5   # a path under another controller, then a twist
    path = Mission(3, "linf", specs, 0.08, 0.3, t + 0.2, path=((1.6, 0.9, 0.0), (2.0, 1.2, 0.5)),
                   controller="turn_then_go")
    agent.on_message("mission", keys.mission, encode_mission(path))
    for _ in range(40):
        seq, t = seq + 1, t + 1 / 30
        frame(seq, t)
    twist = Mission(4, "l1", specs, 0.08, 0.3, t + 0.2, twist=(0.05, 0.0, 0.1), controller="tracking")
    agent.on_message("mission", keys.mission, encode_mission(twist))
    for _ in range(40):
        seq, t = seq + 1, t + 1 / 30
        frame(seq, t)
    sent["stop"] = [agent.stop_command().hex()]
    return {"sent": sent, "ways": ways, "phase": agent.state.phase.value, "ticks": agent.ticks,
            "rejected": agent.rejections.count,
            "numpy": "numpy" in sys.modules, "scipy": "scipy" in sys.modules}


if __name__ == "__main__":
    sys.meta_path.insert(0, _Refuse())
    out = drive()
    out["numpy"] = "numpy" in sys.modules
    print(json.dumps(out))
