"""docs/benchmarks.md and its PNG plots from the results of bench/run_all.py.

Markdown is built by pure functions of the results; plots are written with
matplotlib's Agg backend into docs/bench/.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from vsfleet.analysis import PAPER_MAX_M, PAPER_MEAN_M, PAPER_STD_M  # noqa: E402

from .leader_follower import AT_GOAL_M, BROKEN_M, ERROR_METRIC  # noqa: E402
from .loop import messages_per_frame, percentiles_s  # noqa: E402
from .precision import CONTROLLER_LABELS  # noqa: E402


def _ms(x: float) -> str:
    return "–" if x is None or not math.isfinite(x) else f"{1e3 * x:.2f}"


def _cm(x: float) -> str:
    return f"{100 * x:.3f}"


def table(head: list[str], rows: list[list], align: str | None = None) -> str:
    align = align or "l" + "r" * (len(head) - 1)
    sep = ["---:" if a == "r" else "---" for a in align]
    lines = ["| " + " | ".join(head) + " |", "| " + " | ".join(sep) + " |"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


# ---------------------------------------------------------------- sections


def fit_section(rows) -> str:
    body = [[n, m, f"{1e3 * mo:.3f}", f"{1e3 * mp:.3f}", f"{ratio:.1f}", f"{oc:.9f}", f"{pc:.9f}",
             f"{pc / oc:.6f}" if oc > 0 else "–"] for n, m, mo, mp, ratio, oc, pc in rows]
    worse = [(n, m) for n, m, _, _, _, oc, pc in rows if pc < oc * (1 - 1e-9)]
    lo, hi = min(r[4] for r in rows), max(r[4] for r in rows)
    return "\n".join([
        "## 1. Fit: ours against scipy's Powell",
        "",
        "`vsfleet.fit.fit_structure` against `scipy.optimize.minimize(method=\"Powell\")` (the paper's "
        "direction-set method) on the same cost, as `bench/fit.py` (`make bench-fit`) measures it: one seeded "
        "formation per n (template uniform in [-1, 1]², a random rigid transform, 0.05 m Gaussian noise), "
        "Powell from the centroid translation with th = 0 and scipy's default tolerances. Times are minima over repeats "
        "per fit. *Time ratio* = Powell / ours (> 1: ours is faster). *Cost ratio* = Powell's cost / ours "
        "(≥ 1: ours found an equal or lower cost).",
        "",
        table(["n", "metric", "ours [ms]", "Powell [ms]", "time ratio", "our cost [m]", "Powell cost [m]",
               "cost ratio"], body, "lrrrrrrr"),
        "",
        f"Time ratio from {lo:.1f}× to {hi:.1f}×. "
        + ("Powell never found a lower cost than ours." if not worse else
           f"Powell found a lower cost for {worse}."),
        "",
        "![fit times](bench/fit.png)",
    ])


def _agree(r) -> str:
    return f"{r.agreed_frames}/{r.all_ran_frames} ({100 * r.agreed_frames / max(r.all_ran_frames, 1):.1f}%)"


def latency_section(loops, floors, frames_asked: int) -> str:
    body = []
    for r in loops:
        p = percentiles_s(r.latency_s)
        fp = percentiles_s(r.frame_latency_s)
        floor = _floor(floors, r.rate_hz)
        ratio = (lambda k: f"{p[k] / floor[k]:.1f}" if floor and floor[k] else "–")
        body.append([r.robots, f"{r.rate_hz:.0f}", r.frames, _ms(p["p50"]), _ms(p["p99"]), _ms(p["max"]),
                     f"{ratio('p50')} / {ratio('p99')} / {ratio('max')}", _ms(fp["p50"]), _ms(fp["p99"]),
                     f"{r.missed} ({100 * r.missed / (r.frames * r.robots):.2f}%)", r.late,
                     f"{1e3 * r.agent_cpu_s_per_tick.mean():.2f}", f"{r.agent_rss_mib.mean():.0f}", _agree(r),
                     f"{r.others_cores:.2f}"])
    fl = []
    for f in floors:
        p = percentiles_s(f.rtt_s)
        fl.append([f.label, f.rtt_s.size, _ms(p["p50"]), _ms(p["p99"]), _ms(p["max"]), f.lost])
    return "\n".join([
        "## 2. Loop latency and scale",
        "",
        "From the tracker's publish of a frame to the receipt of the resulting command for the same `seq`. "
        "`bench/loop.py` plays the tracker and simfleet's receiving side in one process. The router is "
        "its own `vsfleet router` process on a free loopback port, as on a deployment. Two client "
        "sessions connect to it: a *tracker* that publishes one message per frame on `vs/bench/frame/bench` "
        "(every robot's pose), and a *sim* subscribed to `vs/bench/cmd/**` and `vs/bench/state/**`. N real "
        "`vsfleet agent` processes (`fleetctl.run.child_command`, `--dt` = one period) are clients of the "
        "same router, so a frame travels tracker → router → N agents → router → sim, as in `vsfleet run`. "
        "The mission: robots r1..rN on a circle (neighbours ≥ 0.3 m apart), metric l2, the default "
        "controller, goal 1 km ahead so every robot keeps moving. The robots move: each integrates "
        "its latest fresh command exactly over one period (`integrate_arc`), observed with 1 mm / 5 mrad "
        "Gaussian noise. Start of a latency = just before the frame is put; end = the command's arrival "
        "in the sim session's callback; one clock (`time.perf_counter`). Every agent runs 2 s of frames "
        "before the measurement starts.",
        "",
        f"*Per command* = over every answered (frame, robot); *whole frame* = until the frame's last robot "
        f"answered (frames every robot answered). *Missed* = (frame, robot) pairs never answered (an agent "
        f"that falls behind runs the newest frame and skips the rest). *Late* = answered after one period. "
        f"*× floor* = p50 / p99 / max per command over the Zenoh floor's p50 / p99 / max at the same rate "
        f"(the floor is a round trip through the same router process: the same four hops). *CPU/tick* = an "
        f"agent's user + system CPU (/proc/<pid>/stat, all threads) over the measurement per frame published. "
        f"*RSS* = VmRSS per agent at the end. *Agree* = of the frames every agent ran, those on which every "
        f"agent's fitted and advanced structure (`state`: x, y, th, gx, gy, gth, used) is bit-identical. "
        f"*Others* = CPU cores busy with other processes on the machine during the run (from /proc/stat, "
        f"minus the agents and this process). Frames asked per run: {frames_asked}.",
        "",
        table(["agents", "Hz", "frames", "p50 [ms]", "p99 [ms]", "max [ms]", "× floor", "frame p50 [ms]",
               "frame p99 [ms]", "missed", "late", "CPU/tick [ms]", "RSS [MiB]", "agree", "others [cores]"], body),
        "",
        "### The Zenoh floor",
        "",
        "Round trip of a plain message (a pose-sized msgpack payload, the agents' QoS: express, drop, "
        "real-time priority) from a client session in the bench process through the same kind of "
        "`vsfleet router` process to a separate Python client process (`bench/zenoh_pong.py`) that puts it back from its "
        "subscriber callback, and back to the bench process: the same hops and processes as the loop, "
        "without decoding or the control step. Measured in the same run as the loop, before it.",
        "",
        table(["pings", "count", "p50 [ms]", "p99 [ms]", "max [ms]", "lost"], fl),
        "",
        "![latency distributions](bench/latency.png)",
    ])


def _floor(floors, rate_hz: float) -> dict | None:
    """The floor's p50 / p99 / max [s] at rate_hz (None if not measured)."""
    for f in floors:
        if f.rate_hz == rate_hz and f.rtt_s.size:
            return percentiles_s(f.rtt_s)
    return None


