"""vsfleet router: a zenoh router as a router-mode zenoh-python session (no zenohd needed).

Where zenohd is installed, ``zenohd -c deploy/router.json5`` does the same job.
The admin space is on, so ``@/**`` queries show sessions and tokens.

``open_loopback_router`` (the router the tests and benches embed) returns an EmbeddedRouter: the
session, declaring no key-expression id for what it subscribes to with a callback, so that it closes
behind its input without a zenoh ERROR line (see there why).
"""

from __future__ import annotations

import argparse
import json
import logging
import socket
import sys
import threading
import time

import zenoh

from vsfleet.zglue.lifecycle import StopFlag
from vsfleet.zglue.program import common_flags, program, refusing
from vsfleet.zglue.zconf import add_zenoh_args, open_session, zenoh_config, zenoh_flags

log = logging.getLogger("vsfleet.router")


def free_loopback_port() -> int:
    """A TCP port on 127.0.0.1 that is free right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_listening(port: int, timeout_s: float, host: str = "127.0.0.1") -> None:
    """Wait until something accepts TCP connections on host:port (or raise TimeoutError)."""
    deadline = time.monotonic() + timeout_s
    retry = threading.Event()
    while True:
        try:
            socket.create_connection((host, port), timeout=1.0).close()
            return
        except OSError:
            if time.monotonic() > deadline:
                raise TimeoutError(f"nothing listens on {host}:{port} after {timeout_s} s") from None
            retry.wait(0.05)


def loopback_router_config(port: int) -> zenoh.Config:
    """Router on tcp/127.0.0.1:port, multicast scouting off, admin space on."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("adminspace/enabled", "true")
    conf.insert_json5("transport/shared_memory/enabled", "false")   # as every program's default (zglue.zconf)
    return conf


def child_command(*args: str) -> list[str]:
    """The command line of a `vsfleet <command>` child process (run's children, the router child)."""
    return [sys.executable, "-m", "vsfleet.fleetctl.cli", *args]


def start_router_child(children, cwd=None) -> str:
    """A `vsfleet router` process on a free loopback port, multicast scouting off (as on a deployment), started as
    ``children``'s "router" (fleetctl.run.Children); waits until it listens and returns its endpoint."""
    port = free_loopback_port()
    children.start("router", child_command("router", "--listen", f"tcp/127.0.0.1:{port}", "--no-multicast-scouting"),
                   cwd=cwd)
    wait_listening(port, 30.0)
    return f"tcp/127.0.0.1:{port}"


def client_config(endpoint: str) -> zenoh.Config:
    """A client session's config for a loopback router's endpoint (the flags every child gets: zenoh_flags)."""
    p = argparse.ArgumentParser()
    add_zenoh_args(p)
    return zenoh_config(p.parse_args(zenoh_flags(endpoint)))


class EmbeddedRouter:
    """A zenoh.Session (every attribute is the session's) that can close behind its input without a
    zenoh ERROR line: `vsfleet run`'s session and the tests' embedded router.

    Why: zenoh hands a subscription's samples to the session as a key-expression id plus a suffix
    (``1`` + ``/truth/r007``), the id standing for the non-wild prefix of the subscribed key
    (``vs/demo`` for ``vs/demo/**``). Session.close forgets the session's ids and subscribers before
    its receive threads stop delivering (zenoh/src/api/session.rs, ``close_inner`` takes
    ``local_resources`` and ``remote_resources``), and the data path does not look whether the session
    is closing: a sample still on its way when the session closes finds no id 1
    (``remote_key_to_expr``) and is logged as
    ``ERROR ... Received Data for unknown key_expr: Remote resource 1 not found``, one line each. A
    session behind on its input when it closes printed hundreds (ring-100's run, 223).
    Undeclaring the subscription first shortened that window but did not close it: a sample routed
    just before the undeclare was still delivered after the close (1 run in 6 of the integration
    suite, 2026-12-04).
    So a key whose first chunk is literal is declared with that chunk as ``*`` (``*/demo/**``), which
    has no non-wild prefix: no id is declared, every sample carries its whole key, and one that
    arrives after the close is dropped without a word (0 ERROR lines in 13 closes behind the input,
    against 8 of 8 closes with the plain key, 2026-12-05). The callback sees only what the plain key
    matches: a sample whose first chunk is another is dropped before it (``*`` is exactly one chunk).
    Such a key is wider than a deployment's access control allows (``vs/<fleet>/**``), which is why
    only this wrapper does it: `vsfleet run` and the tests run without access control.
    With no id to miss, the close needs nothing before it (the undeclaring this wrapper did first,
    until 2026-12-05, is gone).
    """

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session

    def __getattr__(self, name: str):
        if name == "session":  # not set yet (a copy being made): no recursion
            raise AttributeError(name)
        return getattr(self.session, name)

    def declare_subscriber(self, key_expr, handler=None, **kwargs):
        if callable(handler):
            key_expr, handler = idless(key_expr, handler)
        return self.session.declare_subscriber(key_expr, handler, **kwargs)

    def declare_queryable(self, key_expr, handler=None, **kwargs):
        if callable(handler):
            key_expr, handler = idless(key_expr, handler, query=True)
        return self.session.declare_queryable(key_expr, handler, **kwargs)

    def liveliness(self) -> "_Liveliness":
        return _Liveliness(self.session.liveliness())

    def __enter__(self) -> "EmbeddedRouter":
        return self

    def __exit__(self, *exc) -> None:
        self.session.close()


