"""The compiled core (vsfleet._core): every .c file in vsfleet/_core, one extension.

Flags are fixed here and nowhere else: -O2 -ffp-contract=off (no fused multiply-add, so
aarch64 and x86-64 round alike), never -ffast-math, C99; linked with -pthread (the field's
raster runs on two threads: vs_field.c), not compiled with it (it defines _REENTRANT, and
glibc's headers then define _POSIX_C_SOURCE before Python.h does).  VSFLEET_CORE_OPT=-O0 /
-O3 rebuilds the same core at another optimisation level (tests/test_core_golden.py's check
that the golden vectors do not depend on it).  Metadata lives in pyproject.toml.
"""

import os
from glob import glob

from setuptools import Extension, setup

OPT = os.environ.get("VSFLEET_CORE_OPT", "-O2")
if OPT not in ("-O0", "-O1", "-O2", "-O3"):
    raise SystemExit(f"VSFLEET_CORE_OPT must be -O0..-O3, got {OPT!r}")
EXTRA = os.environ.get("VSFLEET_CORE_CFLAGS", "").split()  # make test-sanitize: -fsanitize=...
CFLAGS = ["-std=c99", OPT, "-ffp-contract=off", "-fno-fast-math", "-fno-unsafe-math-optimizations",
          "-Wall", "-Wextra", "-Wno-unused-parameter", "-Wno-missing-field-initializers", *EXTRA]

setup(ext_modules=[Extension(
    "vsfleet._core",
    sources=sorted(glob("vsfleet/_core/*.c")),
    depends=sorted(glob("vsfleet/_core/*.h")),
    include_dirs=["vsfleet/_core"],
    extra_compile_args=CFLAGS,
    extra_link_args=["-pthread", *(f for f in EXTRA if f.startswith("-fsanitize"))],
)])