def step_section(rows) -> str:
    body = [[r["n"], f"{r['step_p50_us']:.0f}", f"{r['step_p90_us']:.0f}",
             f"{r['paced_p50_us']:.0f}" if "paced_p50_us" in r else "-", f"{r['decode_p50_us']:.0f}", r["frames"]]
            for r in rows]
    return "\n".join([
        "### The agent step alone",
        "",
        "CPU time of one call of `vsfleet.step.agent_step` (fit, advance, every robot's controller, the "
        "failure rule) and of decoding the frame (`vsfleet.wire.decode_frame`), in one process without "
        "zenoh (`bench/step.py`): N robots on a circle translating at 0.05 m/s with 1 mm noise, after the "
        "failure rule's window has filled. *Paced*: the same step called once per 1/30 s with a sleep in "
        "between, as an agent runs it: its caches have gone cold by then, and this, not the back-to-back "
        "figure, is what an agent process pays per tick.",
        "",
        table(["N", "step p50 [µs]", "step p90 [µs]", "paced at 30 Hz, p50 [µs]", "decode p50 [µs]", "frames"], body),
    ])


def largest_holding(runs, strict: bool = True) -> int | None:
    """Largest fleet size such that it and every smaller measured size held (None if none did)."""
    best = None
    for r in sorted(runs, key=lambda r: r.robots):
        if not (r.holds if strict else r.nearly_holds):
            break
        best = r.robots
    return best


