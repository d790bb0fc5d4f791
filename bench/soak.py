"""A soak (issue 30): one fleet for --minutes under hostile frames and injected faults, then a report.

The fleet is the e2e triangle (tests/data/e2e-triangle.toml: r1, r2, r3 at 30 Hz, the same robots, tracker
and mission parameters) with bodies (radius 0.05 m, so that contacts mean something) and on_failure
"rejoin", as real `vsfleet` processes on a free loopback port, multicast scouting off, as the multi-process
tests start them (tests/integration/conftest.py): a `vsfleet router` child, `vsfleet sim`, `vsfleet tracker
sim` and one `vsfleet agent` per robot. Its mission alternates between two goals --spread m either side of
the origin (every --mission-every s a new mission, the next version, effective 1.5 s after it is put), so
the fleet keeps moving for the whole soak. This process observes the key space with its own zenoh session
(state, truth, event, the tracker's frames) and injects, after a 30 s warm-up:

- hostile messages throughout: `vsfleet fuzz --kinds frame,mission,cmd,fault --rate 30` (per kind) in
  segments of --fuzz-segment s, restarted 2 s after each ends (never while the router is down);
- an agent killed (SIGKILL) and restarted 3 s later, every --kill-every s, rotating r1, r2, r3;
- a tracker blackout (SIGSTOP, 1 s, SIGCONT) every --blackout-every s;
- a router restart (SIGKILL, 1 s outage, a new `vsfleet router` on the same port) every --router-every s;
- the mission changes above.

Two injections are never closer than 12 s (a later one is pushed back), and none falls in the last 15 s.
Progress goes to stderr every 30 s. The report (stdout, markdown; soak.json):

- RSS (VmRSS, /proc/<pid>/status) of every process at the start (its first reading >= 30 s after it
  started) and at the end; for a restarted process, its newest instance's, labelled, and the largest
  growth of any of its instances; and its parts: RssAnon (heap) and RssShmem (zenoh's shared-memory
  segments mapped in: a client maps each sender's SHM pool, 16 MiB, through which zenoh sends messages
  over 3 KiB to a process on the same host, the fuzzer's oversized ones among them);
- CPU per frame of each agent: utime + stime (/proc/<pid>/stat) over the states it published between
  two readings, summed over its instances;
- rejections: per fuzz segment, each agent's ``rejected`` (its state) and simfleet's (its truth) counted
  during the segment against what the fuzzer sent (frame + mission for an agent, cmd + fault for
  simfleet), on the segments where that count can be exact (the same agent instance throughout, no
  router outage, a fresh reading at both ends); totals for the rest;
- crashes: any process that exited without being killed by the soak (it is restarted and counted);
- contacts: truth frames on which two bodies overlap (vsfleet.analysis.min_gap_m < 0);
- agreement: the fraction of frames on which every agent's copy is bit-identical
  (vsfleet.analysis.agreement, frames >= 2 agents ran whole), outside the injected faults: frames from
  0.5 s before a kill, blackout or router restart to --settle s after its end are left out (and reported
  apart); mission changes are not faults and are not left out.

Writes soak.md and soak.json under runs/bench/soak/ (or --out DIR); --docs writes soak.md into
docs/bench/sections/ (the JSON and the processes' logs stay under runs/bench/soak/). --render JSON writes the
markdown again from a run's soak.json, running nothing.

Run: .venv/bin/python -m bench.soak [--minutes 30] [--fuzz-no-shm] [--out DIR | --docs] [--render runs/bench/soak/soak.json]
(--fuzz-no-shm: the fuzzer's session with zenoh shared memory off, to tell its SHM pools from other growth.)
"""

from __future__ import annotations

import argparse
import dataclasses
import heapq
import json
import math
import os
import platform
import re
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # bench.outputs, also when run as a script

from bench.outputs import DOCS, RUNS, add_output_flags  # noqa: E402

CLK_TCK = os.sysconf("SC_CLK_TCK")
ROBOTS = ("r1", "r2", "r3")
FLEET = "soak"
WARMUP_S = 30.0          # no injection before, and the first RSS reading of a process after this long
MIN_SPACING_S = 12.0     # two injections never closer than this
TAIL_S = 15.0            # no injection in the last seconds of the soak
PRE_S = 0.5              # frames this long before an injection are left out of the agreement
AGENT_RESTART_S = 3.0    # a killed agent is restarted this long after the kill
BLACKOUT_S = 1.0
ROUTER_OUTAGE_S = 1.0
MISSION_DELAY_S = 1.5    # a new mission's effective_t, after its put
FUZZ_GAP_S = 2.0         # between fuzz segments: the counts are read here
FUZZ_KINDS = "frame,mission,cmd,fault"
SAMPLE_S = 5.0
PROGRESS_S = 30.0
FAULT_KINDS = ("agent_kill", "blackout", "router")
RSS_TARGET_MIB = 2.0
# An agent's RSS rises by 2-4 MiB in its first minute or two (the allocator's and zenoh's buffers reaching their
# working size), then stays nearly flat: in the 30-minute soak of 2026-12-04 18:08 the agent instances grew up to
# +4.19 MiB from their first reading (30 s) but at most +1.96 MiB from 120 s after their start. So the report
# gives, beside the raw growth from the first reading (the target's figure), the growth after this warm-up: from
# the first reading >= RSS_WARMUP_S after the process started to its last, for an instance that ran at least
# RSS_AFTER_MIN_S past the warm-up (others have no such figure).
RSS_WARMUP_S = 120.0
RSS_AFTER_MIN_S = 60.0
AGREE_TARGET = 0.999

# e2e-triangle's fleet (tests/data/e2e-triangle.toml), with bodies and on_failure rejoin; the goal is set per mission
SCENARIO = """\
# Written by bench/soak.py: tests/data/e2e-triangle.toml's robots, tracker and mission parameters, with
# bodies (radius 0.05 m) and on_failure = "rejoin"; the soak alternates the goal between two points.
schema = 1

[fleet]
name = "{fleet}"
duration_s = {duration_s}

[mission]
metric = "linf"
speed_max = 0.08
turn_rate_max = 0.3
goal = {{ x = {gx}, y = {gy}, th = {gth} }}
on_failure = "rejoin"

[tracker]
rate_hz = 30.0
noise_xy_m = 0.001
noise_th_rad = 0.005
latency_s = 0.005

[defaults]
wheel_base = 0.12
wheel_speed_max = 0.3
wheel_accel_max = 0.8
radius = 0.05

[robots.r1]
p = [0.3, 0.0]
start = [0.30, 0.02, 0.0]
gain = [1.0, 0.97]

[robots.r2]
p = [-0.15, 0.26]
start = [-0.16, 0.25, 0.2]
gain = [0.98, 1.0]

[robots.r3]
p = [-0.15, -0.26]
start = [-0.13, -0.27, -0.1]
wheel_speed_max = 0.25
gain = [1.02, 1.0]
"""


