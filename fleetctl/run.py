"""vsfleet run SCENARIO.toml: the localhost multi-process fleet.

Starts a zenoh router (`vsfleet router` on a free loopback port, multicast off, its own
process) and joins it as a client, then simfleet, the tracker and one agent process per robot, all
as clients of that router. The agents are forked from one fork server that
imported the agent once (``--spawn exec``: each its own python), so a hundred of
them start in seconds on two cores. The tracker is the simulated one, or with ``--tracker
camera`` (or the scenario's ``[tracker] kind = "camera"``) the camera loop:
`vsfleet tracker camera --source render` draws the fleet's truth through a
synthetic camera (calibrated on its rendered references first), detects the
ArUco markers and publishes the frames the agents follow. Publishes the mission and, as the
operator, answers mission queries on ``vs/<fleet>/mission`` (agents that start
after the put ask there first). Shows progress, stops everything cleanly (also on Ctrl-C or
when a child dies), prints a summary and writes the run to runs/<timestamp>/:
``run.mcap`` (every message and liveliness token, as ``vsfleet record`` writes
it; recorded raw while the fleet runs, its Foxglove and JSON views added once it is over), ``log.msgpack``, ``summary.json``, the scenario and the plots of
``vsfleet plot`` (trajectories.png, deviation.png, fault.png).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import signal
import subprocess
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import msgpack
import zenoh
from mcap.exceptions import McapError

from vsfleet.analysis import (
    PAPER_MAX_M,
    PAPER_MEAN_M,
    PAPER_STD_M,
    agreement,
    deviation_stats,
    fitted_truth,
    min_gap_m,
    goal_distance,
    truth_frames,
)
from vsfleet.geometry import angle_diff
from vsfleet.scenario import ENGINES, Scenario
from vsfleet.wire import Keys, Mission, WireError, decode_state, decode_truth, encode_mission

from vsfleet.zglue.lifecycle import StopFlag, wall_clock
from vsfleet.zglue.program import common_flags, program, refusing
from .mission_cmd import stamp
from .record import LiveRecorder, iter_log, write_log
from .router import EmbeddedRouter, child_command, client_config, start_router_child  # noqa: F401 (child_command: also run's name)
from vsfleet.zglue.scenario_file import load_scenario
from vsfleet.zglue.forks import ForkedChild, ForkServer
from vsfleet.zglue.zconf import RELIABLE_QOS, open_session, zenoh_flags

log = logging.getLogger("vsfleet.run")

DEFAULT_CAMERA = Path(__file__).resolve().parent.parent / "deploy" / "camera" / "overhead.toml"
GOAL_POS_TOL_M = 0.01
GOAL_TH_TOL_RAD = 0.02
SETTLED_WHEEL_M_S = 0.002
SETTLE_S = 1.0


# How a child that was asked to stop may end: 0 once it is up (it handles SIGTERM and SIGINT itself);
# 130 (vsfleet's code for Ctrl-C) or killed by SIGINT / SIGTERM when the stop came while it was still
# starting (a Ctrl-C reaches the whole process group); anything else is a failure.
STOPPED_CODES = (0, 130, -signal.SIGINT, -signal.SIGTERM)


@dataclass
class Recorder:
    """Every message under vs/<fleet>/**: (receive time [s], key, payload)."""

    records: list[tuple[float, str, bytes]] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def on_sample(self, sample: zenoh.Sample) -> None:
        rec = (wall_clock(), str(sample.key_expr), sample.payload.to_bytes())
        with self.lock:
            self.records.append(rec)

    def snapshot(self) -> list[tuple[float, str, bytes]]:
        with self.lock:
            return list(self.records)

    def tail(self, k: int) -> list[tuple[float, str, bytes]]:
        """The newest k records, oldest first: a copy of those only, not of the whole recording (ring-100 records
        ~12,000 messages a second, and the run looks at its tail every second, holding the recorder's lock)."""
        if k <= 0:
            return []
        with self.lock:
            return self.records[-k:]

    def write(self, path: Path) -> None:
        with path.open("wb") as f:
            for t, key, payload in self.snapshot():
                f.write(msgpack.packb([t, key, payload], use_bin_type=True))


def decoded(records, keys: Keys, kind: str, decode):
    out = []
    for _, key, payload in records:
        if key.startswith(f"{keys.prefix}/{kind}/"):
            try:
                out.append((keys.robot_of(key, kind), decode(payload)))
            except WireError:
                pass
    return out


@dataclass(frozen=True)
class RunSummary:
    scenario: str
    duration_s: float
    reached_goal: bool
    goal_distance_start_m: float
    goal_distance_end_m: float
    deviation: list
    agreement: dict
    children_ok: bool
    min_gap_m: float = math.inf  # bodies and obstacles: the smallest clearance seen (truth; < 0: contact)

    def table(self) -> str:
        lines = [f"run {self.scenario}: {self.duration_s:.1f} s, goal reached: {self.reached_goal}, "
                 f"distance to goal {self.goal_distance_start_m:.3f} m -> {self.goal_distance_end_m:.4f} m",
                 "deviation from the structure (from truth)   mean [cm]  sigma [cm]  max [cm]  samples"]
        for d in self.deviation:
            lines.append(f"  {d['robot']:<40} {100 * d['mean_m']:9.3f} {100 * d['std_m']:10.3f} "
                         f"{100 * d['max_m']:9.3f}  {d['samples']:7d}")
        lines.append(f"  {'paper, real R3 robots (Fig. 10)':<40} {100 * PAPER_MEAN_M:9.3f} "
                     f"{100 * PAPER_STD_M:10.3f} {100 * PAPER_MAX_M:9.3f}")
        a = self.agreement
        lines.append(f"agreement: {a['identical']}/{a['frames']} frames bit-identical across agents; "
                     f"max difference {a['max_pos_m']:.3g} m, {a['max_th_rad']:.3g} rad")
        if math.isfinite(self.min_gap_m):
            lines.append(f"smallest gap between bodies and obstacles (from truth): {100 * self.min_gap_m:.2f} cm"
                         + (" -- CONTACT" if self.min_gap_m < 0.0 else ""))
        return "\n".join(lines)


def summarise(scenario: Scenario, mission: Mission, records, elapsed_s: float, children_ok: bool) -> RunSummary:
    keys = Keys(scenario.fleet)
    frames = truth_frames(decoded(records, keys, "truth", decode_truth))
    fitted = fitted_truth(mission, frames)
    states = decoded(records, keys, "state", decode_state)
    agr = agreement(states)
    d0 = goal_distance(mission, fitted[0][1]) if fitted else math.nan
    d1 = goal_distance(mission, fitted[-1][1]) if fitted else math.nan
    return RunSummary(scenario=scenario.name, duration_s=elapsed_s, reached_goal=d1 <= GOAL_POS_TOL_M,
                      goal_distance_start_m=d0, goal_distance_end_m=d1,
                      deviation=[asdict(s) for s in deviation_stats(fitted)], agreement=asdict(agr),
                      children_ok=children_ok, min_gap_m=min_gap_m(mission, frames))


#: how `vsfleet run` and bench/loop.py start the agents: "fork" (from a fork server, vsfleet.zglue.forks) or
#: "exec" (one python each)
SPAWN_MODES = ("fork", "exec")
#: what the fork server imports before it forks agents: the agent's program and nothing of numpy, which an agent does
#: not load (issue 29; tests/integration/test_agent_numpy_free.py)
AGENT_PRELOAD = ("vsfleet.fleetctl.cli", "vsfleet.agent.main")


class Children:
    """The fleet's processes; stopped with SIGTERM, then SIGKILL after a grace period."""

    def __init__(self, log_dir: Path) -> None:
        self.procs: dict[str, subprocess.Popen | ForkedChild] = {}
        self.log_dir = log_dir
        self.forks: ForkServer | None = None

    def start_forked(self, name: str, module: str, argv: list[str], preload: list[str],
                     cwd: Path | None = None, title: list[str] | None = None) -> ForkedChild:
        """Start child ``name`` running ``module.main(argv)`` forked from this fleet's fork server
        (vsfleet.zglue.forks, started on first use, importing ``preload``); its output goes to
        <log_dir>/<name>.log as with start, and it shows ``title`` as its command line."""
        if self.forks is None:
            self.forks = ForkServer(preload, self.log_dir / "fork-server.log", cwd=cwd)
        log_path = self.log_dir / f"{name}.log"
        log_path.write_bytes(b"")
        proc = self.forks.start(module, argv, log_path, cwd=cwd, title=title)
        self.procs[name] = proc
        return proc

    def start_agent(self, name: str, args: list[str], spawn: str = "fork", cwd: Path | None = None):
        """`vsfleet agent ARGS` as child ``name``: forked from the fork server, or its own python (exec)."""
        if spawn == "exec":
            return self.start(name, child_command("agent", *args), cwd=cwd)
        if spawn != "fork":
            raise ValueError(f"spawn must be one of {SPAWN_MODES}, got {spawn!r}")
        return self.start_forked(name, "vsfleet.fleetctl.cli", ["agent", *args], list(AGENT_PRELOAD), cwd=cwd,
                                 title=child_command("agent", *args))

    def start(self, name: str, cmd: list[str], cwd: Path | None = None) -> subprocess.Popen:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        with (self.log_dir / f"{name}.log").open("wb") as out:  # the child keeps its own handle
            proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                    env=env, cwd=cwd, start_new_session=True)
        self.procs[name] = proc
        return proc

    def dead(self) -> list[str]:
        return [n for n, p in self.procs.items() if p.poll() is not None]

    def last_line(self, name: str) -> str:
        """The last non-empty line of a child's log (a child's error is one line: `vsfleet agent: ...`)."""
        lines = (self.log_dir / f"{name}.log").read_text(errors="replace").strip().splitlines()
        return lines[-1] if lines else "(no output)"

    def stop(self, names: list[str] | None = None, grace_s: float = 5.0) -> bool:
        """Terminate (then kill) the named children; True if all stopped cleanly (STOPPED_CODES)."""
        names = list(self.procs) if names is None else names
        for n in names:
            if self.procs[n].poll() is None:
                self.procs[n].send_signal(signal.SIGTERM)
        ok = True
        deadline = time.monotonic() + grace_s
        for n in names:
            p = self.procs[n]
            try:
                p.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
                ok = False
            ok = ok and p.returncode in STOPPED_CODES
        if self.forks is not None and all(p.poll() is not None for p in self.procs.values()):
            self.forks.close()  # every child has ended: the fork server ends too
            self.forks = None
        return ok


def settled_at_goal(mission: Mission, recorder: Recorder, keys: Keys, window_s: float) -> bool:
    """True when, over the last window, the truth-fitted structure sits at the goal and wheels are still."""
    if mission.goal is None and mission.path is None:
        return False
    now = wall_clock()
    # the window's records: about 4 a robot a tick (truth, pose, cmd, state) at up to 30 Hz, and at least 2000
    recent = [r for r in recorder.tail(max(2000, math.ceil(4 * 30 * window_s * len(mission.robots))))
              if r[0] >= now - window_s]
    truth = decoded(recent, keys, "truth", decode_truth)
    if not truth or any(abs(m.vl) > SETTLED_WHEEL_M_S or abs(m.vr) > SETTLED_WHEEL_M_S for _, m in truth):
        return False
    fitted = fitted_truth(mission, truth_frames(truth))
    if not fitted:
        return False
    goal_th = mission.goal[2] if mission.goal is not None else mission.path[-1][2]
    pose = fitted[-1][1]
    return goal_distance(mission, pose) <= GOAL_POS_TOL_M and abs(angle_diff(goal_th, pose.th)) <= GOAL_TH_TOL_RAD


def tracker_args(scenario: Scenario, scenario_path: str, kind: str | None, camera: str | None,
                 run_dir: Path) -> list[str]:
    """`vsfleet tracker ...` arguments (without the zenoh flags) of the scenario's tracker, or of ``kind``.

    camera: the config ``camera`` (else the scenario's [tracker] camera, relative to its file, else
    DEFAULT_CAMERA), calibrated on its rendered references into run_dir. ValueError if it cannot be.
    """
    tr = scenario.tracker
    kind = kind or tr.kind
    common = ["--fleet", scenario.fleet, "--rate", str(tr.rate_hz)]
    if kind == "sim":
        return ["sim", *common, "--noise-xy", str(tr.noise_xy_m), "--noise-th", str(tr.noise_th_rad),
                "--latency", str(tr.latency_s), "--drop", str(tr.drop_prob)]
    if kind != "camera":
        raise ValueError(f"--tracker must be sim or camera, got {kind!r}")
    if camera is None:
        camera = (Path(scenario_path).parent / tr.camera).resolve() if tr.camera is not None else DEFAULT_CAMERA
    calibration = Path(run_dir) / "calibration.json"
    # the tracker's own command calibrates the synthetic camera on its rendered references (a tool
    # starts programs, it does not import them): its one-line error (no OpenCV, no [sim_camera],
    # a robot no marker maps to) is this run's
    try:
        done = subprocess.run(child_command("tracker", "calibrate", "--camera", str(camera), "--source", "render",
                                            "--robots", ",".join(scenario.mission.robot_ids), "--out",
                                            str(calibration)),
                              capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=120)
    except subprocess.TimeoutExpired:
        raise ValueError("--tracker camera: the calibration took over 120 s") from None
    if done.returncode != 0:
        lines = [line for line in done.stderr.splitlines() if line.strip()]
        raise ValueError(f"--tracker camera: {lines[-1] if lines else f'calibration failed ({done.returncode})'}")
    log.info("%s", done.stdout.strip().replace("\n", "; "))
    return ["camera", "--camera", str(camera), "--calibration", str(calibration), "--source", "render", *common]


def run(scenario_path: str, duration_s: float | None = None, out_dir: str = "runs",
        fleet: str | None = None, stop: StopFlag | None = None, until_goal: bool = True,
        progress: bool = True, tracker: str | None = None, camera: str | None = None,
        foxglove_port: int | None = None, engine: str | None = None, spawn: str = "fork") -> tuple[RunSummary, Path]:
    scenario = load_scenario(scenario_path, fleet=fleet)
    duration = scenario.duration_s if duration_s is None else duration_s
    keys = Keys(scenario.fleet)
    run_dir = Path(out_dir) / time.strftime("%Y%m%d-%H%M%S") / scenario.name
    run_dir.mkdir(parents=True, exist_ok=True)
    stop = stop or StopFlag()
    children = Children(run_dir)
    recorder = Recorder()
    tracker_cmd = tracker_args(scenario, scenario_path, tracker, camera, run_dir)
    # the live recording is raw; the Foxglove and JSON views of every message are derived once the run is over
    # (finish_recording): derived live they cost the run's process about a third of a core at 100 robots (9,000
    # messages a second), which the fleet on two cores does not have
    mcap = LiveRecorder(run_dir / RAW_MCAP, derived=False)
    # the router is a process of its own, as on a deployment: in this process its receive threads also ran the
    # recorder's callbacks, and at 100 robots (9,000 messages a second) it fell behind on the fleet's own traffic
    # (ring-100, 2026-12-05: the tracker's frames reached the agents at 17 Hz instead of 30)
    router = None
    try:
        endpoint = start_router_child(children)
        router = EmbeddedRouter(open_session(client_config(endpoint)))   # this process's session: a client
        flags = zenoh_flags(endpoint)
        def on_sample(sample: zenoh.Sample) -> None:  # one subscription feeds both records
            recorder.on_sample(sample)
            mcap.on_sample(sample)

        robots = scenario.mission.robot_ids
        up = AgentsUp(keys, robots)

        def on_token(sample: zenoh.Sample) -> None:
            mcap.on_liveliness(sample)
            up.on_token(sample)

        router.declare_subscriber(keys.everything, on_sample)
        router.liveliness().declare_subscriber(keys.alive(), on_token, history=True)
        tr = scenario.tracker
        children.start("sim", child_command("sim", str(scenario_path), "--fleet", scenario.fleet,
                                            *(("--engine", engine) if engine else ()), *flags))
        children.start("tracker", child_command("tracker", *tracker_cmd, *flags))
        agents = [f"agent-{r}" for r in robots]
        for r in robots:  # forked from one fork server (spawn "fork"): no interpreter and imports each
            children.start_agent(f"agent-{r}", ["--robot", r, "--fleet", scenario.fleet, "--dt", str(1.0 / tr.rate_hz),
                                                *flags], spawn=spawn)
        if foxglove_port is not None:  # the live view beside the fleet (fleetctl.foxglove_live)
            children.start("foxglove", child_command("foxglove", "--fleet", scenario.fleet,
                                                     "--port", str(foxglove_port), *flags))
            print(f"foxglove: open ws://127.0.0.1:{foxglove_port} in Foxglove (layout docs/foxglove-layout.json)",
                  flush=True)
        # the mission once every agent is up (alive means listening), so the structure does not set off while
        # agents are still starting: 100 forked agents take 1-2 s, and robots whose agents were not up yet stood
        # still, were judged failed and held the structure (ring-100, 2026-12-05: 10-30 fail decisions at frame 55)
        if not up.wait(AGENTS_UP_S):
            log.warning("not every agent up after %.0f s (%d of %d): the mission goes out anyway", AGENTS_UP_S,
                        len(up.alive), len(robots))
        mission = stamp(scenario.mission, wall_clock(), 0.0, version=1)
        payload = encode_mission(mission)
        router.declare_queryable(keys.mission, lambda q: q.reply(keys.mission, payload), complete=True)
        router.put(keys.mission, payload, **RELIABLE_QOS)
        log.info("fleet of %d robots started on %s; logs in %s", len(agents), endpoint, run_dir)

        t_start = wall_clock()
        next_report = t_start
        reason = "duration reached"
        while True:
            now = wall_clock()
            elapsed = now - t_start
            if stop.is_set():
                reason = "interrupted"
                break
            if children.dead():
                reason = "child exited early: " + "; ".join(
                    f"{n} (code {children.procs[n].returncode}: {children.last_line(n)})" for n in children.dead())
                log.error("%s", reason)
                break
            if elapsed >= duration:
                break
            if now >= next_report:
                next_report += 1.0
                if progress:
                    print(progress_line(mission, recorder, keys, elapsed, duration), flush=True)
                if until_goal and elapsed > 2.0 and settled_at_goal(mission, recorder, keys, SETTLE_S):
                    reason = "settled at the goal"
                    break
            stop.wait(0.1)
        elapsed = wall_clock() - t_start
        ok = children.stop(agents) and children.stop(["tracker", "sim"])
        ok = ok and not reason.startswith("child")
    finally:
        children.stop([n for n in children.procs if n != "router"])
        if router is not None:
            router.close()
        children.stop()   # the router last
        mcap.close()
    log.info("run ended: %s", reason)
    finish_recording(run_dir)
    summary = summarise(scenario, mission, recorder.snapshot(), elapsed, ok)
    recorder.write(run_dir / "log.msgpack")
    (run_dir / "summary.json").write_text(json.dumps(asdict(summary), indent=2))
    (run_dir / "scenario.toml").write_bytes(Path(scenario_path).read_bytes())
    from .plot import plot_file  # noqa: PLC0415 - matplotlib (~1 s of imports) only once the run is over
    try:
        plots = plot_file(run_dir / "run.mcap", run_dir, fleet=scenario.fleet, timeline=scenario.faults)
        for note in plots.notes:
            log.info("plots: %s", note)
    except (OSError, ValueError, McapError) as exc:
        log.error("cannot plot the run: %s", exc)
    return summary, run_dir


RAW_MCAP = "run.raw.mcap"
AGENTS_UP_S = 20.0   # [s] the run waits this long at most for every agent's liveliness token before the mission


class AgentsUp:
    """Which of the mission's agents have declared their liveliness token; wait() until all have (or a timeout)."""

    def __init__(self, keys: Keys, robots: tuple[str, ...]) -> None:
        self.expected = {keys.alive("agent", r) for r in robots}
        self.alive: set[str] = set()
        self._all = threading.Event()
        self._lock = threading.Lock()

    def on_token(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        with self._lock:
            if key not in self.expected:
                return
            if sample.kind == zenoh.SampleKind.PUT:
                self.alive.add(key)
            else:
                self.alive.discard(key)
            if self.alive == self.expected:
                self._all.set()

    def wait(self, timeout_s: float) -> bool:
        return self._all.wait(timeout_s)


def finish_recording(run_dir: Path) -> int:
    """run.mcap from the run's raw recording, with every message's Foxglove and JSON views added (as `vsfleet
    record` writes them live); the raw file is then removed. Returns the records written."""
    raw = run_dir / RAW_MCAP
    count = write_log(run_dir / "run.mcap", iter_log(raw), derived=True)
    raw.unlink()
    return count


#: the progress line fits the newest complete truth frame among the newest PROGRESS_RECORDS_PER_ROBOT x n records
#: (at least 400): a fleet's tick puts about 4 messages a robot on the key space (truth, pose, cmd, state), so this
#: spans about 5 ticks. A fixed 400 held no complete frame of ring-100 in 7-14 of its progress lines.
PROGRESS_RECORDS_PER_ROBOT = 20


def progress_line(mission: Mission, recorder: Recorder, keys: Keys, elapsed: float, duration: float) -> str:
    recent = recorder.tail(max(400, PROGRESS_RECORDS_PER_ROBOT * len(mission.robots)))
    fitted = fitted_truth(mission, truth_frames(decoded(recent, keys, "truth", decode_truth)))
    if not fitted:
        return f"[{elapsed:5.1f}/{duration:.0f} s] waiting for truth"
    _, pose, dev = fitted[-1]
    dist = goal_distance(mission, pose)
    eta = min(duration - elapsed, dist / mission.speed_max if mission.speed_max > 0 else math.inf)
    return (f"[{elapsed:5.1f}/{duration:.0f} s] structure ({pose.x:+.3f}, {pose.y:+.3f}, {pose.th:+.2f}) "
            f"to goal {dist:.3f} m, max deviation {100 * max(dev.values()):.2f} cm, ETA {eta:4.0f} s")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet run", description=__doc__.splitlines()[0])
    p.add_argument("scenario", help="scenario TOML file, e.g. scenarios/paper-triangle.toml")
    p.add_argument("--duration", type=float, default=None, help="override the scenario's duration [s]")
    p.add_argument("--fleet", default=None, help="override the fleet name")
    p.add_argument("--out", default="runs", help="directory for run records")
    p.add_argument("--no-stop-at-goal", action="store_true", help="run the full duration")
    p.add_argument("--tracker", choices=("sim", "camera"), default=None,
                   help="sim: the simulated tracker; camera: render -> detect -> frames through a synthetic "
                        "camera (default: the scenario's [tracker] kind)")
    p.add_argument("--camera", default=None, metavar="TOML",
                   help="camera config of --tracker camera (default: the scenario's, else "
                        "deploy/camera/overhead.toml)")
    p.add_argument("--foxglove", type=int, nargs="?", const=8765, default=None, metavar="PORT",
                   help="also serve the fleet live to Foxglove on ws://127.0.0.1:PORT (default 8765)")
    p.add_argument("--engine", choices=ENGINES, default=None,
                   help="the simulated fleet's physics engine (default: the scenario's [sim] engine)")
    p.add_argument("--spawn", choices=SPAWN_MODES, default="fork",
                   help="how the agents start: forked from one process that imported the agent once (default; "
                        "100 agents on two cores start in seconds), or each its own python (exec)")
    return common_flags(p, zenoh=False)  # run starts its own router; the children get their flags


@program(build_parser, log)
def main(args: argparse.Namespace) -> int:
    with refusing(OSError, ValueError):
        summary, run_dir = run(args.scenario, args.duration, args.out, args.fleet,
                               until_goal=not args.no_stop_at_goal, tracker=args.tracker, camera=args.camera,
                               foxglove_port=args.foxglove, engine=args.engine, spawn=args.spawn)
    print(summary.table())
    print(f"run written to {run_dir}")
    return 0 if summary.children_ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
