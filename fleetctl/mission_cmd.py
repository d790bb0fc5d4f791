"""vsfleet mission set FILE: publish a mission (TOML scenario or msgpack/JSON mission) reliably.

The mission's ``version`` defaults to the current UNIX time in milliseconds (so
it increases), and ``effective_t`` to now + --delay seconds. Agents answer
mission queries themselves (each under ``vs/<fleet>/peer/<robot>/mission``; a late
joiner takes the answer of a majority of them), so late joiners get it without
this process.

Before publishing it checks the mission's robots against the fleet's live agents
(their liveliness tokens) and refuses a mismatch with a clear message; --force
publishes anyway (for example before the agents start, when nothing can check).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
from pathlib import Path

import zenoh

from vsfleet.wire import Keys, Mission, encode_mission, mission_from_dict

from vsfleet.zglue.lifecycle import wall_clock
from vsfleet.zglue.program import Refused, common_flags, program
from vsfleet.zglue.scenario_file import load_scenario
from vsfleet.zglue.zconf import RELIABLE_QOS, open_session, zenoh_config

log = logging.getLogger("vsfleet.mission")


def load_mission(path: str) -> Mission:
    p = Path(path)
    if p.suffix == ".toml":
        return load_scenario(p).mission
    return mission_from_dict(json.loads(p.read_text()))


def stamp(mission: Mission, now_s: float, delay_s: float, version: int | None = None) -> Mission:
    """A copy with version (default: now in ms) and effective_t = now + delay [s]."""
    return dataclasses.replace(mission, version=int(now_s * 1000) if version is None else version,
                               effective_t=now_s + delay_s)


def live_agents(session: zenoh.Session, keys: Keys, timeout_s: float = 2.0) -> set[str]:
    """Robot ids of the agents whose liveliness tokens are up now."""
    prefix = keys.alive("agent", "")
    return {str(r.ok.key_expr)[len(prefix):] for r in
            session.liveliness().get(keys.alive("agent"), timeout=timeout_s) if r.ok is not None}


def robot_set_mismatch(mission: Mission, live: set[str]) -> str | None:
    """Why the mission's robots do not match the live agents, or None when they do."""
    named = set(mission.robot_ids)
    if named == live:
        return None
    parts = []
    if named - live:
        parts.append(f"names robots with no live agent: {sorted(named - live)}")
    if live - named:
        parts.append(f"leaves out live agents: {sorted(live - named)}")
    return "the mission " + " and ".join(parts)


def publish_mission(session: zenoh.Session, keys: Keys, mission: Mission) -> None:
    session.put(keys.mission, encode_mission(mission), **RELIABLE_QOS)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet mission set", description=__doc__.splitlines()[0])
    p.add_argument("file", help="scenario .toml (its [mission] and [robots]) or mission .json")
    p.add_argument("--fleet", default="demo")
    p.add_argument("--delay", type=float, default=0.5, help="effective_t = now + delay [s]")
    p.add_argument("--version", type=int, default=None)
    p.add_argument("--force", action="store_true",
                   help="publish even if the mission's robots do not match the live agents")
    return common_flags(p)


@program(build_parser, log)
def main(args: argparse.Namespace) -> int:
    try:
        mission = stamp(load_mission(args.file), wall_clock(), args.delay, args.version)
        keys = Keys(args.fleet)
    except (OSError, ValueError) as exc:
        raise Refused(f"cannot load mission: {exc}") from exc
    with open_session(zenoh_config(args)) as session:
        if not args.force:
            why = robot_set_mismatch(mission, live_agents(session, keys))
            if why is not None:
                raise Refused(f"{why}; nothing published (use --force to publish anyway)")
        publish_mission(session, keys, mission)
    log.info("published mission v%d on %s", mission.version, keys.mission)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
