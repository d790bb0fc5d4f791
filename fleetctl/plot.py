"""vsfleet plot FILE.mcap: the paper's figures from a recording, as PNG files (matplotlib, Agg).

* ``trajectories.png`` — each robot's path (from truth, else from the tracker's
  poses), the structure's path (an agent's fitted pose) with its outline at the
  start and the end, and the goal (cf. Tan & Lewis, Figure 9); in a room, the
  mission's obstacles as filled circles and each robot's body as a circle of
  its radius at its first and last position;
* ``deviation.png`` — each robot's distance from the structure fitted to the
  true positions, over time, with mean, sigma and max (Figure 10);
* ``fault.png`` — the same deviation around the first fault, the fault time
  marked (Figure 12). Faults come from ``fault/<robot>`` messages, from
  ``event`` messages that describe a fault, or from a scenario's fault
  timeline (``--scenario``; ``vsfleet run`` passes its own). Without fault
  information this figure is skipped, and the program says so.

The figure functions return matplotlib Figures (no pyplot, no global backend).
"""

from __future__ import annotations

import argparse
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import msgpack
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Polygon
from mcap.exceptions import McapError

from vsfleet.analysis import fitted_truth, truth_frames
from vsfleet.geometry import Pose2
from vsfleet.step import mission_arrays, planned_way, shape_name
from vsfleet.wire import (
    Mission,
    PoseMsg,
    StateMsg,
    TruthMsg,
    WireError,
    decode_fault,
    decode_mission,
    decode_pose,
    decode_state,
    decode_truth,
)
from vsfleet.zglue.program import common_flags

from .foxglove_views import swept_poses
from .record import RAW, LogRecord, read_log, split_key, structure_points

log = logging.getLogger("vsfleet.plot")

MAX_FIT_FRAMES = 2000          # truth frames fitted for the deviation plots (evenly thinned beyond)
FAULT_BEFORE_S = 5.0
FAULT_AFTER_S = 15.0


@dataclass(frozen=True)
class FaultMark:
    """A fault at t_s [s, UNIX; tracker clock] on ``robot`` (may be '' if unknown)."""

    t_s: float
    robot: str
    kind: str
    source: str  # "fault message", "event" or "scenario"


@dataclass
class RunData:
    """The decoded messages of one fleet in a log, by robot, in receive order."""

    fleet: str
    mission: Mission | None = None
    truth: dict[str, list[TruthMsg]] = field(default_factory=dict)
    pose: dict[str, list[PoseMsg]] = field(default_factory=dict)
    state: dict[str, list[StateMsg]] = field(default_factory=dict)
    faults: list[FaultMark] = field(default_factory=list)
    first_t_s: float = math.nan

    @property
    def t0_s(self) -> float:
        """Time origin of the plots: the first truth time, else the first pose, else the first message."""
        if self.truth:
            return min(m[0].t for m in self.truth.values())
        if self.pose:
            return min(m[0].t for m in self.pose.values())
        return self.first_t_s

    @property
    def robots(self) -> list[str]:
        if self.mission is not None:
            return list(self.mission.robot_ids)
        return sorted(set(self.truth) | set(self.pose) | set(self.state))


def fleets_in(records: Iterable[LogRecord]) -> list[str]:
    return sorted({p[0] for r in records if r.role == RAW and (p := split_key(r.key)) is not None})


def fault_from_event(m: dict, t_default_s: float) -> FaultMark | None:
    """An event map that describes a fault: one of kind/event/type is 'fault' (or it has a 'fault' field)."""
    if not isinstance(m, dict):
        return None
    tagged = any(m.get(f) == "fault" for f in ("kind", "event", "type"))
    if not tagged and "fault" not in m:
        return None
    what = m.get("fault") if isinstance(m.get("fault"), str) else m.get("fault_kind", "fault")
    if what == "none":
        return None
    t = m.get("t")
    t_s = float(t) if isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t) else t_default_s
    robot = m.get("robot") if isinstance(m.get("robot"), str) else ""
    return FaultMark(t_s, robot, str(what), "event")


