"""vsfleet router: a zenoh router as a router-mode zenoh-python session (no zenohd needed).

Where zenohd is installed, ``zenohd -c deploy/router.json5`` does the same job.
The admin space is on, so ``@/**`` queries show sessions and tokens.
"""

from __future__ import annotations

import argparse
import json
import logging
import socket
import threading
import time

import zenoh

from vsfleet.zglue.lifecycle import StopFlag
from vsfleet.zglue.program import common_flags, program, refusing
from vsfleet.zglue.zconf import open_session, zenoh_config

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
    return conf


def open_loopback_router(port: int | None = None) -> tuple[zenoh.Session, str]:
    """Open an embedded router on a free loopback port; returns (session, endpoint)."""
    port = port or free_loopback_port()
    session = open_session(loopback_router_config(port))
    return session, f"tcp/127.0.0.1:{port}"


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
