"""The far end of the Zenoh floor benchmark: echo every vs/<fleet>/bench/ping on .../bench/pong.

A client of the same router as the agents, started the same way (a Python
process, the agents' QoS for poses and commands), but the reply is put straight
from the subscriber callback: no decoding, no queue, no control step. Run by
bench/loop.py; stops on SIGTERM.
"""

from __future__ import annotations

import argparse

import zenoh

from vsfleet.zglue.lifecycle import StopFlag
from vsfleet.zglue.zconf import STREAM_QOS, add_zenoh_args, init_logging, open_session, zenoh_config
from vsfleet.wire import Keys


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="zenoh_pong", description=__doc__.splitlines()[0])
    p.add_argument("--fleet", default="bench")
    add_zenoh_args(p)
    args = p.parse_args(argv)
    init_logging()
    keys = Keys(args.fleet)
    stop = StopFlag()
    with open_session(zenoh_config(args)) as session:
        pub = session.declare_publisher(f"{keys.prefix}/bench/pong", **STREAM_QOS)
        sub = session.declare_subscriber(f"{keys.prefix}/bench/ping", lambda s: pub.put(s.payload))
        token = session.liveliness().declare_token(keys.alive("pong", "0"))
        while not stop.wait(0.5):
            pass
        token.undeclare()
        sub.undeclare()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