def goals(spread_m: float) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The two goals the missions alternate between: +-spread along x, a little off the axis, turned."""
    return (spread_m, 0.15 * spread_m, 0.3), (-spread_m, -0.15 * spread_m, -0.3)


# ---------------------------------------------------------------- the schedule (pure)


@dataclass(frozen=True)
class Injection:
    t: float       # [s] from the start of the soak (the fleet up)
    kind: str      # agent_kill | blackout | router | mission
    target: str    # the robot (agent_kill), "tracker", "router", or the goal index (mission: "0" / "1")


def schedule(duration_s: float, *, kill_every_s: float = 120.0, blackout_every_s: float = 180.0,
             router_every_s: float = 600.0, mission_every_s: float = 150.0, robots=ROBOTS,
             warmup_s: float = WARMUP_S, spacing_s: float = MIN_SPACING_S, tail_s: float = TAIL_S) -> list[Injection]:
    """Every injection of a soak of ``duration_s``, in time order.

    Each kind starts after the warm-up at its own offset (so that a 2-minute soak has one of each: mission
    +10 s, blackout +25 s, agent kill +45 s, router +70 s) and repeats at its period; agent kills rotate
    through ``robots``; missions alternate between the goals (target "1", "0", "1", ...; the initial
    mission is goal 0). An injection within ``spacing_s`` of one already placed is pushed back until it is
    not; none falls after ``duration_s - tail_s``."""
    last = duration_s - tail_s
    nominal: list[tuple[float, int, str, str]] = []  # (t, priority, kind, target)
    plans = (("router", router_every_s, 70.0), ("agent_kill", kill_every_s, 45.0),
             ("blackout", blackout_every_s, 25.0), ("mission", mission_every_s, 10.0))
    for prio, (kind, every, offset) in enumerate(plans):
        if every <= 0:
            continue
        k = 0
        while (t := warmup_s + offset + k * every) <= last:
            target = {"router": "router", "blackout": "tracker", "agent_kill": robots[k % len(robots)],
                      "mission": str((k + 1) % 2)}[kind]
            nominal.append((t, prio, kind, target))
            k += 1
    placed: list[Injection] = []
    for t, _, kind, target in sorted(nominal, key=lambda n: (n[1], n[0])):  # routers first, then kills...
        while any(abs(t - p.t) < spacing_s for p in placed):
            t = max(p.t for p in placed if abs(t - p.t) < spacing_s) + spacing_s
        if t <= last:
            placed.append(Injection(round(t, 3), kind, target))
    placed.sort(key=lambda i: i.t)
    # the missions alternate in the order they happen, whatever pushing did to them
    out, k = [], 0
    for inj in placed:
        if inj.kind == "mission":
            inj = dataclasses.replace(inj, target=str((k + 1) % 2))
            k += 1
        out.append(inj)
    return out


# ---------------------------------------------------------------- what is left out (pure)


def fault_windows(done: list[dict]) -> list[tuple[float, float | None]]:
    """(start, end) [s, wall] of every fault injected (end None: still on), from the executed injections."""
    return [(d["start"], d.get("end")) for d in done if d["kind"] in FAULT_KINDS]


def excluded(t: float, windows, settle_s: float, pre_s: float = PRE_S) -> bool:
    """Whether a frame at ``t`` [s] falls within pre_s before a fault to settle_s after its end."""
    return any(start - pre_s <= t and (end is None or t <= end + settle_s) for start, end in windows)


# ---------------------------------------------------------------- /proc readings


def proc_cpu_s(pid: int) -> float:
    """User + system CPU time [s] of a process (all its threads), from /proc/<pid>/stat."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    rest = stat[stat.rfind(")") + 2:].split()
    return (int(rest[11]) + int(rest[12])) / CLK_TCK


def proc_mem_mib(pid: int) -> dict[str, float]:
    """VmRSS and its parts RssAnon (the heap, stacks) and RssShmem (shared memory mapped in: zenoh's SHM
    segments) [MiB], from /proc/<pid>/status."""
    out = {"VmRSS": math.nan, "RssAnon": math.nan, "RssShmem": math.nan}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        name = line.split(":", 1)[0]
        if name in out:
            out[name] = int(line.split()[1]) / 1024.0
    return out


def shm_segments(pid: int) -> int:
    """How many zenoh shared-memory segments (/dev/shm/*.zenoh) the process has mapped."""
    try:
        return len({line.split()[-1] for line in Path(f"/proc/{pid}/maps").read_text().splitlines()
                     if line.endswith(".zenoh") and "/dev/shm/" in line})
    except OSError:
        return -1


def machine_busy_s() -> float:
    """Busy CPU seconds of the whole machine since boot (/proc/stat: all but idle and iowait)."""
    v = [int(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:9]]
    return (sum(v) - v[3] - v[4]) / CLK_TCK


def machine() -> dict:
    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), platform.machine())
    try:
        commit = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=ROOT, capture_output=True,
                                text=True, timeout=10).stdout.strip() or "?"
    except (OSError, subprocess.SubprocessError):
        commit = "?"
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(), "commit": commit,
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "loadavg_start": Path("/proc/loadavg").read_text().split()[:3]}


# ---------------------------------------------------------------- the report (pure, on plain data)


def rss_rows(instances: list[dict]) -> list[dict]:
    """Per process name: its newest instance's first (>= 30 s after it started, else its earliest) and last
    RSS readings [MiB], and the largest growth of any of its instances. ``instances``: dicts with name,
    index (1 = original), started [s, soak clock], ended (None: ran to the end), first_rss, last_rss."""
    rows = []
    by_name: dict[str, list[dict]] = {}
    for inst in instances:
        if inst.get("first_rss") is not None and inst.get("last_rss") is not None:
            by_name.setdefault(inst["name"], []).append(inst)
    for name in sorted(by_name, key=_proc_order):
        insts = sorted(by_name[name], key=lambda i: i["index"])
        newest = insts[-1]
        growth = [i["last_rss"] - i["first_rss"] for i in insts]
        warm = [w for i in insts if (w := after_warmup(i)) is not None]
        count = max(i["index"] for i in insts)
        label = ("the original, the whole soak" if count == 1 else
                 f"instance {newest['index']} of {count}, from {_mmss(newest['started'])}")
        if not newest.get("first_after_warmup", True):
            label += f" (first reading {newest['first_at'] - newest['started']:.0f} s after it started)"
        rows.append({"process": name, "instance": label, "instances": count,
                     "first_mib": newest["first_rss"], "first_at": newest.get("first_at"),
                     "last_mib": newest["last_rss"], "last_at": newest.get("last_at"),
                     "growth_mib": newest["last_rss"] - newest["first_rss"], "max_growth_mib": max(growth),
                     "anon_growth_mib": _diff(newest.get("last_anon"), newest.get("first_anon")),
                     "max_anon_growth_mib": max((d for i in insts
                                                 if (d := _diff(i.get("last_anon"), i.get("first_anon"))) is not None),
                                                default=None),
                     "last_shmem_mib": newest.get("last_shmem"), "shm_segments": newest.get("last_shm_segments"),
                     "holds": max(growth) <= RSS_TARGET_MIB,
                     # after the warm-up (RSS_WARMUP_S): the newest instance's, and the largest of those long enough
                     "warm_growth_mib": (w := after_warmup(newest)) and w["rss"],
                     "warm_anon_growth_mib": w and w["anon"],
                     "max_warm_growth_mib": max((x["rss"] for x in warm), default=None),
                     "max_warm_anon_growth_mib": max((x["anon"] for x in warm if x["anon"] is not None), default=None),
                     "warm_instances": len(warm),
                     "warm_holds": bool(warm) and max(x["rss"] for x in warm) <= RSS_TARGET_MIB})
    return rows


def after_warmup(inst: dict) -> dict | None:
    """An instance's growth after the warm-up: from its first reading (series: (t, VmRSS, RssAnon, RssShmem)
    every 5 s) >= RSS_WARMUP_S after it started to its last reading; None if it ran less than RSS_AFTER_MIN_S
    past that reading. {"from": t, "to": t, "rss": MiB, "anon": MiB or None}."""
    after = [p for p in inst.get("series") or [] if p[0] >= inst["started"] + RSS_WARMUP_S]
    if not after or inst.get("last_at") is None or inst["last_at"] - after[0][0] < RSS_AFTER_MIN_S:
        return None
    start = after[0]
    anon0 = start[2] if len(start) > 2 else None
    return {"from": start[0], "to": inst["last_at"], "rss": inst["last_rss"] - start[1],
            "anon": _diff(inst.get("last_anon"), anon0)}


