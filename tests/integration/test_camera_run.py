"""`vsfleet run --tracker camera`: the whole loop through the camera from one command.

simfleet -> synthetic overhead camera (render) -> ArUco detection -> one frame per camera frame on
vs/<fleet>/frame/cam1 -> agents -> simfleet, started by `vsfleet run`, observed in the run's record
of the key space (log.msgpack) and its summary (computed from truth).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import uuid
from pathlib import Path

import msgpack
import pytest

pytest.importorskip("cv2")

from vsfleet.wire import WireError, decode_frame, decode_pose, decode_state  # noqa: E402

from .test_run import fleet_pids  # noqa: E402

pytestmark = pytest.mark.integration

ROOT = Path(__file__).parent.parent.parent
SCENARIO = ROOT / "scenarios" / "camera-triangle.toml"
MAX_DEVIATION_M = 0.025  # the paper's real robots (Fig. 10); measured here 1.2 cm, at the start
GOAL_TOL_M = 0.01        # vsfleet run's "goal reached"


def records(path: Path):
    with path.open("rb") as f:
        yield from msgpack.Unpacker(f, raw=False)


def decoded(recs, prefix: str, decode):
    out = []
    for _, key, payload in recs:
        if key.startswith(prefix):
            try:
                out.append((key[len(prefix):], decode(payload)))
            except WireError:
                pass
    return out


def run_camera_triangle(tmp_path: Path, *flags: str) -> tuple[str, Path, dict, str]:
    """`vsfleet run scenarios/camera-triangle.toml FLAGS` on a fleet name of its own, to its end (at most 180 s:
    the scenario lasts at most 40 s; a busy host is slower), every child killed after; (fleet, its run
    directory, summary.json, the output). Asserts it exited 0 and reached its goal with every child well."""
    fleet = "t" + uuid.uuid4().hex[:8]
    proc = subprocess.Popen([sys.executable, "-m", "vsfleet.fleetctl.cli", "run", str(SCENARIO), *flags,
                             "--fleet", fleet, "--out", str(tmp_path)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, stdin=subprocess.DEVNULL)
    try:
        out, _ = proc.communicate(timeout=180)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
        pytest.fail("vsfleet run did not end\n" + out)
    finally:
        if proc.poll() is None:
            proc.kill()
        for pid in fleet_pids(fleet).values():
            os.kill(pid, signal.SIGKILL)
    assert proc.returncode == 0, out
    (run_dir,) = tmp_path.glob("*/camera-triangle")
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["children_ok"] and summary["reached_goal"], out
    return fleet, run_dir, summary, out


def test_vsfleet_run_with_the_camera_tracker_reaches_the_goal_in_formation(tmp_path):
    fleet, run_dir, summary, _out = run_camera_triangle(tmp_path, "--tracker", "camera")
    assert summary["goal_distance_end_m"] <= GOAL_TOL_M
    assert {d["robot"] for d in summary["deviation"]} == {"r1", "r2", "r3"}
    assert all(d["max_m"] < MAX_DEVIATION_M for d in summary["deviation"]), summary["deviation"]

    recs = list(records(run_dir / "log.msgpack"))
    frames = decoded(recs, f"vs/{fleet}/frame/", decode_frame)
    poses = decoded(recs, f"vs/{fleet}/pose/", decode_pose)
    states = decoded(recs, f"vs/{fleet}/state/", decode_state)
    assert frames and {src for src, _ in frames} == {"cam1"}
    seqs = [f.seq for _, f in frames]
    assert seqs == sorted(set(seqs))  # one frame per camera frame, in order
    # the camera numbers its frames 1, 2, ...; frames and poses are best-effort (dropped under congestion,
    # docs/protocol.md), so the record may miss some: 226 of 244 frames (93 %) in one busy-loop rehearsal.
    # Frames are latest-value and express: a tracker that fell behind on a loaded host publishes its backlog in
    # a burst, and the burst's older frames drop. Another busy-loop rehearsal (2026-12-05) recorded 200 of 240:
    # frames 97-129 and 132-138 missing, the frame before the first hole recorded 2.0 s after its capture, the
    # 34 frames' capture span (1.9 s) delivered in 0.62 s. So a hole whose ends reached the record in less than
    # half their capture span is such a burst; the frames missing elsewhere stay within the 10 %.
    at = [rec_t for rec_t, key, _ in recs if key.startswith(f"vs/{fleet}/frame/")]
    assert len(at) == len(frames)
    burst = {a: (at[i + 1] - at[i]) < 0.5 * (frames[i + 1][1].t - frames[i][1].t)
             for i, (a, b) in enumerate(zip(seqs, seqs[1:])) if b - a > 1}
    missing_elsewhere = sum(b - a - 1 for a, b in zip(seqs, seqs[1:]) if b - a > 1 and not burst[a])
    assert seqs[0] - 1 + missing_elsewhere <= 0.1 * max(seqs), (len(seqs), max(seqs), burst)
    by_seq = {f.seq: f for _, f in frames}
    # a pose whose frame was dropped in such a burst has no frame to match (poses are batched, not express: they
    # were not dropped with it): a busy-loop run (2026-12-06) recorded 813 poses, 150 without their frame, 135 of
    # them in the burst hole 86-129 and 15 in the hole 132-136; the rest stay within the 10 %
    in_bursts = {s for a, b in zip(seqs, seqs[1:]) if b - a > 1 and burst[a] for s in range(a + 1, b)}
    kept = [(robot, p) for robot, p in poses if p.seq not in in_bursts]
    matched = [(robot, p) for robot, p in kept if p.seq in by_seq]
    assert len(matched) >= 0.9 * len(kept), (len(matched), len(kept), len(poses))
    for robot, p in matched:  # each pose published is its frame's entry for that robot
        assert by_seq[p.seq].poses[robot] == (p.x, p.y, p.th) and by_seq[p.seq].t == p.t
    assert sum(len(f.poses) == 3 for f in by_seq.values()) > 0.9 * len(by_seq)
    assert states and {s.seq for _, s in states} <= set(range(1, max(seqs) + 1))  # answers to the camera's frames
