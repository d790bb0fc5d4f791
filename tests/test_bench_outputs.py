"""A bench run writes under runs/ (gitignored), never into a tracked file, unless a flag asks:
--out DIR, or --docs (its tracked copy under docs/, which make bench passes to bench/run_all.py)."""

from __future__ import annotations

import argparse
import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
RUNS = ROOT / "runs"
DOCS = ROOT / "docs"

# every bench that writes files -> where --docs puts them
WRITERS = {"bench.faults": DOCS / "img", "bench.precision": DOCS / "img", "bench.loop": DOCS / "bench",
           "bench.run_all": DOCS, "bench.engine": DOCS / "bench" / "sections", "bench.room": DOCS / "bench" / "room",
           "bench.soak": DOCS / "bench" / "sections", "bench.decode": DOCS / "bench" / "sections",
           "bench.crowd_plot": DOCS / "bench" / "crowd"}
# benches that write only where they are told
WHERE_TOLD = {
    "bench.report": "run_all's plots and sections, into the directory run_all was given",
    "bench.slowed": "every run as JSON lines, only with --jsonl PATH",
}
WRITES = re.compile(r"savefig\(|\.write_(text|bytes)\(|json\.dump\(|open\([^)]*[\"'][wa]")


class Parsed(Exception):
    pass


def parsed_args(monkeypatch, module: str, argv: list[str]) -> argparse.Namespace:
    """The bench's own arguments for ``argv``, as its main parses them; it stops there (nothing runs)."""
    real = argparse.ArgumentParser.parse_args

    def stop(self, args=None, namespace=None):
        raise Parsed(real(self, args, namespace))

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", stop)
    with pytest.raises(Parsed) as parsed:
        importlib.import_module(module).main(argv)
    return parsed.value.args[0]


@pytest.mark.parametrize("module", sorted(WRITERS))
def test_a_bench_writes_under_runs_unless_a_flag_says_otherwise(monkeypatch, module):
    args = parsed_args(monkeypatch, module, [])
    out = getattr(args, "out", None)
    assert out is not None and Path(out).resolve().is_relative_to(RUNS), f"{module} writes by default: {vars(args)}"
    assert Path(parsed_args(monkeypatch, module, ["--docs"]).out) == WRITERS[module]
    assert Path(parsed_args(monkeypatch, module, ["--out", "elsewhere"]).out) == Path("elsewhere")


def test_room_draws_its_picture_only_where_told(monkeypatch):
    assert parsed_args(monkeypatch, "bench.room", []).picture is None


def test_every_bench_that_writes_files_is_held_to_it():
    """A new bench that writes files joins WRITERS (and takes bench.outputs' flags) or WHERE_TOLD."""
    writers = {f"bench.{p.stem}" for p in (ROOT / "bench").glob("*.py") if WRITES.search(p.read_text())}
    assert writers - set(WRITERS) - set(WHERE_TOLD) == set()
    assert "bench.faults" in writers  # the pattern does find a writer


def test_make_bench_is_what_refreshes_docs():
    recipe = re.search(r"^bench:.*\n((?:\t.*\n)+)", (ROOT / "Makefile").read_text(), re.M).group(1)
    assert "bench.run_all --docs" in recipe