def _diff(a, b):
    return None if a is None or b is None else a - b


def rss_series_rows(rep: dict) -> list[dict]:
    """The RSS of each process instance that ran the whole soak, at about every 5 minutes (the reading nearest
    each mark; the first mark is the warm-up's end and the last the end)."""
    end_min = rep["elapsed_s"] / 60.0
    marks = [WARMUP_S / 60.0] + [float(m) for m in range(5, int(end_min), 5) if m < end_min - 1] + [round(end_min, 1)]
    rows = []
    for inst in sorted(rep["instances"], key=lambda i: _proc_order(i["name"])):
        series = inst.get("series") or []
        if inst["index"] != 1 or inst["ended"] is not None or len(series) < 2:
            continue
        values = [min(series, key=lambda p: abs(p[0] - 60.0 * m))[1] for m in marks]
        rows.append({"process": inst["name"], "marks": marks, "values": values})
    return rows


def _proc_order(name: str) -> tuple[int, str]:
    order = {"router": 0, "sim": 1, "tracker": 2}
    return (order.get(name, 3), name)


def _mmss(t: float | None) -> str:
    if t is None:
        return "?"
    return f"{int(t // 60)}:{int(t % 60):02d}"


def cpu_rows(instances: list[dict]) -> list[dict]:
    """Per agent: CPU [ms] per frame it ran, summed over its instances: (cpu_last - cpu_first) /
    (states_last - states_first) from each instance's first and last readings."""
    acc: dict[str, list[float]] = {}
    for inst in instances:
        if not inst["name"].startswith("agent-") or inst.get("first_cpu") is None or inst.get("last_cpu") is None:
            continue
        a = acc.setdefault(inst["name"], [0.0, 0, 0])
        frames = inst["last_states"] - inst["first_states"]
        if frames > 0:
            a[0] += inst["last_cpu"] - inst["first_cpu"]
            a[1] += frames
            a[2] += 1
    return [{"agent": name, "cpu_ms_per_frame": 1000.0 * cpu / frames if frames else math.nan,
             "frames": frames, "instances": n} for name, (cpu, frames, n) in sorted(acc.items())]


def rejection_rows(segments: list[dict], robots=ROBOTS) -> list[dict]:
    """Per receiver (each agent, simfleet): over the fuzz segments where its count is exact, what it counted
    against what the fuzzer sent it; and the totals over every segment. A segment dict holds ``sent``
    (by kind), ``router_outage`` (bool) and ``counted``: {receiver: delta or None (no exact count: its
    reason in ``why``)}."""
    rows = []
    for rx in (*robots, "simfleet"):
        kinds = ("cmd", "fault") if rx == "simfleet" else ("frame", "mission")
        row = {"receiver": rx if rx == "simfleet" else f"agent {rx}", "kinds": "+".join(kinds), "segments": 0,
               "exact": 0, "sent": 0, "counted": 0, "mismatches": [], "not_compared": Counter(),
               "sent_all": 0}
        for seg in segments:
            sent = sum(seg["sent"].get(k, 0) for k in kinds)
            row["sent_all"] += sent
            got = seg["counted"].get(rx)
            if got is None or seg.get("router_outage"):
                why = "a router restart in the segment" if seg.get("router_outage") else seg["why"].get(rx, "?")
                row["not_compared"][why] += 1
                continue
            row["segments"] += 1
            row["sent"] += sent
            row["counted"] += got
            if got == sent:
                row["exact"] += 1
            else:
                row["mismatches"].append({"segment": seg["index"], "sent": sent, "counted": got})
        row["not_compared"] = dict(row["not_compared"])
        rows.append(row)
    return rows


def targets(rep: dict) -> list[dict]:
    """The issue's must-show targets, each with its measured value and whether it holds."""
    rss = rep["rss"]
    worst = max(rss, key=lambda r: r["max_growth_mib"]) if rss else None
    ag = rep["agreement"]["outside"]
    frac = ag["identical"] / ag["frames"] if ag["frames"] else math.nan
    return [
        {"target": "0 crashes", "value": f"{len(rep['crashes'])}", "holds": not rep["crashes"]},
        {"target": f"RSS growth <= {RSS_TARGET_MIB:g} MiB per process",
         "value": (f"largest {worst['max_growth_mib']:+.2f} MiB ({worst['process']})" if worst else "no readings"),
         "holds": bool(rss) and all(r["holds"] for r in rss)},
        {"target": "0 contacts", "value": f"{rep['contacts']['frames']} (smallest gap "
                                          f"{100 * rep['contacts']['min_gap_m']:.1f} cm)",
         "holds": rep["contacts"]["frames"] == 0 and rep["contacts"]["truth_frames"] > 0},
        {"target": f">= {100 * AGREE_TARGET:g}% of frames bit-identical outside injected faults",
         "value": f"{100 * frac:.3f}% ({ag['identical']}/{ag['frames']})",
         "holds": bool(ag["frames"]) and frac >= AGREE_TARGET},
    ] + _warm_target(rss)


def _warm_target(rss: list[dict]) -> list[dict]:
    """The RSS target again, on the growth after the warm-up (RSS_WARMUP_S): a second row, never instead of the raw one."""
    warm = [r for r in rss if r.get("max_warm_growth_mib") is not None]
    if not warm:
        return []
    worst = max(warm, key=lambda r: r["max_warm_growth_mib"])
    n = sum(r.get("warm_instances", 0) for r in rss)
    return [{"target": f"(the same, after a {RSS_WARMUP_S:g} s warm-up)",
             "value": f"largest {worst['max_warm_growth_mib']:+.2f} MiB ({worst['process']}; {n} instances that ran "
                      f">= {RSS_WARMUP_S + RSS_AFTER_MIN_S:g} s)",
             "holds": all(r["max_warm_growth_mib"] <= RSS_TARGET_MIB for r in warm)}]


