"""The fuzzer's own payloads: every one it sends is invalid, so a fleet that accepts one is wrong."""

import random

import pytest

from vsfleet.fleetctl.fuzz import CATEGORIES, KINDS, UNKNOWN_ROBOT, bad_payload, target_key
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
