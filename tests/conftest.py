"""The suite's three tiers: every test under tests/integration/ is marked ``integration``, and so is
any test elsewhere that runs a command line as a child process; every test of a module in FLEET_MODULES
(closed-loop runs of a simulated fleet in this process, simfleet.offline: each 0.3-1.5 s) is marked
``fleet``; every other test is a unit test. Starting a process in a unit or fleet test (in the test or in
any fixture it sets up) fails it.

``make test-unit`` runs ``-m "not integration and not fleet"``, ``make test-fleet`` ``-m fleet``;
``make test`` runs all three tiers.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

INTEGRATION_DIR = Path(__file__).parent / "integration"
#: the modules of closed-loop fleet runs (the fleet tier): 48 of the unit tier's 131 s of tests on 2026-12-06
FLEET_MODULES = ("test_closed_loop.py", "test_room.py", "test_offline_faults.py", "test_reshape.py",
                 "test_core_agent_step.py", "test_engine_mujoco.py")
SPAWNERS = ("fork", "forkpty", "posix_spawn", "posix_spawnp", "system", "execv", "execve")


class ProcessInUnitTest(RuntimeError):
    """A unit test tried to start a process: mark it ``integration`` (or move it to tests/integration/)."""


#: the unit tier's longest tests (1.5-5 s each, measured 2026-12-05), run first: `make test-unit` runs two workers with
#: --dist worksteal, and a long test taken last kept one worker busy while the other had nothing left (scheduling
#: only: no test depends on the order)
SLOW_FIRST = (
    "tests/test_core_advance.py::test_the_core_advance_equals_the_reference_on_random_fleets_goals_and_options",
    "tests/test_core_failure.py::test_the_core_keeps_the_same_state_and_decides_the_same_as_the_reference_on_every_frame",
    "tests/test_core_step.py::test_the_core_step_agrees_with_the_numpy_reference_on_the_same_frames",
    "tests/test_reshape.py::test_the_core_and_the_reference_choose_the_same_shape_and_structure_bit_for_bit",
    "tests/test_core_agent_golden.py::test_each_agent_step_record_agrees_with_the_numpy_reference",
    # the same records' other two checks on the same worker, which then runs each record's fleet offline once
    # (run_frames is cached in the worker: 0.2-0.8 s a record, 14 records)
    "tests/test_core_agent_golden.py::test_each_agent_step_record_is_what_the_python_glue_decides_bit_for_bit",
    "tests/test_core_agent_golden.py::test_each_agent_step_record_is_its_run",
    "tests/test_core_wire.py::test_a_random_valid_frame_in_any_msgpack_form_decodes_to_the_same_bits",
    "tests/test_core_control.py::test_every_controller_in_a_closed_loop_computes_the_references_wheels_and_state",
    "tests/test_core_wire.py::test_a_random_frame_with_bytes_overwritten_gets_the_same_verdict",
    "tests/test_camera.py::test_lens_distortion_is_undone_by_the_pinhole_calibration",
)


def pytest_collection_modifyitems(config, items):
    for item in items:
        if INTEGRATION_DIR in Path(item.path).parents:
            item.add_marker(pytest.mark.integration)
        elif Path(item.path).name in FLEET_MODULES and item.get_closest_marker("integration") is None:
            item.add_marker(pytest.mark.fleet)
    rank = {prefix: k for k, prefix in enumerate(SLOW_FIRST)}

    def first(item) -> int:
        return rank.get(item.nodeid.split("[")[0], len(SLOW_FIRST))

    items.sort(key=first)   # stable: every other test keeps its place


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