def markdown(rep: dict) -> str:
    m = rep["machine"]
    cfg = rep["config"]
    lines = ["## Soak (issue 30)", "",
             f"*`bench/soak.py --minutes {cfg['minutes']:g}`, measured on {m['date']}: {m['cpu']}, {m['cores']} cores, "
             f"Python {m['python']}, code at `{m['commit']}`. "
             + ("**The machine was shared with other work**: " if rep["others_cores"] >= 0.1
                else "Little else ran on the machine: ")
             + f"load average {' '.join(m['loadavg_start'])} at the start, "
             f"{' '.join(rep.get('loadavg_end', ['?']))} at the end; other processes kept "
             f"{rep['others_cores']:.2f} of the {m['cores']} cores busy on average during the soak.*", "",
             f"One fleet (the e2e triangle: 3 robots, 30 Hz, bodies of radius 0.05 m, on_failure rejoin) as real "
             f"processes on loopback for {rep['elapsed_s'] / 60:.1f} min, its mission alternating between goals "
             f"{cfg['goals'][0][:2]} and {cfg['goals'][1][:2]} every {cfg['mission_every_s']:g} s (the fleet moved in "
             f"{100 * rep['moving_fraction']:.0f}% of 5 s windows), with hostile messages throughout (`vsfleet fuzz "
             f"--kinds {FUZZ_KINDS} --rate {cfg['fuzz_rate']:g}`"
             f"{' with zenoh shared memory off' if cfg.get('fuzz_no_shm') else ''}: {rep['fuzz']['sent']} invalid messages in "
             f"{rep['fuzz']['segments']} segments, {100 * rep['fuzz']['coverage']:.0f}% of the soak), "
             f"and {_injected(rep)}. Every number below is measured; the targets are the issue's.", "",
             "| target | measured | holds |", "|---|---|---|"]
    lines += [f"| {t['target']} | {t['value']} | {'yes' if t['holds'] else '**NO**'} |" for t in targets(rep)]
    lines += ["", "### Memory (VmRSS, MiB)", "",
              "First reading: 30 s after the process started; last: at the end of the soak (or its kill). A "
              "restarted process is shown by its newest instance; *largest growth* is over all its instances. "
              f"*After warm-up*: the same growth from the first reading {RSS_WARMUP_S:g} s after the process started "
              f"(an agent's RSS rises for its first minute or two, then stays nearly flat), for instances that ran "
              f"at least {RSS_AFTER_MIN_S:g} s past it (- for one that did not); the raw growth stays the target's figure.",
              "",
              "| process | instance shown | first | last | growth | largest growth (any instance) | "
              "growth after warm-up | largest after warm-up (instances long enough) |",
              "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['process']} | {r['instance']} | {r['first_mib']:.1f} | {r['last_mib']:.1f} | "
              f"{r['growth_mib']:+.2f} | {r['max_growth_mib']:+.2f} | {_mib(r.get('warm_growth_mib'), none='-')} | "
              f"{_mib(r.get('max_warm_growth_mib'), none='-')}{_of(r)} |" for r in rep["rss"]]
    if any(r.get("anon_growth_mib") is not None for r in rep["rss"]):
        lines += ["", "VmRSS is RssAnon (heap, stacks) + RssFile + RssShmem (shared memory mapped in: zenoh's SHM "
                  "segments, /dev/shm/*.zenoh). The same instances:", "",
                  "| process | RssAnon growth | largest RssAnon growth (any instance) | RssShmem at the end | "
                  "zenoh SHM segments mapped at the end |", "|---|---|---|---|---|"]
        lines += [f"| {r['process']} | {_mib(r.get('anon_growth_mib'))} | {_mib(r.get('max_anon_growth_mib'))} | "
                  f"{_mib(r.get('last_shmem_mib'), sign=False)} | {r.get('shm_segments', '?')} |" for r in rep["rss"]]
    series = rss_series_rows(rep)
    if series:
        marks = series[0]["marks"]
        lines += ["", "RSS over the soak of the processes that ran all of it (MiB, at the minute shown):", "",
                  "| process | " + " | ".join(f"{m:g} min" for m in marks) + " |",
                  "|---|" + "---|" * len(marks)]
        lines += [f"| {r['process']} | " + " | ".join("" if v is None else f"{v:.1f}" for v in r["values"]) + " |"
                  for r in series]
    lines += ["", "### CPU per frame", "",
              "utime + stime from /proc over the states each agent published between its first (after 30 s) and last "
              "readings, summed over its instances.", "",
              "| agent | instances | frames | CPU per frame (ms) |", "|---|---|---|---|"]
    lines += [f"| {r['agent']} | {r['instances']} | {r['frames']} | {r['cpu_ms_per_frame']:.2f} |" for r in rep["cpu"]]
    lines += ["", "### Rejections", "",
              f"Per fuzz segment, each receiver's count (the agents' `rejected` in their state, simfleet's in its truth) "
              f"read in the {FUZZ_GAP_S:g} s gaps before and after the segment, against what the fuzzer sent it. "
              "*Compared*: segments where the count can be exact (the same agent instance throughout, no router "
              "restart, a fresh reading at both ends).", "",
              "| receiver | kinds | segments compared | counted exactly | sent (compared) | counted (compared) | "
              "not compared (why) | sent over the whole soak |", "|---|---|---|---|---|---|---|---|"]
    for r in rep["rejections"]:
        why = "; ".join(f"{n}: {w}" for w, n in r["not_compared"].items()) or "none"
        lines.append(f"| {r['receiver']} | {r['kinds']} | {r['segments']} | {r['exact']} | {r['sent']} | "
                     f"{r['counted']} | {why} | {r['sent_all']} |")
    mism = [(r["receiver"], x) for r in rep["rejections"] for x in r["mismatches"]]
    if mism:
        lines += ["", "Segments counted differently: " + "; ".join(
            f"{rx} segment {x['segment']}: sent {x['sent']}, counted {x['counted']}" for rx, x in mism[:12]) + "."]
    ag = rep["agreement"]
    lines += ["", "### Agreement, contacts, crashes", "",
              f"- Frames bit-identical across every agent that ran them whole (>= 2 agents): outside the injected "
              f"faults {ag['outside']['identical']}/{ag['outside']['frames']}; within them (0.5 s before a fault to "
              f"{cfg['settle_s']:g} s after its end) {ag['inside']['identical']}/{ag['inside']['frames']}. "
              f"{ag['all3']} frames were run whole by all three agents; {ag['skipped']} frames were not compared "
              f"(fewer than 2 agents, or one ran it on its deadline); this process received "
              f"{rep['frames_seen']} of the tracker's frames.",
              f"- Contacts: {rep['contacts']['frames']} of {rep['contacts']['truth_frames']} truth frames with two "
              f"bodies overlapping; smallest gap between bodies {100 * rep['contacts']['min_gap_m']:.1f} cm.",
              f"- Crashes: {len(rep['crashes'])}" + ("." if not rep["crashes"] else ": " + "; ".join(
                  f"{c['process']} (exit {c['rc']}) at {_mmss(c['t'])}" for c in rep["crashes"]) + "."),
              f"- Decisions (events): {_counts(rep['events'])}.",
              f"- Error lines in the processes' logs: {rep['errors']['count']}"
              + ("." if not rep["errors"]["count"] else " (" + "; ".join(
                  f"{k}: {n}" for k, n in rep["errors"]["by_log"].items()) + ")."),
              ]
    if ag.get("disagreements"):
        lines.append("- Frames whose copies differed: " + "; ".join(
            f"seq {d['seq']} at {_mmss(d['t'])} ({'outside' if d['outside'] else 'within'} a fault window, agents "
            f"{','.join(d['agents'])}, up to {1000 * d['max_pos_m']:.3f} mm)" for d in ag["disagreements"][:8]) + ".")
    if rep.get("stop_lines"):
        lines += ["", "What the processes running at the end said as they stopped:", ""]
        lines += [f"- `{name}`: {line}" for name, line in rep["stop_lines"].items()]
    if rep.get("notes"):
        lines += [""] + [f"{n}" for n in rep["notes"]]
    return "\n".join(lines) + "\n"


def _of(r: dict) -> str:
    """How many of a process's instances have a growth after the warm-up: " (k of n)"."""
    return "" if r.get("warm_instances") is None else f" ({r['warm_instances']} of {r['instances']})"


def _mib(v, sign: bool = True, none: str = "?") -> str:
    return none if v is None else (f"{v:+.2f}" if sign else f"{v:.1f}")


def _counts(c: dict) -> str:
    return ", ".join(f"{k} {v}" for k, v in sorted(c.items())) or "none"


def _injected(rep: dict) -> str:
    c = Counter(d["kind"] for d in rep["injections"])
    return (f"{c['agent_kill']} agents killed (SIGKILL) and restarted {AGENT_RESTART_S:g} s later, rotating r1, r2, r3; "
            f"{c['blackout']} tracker blackouts (SIGSTOP {BLACKOUT_S:g} s); {c['router']} router restarts (SIGKILL, "
            f"{ROUTER_OUTAGE_S:g} s outage); {c['mission']} mission changes")


