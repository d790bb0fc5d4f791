"""The suite's own guard: a multi-process test fails on any error line its processes log that it did not provoke
(tests/integration/conftest.py: error_lines, the autouse fixture no_unprovoked_errors)."""

from __future__ import annotations

import pytest

from .conftest import error_lines

pytestmark = pytest.mark.integration

ZENOH = ("\x1b[2m2026-12-04T15:01:02.123Z\x1b[0m \x1b[31mERROR\x1b[0m \x1b[2mThreadId(12)\x1b[0m "
         "zenoh::net::routing::dispatcher::pubsub: Received Data for unknown key_expr: Remote resource 1 not found")
OURS = "2026-12-04 15:01:02,123 vsfleet.agent ERROR frame 12: the step raised"
TRACE = "Traceback (most recent call last):"
FINE = ["2026-12-04 15:01:02,123 vsfleet.agent INFO 0 errors so far", "ERRORS_SEEN=0", "rejected: error_count 3"]


def test_zenoh_and_our_own_error_lines_and_tracebacks_are_caught_and_ordinary_lines_are_not(tmp_path_factory):
    root = tmp_path_factory.mktemp("logs")        # not the test's tmp_path, which the guard itself reads
    (root / "run" / "demo").mkdir(parents=True)
    (root / "agent-r1.log").write_text("\n".join([*FINE, OURS, TRACE]) + "\n")
    (root / "run" / "demo" / "router.log").write_text(ZENOH + "\n")
    bad = error_lines(root)
    assert bad == [f"agent-r1.log: {OURS}", f"agent-r1.log: {TRACE}", f"run/demo/router.log: {ZENOH}"]


def test_an_error_the_test_provokes_on_purpose_is_allowed_by_its_pattern(tmp_path_factory):
    root = tmp_path_factory.mktemp("logs")
    (root / "router.log").write_text(ZENOH + "\n" + OURS + "\n")
    assert error_lines(root, allowed=[r"unknown key_expr"]) == [f"router.log: {OURS}"]
    assert error_lines(root, allowed=[r"unknown key_expr", r"the step raised"]) == []
