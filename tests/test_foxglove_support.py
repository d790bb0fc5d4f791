"""The tests' Foxglove client (tests/foxglove_support.py) against a scripted server: it sends a subscription again
when the server answers "Unknown channel ID" for a channel it advertised (foxglove-sdk's advertise race)."""

from __future__ import annotations

import json
import logging
import re
import struct
import threading

import foxglove
from websockets.sync.server import serve

from tests.foxglove_support import RESUBSCRIBE_MAX, UNKNOWN_CHANNEL, UNKNOWN_CHANNEL_LOG, FoxgloveClient

CHANNEL = {"id": 7, "topic": "/t", "encoding": "json", "schemaName": "T", "schema": "{}"}


def scripted_server(refusals: int):
    """A server that advertises one channel, refuses the first ``refusals`` subscriptions to it as foxglove-sdk does
    when the subscribe overtakes its own bookkeeping, then sends one message on the accepted one. Returns the
    server and the subscribe requests it received."""
    received: list[dict] = []

    def handler(ws) -> None:
        ws.send(json.dumps({"op": "serverInfo", "name": "scripted", "capabilities": []}))
        ws.send(json.dumps({"op": "advertise", "channels": [CHANNEL]}))
        for text in ws:
            m = json.loads(text)
            if m.get("op") != "subscribe":
                continue
            received.append(m)
            if len(received) <= refusals:
                ws.send(json.dumps({"op": "status", "level": 2, "message": f"Unknown channel ID: {CHANNEL['id']}"}))
                continue
            (sub,) = m["subscriptions"]
            ws.send(struct.pack("<BIQ", 0x01, sub["id"], 5) + json.dumps({"x": 1}).encode())

    server = serve(handler, "127.0.0.1", 0, subprotocols=["foxglove.sdk.v1"])
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, received


def subscribed_client(server) -> FoxgloveClient:
    """A client of the scripted server, subscribed to its channel once it is advertised."""
    client = FoxgloveClient(f"ws://127.0.0.1:{server.socket.getsockname()[1]}")
    try:
        client.wait_for(lambda c: "/t" in c.topics(), 10)
        client.subscribe(["/t"])
    except BaseException:
        client.close()
        raise
    return client


def test_a_subscription_the_server_calls_unknown_is_sent_again_and_its_messages_arrive():
    server, received = scripted_server(refusals=1)
    client = subscribed_client(server)
    try:
        client.wait_for(lambda c: len(c.messages["/t"]) == 1, 10)
        assert client.messages["/t"] == [(5, {"x": 1})]
        assert client.resubscribed == 1
        assert [m["subscriptions"] for m in received] == [[{"id": 1, "channelId": 7}]] * 2  # the same request
        assert [s["message"] for s in client.statuses] == ["Unknown channel ID: 7"]
    finally:
        client.close()
        server.shutdown()


def test_a_server_that_keeps_refusing_gets_the_subscription_a_bounded_number_of_times():
    server, received = scripted_server(refusals=100)
    client = subscribed_client(server)
    try:
        client.wait_for(lambda c: len(c.statuses) == 1 + RESUBSCRIBE_MAX, 10)
        assert client.resubscribed == RESUBSCRIBE_MAX
        assert len(received) == 1 + RESUBSCRIBE_MAX and not client.messages["/t"]
    finally:
        client.close()
        server.shutdown()


def test_foxglove_sdks_own_server_answers_an_unknown_channel_as_the_client_expects_and_logs_the_allowed_line(caplog):
    """The status text the client matches, and the log line the multi-process tests allow, as foxglove-sdk writes
    them (a subscription to a channel id never advertised)."""
    ctx = foxglove.Context()
    channel = foxglove.Channel("/t", schema={"type": "object"}, message_encoding="json", context=ctx)
    server = foxglove.start_server(name="t", host="127.0.0.1", port=0, context=ctx)
    client = None
    try:
        with caplog.at_level(logging.ERROR, logger="foxglove"):
            client = FoxgloveClient(f"ws://127.0.0.1:{server.port}")
            client.wait_for(lambda c: "/t" in c.topics(), 10)
            client.ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": 999}]}))
            client.wait_for(lambda c: c.statuses, 10)
        assert UNKNOWN_CHANNEL.fullmatch(client.statuses[0]["message"]).group(1) == "999"
        lines = [f"{r.name} {r.levelname} {r.getMessage()}" for r in caplog.records]
        assert any(re.search(UNKNOWN_CHANNEL_LOG, line) for line in lines), lines
    finally:
        if client is not None:
            client.close()
        server.stop()
        channel.close()
