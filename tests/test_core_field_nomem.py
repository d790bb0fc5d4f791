"""A deferred field that runs out of memory while a descent resolves a component stays as it was
(tests/cdriver/field_nomem_driver.c, linked with malloc, calloc and realloc wrapped so that the k-th one fails, for
every k the resolution reaches): the descent says VS_ENOMEM, and the next one, with memory, answers as the whole build
does, bit for bit, and resolves to its costs. `make test-sanitize` runs the same driver under ASan and UBSan."""

from __future__ import annotations

import re
import shutil
import subprocess

import pytest

from tests.test_core_no_alloc import PURE_C, ROOT, core_cflags

DRIVER = ROOT / "tests" / "cdriver" / "field_nomem_driver.c"
WRAP = "-Wl,--wrap=malloc,--wrap=calloc,--wrap=realloc"


@pytest.mark.integration  # starts gcc and the driver
@pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
def test_a_resolution_that_runs_out_of_memory_leaves_the_deferred_field_as_it_was(tmp_path):
    exe = tmp_path / "field-nomem"
    subprocess.run(["gcc", *core_cflags(), WRAP, "-o", str(exe), *map(str, PURE_C), str(DRIVER), "-lm"],
                   check=True, capture_output=True, timeout=180)
    run = subprocess.run([str(exe)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    failed = re.search(r"field_nomem: (\d+) failed allocations, each left the field as it was; ok", run.stdout)
    assert failed and int(failed.group(1)) > 2, run.stdout
