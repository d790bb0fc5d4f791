"""The core's C sources and every plain C driver (tests/cdriver/) build without a single warning under
the Makefile's CORE_CFLAGS (-Wall -Wextra -Werror, which `make test-sanitize` and `make test-cross`
use). -Wall brings -Wsequence-point: the fuzz driver once stored ``in[len++] = hostile(in, len, ...)``,
an increment unsequenced against the reads of len on the right (C99 6.5p2, undefined behaviour)."""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
CORE = ROOT / "vsfleet" / "_core"
PURE_C = sorted(p for p in CORE.glob("*.c") if not p.name.startswith("py_") and p.name != "module.c")
DRIVERS = sorted((ROOT / "tests" / "cdriver").glob("*.c"))   # fuzz, golden, noalloc: every C driver


def core_cflags() -> list[str]:
    """The Makefile's CORE_CFLAGS, with its -I made absolute."""
    text = (ROOT / "Makefile").read_text()
    match = re.search(r"^CORE_CFLAGS\s*:=\s*(.*)$", text, re.M)
    assert match, "Makefile: no CORE_CFLAGS"
    return [f"-I{CORE}" if f.startswith("-I") else f for f in shlex.split(match.group(1))]


def test_the_makefiles_core_flags_make_every_warning_an_error():
    flags = core_cflags()
    assert {"-std=c99", "-Wall", "-Wextra", "-Werror"} <= set(flags)
    assert not [f for f in flags if f.startswith("-Wno-")], "fix the warning, do not silence it"
    assert "-ffast-math" not in flags


@pytest.mark.integration  # starts gcc
@pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
def test_the_core_and_every_driver_compiles_with_all_warnings_as_errors(tmp_path):
    """-c at the Makefile's -O2 (some warnings need the optimiser's flow analysis), objects in tmp_path."""
    flags = core_cflags() + ["-Wsequence-point"]
    run = subprocess.run(["gcc", *flags, "-c", *map(str, PURE_C), *map(str, DRIVERS)],
                         cwd=tmp_path, capture_output=True, text=True, timeout=180)
    assert len(DRIVERS) >= 3, DRIVERS
    assert run.returncode == 0, run.stderr
    assert not run.stderr.strip(), run.stderr
