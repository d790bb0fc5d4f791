"""The suite's two tiers: every test under tests/integration/ is marked ``integration``, and so is
any test elsewhere that runs a command line as a child process; every other test is a unit test,
and starting a process in one (in the test or in any fixture it sets up) fails it.

``make test-unit`` runs ``-m "not integration"``; ``make test`` runs both tiers.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

INTEGRATION_DIR = Path(__file__).parent / "integration"
SPAWNERS = ("fork", "forkpty", "posix_spawn", "posix_spawnp", "system", "execv", "execve")


class ProcessInUnitTest(RuntimeError):
    """A unit test tried to start a process: mark it ``integration`` (or move it to tests/integration/)."""


def pytest_collection_modifyitems(config, items):
    for item in items:
        if INTEGRATION_DIR in Path(item.path).parents:
            item.add_marker(pytest.mark.integration)


def _guarded(item):
    """A MonkeyPatch context in which ``item`` (a unit test) cannot start a process."""
    mp = pytest.MonkeyPatch()
    if item.get_closest_marker("integration") is not None:
        return mp

    def refuse(*args, **kwargs):
        raise ProcessInUnitTest(f"{item.nodeid} starts a process; a test that does is marked integration")

    mp.setattr(subprocess.Popen, "_execute_child", refuse)
    for name in SPAWNERS:
        if hasattr(os, name):
            mp.setattr(os, name, refuse)
    return mp


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_setup(item):
    mp = _guarded(item)
    try:
        yield
    finally:
        mp.undo()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item):
    mp = _guarded(item)
    try:
        yield
    finally:
        mp.undo()
