"""The structure step's records for the core's golden vectors (tests/golden_core.py).

The recorded frames of the agent step's golden vectors (tests/data/golden-step.json: the paper failure
scenario, noise, a robot missing now and then) packed as vs_golden.c's ``structure_step`` entry, for
each metric: every 4th frame, all robots used, and the same frames with r2 excluded and judged apart.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from golden_step import load
from vsfleet.step import core_mission, frame_arrays, mission_arrays

METRICS = ("l1", "l2", "linf")


def step_records() -> list[tuple[str, list[float]]]:
    mission, frames, config, _ = load()
    out = []
    for metric in METRICS:
        m = dataclasses.replace(mission, metric=metric)
        arrays = mission_arrays(m)
        tpl, wb, vmax, amax, code, kind, goal, limits = core_mission(metric, arrays.template, arrays.envelopes,
                                                                     arrays.goal, arrays.limits)
        n = len(arrays.ids)
        head = [float(n), float(code), float(kind), float(len(goal) // 3), *goal, *limits, *tpl.ravel(), *wb,
                *vmax, *amax]
        for k, (frame, _) in enumerate(frames):
            if k % 4:
                continue
            pose, seen, _fresh = frame_arrays(arrays.ids, frame.poses, frame.fresh)
            pose = np.where(seen[:, None], pose, 0.0)
            for excluded, judged in ((np.zeros(n), np.zeros(n)), (np.array([0.0, 1.0, 0.0]), np.zeros(n)),
                                     (np.zeros(n), np.array([0.0, 1.0, 0.0]))):
                out.append(("structure_step", [*head, *pose.ravel(), *seen.astype(float), *excluded, *judged,
                                               frame.t - m.effective_t, config.dt_s]))
    return out
