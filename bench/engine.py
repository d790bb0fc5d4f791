"""The kinematic engine and MuJoCo side by side: the same closed loop on both, and MuJoCo's cost.

1. The paper triangle (scenarios/paper-triangle.toml) and the halted robot (scenarios/paper-failure.toml:
   r2 stops at 8 s, on_failure hold), offline (simfleet.offline.run_offline: the real agents on counted
   frames, the scenario's tracker noise, commands one frame late) on each engine, over seeds: mean and
   max formation error (every robot's distance from its point on the structure fitted to the true
   positions, every frame until the goal), time to goal, wheel-command jitter (total variation of the
   commands per robot per second, until the goal), contacts the engine reported.
2. Contacts: a pillar on the path (scenarios/paper-triangle-obstacle.toml), a tight row
   (scenarios/tight-row.toml, 3 bodies 2 cm apart) and a crowded start (scenarios/crowd-10.toml, 10 bodies
   packed in a 2 x 5 block 2 cm apart, spreading into a line), on each engine: the contacts MuJoCo reports
   and the smallest gap between bodies and obstacles from the true positions.
3. Rooms: bench/room.py's randomised rooms (bench.room.make_room(seed), to_scenario; --rooms SEED ...), each
   offline on each engine as bench/room.py runs it: reached (the goal pose: 5 mm and 0.03 rad) or not and
   when, ended blocked, the contacts MuJoCo reports, the smallest gap.
4. The camera loop: `vsfleet run scenarios/camera-triangle.toml --engine ENGINE` (real processes; the
   synthetic overhead camera renders the truth, the ArUco tracker detects it, the agents follow its
   frames) on each engine: time to goal (from the agents' first state to the first truth frame whose
   fitted structure is within 1 cm and 0.02 rad of the goal), mean and max formation error until then, the
   contacts simfleet counted, agreement across agents.
5. Real time at 200 Hz for 30 robots (bodies 0.08 m, 0.3 m apart, all driven): CPU per simulated second
   of the engine's step alone and of simfleet's step with its truth messages encoded, in this process;
   then `vsfleet sim` itself as a process on a loopback router (3 runs per engine), with this process
   commanding all 30 robots at 30 Hz and reading their truth: simulated seconds per wall second, steps
   over 100 ms late (its own count) and its CPU per simulated second (from /proc, from its first truth
   message on), with the machine's load average.

Writes engine.md (a section of docs/benchmarks.md), engine.summary and engine.json under
runs/bench/engine/, or --out DIR, or with --docs docs/bench/sections/. Progress goes to stderr.

Run: .venv/bin/python bench/engine.py [--seeds 1 2 3] [--rooms 0 8 ...] [--camera-runs 1] [--live-seconds 15]
     [--live-runs 3] [--out DIR | --docs]
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

import msgpack
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench import room as rooms  # noqa: E402
from bench.outputs import DOCS, add_output_flags  # noqa: E402
from vsfleet.analysis import fitted_truth, goal_distance, truth_frames  # noqa: E402
from vsfleet.fleetctl.router import open_loopback_router  # noqa: E402
from vsfleet.fleetctl.run import child_command, decoded  # noqa: E402
from vsfleet.geometry import angle_diff  # noqa: E402
from vsfleet.scenario import ENGINES  # noqa: E402
from vsfleet.simfleet.engine import make_engine  # noqa: E402
from vsfleet.simfleet.main import Fleet  # noqa: E402
from vsfleet.simfleet.offline import run_offline  # noqa: E402
from vsfleet.simfleet.physics import Fault, FaultArrays  # noqa: E402
from vsfleet.wire import CmdMsg, Keys, decode_state, decode_truth, encode  # noqa: E402
from vsfleet.zglue.scenario_file import load_scenario  # noqa: E402
from vsfleet.zglue.zconf import zenoh_flags  # noqa: E402

SCENARIOS = ROOT / "scenarios"
LOOP_CASES = (("paper triangle", "paper-triangle"), ("halted robot (r2 stops at 8 s, hold)", "paper-failure"))
CONTACT_CASES = (("pillar on the path", "paper-triangle-obstacle"), ("tight row (3 bodies 2 cm apart)", "tight-row"),
                 ("crowded start (10 bodies packed 2 cm apart, into a line)", "crowd-10"))
# bench/room.py's rooms: each kind (pillars, wall, bend, sealed) for 3, 4 and 10 robots, and pillars for 30. In its
# 80-room run (docs/bench/sections/rooms.md): 0 (a wall with a gap) stood stalled in the gap, 9 (sealed) has no
# way and ended blocked, 28 passed 15 mm from a wall, the rest reached the goal
ROOM_SEEDS = (0, 8, 9, 12, 13, 20, 22, 28, 11)
ROOM_CAP_S = 90.0  # each room's run [s] (it stops at the goal's position)
CAMERA = "camera-triangle"
CAMERA_GOAL_M = 0.01      # vsfleet run's goal: the structure within this of the goal position ...
CAMERA_GOAL_RAD = 0.02    # ... and this of its heading
N_ROBOTS = 30
SPACING_M = 0.3
RADIUS_M = 0.08
CMD = (0.10, 0.12)  # every robot's wheels [m/s]: the same gentle arc, so no two meet
FLEET30 = "engine30"


# ---------------------------------------------------------------- 1, 2: the closed loop and contacts on each engine


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


# ---------------------------------------------------------------- 3: rooms on each engine


def room_case(seed: int, engine: str, cap_s: float = ROOM_CAP_S) -> dict:
    """bench/room.py's room ``seed`` offline on ``engine``, run as bench/room.py runs it (to the goal's
    position, then again to the end if the heading is not there yet): when it reached the goal pose, whether
    it ended blocked, the contacts the engine reported and the smallest gaps [m]."""
    room = rooms.make_room(seed)
    sc = rooms.to_scenario(room, cap_s)
    t0 = time.process_time()
    run = run_offline(sc, cap_s, seed=seed, goal_tol_m=rooms.GOAL_M, engine=engine)
    sim_s = float(run.trace[-1][0])
    if run.t_goal_s is not None and rooms.heading_error(run.trace[-1][1], room.goal) > rooms.GOAL_RAD:
        run = run_offline(sc, cap_s, seed=seed, goal_tol_m=rooms.GOAL_M, stop_at_goal=False, engine=engine)
        sim_s += float(run.trace[-1][0])
    cpu = time.process_time() - t0
    t_goal = rooms.goal_time(run, room.goal)
    said = [[d.kind for d in ds if d.kind in ("blocked", "unblocked")] for ds in run.decisions.values()]
    bb, bo = rooms.min_gaps_m(run.positions_m, room.radii, room.obstacles)
    return {"seed": seed, "engine": engine, "kind": room.kind, "shape": room.shape, "n": room.n,
            "obstacles": len(room.obstacles), "t_goal_s": t_goal,
            "ended_blocked": t_goal is None and any(k and k[-1] == "blocked" for k in said),
            "contacts": [c.describe() for c in run.contacts], "gap_bodies_m": bb, "gap_obstacles_m": bo,
            "gap_m": min(bb, bo), "sim_s": sim_s, "cpu_s": cpu}


# ---------------------------------------------------------------- 4: the camera loop on each engine


def camera_case(engine: str, work: Path, k: int = 0) -> dict:
    """`vsfleet run scenarios/camera-triangle.toml --engine ENGINE` (real processes, the ArUco tracker on
    rendered frames of the engine's truth): time to goal, formation error until then, contacts, agreement."""
    path = SCENARIOS / f"{CAMERA}.toml"
    fleet = f"bench{os.getpid()}{engine[:3]}{k}"
    out = work / f"camera-{engine}-{k}"
    t0 = time.monotonic()
    done = subprocess.run(child_command("run", str(path), "--engine", engine, "--fleet", fleet, "--out", str(out)),
                          capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=300)
    wall = time.monotonic() - t0
    run_dirs = [d for d in out.glob(f"*/{CAMERA}") if (d / "summary.json").exists()]
    if len(run_dirs) != 1:  # a run that ends with a child failed still writes its record: children_ok says so
        raise RuntimeError(f"vsfleet run --engine {engine} wrote no record ({done.returncode}):\n"
                           f"{done.stdout[-3000:]}{done.stderr[-3000:]}")
    run_dir = run_dirs[0]
    summary = json.loads((run_dir / "summary.json").read_text())
    with (run_dir / "log.msgpack").open("rb") as f:
        records = list(msgpack.Unpacker(f, raw=False))
    sc = load_scenario(path, fleet=fleet)
    keys, mission = Keys(fleet), sc.mission
    states = decoded(records, keys, "state", decode_state)
    t_first = min(m.t for _, m in states)  # the agents' first answer (the clock is the truth's: sim time)
    fitted = [f for f in fitted_truth(mission, truth_frames(decoded(records, keys, "truth", decode_truth)))
              if f[0] >= t_first]
    t_goal = next((t for t, pose, _ in fitted if goal_distance(mission, pose) <= CAMERA_GOAL_M
                   and abs(angle_diff(mission.goal[2], pose.th)) <= CAMERA_GOAL_RAD), None)
    until = [d for t, _, dev in fitted if t_goal is None or t <= t_goal for d in dev.values()]
    sim_log = (run_dir / "sim.log").read_text(errors="replace")
    m = re.search(r"(\d+) contacts \(engine (\w+)\)", sim_log)
    if m is None or m.group(2) != engine:
        raise RuntimeError(f"no final line from vsfleet sim --engine {engine}:\n{sim_log[-2000:]}")
    a = summary["agreement"]
    return {"engine": engine, "t_goal_s": None if t_goal is None else t_goal - t_first,
            "mean_m": float(np.mean(until)), "max_m": float(np.max(until)), "frames": len(fitted),
            "reached_goal": summary["reached_goal"], "goal_distance_end_m": summary["goal_distance_end_m"],
            "children_ok": summary["children_ok"], "agreement": f"{a['identical']}/{a['frames']}",
            "contacts": int(m.group(1)), "wall_s": wall}


# ---------------------------------------------------------------- 5: 30 robots at 200 Hz


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


def code_state() -> str:
    """The commit measured, and the tracked files that differed from it (the tree is shared)."""
    def git(*args: str) -> str:
        try:
            return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=30).stdout
        except (OSError, subprocess.TimeoutExpired):
            return ""
    head = git("rev-parse", "--short", "HEAD").strip() or "unknown"
    dirty = [line[3:] for line in git("status", "--porcelain", "--untracked-files=no").splitlines() if line[3:]]
    return f"code at `{head}`" + (f", with uncommitted changes to {', '.join(dirty)}" if dirty else "")


