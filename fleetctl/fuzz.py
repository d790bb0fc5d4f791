"""vsfleet fuzz: throw invalid messages at every key the programs subscribe to.

Keys fuzzed: ``pose/<robot>`` and ``mission`` (agents), ``fault/<robot>`` and
``cmd/<robot>`` (simfleet). Every payload is invalid
by construction (a test decodes each one), so a correct fleet rejects, counts
and logs it and keeps formation. Categories: random bytes, truncated msgpack,
wrong types, NaN/inf, huge numbers, unknown robot ids, oversized payloads; the
rate (per key) is set so that a flood is 10x the tracker's rate. Before it closes,
it waits until the router has routed every put (RouterBarrier). At exit it prints
one JSON line: what it sent, per key kind and category, and whether the router
confirmed it routed all of it.
"""

from __future__ import annotations

import argparse
import json
import logging
import random
import threading
from collections import Counter

import msgpack
import zenoh

from vsfleet.wire import (
    MAX_FRAME_BYTES,
    MAX_MISSION_BYTES,
    MAX_PAYLOAD_BYTES,
    CmdMsg,
    FaultMsg,
    Keys,
    Mission,
    PoseMsg,
    RobotSpec,
    check_name,
    encode,
    encode_mission,
)

from vsfleet.zglue.lifecycle import StopFlag, pace, wall_clock
from vsfleet.zglue.program import common_flags, program, refusing
from vsfleet.zglue.zconf import RELIABLE_QOS, open_session, zenoh_config

log = logging.getLogger("vsfleet.fuzz")

KINDS = ("frame", "pose", "mission", "fault", "cmd")
# the fields a decoder requires (an optional field may be absent, so deleting it proves nothing)
REQUIRED = {"frame": ("t", "seq", "src", "poses"), "pose": ("t", "seq", "x", "y", "th", "src"), "cmd": ("t", "seq", "vl", "vr", "ttl"),
            "fault": ("kind", "factor", "duration"), "mission": ("version", "metric", "robots", "goal", "speed_max",
                                            "turn_rate_max", "effective_t")}
CATEGORIES = ("random_bytes", "truncated", "wrong_type", "non_finite", "huge", "unknown_robot",
              "oversized", "not_a_map", "missing_field")
UNKNOWN_ROBOT = "zz-fuzz"  # no mission names it; simfleet has no such robot


def _valid(kind: str, now_s: float, rng: random.Random) -> dict:
    """A valid message of ``kind`` as a dict (the fuzzer breaks it before sending)."""
    x, y = rng.uniform(-2, 2), rng.uniform(-2, 2)
    if kind == "frame":
        return {"t": now_s, "seq": rng.randrange(1 << 20), "src": "fuzz",
                "poses": {"r1": [x, y, 0.0], "r2": [y, x, 0.0]}}
    if kind == "pose":
        msg = PoseMsg(now_s, rng.randrange(1 << 20), x, y, 0.0, "fuzz")
    elif kind == "cmd":
        msg = CmdMsg(now_s, rng.randrange(1 << 20), 0.2, 0.2, 0.3)
    elif kind == "fault":
        msg = FaultMsg("stop", 0.0, 1.0)
    else:
        m = Mission(2**40, "l2", (("r1", RobotSpec((0.0, 0.0), 0.1, 0.3, 1.0)),
                                  ("r2", RobotSpec((0.3, 0.0), 0.1, 0.3, 1.0))),
                    0.1, 0.3, now_s, goal=(x, y, 0.0))
        return msgpack.unpackb(encode_mission(m))
    return msgpack.unpackb(encode(msg))


def _number_fields(kind: str, d: dict) -> list[str]:
    return [k for k, v in d.items() if isinstance(v, float) and k != "t"] or [k for k in d]


def bad_payload(kind: str, category: str, now_s: float, rng: random.Random) -> bytes:
    """One invalid payload of ``category`` for a key of ``kind`` (for unknown_robot: a valid one
    that must be sent to an unknown robot's key)."""
    d = _valid(kind, now_s, rng)
    pack = lambda obj: msgpack.packb(obj, use_bin_type=True)  # noqa: E731
    if category == "random_bytes":
        # a leading 0xc1 is never valid msgpack, so the rest cannot decode into a message
        return b"\xc1" + rng.randbytes(rng.randrange(0, 200))
    if category == "truncated":
        full = pack(d)
        return full[:rng.randrange(0, len(full))]
    if category == "wrong_type":
        field = rng.choice(REQUIRED[kind])
        d[field] = rng.choice([[1, 2], {"a": 1}, b"\x00", True] + ([] if isinstance(d[field], str) else ["x"]))
        return pack(d)
    if category == "non_finite":
        value = rng.choice([float("nan"), float("inf"), -float("inf")])
        if kind == "frame":
            d["poses"]["r1"][rng.randrange(3)] = value
            return pack(d)
        d[rng.choice(_number_fields(kind, d))] = value
        if kind == "mission":
            d["goal"]["x"] = float("nan")
        return pack(d)
    if category == "huge":
        value = rng.choice([1e300, -1e300, 1e12, 2.0**80])
        if kind == "mission":
            d["goal"]["y"] = value
        elif kind == "frame":
            d["poses"]["r2"][rng.randrange(3)] = value
        else:
            d[rng.choice(_number_fields(kind, d))] = value
        return pack(d)
    if category == "unknown_robot":
        if kind == "mission":  # a robot id that is not a key chunk
            d["robots"]["bad/id"] = d["robots"].pop("r1")
        if kind == "frame":    # a robot id that is not a key chunk
            d["poses"]["bad/id"] = d["poses"].pop("r1")
        return pack(d)
    if category == "oversized":
        limit = {"mission": MAX_MISSION_BYTES, "frame": MAX_FRAME_BYTES}.get(kind, MAX_PAYLOAD_BYTES)
        d["pad"] = "x" * (limit + 1)
        return pack(d)
    if category == "not_a_map":
        return pack(rng.choice([[1, 2, 3], "pose", 42, None, list(d.values())]))
    if category == "missing_field":
        del d[rng.choice(REQUIRED[kind])]
        return pack(d)
    raise ValueError(f"unknown category {category!r}")


