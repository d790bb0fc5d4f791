"""Per-robot dict reference of the failure rule (the code vsfleet.failure's arrays replaced); tests only.

The rule itself, the assembly phase included, is stated once, in vsfleet.failure's docstring; this module
implements the same rule robot by robot, so that tests can compare the two on random frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

from vsfleet import failure
from vsfleet.coreconst import FAILURE_SETTLED_RATIO


# The policy, health and decision types are the array code's own (only the rule is re-implemented here).
FailurePolicy, Health, Decision = failure.FailurePolicy, failure.Health, failure.Decision


@dataclass(frozen=True)
class Motion:
    """Per robot: the last frame's (t, x, y, expected dx, expected dy) and a window of
    (t, expected dx, expected dy, observed dx, observed dy) [s, m; world] per frame."""

    last: dict[str, tuple[float, float, float, float, float]] = field(default_factory=dict)
    window: dict[str, tuple[tuple[float, float, float, float, float], ...]] = field(default_factory=dict)


def update_motion(policy: FailurePolicy, motion: Motion, poses: Mapping[str, tuple[float, float, float]],
                  expected_next_m: Mapping[str, tuple[float, float]], t: float,
                  step_s: float | None = None, max_gap_s: float = math.inf,
                  deviations_m: Mapping[str, float] | None = None
                  ) -> tuple[Motion, dict[str, float], set[str]]:
    """Record this frame's observed motion; return each robot's progress ratio where known, and the
    robots that approach their points (the assembly phase).

    poses: robot -> (x, y, th) [m, rad] in this frame; expected_next_m: robot -> the
    displacement [m; world] its predicted command should produce by the next frame.
    Over the window the net expected displacement E (vector sum) is compared with the
    net observed one projected on it: ratio = (sum observed . E) / |E|^2. Net sums make
    the test blind to dithering and to a frame of command latency. A ratio is reported
    once the window spans 80% of fail_after_s and |E| reaches min_expected_m.

    With step_s (the time [s] expected_next_m is for), each expected step is scaled to
    the time that actually passed to the next frame, capped at max_gap_s (a command's
    ttl: after it the robot halts). An agent that missed a frame then sums nearly the
    same expectation as one that saw it, so their decisions fall on the same frame.

    deviations_m: each robot's deviation [m] in this frame, kept with its window item; a robot
    approaches when, over a window spanning 80% of fail_after_s, its deviation shrank by more than
    min_approach_m (from the window's oldest item to this frame).
    """
    deviations_m = deviations_m or {}
    last, window, ratios, approaching = dict(motion.last), dict(motion.window), {}, set()
    for r, (x, y, _th) in poses.items():
        if r in last:
            t0, x0, y0, ex, ey = last[r]
            if step_s is not None:
                scale = min(t - t0, max_gap_s) / step_s
                ex, ey = ex * scale, ey * scale
            w = tuple(item for item in window.get(r, ()) if item[0] > t - policy.fail_after_s)
            d = deviations_m.get(r, math.inf)
            w += ((t, ex, ey, x - x0, y - y0, d),)
            window[r] = w
            sx = math.fsum(item[1] for item in w)
            sy = math.fsum(item[2] for item in w)
            e2 = sx * sx + sy * sy
            settled = t - w[0][0] >= FAILURE_SETTLED_RATIO * policy.fail_after_s
            if settled and math.isfinite(d) and w[0][5] - d > policy.min_approach_m:
                approaching.add(r)
            if settled and e2 >= policy.min_expected_m ** 2:
                ox = math.fsum(item[3] for item in w)
                oy = math.fsum(item[4] for item in w)
                ratios[r] = (ox * sx + oy * sy) / e2
        ex, ey = expected_next_m.get(r, (0.0, 0.0))
        last[r] = (t, x, y, ex, ey)
    return Motion(last, window), ratios, approaching


def update_health(policy: FailurePolicy, health: Health, deviations_m: Mapping[str, float],
                  robots: tuple[str, ...], t: float,
                  progress: Mapping[str, float] | None = None,
                  on_way: set[str] | None = None) -> tuple[Health, list[Decision]]:
    """Advance the failure state by one frame at tracker time t [s].

    deviations_m: each seen robot's distance [m] to its structure point; robots of
    ``robots`` absent from it were not seen in this frame. progress: each robot's
    progress ratio from :func:`update_motion`, where known. on_way: the seen robots in the assembly
    phase (approaching, from :func:`update_motion`, or held back by the safety filter): the deviation
    test does not judge them.
    """
    progress = progress or {}
    on_way = on_way or set()
    since = dict(health.since_t)
    failed, dropped = set(health.failed), set(health.dropped)
    decisions: list[Decision] = []
    in_fit = [deviations_m[r] for r in robots if r not in dropped and r in deviations_m]
    structure_off = len(in_fit) >= 2 and min(in_fit) > policy.fail_deviation_m
    for r in robots:
        d = deviations_m.get(r, math.inf)
        if r in dropped:
            if policy.mode != "rejoin":
                continue
            if d <= policy.rejoin_deviation_m:
                start = since.setdefault(r, t)
                if t - start >= policy.rejoin_after_s:
                    dropped.discard(r)
                    failed.discard(r)
                    since.pop(r, None)
                    decisions.append(Decision(t, r, "rejoin", d))
            else:
                since.pop(r, None)
            continue
        stuck = progress.get(r, 1.0) < policy.min_progress_ratio
        off = (d > policy.fail_deviation_m and not (structure_off and math.isfinite(d))
               and not (r in on_way and math.isfinite(d)))
        complies = not (off or stuck)
        if r in failed:  # hold: healthy again once it has complied for recover_after_s
            if not complies:
                since.pop(r, None)
            elif t - since.setdefault(r, t) >= policy.recover_after_s:
                failed.discard(r)
                since.pop(r, None)
                decisions.append(Decision(t, r, "recover", d))
            continue
        if not complies:
            start = since.setdefault(r, t - (policy.fail_after_s if stuck else 0.0))
            if t - start >= policy.fail_after_s:
                failed.add(r)
                since.pop(r, None)  # from now on: since when it complies (recover, rejoin)
                decisions.append(Decision(t, r, "fail", d))
                if policy.mode in ("drop", "rejoin"):
                    dropped.add(r)
                    decisions.append(Decision(t, r, "drop", d))
        else:
            since.pop(r, None)
    return Health(since, frozenset(failed), frozenset(dropped)), decisions
