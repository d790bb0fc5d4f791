"""The agent step alone: CPU time per call of vsfleet.step.agent_step, and of decoding its frame.

For N robots on a circle (bench.loop's mission), one agent's step is run on a
sequence of noisy frames of robots that follow their structure points (so the
failure rule, the fit, the advance and every robot's predicted command all do
their normal work). Reported: the median and p90 over repeats of the time per
step [us], and the frame decode time [us]. No zenoh, no process: this is the
floor of an agent's CPU per tick.

Back to back, the step runs with warm caches. An agent runs it once per frame
and sleeps in between, while other processes run; ``paced_us`` is the same step
run that way (a sleep of one frame period before each call), which is what an
agent process actually pays per tick.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from vsfleet.frames import Frame
from vsfleet.step import AgentState, StepConfig, agent_step
from vsfleet.wire import FrameMsg, decode_frame, encode_frame

from .loop import bench_mission

SIZES = (3, 10, 100, 1000)


def frames_for(n: int, count: int, rate_hz: float = 30.0, seed: int = 0) -> tuple[list[Frame], list[bytes]]:
    """Frames of n robots translating together at 0.05 m/s (+ 1 mm noise), and their encoded messages."""
    mission = bench_mission(n, 0.0)
    rng = np.random.default_rng(seed)
    ids = mission.robot_ids
    base = np.array([mission.spec(r).p for r in ids])
    frames, payloads = [], []
    for k in range(count):
        t = 10.0 + k / rate_hz
        xy = base + (0.05 * (t - 10.0), 0.0) + rng.normal(0.0, 0.001, base.shape)
        poses = {r: (float(x), float(y), float(rng.normal(0.0, 0.005))) for r, (x, y) in zip(ids, xy)}
        frames.append(Frame(seq=k + 1, t=t, poses=poses, complete=True, fresh=frozenset(ids), src="bench"))
        payloads.append(encode_frame(FrameMsg(t=t, seq=k + 1, src="bench", poses=poses)))
    return frames, payloads


def time_step(n: int, count: int, rate_hz: float = 30.0, paced: int = 0, reference: bool = False) -> dict[str, float]:
    """Per-call CPU time [us] of agent_step (median, p90 over count frames) and of decode_frame;
    with ``paced``, also the step's median when each of ``paced`` more calls follows a sleep of
    one frame period (as in an agent process: caches gone cold in between). ``reference``: the old
    numpy step (StepConfig.reference) instead of the compiled core."""
    mission = bench_mission(n, 0.0)
    frames, payloads = frames_for(n, count, rate_hz)
    config = StepConfig(dt_s=1.0 / rate_hz, reference=reference)
    state = AgentState(mission.robot_ids[0])
    step_us, decode_us = [], []
    for f, p in zip(frames, payloads):
        t0 = time.thread_time_ns()
        decode_frame(p)
        t1 = time.thread_time_ns()
        state, _ = agent_step(state, mission, f, f.t + 0.01, config)
        t2 = time.thread_time_ns()
        decode_us.append((t1 - t0) / 1e3)
        step_us.append((t2 - t1) / 1e3)
    warm = slice(min(len(step_us) // 4, 60), None)  # after the failure rule's window has filled
    s, d = np.array(step_us[warm]), np.array(decode_us[warm])
    out = {"n": n, "step_p50_us": float(np.median(s)), "step_p90_us": float(np.percentile(s, 90)),
           "decode_p50_us": float(np.median(d)), "frames": int(s.size)}
    if paced:
        cold = []
        for f in frames[-paced:]:  # again, on the same state: the rule's window stays full
            time.sleep(1.0 / rate_hz)
            t1 = time.thread_time_ns()
            state, _ = agent_step(state, mission, replace(f, t=f.t + count / rate_hz), f.t + count / rate_hz
                                  + 0.01, config)
            cold.append((time.thread_time_ns() - t1) / 1e3)
        out["paced_p50_us"] = float(np.median(cold))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", default=",".join(map(str, SIZES)))
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--paced", type=int, default=0, help="also this many calls paced at 30 Hz (cold caches)")
    p.add_argument("--reference", action="store_true", help="also the old numpy step, beside the core")
    a = p.parse_args(argv)
    for n in (int(x) for x in a.sizes.split(",")):
        for ref in ((False, True) if a.reference else (False,)):
            r = time_step(n, a.frames if n < 1000 else max(100, a.frames // 3), paced=a.paced, reference=ref)
            print(f"{'numpy' if ref else 'core '} N={n:5d}: step p50 {r['step_p50_us']:9.1f} us, "
                  f"p90 {r['step_p90_us']:9.1f} us; decode p50 {r['decode_p50_us']:7.1f} us ({r['frames']} frames)"
                  + (f"; paced at 30 Hz p50 {r['paced_p50_us']:.1f} us" if a.paced else ""), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
