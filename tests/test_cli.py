"""The `vsfleet` entry point and the session helpers, in-process: version, one-line errors, --verbose.

A fake program module (written to tmp_path and put on sys.path) stands in for a subcommand, so each
error path is exercised without zenoh or a router.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json

import pytest
import zenoh

from vsfleet.fleetctl import cli
from vsfleet.zglue.zconf import (CONNECT_HINT, START_ROUTER_HINT, SessionError, ZenohConfigError, add_zenoh_args,
                            describe_failure, describe_target, waits_for_router, zenoh_config)


def config(*flags: str) -> zenoh.Config:
    p = argparse.ArgumentParser()
    add_zenoh_args(p)
    return zenoh_config(p.parse_args(list(flags)))


def test_version_prints_the_installed_packages_version(capsys):
    assert cli.main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"vsfleet {importlib.metadata.version('vsfleet')}"


FAKE = '''
import sys
from vsfleet.zglue.zconf import SessionError, StoppedWaiting

def main(argv):
    kind = argv[0]
    if kind == "bug":
        raise KeyError("the key that was not there")
    if kind == "nosession":
        raise SessionError("no zenoh router reachable (mode client, tried tcp/127.0.0.1:1)")
    if kind == "stopped":
        raise StoppedWaiting("stopped by SIGTERM while waiting for a zenoh router")
    if kind == "exit-text":
        raise SystemExit("--cfg expects KEY:VALUE")
    if kind == "interrupt":
        raise KeyboardInterrupt
    if kind == "argv":
        print(" ".join(argv))
    return 0
'''


@pytest.fixture
def fake_command(tmp_path, monkeypatch):
    (tmp_path / "fake_vsfleet_program.py").write_text(FAKE)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(cli.COMMANDS, "fake", ("fake_vsfleet_program", "a test stand-in"))
    return "fake"


@pytest.mark.parametrize("kind, code, line", [
    ("bug", 1, "vsfleet fake: unexpected error: KeyError: 'the key that was not there' "
               "(run `vsfleet fake ... --verbose` for the traceback)"),
    ("nosession", 2, "vsfleet fake: no zenoh router reachable (mode client, tried tcp/127.0.0.1:1)"),
    ("stopped", 0, "vsfleet fake: stopped by SIGTERM while waiting for a zenoh router"),
    ("exit-text", 2, "vsfleet fake: --cfg expects KEY:VALUE"),
    ("interrupt", 130, "vsfleet fake: interrupted"),
])
def test_every_error_reaches_the_user_as_one_line_without_a_traceback(fake_command, capsys, kind, code, line):
    assert cli.main([fake_command, kind]) == code
    err = capsys.readouterr().err
    assert err.splitlines() == [line]


@pytest.mark.parametrize("argv", [["--verbose", "fake", "bug"], ["fake", "bug", "--verbose"], ["-v", "fake", "bug"]])
def test_verbose_before_or_after_the_command_shows_the_traceback_of_an_unexpected_error(fake_command, capsys, argv):
    assert cli.main(argv) == 1
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and "KeyError" in err
    assert err.splitlines()[-1] == "vsfleet fake: unexpected error: KeyError: 'the key that was not there'"


def test_an_unknown_command_is_named_and_exits_2(capsys):
    assert cli.main(["frobnicate"]) == 2
    assert capsys.readouterr().err.startswith("vsfleet: unknown command 'frobnicate'")


def test_wait_and_a_timeout_of_minus_one_in_the_config_both_mean_waiting(tmp_path):
    assert not waits_for_router(config("--connect", "tcp/127.0.0.1:1"))
    assert waits_for_router(config("--connect", "tcp/127.0.0.1:1", "--wait"))
    assert waits_for_router(config("--cfg", "connect/timeout_ms:-1"))
    robot = tmp_path / "robot.json5"  # as deploy/robot-client.json5, without the login
    robot.write_text(json.dumps({"mode": "client", "connect": {"endpoints": ["tcp/10.0.0.1:7447"], "timeout_ms": -1}}))
    assert waits_for_router(config("--config", str(robot)))
    operator = tmp_path / "operator.json5"
    operator.write_text(json.dumps({"mode": "client", "connect": {"timeout_ms": 10000}}))
    assert not waits_for_router(config("--config", str(operator)))
    assert waits_for_router(config("--config", str(operator), "--wait"))


def test_the_failure_line_names_the_mode_and_endpoints_or_the_scouting_and_what_to_do():
    tried = config("--connect", "tcp/127.0.0.1:1", "--connect", "tcp/10.0.0.1:7447")
    assert describe_target(tried) == "mode client, tried tcp/127.0.0.1:1, tcp/10.0.0.1:7447"
    assert describe_target(config()) == "mode client, scouted by multicast for 3 s and found none"
    assert describe_target(config("--no-multicast-scouting")) == \
        "mode client, no --connect endpoint and multicast scouting off"
    line = describe_failure(tried, zenoh.ZError("Unable to connect to any of [...]!  at /x/orchestrator.rs:447."))
    assert line == (f"no zenoh router reachable (mode client, tried tcp/127.0.0.1:1, tcp/10.0.0.1:7447); "
                    f"{START_ROUTER_HINT}, {CONNECT_HINT}, or add --wait to wait for it")
    other = describe_failure(tried, zenoh.ZError("Failed to load certificate at /src/tls.rs:12."))
    assert other.startswith("cannot open a zenoh session: Failed to load certificate (mode client")


def test_flags_zenoh_rejects_are_one_line_config_errors(tmp_path):
    with pytest.raises(ZenohConfigError, match=r"--cfg nope:1: zenoh rejects nope = 1"):
        config("--cfg", "nope:1")
    with pytest.raises(ZenohConfigError, match="--cfg expects KEY:VALUE"):
        config("--cfg", "nope")
    with pytest.raises(ZenohConfigError, match="cannot read the zenoh config"):
        config("--config", str(tmp_path / "missing.json5"))
    assert issubclass(SessionError, ConnectionError) and issubclass(ZenohConfigError, ValueError)


@pytest.mark.parametrize("argv, passed", [
    (["--verbose", "fake", "argv", "x"], "argv x --verbose"),
    (["-v", "fake", "argv", "-v"], "argv -v"),
    (["fake", "argv", "--verbose"], "argv --verbose"),
    (["fake", "argv", "x"], "argv x"),
])
def test_verbose_before_the_command_reaches_the_programs_own_flag(fake_command, capsys, argv, passed):
    assert cli.main(argv) == 0
    assert capsys.readouterr().out.strip() == passed


@pytest.mark.parametrize("name", list(cli.COMMANDS))
def test_every_program_takes_verbose(name):
    """`vsfleet --verbose CMD` passes --verbose on to every program (zglue.program.common_flags)."""
    import importlib

    module = importlib.import_module(cli.COMMANDS[name][0])
    options = {s for action in module.build_parser()._actions for s in action.option_strings}
    assert {"--verbose", "-v"} <= options


def test_every_program_opens_its_session_through_open_session():
    """A new program that called zenoh.open itself would crash with zenoh's traceback without a router."""
    from pathlib import Path

    root = Path(__file__).parent.parent
    offenders = [str(f.relative_to(root)) for d in ("agent", "simfleet", "tracker", "fleetctl")
                 for f in sorted((root / d).rglob("*.py"))
                 if f.name != "zconf.py" and "zenoh.open(" in f.read_text()]
    assert offenders == []


