"""simfleet's own account of each robot's commands, read from its log.

simfleet logs ``<robot>: command expired at t=...`` when a robot's command runs out of ttl
and ``<robot>: commanded again at t=...`` when a fresh one arrives, on its own clock.
"""

from __future__ import annotations

import re
import threading
import time
from pathlib import Path

EVENT = re.compile(r"([A-Za-z0-9_-]+): (command expired|commanded again) at t=(\d+\.\d{3}) \(")


def command_events(log_text: str) -> dict[str, list[tuple[float, bool]]]:
    """{robot: [(t, commanded?), ...]} in log order."""
    out: dict[str, list[tuple[float, bool]]] = {}
    for robot, what, t in EVENT.findall(log_text):
        out.setdefault(robot, []).append((float(t), what == "commanded again"))
    return out


def halts(log_text: str, after_t: float, ttl_s: float | None = None) -> dict[str, float]:
    """Each robot's halt in force after ``after_t``: the expiry of the command it was running on.

    A robot still commanded at ``after_t`` halts at its first expiry after it. A robot whose
    command had already expired (its agent starved of CPU just before, say) and which was not
    commanded again halted at that expiry, returned as it is (t <= after_t), if that was at
    most ``ttl_s`` before (any time, with None). Robots with neither are absent.
    """
    out: dict[str, float] = {}
    for robot, evs in command_events(log_text).items():
        before = [(t, commanded) for t, commanded in evs if t <= after_t]
        if before and not before[-1][1]:
            if ttl_s is None or before[-1][0] >= after_t - ttl_s:
                out[robot] = before[-1][0]
            continue
        first = next((t for t, commanded in evs if t > after_t and not commanded), None)
        if first is not None:
            out[robot] = first
    return out


def wait_halts(log: Path, after_t: float, ttl_s: float, robots, timeout_s: float) -> dict[str, float]:
    """Wait until :func:`halts` covers every one of ``robots``; TimeoutError names the rest."""
    deadline = time.monotonic() + timeout_s
    retry = threading.Event()
    while True:
        found = halts(log.read_text(errors="replace"), after_t, ttl_s)
        if set(robots) <= set(found):
            return found
        if time.monotonic() > deadline:
            raise TimeoutError(f"simfleet did not halt {sorted(set(robots) - set(found))} within {timeout_s} s")
        retry.wait(0.05)
