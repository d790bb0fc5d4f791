"""Golden vectors of the agent step: recorded inputs (mission, frames, clock) and outputs as hex floats.

``python tests/golden_step.py`` records them into tests/data/golden-step.json: the paper
failure scenario under ``drop`` (r2 halts at 8 s and is dropped) for 16 s of 30 Hz frames,
observed with noise, and every agent's outputs. tests/test_golden_step.py replays the
inputs through vsfleet.step.agent_step and requires the same outputs bit for bit. Record
again only on purpose (a change of the controller, the advance or the failure rule) and say
so in the commit.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from vsfleet.zglue.scenario_file import load_scenario
from vsfleet.simfleet.physics import Fault, RobotState, step_fleet
from vsfleet.frames import Frame
from vsfleet.geometry import Pose2
from vsfleet.step import AgentState, StepConfig, StepOutput, agent_step
from vsfleet.wire import decode_mission, encode_mission

ROOT = Path(__file__).resolve().parent.parent
PATH = ROOT / "tests" / "data" / "golden-step.json"
SECONDS, SEED = 16.0, 7


def hexes(values) -> list[str]:
    return [float(v).hex() for v in values]


def outputs(out: StepOutput) -> dict:
    """One step's outputs in a form that compares bit for bit (hex floats)."""
    d: dict = {}
    if out.cmd is not None:
        d["cmd"] = hexes((out.cmd.vl, out.cmd.vr))
    if out.state is not None:
        s = out.state
        d["state"] = hexes((s.x, s.y, s.th, s.gx, s.gy, s.gth, s.cost, s.err)) + [list(s.used)]
    if out.wheels_m_s is not None:
        d["wheels"] = hexes(out.wheels_m_s.ravel())
    if out.health is not None:
        d["health"] = [list(out.health.failed), list(out.health.dropped),
                       [[r, float(t).hex()] for r, t in out.health.since]]
    d["events"] = [[e.robot, e.kind, float(e.t).hex(), float(e.dev).hex()] for e in out.events]
    return d


def replay(mission, frames, config: StepConfig, robot: str) -> list[dict]:
    """Every frame through agent_step for ``robot``'s agent: its outputs, in order."""
    state, got = AgentState(robot), []
    for f, now in frames:
        state, out = agent_step(state, mission, f, now, config)
        got.append(outputs(out))
    return got


def record() -> dict:
    sc = load_scenario(ROOT / "scenarios" / "paper-failure.toml")
    mission = dataclasses.replace(sc.mission, on_failure="drop", effective_t=0.0)
    dt = 1.0 / sc.tracker.rate_hz
    config = StepConfig(dt_s=dt, command_age_s=dt)
    robots = {r.robot: r for r in sc.robots}
    states = {r.robot: RobotState(Pose2(*r.start)) for r in sc.robots}
    faults = {r: Fault() for r in robots}
    timeline = list(sc.faults)
    rng = np.random.default_rng(SEED)
    agents = {r: AgentState(r) for r in robots}
    substeps = max(1, round(sc.sim.rate_hz / sc.tracker.rate_hz))
    t, frames, outs = 0.0, [], {r: [] for r in robots}
    cmds = {r: (0.0, 0.0) for r in robots}
    for k in range(int(SECONDS * sc.tracker.rate_hz)):
        poses = {r: (s.pose.x + rng.normal(0.0, 0.002), s.pose.y + rng.normal(0.0, 0.002),
                     s.pose.th + rng.normal(0.0, 0.01)) for r, s in states.items()}
        if k % 97 == 50:  # now and then a robot is missing from a frame
            poses.pop(sorted(poses)[k % 3])
        frame = Frame(seq=k + 1, t=t, poses=poses, complete=len(poses) == 3, fresh=frozenset(poses), src="sim")
        now = t + 0.004
        frames.append({"t": t.hex(), "now": now.hex(), "seq": k + 1,
                       "poses": {r: hexes(p) for r, p in poses.items()}})
        for r in robots:
            agents[r], out = agent_step(agents[r], mission, frame, now, config)
            outs[r].append(outputs(out))
            if out.cmd is not None:
                cmds[r] = (out.cmd.vl, out.cmd.vr)
        t = step_fleet(states, robots, cmds, faults, timeline, t, dt / substeps, substeps)
    kept = ("r1", "r2")  # one healthy agent and the failing robot's own (all agents' rows agree: tested)
    return {"mission": encode_mission(mission).hex(), "dt_s": dt.hex(), "frames": frames,
            "outputs": {r: outs[r] for r in kept}}


def load(path: Path = PATH):
    """(mission, [(Frame, now)], config, {robot: outputs}) of the recorded vectors."""
    d = json.loads(path.read_text())
    mission = decode_mission(bytes.fromhex(d["mission"]))
    dt = float.fromhex(d["dt_s"])
    frames = []
    for f in d["frames"]:
        poses = {r: tuple(float.fromhex(v) for v in p) for r, p in f["poses"].items()}
        frames.append((Frame(seq=f["seq"], t=float.fromhex(f["t"]), poses=poses, complete=len(poses) == 3,
                             fresh=frozenset(poses), src="sim"), float.fromhex(f["now"])))
    return mission, frames, StepConfig(dt_s=dt, command_age_s=dt), d["outputs"]


if __name__ == "__main__":
    PATH.write_text(json.dumps(record(), separators=(",", ":")) + "\n")
    print(f"wrote {PATH}")
