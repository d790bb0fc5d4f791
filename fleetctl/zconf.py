"""One way to start every process: zenoh-python's usual flags layered into a Config.

Layering order (as zenoh-python's examples/common): the --config file, then the
flags, then each --cfg KEY:VALUE override. The default mode is client.
"""

from __future__ import annotations

import argparse
import json
import logging

import zenoh

log = logging.getLogger(__name__)

# QoS (documented in docs/protocol.md). Poses and commands are latest-value
# streams: express (no batching) and dropped under congestion rather than
# queued. Mission and events are reliable and block rather than drop.
STREAM_QOS = dict(congestion_control=zenoh.CongestionControl.DROP, express=True,
                  priority=zenoh.Priority.REAL_TIME)
TELEMETRY_QOS = dict(congestion_control=zenoh.CongestionControl.DROP, express=True,
                     priority=zenoh.Priority.DATA)
RELIABLE_QOS = dict(congestion_control=zenoh.CongestionControl.BLOCK,
                    priority=zenoh.Priority.INTERACTIVE_HIGH)


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


def zenoh_config(args: argparse.Namespace) -> zenoh.Config:
    """Build a zenoh.Config from parsed flags (file, then flags, then --cfg overrides)."""
    conf = zenoh.Config.from_file(args.config) if args.config else zenoh.Config()
    if args.mode is not None or not args.config:
        conf.insert_json5("mode", json.dumps(args.mode or "client"))
    if args.connect:
        conf.insert_json5("connect/endpoints", json.dumps(args.connect))
    if args.listen:
        conf.insert_json5("listen/endpoints", json.dumps(args.listen))
    if args.no_multicast_scouting:
        conf.insert_json5("scouting/multicast/enabled", "false")
    for item in args.cfg:
        key, sep, value = item.partition(":")
        if not sep or not key:
            raise SystemExit(f"--cfg expects KEY:VALUE, got {item!r}")
        conf.insert_json5(key, value)
    return conf


def zenoh_flags(endpoint: str) -> list[str]:
    """Command-line flags for a child process that connects as a client to ``endpoint``."""
    return ["--mode", "client", "--connect", endpoint, "--no-multicast-scouting"]


def init_logging(verbose: bool = False) -> None:
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    zenoh.init_log_from_env_or("error")