def extract(records: Iterable[LogRecord], fleet: str | None = None) -> RunData:
    """Decode one fleet's messages (the only fleet in the log when ``fleet`` is None)."""
    records = [r for r in records if r.role == RAW]
    if fleet is None:
        fleets = fleets_in(records)
        if len(fleets) > 1:
            raise ValueError(f"the log holds several fleets {fleets}; choose one with --fleet")
        fleet = fleets[0] if fleets else "demo"
    data = RunData(fleet)
    if records:
        data.first_t_s = records[0].publish_time_ns * 1e-9
    for rec in records:
        parts = split_key(rec.key)
        if parts is None or parts[0] != fleet:
            continue
        _, kind, robot = parts
        try:
            if kind == "truth" and robot:
                data.truth.setdefault(robot, []).append(decode_truth(rec.payload))
            elif kind == "pose" and robot:
                data.pose.setdefault(robot, []).append(decode_pose(rec.payload))
            elif kind == "state" and robot:
                data.state.setdefault(robot, []).append(decode_state(rec.payload))
            elif kind == "mission" and robot is None:
                data.mission = decode_mission(rec.payload)
            elif kind == "fault" and robot:
                f = decode_fault(rec.payload)
                if f.kind != "none":
                    data.faults.append(FaultMark(rec.publish_time_ns * 1e-9, robot, f.kind, "fault message"))
            elif kind == "event" and robot:  # event/<deciding agent's robot>
                mark = fault_from_event(msgpack.unpackb(rec.payload, raw=False, strict_map_key=False),
                                        rec.publish_time_ns * 1e-9)
                if mark is not None:
                    data.faults.append(mark)
        except (WireError, ValueError, TypeError):
            continue  # a bad message is not plotted
    data.faults.sort(key=lambda f: f.t_s)
    return data


def add_timeline(data: RunData, timeline: Sequence) -> None:
    """Add a scenario's faults (``at_s`` after the simulation starts, i.e. after the first truth)."""
    if not data.truth:
        return
    t0 = data.t0_s
    for ev in timeline:
        if ev.kind != "none":
            data.faults.append(FaultMark(t0 + ev.at_s, ev.robot, ev.kind, "scenario"))
    data.faults.sort(key=lambda f: f.t_s)


def deviations(data: RunData, max_frames: int = MAX_FIT_FRAMES):
    """(t [s], {robot: deviation [m]}) per truth frame fitted with the mission (thinned to max_frames)."""
    if data.mission is None or not data.truth:
        return []
    frames = truth_frames((r, m) for r, msgs in data.truth.items() for m in msgs)
    stride = max(1, math.ceil(len(frames) / max_frames))
    return [(t, dev) for t, _pose, dev in fitted_truth(data.mission, frames[::stride])]


def _canvas(fig: Figure) -> Figure:
    FigureCanvasAgg(fig)
    return fig


# ---------------------------------------------------------------- figures


def draw_plan(ax, mission: Mission, states: list[StateMsg], spacing_m: float = 0.15) -> None:
    """The room's plan from the structure's first fitted pose (vsfleet.step.planned_way: what the field of the
    shape it has there gives), and again from each state whose shape differs from the one before (a reshape:
    that shape's field from there); the robots' bodies, in the shape planned for, swept along each plan every
    ``spacing_m`` [m] of the way. states: one agent's state messages, in order."""
    t0 = states[0].t
    starts = [m for k, m in enumerate(states) if k == 0 or m.shape != states[k - 1].shape]
    colours = ("tab:green", "tab:purple", "tab:olive", "tab:cyan")
    for k, first in enumerate(starts):
        planned = planned_way(mission, Pose2(first.x, first.y, first.th), shape=first.shape)
        if planned is None:
            continue
        way, blocked = planned
        colour = colours[k % len(colours)]
        label = "plan from the start" if k == 0 else f"plan from {first.t - t0:.1f} s"
        if first.shape:
            label += f" ({shape_name(mission_arrays(mission), first.shape)})"
        ax.plot(way[:, 0], way[:, 1], color=colour, lw=1.0, alpha=0.9,
                label=label + (" (blocked: to the closest safe pose)" if blocked else ""))
        for x, y, th in swept_poses(way, spacing_m):
            for point, r in zip(structure_points(mission, x, y, th, first.shape), mission.radii):
                ax.add_patch(Circle((point[0], point[1]), max(r, 0.005), fill=False, ec=colour, alpha=0.25,
                                    lw=0.6, zorder=2, gid="swept body"))