def cores_to_answer_all(r) -> float:
    """CPU cores a run would need to answer every frame, if each frame cost what an answered one did."""
    return r.rate_hz * (float(r.agent_cpu_s_per_answer.sum()) + r.bench_cpu_s_per_frame)


def scale_section(runs_30hz, rate_hz: float = 30.0, pose_bytes: int = 63) -> str:
    runs = sorted(runs_30hz, key=lambda r: (r.robots, -r.frames))
    body = []
    for r in runs:
        p = percentiles_s(r.latency_s)
        body.append([r.robots, r.frames, f"{r.missed} ({100 * r.missed_share:.2f}%)",
                     f"{100 * r.incomplete / max(r.states, 1):.1f}%", _ms(p["p99"]),
                     "yes" if r.holds else "**no**", "yes" if r.nearly_holds else "**no**",
                     f"{1e3 * r.agent_cpu_s_per_tick.mean():.2f}", f"{1e3 * r.agent_cpu_s_per_answer.mean():.2f}",
                     f"{r.agent_rss_mib.mean():.1f}", f"{1e3 * r.bench_cpu_s_per_frame:.2f}",
                     f"{r.agent_cpu_s_per_tick.sum() * r.rate_hz + r.bench_cpu_s_per_frame * r.rate_hz:.2f}",
                     _agree(r), f"{r.others_cores:.2f}"])
    best, near = largest_holding(runs), largest_holding(runs, strict=False)
    msg = []
    for n in (3, 10, 30, 100, 300, 1000):
        m = messages_per_frame(n)
        msg.append([n, f"{m['published']:,}", f"{m['delivered']:,}", f"{m['delivered'] * rate_hz:,.0f}",
                    f"{n * pose_bytes / 1024:.1f}"])
    return "\n".join([
        "## 3. Scale",
        "",
        f"The {rate_hz:.0f} Hz runs of §2, side by side. A size *holds* {rate_hz:.0f} Hz when every agent "
        f"answered every measured frame (no missed tick) and p99 latency stayed under one period; *≤ 0.1 %* "
        f"relaxes the first condition to at most 0.1 % of (frame, robot) pairs missed. CPU = an agent's "
        f"user + system time *per frame* published and *per tick* it answered (they differ when it skips "
        f"frames). *Bench* = per frame, the bench process (the tracker and the sim side) plus the router "
        f"process. *Used* = cores the agents and the bench used. The machine has {os.cpu_count()} cores, "
        f"shared with *others*.",
        "",
        table(["agents", "frames", "missed", "incomplete", "p99 [ms]", "holds", "≤ 0.1 %",
               "CPU/frame [ms]", "CPU/tick [ms]", "RSS/agent [MiB]", "bench CPU/frame [ms]", "used [cores]",
               "agree", "others [cores]"], body),
        "",
        f"**Largest fleet that held {rate_hz:.0f} Hz with no missed tick: "
        + (f"{best} agent processes" if best else "none of the measured sizes")
        + "**; with ≤ 0.1 % missed: " + (f"{near}." if near else "none of the measured sizes."),
        "",
        "![scale](bench/scale.png)",
        "",
        "### Messages per frame",
        "",
        "A tracker publishes one message per frame (`vs/<fleet>/frame/<src>`) that every agent receives: N "
        "deliveries, plus N commands to the fleet and N states to a recorder or monitor. (Before frames, "
        "every agent subscribed to every robot's pose: N² deliveries and N wake-ups per agent per frame.) "
        f"A pose inside a frame is about {pose_bytes // 2} bytes of msgpack.",
        "",
        table(["N", "published / frame", "delivered / frame", f"delivered / s at {rate_hz:.0f} Hz",
               "one frame [KiB]"], msg),
    ])