def _t(t_s: float | None) -> str:
    return "-" if t_s is None else f"{t_s:.1f} s"


def _room_goal(r: dict) -> str:
    return _t(r["t_goal_s"]) if r["t_goal_s"] is not None else "blocked" if r["ended_blocked"] else "not reached"


def _goal(s: dict) -> str:
    if s["t_goal_s"] is None:
        return f"not reached (0/{s['runs']})"
    return f"{s['t_goal_s']:.1f} s" + ("" if s["reached"] == s["runs"] else f" ({s['reached']}/{s['runs']})")


def report(res: dict) -> tuple[str, str]:
    seeds = res["seeds"]
    lines = ["## Physics engines: kinematic and MuJoCo", "",
             f"`bench/engine.py` ({res['machine']}; {res.get('code', 'code unknown')}"
             f"{'' if res.get('code_end', res.get('code')) == res.get('code') else '; at the end: ' + res['code_end']}"
             f"; seeds {seeds}; "
             f"{res.get('wall_s', 0) / 60:.0f} min; the "
             f"machine was shared, 1-minute load average {res.get('load_start', '?')} at the start). The same fleet on "
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
    if res["rooms"]:
        lines += ["", "Rooms: bench/room.py's randomised rooms, by seed (`make_room(seed)`, `to_scenario`: the fleet "
                  "starts assembled, each robot its own body, wheel base and wheel gains; physics at 120 Hz, tracker "
                  f"at 30 Hz with σ 2 mm), offline on each engine for at most {ROOM_CAP_S:.0f} s. *Goal*: the first "
                  f"time the fitted structure is within {1000 * rooms.GOAL_M:.0f} mm and {rooms.GOAL_RAD} rad of the "
                  "goal pose; *blocked*: not reached and the agents' last word was `blocked` (a sealed room "
                  "has no way). Gaps are the smallest between bodies, or a body and an "
                  "obstacle, from the true positions.", "",
                  "| room | kind | robots | obstacles | kinematic: goal | kinematic: smallest gap (mm) | "
                  "mujoco: goal | mujoco: smallest gap (mm) | mujoco: contacts |",
                  "|---|---|---|---|---|---|---|---|---|"]
        by = {(r["seed"], r["engine"]): r for r in res["rooms"]}
        for seed in dict.fromkeys(r["seed"] for r in res["rooms"]):
            k, m = by[seed, "kinematic"], by[seed, "mujoco"]
            lines.append(f"| {seed} | {k['kind']} | {k['n']} | {k['obstacles']} | {_room_goal(k)} | "
                         f"{1000 * k['gap_m']:.1f} | {_room_goal(m)} | {1000 * m['gap_m']:.1f} | "
                         f"{len(m['contacts'])} |")
    if res["camera"]:
        runs = len(next(iter(res["camera"].values())))
        lines += ["", f"The camera loop: `vsfleet run scenarios/{CAMERA}.toml --engine ENGINE` ({runs} run"
                  f"{'s' if runs > 1 else ''} per engine, real processes on a loopback router): the synthetic "
                  "overhead camera renders the engine's truth at 30 Hz, the ArUco tracker detects the markers, "
                  "the agents follow its frames. Time to goal: from the agents' first state to the first truth "
                  f"frame whose fitted structure is within {100 * CAMERA_GOAL_M:.0f} cm and {CAMERA_GOAL_RAD} rad "
                  "of the goal (`vsfleet run`'s goal rule). Formation error from the truth, over that time. "
                  "At the end: `vsfleet run`'s own summary once the fleet has stood still at the goal for 1 s.", "",
                  "| engine | time to goal | mean formation error (cm) | max (cm) | at the end: goal reached, "
                  "distance (cm) | frames bit-identical across agents | contacts | wall time |",
                  "|---|---|---|---|---|---|---|---|"]
        for engine in ENGINES:
            for c in res["camera"].get(engine, ()):
                lines.append(f"| {engine} | {_t(c['t_goal_s'])} | {100 * c['mean_m']:.3f} | {100 * c['max_m']:.3f} | "
                             f"{'yes' if c['reached_goal'] else 'NO'}, {100 * c['goal_distance_end_m']:.2f} | "
                             f"{c['agreement']} | {c['contacts']} | {c['wall_s']:.0f} s |")
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
    summary = (f"- **Physics engines** ({res['machine'].rsplit(', ', 1)[-1][:10]}, `bench/engine.py`, kinematic vs "
               f"MuJoCo, seeds {seeds}): the paper triangle on MuJoCo {paper['mean_cm']:.3f} cm mean / "
               f"{paper['max_cm']:.3f} cm max formation error, goal in {_goal(paper)} (kinematic "
               f"{res['loop']['paper-triangle']['kinematic']['mean_cm']:.3f} cm, "
               f"{_goal(res['loop']['paper-triangle']['kinematic'])}); a pillar on the path, a tight row and 10 "
               f"robots packed 2 cm apart: {contacts} contacts")
    if res["rooms"]:
        mj = [r for r in res["rooms"] if r["engine"] == "mujoco"]
        kin = [r for r in res["rooms"] if r["engine"] == "kinematic"]
        summary += (f"; {len(mj)} of bench/room.py's rooms: reached {sum(r['t_goal_s'] is not None for r in mj)} "
                    f"on MuJoCo, {sum(r['t_goal_s'] is not None for r in kin)} kinematic, "
                    f"{sum(len(r['contacts']) for r in mj)} contacts, smallest gap "
                    f"{1000 * min(r['gap_m'] for r in mj):.1f} mm")
    if res["camera"].get("mujoco"):
        cams = res["camera"]["mujoco"]
        summary += ("; the camera loop on MuJoCo's truth: goal in "
                    + ", ".join(_t(c["t_goal_s"]) for c in cams) + ", "
                    + ", ".join(f"{100 * c['mean_m']:.3f}" for c in cams) + " cm mean")
    summary += (f"; `vsfleet sim --engine mujoco` with {N_ROBOTS} robots at 200 Hz: "
                f"{1000 * lv['cpu_per_sim_s']:.0f} ms CPU per simulated s, late steps per run {lv['late_steps']}.")
    return "\n".join(lines) + "\n", summary + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--inproc-seconds", type=float, default=10.0, help="simulated seconds of the in-process timing")
    ap.add_argument("--live-seconds", type=float, default=15.0, help="wall seconds of each `vsfleet sim` run")
    ap.add_argument("--live-runs", type=int, default=3, help="`vsfleet sim` runs per engine")
    ap.add_argument("--rooms", type=int, nargs="*", default=list(ROOM_SEEDS), help="bench/room.py's room seeds")
    ap.add_argument("--camera-runs", type=int, default=1, help="camera-loop runs (vsfleet run) per engine")
    add_output_flags(ap, "engine", DOCS / "bench" / "sections", "engine.md, engine.summary and engine.json")
    args = ap.parse_args(argv)
    logging.getLogger("vsfleet").setLevel(logging.ERROR)  # the agents' decisions are not this bench's
    res: dict = {"machine": machine(), "seeds": args.seeds, "inproc_sim_s": args.inproc_seconds,
                 "live_wall_s": args.live_seconds, "live_runs": args.live_runs, "loop": {}, "contacts": {},
                 "rooms": [], "camera": {}, "inproc": {}, "live": {}, "runs": [],
                 "load_start": f"{os.getloadavg()[0]:.1f}", "code": code_state()}
    t_bench = time.monotonic()

    def progress(text: str) -> None:
        print(f"[{time.monotonic() - t_bench:6.0f} s] {text}", file=sys.stderr, flush=True)

    for cases, key in ((LOOP_CASES, "loop"), (CONTACT_CASES, "contacts")):
        for label, name in cases:
            res[key][name] = {}
            for engine in ENGINES:
                runs = [loop_case(name, engine, s) for s in args.seeds]
                res["runs"] += runs
                res[key][name][engine] = s = summarise(runs)
                progress(f"{label} / {engine}: mean {s['mean_cm']:.3f} cm, max {s['max_cm']:.3f} cm, goal "
                         f"{_goal(s)}, jitter {s['jitter_m_s2']:.3f}, contacts {s['contacts']}, gap "
                         f"{s['min_gap_cm']:.2f} cm")
    for seed in args.rooms:
        for engine in ENGINES:
            res["rooms"].append(r := room_case(seed, engine))
            progress(f"room {seed} ({r['kind']}, {r['n']} robots, {r['obstacles']} obstacles) / {engine}: goal "
                     f"{_t(r['t_goal_s'])}{', ended blocked' if r['ended_blocked'] else ''}, contacts "
                     f"{len(r['contacts'])}, gap "
                     f"{1000 * r['gap_m']:.1f} mm, {r['cpu_s']:.0f} s CPU")
    with tempfile.TemporaryDirectory(prefix="vsfleet-engine-") as tmp:
        work = Path(tmp)
        for engine in ENGINES:
            res["camera"][engine] = each = [camera_case(engine, work, k) for k in range(args.camera_runs)]
            for c in each:
                progress(f"camera loop / {engine}: goal {_t(c['t_goal_s'])}, mean {100 * c['mean_m']:.3f} cm, max "
                         f"{100 * c['max_m']:.3f} cm, contacts {c['contacts']}, agreement {c['agreement']}, "
                         f"{c['wall_s']:.0f} s wall")
        path = work / f"{FLEET30}.toml"
        path.write_text(fleet30_toml())
        sc = load_scenario(path)
        for engine in ENGINES:
            res["inproc"][engine] = p = in_process(sc, engine, args.inproc_seconds)
            res["live"][engine] = lv = live_runs(path, engine, args.live_seconds, work, args.live_runs)
            progress(f"{N_ROBOTS} robots / {engine}: step {1000 * p['step_cpu_per_sim_s']:.0f} ms, simfleet "
                     f"{1000 * p['sim_cpu_per_sim_s']:.0f} ms per simulated s; live pace {lv['pace']:.3f}, "
                     f"late {lv['late_steps']}, {1000 * lv['cpu_per_sim_s']:.0f} ms CPU per simulated s")
    res["wall_s"] = time.monotonic() - t_bench
    res["code_end"] = code_state()  # the tree is shared: it may have changed during the run
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
