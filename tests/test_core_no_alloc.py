"""The agent's frame allocates nothing (issue 29): tests/cdriver/noalloc_driver.c, linked with malloc, calloc,
realloc and qsort wrapped, runs vs_agent_step_ws on every metric, controller and room over a closed loop with the
workspace sized once per mission (vs_agent_work_f64), and counts every such call a frame makes after its warm-up
frame. Before the workspace, its frames of then (none in the second shape) made 49095 allocations and 4207 qsort
calls (glibc's qsort mallocs). Half its room runs now put the goal in a slot that only the second shape (0.6 x the
template) fits, so frames run in that shape are counted too: the driver exits 5 when such a run spent none in it,
and the test asks for some."""

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
DRIVER = ROOT / "tests" / "cdriver" / "noalloc_driver.c"
WRAP = "-Wl,--wrap=malloc,--wrap=calloc,--wrap=realloc,--wrap=posix_memalign,--wrap=qsort"


def core_cflags() -> list[str]:
    """The Makefile's CORE_CFLAGS (-Wall -Wextra -Werror among them), with its -I made absolute."""
    match = re.search(r"^CORE_CFLAGS\s*:=\s*(.*)$", (ROOT / "Makefile").read_text(), re.M)
    assert match, "Makefile: no CORE_CFLAGS"
    return [f"-I{CORE}" if f.startswith("-I") else f for f in shlex.split(match.group(1))]


def run_wrapped_driver(tmp_path: Path, driver: Path, wrap: str) -> subprocess.CompletedProcess:
    """A C driver built with the core's sources, CORE_CFLAGS and the linker's --wrap list ``wrap``, then run; it must
    exit 0 (its output is in the message otherwise)."""
    exe = tmp_path / driver.stem
    subprocess.run(["gcc", *core_cflags(), wrap, "-o", str(exe), *map(str, PURE_C), str(driver), "-lm"],
                   check=True, capture_output=True, timeout=180)
    run = subprocess.run([str(exe)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    return run


@pytest.mark.integration  # starts gcc and the driver
@pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
def test_no_frame_of_the_agent_allocates_once_its_mission_is_adopted(tmp_path):
    run = run_wrapped_driver(tmp_path, DRIVER, WRAP)
    summary = re.search(r"24 runs, 2160 frames counted: 0 allocations, 0 sorts; 0 frames failed \([1-9]\d* decisions, "
                        r"(\d+) frames in the second shape", run.stdout)
    assert summary, run.stdout
    assert int(summary.group(1)) > 0, run.stdout   # the reshape path was counted