def trajectory_figure(data: RunData) -> Figure:
    """Figure 9: robots' paths (truth, else pose), the structure's path and outlines, the goal."""
    fig = _canvas(Figure(figsize=(7.5, 6.5)))
    ax = fig.add_subplot()
    source = "truth" if data.truth else "tracker poses"
    series = data.truth if data.truth else data.pose
    for r in data.robots:
        msgs = series.get(r, [])
        if not msgs:
            continue
        xs, ys = [m.x for m in msgs], [m.y for m in msgs]
        (line,) = ax.plot(xs, ys, lw=1.4, label=r)
        ax.scatter([xs[0]], [ys[0]], s=18, color=line.get_color(), zorder=3)
        radius = data.mission.spec(r).radius if data.mission is not None and r in data.mission.robot_ids else None
        if radius is not None:  # its body where it starts and where it ends
            for x, y in ((xs[0], ys[0]), (xs[-1], ys[-1])):
                ax.add_patch(Circle((x, y), radius, fill=False, ec=line.get_color(), lw=0.9, zorder=3,
                                    gid=f"body {r}"))
    if data.state:
        agent = max(data.state, key=lambda a: len(data.state[a]))
        st = data.state[agent]
        ax.plot([m.x for m in st], [m.y for m in st], ls="--", lw=1.2, color="0.3",
                label=f"structure (agent {agent})")
        if data.mission is not None:
            for m, style in ((st[0], ":"), (st[-1], "-")):
                pts = [(p[0], p[1]) for p in structure_points(data.mission, m.x, m.y, m.th, m.shape)]
                ax.add_patch(Polygon(pts, closed=True, fill=False, ec="0.45", ls=style, lw=1.0))
    if data.mission is not None and data.state:
        draw_plan(ax, data.mission, data.state[max(data.state, key=lambda a: len(data.state[a]))])
    if data.mission is not None:
        for i, (x, y, r) in enumerate(data.mission.obstacles):
            ax.add_patch(Circle((x, y), r, fc="0.55", ec="0.25", alpha=0.6, lw=0.8, zorder=1, gid=f"obstacle {i}",
                                label="obstacles" if i == 0 else None))
        goal = data.mission.goal or (data.mission.path[-1] if data.mission.path else None)
        if data.mission.path:
            ax.plot([w[0] for w in data.mission.path], [w[1] for w in data.mission.path], ls=":",
                    color="tab:red", lw=1.0, label="path")
        if goal is not None:
            ax.plot([goal[0]], [goal[1]], marker="*", ms=14, ls="none", color="tab:red", label="goal")
            ax.annotate("", xy=(goal[0] + 0.08 * math.cos(goal[2]), goal[1] + 0.08 * math.sin(goal[2])),
                        xytext=(goal[0], goal[1]), arrowprops=dict(arrowstyle="->", color="tab:red"))
            pts = [(p[0], p[1]) for p in structure_points(data.mission, *goal)]
            ax.add_patch(Polygon(pts, closed=True, fill=False, ec="tab:red", ls="--", lw=0.8))
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.set_title(f"fleet {data.fleet}: trajectories ({source}); structure dotted at start, solid at end")
    ax.legend(loc="best", fontsize="small")
    return fig


def deviation_figure(data: RunData) -> Figure | None:
    """Figure 10: each robot's deviation from the truth-fitted structure, with mean, sigma, max.

    Without a mission in the log the agents' own ``err`` (from tracker poses) is
    plotted instead; None when neither is there.
    """
    dev = deviations(data)
    t0 = data.t0_s
    fig = _canvas(Figure(figsize=(8.5, 4.8)))
    ax = fig.add_subplot()
    if dev:
        ts = np.array([t for t, _ in dev]) - t0
        series = {r: np.array([d[r] for _, d in dev]) for r in data.robots}
        what = "distance to the structure fitted to true positions"
    elif data.state:
        series = {r: np.array([m.err for m in data.state[r]]) for r in sorted(data.state)}
        ts = None
        what = "agents' err (tracker poses; no mission in the log)"
    else:
        return None
    for r, d in series.items():
        t = ts if ts is not None else np.array([m.t for m in data.state[r]]) - t0
        ax.plot(t, 100 * d, lw=1.0, label=f"{r}: mean {100 * d.mean():.2f} cm, "
                f"\u03c3 {100 * d.std():.2f} cm, max {100 * d.max():.2f} cm")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("deviation from structure [cm]")
    ax.set_title(f"fleet {data.fleet}: {what}")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right", fontsize="small")
    return fig


