"""One way to start every process: zenoh-python's usual flags layered into a Config.

Layering order (as zenoh-python's examples/common): the --config file, then the
flags, then each --cfg KEY:VALUE override. The default mode is client.
Every program opens its session with ``open_session``: without a router it fails
in one line that says what was tried and what to do (SessionError), or, with
--wait or ``connect/timeout_ms: -1``, waits for the router and says so.
"""

from __future__ import annotations

import argparse
import json
import logging
import re
import signal
import threading
import time

import zenoh

from .lifecycle import StopFlag

log = logging.getLogger(__name__)

# QoS (documented, with the fan-in measurements behind it, in docs/protocol.md). Frames and commands
# are latest-value streams, dropped under congestion rather than queued. A frame has one publisher
# and many subscribers: express (no batching). Commands and states have N publishers and one
# subscriber each (simfleet or a bridge, a monitor): N agents answering the same frame at once
# arrive together at that one session, and as express messages, one batch each, they overflowed
# its transmit and receive queues (30 trivial agents: 34 % of commands lost); batched, none was.
# Mission and events are reliable and block rather than drop.
STREAM_QOS = dict(congestion_control=zenoh.CongestionControl.DROP, express=True,
                  priority=zenoh.Priority.REAL_TIME)
COMMAND_QOS = dict(congestion_control=zenoh.CongestionControl.DROP, express=False,
                   priority=zenoh.Priority.REAL_TIME)
TELEMETRY_QOS = dict(congestion_control=zenoh.CongestionControl.DROP, express=False,
                     priority=zenoh.Priority.DATA)
# Per-robot messages that go out N at a time, once per tick (simfleet's truth/<robot>, a tracker's
# pose/<robot>): batched (not express), so a burst of 100 is one or a few writes instead of 100 express
# batches that overflow the 2-batch queue and are dropped. Each is still its own sample. Express, simfleet's
# 100 truths a tick reached the sim tracker late or not at all: 64 % of ring-100's frames lacked robots
# (docs/protocol.md, QoS).
BURST_QOS = dict(congestion_control=zenoh.CongestionControl.DROP, express=False,
                 priority=zenoh.Priority.DATA)
RELIABLE_QOS = dict(congestion_control=zenoh.CongestionControl.BLOCK,
                    priority=zenoh.Priority.INTERACTIVE_HIGH)


class ZenohConfigError(ValueError):
    """A --config file or a flag that zenoh cannot take."""