# ---------------------------------------------------------------- what this process observes


class Tally:
    """What the soak's own session saw, aggregated as it goes (memory stays bounded)."""

    def __init__(self, keys, mission, robots=ROBOTS) -> None:
        self.keys = keys
        self.mission = mission
        self.robots = robots
        self.lock = threading.Lock()
        self.instance = {r: 1 for r in robots}            # bumped when the soak kills an agent
        self.states_n: Counter = Counter()                 # (robot, instance) -> states seen
        self.rejected: dict[str, tuple[int, int, float]] = {}   # robot -> (instance, rejected, arrival)
        self.sim_rejected: tuple[int, float] = (-1, 0.0)
        self.commanded: set[str] = set()
        self.frames_seen = 0
        self.state_groups: dict[int, dict[str, object]] = {}
        self.state_first: dict[int, float] = {}
        self.truth_groups: dict[float, dict[str, object]] = {}
        self.truth_first: dict[float, float] = {}
        self.events: Counter = Counter()
        self.event_log: list[tuple[float, str, str, str, int]] = []
        self.alive: dict[str, float] = {}
        # finalized
        self.outside = [0, 0]
        self.inside = [0, 0]
        self.all3 = 0
        self.skipped = 0
        self.disagreements: list[dict] = []
        self.contacts = 0
        self.truth_frames = 0
        self.min_gap = math.inf
        self.centroids: list[tuple[float, float, float]] = []  # (t, x, y) every ~5 s
        self.last_centroid_t = 0.0

    # callbacks (zenoh threads)
    def on_state(self, sample) -> None:
        from vsfleet.wire import WireError, decode_state
        now = time.time()
        try:
            robot = self.keys.robot_of(str(sample.key_expr), "state")
            msg = decode_state(sample.payload.to_bytes())
        except WireError:
            return
        with self.lock:
            inst = self.instance.get(robot, 1)
            self.states_n[(robot, inst)] += 1
            self.rejected[robot] = (inst, msg.rejected, now)
            self.state_groups.setdefault(msg.seq, {})[robot] = msg
            self.state_first.setdefault(msg.seq, now)

    def on_truth(self, sample) -> None:
        from vsfleet.wire import WireError, decode_truth
        now = time.time()
        try:
            robot = self.keys.robot_of(str(sample.key_expr), "truth")
            msg = decode_truth(sample.payload.to_bytes())
        except WireError:
            return
        with self.lock:
            self.sim_rejected = (msg.rejected, now)
            if msg.why == "commanded":
                self.commanded.add(robot)
            self.truth_groups.setdefault(msg.t, {})[robot] = msg
            self.truth_first.setdefault(msg.t, now)

    def on_frame(self, _sample) -> None:
        with self.lock:
            self.frames_seen += 1

    def on_event(self, sample) -> None:
        from vsfleet.wire import WireError, decode_event
        try:
            msg = decode_event(sample.payload.to_bytes())
        except WireError:
            return
        with self.lock:
            self.events[msg.kind] += 1
            if len(self.event_log) < 2000:
                self.event_log.append((msg.t, msg.by, msg.kind, msg.robot, msg.seq))

    def on_alive(self, sample) -> None:
        import zenoh
        with self.lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self.alive[str(sample.key_expr)] = time.time()
            else:
                self.alive.pop(str(sample.key_expr), None)

    # main thread
    def finalize(self, windows, settle_s: float, older_than_s: float, t0: float) -> None:
        """Fold frames whose first message came more than ``older_than_s`` ago into the totals."""
        from vsfleet.analysis import agreement, min_gap_m
        now = time.time()
        with self.lock:
            seqs = [s for s, t in self.state_first.items() if t < now - older_than_s]
            groups = [(s, self.state_groups.pop(s)) for s in seqs]
            for s in seqs:
                del self.state_first[s]
            ts = [t for t, a in self.truth_first.items() if a < now - older_than_s]
            truths = [(t, self.truth_groups.pop(t)) for t in sorted(ts)]
            for t in ts:
                del self.truth_first[t]
        for seq, group in groups:
            msgs = list(group.values())
            a = agreement(list(group.items()), min_agents=2, complete_only=True)
            if not a.frames:
                self.skipped += 1
                continue
            t = msgs[0].t
            out = not excluded(t, windows, settle_s)
            bucket = self.outside if out else self.inside
            bucket[0] += 1
            bucket[1] += a.identical
            if len(group) == len(self.robots):
                self.all3 += 1
            if a.identical != a.frames and len(self.disagreements) < 200:
                self.disagreements.append({"seq": seq, "t": t - t0, "outside": out, "agents": sorted(group),
                                           "max_pos_m": a.max_pos_m, "max_th_rad": a.max_th_rad})
        for t, group in truths:
            if len(group) < 2:
                continue
            self.truth_frames += 1
            gap = min_gap_m(self.mission, [(t, group)])
            self.min_gap = min(self.min_gap, gap)
            if gap < 0:
                self.contacts += 1
            if t - self.last_centroid_t >= 5.0 and len(group) == len(self.robots):
                xs = [m.x for m in group.values()]
                ys = [m.y for m in group.values()]
                self.centroids.append((t, sum(xs) / len(xs), sum(ys) / len(ys)))
                self.last_centroid_t = t


def moving_fraction(centroids: list[tuple[float, float, float]], min_m: float = 0.02) -> float:
    """Fraction of consecutive ~5 s windows over which the robots' centroid moved at least ``min_m``."""
    steps = [math.hypot(b[1] - a[1], b[2] - a[2]) for a, b in zip(centroids, centroids[1:])]
    return sum(s >= min_m for s in steps) / len(steps) if steps else math.nan


# ---------------------------------------------------------------- the processes


@dataclass
class Instance:
    name: str
    index: int
    popen: subprocess.Popen
    started: float                # [s, wall]
    log: Path
    killed: bool = False          # by the soak
    ended: float | None = None
    rc: int | None = None
    first: tuple | None = None    # (t, rss, cpu, states, anon, shmem, segments): the first reading >= WARMUP_S after it started
    earliest: tuple | None = None
    last: tuple | None = None
    series: list = field(default_factory=list)  # (t [s, soak clock], rss [MiB]) every reading (5 s)


@dataclass
class Segment:
    index: int
    inst: Instance
    start: float
    duration: float
    before: dict = field(default_factory=dict)
    after: dict = field(default_factory=dict)
    sent: dict = field(default_factory=dict)
    routed: bool | None = None
    router_outage: bool = False


