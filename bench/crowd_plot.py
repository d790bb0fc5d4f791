"""Draw bench/crowd.py's records: each crowd's time to assemble, per fleet size (docs/bench/crowd/crowds.png).

Reads the JSON lines ``bench.crowd --json`` prints (one record per crowd) from one or more files and draws one panel
per fleet size: the time to assemble against the seed, the crowds that did not assemble within their run marked at
its end in red, with the count assembled and the smallest gap in the panel's title. It writes crowds.png under
runs/bench/crowd/, or --out DIR, or --docs (docs/bench/crowd, the tracked copy; bench.outputs).

    PYTHONPATH=. .venv/bin/python -m bench.crowd --n 10 --seeds 1,2,3 --duration 90 --json > /tmp/c10.jsonl
    PYTHONPATH=. .venv/bin/python -m bench.crowd_plot /tmp/c10.jsonl --docs
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .outputs import DOCS, add_output_flags


def load(paths: list[str]) -> list[dict]:
    """Every record in the files, in order (blank lines skipped)."""
    records = []
    for path in paths:
        for line in Path(path).read_text().splitlines():
            if line.strip():
                records.append(json.loads(line))
    return records


def plot(records: list[dict], out: Path, title: str) -> None:
    """One panel per fleet size (ascending): time to assemble [s] against the seed; unassembled crowds in red."""
    import matplotlib  # noqa: PLC0415 - the bench extra only
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    sizes = sorted({r["n"] for r in records})
    fig, axes = plt.subplots(len(sizes), 1, figsize=(10, 2.6 * len(sizes)), squeeze=False)
    for ax, n in zip(axes[:, 0], sizes):
        rows = [r for r in records if r["n"] == n]
        done = [r for r in rows if r["t_assembled_s"] is not None]
        stuck = [r for r in rows if r["t_assembled_s"] is None]
        ax.plot([r["seed"] for r in done], [r["t_assembled_s"] for r in done], "o", ms=4, color="tab:blue",
                label="assembled")
        if stuck:
            ax.plot([r["seed"] for r in stuck], [r["duration_s"] for r in stuck], "x", ms=8, mew=2, color="tab:red",
                    label="not assembled in the run")
        gap_mm = 1000.0 * min(r["min_gap_m"] for r in rows)
        contacts = sum(r["contact_frames"] for r in rows)
        ax.set_title(f"{n} robots: {len(done)} of {len(rows)} assembled; smallest gap {gap_mm:.1f} mm, "
                     f"{contacts} contact frames", fontsize=10)
        ax.set_ylabel("time to assemble [s]")
        ax.set_ylim(0.0, max(r["duration_s"] for r in rows) * 1.05)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("seed (bench/crowd.py)")
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("records", nargs="*", help="files of bench.crowd --json records")
    add_output_flags(ap, "crowd", DOCS / "bench" / "crowd", "crowds.png")
    ap.add_argument("--title", default="Shuffled crowds packed 2 cm apart (bench/crowd.py)")
    a = ap.parse_args(argv)
    records = load(a.records)
    if not records:
        print("no records", file=sys.stderr)
        return 1
    out = Path(a.out) / "crowds.png"
    plot(records, out, a.title)
    print(f"written: {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
