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


AGENT_CLOSING = ("\x1b[2m2026-12-05T16:42:37.093659Z\x1b[0m \x1b[31mERROR\x1b[0m rx-1 ThreadId(07) "
                 "\x1b[2mzenoh::api::session\x1b[0m\x1b[2m:\x1b[0m Received Data for unknown key_expr: Remote resource 5 "
                 "not found at /root/.cargo/git/checkouts/zenoh-9c599d5ef3e0480e/cc83980/zenoh/src/api/session.rs:299.")
SIGNALLED = "2026-12-05 16:42:37,080 vsfleet.zglue.lifecycle INFO signal SIGTERM: stopping"
STOPPED = "2026-12-05 16:42:37,085 vsfleet.agent INFO agent r3 stopping after 1614 ticks, 0 rejected"


def test_zenohs_close_race_line_is_allowed_only_once_the_process_said_it_was_stopping(tmp_path_factory):
    root = tmp_path_factory.mktemp("logs")
    (root / "agent-r3.log").write_text("\n".join([SIGNALLED, STOPPED, AGENT_CLOSING]) + "\n")   # CI, 2026-12-05
    (root / "agent-r2.log").write_text("\n".join([STOPPED, AGENT_CLOSING]) + "\n")
    (root / "agent-r1.log").write_text("\n".join([AGENT_CLOSING, SIGNALLED]) + "\n")  # while it ran: not excused
    (root / "router.log").write_text("\n".join([SIGNALLED, ZENOH]) + "\n")   # another line of zenoh's: not excused
    assert error_lines(root) == [f"agent-r1.log: {AGENT_CLOSING}", f"router.log: {ZENOH}"]
    assert len(error_lines(root, closing=())) == 4


TRACKER_CLOSING = ("\x1b[2m2026-12-06T14:22:15.739191Z\x1b[0m \x1b[31mERROR\x1b[0m rx-1 ThreadId(07) "
                   "\x1b[2mzenoh::net::routing::dispatcher::pubsub\x1b[0m\x1b[2m:\x1b[0m north/98694581:1 Route data "
                   "with unknown scope 3!")
TRACKER_STOPPED = ("2026-12-06 14:22:15,737 vsfleet.tracker INFO tracker stopping after 270 frames (0 dropped), "
                   "0 rejected")


def test_the_routing_tables_close_race_line_is_allowed_only_once_the_process_said_it_was_stopping(tmp_path_factory):
    """The sim tracker behind on its truth when stopped (test_zenoh_errors beside a busy loop, 2026-12-06)."""
    root = tmp_path_factory.mktemp("logs")
    (root / "tracker.log").write_text("\n".join([SIGNALLED, TRACKER_STOPPED, TRACKER_CLOSING]) + "\n")
    (root / "tracker-cam2.log").write_text("\n".join([TRACKER_CLOSING, TRACKER_STOPPED]) + "\n")   # while it ran
    assert error_lines(root) == [f"tracker-cam2.log: {TRACKER_CLOSING}"]
    assert len(error_lines(root, closing=())) == 2
