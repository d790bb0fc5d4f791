"""A real fleet run recorded, replayed into a fresh loopback router and recorded again; plots and monitor on it."""

from __future__ import annotations

import argparse
import signal
from collections import Counter

import pytest

from vsfleet.fleetctl import replay
from vsfleet.fleetctl.monitor import FleetModel
from vsfleet.fleetctl.plot import extract, trajectory_figure
from vsfleet.fleetctl.record import LIVELINESS, RAW, Recording, read_log
from vsfleet.fleetctl.router import open_loopback_router
from vsfleet.fleetctl.run import run
from vsfleet.zglue.zconf import add_zenoh_args, zenoh_config, zenoh_flags

from .test_fleet import E2E

pytestmark = pytest.mark.integration

ROBOTS = ["r1", "r2", "r3"]


def client_config(endpoint: str):
    """The shared zenoh flags of every program, for a client of ``endpoint`` (multicast off)."""
    parser = argparse.ArgumentParser()
    add_zenoh_args(parser)
    return zenoh_config(parser.parse_args(zenoh_flags(endpoint)))


@pytest.fixture(scope="module")
def recorded_run(tmp_path_factory):
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    summary, run_dir = run(str(E2E), duration_s=6, out_dir=str(tmp_path_factory.mktemp("runs")), progress=False)
    for s, h in handlers.items():
        signal.signal(s, h)
    assert summary.children_ok
    return run_dir, read_log(run_dir / "run.mcap")


@pytest.fixture
def keep_signal_handlers():
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    yield
    for s, h in handlers.items():
        signal.signal(s, h)


def raw(records):
    return [(r.key, r.payload, r.publish_time_ns) for r in records if r.role == RAW]


def tokens(records):
    return Counter((r.key, r.alive) for r in records if r.role == LIVELINESS)


def test_the_run_record_holds_the_mission_every_robots_messages_and_the_agents_tokens(recorded_run):
    _, records = recorded_run
    kinds = Counter(r.key.split("/")[2] for r in records if r.role == RAW)
    assert kinds["mission"] == 1
    assert kinds["truth"] > 300 and kinds["pose"] > 100 and kinds["state"] > 100 and kinds["cmd"] > 100
    assert {("vs/e2e/alive/agent/" + r, True) for r in ROBOTS} <= set(tokens(records))


def test_record_replay_record_loses_no_message_and_keeps_keys_order_and_publish_times(
        recorded_run, keep_signal_handlers, tmp_path, capsys):
    run_dir, recorded = recorded_run
    first = replay.with_frames(recorded)  # what replay publishes: the record, plus frames where only poses were
    router, endpoint = open_loopback_router()
    try:
        with Recording(client_config(endpoint), tmp_path / "again.mcap", "vs/e2e/**") as rec:
            code = replay.main([str(run_dir / "run.mcap"), "--speed", "3", "--wait-subscribers", "10",
                                *zenoh_flags(endpoint)])
            assert code == 0
            assert rec.wait_count(len(first), timeout_s=30), f"{rec.count} of {len(first)} records"
    finally:
        router.close()
    second = read_log(tmp_path / "again.mcap")
    assert len(second) == len(first)
    assert raw(second) == raw(first)          # same keys, payloads and publish times, in the same order
    frames = [r for r in second if r.role == RAW and r.key.startswith("vs/e2e/frame/")]
    assert frames, "every tracker frame is on vs/<fleet>/frame/<src> after replay"
    assert tokens(second) == tokens(first)    # every token appeared and went away as recorded
    assert "ETA" in capsys.readouterr().err   # progress, a line at a time off a terminal


def test_the_run_writes_its_plots_with_one_trajectory_per_robot_and_no_fault_figure(recorded_run):
    run_dir, records = recorded_run
    assert (run_dir / "trajectories.png").stat().st_size > 10_000
    assert (run_dir / "deviation.png").stat().st_size > 10_000
    assert not (run_dir / "fault.png").exists()  # e2e-triangle has no fault
    data = extract(records)
    assert data.mission is not None and sorted(data.truth) == ROBOTS
    labels = [line.get_label() for line in trajectory_figure(data).axes[0].get_lines()]
    assert [label for label in labels if label in ROBOTS] == ROBOTS


def test_the_monitor_model_on_the_recorded_run_shows_three_live_agents_that_agree_and_reject_nothing(recorded_run):
    _, records = recorded_run
    # halfway between every agent's first state and the first agent's token going away (on a loaded
    # host the agents come up late in the run: the middle of the whole record may precede them)
    first_state: dict[str, int] = {}
    for r in records:
        if r.role == RAW and r.key.startswith("vs/e2e/state/"):
            first_state.setdefault(r.key.rsplit("/", 1)[1], r.log_time_ns)
    assert sorted(first_state) == ROBOTS
    all_up = max(first_state.values())
    gone = min((r.log_time_ns for r in records if r.role == LIVELINESS and not r.alive and r.log_time_ns > all_up
                and r.key.startswith("vs/e2e/alive/agent/")), default=records[-1].log_time_ns)
    assert gone - all_up >= 1e9, "at least a second of the run with every agent up"
    middle = (all_up + gone) // 2
    model = FleetModel("e2e")
    for r in records:
        if r.log_time_ns > middle:
            break
        if r.role == LIVELINESS:
            model.ingest_liveliness(r.t_recv_s, r.key, r.alive)
        else:
            model.ingest(r.t_recv_s, r.key, r.payload)
    view = model.view()
    assert [row.robot for row in view.robots] == ROBOTS
    for row in view.robots:
        assert row.alive is True and row.rejected == 0
        assert 20.0 <= row.pose_rate_hz <= 40.0        # the tracker runs at 30 Hz
        assert row.pose_age_s < 0.5 and row.err_m < 0.025
        assert row.vl_m_s is not None and row.vr_m_s is not None
    assert view.agents_compared == 3 and view.agreement_seq is not None and view.agreement_complete
    assert view.agreement_pos_m == 0.0 and view.agreement_th_rad == 0.0
    assert view.mission_version == 1 and view.bad_messages == 0