def precision_section(rows, noise_rows, scenario, seeds, duration_s: float) -> str:
    tr = scenario.tracker
    body = []
    for r in rows:
        goals = [g for g in r.t_goal_s if g is not None]
        tg = f"{np.mean(goals):.1f}" if len(goals) == len(r.t_goal_s) else (
            f"{np.mean(goals):.1f} ({len(goals)}/{len(r.t_goal_s)})" if goals
            else f"not reached: {100 * np.mean(r.goal_left_m):.0f} cm to go")
        body.append([CONTROLLER_LABELS.get(r.controller, r.controller), r.metric, _cm(r.mean_m), _cm(r.std_m),
                     _cm(r.max_m), tg, r.samples])
    body.append(["**paper, real R3 robots (Fig. 10)**", "–", _cm(PAPER_MEAN_M), _cm(PAPER_STD_M),
                 _cm(PAPER_MAX_M), "–", "–"])
    nz = [[f"{1e3 * r.noise_xy_m:.0f}", _cm(r.mean_m), _cm(r.std_m), _cm(r.max_m)] for r in noise_rows]
    nr = noise_rows[0] if noise_rows else None
    return "\n".join([
        "## 4. Precision against the paper",
        "",
        f"`scenarios/paper-triangle.toml` (three robots in a 0.52 m triangle drive "
        f"{math.hypot(*scenario.mission.goal[:2]):.1f} m to a goal at "
        f"up to 0.08 m/s; the robots' wheels differ: gains 0.97–1.02, one robot's top wheel speed 0.25 "
        f"instead of 0.3 m/s) in the offline closed loop `simfleet.offline.run_offline`: the real `Agent` "
        f"objects, one per robot, the simulated physics ({scenario.sim.rate_hz:.0f} Hz), a tracker at "
        f"**{tr.rate_hz:.0f} Hz** with Gaussian noise **σ = {1e3 * tr.noise_xy_m:.0f} mm** in position and "
        f"**{tr.noise_th_rad:.3f} rad** in heading, and **one frame of latency** (each command takes effect "
        f"one frame, {1e3 / tr.rate_hz:.0f} ms, after the observation it answers). Deviation = a robot's "
        f"distance from its template point under the structure fitted to the *true* positions with the "
        f"run's metric; pooled over the 3 robots, every frame until the structure is within 5 mm of the "
        f"goal (else the whole {duration_s:.0f} s, all of it in motion), and seeds {list(seeds)}. Time to "
        f"goal = mean over the seeds that got within 5 mm, else the structure's mean distance to the goal "
        f"after {duration_s:.0f} s (those controllers keep the shape but drag the structure: it waits for "
        f"its slowest robot).",
        "",
        table(["controller", "metric", "mean [cm]", "σ [cm]", "max [cm]", "time to goal [s]", "samples"], body),
        "",
        f"{sum(r.mean_m < PAPER_MEAN_M for r in rows)}/{len(rows)} controller × metric combinations have a "
        f"mean below the paper's {_cm(PAPER_MEAN_M)} cm and {sum(r.max_m < PAPER_MAX_M for r in rows)}/{len(rows)} "
        f"a max below its {_cm(PAPER_MAX_M)} cm. The simulation is cleaner than the 1996 testbed (an "
        "overhead-camera tracker and WaveLAN links to R3 robots), so the comparison is of orders of "
        "magnitude under the stated noise and latency, not of testbeds.",
        "",
        (f"Sensitivity to tracker noise ({CONTROLLER_LABELS.get(nr.controller, nr.controller)}, "
         f"metric {nr.metric}, seed {seeds[0]}; heading noise as above):" if nr else ""),
        "",
        table(["position noise σ [mm]", "mean [cm]", "σ [cm]", "max [cm]"], nz) if nz else "",
        "",
        "![precision](bench/precision.png)",
    ])