class Soak:
    def __init__(self, args, work: Path) -> None:
        from vsfleet.fleetctl.router import free_loopback_port
        from vsfleet.zglue.scenario_file import load_scenario
        from vsfleet.wire import Keys
        self.args = args
        self.work = work
        self.goals = goals(args.spread)
        self.scenario_path = work / "soak.toml"
        g = self.goals[0]
        self.scenario_path.write_text(SCENARIO.format(fleet=FLEET, duration_s=args.minutes * 60, gx=g[0], gy=g[1],
                                                      gth=g[2]))
        self.scenario = load_scenario(self.scenario_path)
        self.keys = Keys(FLEET)
        self.port = free_loopback_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.instances: list[Instance] = []
        self.current: dict[str, Instance] = {}
        self.crashes: list[dict] = []
        self.done: list[dict] = []     # executed injections: kind, target, start, end [s, wall]
        self.segments: list[Segment] = []
        self.fuzz_seg: Segment | None = None
        self.router_down = False
        self.version = 1
        self.t0 = 0.0
        self.actions: list[tuple[float, int, object]] = []
        self._n = 0
        self.tally: Tally | None = None
        self.session = None

    # -- children
    def start(self, name: str, *args: str) -> Instance:
        from vsfleet.fleetctl.run import child_command
        from vsfleet.zglue.zconf import zenoh_flags
        index = sum(1 for i in self.instances if i.name == name) + 1
        log = self.work / "logs" / f"{name}.{index}.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        flags = [] if name == "router" else zenoh_flags(self.endpoint)
        with log.open("ab") as out:
            p = subprocess.Popen(child_command(*args, *flags), stdout=out, stderr=subprocess.STDOUT,
                                 stdin=subprocess.DEVNULL, start_new_session=True)
        inst = Instance(name, index, p, time.time(), log)
        self.instances.append(inst)
        if name != "fuzz":
            self.current[name] = inst
        return inst

    def start_router(self) -> None:
        from vsfleet.fleetctl.router import wait_listening
        self.start("router", "router", "--listen", self.endpoint, "--no-multicast-scouting")
        wait_listening(self.port, 20.0)
        self.router_down = False

    def start_sim(self) -> None:
        self.start("sim", "sim", str(self.scenario_path))

    def start_tracker(self) -> None:
        tr = self.scenario.tracker
        self.start("tracker", "tracker", "sim", "--fleet", FLEET, "--rate", str(tr.rate_hz), "--noise-xy",
                   str(tr.noise_xy_m), "--noise-th", str(tr.noise_th_rad), "--latency", str(tr.latency_s))

    def start_agent(self, robot: str) -> None:
        self.start(f"agent-{robot}", "agent", "--robot", robot, "--fleet", FLEET)

    def restart(self, name: str) -> None:
        if name == "router":
            self.start_router()
        elif name == "sim":
            self.start_sim()
        elif name == "tracker":
            self.start_tracker()
        elif name.startswith("agent-"):
            robot = name.split("-", 1)[1]
            with self.tally.lock:
                self.tally.instance[robot] += 1
            self.start_agent(robot)

    def kill(self, name: str, sig=signal.SIGKILL) -> None:
        inst = self.current[name]
        if sig in (signal.SIGKILL, signal.SIGTERM):
            inst.killed = True
        inst.popen.send_signal(sig)

    # -- the observer
    def open_session(self):
        import zenoh
        from vsfleet.zglue.zconf import zenoh_config
        from vsfleet.fleetctl.mission_cmd import stamp
        conf = zenoh_config(argparse.Namespace(mode="client", connect=[self.endpoint], listen=[], config=None,
                                               no_multicast_scouting=True, cfg=[], wait=False))
        self.session = zenoh.open(conf)
        self.mission = stamp(self.scenario.mission, time.time(), 0.0, version=1)
        self.tally = Tally(self.keys, self.mission)
        t = self.tally
        self.subs = [self.session.declare_subscriber(self.keys.state(), t.on_state),
                     self.session.declare_subscriber(self.keys.truth(), t.on_truth),
                     self.session.declare_subscriber(self.keys.frame("sim"), t.on_frame),
                     self.session.declare_subscriber(self.keys.event(), t.on_event),
                     self.session.liveliness().declare_subscriber(self.keys.alive(), t.on_alive, history=True)]

    def publish_mission(self, goal_index: int) -> None:
        from vsfleet.fleetctl.mission_cmd import stamp
        from vsfleet.wire import encode_mission
        from vsfleet.zglue.zconf import RELIABLE_QOS
        self.mission = stamp(dataclasses.replace(self.scenario.mission, goal=self.goals[goal_index]), time.time(),
                             MISSION_DELAY_S if self.version > 1 or goal_index else 0.0, version=self.version)
        self.session.put(self.keys.mission, encode_mission(self.mission), **RELIABLE_QOS)

    def wait(self, pred, timeout_s: float, what: str) -> None:
        deadline = time.time() + timeout_s
        while not pred():
            if time.time() > deadline:
                raise TimeoutError(f"{what}: not within {timeout_s} s\n{self.tails()}")
            self.check_children()
            time.sleep(0.1)

    def tails(self) -> str:
        return "\n".join(f"--- {i.log.name}\n{i.log.read_text(errors='replace')[-1500:]}"
                         for i in self.current.values())

    # -- the soak
    def bring_up(self) -> None:
        self.start_router()
        self.open_session()
        self.start_sim()
        self.start_tracker()
        for r in ROBOTS:
            self.start_agent(r)
        want = {self.keys.alive("agent", r) for r in ROBOTS} | {self.keys.alive("tracker", "sim"),
                                                                 self.keys.alive("sim", "simfleet")}
        self.wait(lambda: want <= set(self.tally.alive), 60, "every process alive")
        self.publish_mission(0)
        self.version += 1
        self.wait(lambda: self.tally.commanded >= set(ROBOTS) and
                  {r for r, _ in self.tally.states_n} >= set(ROBOTS), 60, "every robot commanded")
        self.t0 = time.time()

    def at(self, t_wall: float, fn) -> None:
        self._n += 1
        heapq.heappush(self.actions, (t_wall, self._n, fn))

    def inject(self, inj: Injection) -> None:
        rec = {"kind": inj.kind, "target": inj.target, "planned": inj.t, "start": time.time(), "end": None}
        self.done.append(rec)
        if inj.kind == "agent_kill":
            name = f"agent-{inj.target}"
            self.kill(name)
            self.current[name].popen.wait(timeout=10)

            def back():
                self.restart(name)
                rec["end"] = time.time()
            self.at(rec["start"] + AGENT_RESTART_S, back)
        elif inj.kind == "blackout":
            self.kill("tracker", signal.SIGSTOP)

            def cont():
                self.current["tracker"].popen.send_signal(signal.SIGCONT)
                rec["end"] = time.time()
            self.at(rec["start"] + BLACKOUT_S, cont)
        elif inj.kind == "router":
            self.router_down = True
            if self.fuzz_seg is not None:
                self.fuzz_seg.router_outage = True
            self.kill("router")
            self.current["router"].popen.wait(timeout=10)

            def up():
                self.start_router()
                rec["end"] = time.time()
            self.at(rec["start"] + ROUTER_OUTAGE_S, up)
        elif inj.kind == "mission":
            self.publish_mission(int(inj.target))
            rec["version"] = self.version
            self.version += 1
            rec["end"] = time.time()

    def check_children(self) -> None:
        for inst in list(self.current.values()) + ([self.fuzz_seg.inst] if self.fuzz_seg else []):
            rc = inst.popen.poll()
            if rc is None or inst.ended is not None:
                continue
            inst.ended, inst.rc = time.time(), rc
            if inst.killed or (inst.name == "fuzz" and rc == 0):
                continue
            tail = [ln for ln in inst.log.read_text(errors="replace").splitlines() if ln.strip()][-5:]
            self.crashes.append({"process": inst.name, "instance": inst.index, "rc": rc,
                                 "t": inst.ended - self.t0 if self.t0 else None, "log": inst.log.name, "tail": tail})
            print(f"[soak] CRASH: {inst.name} (instance {inst.index}) exited {rc}; {inst.log}: {tail[-1:]}",
                  file=sys.stderr, flush=True)
            if inst.name != "fuzz" and self.t0:
                self.restart(inst.name)

    def sample(self) -> None:
        now = time.time()
        insts = list(self.current.values()) + ([self.fuzz_seg.inst] if self.fuzz_seg else [])
        for inst in insts:
            if inst.ended is not None or inst.popen.poll() is not None:
                continue
            try:
                mem, cpu = proc_mem_mib(inst.popen.pid), proc_cpu_s(inst.popen.pid)
                rss = mem["VmRSS"]
            except (OSError, ValueError, IndexError):
                continue
            states = 0
            if inst.name.startswith("agent-"):
                robot = inst.name.split("-", 1)[1]
                with self.tally.lock:
                    states = self.tally.states_n[(robot, self.tally.instance[robot])]
            reading = (now - self.t0 if self.t0 else 0.0, rss, cpu, states, mem["RssAnon"], mem["RssShmem"],
                       shm_segments(inst.popen.pid))
            inst.earliest = inst.earliest or reading
            if inst.first is None and self.t0 and now - self.t0 >= WARMUP_S - 0.5 \
                    and now - inst.started >= WARMUP_S - 0.5:
                inst.first = reading
            inst.last = reading
            if not inst.series or reading[0] - inst.series[-1][0] >= SAMPLE_S - 0.5:
                inst.series.append((round(reading[0], 1), round(rss, 2), round(mem["RssAnon"], 2),
                                    round(mem["RssShmem"], 2)))

    def snapshot(self) -> dict:
        """Each receiver's newest rejection count, with its instance and how fresh it is."""
        now = time.time()
        with self.tally.lock:
            snap = {r: (inst, n, now - t) for r, (inst, n, t) in self.tally.rejected.items()}
            n, t = self.tally.sim_rejected
            snap["simfleet"] = (1, n, now - t)
        return snap

    def close_segment(self, seg: Segment) -> None:
        line = next((ln for ln in reversed(seg.inst.log.read_text(errors="replace").splitlines())
                     if ln.startswith("{")), None)
        if line:
            summary = json.loads(line)
            seg.sent, seg.routed = summary["by_kind"], summary["routed"]

    def fuzz_tick(self, deadline: float) -> None:
        now = time.time()
        seg = self.fuzz_seg
        if seg is not None:
            if seg.inst.popen.poll() is None:
                return
            self.check_children()
            if now < (seg.inst.ended or now) + FUZZ_GAP_S:
                return
            seg.after = self.snapshot()
            self.close_segment(seg)
            self.segments.append(seg)
            self.fuzz_seg = None
        remaining = deadline - now - 5.0
        if self.router_down or remaining < 10.0 or self.stopping:
            return
        dur = min(self.args.fuzz_segment, remaining)
        index = len(self.segments) + 1
        before = self.snapshot()
        inst = self.start("fuzz", "fuzz", "--fleet", FLEET, "--kinds", FUZZ_KINDS, "--rate", str(self.args.fuzz_rate),
                          "--duration", f"{dur:.1f}", "--robots", ",".join(ROBOTS), "--seed", str(index),
                          *(("--cfg", "transport/shared_memory/enabled:false") if self.args.fuzz_no_shm else ()))
        self.fuzz_seg = Segment(index, inst, now, dur, before=before)

    def run(self) -> dict:
        args = self.args
        self.stopping = False
        self.machine = machine()
        busy0 = machine_busy_s()
        self_cpu0 = time.process_time()
        duration = args.minutes * 60.0
        plan = schedule(duration, kill_every_s=args.kill_every, blackout_every_s=args.blackout_every,
                        router_every_s=args.router_every, mission_every_s=args.mission_every)
        self.bring_up()
        deadline = self.t0 + duration
        for inj in plan:
            self.at(self.t0 + inj.t, lambda inj=inj: self.inject(inj))
        print(f"[soak] fleet up on {self.endpoint}; {len(plan)} injections planned over {args.minutes:g} min; "
              f"logs in {self.work / 'logs'}", file=sys.stderr, flush=True)
        next_sample, next_progress, next_final = self.t0, self.t0 + PROGRESS_S, self.t0 + 1.0
        fleet_cpu_dead = 0.0
        while True:
            now = time.time()
            while self.actions and self.actions[0][0] <= now:
                _, _, fn = heapq.heappop(self.actions)
                fn()
            self.check_children()
            if now >= deadline:
                self.stopping = True
            self.fuzz_tick(deadline)
            if now >= next_sample:
                self.sample()
                next_sample += SAMPLE_S
            if now >= next_final:
                self.tally.finalize(fault_windows(self.done), args.settle, 3.0, self.t0)
                next_final = now + 1.0
            if now >= next_progress:
                self.progress(now)
                next_progress += PROGRESS_S
            if self.stopping and self.fuzz_seg is None and not self.actions:
                break
            time.sleep(0.05)
        self.sample()
        end_t = time.time()
        loadavg_end = Path("/proc/loadavg").read_text().split()[:3]
        busy = machine_busy_s() - busy0
        time.sleep(3.5)
        self.tally.finalize(fault_windows(self.done), args.settle, 3.0, self.t0)
        self.stop_all()
        fleet_cpu = sum((i.last[2] - (i.earliest[2] if i.earliest else 0.0)) for i in self.instances
                        if i.last) + fleet_cpu_dead
        own = time.process_time() - self_cpu0
        others = max(0.0, busy - fleet_cpu - own) / max(1e-9, end_t - self.t0)
        return self.report(end_t, loadavg_end, others)

    def progress(self, now: float) -> None:
        c = Counter(d["kind"] for d in self.done)
        t = self.tally
        sent = sum(sum(s.sent.values()) for s in self.segments)
        print(f"[soak] {(now - self.t0) / 60:5.1f}/{self.args.minutes:g} min: injected {dict(c) or 'nothing yet'}; "
              f"frames seen {t.frames_seen}, states {sum(t.states_n.values())}; fuzz sent {sent} "
              f"({len(self.segments)} segments done); agreement outside faults {t.outside[1]}/{t.outside[0]}, "
              f"within {t.inside[1]}/{t.inside[0]}; contacts {t.contacts}; crashes {len(self.crashes)}",
              file=sys.stderr, flush=True)

    def stop_all(self) -> None:
        if "tracker" in self.current:
            try:
                self.current["tracker"].popen.send_signal(signal.SIGCONT)
            except ProcessLookupError:
                pass
        live = [i for i in self.instances if i.popen.poll() is None]
        for i in live:
            if i.name != "router":
                i.popen.send_signal(signal.SIGTERM)
        for i in live:
            if i.name == "router":
                continue
            try:
                i.rc = i.popen.wait(timeout=10)
            except subprocess.TimeoutExpired:
                i.popen.kill()
                i.rc = i.popen.wait()
            i.ended = i.ended or time.time()
        try:
            for s in self.subs:
                s.undeclare()
            self.session.close()
        except Exception:  # noqa: BLE001 - the report matters more than a clean close
            pass
        for i in live:
            if i.name == "router":
                i.popen.send_signal(signal.SIGTERM)
                try:
                    i.rc = i.popen.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    i.popen.kill()
                    i.rc = i.popen.wait()
                i.ended = i.ended or time.time()
        self.unclean = [{"process": i.name, "instance": i.index, "rc": i.rc} for i in live
                        if i.rc not in (0, 130, -signal.SIGINT, -signal.SIGTERM)]

    def report(self, end_t: float, loadavg_end, others: float) -> dict:
        t0 = self.t0
        insts = []
        for i in self.instances:
            if i.name == "fuzz":
                continue
            first = i.first or i.earliest
            insts.append({"name": i.name, "index": i.index, "started": i.started - t0,
                          "ended": None if i.ended is None or i.ended >= end_t else i.ended - t0,
                          "killed": i.killed, "rc": i.rc, "first_rss": first[1] if first else None,
                          "first_at": first[0] if first else None, "first_cpu": first[2] if first else None,
                          "first_states": first[3] if first else None, "first_after_warmup": i.first is not None,
                          "last_rss": i.last[1] if i.last else None, "last_at": i.last[0] if i.last else None,
                          "last_cpu": i.last[2] if i.last else None, "last_states": i.last[3] if i.last else None,
                          "first_anon": first[4] if first else None, "last_anon": i.last[4] if i.last else None,
                          "first_shmem": first[5] if first else None, "last_shmem": i.last[5] if i.last else None,
                          "last_shm_segments": i.last[6] if i.last else None,
                          "series": i.series})
        segs = []
        for s in self.segments:
            counted, why = {}, {}
            for rx in (*ROBOTS, "simfleet"):
                b, a = s.before.get(rx), s.after.get(rx)
                if b is None or a is None:
                    counted[rx], why[rx] = None, "no reading"
                elif b[0] != a[0]:
                    counted[rx], why[rx] = None, "the agent was killed and restarted in the segment"
                elif b[2] > 1.0 or a[2] > 1.0:
                    counted[rx], why[rx] = None, "no fresh reading at one end (no frames then: a blackout, a stall, or the agent down)"
                else:
                    counted[rx] = a[1] - b[1]
            end = s.inst.ended - t0 if s.inst.ended else None
            seg_end = (s.inst.ended or end_t) + FUZZ_GAP_S + 1.0
            outage = s.router_outage or any(d["kind"] == "router" and s.start - 1.0 <= d["start"] <= seg_end
                                            for d in self.done)
            segs.append({"index": s.index, "start": s.start - t0, "end": end, "sent": s.sent, "routed": s.routed,
                         "router_outage": outage, "counted": counted, "why": why, "rc": s.inst.rc})
        fuzz_time = sum((s.inst.ended or end_t) - s.start for s in self.segments)
        err = error_lines(self.work / "logs")
        t = self.tally
        rep = {
            "machine": self.machine, "loadavg_end": loadavg_end, "others_cores": others,
            "config": {"minutes": self.args.minutes, "kill_every_s": self.args.kill_every,
                       "blackout_every_s": self.args.blackout_every, "router_every_s": self.args.router_every,
                       "mission_every_s": self.args.mission_every, "settle_s": self.args.settle,
                       "fuzz_rate": self.args.fuzz_rate, "fuzz_segment_s": self.args.fuzz_segment,
                       "fuzz_no_shm": self.args.fuzz_no_shm,
                       "goals": self.goals, "scenario": SCENARIO.splitlines()[0]},
            "elapsed_s": end_t - t0,
            "injections": [{**d, "start": d["start"] - t0, "end": None if d["end"] is None else d["end"] - t0}
                           for d in self.done],
            "instances": insts,
            "rss": rss_rows(insts),
            "cpu": cpu_rows(insts),
            "segments": segs,
            "rejections": rejection_rows(segs),
            "fuzz": {"segments": len(segs), "sent": sum(sum(s["sent"].values()) for s in segs),
                     "coverage": fuzz_time / max(1e-9, end_t - t0),
                     "not_routed": [s["index"] for s in segs if s["routed"] is False]},
            "crashes": self.crashes,
            "unclean_stops": self.unclean,
            "contacts": {"frames": t.contacts, "truth_frames": t.truth_frames,
                         "min_gap_m": t.min_gap if math.isfinite(t.min_gap) else math.nan},
            "agreement": {"outside": {"frames": t.outside[0], "identical": t.outside[1]},
                          "inside": {"frames": t.inside[0], "identical": t.inside[1]},
                          "all3": t.all3, "skipped": t.skipped, "disagreements": t.disagreements},
            "frames_seen": t.frames_seen,
            "states": sum(t.states_n.values()),
            "events": dict(t.events),
            "event_log": t.event_log[:500],
            "moving_fraction": moving_fraction(t.centroids),
            "centroids": [(round(c[0] - t0, 1), round(c[1], 3), round(c[2], 3)) for c in t.centroids],
            "errors": err,
            "stop_lines": stop_lines(self.work / "logs"),
            "notes": [],
        }
        return rep


