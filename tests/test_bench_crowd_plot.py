"""bench/crowd_plot.py reads bench/crowd.py's JSON records and draws one panel per fleet size."""

import json

import pytest

from bench.crowd_plot import load, main


def test_the_records_of_two_files_load_in_order_and_draw_a_png(tmp_path):
    pytest.importorskip("matplotlib")
    rec = {"n": 10, "seed": 1, "duration_s": 90.0, "t_assembled_s": 12.5, "min_gap_m": 0.0132, "contact_frames": 0}
    a, b = tmp_path / "a.jsonl", tmp_path / "b.jsonl"
    a.write_text(json.dumps(rec) + "\n\n")
    b.write_text(json.dumps({**rec, "n": 20, "seed": 4, "t_assembled_s": None}) + "\n")
    assert [(r["n"], r["seed"]) for r in load([str(a), str(b)])] == [(10, 1), (20, 4)]
    assert main([str(a), str(b), "--out", str(tmp_path / "fig")]) == 0
    assert (tmp_path / "fig" / "crowds.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    empty = tmp_path / "empty.jsonl"
    empty.write_text("")
    assert main([str(empty), "--out", str(tmp_path / "none")]) == 1
    assert not (tmp_path / "none").exists()
