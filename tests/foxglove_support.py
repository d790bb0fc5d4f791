"""Test support: a Foxglove WebSocket protocol (foxglove.websocket.v1 / foxglove.sdk.v1) client and protobuf decoding.

The client is written from the protocol spec (foxglove/ws-protocol docs/spec.md)
on the ``websockets`` package, not with the SDK, so it checks what a viewer sees:
serverInfo, advertise, subscribe, binary Message Data (0x01) and Time (0x02).
Protobuf payloads are decoded with the FileDescriptorSet the channel advertises
(or an MCAP file stores), through google.protobuf.
"""

from __future__ import annotations

import base64
import json
import re
import struct
import threading
from collections import defaultdict
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, json_format, message_factory
from websockets.sync.client import connect

# foxglove-sdk servers (0.30) accept only "foxglove.sdk.v1", which is foxglove.websocket.v1 renamed
# (lichtblick-suite/lichtblick PR 819); older servers speak "foxglove.websocket.v1". Offer both.
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
# foxglove-sdk's server sends a client the advertise of a channel, then adds the channel to that client's map
# (rust/foxglove/src/websocket/connected_client.rs, advertise_channels, since PR 523). A client that subscribes the
# moment the advertise arrives can be handled in between: the server logs "attempted to subscribe to unknown
# channel", answers with this error status and drops the subscription (a quiet CI rehearsal got 0 messages so,
# 2026-12-06). The client sends such a subscription again, at most this many times.
UNKNOWN_CHANNEL = re.compile(r"Unknown channel ID: (\d+)")
RESUBSCRIBE_MAX = 5
# the server's log line for it (a multi-process test allows it: the client has sent the subscription again)
UNKNOWN_CHANNEL_LOG = r"foxglove\S* ERROR .*attempted to subscribe to unknown channel: \d+"


def protobuf_class(schema_name: str, fds_bytes: bytes):
    """The message class of ``schema_name`` built from a serialized FileDescriptorSet."""
    fds = descriptor_pb2.FileDescriptorSet.FromString(fds_bytes)
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def decode_protobuf(schema_name: str, fds_bytes: bytes, data: bytes) -> dict:
    """A protobuf message as a dict (field names as in the .proto, defaults included)."""
    msg = protobuf_class(schema_name, fds_bytes).FromString(data)
    return json_format.MessageToDict(msg, preserving_proto_field_name=True,
                                     always_print_fields_with_no_presence=True)


class FoxgloveClient:
    """Connects, records server info, advertised channels, messages per topic and server time; one reader thread."""

    def __init__(self, url: str, open_timeout_s: float = 10.0) -> None:
        self.ws = connect(url, subprotocols=SUBPROTOCOLS, open_timeout=open_timeout_s, max_size=None).__enter__()
        self.cond = threading.Condition()
        self.server_info: dict | None = None
        self.channels: dict[int, dict] = {}          # channel id -> advertised channel
        self.subs: dict[int, int] = {}               # subscription id -> channel id
        self.messages: dict[str, list[tuple[int, Any]]] = defaultdict(list)  # topic -> [(timestamp ns, decoded)]
        self.times: list[int] = []
        self.errors: list[str] = []
        self.statuses: list[dict] = []               # the server's status messages, in order
        self.resubscribed = 0
        self._classes: dict[int, Any] = {}
        self._next_sub = 1
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    @property
    def subprotocol(self) -> str | None:
        return self.ws.subprotocol

    def _read(self) -> None:
        try:
            for frame in self.ws:
                if isinstance(frame, str):
                    self._on_text(json.loads(frame))
                else:
                    self._on_binary(frame)
        except Exception as exc:  # the connection closed
            with self.cond:
                self.errors.append(repr(exc))
                self.cond.notify_all()

    def _on_text(self, m: dict) -> None:
        with self.cond:
            if m.get("op") == "serverInfo":
                self.server_info = m
            elif m.get("op") == "advertise":
                for ch in m["channels"]:
                    self.channels[ch["id"]] = ch
            elif m.get("op") == "unadvertise":
                for cid in m["channelIds"]:
                    self.channels.pop(cid, None)
            elif m.get("op") == "status":
                self.statuses.append(m)
                again = UNKNOWN_CHANNEL.fullmatch(str(m.get("message", "")))
                if again is not None and self.resubscribed < RESUBSCRIBE_MAX:
                    cid = int(again.group(1))
                    subs = [{"id": sid, "channelId": c} for sid, c in self.subs.items() if c == cid]
                    if subs and cid in self.channels:  # ours, and still advertised
                        self.resubscribed += 1
                        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            self.cond.notify_all()

    def _decode(self, ch: dict, data: bytes) -> Any:
        if ch["encoding"] == "json":
            return json.loads(data)
        if ch["encoding"] == "protobuf":
            cls = self._classes.get(ch["id"])
            if cls is None:
                cls = self._classes[ch["id"]] = protobuf_class(ch["schemaName"], base64.b64decode(ch["schema"]))
            return json_format.MessageToDict(cls.FromString(data), preserving_proto_field_name=True,
                                             always_print_fields_with_no_presence=True)
        return data

    def _on_binary(self, b: bytes) -> None:
        op = b[0]
        if op == 0x01:
            sub_id, t_ns = struct.unpack_from("<IQ", b, 1)
            with self.cond:
                ch = self.channels.get(self.subs.get(sub_id, -1))
            if ch is None:
                return
            decoded = self._decode(ch, bytes(b[13:]))
            with self.cond:
                self.messages[ch["topic"]].append((t_ns, decoded))
                self.cond.notify_all()
        elif op == 0x02:
            (t_ns,) = struct.unpack_from("<Q", b, 1)
            with self.cond:
                self.times.append(t_ns)
                self.cond.notify_all()

    def wait_for(self, predicate, timeout_s: float):
        with self.cond:
            result = self.cond.wait_for(lambda: predicate(self), timeout=timeout_s)
        if not result:
            with self.cond:
                got = {t: len(m) for t, m in sorted(self.messages.items())}
            raise TimeoutError(f"condition not met within {timeout_s} s; topics {sorted(self.topics())}; "
                               f"messages per subscribed topic {got}")
        return result

    def topics(self) -> dict[str, dict]:
        with self.cond:
            return {ch["topic"]: ch for ch in self.channels.values()}

    def subscribe(self, topics) -> None:
        with self.cond:
            by_topic = {ch["topic"]: cid for cid, ch in self.channels.items()}
            subs = []
            for t in topics:
                sid = self._next_sub
                self._next_sub += 1
                self.subs[sid] = by_topic[t]
                subs.append({"id": sid, "channelId": by_topic[t]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def close(self) -> None:
        self.ws.__exit__(None, None, None)
        self._thread.join(timeout=5.0)