def target_key(keys: Keys, kind: str, category: str, robots: list[str], rng: random.Random) -> str:
    if kind == "mission":
        return keys.mission
    if kind == "frame":
        return keys.frame("fuzz")
    robot = UNKNOWN_ROBOT if category == "unknown_robot" else rng.choice(robots)
    return getattr(keys, kind)(robot)


def run_fuzz(conf: zenoh.Config, fleet: str, robots: list[str], kinds: tuple[str, ...], rate_hz: float,
             duration_s: float, seed: int = 0, stop: StopFlag | None = None,
             clock=wall_clock) -> tuple[Counter, bool]:
    """Publish ``rate_hz`` invalid messages per second per key kind for ``duration_s``; returns what
    was sent (by kind/category) and whether the router confirmed it routed all of it (RouterBarrier)."""
    stop = stop or StopFlag()
    rng = random.Random(seed)
    keys = Keys(fleet)
    sent: Counter = Counter()
    with open_session(conf) as session:
        barrier = RouterBarrier(conf)  # declared before the flood, so the router knows its subscriber
        try:
            t0 = clock()
            period = 1.0 / rate_hz
            k = 0
            while not stop.is_set() and clock() - t0 < duration_s:
                for kind in kinds:
                    # oversized missions are 1 MiB: send one in 50 so the flood stays a flood of messages
                    cats = [c for c in CATEGORIES if not (c == "oversized" and kind == "mission" and k % 50)]
                    category = rng.choice(cats)
                    key = target_key(keys, kind, category, robots, rng)
                    session.put(key, bad_payload(kind, category, clock(), rng), **RELIABLE_QOS)
                    sent[f"{kind}/{category}"] += 1
                k += 1
                pace(t0 + k * period, stop, clock)
            routed = barrier.wait(session)
        finally:
            barrier.close()
        log.info("the router %s every put before closing", "has routed" if routed else "did not confirm it routed")
    return sent, routed


class RouterBarrier:
    """Proof that the router has routed every put a session made: a marker put after them, on the same
    priority and blocking, that comes back through the router to a second session of this program.
    One link, read in order: once the marker is routed, every put before it is in the router's
    queues to its subscribers (blocking, so none is dropped there). Closing the session at once
    instead could lose puts still queued in it on a loaded host."""

    def __init__(self, conf: zenoh.Config) -> None:
        self.echo = open_session(conf)
        self.key = f"vsfuzz/{self.echo.zid()}/barrier"
        self.arrived = threading.Event()
        self.sub = self.echo.declare_subscriber(self.key, lambda _sample: self.arrived.set())

    def wait(self, session: zenoh.Session, timeout_s: float = 10.0) -> bool:
        """Put the marker on ``session`` and wait for it (False if it did not come within timeout_s)."""
        session.put(self.key, b"", **RELIABLE_QOS)
        return self.arrived.wait(timeout_s)

    def close(self) -> None:
        self.sub.undeclare()
        self.echo.close()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet fuzz", description=__doc__.splitlines()[0])
    p.add_argument("--fleet", default="demo")
    p.add_argument("--robots", default="r1,r2,r3", help="comma-separated robot ids to target")
    p.add_argument("--kinds", default=",".join(KINDS), help=f"comma-separated subset of {KINDS}")
    p.add_argument("--rate", type=float, default=300.0,
                   help="messages per second per key kind (300 = 10x a 30 Hz tracker)")
    p.add_argument("--duration", type=float, default=5.0, help="seconds")
    p.add_argument("--seed", type=int, default=0)
    return common_flags(p)


@program(build_parser, log)
def main(args: argparse.Namespace) -> int:
    kinds = tuple(k for k in args.kinds.split(",") if k)
    robots = [r for r in args.robots.split(",") if r]
    with refusing(ValueError):
        check_name(args.fleet, "fleet")
        for r in robots:
            check_name(r, "robot")
        unknown = set(kinds) - set(KINDS)
        if unknown or not kinds or not robots:
            raise ValueError(f"--kinds must be a non-empty subset of {KINDS}, --robots non-empty")
        if not (0 < args.rate <= 10000) or not (0 < args.duration <= 3600):
            raise ValueError("--rate must be in (0, 10000] and --duration in (0, 3600]")
    sent, routed = run_fuzz(zenoh_config(args), args.fleet, robots, kinds, args.rate, args.duration, args.seed)
    by_kind = Counter()
    for name, n in sent.items():
        by_kind[name.split("/")[0]] += n
    print(json.dumps({"sent": dict(sorted(sent.items())), "by_kind": dict(by_kind), "routed": routed}), flush=True)
    log.info("sent %d invalid messages", sum(sent.values()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