def add_zenoh_args(parser: argparse.ArgumentParser) -> None:
    """Add --mode, --connect, --listen, --config, --no-multicast-scouting, --cfg."""
    g = parser.add_argument_group("zenoh")
    g.add_argument("--mode", "-m", choices=["peer", "client", "router"], default=None,
                   help="zenoh session mode (default: client, or the config file's)")
    g.add_argument("--connect", "-e", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    g.add_argument("--listen", "-l", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable)")
    g.add_argument("--config", "-c", metavar="FILE", help="zenoh JSON5 config file")
    g.add_argument("--no-multicast-scouting", action="store_true",
                   help="disable multicast scouting")
    g.add_argument("--cfg", action="append", default=[], metavar="KEY:VALUE",
                   help="config override, VALUE is JSON5, e.g. --cfg 'scouting/gossip/enabled:false'")
    g.add_argument("--wait", action="store_true",
                   help="wait for the router however long it takes, logging every few seconds "
                        "(same as --cfg connect/timeout_ms:-1); default: fail at once if none is reachable")


#: how often a session tries its router again after losing it: from 0.25 s, growing 1.5x to at most 0.5 s, so that
#: a fleet's sessions are back within about 0.5 s of a restarted router (zenoh's own default starts at 1 s and
#: doubles to 4 s: 30 agents came back 2.15-2.32 s after a restart, tests/integration/test_router_restart_30.py;
#: at most 1 s: 0.3-0.7 s on a quiet host, 2.31 s beside a busy loop, the slowest sessions' tries falling just
#: before the new router listened and the next one 1 s later)
RECONNECT_RETRY = "{period_init_ms: 250, period_max_ms: 500, period_increase_factor: 1.5}"
# Shared memory is off unless a config file turns it on: every session that talks to a process over SHM has
# that process map its 16 MiB pool, and keep it mapped after the session ends; bench/soak.py's 29 fuzzer
# sessions grew simfleet's RSS by 17.25 MiB each (+617 MiB in 30 min). Our messages are small (a frame of
# 100 robots is 4 KiB): the network path costs them nothing that matters.


def zenoh_config(args: argparse.Namespace, defaults: tuple[tuple[str, str], ...] = ()) -> zenoh.Config:
    """Build a zenoh.Config from parsed flags (file, then flags, then --cfg overrides).

    ``defaults``: a program's own (key, JSON5 value) settings, taken like ours above: only without a --config
    file, and under the flags and --cfg."""
    try:
        conf = zenoh.Config.from_file(args.config) if args.config else zenoh.Config()
    except zenoh.ZError as exc:
        raise ZenohConfigError(f"cannot read the zenoh config {args.config}: {_zenoh_reason(exc)}") from None
    settings = []
    if not args.config:  # the program's own first: every flag below, and --cfg, override them
        settings.extend(("(default)", key, value) for key, value in defaults)
    if args.mode is not None or not args.config:
        settings.append(("--mode", "mode", json.dumps(args.mode or "client")))
    if not args.config:  # a file's own settings stand; --cfg overrides either
        settings.append(("(default)", "connect/retry", RECONNECT_RETRY))
        settings.append(("(default)", "transport/shared_memory/enabled", "false"))
    if args.connect:
        settings.append(("--connect", "connect/endpoints", json.dumps(args.connect)))
    if args.listen:
        settings.append(("--listen", "listen/endpoints", json.dumps(args.listen)))
    if args.no_multicast_scouting:
        settings.append(("--no-multicast-scouting", "scouting/multicast/enabled", "false"))
    if getattr(args, "wait", False):
        settings.append(("--wait", "connect/timeout_ms", "-1"))
    for item in args.cfg:
        key, sep, value = item.partition(":")
        if not sep or not key:
            raise ZenohConfigError(f"--cfg expects KEY:VALUE, got {item!r}")
        settings.append((f"--cfg {item}", key, value))
    for flag, key, value in settings:
        try:
            conf.insert_json5(key, value)
        except zenoh.ZError as exc:
            raise ZenohConfigError(f"{flag}: zenoh rejects {key} = {value}: {_zenoh_reason(exc)}") from None
    return conf


def zenoh_flags(endpoint: str) -> list[str]:
    """Command-line flags for a child process that connects as a client to ``endpoint``."""
    return ["--mode", "client", "--connect", endpoint, "--no-multicast-scouting"]


def init_logging(verbose: bool = False) -> None:
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    zenoh.init_log_from_env_or("error")


START_ROUTER_HINT = "start one with `vsfleet router --listen tcp/0.0.0.0:7447`"
CONNECT_HINT = "point at one with `--connect tcp/HOST:7447`"
WAIT_LOG_EVERY_S = 5.0
SIGNAL_POLL_S = 0.05  # how often a program waiting for its router looks at whether it was asked to stop


class SessionError(ConnectionError):
    """zenoh could not open the session; the message (one line) says what was tried and what to do."""


class StoppedWaiting(Exception):
    """SIGTERM or SIGINT arrived while the program was waiting for its router: nothing was opened.

    open_pending: zenoh.open still blocks in its worker thread; the interpreter's normal exit can
    then hang on zenoh's runtime, so the program should end with os._exit once it has said why."""

    open_pending = False


def _get(conf: zenoh.Config, key: str, mode: str):
    """A config value as Python (None if unset); per-mode values ({router, peer, client}) resolved for ``mode``."""
    try:
        value = json.loads(conf.get_json(key))
    except (zenoh.ZError, ValueError):
        return None
    if isinstance(value, dict) and mode in value:
        value = value[mode]
    return value


def session_mode(conf: zenoh.Config) -> str:
    """The mode zenoh will open: the config's, else zenoh's default (peer)."""
    return _get(conf, "mode", "peer") or "peer"


def waits_for_router(conf: zenoh.Config) -> bool:
    """True if the config asks to wait without limit for the first connection (connect/timeout_ms: -1)."""
    return _get(conf, "connect/timeout_ms", session_mode(conf)) == -1


def describe_target(conf: zenoh.Config) -> str:
    """What the session tries to reach, for a one-line message: the mode, then the endpoints or the scouting."""
    mode = session_mode(conf)
    endpoints = _get(conf, "connect/endpoints", mode) or []
    if mode == "router" and not endpoints:
        listen = _get(conf, "listen/endpoints", mode) or ["zenoh's default listener"]
        return f"mode router, listening on {', '.join(map(str, listen))}"
    if endpoints:
        return f"mode {mode}, tried {', '.join(map(str, endpoints))}"
    if _get(conf, "scouting/multicast/enabled", mode) is False:
        return f"mode {mode}, no --connect endpoint and multicast scouting off"
    timeout_ms = _get(conf, "scouting/timeout", mode)
    timeout_ms = 3000 if timeout_ms is None else timeout_ms  # zenoh's default
    within = f" for {timeout_ms / 1000:g} s" if isinstance(timeout_ms, (int, float)) else ""
    return f"mode {mode}, scouted by multicast{within} and found none"


def _zenoh_reason(exc: BaseException) -> str:
    """zenoh's error text without its Rust source location (`` at /.../orchestrator.rs:447.``)."""
    return re.sub(r"\s+at \S+\.rs:\d+\.?", "", str(exc)).strip()


def describe_failure(conf: zenoh.Config, exc: BaseException | None = None) -> str:
    """One line: why the session did not open, what was tried, and what to do about it."""
    mode = session_mode(conf)
    target = describe_target(conf)
    reason = _zenoh_reason(exc) if exc is not None else ""
    if mode == "router":
        hint = ("; another program listens there: stop it, or give another `--listen tcp/0.0.0.0:PORT`"
                if "in use" in reason else "")
        return f"cannot start a zenoh router ({target}): {reason or 'zenoh refused'}{hint}"
    unreachable = not reason or re.search(r"Unable to connect|[Tt]imeout|No peer specified", reason)
    what = "no zenoh router reachable" if unreachable else f"cannot open a zenoh session: {reason}"
    line = f"{what} ({target}); {START_ROUTER_HINT}, {CONNECT_HINT}, or add --wait to wait for it"
    if unreachable and _get(conf, "transport/auth/usrpwd/user", mode):
        line += "; if the router is up, check the login (transport/auth) in the config"
    return line


def open_session(conf: zenoh.Config, *, log_every_s: float = WAIT_LOG_EVERY_S) -> zenoh.Session:
    """``zenoh.open(conf)`` for every program: SessionError (one line) if no router is reachable.

    With ``connect/timeout_ms: -1`` (--wait) it waits instead, logging every ``log_every_s`` [s];
    SIGTERM or SIGINT while waiting raises StoppedWaiting. The session is a context manager.
    """
    if not waits_for_router(conf):
        try:
            return zenoh.open(conf)
        except zenoh.ZError as exc:
            raise SessionError(describe_failure(conf, exc)) from None
    return _open_waiting(conf, log_every_s)


def _open_waiting(conf: zenoh.Config, log_every_s: float) -> zenoh.Session:
    """Open in a worker thread (zenoh blocks until connected) while this thread logs and stays interruptible."""
    scouting = not _get(conf, "connect/endpoints", session_mode(conf))
    target = (f"mode {session_mode(conf)}, scouting by multicast" if scouting
              else describe_target(conf).replace("tried ", "at "))
    done, abandoned = threading.Event(), threading.Event()
    result: dict = {}

    def work() -> None:
        while not abandoned.is_set():
            try:
                session = zenoh.open(conf)
            except zenoh.ZError as exc:  # scouting timed out: scout again; anything else is for the caller
                if scouting and re.search(r"[Tt]imeout", str(exc)):
                    abandoned.wait(1.0)
                    continue
                result["error"] = exc
                break
            if abandoned.is_set():
                session.close()
                return
            result["session"] = session
            break
        done.set()

    stopped: list[int] = []  # the signal that asked to stop; the handler only records it

    def on_signal(signum, _frame) -> None:
        # never raise here: the signal may land inside a log call, and logging swallows what its
        # handlers raise (it printed "--- Logging error ---" and the program waited on)
        stopped.append(signum)

    def stop() -> StoppedWaiting:
        return StoppedWaiting(f"stopped by {signal.Signals(stopped[0]).name} while waiting for a zenoh router "
                              f"({target})")

    in_main = threading.current_thread() is threading.main_thread()
    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)} if in_main else {}
    # a signal the program's own StopFlag took before this handler was in place (run_agent makes its StopFlag, then
    # opens its session): a forked agent told to stop at once waited for its router for ever (a CI rehearsal under a
    # busy loop, 2026-12-07: SIGTERM came 0.5 s after the fork, inside that window)
    for handler in previous.values():
        flag = getattr(handler, "__self__", None)
        if isinstance(flag, StopFlag) and flag.signalled is not None and not stopped:
            stopped.append(flag.signalled)
    t0 = time.monotonic()
    worker = threading.Thread(target=work, name="zenoh-open", daemon=True)
    try:
        worker.start()
        log.info("waiting for a zenoh router (%s); %s, %s; Ctrl-C to stop", target, START_ROUTER_HINT,
                 CONNECT_HINT)
        next_log = t0 + log_every_s
        while not done.wait(SIGNAL_POLL_S):
            if stopped:
                raise stop()
            if time.monotonic() >= next_log:
                next_log += log_every_s
                log.info("still waiting for a zenoh router (%s): %.0f s so far", target, time.monotonic() - t0)
        if stopped:  # asked to stop as the session opened: close it
            if "session" in result:
                result.pop("session").close()
            raise stop()
    except BaseException as exc:
        abandoned.set()
        if isinstance(exc, StoppedWaiting):  # the worker may be inside zenoh.open, or closing what it opened
            exc.open_pending = worker.is_alive()
        raise
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    if "error" in result:
        raise SessionError(describe_failure(conf, result["error"]))
    log.info("connected to the zenoh router after %.1f s of waiting", time.monotonic() - t0)
    return result["session"]