def test_help_prints_the_usage_and_exits_0(capsys):
    assert cli.main(["--help"]) == 0
    assert capsys.readouterr().err.startswith("usage: vsfleet [--version] [--verbose] COMMAND")


def end_abandoned_waits(port: int) -> None:
    """A router on ``port``: the abandoned zenoh.open of a stopped wait connects, its worker closes the session and
    ends; waits for those workers."""
    import threading

    router = zenoh.open(config("--mode", "router", "--listen", f"tcp/127.0.0.1:{port}", "--no-multicast-scouting"))
    for worker in [t for t in threading.enumerate() if t.name == "zenoh-open"]:
        worker.join(timeout=30)
    router.close()


def test_a_signal_the_programs_stop_flag_took_before_the_wait_began_stops_the_wait():
    """run_agent makes its StopFlag (its SIGTERM handler), then opens its session: a SIGTERM between the two was
    recorded by the flag, which the wait for the router did not read, so a forked agent told to stop at once waited
    for ever (a CI rehearsal with a busy core, 2026-12-07). The wait now takes a signal its predecessor recorded."""
    import signal
    import threading
    import time

    from vsfleet.fleetctl.router import free_loopback_port
    from vsfleet.zglue.lifecycle import StopFlag
    from vsfleet.zglue.zconf import StoppedWaiting, _open_waiting

    port = free_loopback_port()
    before = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        flag = StopFlag()
        signal.raise_signal(signal.SIGTERM)   # handled now, by the flag's handler: recorded, nothing else
        assert flag.signalled == signal.SIGTERM
        t0 = time.monotonic()
        with pytest.raises(StoppedWaiting) as stopped:
            _open_waiting(config("--mode", "client", "--connect", f"tcp/127.0.0.1:{port}",
                                 "--no-multicast-scouting", "--wait"), log_every_s=0.2)
        assert time.monotonic() - t0 < 5.0
        assert "stopped by SIGTERM" in str(stopped.value)
        assert signal.getsignal(signal.SIGTERM) == flag._on_signal   # the program's own handler, back in place
    finally:
        for s, h in before.items():
            signal.signal(s, h)
        end_abandoned_waits(port)
    assert not any(t.name == "zenoh-open" for t in threading.enumerate())