ERROR_LINE = re.compile(r"\bERROR\b|\bCRITICAL\b|^Traceback \(most recent call last\)")
ANSI = re.compile(r"\x1b\[[0-9;]*m")


def error_lines(logs: Path) -> dict:
    by_log: Counter = Counter()
    examples: list[str] = []
    for f in sorted(logs.glob("*.log")):
        for line in f.read_text(errors="replace").splitlines():
            plain = ANSI.sub("", line)
            if ERROR_LINE.search(plain):
                by_log[re.sub(r"\.\d+\.log$", "", f.name)] += 1
                if len(examples) < 40:
                    examples.append(f"{f.name}: {plain[:300]}")
    return {"count": sum(by_log.values()), "by_log": dict(by_log), "examples": examples}


STOP_LINE = re.compile(r"(simfleet stopping|agent \S+ stopping|tracker .*stopping).*")


def stop_lines(logs: Path) -> dict:
    """What each process that was stopped at the end said as it stopped (its counts), by log file."""
    out = {}
    for f in sorted(logs.glob("*.log")):
        if f.name.startswith("fuzz"):
            continue
        found = [m.group(0) for line in f.read_text(errors="replace").splitlines() if (m := STOP_LINE.search(line))]
        if found:
            out[f.name] = found[-1][:400]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--kill-every", type=float, default=120.0, help="an agent killed and restarted every [s]")
    ap.add_argument("--blackout-every", type=float, default=180.0, help="a 1 s tracker blackout every [s]")
    ap.add_argument("--router-every", type=float, default=600.0, help="a router restart every [s]")
    ap.add_argument("--mission-every", type=float, default=150.0, help="a new mission every [s]")
    ap.add_argument("--spread", type=float, default=5.5, help="the goals are this far either side of the origin [m]")
    ap.add_argument("--fuzz-rate", type=float, default=30.0, help="invalid messages per second per kind")
    ap.add_argument("--fuzz-segment", type=float, default=60.0, help="seconds per `vsfleet fuzz` run")
    ap.add_argument("--fuzz-no-shm", action="store_true",
                    help="the fuzzer without zenoh shared memory (its messages over 3 KiB then go by TCP, not SHM)")
    ap.add_argument("--settle", type=float, default=5.0,
                    help="frames this long after a fault ends are left out of the agreement [s]")
    ap.add_argument("--work", type=Path, default=RUNS / "soak",
                    help="soak.json, the scenario and the processes' logs (default: runs/bench/soak)")
    ap.add_argument("--render", type=Path, metavar="JSON", help="write the markdown from a run's soak.json; run nothing")
    add_output_flags(ap, "soak", DOCS / "bench" / "sections", "soak.md (and soak.json unless --docs)")
    args = ap.parse_args(argv)
    if args.render:
        rep = json.loads(args.render.read_text())
        rep["rss"] = rss_rows(rep["instances"])   # again, from the stored readings: with the growth after the warm-up
    else:
        work = args.work
        work.mkdir(parents=True, exist_ok=True)
        for old in (work / "logs").glob("*.log"):
            old.unlink()
        soak = Soak(args, work)
        try:
            rep = soak.run()
        finally:
            if soak.instances and any(i.popen.poll() is None for i in soak.instances):
                soak.stop_all()
        (work / "soak.json").write_text(json.dumps(rep, indent=1, default=str))
        print(f"[soak] written: {work / 'soak.json'}", file=sys.stderr)
    text = markdown(rep)
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "soak.md").write_text(text)
    if args.out.resolve() != (DOCS / "bench" / "sections").resolve() and not args.render:
        (args.out / "soak.json").write_text(json.dumps(rep, indent=1, default=str))
    print(f"[soak] written: {args.out / 'soak.md'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
