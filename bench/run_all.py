"""make bench: every benchmark, then benchmarks.md with tables, bench/*.png plots and img/ figures.

Run: .venv/bin/python -m bench.run_all [--quick] [--sections fit,precision,lf,latency,scale,figures]
     [--out DIR | --docs]

Sections: the fit against scipy Powell (bench/fit.py), precision against the
paper (bench/precision.py), virtual structure against leader-follower
(bench/leader_follower.py), loop latency with the Zenoh floor, and scale
(bench/loop.py); figures: Figs 9 and 10 (bench/precision.py) and 12
(bench/faults.py) again, into img/. Everything goes to runs/bench/docs/
(untracked), or --out DIR; ``make bench`` passes --docs: docs/benchmarks.md,
docs/bench/ and docs/img/, the one way the benchmarks refresh docs/. Progress
lines with ETAs go to stderr. ``--quick`` runs everything with far fewer frames
and seeds (for development); the document states the counts actually used.
Benchmarks print figures; nothing here is a test.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import json
import logging
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

from vsfleet.zglue.scenario_file import load_scenario
from vsfleet.wire import FrameMsg, encode_frame

from . import fit as fit_bench
from . import step as step_bench
from . import report
from .outputs import DOCS, add_output_flags
from .leader_follower import compare, tune
from .loop import percentiles_s, run_floor, run_loop

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "scenarios" / "paper-triangle.toml"
SECTIONS = ("fit", "precision", "lf", "latency", "scale", "figures")  # precision: against the paper (key "paper");
# the issue-13 precision and fault tables are bench/precision.py's and bench/faults.py's (sections precision,
# faults, kept as they were written); figures: their Figs 9, 10 and 12 (img/), drawn here again
LATENCY_CONFIGS = ((3, 30.0), (10, 30.0), (30, 30.0), (100, 30.0), (10, 100.0))
SWEEP_SIZES = ()   # besides the 30 Hz latency runs' sizes (none: those are the issue's)
STEP_SIZES = (3, 10, 100, 1000)
LF_DURATION_S, LF_FAULT_AT_S, LF_SEED = 45.0, 8.0, 2

FULL = dict(loop_frames=3_000, sweep_frames=900, precision_seeds=(1, 2, 3),
            floor=(("back to back", None, 10_000), ("at 30 Hz", 30.0, 2_000), ("at 100 Hz", 100.0, 3_000)))
QUICK = dict(loop_frames=300, sweep_frames=150, precision_seeds=(1,),
             floor=(("back to back", None, 1_000), ("at 30 Hz", 30.0, 150), ("at 100 Hz", 100.0, 300)))


class Progress:
    """Progress lines on stderr: elapsed time and an overall ETA from per-section estimates [s]."""

    def __init__(self, estimates_s: dict[str, float]) -> None:
        self.estimates = dict(estimates_s)
        self.t0 = time.monotonic()
        self.section: str | None = None
        self.section_t0 = self.t0

    def start(self, section: str) -> None:
        self.section, self.section_t0 = section, time.monotonic()

    def done(self, section: str) -> None:
        self.estimates.pop(section, None)
        self.section = None

    def log(self, msg: str) -> None:
        now = time.monotonic()
        left = sum(self.estimates.values())
        if self.section in self.estimates:
            left -= min(self.estimates[self.section], now - self.section_t0)
        print(f"[bench {now - self.t0:6.0f} s | ~{left / 60:.0f} min left] {msg}", file=sys.stderr, flush=True)


def estimates_s(cfg: dict, sections) -> dict[str, float]:
    loop = sum(cfg["loop_frames"] / hz + 10 + n for n, hz in LATENCY_CONFIGS) + 60
    floor = sum(c / r if r else c * 3e-4 for _, r, c in cfg["floor"]) + 10
    est = {"fit": 15.0, "precision": 100.0 * len(cfg["precision_seeds"]) + 20, "lf": 40.0,
           "latency": loop + floor, "scale": 3 * (cfg["sweep_frames"] / 30.0 + 15), "figures": 20.0}
    return {k: v for k, v in est.items() if k in sections}


def machine() -> dict:
    def first(path: str, prefix: str) -> str:
        try:
            for line in Path(path).read_text().splitlines():
                if line.startswith(prefix):
                    return line.split(":", 1)[1].strip()
        except OSError:
            pass
        return "?"

    def version(pkg: str) -> str:
        try:
            return importlib.metadata.version(pkg)
        except importlib.metadata.PackageNotFoundError:
            return "?"

    try:
        commit = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=ROOT, capture_output=True,
                                text=True, timeout=10).stdout.strip() or "?"
    except (OSError, subprocess.SubprocessError):
        commit = "?"
    mem_kib = first("/proc/meminfo", "MemTotal").split()[0]
    return {
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "cpu": first("/proc/cpuinfo", "model name"), "cores": os.cpu_count(),
        "memory_gib": round(int(mem_kib) / 2**20, 1) if mem_kib.isdigit() else "?",
        "os": f"{platform.system()} {platform.release()}", "python": platform.python_version(),
        "zenoh": version("eclipse-zenoh"), "numpy": version("numpy"), "scipy": version("scipy"),
        "commit": commit, "loadavg_start": Path("/proc/loadavg").read_text().split()[:3],
    }


def run_sweep(measured: dict[int, object], frames: int, log) -> list:
    """30 Hz runs of SWEEP_SIZES, ascending; a size is skipped once two smaller sizes failed."""
    out = []
    for n in SWEEP_SIZES:
        failed = [k for k, r in measured.items() if k < n and not r.nearly_holds]
        if len(failed) >= 2:
            log(f"[scale] skipping {n} agents: {sorted(failed)} already missed ticks")
            continue
        r = run_loop(n, 30.0, frames, log=log, label=f"scale {n} agents @30 Hz")
        log(f"[scale] {n} agents: missed {r.missed}, p99 {1e3 * percentiles_s(r.latency_s)['p99']:.1f} ms, "
            f"holds {r.holds}, with <= 0.1% missed {r.nearly_holds}")
        measured[n] = r
        out.append(r)
    return out


def summary_lines(res: dict) -> list[str]:
    out = []
    if "fit" in res:
        rows = res["fit"]
        slower = [f"{m} n={n} ({ratio:.1f}×)" for n, m, _, _, ratio, _, _ in rows if ratio < 1.0]
        costs = [r[6] / r[5] for r in rows if r[5] > 0]
        out.append(f"- **Fit** (time ratio Powell/ours): {min(r[4] for r in rows):.1f}–{max(r[4] for r in rows):.1f}× "
                   f"over n = 3…1000 and l1/l2/linf; "
                   + (f"ours is slower for {', '.join(slower)}" if slower else "ours is faster everywhere")
                   + f". Cost ratio Powell/ours {min(costs):.6f}–{max(costs):.4f}"
                   + (" (Powell never found a lower cost)." if min(costs) >= 1 - 1e-9 else "."))
    if "loops" in res:
        parts = []
        for r in res["loops"]:
            p = percentiles_s(r.latency_s)
            parts.append(f"{r.robots}@{r.rate_hz:.0f} Hz {1e3 * p['p50']:.1f}/{1e3 * p['p99']:.1f}/{1e3 * p['max']:.0f}")
        floor = {f.label: percentiles_s(f.rtt_s) for f in res["floors"]}
        out.append("- **Loop latency** p50/p99/max [ms]: " + "; ".join(parts) + ". Zenoh floor p50/p99: "
                   + ", ".join(f"{k} {1e3 * v['p50']:.2f}/{1e3 * v['p99']:.2f} ms" for k, v in floor.items())
                   + ". Frames every agent ran with bit-identical copies: "
                   + "; ".join(f"{r.robots}@{r.rate_hz:.0f} Hz {r.agreed_frames}/{r.all_ran_frames}"
                               for r in res["loops"]) + ".")
    if "step" in res:
        out.append("- **The agent step alone** (p50 CPU): "
                   + ", ".join(f"N = {r['n']}: {r['step_p50_us']:.0f} µs" for r in res["step"]) + ".")
    if "scale_runs" in res:
        best = report.largest_holding(res["scale_runs"])
        near = report.largest_holding(res["scale_runs"], strict=False)
        cpu = {r.robots: 1e3 * r.agent_cpu_s_per_answer.mean() for r in res["scale_runs"]}
        rss = [r.agent_rss_mib.mean() for r in res["scale_runs"]]
        out.append(f"- **Scale**: largest fleet holding 30 Hz with no missed tick: "
                   f"{best if best else 'none measured'} (with <= 0.1% missed: {near if near else 'none'}); "
                   f"CPU per agent per answered tick "
                   + ", ".join(f"{k}: {v:.1f} ms" for k, v in sorted(cpu.items()))
                   + f"; RSS per agent {min(rss):.0f}–{max(rss):.0f} MiB.")
    if "precision" in res:
        r = min(res["precision"], key=lambda r: r.mean_m)
        w = max(res["precision"], key=lambda r: r.max_m)
        out.append(f"- **Precision against the paper** (paper triangle): mean deviation {100 * min(x.mean_m for x in res['precision']):.2f}–"
                   f"{100 * max(x.mean_m for x in res['precision']):.2f} cm (best {r.controller}/{r.metric}), "
                   f"worst max {100 * w.max_m:.2f} cm ({w.controller}/{w.metric}); paper 0.783 / 0.318 / 2.5 cm.")
    if "lf" in res:
        broke = [(c, s.method) for c, _, _, a, b in res["lf"] for s in (a, b) if s.broke]
        out.append("- **Virtual structure vs leader–follower**: formation broke in "
                   + (", ".join(f"{c} ({m})" for c, m in broke) if broke else "no case") + ".")
    return out


def concurrency_note(res: dict) -> str:
    runs = list(res.get("loops", [])) + list(res.get("sweep", []))
    if not runs:
        return ""
    others = [r.others_cores for r in runs]
    mean, mx = sum(others) / len(others), max(others)
    if mx < 0.1:
        return "No other work was running on the machine during the loop runs (< 0.1 core busy)."
    return (f"**Other work was running on this machine concurrently** (other workers' test suites): during the "
            f"loop and scale runs, processes other than the benchmark kept on average {mean:.2f} and at most "
            f"{mx:.2f} of the {os.cpu_count()} cores busy (column *others* in §2–3). Latency, missed ticks and "
            f"the largest fleet are for what was left of the machine.")


SECTION_ORDER = ("fit", "latency", "scale", "precision", "faults", "paper", "lf")


def machine_line(m: dict, quick: bool, elapsed_s: float) -> str:
    return (f"*Measured on {m['date']} ({elapsed_s / 60:.0f} min{', --quick' if quick else ''}): {m['cpu']}, "
            f"{m['cores']} cores, {m['memory_gib']} GiB, {m['os']}; Python {m['python']}, eclipse-zenoh "
            f"{m['zenoh']}, numpy {m['numpy']}; code at `{m['commit']}`; load average at the start "
            f"{' '.join(m['loadavg_start'])}.*")


def write_doc(res: dict, cfg: dict, quick: bool, out: Path, elapsed_s: float) -> None:
    """Write the sections measured in this run to docs/bench/sections/, each with its machine and date,
    then assemble docs/benchmarks.md from every section file there (sections run earlier are kept)."""
    plots = out.parent / "bench"
    sections_dir = plots / "sections"
    sections_dir.mkdir(parents=True, exist_ok=True)
    m = res["machine"]
    stamp = machine_line(m, quick, elapsed_s)
    note = concurrency_note(res)
    scenario = load_scenario(PAPER)
    made: dict[str, str] = {}
    if "fit" in res:
        report.plot_fit(res["fit"], plots / "fit.png")
        made["fit"] = report.fit_section(res["fit"])
    if "loops" in res:
        report.plot_latency(res["loops"], res["floors"], plots / "latency.png")
        text = report.latency_section(res["loops"], res["floors"], cfg["loop_frames"])
        if "step" in res:
            text += "\n\n" + report.step_section(res["step"])
        made["latency"] = text
    if "scale_runs" in res:
        report.plot_scale(res["scale_runs"], plots / "scale.png")
        made["scale"] = report.scale_section(res["scale_runs"], pose_bytes=len(encode_frame(FrameMsg(
            t=time.time(), seq=123_456, src="sim", poses={"r001": (1.234567, -2.345678, 0.1234567)}))) - 20)
    if "precision" in res:
        report.plot_precision(res["precision"], plots / "precision.png")
        made["paper"] = report.precision_section(res["precision"], res["noise"], scenario,
                                                     cfg["precision_seeds"], scenario.duration_s)
    if "lf" in res:
        report.plot_leader_follower(res["lf"], scenario.mission, plots / "leader_follower.png")
        made["lf"] = report.lf_section(res["lf"], res["lf_tuning"], LF_DURATION_S, LF_FAULT_AT_S, LF_SEED)
    summary = summary_lines(res)
    for key, text in made.items():
        head, _, rest = text.partition("\n")
        body = "\n".join([head, "", stamp] + ([note] if note and key in ("latency", "scale") else []) + [rest])
        (sections_dir / f"{key}.md").write_text(body + "\n")
        mine = [line for line in summary if _summary_key(line) == key]
        (sections_dir / f"{key}.summary").write_text("\n".join(mine) + "\n")
    present = [k for k in SECTION_ORDER if (sections_dir / f"{k}.md").exists()]
    present += sorted(p.stem for p in sections_dir.glob("*.md") if p.stem not in SECTION_ORDER)
    parts = ["# Benchmarks", "",
             "Generated by `make bench` (`bench/run_all.py`; `--sections` re-runs some sections and keeps the "
             "others). Each section says when and on what machine it was measured. Benchmarks print figures; "
             "the tests never assert times.", "", "## Summary", ""]
    for k in present:
        summ = sections_dir / f"{k}.summary"
        if summ.exists():
            parts += [line for line in summ.read_text().splitlines() if line.strip()]
    parts.append("")
    for number, k in enumerate(present, 1):  # sections numbered in the order they stand
        text = re.sub(r"^## (\d+\. )?", f"## {number}. ", (sections_dir / f"{k}.md").read_text().rstrip("\n"))
        parts += [text, ""]
    out.write_text("\n".join(parts))
    old = {}
    results = plots / "results.json"
    if results.exists():
        try:
            old = json.loads(results.read_text())
        except ValueError:
            old = {}
    new = results_json(res)
    old.update({k: v for k, v in new.items() if k != "machine"})
    old.setdefault("machines", {}).update({k: new["machine"] for k in made})
    old.pop("machine", None)
    results.write_text(json.dumps(old, indent=1, default=str))


def _summary_key(line: str) -> str:
    """The section a summary line belongs to, from its bold label."""
    for label, key in (("**Fit**", "fit"), ("**Loop latency**", "latency"), ("**The agent step", "latency"),
                       ("**Scale**", "scale"), ("**Precision against the paper**", "paper"),
                       ("**Virtual structure vs leader", "lf")):
        if label in line:
            return key
    return "other"


def results_json(res: dict) -> dict:
    """The figures of the document, machine-readable (no raw samples)."""
    def loop(r):
        return {"robots": r.robots, "rate_hz": r.rate_hz, "frames": r.frames,
                "latency_s": percentiles_s(r.latency_s), "frame_latency_s": percentiles_s(r.frame_latency_s),
                "missed": r.missed, "late": r.late, "incomplete": r.incomplete, "states": r.states,
                "holds": r.holds, "agent_cpu_s_per_tick_mean": float(r.agent_cpu_s_per_tick.mean()),
                "agent_rss_mib_mean": float(r.agent_rss_mib.mean()),
                "agent_cpu_s_per_answer_mean": float(r.agent_cpu_s_per_answer.mean()),
                "nearly_holds": r.nearly_holds, "agreed_frames": r.agreed_frames,
                "all_ran_frames": r.all_ran_frames,
                "bench_cpu_s_per_frame": r.bench_cpu_s_per_frame, "others_cores": r.others_cores}
    out = {"machine": res["machine"]}
    if "fit" in res:
        out["fit"] = [dict(zip(("n", "metric", "ours_s", "powell_s", "time_ratio", "our_cost", "powell_cost"), r))
                      for r in res["fit"]]
    if "step" in res:
        out["step"] = res["step"]
    if "loops" in res:
        out["latency"] = [loop(r) for r in res["loops"]]
        out["floor"] = [{"label": f.label, "rate_hz": f.rate_hz, "rtt_s": percentiles_s(f.rtt_s), "lost": f.lost}
                        for f in res["floors"]]
    if "sweep" in res:
        out["scale_sweep"] = [loop(r) for r in res["sweep"]]
    if "precision" in res:
        out["precision"] = [r.__dict__ for r in res["precision"]]
        out["precision_noise"] = [r.__dict__ for r in res["noise"]]
    if "lf" in res:
        out["leader_follower"] = [s.__dict__ for _, _, _, a, b in res["lf"] for s in (a, b)]
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="bench.run_all", description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="few frames and seeds (development)")
    p.add_argument("--sections", default=",".join(SECTIONS), help=f"comma list of {', '.join(SECTIONS)}")
    add_output_flags(p, "docs", DOCS, "benchmarks.md, bench/ (plots, sections, results.json) and img/ (figures)")
    args = p.parse_args(argv)
    sections = [s for s in args.sections.split(",") if s]
    unknown = set(sections) - set(SECTIONS)
    if unknown:
        p.error(f"unknown sections {sorted(unknown)}")
    logging.basicConfig(level=logging.ERROR)  # the offline agents log every failure-policy decision
    cfg = QUICK if args.quick else FULL
    prog = Progress(estimates_s(cfg, sections))
    res: dict = {"machine": machine()}
    t0 = time.monotonic()
    scenario = load_scenario(PAPER)

    if "fit" in sections:
        prog.start("fit")
        res["fit"] = fit_bench.measure(log=prog.log)
        prog.done("fit")
    if "precision" in sections:
        from .precision import noise_sweep, precision_table
        prog.start("precision")
        res["precision"] = precision_table(scenario, seeds=cfg["precision_seeds"], log=prog.log)
        res["noise"] = noise_sweep(scenario, "arc", "linf", seeds=cfg["precision_seeds"][:1], log=prog.log)
        prog.done("precision")
    if "lf" in sections:
        prog.start("lf")
        prog.log("[leader-follower] tuning the baseline")
        res["lf_tuning"] = tune(scenario, LF_DURATION_S, seed=LF_SEED)
        res["lf"] = compare(scenario, LF_DURATION_S, LF_FAULT_AT_S, seed=LF_SEED, log=prog.log)
        prog.done("lf")
    if "latency" in sections:
        prog.start("latency")
        prog.log("[step] the agent step alone")
        res["step"] = [step_bench.time_step(n, 300 if n < 1000 else 100, paced=90) for n in STEP_SIZES]
        prog.log("[floor] zenoh ping-pong")
        res["floors"] = run_floor(list(cfg["floor"]), log=prog.log)
        res["loops"] = []
        for n, hz in LATENCY_CONFIGS:
            r = run_loop(n, hz, cfg["loop_frames"], log=prog.log, label=f"latency {n} agents @{hz:.0f} Hz")
            pc = percentiles_s(r.latency_s)
            prog.log(f"[latency {n} agents @{hz:.0f} Hz] p50 {1e3 * pc['p50']:.2f} ms, p99 {1e3 * pc['p99']:.2f} ms, "
                     f"max {1e3 * pc['max']:.1f} ms, missed {r.missed}")
            res["loops"].append(r)
        prog.done("latency")
    if "scale" in sections:
        prog.start("scale")
        measured = {r.robots: r for r in res.get("loops", []) if r.rate_hz == 30.0}
        res["sweep"] = run_sweep(measured, cfg["sweep_frames"], prog.log)
        res["scale_runs"] = list(measured.values())
        prog.done("scale")
    out = args.out / "benchmarks.md"
    if "figures" in sections:
        from .faults import fig12
        from .precision import figures
        prog.start("figures")
        for path in (*figures(args.out / "img"), fig12(args.out / "img")):
            prog.log(f"[figures] {path}")
        prog.done("figures")
    write_doc(res, cfg, args.quick, out, time.monotonic() - t0)
    prog.log(f"wrote {out} and {out.parent / 'bench'}/*.png")
    for line in summary_lines(res):
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