def test_a_signal_that_lands_inside_a_log_call_while_waiting_still_stops_the_wait(caplog):
    """SIGTERM delivered while the waiting loop writes its "still waiting" line: logging swallows what
    a handler raises, so a signal handler that raised lost the stop and the program waited on (seen in
    two CI rehearsals). The handler only records the signal; the loop then stops within a poll."""
    import logging
    import os
    import signal
    import threading
    import time

    from vsfleet.fleetctl.router import free_loopback_port
    from vsfleet.zglue.zconf import StoppedWaiting, _open_waiting

    port = free_loopback_port()
    signalled: list[float] = []

    class SignalInsideEmit(logging.Handler):
        def emit(self, record):
            try:  # as logging.StreamHandler does: whatever emit raises goes to handleError
                if "still waiting" in record.getMessage() and not signalled:
                    signalled.append(time.monotonic())
                    os.kill(os.getpid(), signal.SIGTERM)
                    for _ in range(10_000):  # the signal is handled here, inside emit
                        pass
            except Exception:  # noqa: BLE001
                self.handleError(record)

    logger = logging.getLogger("vsfleet.zglue.zconf")
    handler = SignalInsideEmit()
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    # a second SIGTERM 3 s later, outside any log call: a wait that lost the first one ends then, late
    watchdog = threading.Timer(3.0, lambda: os.kill(os.getpid(), signal.SIGTERM))
    try:
        watchdog.start()
        with pytest.raises(StoppedWaiting) as stopped:
            _open_waiting(config("--mode", "client", "--connect", f"tcp/127.0.0.1:{port}",
                                 "--no-multicast-scouting", "--wait"), log_every_s=0.2)
        took_s = time.monotonic() - signalled[0]
        watchdog.cancel()
        assert took_s < 1.0, f"stopped {took_s:.2f} s after the first SIGTERM"
        assert "stopped by SIGTERM" in str(stopped.value) and stopped.value.open_pending
    finally:
        watchdog.cancel()
        logger.removeHandler(handler)
        end_abandoned_waits(port)
    assert not any(t.name == "zenoh-open" for t in threading.enumerate())


def test_every_command_dispatches_to_an_installed_vsfleet_module():
    """Each target is a vsfleet.* module the wheel installs (a top-level ``fleetctl.bridge_ros2`` imported
    only from the checkout's root), found without importing it, in a program or a tool."""
    import importlib.util

    for name, (module, _) in cli.COMMANDS.items():
        assert module.split(".")[:2] in (["vsfleet", room] for room in ("agent", "simfleet", "tracker", "fleetctl")), \
            (name, module)
        assert importlib.util.find_spec(module) is not None, (name, module)


def test_without_a_config_file_sessions_retry_a_lost_router_quickly_and_announce_no_shared_memory(tmp_path):
    """zglue.zconf's defaults (a file's own settings stand, --cfg overrides either): reconnect from 0.25 s (the
    30-agent router restart: back in 0.3-0.7 s, not 2.2 s) and no shared memory (bench/soak.py: each fuzzer
    session's 16 MiB pool stayed mapped in simfleet, +17 MiB a session)."""
    import argparse
    import json

    from vsfleet.zglue.zconf import add_zenoh_args, zenoh_config

    parser = argparse.ArgumentParser()
    add_zenoh_args(parser)
    conf = zenoh_config(parser.parse_args([]))
    assert json.loads(conf.get_json("transport/shared_memory/enabled")) is False
    assert json.loads(conf.get_json("connect/retry")) == {"period_init_ms": 250, "period_max_ms": 500,
                                                          "period_increase_factor": 1.5}
    conf = zenoh_config(parser.parse_args(["--cfg", "transport/shared_memory/enabled:true"]))
    assert json.loads(conf.get_json("transport/shared_memory/enabled")) is True
    path = tmp_path / "z.json5"
    path.write_text('{mode: "client"}')
    conf = zenoh_config(parser.parse_args(["--config", str(path)]))
    assert json.loads(conf.get_json("transport/shared_memory/enabled")) is True   # zenoh's own default


def test_simfleet_keeps_a_deep_transmit_queue_for_its_truth_bursts_unless_a_config_file_or_cfg_says_otherwise(
        tmp_path):
    """simfleet's own zenoh default (SIM_ZENOH_DEFAULTS: 16 batches of priority data, where truth/<robot> goes;
    2 dropped part of a tick's 100 truths on a loaded host) is taken like zconf's: not over a --config file's
    settings, and under --cfg. Another program keeps zenoh's 2."""
    import json

    from vsfleet.simfleet.main import SIM_ZENOH_DEFAULTS, build_parser
    from vsfleet.zglue.zconf import zenoh_config

    key = "transport/link/tx/queue/size/data"

    def batches(*flags: str, defaults=SIM_ZENOH_DEFAULTS) -> int:
        conf = zenoh_config(build_parser().parse_args(["scenario.toml", *flags]), defaults)
        return json.loads(conf.get_json(key))

    assert batches() == 16
    assert batches("--cfg", f"{key}:4") == 4
    path = tmp_path / "z.json5"
    path.write_text('{mode: "client"}')
    assert batches("--config", str(path)) == 2
    assert batches(defaults=()) == 2
