"""Golden vectors of the compiled core: flat calls and their outputs as C99 hex floats.

``python tests/golden_core.py`` records tests/data/golden-core.txt from the core as built
here (vsfleet._core.golden_call). Each line is ``<entry> <n_in> <in...> <n_out> <out...>``
(vsfleet/_core/vs_golden.c packs and unpacks them). tests/test_core_golden.py replays them
through the binding, through a plain C driver built at -O0, -O2 and -O3, and with numpy's
AVX-512 paths off; ``make test-cross`` replays them on aarch64 under qemu. Record again only
on purpose (a change of the core's arithmetic), and say so in the commit.
``python tests/golden_core.py --only ENTRY`` records that entry's lines again (at the end of the file)
and leaves every other line as it is.
"""

from __future__ import annotations

import math
import random
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
PATH = ROOT / "tests" / "data" / "golden-core.txt"


def trig_records(seed: int = 11) -> list[tuple[str, list[float]]]:
    """Arguments for the core's own elementary functions: random, special and huge values."""
    rng = random.Random(seed)
    special = [0.0, -0.0, 1e-300, -1e-300, 2.0 ** -30, math.pi / 4, math.pi / 2, math.pi, -math.pi,
               2 * math.pi, 1e6, -1e6, 1e15, 1e300, -1e300]
    angles = special + [rng.uniform(-10.0, 10.0) for _ in range(2000)] + [rng.uniform(-1e5, 1e5) for _ in range(200)]
    pairs: list[float] = []
    for y, x in [(0.0, -1.0), (-0.0, -1.0), (0.0, 0.0), (1.0, 0.0), (-1.0, 0.0), (1e-300, 1e300),
                 (1e300, 1e-300), (-1e300, -1e-300), (1.0, 1.0), (1.0, -1.0)]:
        pairs += [y, x]
    for _ in range(2000):
        pairs += [rng.gauss(0.0, 1.0), rng.gauss(0.0, 1.0)]
    return [("sin", angles), ("cos", angles), ("atan2", pairs), ("wrap_angle", angles)]


def safety_records(seed: int = 5, count: int = 120) -> list[tuple[str, list[float]]]:
    """The safety filter on random crowded fleets (2-20 robots of 0.05 m, 0-4 obstacles), random nominal and
    previous commands, some robots inactive, both control points (offset 0 and 0.03 m)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        n, m = int(rng.integers(2, 21)), int(rng.integers(0, 5))
        xy = rng.uniform(-0.4, 0.4, (n, 2)) * np.sqrt(n)
        pose = np.c_[xy, rng.uniform(-math.pi, math.pi, n)]
        obstacles = np.c_[rng.uniform(-1.0, 1.0, (m, 2)) * np.sqrt(n), rng.uniform(0.05, 0.3, m)]
        wheels = rng.uniform(-0.3, 0.3, (n, 2))
        prev = np.clip(wheels + rng.normal(0.0, 0.02, (n, 2)), -0.3, 0.3)
        active = (rng.uniform(size=n) > 0.15).astype(float)
        out.append(("safety_filter", [float(n), float(m), 0.015, 5.0, 0.03 * (k % 2), 1.0 / 30.0, *pose.ravel(),
                                      *np.full(n, 0.05), *active, *np.full(n, 0.12), *np.full(n, 0.3),
                                      *np.full(n, 0.8), *prev.ravel(), *obstacles.ravel(), *wheels.ravel()]))
    return out


def records() -> list[tuple[str, list[float]]]:
    """Every recorded call: (entry, flat inputs)."""
    from step_core_records import (agent_step_records, assembly_records, held_records,  # noqa: PLC0415 - (tests/)
                                   shape_records, step_records)
    return (trig_records() + step_records() + safety_records() + field_records() + shape_records()
            + assembly_records() + agent_step_records() + refine_records() + held_records())


def line(entry: str, inputs, outputs) -> str:
    return " ".join([entry, str(len(inputs)), *(float(v).hex() for v in inputs),
                     str(len(outputs)), *(float(v).hex() for v in outputs)])


def read(path: Path = PATH) -> list[tuple[str, list[float], list[float]]]:
    """The recorded (entry, inputs, outputs)."""
    out = []
    for text in path.read_text().splitlines():
        if not text or text.startswith("#"):
            continue
        f = text.split()
        n_in = int(f[1])
        ins = [float.fromhex(v) for v in f[2:2 + n_in]]
        n_out = int(f[2 + n_in])
        outs = [float.fromhex(v) for v in f[3 + n_in:3 + n_in + n_out]]
        out.append((f[0], ins, outs))
    return out


def field_records(seed: int = 17, count: int = 24) -> list[tuple[str, list[float]]]:
    """The room's navigation function (vs_field_build) on random rooms: 2-10 robots, 0-12 obstacles, coarse
    lattices (so that qemu replays them in seconds); the record keeps the lattice and a hash of every cost."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        n, m = int(rng.integers(2, 11)), int(rng.integers(0, 13))
        tpl = rng.uniform(-0.5, 0.5, (n, 2))
        radii = rng.uniform(0.0, 0.1, n)
        obs = np.c_[rng.uniform(-2.0, 2.0, (m, 2)), rng.uniform(0.05, 0.4, m)]
        goal = [*rng.uniform(-1.0, 1.0, 2), float(rng.uniform(-4.0, 4.0))]
        cell, heads = float(rng.choice([0.06, 0.08, 0.1])), float(rng.choice([8, 12, 16]))
        build = [float(n), float(m), 0.02, cell, heads, 60000.0, *goal, *tpl.ravel(), *radii, *obs.ravel()]
        out.append(("field_build", build))
        for _ in range(3):   # descents from random poses, some far outside the lattice
            pose = [*rng.uniform(-4.0, 4.0, 2), float(rng.uniform(-4.0, 4.0)), float(rng.choice([0.5, 2.0, 50.0]))]
            out.append(("field_follow", build + pose))
    return out


