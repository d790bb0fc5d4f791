"""The fuzzer's own payloads: every one it sends is invalid, so a fleet that accepts one is wrong."""

import json
import random
import threading
import time

import pytest
import zenoh

from vsfleet.fleetctl.fuzz import CATEGORIES, KINDS, UNKNOWN_ROBOT, bad_payload, target_key, wait_for_routes
from vsfleet.fleetctl.lifecycle import StopFlag
from vsfleet.fleetctl.router import open_loopback_router
from vsfleet.wire import DECODERS, Keys, WireError

KEYS = Keys("demo")


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("category", CATEGORIES)
def test_every_fuzzed_payload_is_rejected_by_the_decoder_of_its_key(kind, category):
    rng = random.Random(f"{kind}/{category}")
    for _ in range(40):
        payload = bad_payload(kind, category, 1.7e9, rng)
        key = target_key(KEYS, kind, category, ["r1", "r2"], rng)
        if category == "unknown_robot" and kind not in ("mission", "frame"):
            # a valid message, on the key of a robot that no mission and no simfleet has
            assert key.endswith("/" + UNKNOWN_ROBOT)
            DECODERS[kind](payload)
            continue
        with pytest.raises(WireError):
            DECODERS[kind](payload)


def test_fuzzed_keys_target_the_fleets_robots_and_the_mission():
    rng = random.Random(0)
    keys = {target_key(KEYS, "cmd", "huge", ["r1", "r2"], rng) for _ in range(50)}
    assert keys == {"vs/demo/cmd/r1", "vs/demo/cmd/r2"}
    assert target_key(KEYS, "mission", "huge", ["r1"], rng) == "vs/demo/mission"


def _client(endpoint: str) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


def test_the_flood_starts_only_once_the_fleets_subscribers_are_routed():
    """A just-opened session drops puts made before it knows of the subscribers: the fuzzer waits for
    a route for each kind the fleet reads (pose/<robot> is read by tools only, so it is not waited on)."""
    router, endpoint = open_loopback_router()
    try:
        with zenoh.open(_client(endpoint)) as fleet_side, zenoh.open(_client(endpoint)) as fuzz_side:
            stop, clock = StopFlag(), time.monotonic
            t0 = clock()
            assert not wait_for_routes(fuzz_side, KEYS, ("cmd", "pose"), ["r1"], 0.3, stop, clock)
            assert clock() - t0 >= 0.3  # it waited its whole timeout for cmd/r1, which nobody reads
            got = threading.Event()
            sub = fleet_side.declare_subscriber(KEYS.cmd(), lambda s: got.set())
            assert wait_for_routes(fuzz_side, KEYS, ("cmd", "pose"), ["r1"], 20.0, stop, clock)
            fuzz_side.put(KEYS.cmd("r1"), b"\x00")  # routed now: the very first put arrives
            assert got.wait(10.0)
            sub.undeclare()
    finally:
        router.close()
