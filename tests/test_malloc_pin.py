"""Every program pins glibc's mmap and trim thresholds (zglue.program.pin_mmap_threshold, issue 30: RSS)."""

import ctypes
import os
import subprocess
import sys

import pytest

from vsfleet.zglue.program import pin_mmap_threshold

CHILD = r"""
import ctypes, sys
from vsfleet.zglue.program import pin_mmap_threshold
pinned = pin_mmap_threshold() if sys.argv[1] == "pin" else None
libc = ctypes.CDLL(None)
libc.malloc.restype = ctypes.c_void_p; libc.malloc.argtypes = [ctypes.c_size_t]; libc.free.argtypes = [ctypes.c_void_p]
def anon():
    return next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("RssAnon"))
# a large block freed: glibc raises its thresholds (unpinned). 16 MiB, more than the heap's free top can hold
# after any interpreter's start, so it is mmapped: a 4 MiB block came from the top of the heap when the child ran
# without HOME, LANG or PYTHONUNBUFFERED (the interpreter's start had left that much free there), no threshold was
# raised, and the unpinned control kept only 124 KiB (two integration runs, 2026-12-04/05)
big = libc.malloc(16 << 20); libc.free(big)
base = anon()
keep = []
for _ in range(16):                                    # 1 MiB blocks between small long-lived ones (fragmented)
    p = libc.malloc(1 << 20); ctypes.memset(p, 1, 1 << 20); keep.append((p, libc.malloc(64)))
for p, _small in keep:
    libc.free(p)
print(pinned, anon() - base)
"""


def _run(mode, **env):
    out = subprocess.run([sys.executable, "-c", CHILD, mode], capture_output=True, text=True, check=True,
                         env={**os.environ, **env}).stdout.split()
    return out[0], int(out[1])


@pytest.mark.integration   # it starts a Python process per case
@pytest.mark.skipif(not hasattr(ctypes.CDLL(None), "mallopt") or not os.path.exists("/proc/self/status"),
                    reason="glibc (mallopt) and /proc only")
def test_pinned_thresholds_give_freed_large_blocks_back():
    pinned, kib = _run("pin")
    assert pinned == "True"
    assert kib < 1024, kib                       # the 16 MiB went back to the system as they were freed
    _none, kib_unpinned = _run("none")
    assert kib_unpinned > 8 * 1024, kib_unpinned  # unpinned, glibc kept them in the heap


def test_an_environment_setting_is_left_alone(monkeypatch):
    monkeypatch.setenv("MALLOC_MMAP_THRESHOLD_", "262144")
    assert pin_mmap_threshold() is False
