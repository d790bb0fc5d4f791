"""Where a bench writes its files: under runs/ (gitignored) unless a flag asks for another place.

Every bench that writes files takes ``--out DIR`` (anywhere) or ``--docs`` (its tracked copy under
docs/); with neither, it writes under runs/bench/<name>/, and a run for a look changes no tracked
file. ``make bench`` runs bench/run_all.py with ``--docs``, which writes docs/benchmarks.md, docs/bench/
and the figures in docs/img/ (tests/test_bench_outputs.py holds every bench to this).
"""

from __future__ import annotations

import argparse
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RUNS = ROOT / "runs" / "bench"
DOCS = ROOT / "docs"


def add_output_flags(parser: argparse.ArgumentParser, name: str, docs_dir: Path, what: str) -> None:
    """``--out DIR`` / ``--docs`` (one or neither): ``args.out`` is the directory for ``what``,
    runs/bench/``name`` unless one of them says otherwise."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--out", type=Path, default=RUNS / name,
                       help=f"directory for {what} (default: {(RUNS / name).relative_to(ROOT)}, untracked)")
    group.add_argument("--docs", dest="out", action="store_const", const=docs_dir,
                       help=f"write {what} into {docs_dir.relative_to(ROOT)}, the tracked copy (make bench does)")
