"""One set of golden vectors for the compiled core (tests/data/golden-core.txt), reproduced bit for bit:
through the Python binding as built, through a plain C driver built at -O0, -O2 and -O3, and with
numpy's AVX-512 paths switched off (`make test-cross` replays the same file on aarch64 under qemu)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vsfleet import _core

sys.path.insert(0, str(Path(__file__).resolve().parent))
from golden_core import PATH, read  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
CORE = ROOT / "vsfleet" / "_core"
PURE_C = sorted(p for p in CORE.glob("*.c") if not p.name.startswith("py_") and p.name != "module.c")
RECORDS = read(PATH)


def test_the_golden_file_covers_every_entry_the_core_offers():
    names = {r[0] for r in RECORDS}
    assert names == {"sin", "cos", "atan2", "wrap_angle", "structure_step", "structure_step_shapes",
                     "structure_step_held", "safety_filter",
                     "field_build", "field_follow", "field_refine", "assembly_targets", "agent_step"}
    assert sum(r[0] == "structure_step" for r in RECORDS) >= 1000
    refined = [r[2] for r in RECORDS if r[0] == "field_refine"]
    # open, tight, built, n, blocked: descents the finer lattice opened, and ones it did not
    assert sum(o[2] == 1.0 and o[4] == 0.0 for o in refined) >= 8
    assert sum(o[2] == 1.0 and o[4] == 1.0 for o in refined) >= 2
    assert sum(o[2] == 0.0 for o in refined) >= 8
    # a first plan's field (provisional): held where the wall's field has no way, never blocked; beside the pillar
    # the same as structure_step on the same inputs
    held = [r for r in RECORDS if r[0] == "structure_step_held"]
    plain = [list(_core.golden_call("structure_step", np.asarray(i, dtype=float))) for _e, i, _o in held]
    assert len(held) >= 20 and all(o[0] == 0.0 or o[12] == 0.0 for _e, _i, o in held)
    stopped = [o for (_e, _i, o), p in zip(held, plain) if o[0] == 1.0 and p[12] == 1.0]   # blocked without the flag
    assert len(stopped) >= 5 and all(o[11] == 0.0 and o[7:10] == [0.0, 0.0, 0.0] and o[-1] == 1.0 for o in stopped)
    assert sum(o[:-1] == p and o[-1] == 0.0 for (_e, _i, o), p in zip(held, plain) if o[0] == 1.0) >= 5


@pytest.mark.parametrize("entry", sorted({r[0] for r in RECORDS}))
def test_the_binding_as_built_reproduces_every_record_bit_for_bit(entry):
    bad = []
    for k, (name, inputs, want) in enumerate(RECORDS):
        if name != entry:
            continue
        got = _core.golden_call(entry, np.asarray(inputs, dtype=float))
        if [g.hex() for g in got] != [w.hex() for w in want]:
            bad.append(k)
    assert not bad, f"{entry}: {len(bad)} records differ, first line {bad[0] + 2}"


@pytest.mark.integration  # starts gcc and the driver
@pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
@pytest.mark.parametrize("opt", ["-O0", "-O2", "-O3"])
def test_a_plain_c_driver_built_at_each_optimisation_level_reproduces_the_records(opt, tmp_path):
    exe = tmp_path / f"golden{opt}"
    subprocess.run(["gcc", "-std=c99", opt, "-ffp-contract=off", "-fno-fast-math", "-pthread", f"-I{CORE}", "-o",
                    str(exe), *map(str, PURE_C), str(ROOT / "tests" / "cdriver" / "golden_driver.c"), "-lm"],
                   check=True, capture_output=True, timeout=120)
    run = subprocess.run([str(exe), str(PATH)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    assert f"{len(RECORDS)} records, 0 mismatched" in run.stdout


@pytest.mark.integration  # a child interpreter
def test_the_records_hold_with_numpys_avx512_paths_switched_off():
    """numpy reads NPY_DISABLE_CPU_FEATURES once, at import: a child interpreter replays the records."""
    env = dict(os.environ, NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL AVX512_SPR")
    code = ("import sys, numpy as np; sys.path.insert(0, 'tests'); from golden_core import read, PATH;"
            "from vsfleet import _core;"
            "bad = [e for e, i, w in read(PATH) if [g.hex() for g in _core.golden_call(e, np.asarray(i, dtype=float))]"
            " != [v.hex() for v in w]]; print('mismatched', len(bad), bad[:3])")
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "mismatched 0 " in run.stdout, run.stdout


@pytest.mark.integration  # a child pytest
def test_the_agent_steps_golden_vectors_hold_with_numpys_avx512_paths_switched_off():
    """tests/data/golden-step.json (the whole agent step, bit for bit) on a numpy without AVX-512 paths:
    what a laptop without AVX-512 computes (numpy's SIMD sums broke it by one ulp before the core)."""
    env = dict(os.environ, NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL AVX512_SPR")
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:xdist",
                          "tests/test_golden_step.py"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    assert " passed" in run.stdout
