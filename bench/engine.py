"""The kinematic engine and MuJoCo side by side: the same closed loop on both, and MuJoCo's cost.

1. The paper triangle (scenarios/paper-triangle.toml) and the halted robot (scenarios/paper-failure.toml:
   r2 stops at 8 s, on_failure hold), offline (simfleet.offline.run_offline: the real agents on counted
   frames, the scenario's tracker noise, commands one frame late) on each engine, over seeds: mean and
   max formation error (every robot's distance from its point on the structure fitted to the true
   positions, every frame until the goal), time to goal, wheel-command jitter (total variation of the
   commands per robot per second, until the goal), contacts the engine reported.
2. Contacts: a pillar on the path (scenarios/paper-triangle-obstacle.toml) and a crowded start
   (scenarios/tight-row.toml, bodies 2 cm apart), on each engine: the contacts MuJoCo reports and the
   smallest gap between bodies and obstacles from the true positions.
3. Real time at 200 Hz for 30 robots (bodies 0.08 m, 0.3 m apart, all driven): CPU per simulated second
   of the engine's step alone and of simfleet's step with its truth messages encoded, in this process;
   then `vsfleet sim` itself as a process on a loopback router (3 runs per engine), with this process
   commanding all 30 robots at 30 Hz and reading their truth: simulated seconds per wall second, steps
   over 100 ms late (its own count) and its CPU per simulated second (from /proc, from its first truth
   message on), with the machine's load average.

Writes engine.md (a section of docs/benchmarks.md), engine.summary and engine.json under
runs/bench/engine/, or --out DIR, or with --docs docs/bench/sections/.

Run: .venv/bin/python bench/engine.py [--seeds 1 2 3] [--live-seconds 15] [--live-runs 3] [--out DIR | --docs]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.outputs import DOCS, add_output_flags  # noqa: E402
from vsfleet.fleetctl.router import open_loopback_router  # noqa: E402
from vsfleet.fleetctl.run import child_command  # noqa: E402
from vsfleet.scenario import ENGINES  # noqa: E402
from vsfleet.simfleet.engine import make_engine  # noqa: E402
from vsfleet.simfleet.main import Fleet  # noqa: E402
from vsfleet.simfleet.offline import run_offline  # noqa: E402
from vsfleet.simfleet.physics import Fault, FaultArrays  # noqa: E402
from vsfleet.wire import CmdMsg, Keys, decode_truth, encode  # noqa: E402
from vsfleet.zglue.scenario_file import load_scenario  # noqa: E402
from vsfleet.zglue.zconf import zenoh_flags  # noqa: E402

SCENARIOS = ROOT / "scenarios"
LOOP_CASES = (("paper triangle", "paper-triangle"), ("halted robot (r2 stops at 8 s, hold)", "paper-failure"))
CONTACT_CASES = (("pillar on the path", "paper-triangle-obstacle"), ("crowded start (2 cm apart)", "tight-row"))
N_ROBOTS = 30
SPACING_M = 0.3
RADIUS_M = 0.08
CMD = (0.10, 0.12)  # every robot's wheels [m/s]: the same gentle arc, so no two meet
FLEET30 = "engine30"


# ---------------------------------------------------------------- 1, 2: the closed loop on each engine


def min_gap_m(run, scenario) -> float:
    """The smallest gap [m] between two bodies or a body and an obstacle over the run (true positions)."""
    radii = {r.robot: r.radius or 0.0 for r in scenario.robots}
    rad = np.array([radii[r] for r in run.robots])
    pos = run.positions_m  # (frames, n, 2)
    gap = np.inf
    for i in range(len(rad)):
        for j in range(i + 1, len(rad)):
            gap = min(gap, float(np.min(np.hypot(*(pos[:, i] - pos[:, j]).T)) - rad[i] - rad[j]))
        for ox, oy, ro in scenario.mission.obstacles:
            gap = min(gap, float(np.min(np.hypot(pos[:, i, 0] - ox, pos[:, i, 1] - oy))) - rad[i] - ro)
    return gap


def loop_case(name: str, engine: str, seed: int) -> dict:
    sc = load_scenario(SCENARIOS / f"{name}.toml")
    t0 = time.process_time()
    run = run_offline(sc, sc.duration_s, engine=engine, seed=seed)
    cpu = time.process_time() - t0
    return {"scenario": name, "engine": engine, "seed": seed, "mean_m": float(run.deviations_m.mean()),
            "max_m": float(run.deviations_m.max()), "t_goal_s": run.t_goal_s, "jitter_m_s2": run.wheel_tv_m_s2,
            "contacts": [c.describe() for c in run.contacts], "min_gap_m": min_gap_m(run, sc),
            "sim_s": float(run.trace[-1][0]), "cpu_s": cpu}


def summarise(cases: list[dict]) -> dict:
    goals = [c["t_goal_s"] for c in cases]
    reached = [g for g in goals if g is not None]
    return {"mean_cm": 100 * float(np.mean([c["mean_m"] for c in cases])),
            "max_cm": 100 * max(c["max_m"] for c in cases),
            "t_goal_s": float(np.mean(reached)) if reached else None, "reached": len(reached), "runs": len(goals),
            "jitter_m_s2": float(np.mean([c["jitter_m_s2"] for c in cases])),
            "contacts": sum(len(c["contacts"]) for c in cases),
            "min_gap_cm": 100 * min(c["min_gap_m"] for c in cases),
            "cpu_per_sim_s": float(sum(c["cpu_s"] for c in cases) / sum(c["sim_s"] for c in cases))}


# ---------------------------------------------------------------- 3: 30 robots at 200 Hz


def fleet30_toml() -> str:
    rows = [f'[robots.r{i:02d}]\np = [{SPACING_M * (i % 6):.2f}, {SPACING_M * (i // 6):.2f}]\n'
            for i in range(N_ROBOTS)]
    return ('schema = 1\n[fleet]\nname = "%s"\nduration_s = 60.0\n[mission]\nmetric = "l2"\nspeed_max = 0.05\n'
            'turn_rate_max = 0.3\ntwist = { vx = 0.0, vy = 0.0, w = 0.0 }\n[sim]\nrate_hz = 200.0\n'
            'truth_rate_hz = 100.0\n[defaults]\nwheel_base = 0.12\nwheel_speed_max = 0.3\nwheel_accel_max = 0.8\n'
            'radius = %r\n' % (FLEET30, RADIUS_M)) + "".join(rows)


def in_process(scenario, engine: str, sim_s: float) -> dict:
    """CPU [s] per simulated second: the engine's step alone, then simfleet's Fleet.step with its truth
    messages encoded at the truth rate (its loop without zenoh), every robot commanded."""
    n, dt = len(scenario.robots), 1.0 / scenario.sim.rate_hz
    steps = int(round(sim_s / dt))
    e = make_engine(engine, scenario.robots, scenario.mission.obstacles, dt)
    cmd, fresh, faults = np.tile(CMD, (n, 1)), np.ones(n, dtype=bool), FaultArrays.of([Fault()] * n)
    t0 = time.process_time()
    for k in range(steps):
        e.step(cmd, fresh, faults, k * dt)
    alone = (time.process_time() - t0) / sim_s
    keys = Keys(scenario.fleet)
    t0 = time.process_time()
    fleet = Fleet(scenario, keys, t0=0.0, engine=engine)
    build = time.process_time() - t0
    for r in fleet.ids:
        fleet.on_cmd(keys.cmd(r), encode(CmdMsg(0.0, 1, *CMD, 5.0)), now=0.0)
    truth_every = max(1, round(scenario.sim.rate_hz / scenario.sim.truth_rate_hz))
    t0 = time.process_time()
    for k in range(steps):
        if k % truth_every == 0:
            [encode(m) for m in fleet.truth().values()]
        if k % 200 == 0:  # a fresh command every second
            for r in fleet.ids:
                fleet.on_cmd(keys.cmd(r), encode(CmdMsg(fleet.t, k, *CMD, 5.0)), now=fleet.t)
        fleet.step()
    return {"engine": engine, "step_cpu_per_sim_s": alone, "sim_cpu_per_sim_s": (time.process_time() - t0) / sim_s,
            "build_cpu_s": build, "contacts": fleet.contacts}


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime


def live(path: Path, engine: str, wall_s: float, work: Path) -> dict:
    """`vsfleet sim --engine ENGINE` on a loopback router for wall_s, this process commanding every robot
    at 30 Hz (as its agents would) and reading truth/*: its pace, late steps and CPU per simulated second."""
    sc = load_scenario(path)
    keys = Keys(sc.fleet)
    router, endpoint = open_loopback_router()
    truth: list[tuple[float, float]] = []  # (wall, sim t) of each truth message of robot 0
    first = threading.Event()
    cpu0: list[float] = []
    first_robot = keys.truth(sc.robots[0].robot)
    log_path = work / f"sim-{engine}.log"
    proc = None

    def on_truth(sample) -> None:
        if str(sample.key_expr) != first_robot:
            return
        truth.append((time.monotonic(), decode_truth(sample.payload.to_bytes()).t))
        if not first.is_set():
            cpu0.append(_cpu_s(proc.pid))
            first.set()

    try:
        sub = router.declare_subscriber(keys.truth(), on_truth)
        pubs = {r.robot: router.declare_publisher(keys.cmd(r.robot)) for r in sc.robots}
        with log_path.open("wb") as out:
            proc = subprocess.Popen(child_command("sim", str(path), "--engine", engine, *zenoh_flags(endpoint)),
                                    stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                    start_new_session=True)
        if not first.wait(60.0):
            raise RuntimeError(f"vsfleet sim --engine {engine} sent no truth within 60 s:\n{log_path.read_text()}")
        t_end = time.monotonic() + wall_s
        seq = 0
        while time.monotonic() < t_end:  # pacing the commands at 30 Hz, as a tracker's frames would
            seq += 1
            for r, pub in pubs.items():
                pub.put(encode(CmdMsg(time.time(), seq, *CMD, 0.3)))
            time.sleep(1 / 30)
        cpu1 = _cpu_s(proc.pid)
        w1, s1 = truth[-1]
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=20)
        sub.undeclare()
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        router.close()
    w0, s0 = truth[0]
    text = log_path.read_text()
    m = re.search(r"simfleet stopping at step (\d+) \((\d+) steps over 100 ms late\).*?(\d+) contacts", text)
    if m is None:
        raise RuntimeError(f"no final line from vsfleet sim --engine {engine}:\n{text[-2000:]}")
    sim_s = s1 - s0
    return {"engine": engine, "wall_s": w1 - w0, "sim_s": sim_s, "pace": sim_s / (w1 - w0),
            "steps": int(m.group(1)), "late_steps": int(m.group(2)), "contacts": int(m.group(3)),
            "cpu_per_sim_s": (cpu1 - cpu0[0]) / sim_s, "load_1min": os.getloadavg()[0]}


def live_runs(path: Path, engine: str, wall_s: float, work: Path, runs: int) -> dict:
    """``runs`` live runs: each one's figures, and the slowest pace, the median CPU and the late steps."""
    each = [live(path, engine, wall_s, work) for _ in range(runs)]
    return {"engine": engine, "runs": each, "pace": min(r["pace"] for r in each),
            "cpu_per_sim_s": float(np.median([r["cpu_per_sim_s"] for r in each])),
            "late_steps": [r["late_steps"] for r in each], "steps": [r["steps"] for r in each],
            "load_1min": [r["load_1min"] for r in each]}


# ---------------------------------------------------------------- the report


def machine() -> str:
    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), platform.processor() or platform.machine())
    try:
        import mujoco
        mj = f", MuJoCo {mujoco.__version__}"
    except ImportError:
        mj = ""
    return (f"{cpu}, {os.cpu_count()} cores, python {platform.python_version()}{mj}, "
            f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")


def _goal(s: dict) -> str:
    if s["t_goal_s"] is None:
        return f"not reached (0/{s['runs']})"
    return f"{s['t_goal_s']:.1f} s" + ("" if s["reached"] == s["runs"] else f" ({s['reached']}/{s['runs']})")


def report(res: dict) -> tuple[str, str]:
    seeds = res["seeds"]
    lines = ["## Physics engines: kinematic and MuJoCo", "",
             f"`bench/engine.py` ({res['machine']}; seeds {seeds}; the machine was shared). The same fleet on "
             "simfleet's kinematic engine (exact unicycle arcs, perfect traction, bodies pass through each "
             "other) and on MuJoCo (`--engine mujoco`: rigid bodies with mass, servo-driven wheels whose "
             "radii differ by the scenario's gains, frictionless casters, friction and contacts; "
             "docs/engine.md), through the offline runner (the real agents on counted frames, the scenario's "
             "tracker noise, commands one frame late). Formation error: each robot's distance from its point "
             "on the structure fitted to the true positions, every frame until the goal (the halted robot: "
             "the whole run, r2 included). Jitter: total variation of the wheel commands per robot per "
             "second, until the goal.", "",
             "| case | engine | mean formation error (cm) | max (cm, worst seed) | time to goal (mean) | "
             "wheel-command jitter (m/s²) | contacts | CPU per simulated s |",
             "|---|---|---|---|---|---|---|---|"]
    for label, name in LOOP_CASES:
        for engine in ENGINES:
            s = res["loop"][name][engine]
            lines.append(f"| {label} | {engine} | {s['mean_cm']:.3f} | {s['max_cm']:.3f} | {_goal(s)} | "
                         f"{s['jitter_m_s2']:.3f} | {s['contacts']} | {1000 * s['cpu_per_sim_s']:.0f} ms |")
    lines += ["", "Contacts (MuJoCo reports every contact between bodies or with an obstacle; the kinematic "
              "engine cannot, so its column is the geometry's smallest gap only):", "",
              "| case | engine | contacts | smallest gap, bodies and obstacles (cm) | time to goal |",
              "|---|---|---|---|---|"]
    for label, name in CONTACT_CASES:
        for engine in ENGINES:
            s = res["contacts"][name][engine]
            lines.append(f"| {label} | {engine} | {s['contacts'] if engine == 'mujoco' else 'n/a'} | "
                         f"{s['min_gap_cm']:.2f} | {_goal(s)} |")
    lines += ["", f"Real time at 200 Hz for {N_ROBOTS} robots (bodies {RADIUS_M} m, {SPACING_M} m apart, "
              "every robot driven). In this process: the engine's step alone, and simfleet's step with its "
              f"truth messages encoded (its loop without zenoh), over {res['inproc_sim_s']:.0f} simulated s. "
              f"`vsfleet sim` as a process, {res['live_runs']} runs of {res['live_wall_s']:.0f} s on a loopback "
              "router, this process commanding all robots at 30 Hz and reading truth/*: the slowest run's pace, "
              "the median CPU per simulated s (from /proc, from its first truth message on), and each run's "
              "late steps (its own count: a step over 100 ms behind the wall clock) with the machine's 1-minute "
              "load average at its end (2 cores, shared).", "",
              "| engine | step alone, CPU per simulated s | simfleet's step + truth, CPU per simulated s | "
              "`vsfleet sim`: simulated s per wall s | steps over 100 ms late, each run (load) | "
              "CPU per simulated s | keeps real time |",
              "|---|---|---|---|---|---|---|"]
    for engine in ENGINES:
        p, lv = res["inproc"][engine], res["live"][engine]
        late = ", ".join(f"{n} of {k} ({load:.1f})" for n, k, load in zip(lv["late_steps"], lv["steps"],
                                                                          lv["load_1min"]))
        keeps = ("yes" if lv["pace"] > 0.98 and lv["cpu_per_sim_s"] < 1.0 and not any(lv["late_steps"])
                 else "on pace; some steps late" if lv["pace"] > 0.98 and lv["cpu_per_sim_s"] < 1.0 else "NO")
        lines.append(f"| {engine} | {1000 * p['step_cpu_per_sim_s']:.0f} ms | {1000 * p['sim_cpu_per_sim_s']:.0f} ms | "
                     f"{lv['pace']:.3f} | {late} | {1000 * lv['cpu_per_sim_s']:.0f} ms | {keeps} |")
    paper = res["loop"]["paper-triangle"]["mujoco"]
    contacts = sum(res["contacts"][n]["mujoco"]["contacts"] for _, n in CONTACT_CASES)
    lv = res["live"]["mujoco"]
    summary = (f"- **Physics engines** (kinematic vs MuJoCo, seeds {seeds}): the paper triangle on MuJoCo "
               f"{paper['mean_cm']:.3f} cm mean / {paper['max_cm']:.3f} cm max formation error, goal in "
               f"{_goal(paper)} (kinematic {res['loop']['paper-triangle']['kinematic']['mean_cm']:.3f} cm, "
               f"{_goal(res['loop']['paper-triangle']['kinematic'])}); a pillar on the path and a crowded start: "
               f"{contacts} contacts; `vsfleet sim --engine mujoco` with {N_ROBOTS} robots at 200 Hz: "
               f"{1000 * lv['cpu_per_sim_s']:.0f} ms CPU per simulated s, late steps per run {lv['late_steps']}.")
    return "\n".join(lines) + "\n", summary + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--inproc-seconds", type=float, default=10.0, help="simulated seconds of the in-process timing")
    ap.add_argument("--live-seconds", type=float, default=15.0, help="wall seconds of each `vsfleet sim` run")
    ap.add_argument("--live-runs", type=int, default=3, help="`vsfleet sim` runs per engine")
    add_output_flags(ap, "engine", DOCS / "bench" / "sections", "engine.md, engine.summary and engine.json")
    args = ap.parse_args(argv)
    logging.getLogger("vsfleet").setLevel(logging.ERROR)  # the agents' decisions are not this bench's
    res: dict = {"machine": machine(), "seeds": args.seeds, "inproc_sim_s": args.inproc_seconds,
                 "live_wall_s": args.live_seconds, "live_runs": args.live_runs, "loop": {}, "contacts": {}, "inproc": {}, "live": {},
                 "runs": []}
    for cases, key in ((LOOP_CASES, "loop"), (CONTACT_CASES, "contacts")):
        for label, name in cases:
            res[key][name] = {}
            for engine in ENGINES:
                runs = [loop_case(name, engine, s) for s in args.seeds]
                res["runs"] += runs
                res[key][name][engine] = s = summarise(runs)
                print(f"{label} / {engine}: mean {s['mean_cm']:.3f} cm, max {s['max_cm']:.3f} cm, goal {_goal(s)}, "
                      f"jitter {s['jitter_m_s2']:.3f}, contacts {s['contacts']}, gap {s['min_gap_cm']:.2f} cm",
                      file=sys.stderr, flush=True)
    with tempfile.TemporaryDirectory(prefix="vsfleet-engine-") as tmp:
        work = Path(tmp)
        path = work / f"{FLEET30}.toml"
        path.write_text(fleet30_toml())
        sc = load_scenario(path)
        for engine in ENGINES:
            res["inproc"][engine] = p = in_process(sc, engine, args.inproc_seconds)
            res["live"][engine] = lv = live_runs(path, engine, args.live_seconds, work, args.live_runs)
            print(f"{N_ROBOTS} robots / {engine}: step {1000 * p['step_cpu_per_sim_s']:.0f} ms, simfleet "
                  f"{1000 * p['sim_cpu_per_sim_s']:.0f} ms per simulated s; live pace {lv['pace']:.3f}, "
                  f"late {lv['late_steps']}, {1000 * lv['cpu_per_sim_s']:.0f} ms CPU per simulated s",
                  file=sys.stderr, flush=True)
    section, summary = report(res)
    print(section)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "engine.md").write_text(section)
    (args.out / "engine.summary").write_text(summary)
    (args.out / "engine.json").write_text(json.dumps(res, indent=1, default=str))
    print(f"written: {args.out / 'engine.md'}, engine.summary, engine.json", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
