"""vsfleet router: a zenoh router as a router-mode zenoh-python session (no zenohd needed).

Where zenohd is installed, ``zenohd -c deploy/router.json5`` does the same job.
The admin space is on, so ``@/**`` queries show sessions and tokens.

``open_loopback_router`` (the router `vsfleet run` and the tests embed) returns an EmbeddedRouter:
the session, whose close first undeclares what was declared on it with a callback (see there why).
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
    """A router-mode zenoh.Session (every attribute is the session's) that, on close, first undeclares
    the subscribers and queryables declared on it with a callback, then closes.

    Why: a subscription declares the non-wild prefix of its key as a key-expression id (``vs/demo`` for
    ``vs/demo/**``: id 1 in a session that declared nothing before), and the router hands the session
    every sample as that id plus a suffix (``1`` + ``/truth/r007``). zenoh's Session.close forgets the
    session's ids and subscribers before its router stops delivering (zenoh/src/api/session.rs,
    ``close_inner`` takes ``local_resources``), and the data path does not look whether the session is
    closing (``send_push_consume``; ``remote_key_to_expr``, session.rs:299, finds no id 1): every sample
    still queued for the session when it closes is logged as
    ``ERROR ... Received Data for unknown key_expr: Remote resource 1 not found``, one line each (a
    query to a queryable likewise). A router behind on its input when it closes, as `vsfleet run`'s is
    with 100 robots (its recorder runs on zenoh's receive threads), printed hundreds.
    Undeclared first, the subscription takes its route out of the router and what is still queued is
    dropped without a word. A subscriber or queryable declared with a callback runs on when its handle
    is dropped (zenoh-python), and `vsfleet run` keeps none, so this wrapper keeps them; one declared
    with a channel ends with its handle, which its caller holds and undeclares.
    """

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self._background: list = []  # subscribers and queryables declared with a callback
        self._lock = threading.Lock()

    def __getattr__(self, name: str):
        if name == "session":  # not set yet (a copy being made): no recursion
            raise AttributeError(name)
        return getattr(self.session, name)

    def _keep(self, entity, handler):
        if callable(handler):
            with self._lock:
                self._background.append(entity)
        return entity

    def declare_subscriber(self, key_expr, handler=None, **kwargs):
        return self._keep(self.session.declare_subscriber(key_expr, handler, **kwargs), handler)

    def declare_queryable(self, key_expr, handler=None, **kwargs):
        return self._keep(self.session.declare_queryable(key_expr, handler, **kwargs), handler)

    def liveliness(self) -> "_Liveliness":
        return _Liveliness(self.session.liveliness(), self._keep)

    def close(self) -> None:
        with self._lock:
            background, self._background = self._background, []
        for entity in reversed(background):
            try:
                entity.undeclare()
            except zenoh.ZError:  # its caller undeclared it already
                pass
        self.session.close()

    def __enter__(self) -> "EmbeddedRouter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class _Liveliness:
    """The session's liveliness(); its subscribers declared with a callback are kept for the close."""

    def __init__(self, liveliness, keep) -> None:
        self._liveliness = liveliness
        self._keep = keep

    def __getattr__(self, name: str):
        return getattr(self._liveliness, name)

    def declare_subscriber(self, key_expr, handler=None, **kwargs):
        return self._keep(self._liveliness.declare_subscriber(key_expr, handler, **kwargs), handler)


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
