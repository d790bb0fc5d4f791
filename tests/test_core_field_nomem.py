"""A deferred field that runs out of memory while a descent resolves a component stays as it was
(tests/cdriver/field_nomem_driver.c, linked with malloc, calloc and realloc wrapped so that the k-th one fails, for
every k the resolution reaches): the descent says VS_ENOMEM, and the next one, with memory, answers as the whole build
does, bit for bit, and resolves to its costs; and a build whose k-th allocation fails (the cost array's posix_memalign
among them) says VS_ENOMEM; and a field whose finer lattice (vs_field_set_refine) runs out of memory while it is
built or resolved says VS_ENOMEM, keeps no finer lattice, and the next descent, with memory, answers as one that never
ran out. `make test-sanitize` runs the same driver under ASan and UBSan."""

from __future__ import annotations

import re
import shutil

import pytest

from tests.test_core_no_alloc import ROOT, run_wrapped_driver

DRIVER = ROOT / "tests" / "cdriver" / "field_nomem_driver.c"
WRAP = "-Wl,--wrap=malloc,--wrap=calloc,--wrap=realloc,--wrap=posix_memalign"


@pytest.mark.integration  # starts gcc and the driver
@pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
def test_a_resolution_that_runs_out_of_memory_leaves_the_deferred_field_as_it_was(tmp_path):
    run = run_wrapped_driver(tmp_path, DRIVER, WRAP)
    failed = re.search(r"field_nomem: (\d+) failed allocations, each left the field as it was; ok", run.stdout)
    assert failed and int(failed.group(1)) > 2, run.stdout
    built = re.search(r"field_nomem: build: (\d+) failed allocations \((\d+) aligned\), each VS_ENOMEM; ok", run.stdout)
    assert built and int(built.group(1)) >= 2 and int(built.group(2)) >= 1, run.stdout
    refined = re.search(r"field_nomem: refine: (\d+) failed allocations, each VS_ENOMEM, then the same descent; ok",
                        run.stdout)
    assert refined and int(refined.group(1)) >= 3, run.stdout
