"""The golden vectors of the agent's whole step (vs_golden.c's ``agent_step``, tests/data/golden-core.txt) tied to
the readable step: each record's frames, run through vsfleet.step.agent_step from the same start
  - on the Python glue (the structures shared between agents, so the frame goes through the numpy glue of
    vsfleet.step over the core's kernels, not through vs_agent_step) give the recorded outputs bit for bit: the
    structure, the command, the deviations, the decisions, the room's events and the state after the last frame;
  - on the numpy reference (StepConfig(reference=True)) give the same decisions, events, shapes and robots used,
    and numbers within REFERENCE_TOL: the reference computes its trigonometry with numpy's (libm's), the core with
    its own kernels (vs_math.c), so their last bits differ (tests/test_core_step.py holds them within 1e-9; over
    these runs the commands differ by up to 9e-9 m/s, the precision controller's and arc's most).

tests/test_core_golden.py replays the same records through the binding and the plain C driver (-O0/-O2/-O3,
aarch64 under qemu); the records come from tests/step_core_records.py (AGENT_RUNS: real scenarios offline).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import vsfleet.agentcore as agentcore
import vsfleet.step as step  # noqa: E402
from golden_core import PATH, read  # noqa: E402
from step_core_records import AGENT_RUNS, agent_run_frames, agent_step_inputs  # noqa: E402
from vsfleet.coreconst import DECISION_KINDS  # noqa: E402
from vsfleet.step import AgentState, agent_step  # noqa: E402

RECORDS = [(i, o) for e, i, o in read(PATH) if e == "agent_step"]
#: the numpy reference against the core [m, rad, m/s, m of cost]
REFERENCE_TOL = 2e-8
#: the 12 scalars end the packed state: stall_watch, then the pose where the watch began (x, y, th)
STALL_WATCH, STALL_POSE = -7, slice(-6, -3)


def hexes(values) -> list[str]:
    """Bits as text, NaN as one (the golden entry writes +NaN)."""
    return [float("nan").hex() if math.isnan(v) else float(v).hex() for v in values]


def frame_outputs(outs: list[float], n: int, frames: int) -> tuple[list, list[float]]:
    """The recorded outputs split per frame (vs_golden.c's g_agent_step), and the final state."""
    per, k = [], 0
    for _ in range(frames):
        ran, resynced = outs[k], outs[k + 1]
        k += 2
        if not ran:
            per.append({"ran": 0.0, "resynced": resynced})
            continue
        head = outs[k:k + 21]
        used, dev = outs[k + 21:k + 21 + n], outs[k + 21 + n:k + 21 + 2 * n]
        k += 21 + 2 * n
        d = int(outs[k])
        decisions = [outs[k + 1 + 4 * j:k + 5 + 4 * j] for j in range(d)]
        k += 1 + 4 * d
        per.append({"ran": 1.0, "resynced": resynced, "head": head, "used": used, "dev": dev,
                    "decisions": decisions})
    return per, outs[k:]


@functools.lru_cache(maxsize=None)
def run_frames(k: int):
    return agent_run_frames(AGENT_RUNS[k])


def step_outputs(robot, config, warm, record, run_with, warm_with=None) -> tuple[list, list[float]]:
    """The same frames through vsfleet.step.agent_step on the StepConfig run_with, in the golden entry's terms; the
    frames before the record on warm_with (None: run_with)."""
    ref = run_with
    state = AgentState(robot=robot)
    for m, frame, now_s in warm:
        state, _ = agent_step(state, m, frame, now_s, warm_with or ref)
    per = []
    for m, frame, now_s in record:
        before = state.shape
        state, out = agent_step(state, m, frame, now_s, ref)
        resynced = float(any("no frame for" in note.text for note in out.notes))
        s = out.structure
        if s is None:
            per.append({"ran": 0.0, "resynced": resynced})
            continue
        ids = state.ids
        room = [e for e in out.events if e.kind in ("blocked", "unblocked")]
        event, event_dev = (0.0, 0.0) if not room else (1.0 if room[0].kind == "blocked" else 2.0, room[0].dev)
        err = out.state.err if out.state is not None else 0.0
        head = [s.fit_pose.x, s.fit_pose.y, s.fit_pose.th, s.goal_pose.x, s.goal_pose.y, s.goal_pose.th,
                s.twist.vx_m_s, s.twist.vy_m_s, s.twist.w_rad_s, s.cost, float(s.at_goal), float(s.blocked),
                s.left_m, float(s.shape), out.cmd.vl, out.cmd.vr, float(out.state is not None), err, event,
                event_dev, float(before)]
        decisions = [[float(ids.index(e.robot)), float(DECISION_KINDS.index(e.kind)), e.t, e.dev]
                     for e in out.events if e.kind in DECISION_KINDS]
        per.append({"ran": 1.0, "resynced": resynced, "head": head, "used": [float(u) for u in s.used],
                    "dev": list(s.deviations_m), "decisions": decisions})
    mission = record[0][0]
    arrays = step.mission_arrays(mission)
    controller = config.controller or step.mission_controller(mission.controller, mission.controller_gains)
    kernel = agentcore.agent_kernel(agentcore.core_mission_of(mission), mission, robot, controller, config)
    _ctrl, arrays_in, scalars = agentcore._core_inputs(kernel, state, controller, len(arrays.ids))
    return per, [float(v) for a in arrays_in for v in np.asarray(a).ravel()] + [*map(float, scalars)]


def without_stale_stall_pose(state: list[float]) -> list[float]:
    """The packed state with the stall watch's pose zeroed when the watch is off: vs_agent_step leaves the last
    pose there (never read while off), the Python state holds None (packed as zeros by agentcore._core_inputs)."""
    state = list(state)
    if state[STALL_WATCH] == 0.0:
        state[STALL_POSE] = [0.0, 0.0, 0.0]
    return state


def test_the_golden_file_holds_one_agent_step_record_per_run():
    assert len(RECORDS) == len(AGENT_RUNS)


@pytest.mark.parametrize("k", range(len(AGENT_RUNS)), ids=[run[0] for run in AGENT_RUNS])
def test_each_agent_step_record_is_its_run(k):
    """The record's inputs are still what its run gives: else the ties below would hold for other frames."""
    assert hexes(agent_step_inputs(*run_frames(k))) == hexes(RECORDS[k][0]), \
        "the run no longer gives the recorded inputs (simfleet or the scenario changed): record this entry again"


@pytest.mark.parametrize("k", range(len(AGENT_RUNS)), ids=[run[0] for run in AGENT_RUNS])
def test_each_agent_step_record_is_what_the_python_glue_decides_bit_for_bit(k):
    robot, config, warm, record = run_frames(k)
    inputs, outs = RECORDS[k]
    want, want_state = frame_outputs(outs, int(inputs[0]), len(record))
    got, got_state = step_outputs(robot, config, warm, record, dataclasses.replace(config, shared_structures={}))
    assert any(f["ran"] for f in want)
    for j, (w, g) in enumerate(zip(want, got)):
        assert g.keys() == w.keys(), f"frame {j}"
        for key in w:
            if key == "decisions":
                assert [hexes(d) for d in g[key]] == [hexes(d) for d in w[key]], f"frame {j}: {key}"
            else:
                assert hexes(np.ravel(g[key])) == hexes(np.ravel(w[key])), f"frame {j}: {key}"
    assert hexes(without_stale_stall_pose(got_state)) == hexes(without_stale_stall_pose(want_state))


#: the head's values that are counts, flags or codes (vs_golden.c): equal on the reference too
EXACT_HEAD = (10, 11, 13, 16, 18, 20)


@pytest.mark.parametrize("k", range(len(AGENT_RUNS)), ids=[run[0] for run in AGENT_RUNS])
def test_each_agent_step_record_agrees_with_the_numpy_reference(k):
    robot, config, warm, record = run_frames(k)
    inputs, outs = RECORDS[k]
    n = int(inputs[0])
    want, want_state = frame_outputs(outs, n, len(record))
    # the frames before the record on the core (the test above: the glue comes to the record's start bit for bit),
    # the record's on the reference: the reference from the recorded start (0-830 frames before each record: on
    # the reference they took three quarters of this test's time)
    got, got_state = step_outputs(robot, config, warm, record, dataclasses.replace(config, reference=True), config)
    for j, (w, g) in enumerate(zip(want, got)):
        assert g.keys() == w.keys() and g["resynced"] == w["resynced"], f"frame {j}"
        if not w["ran"]:
            continue
        assert [g["head"][i] for i in EXACT_HEAD] == [w["head"][i] for i in EXACT_HEAD], f"frame {j}"
        assert g["used"] == w["used"], f"frame {j}"
        assert [d[:3] for d in g["decisions"]] == [d[:3] for d in w["decisions"]], f"frame {j}: decisions"
        np.testing.assert_allclose([d[3] for d in g["decisions"]], [d[3] for d in w["decisions"]], rtol=0,
                                   atol=REFERENCE_TOL)
        np.testing.assert_allclose(g["head"], w["head"], rtol=0, atol=REFERENCE_TOL, err_msg=f"frame {j}")
        np.testing.assert_allclose(g["dev"], w["dev"], rtol=0, atol=REFERENCE_TOL, err_msg=f"frame {j}")
    # the failure rule's verdicts after the last frame: failed and dropped (the state's arrays 11, 12)
    flags = slice(n * (2 + 3 + 2 + 10 + 2 + 2 + 1 + 1 + 2 + 1 + 1), n * (2 + 3 + 2 + 10 + 2 + 2 + 1 + 1 + 2 + 1 + 1 + 2))
    assert got_state[flags] == want_state[flags]


def test_the_agent_step_records_cover_what_carries_over_between_frames():
    """Decisions (fail, drop), a room's 'blocked' flag (a goal walled in), shapes taken, gaps past ttl and past the resync gap, frames
    with no robot usable and frames without the agent's own robot."""
    frames = [f for k, (inputs, outs) in enumerate(RECORDS)
              for f in frame_outputs(outs, int(inputs[0]), AGENT_RUNS[k][6])[0]]
    ran = [f for f in frames if f["ran"]]
    kinds = {int(d[1]) for f in ran for d in f["decisions"]}
    assert {DECISION_KINDS.index("fail"), DECISION_KINDS.index("drop")} <= kinds
    assert any(f["head"][18] == 1.0 for f in ran)                 # blocked or stuck
    assert any(f["head"][13] != f["head"][20] for f in ran)       # a shape taken
    assert any(f["resynced"] for f in frames) and any(not f["ran"] for f in frames)
    assert any(not f["head"][16] for f in ran)                    # the agent's own robot unseen
