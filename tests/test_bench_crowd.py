"""bench/crowd.py's tie-break cost mode times the frame its docstring names: a packed crowd that the tie-break sends
round (no time is asserted: speed is measured in bench/, not in tests)."""

import json

import numpy as np

from bench.crowd import RADIUS_M, crowd_doc, main, tiebreak_cost_us
from vsfleet.assembly import assembly_targets


def test_the_timed_frame_is_a_packed_crowd_that_the_core_sends_round_as_the_record_says():
    rec = tiebreak_cost_us(10, repeats=3)
    doc = crowd_doc(10, 1, 1.0)
    ids = sorted(doc["robots"])
    pose = np.array([doc["robots"][r]["start"] for r in ids])
    points = np.array([doc["robots"][r]["p"] for r in ids])
    gaps = np.hypot(*(pose[:, None, :2] - pose[None, :, :2]).transpose(2, 0, 1))[np.triu_indices(10, 1)]
    assert abs(gaps.min() - (2 * RADIUS_M + 0.02)) < 1e-9              # packed 2 cm apart
    _, _, detoured = assembly_targets(np.full(10, RADIUS_M), pose, np.ones(10, bool), points, points, 0.015, 0.0)
    assert rec["n"] == 10 and rec["detoured"] == int(detoured.sum()) > 0
    assert rec["core_us"] > 0.0 and rec["reference_us"] > 0.0


def test_the_mode_prints_one_record_per_size(capsys):
    assert main(["--tiebreak-cost", "5,10", "--json"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [json.loads(line)["n"] for line in lines] == [5, 10]