def refine_records(seed: int = 29, count: int = 16) -> list[tuple[str, list[float]]]:
    """A field armed with its finer lattice (vs_field_set_refine): thin walls of discs with one gap about as wide as
    a line-like structure of 2-5 robots, a few pillars; the coarse lattice grown to fit 1,500 states, the finer one
    60,000 at 16 headings. Two descents each from the wall's far side: 12 of the 32 find no way on the coarse
    lattice and take the finer one's, 2 find none on either (recorded 2026-12-07)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        tpl, radii, obs, goal = gap_room(rng)
        build = [float(len(tpl)), float(len(obs)), 0.02, 0.04, 8.0, 1500.0, *goal, *tpl.ravel(), *radii, *obs.ravel()]
        for _ in range(2):
            pose = [*far_side(rng), float(rng.choice([0.5, 2.0, 50.0]))]
            out.append(("field_refine", build + [16.0, 60000.0] + pose))
    return out


def gap_room(rng) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[float]]:
    """refine_records' room: a line-like structure of 2-5 robots (template (n, 2), radii (n,)), a thin wall of discs
    across x = 0 with one gap about its width, 0-3 pillars (obstacles (m, 3)), and a goal (x, y, th) beyond the wall."""
    n = int(rng.integers(2, 6))
    tpl = np.c_[rng.uniform(-0.3, 0.3, n), rng.uniform(-0.08, 0.08, n)]
    radii = rng.uniform(0.02, 0.06, n)
    gap_y, gap = float(rng.uniform(-0.5, 0.5)), float(rng.uniform(0.12, 0.4))
    wall = [(0.0, y, 0.06) for y in np.arange(-2.0, 2.01, 0.1) if abs(y - gap_y) > gap / 2]
    pillars = [(*rng.uniform(-1.5, 1.5, 2), float(rng.uniform(0.05, 0.2))) for _ in range(int(rng.integers(0, 4)))]
    goal = [float(rng.uniform(0.6, 1.2)), float(rng.uniform(-0.5, 0.5)), float(rng.uniform(-4.0, 4.0))]
    return tpl, radii, np.array(wall + pillars), goal


def far_side(rng) -> list[float]:
    """A structure pose (x, y, th) on the far side of gap_room's wall."""
    return [float(rng.uniform(-1.4, -0.5)), float(rng.uniform(-0.6, 0.6)), float(rng.uniform(-4.0, 4.0))]


def main(only: str | None = None) -> None:
    """Record every entry (only: that entry's lines alone, again, at the end; the others kept as they are)."""
    from vsfleet import _core
    if only is None:
        lines, todo = ["# golden vectors of vsfleet's compiled core: tests/golden_core.py (entry n_in in... n_out out...)"], \
            records()
    else:
        from step_core_records import agent_step_records, assembly_records, held_records  # noqa: PLC0415 - (tests/)
        makers = {"agent_step": agent_step_records, "field_refine": refine_records, "structure_step_held": held_records,
                  "assembly_targets": assembly_records}
        if only not in makers:
            raise SystemExit(f"--only: one of {sorted(makers)}")
        lines = [t for t in PATH.read_text().splitlines() if t.split(" ", 1)[0] != only]
        todo = makers[only]()
    before = len(lines)
    for entry, inputs in todo:
        lines.append(line(entry, inputs, _core.golden_call(entry, np.asarray(inputs, dtype=float))))
    PATH.write_text("\n".join(lines) + "\n")
    print(f"wrote {len(lines) - before} records to {PATH}")


if __name__ == "__main__":
    import argparse
    import sys
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", help="record this entry's lines alone (agent_step)")
    main(parser.parse_args().only)