def lf_reading(results) -> str:
    """One line per case, from the numbers."""
    lines = []
    for case, _, _, vs, lf in results:
        def say(s):
            broke = f"broke at {s.t_broke_s:.1f} s" if s.broke else "held its shape"
            return (f"{s.method} {broke} (max {_cm(s.max_error_m)} cm) and made {100 * s.progress:.0f}% of "
                    f"the way, {s.at_goal}/{s.robots} robots at their goal points")
        lines.append(f"- *{case}*: {say(lf)}; the {say(vs)}.")
    return "\n".join(lines)


def lf_section(results, tuning, duration_s: float, fault_at_s: float, seed: int) -> str:
    body = []
    for case, _, _, s_vs, s_lf in results:
        for s in (s_vs, s_lf):
            body.append([case, s.method, _cm(s.mean_error_m), _cm(s.max_error_m),
                         f"**yes** (at {s.t_broke_s:.1f} s)" if s.broke else "no",
                         f"{100 * s.progress:.0f}%", "–" if s.t_goal_s is None else f"{s.t_goal_s:.1f}",
                         f"{s.at_goal}/{s.robots}"])
    tune = [[f"{100 * d:.0f}", f"{a:.0f}", _cm(mean), _cm(mx)] for d, a, mean, mx in tuning]
    return "\n".join([
        "## 5. Virtual structure against leader–follower",
        "",
        "The baseline (`bench/leader_follower.py`) is the l–ψ controller of Desai, Ostrowski & Kumar "
        "(1998): r1 leads, driving to its own point of the goal pose (go-to-goal at up to the mission's "
        "0.08 m/s and 0.3 rad/s, then turning to the goal heading); each follower keeps the distance l and "
        "bearing ψ of an off-axis point d ahead of its axle to the leader, with the feedback-linearising "
        "law that makes l̇ = a(l_d − l) and ψ̇ = a(ψ_d − ψ) (slots from the template, so a follower's axle "
        "sits on its template point when it is in line). Followers know the leader's twist from its wheel "
        "odometry (what a leader would broadcast). Wheel commands are clipped to each robot's envelope "
        "(`vsfleet.kinematics.limit_wheels`) like the virtual structure's. Both run in the same simulated "
        "fleet: the paper triangle, `simfleet.physics.step_robot` with its `Fault` model, the same tracker "
        "noise, one frame of command latency and the same seed "
        f"({seed}); the virtual structure is `simfleet.offline.run_offline` (real `Agent` objects, default "
        f"controller, `on_failure = hold`, the paper's behaviour) with metric {ERROR_METRIC}. Faults strike "
        f"at t = {fault_at_s:.0f} s and last to the end of the {duration_s:.0f} s run.",
        "",
        f"*Formation error* (the same for both) = each robot's distance from its template point under the "
        f"{ERROR_METRIC}-best-fit structure pose of the true positions (`vsfleet.fit.fit_structure`), mean "
        f"and max over robots and frames. *Broke* = the error exceeded **{100 * BROKEN_M:.0f} cm** (a third of "
        f"the template's 0.3 m radius) at some frame. *Progress* = 1 − (final / initial distance of that "
        f"fitted structure to the goal); *goal at* = first time it was within {100 * AT_GOAL_M:.0f} cm of "
        f"the goal. *At goal* = robots within {100 * AT_GOAL_M:.0f} cm of their goal point at the end.",
        "",
        table(["case", "method", "mean error [cm]", "max error [cm]", "broke", "progress", "goal at [s]",
               "at goal"], body, "llrrlrrr"),
        "",
        "Reading it:",
        "",
        lf_reading(results),
        "",
        "By construction, the leader ignores its followers, so a stopped follower is left behind and a "
        "slow one lags by as much as its wheels fall short; the followers track only the leader, so a "
        "stopped leader stops everyone, in shape (the paper's \"single point of failure\": no progress "
        "until a new leader is chosen). The virtual structure (`on_failure = hold`) answers any halted "
        "robot the same way, by bending a little and halting the structure, and slows the structure "
        "down for a slow robot; with `on_failure = drop` or `rejoin` it carries on without a halted "
        "robot (tests/test_closed_loop.py).",
        "",
        "Baseline tuning (no fault; d = off-axis distance, a = both convergence rates); the table above "
        "uses the lowest max error:",
        "",
        table(["d [cm]", "a [1/s]", "mean error [cm]", "max error [cm]"], tune),
        "",
        "![virtual structure against leader-follower](bench/leader_follower.png)",
    ])