def fault_figure(data: RunData) -> Figure | None:
    """Figure 12: deviation per robot around the first fault, the fault time marked; None without one."""
    dev = deviations(data)
    if not data.faults or not dev:
        return None
    ts = np.array([t for t, _ in dev])
    fault = next((f for f in data.faults if ts[0] <= f.t_s <= ts[-1]), None)
    if fault is None:
        return None
    keep = (ts >= fault.t_s - FAULT_BEFORE_S) & (ts <= fault.t_s + FAULT_AFTER_S)
    t0 = data.t0_s
    fig = _canvas(Figure(figsize=(8.5, 4.8)))
    ax = fig.add_subplot()
    for r in data.robots:
        d = np.array([x[r] for _, x in dev])[keep]
        ax.plot(ts[keep] - t0, 100 * d, lw=1.0, label=r)
    who = f"{fault.robot} " if fault.robot else ""
    ax.axvline(fault.t_s - t0, color="tab:red", ls="--", lw=1.2,
               label=f"fault: {who}{fault.kind} at {fault.t_s - t0:.2f} s ({fault.source})")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("deviation from structure [cm]")
    ax.set_title(f"fleet {data.fleet}: formation error around a fault")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", fontsize="small")
    return fig


@dataclass(frozen=True)
class PlotResult:
    written: list[Path]
    notes: list[str]


def write_plots(data: RunData, out_dir: str | Path, dpi: int = 120) -> PlotResult:
    """Write trajectories.png, deviation.png and (with fault information) fault.png into out_dir."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written, notes = [], []
    if not (data.truth or data.pose):
        notes.append(f"no truth or pose messages for fleet {data.fleet}: nothing to plot")
        return PlotResult(written, notes)
    figures = [("trajectories.png", trajectory_figure(data)), ("deviation.png", deviation_figure(data))]
    if figures[1][1] is None:
        notes.append("no truth with a mission nor agent state in the log: deviation.png skipped")
    if data.mission is None:
        notes.append("no mission in the log: deviation from truth cannot be fitted")
    fault = fault_figure(data)
    if fault is None and not data.faults:
        notes.append("no fault information (fault/<robot>, a fault event or a scenario timeline): "
                     "fault.png skipped")
    elif fault is None:
        notes.append("no fault within the fitted truth (a mission and truth are needed): fault.png skipped")
    figures.append(("fault.png", fault))
    for name, fig in figures:
        if fig is not None:
            fig.savefig(out / name, dpi=dpi)
            written.append(out / name)
    return PlotResult(written, notes)


def plot_file(path: str | Path, out_dir: str | Path | None = None, fleet: str | None = None,
              timeline: Sequence = ()) -> PlotResult:
    data = extract(read_log(path, roles=(RAW,)), fleet)
    add_timeline(data, timeline)
    return write_plots(data, Path(path).parent if out_dir is None else out_dir)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet plot", description=__doc__.splitlines()[0])
    p.add_argument("file", help="MCAP file written by vsfleet record or vsfleet run")
    p.add_argument("--out", default=None, help="directory for the PNGs (default: the file's directory)")
    p.add_argument("--fleet", default=None, help="the fleet to plot, if the log holds several")
    p.add_argument("--scenario", default=None,
                   help="scenario TOML whose fault timeline marks faults not in the log")
    return common_flags(p, zenoh=False)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)  # not under @program: its lines are plain, for an operator
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(message)s")
    try:
        timeline = ()
        if args.scenario:
            from vsfleet.zglue.scenario_file import load_scenario
            timeline = load_scenario(args.scenario).faults
        result = plot_file(args.file, args.out, args.fleet, timeline)
    except (OSError, ValueError, McapError) as exc:
        log.error("%s", exc)
        return 2
    for note in result.notes:
        print(note)
    for path in result.written:
        print(f"wrote {path}")
    return 0 if result.written else 1


if __name__ == "__main__":
    raise SystemExit(main())
