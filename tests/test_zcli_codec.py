"""The msgpack codecs that zenoh-cli loads from our entry points (`zenoh ... --decoder msgpack`)."""

from __future__ import annotations

import json
import math
import queue
import subprocess
import sys
import threading
from importlib.metadata import entry_points
from pathlib import Path

import msgpack
import pytest
import zenoh

from vsfleet.fleetctl.router import open_loopback_router
from vsfleet.wire import FaultMsg, Keys, PoseMsg, StateMsg, decode_fault, encode

POSE = PoseMsg(t=1795378504.397066, seq=42, x=0.125, y=-0.5, th=0.1, src="vgps")
STATE = StateMsg(t=1795378504.4, seq=42, x=0.1, y=0.2, th=0.3, gx=0.11, gy=0.21, gth=0.31, cost=0.004,
                 err=0.003, used=("r1", "r2", "r3"), rejected=0, complete=True, mission=1)


def plugin(group: str, name: str = "msgpack"):
    found = [ep for ep in entry_points(group=group) if ep.name == name]
    assert len(found) == 1, f"{group}:{name} is not registered (pip install -e .)"
    return found[0].load()


def test_the_msgpack_decoder_is_registered_for_zenoh_cli_and_prints_a_pose_as_one_json_line():
    decode = plugin("zenoh_cli.codecs.decoders")
    out = decode(zenoh.KeyExpr("vs/demo/pose/r1"), encode(POSE))
    assert "\n" not in out
    assert json.loads(out) == {"t": POSE.t, "seq": 42, "x": 0.125, "y": -0.5, "th": 0.1, "src": "vgps", "v": 1}


def test_the_decoder_keeps_lists_and_floats_of_a_state_exactly():
    decode = plugin("zenoh_cli.codecs.decoders")
    out = json.loads(decode("vs/demo/state/r1", encode(STATE)))
    assert out["used"] == ["r1", "r2", "r3"]
    assert out["t"] == STATE.t and out["gth"] == STATE.gth and out["complete"] is True


def test_the_decoder_always_prints_valid_json_even_for_nan_binary_and_integer_keys():
    decode = plugin("zenoh_cli.codecs.decoders")
    payload = msgpack.packb({"x": math.nan, "y": -math.inf, "blob": b"\x00\xff", 7: "seven"}, use_bin_type=True)
    out = json.loads(decode("vs/demo/event", payload), parse_constant=pytest.fail)
    assert out == {"x": "nan", "y": "-inf", "blob": "base64:AP8=", "7": "seven"}


def test_the_decoder_refuses_bytes_that_are_not_msgpack():
    decode = plugin("zenoh_cli.codecs.decoders")
    with pytest.raises(ValueError):
        decode("vs/demo/pose/r1", b"\xc1")  # 0xc1 is never used in msgpack


def test_the_msgpack_encoder_turns_json_into_a_payload_our_decoders_accept():
    encode_json = plugin("zenoh_cli.codecs.encoders")
    payload = encode_json("vs/demo/fault/r2", '{"kind": "stop", "factor": 0.0, "duration": 2.5}')
    assert decode_fault(payload) == FaultMsg(kind="stop", factor=0.0, duration=2.5)


ZENOH_CLI = Path(sys.executable).with_name("zenoh")


@pytest.mark.integration
@pytest.mark.skipif(not ZENOH_CLI.exists(), reason="zenoh-cli (dev dependency) is not installed")
def test_zenoh_subscribe_with_the_msgpack_decoder_prints_our_messages_from_a_loopback_router():
    router, endpoint = open_loopback_router()
    keys = Keys("zcli")
    proc = subprocess.Popen(
        [str(ZENOH_CLI), "--mode", "client", "--connect", endpoint, "--cfg", "scouting/multicast/enabled:false",
         "subscribe", "-k", keys.everything, "--decoder", "msgpack", "--line", "{key} {value}"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, text=True)
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout], daemon=True).start()
    try:
        pub = router.declare_publisher(keys.pose("r1"))
        matched = threading.Event()
        listener = pub.declare_matching_listener(lambda status: status.matching and matched.set())
        if pub.matching_status.matching:
            matched.set()
        assert matched.wait(20), "zenoh subscribe never subscribed"
        pub.put(encode(POSE))
        line = lines.get(timeout=10)
        while not line.startswith("vs/"):  # skip any log line
            line = lines.get(timeout=10)
        key, _, value = line.strip().partition(" ")
        assert key == keys.pose("r1")
        assert json.loads(value)["seq"] == 42 and json.loads(value)["src"] == "vgps"
        listener.undeclare()
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        router.close()