# ---------------------------------------------------------------- plots


def plot_fit(rows, path: Path) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), sharey=True)
    for ax, metric in zip(axes, ("l1", "l2", "linf")):
        sel = [r for r in rows if r[1] == metric]
        n = [r[0] for r in sel]
        ax.loglog(n, [1e3 * r[2] for r in sel], "o-", label="ours")
        ax.loglog(n, [1e3 * r[3] for r in sel], "s--", label="scipy Powell")
        ax.set_title(metric)
        ax.set_xlabel("robots n")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("time per fit [ms]")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_latency(loops, floors, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for r in loops:
        x = np.sort(r.latency_s) * 1e3
        if x.size:
            ax.plot(x, np.arange(1, x.size + 1) / x.size, ls="-" if r.rate_hz < 50 else "-.",
                    label=f"{r.robots} agents, {r.rate_hz:.0f} Hz")
    for f, style in zip(floors, ("k--", "k:", "0.5")):
        x = np.sort(f.rtt_s) * 1e3
        if x.size:
            ax.plot(x, np.arange(1, x.size + 1) / x.size, style, lw=1, label=f"zenoh floor, {f.label}")
    ax.set_xscale("log")
    ax.set_xlabel("pose publish → command receipt [ms] (floor: round trip)")
    ax.set_ylabel("fraction of commands")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_scale(runs, path: Path) -> None:
    runs = sorted(runs, key=lambda r: r.robots)
    n = [r.robots for r in runs]
    fig, axes = plt.subplots(1, 4, figsize=(16, 3.8))
    axes[0].plot(n, [1e3 * r.agent_cpu_s_per_tick.mean() for r in runs], "o-", label="per frame published")
    axes[0].plot(n, [1e3 * r.agent_cpu_s_per_answer.mean() for r in runs], "s--", label="per tick answered")
    axes[0].set_ylabel("CPU per agent [ms]")
    axes[0].set_ylim(bottom=0)
    axes[0].legend(fontsize=8)
    axes[1].plot(n, [r.agent_rss_mib.mean() for r in runs], "o-")
    axes[1].set_ylabel("RSS per agent [MiB]")
    axes[1].set_ylim(bottom=0)
    axes[2].plot(n, [cores_to_answer_all(r) for r in runs], "o-", label="needed to answer every frame")
    axes[2].plot(n, [r.rate_hz * (r.agent_cpu_s_per_tick.sum() + r.bench_cpu_s_per_frame) for r in runs], "s--",
                 label="used")
    axes[2].plot(n, [r.others_cores for r in runs], "x:", label="other processes")
    axes[2].axhline(float(os.cpu_count() or 1), color="k", lw=1, label="machine")
    axes[2].set_ylabel("CPU cores")
    axes[2].legend(fontsize=7)
    ax = axes[3]
    ax.plot(n, [100 * r.missed_share for r in runs], "ro-", label="missed ticks")
    ax.plot(n, [100 * r.incomplete / max(1, r.states) for r in runs], "b^--", label="incomplete frames")
    ax.set_ylabel("% of (frame, agent)")
    ax.legend(fontsize=8)
    for ax in axes:
        ax.set_xlabel("agents (30 Hz)")
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_precision(rows, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(9, 4))
    labels = [f"{r.controller}\n{r.metric}" for r in rows]
    x = np.arange(len(rows))
    ax.bar(x - 0.2, [100 * r.mean_m for r in rows], 0.4, yerr=[100 * r.std_m for r in rows], label="mean ± σ")
    ax.bar(x + 0.2, [100 * r.max_m for r in rows], 0.4, label="max")
    ax.axhline(100 * PAPER_MEAN_M, color="k", ls=":", label="paper mean 0.783 cm")
    ax.axhline(100 * PAPER_MAX_M, color="k", ls="--", label="paper max 2.5 cm")
    ax.set_xticks(x, labels, fontsize=7)
    ax.set_ylabel("deviation from the structure [cm]")
    ax.legend(fontsize=8)
    ax.grid(True, axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_leader_follower(results, mission, path: Path) -> None:
    from vsfleet.geometry import Pose2
    from vsfleet.step import mission_template

    tpl = mission_template(mission)
    fig, axes = plt.subplots(2, len(results), figsize=(4.2 * len(results), 8))
    for j, (case, vs, lf, _, _) in enumerate(results):
        ax = axes[0, j]
        ax.plot(vs.t_s, 100 * vs.errors_m.max(axis=1), label="virtual structure")
        ax.plot(lf.t_s, 100 * lf.errors_m.max(axis=1), label="leader–follower")
        ax.axhline(100 * BROKEN_M, color="r", ls=":", lw=1, label="broken")
        ax.set_yscale("log")
        ax.set_title(case, fontsize=9)
        ax.set_xlabel("t [s]")
        ax.grid(True, which="both", alpha=0.3)
        if j == 0:
            ax.set_ylabel("max formation error [cm]")
            ax.legend(fontsize=7)
        ax = axes[1, j]
        for i, r in enumerate(lf.robots):
            ax.plot(lf.positions_m[:, i, 0], lf.positions_m[:, i, 1], lw=1, label=f"L–F {r}")
        sv = np.array([(p.x, p.y) for p in vs.structure])
        ax.plot(sv[:, 0], sv[:, 1], "k--", lw=1, label="VS structure origin")
        for run, mk, name in ((vs, "o", "VS"), (lf, "x", "L–F")):
            end = np.array([run.final_xy[r] for r in run.robots])
            ax.plot(end[:, 0], end[:, 1], mk, ms=7, label=f"{name} final robots")
        goal = Pose2(*mission.goal).apply(tpl)
        ax.plot(goal[:, 0], goal[:, 1], "g+", ms=10, label="goal points")
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.grid(True, alpha=0.3)
        if j == 0:
            ax.set_ylabel("y [m]")
            ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