class _Liveliness:
    """The session's liveliness(), whose subscribers declared with a callback declare no id either."""

    def __init__(self, liveliness) -> None:
        self._liveliness = liveliness

    def __getattr__(self, name: str):
        return getattr(self._liveliness, name)

    def declare_subscriber(self, key_expr, handler=None, **kwargs):
        if callable(handler):
            key_expr, handler = idless(key_expr, handler)
        return self._liveliness.declare_subscriber(key_expr, handler, **kwargs)


def idless(key_expr, handler, query: bool = False):
    """(key, callback) for a declaration that declares no key-expression id (EmbeddedRouter, why).

    ``vs/demo/**`` becomes ``*/demo/**`` and the callback gets only what ``vs/demo/**`` matches: a
    sample's key (a whole key, never wild) has ``vs`` as its first chunk; a query's key may be wild
    (``**``), so it is asked whether it intersects the plain key. A key whose first chunk is already
    wild is left as it is (it declares no id either).
    """
    key = str(key_expr)
    first, sep, rest = key.partition("/")
    if "*" in first or "$" in first:
        return key_expr, handler
    if query:
        plain = zenoh.KeyExpr(key)

        def answer(q) -> None:
            if plain.intersects(q.key_expr):
                handler(q)
        return f"*{sep}{rest}", answer
    head = first + sep

    def deliver(sample) -> None:
        k = str(sample.key_expr)
        if k.startswith(head) if sep else k == key:
            handler(sample)
    return f"*{sep}{rest}", deliver


def open_loopback_router(port: int | None = None) -> tuple[EmbeddedRouter, str]:
    """Open an embedded router on a free loopback port; returns (session, endpoint)."""
    port = port or free_loopback_port()
    session = open_session(loopback_router_config(port))
    return EmbeddedRouter(session), f"tcp/127.0.0.1:{port}"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet router", description=__doc__.splitlines()[0])
    return common_flags(p)


class RouterModeError(ValueError):
    """The flags or the config file ask for another mode than router."""


def router_config(args: argparse.Namespace) -> zenoh.Config:
    """The config from the flags and the --config file, always in router mode.

    A file that sets no ``mode`` would make zenoh open a peer, which neither routes
    for clients nor is what the access control was written for: router mode is set.
    A file or flag that asks for another mode is refused (RouterModeError).
    """
    if args.mode not in (None, "router"):
        raise RouterModeError(f"--mode {args.mode}: `vsfleet router` runs a router; drop the flag")
    if not args.config:
        args = argparse.Namespace(**{**vars(args), "mode": "router"})
    conf = zenoh_config(args)
    mode = json.loads(conf.get_json("mode"))
    if mode is None:
        conf.insert_json5("mode", '"router"')
    elif mode != "router":
        raise RouterModeError(f"{args.config} sets mode {mode!r}: `vsfleet router` runs a router; "
                              f"set \"mode\": \"router\" in it or leave mode out")
    conf.insert_json5("adminspace/enabled", "true")
    conf.insert_json5("transport/shared_memory/enabled", "false")   # as every program's default (zglue.zconf)
    return conf


@program(build_parser, log)
def main(args: argparse.Namespace) -> int:
    try:
        with refusing(RouterModeError):
            conf = router_config(args)
    except zenoh.ZError as exc:  # a config file zenoh cannot read
        log.error("cannot start the router: %s", exc)
        return 1
    session = open_session(conf)  # SessionError: one line from `vsfleet` (port in use, missing certificate)
    stop = StopFlag()
    with session:
        acl = conf.get_json("access_control/enabled") == "true"
        log.info("router up, zid %s, mode %s, access control %s", session.info.zid(),
                 json.loads(conf.get_json("mode")), "on" if acl else "off")
        while not stop.wait(1.0):
            pass
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
