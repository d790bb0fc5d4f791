"""vsfleet record --out FILE.mcap: record a fleet's key space (vs/<fleet>/**) into an MCAP file.

Layout of the file (one channel per key and role; channel metadata
``vsfleet.role`` and ``vsfleet.key``):

* ``raw`` — topic = the zenoh key (``vs/demo/pose/r1``), message encoding
  ``msgpack``, no schema: the payload exactly as received. ``log_time`` is
  the receive time (strictly increasing: receive order), ``publish_time`` the
  payload's ``t`` when it has one, else the sample's zenoh timestamp (stamped
  by the router, or by ``vsfleet replay`` with the original publish time),
  else the receive time. ``vsfleet replay`` publishes these channels.
* ``liveliness`` — topic = the token key (``vs/demo/alive/agent/r1``),
  ``msgpack`` messages ``{"alive": true|false}`` when a token appears or
  disappears (recorded with history, so tokens alive at the start are in).
* ``json`` — topic ``/json/<key>``: the same message as JSON (jsonschema
  ``vsfleet.<kind>``), so Foxglove and other tools can plot every field.
* ``foxglove`` — drawable views built by fleetctl.foxglove_views with the
  foxglove-sdk's message types (protobuf, the SDK's schemas), the same topics
  and schemas that ``vsfleet foxglove`` serves live: ``/foxglove/<key>``
  foxglove.PoseInFrame for pose/<robot>, truth/<robot> and state/<robot>;
  ``/foxglove/vs/<fleet>/scene`` foxglove.SceneUpdate (robots, fitted and
  advanced structure with their template points, targets, mission);
  ``/foxglove/vs/<fleet>/log`` foxglove.Log (events, rejections, missions);
  ``/foxglove/vs/<fleet>/goal`` and ``/path`` from the mission.

At start the recorder also queries the mission (``vsfleet run`` answers as the
operator on ``vs/<fleet>/mission``; agents answer under ``vs/<fleet>/peer/<robot>/mission``,
and their majority answer is taken, see zglue.peers), so a recording started
after the mission was published still has it, on ``vs/<fleet>/mission``.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import queue
import re
import threading
import time
from pathlib import Path
from typing import Any, Iterable, Iterator, NamedTuple

import msgpack
import zenoh
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from vsfleet.wire import Keys, check_name

from .foxglove_views import FleetViews, seconds_to_ns, structure_points  # noqa: F401 (re-exported)

from vsfleet.zglue.lifecycle import StopFlag
from vsfleet.zglue.peers import current_missions
from vsfleet.zglue.program import Refused, common_flags, program, refusing
from .zcli_codec import jsonable
from vsfleet.zglue.zconf import SessionError, open_session, zenoh_config

log = logging.getLogger("vsfleet.record")

ROLE = "vsfleet.role"
KEY = "vsfleet.key"
RAW, LIVELINESS, JSON_ROLE, FOXGLOVE = "raw", "liveliness", "json", "foxglove"
KEY_RE = re.compile(r"^vs/([A-Za-z0-9_-]+)/(.+)$")


class LogRecord(NamedTuple):
    """One recorded message: times [ns since the UNIX epoch], key, payload (msgpack bytes).

    For ``liveliness`` records the payload is msgpack ``{"alive": bool}``.
    """

    log_time_ns: int
    publish_time_ns: int
    key: str
    payload: bytes
    role: str = RAW

    @property
    def t_recv_s(self) -> float:
        return self.log_time_ns * 1e-9

    @property
    def alive(self) -> bool | None:
        """For a liveliness record: whether the token appeared (True) or went away (False)."""
        if self.role != LIVELINESS:
            return None
        return bool(msgpack.unpackb(self.payload).get("alive"))


def payload_time_ns(payload: bytes) -> int | None:
    """The payload's ``t`` [s] as ns, if the payload is a msgpack map with a finite numeric ``t``."""
    try:
        m = msgpack.unpackb(payload, raw=False, strict_map_key=False)
    except Exception:
        return None
    if not isinstance(m, dict):
        return None
    t = m.get("t")
    if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or t < 0:
        return None
    return seconds_to_ns(float(t))


def publish_time_ns(payload: bytes, zenoh_time_ns: int | None, log_time_ns: int) -> int:
    """Payload ``t``, else the zenoh timestamp, else the receive time [ns]."""
    t = payload_time_ns(payload)
    if t is not None:
        return t
    return zenoh_time_ns if zenoh_time_ns is not None else log_time_ns


def liveliness_payload(alive: bool) -> bytes:
    return msgpack.packb({"alive": bool(alive)})


def split_key(key: str) -> tuple[str, str, str | None] | None:
    """``vs/<fleet>/<kind>[/<rest>]`` -> (fleet, kind, rest or None); None for other keys."""
    m = KEY_RE.match(key)
    if not m:
        return None
    kind, _, rest = m.group(2).partition("/")
    return m.group(1), kind, rest or None


# ---------------------------------------------------------------- schemas

_NUM, _INT, _STR, _BOOL = ({"type": "number"}, {"type": "integer"}, {"type": "string"}, {"type": "boolean"})
_FIELDS = {
    "pose": dict(t=_NUM, seq=_INT, x=_NUM, y=_NUM, th=_NUM, src=_STR),
    "cmd": dict(t=_NUM, seq=_INT, vl=_NUM, vr=_NUM, ttl=_NUM),
    "state": dict(t=_NUM, seq=_INT, x=_NUM, y=_NUM, th=_NUM, gx=_NUM, gy=_NUM, gth=_NUM, cost=_NUM,
                  err=_NUM, used={"type": "array", "items": _STR}, rejected=_INT, complete=_BOOL,
                  mission=_INT),
    "truth": dict(t=_NUM, x=_NUM, y=_NUM, th=_NUM, vl=_NUM, vr=_NUM),
    "frame": dict(t=_NUM, seq=_INT, src=_STR, poses={"type": "object"}),
    "event": dict(t=_NUM, seq=_INT, robot=_STR, kind=_STR, dev={"type": ["number", "string"]}, by=_STR,
                  why=_STR),
    "fault": dict(kind=_STR, factor=_NUM, duration=_NUM),
    "mission": dict(version=_INT, metric=_STR, robots={"type": "object"}, speed_max=_NUM,
                    turn_rate_max=_NUM, effective_t=_NUM),
}


def vsfleet_json_schema(kind: str) -> dict:
    """A jsonschema for the JSON mirror of one message kind (the fields docs/protocol.md lists)."""
    return {"title": f"vsfleet.{kind}", "type": "object", "properties": dict(_FIELDS.get(kind, {}))}


def json_mirror(key: str, payload: bytes) -> tuple[str, str, dict, Any] | None:
    """The JSON mirror of a message: (topic ``/json/<key>``, schema name, jsonschema, object); None if not msgpack."""
    try:
        obj = msgpack.unpackb(payload, raw=False, strict_map_key=False)
    except Exception:
        return None
    parts = split_key(key)
    kind = parts[1] if parts else "message"
    return f"/json/{key}", f"vsfleet.{kind}", vsfleet_json_schema(kind), jsonable(obj)


# ---------------------------------------------------------------- writing


class McapLogWriter:
    """Writes LogRecords (and their JSON / Foxglove views) to an MCAP file. Not thread-safe."""

    def __init__(self, path: str | Path, derived: bool = True) -> None:
        self.path = Path(path)
        self._file = self.path.open("wb")
        self._writer = Writer(self._file, chunk_size=256 * 1024, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="vsfleet")
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str], int] = {}
        self._sequence: dict[int, int] = {}
        self._views = FleetViews()
        self._last_log_ns = 0
        self.derived = derived
        self.count = 0  # raw + liveliness records written
        self.closed = False

    # -- channels
    def _schema(self, name: str, schema: dict) -> int:
        return self._schema_id(name, "jsonschema", json.dumps(schema).encode())

    def _schema_id(self, name: str, encoding: str, data: bytes) -> int:
        if name not in self._schemas:
            self._schemas[name] = self._writer.register_schema(name=name, encoding=encoding, data=data)
        return self._schemas[name]

    def _channel(self, topic: str, role: str, key: str, encoding: str, schema_id: int = 0) -> int:
        cid = self._channels.get((topic, role))
        if cid is None:
            cid = self._writer.register_channel(topic=topic, message_encoding=encoding, schema_id=schema_id,
                                                metadata={ROLE: role, KEY: key})
            self._channels[(topic, role)] = cid
        return cid

    def _add(self, cid: int, log_ns: int, pub_ns: int, data: bytes) -> None:
        seq = self._sequence.get(cid, 0)
        self._sequence[cid] = seq + 1
        self._writer.add_message(channel_id=cid, log_time=log_ns, data=data, publish_time=pub_ns, sequence=seq)

    def _add_json(self, topic: str, role: str, key: str, schema_name: str, schema: dict,
                  log_ns: int, pub_ns: int, obj: Any) -> None:
        cid = self._channel(topic, role, key, "json", self._schema(schema_name, schema))
        self._add(cid, log_ns, pub_ns, json.dumps(obj, separators=(",", ":"), allow_nan=False).encode())

    def _log_time(self, log_time_ns: int) -> int:
        """Receive time, nudged so log times strictly increase: log-time order is receive order."""
        t = max(int(log_time_ns), self._last_log_ns + 1)
        self._last_log_ns = t
        return t

    # -- records
    def write(self, key: str, payload: bytes, log_time_ns: int, zenoh_time_ns: int | None = None) -> LogRecord:
        """Record one data sample; returns the record as stored."""
        log_ns = self._log_time(log_time_ns)
        rec = LogRecord(log_ns, publish_time_ns(payload, zenoh_time_ns, log_ns), key, bytes(payload), RAW)
        self.write_record(rec)
        return rec

    def write_liveliness(self, key: str, alive: bool, log_time_ns: int) -> LogRecord:
        log_ns = self._log_time(log_time_ns)
        rec = LogRecord(log_ns, log_ns, key, liveliness_payload(alive), LIVELINESS)
        self.write_record(rec)
        return rec

    def write_record(self, rec: LogRecord) -> None:
        """Write a record with its times as given (e.g. copied from another log)."""
        self._last_log_ns = max(self._last_log_ns, rec.log_time_ns)
        cid = self._channel(rec.key, rec.role, rec.key, "msgpack")
        self._add(cid, rec.log_time_ns, rec.publish_time_ns, rec.payload)
        self.count += 1
        if self.derived and rec.role == RAW:
            try:
                self._derive(rec)
            except (ValueError, TypeError) as exc:  # a derived view must never lose the raw record
                log.debug("no derived view for %s: %s", rec.key, exc)

    def _derive(self, rec: LogRecord) -> None:
        log_ns, pub_ns = rec.log_time_ns, rec.publish_time_ns
        for view in self._views.on_message(rec.key, rec.payload, pub_ns):
            schema = type(view.message).get_schema()  # the SDK's own schema (protobuf)
            key = rec.key if view.topic == f"/foxglove/{rec.key}" else view.topic.removeprefix("/foxglove/")
            cid = self._channel(view.topic, FOXGLOVE, key, schema.encoding,  # key: the source key, or the
                                self._schema_id(schema.name, schema.encoding, schema.data))  # fleet-level view
            self._add(cid, log_ns, view.t_ns, view.message.encode())
        mirror = json_mirror(rec.key, rec.payload)
        if mirror is not None:
            topic, name, schema, obj = mirror
            self._add_json(topic, JSON_ROLE, rec.key, name, schema, log_ns, pub_ns, obj)

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._writer.finish()
            self._file.close()

    def __enter__(self) -> "McapLogWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_log(path: str | Path, records: Iterable[LogRecord], derived: bool = True) -> int:
    """Write records (with their times as given) to a new MCAP file; returns how many."""
    with McapLogWriter(path, derived=derived) as w:
        for rec in records:
            w.write_record(rec)
        return w.count


# ---------------------------------------------------------------- reading


def iter_log(path: str | Path, roles: Iterable[str] = (RAW, LIVELINESS)) -> Iterator[LogRecord]:
    """Records of the given roles, in log-time (= receive) order."""
    roles = set(roles)
    with open(path, "rb") as f:
        reader = make_reader(f)
        for _schema, channel, message in reader.iter_messages(log_time_order=True):
            role = channel.metadata.get(ROLE)
            if role in roles:
                yield LogRecord(message.log_time, message.publish_time, channel.topic, message.data, role)


def read_log(path: str | Path, roles: Iterable[str] = (RAW, LIVELINESS)) -> list[LogRecord]:
    return list(iter_log(path, roles))


# ---------------------------------------------------------------- live recording


def sample_time_ns(sample: zenoh.Sample) -> int | None:
    ts = sample.timestamp
    return ts.get_time_as_ntp64().as_nanos() if ts is not None else None


class LiveRecorder:
    """Takes zenoh samples on any thread; one writer thread appends them to an McapLogWriter.

    ``count`` (records written) and ``wait_count`` let callers wait for records
    without sleeping.
    """

    def __init__(self, path: str | Path, derived: bool = True) -> None:
        self.writer = McapLogWriter(path, derived=derived)
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._cond = threading.Condition()
        self.count = 0
        self._thread = threading.Thread(target=self._drain, name="mcap-writer", daemon=True)
        self._thread.start()

    def on_sample(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        self._queue.put((False, str(sample.key_expr), sample.payload.to_bytes(), time.time_ns(),
                         sample_time_ns(sample)))

    def on_payload(self, key: str, payload: bytes) -> None:
        """A message that did not come as a sample (a query's answer), recorded as received now."""
        self._queue.put((False, key, payload, time.time_ns(), None))

    def on_liveliness(self, sample: zenoh.Sample) -> None:
        self._queue.put((True, str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT, time.time_ns(), None))

    def _drain(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            is_token, key, data, t_ns, z_ns = item
            try:
                if is_token:
                    self.writer.write_liveliness(key, data, t_ns)
                else:
                    self.writer.write(key, data, t_ns, z_ns)
            except Exception:  # a bad record must not stop the recording
                log.exception("cannot record a sample on %s", key)
                continue
            with self._cond:
                self.count += 1
                self._cond.notify_all()

    def wait_count(self, n: int, timeout_s: float) -> bool:
        """Wait until at least n records are written; False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: self.count >= n, timeout=timeout_s)

    def close(self) -> int:
        """Write what is queued, finish the file; returns the number of records."""
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()
        self.writer.close()
        return self.count


def fleet_key_expr(fleet: str | None, key: str | None) -> str:
    if key:
        return key
    return Keys(check_name(fleet or "demo", "fleet")).everything


class Recording:
    """A zenoh session recording ``key_expr`` (data and liveliness tokens) into an MCAP file.

    Use as a context manager; on exit the subscribers are undeclared, the session
    closed and the file finished.
    """

    def __init__(self, conf: zenoh.Config, out: str | Path, key_expr: str, query_mission: bool = True,
                 derived: bool = True) -> None:
        self.key_expr = key_expr
        self.recorder = LiveRecorder(out, derived=derived)
        self.session = open_session(conf)
        try:
            self.sub = self.session.declare_subscriber(key_expr, self.recorder.on_sample)
            self.alive_sub = self.session.liveliness().declare_subscriber(
                key_expr, self.recorder.on_liveliness, history=True)
            if query_mission:
                self._query_mission()
        except Exception:
            self.close()
            raise

    def _query_mission(self) -> None:
        """Record the mission the fleet holds now (the operator's answer, else the agents' majority)."""
        want = zenoh.KeyExpr(self.key_expr)
        if not want.intersects(zenoh.KeyExpr("vs/*/mission")):
            return
        for key, payload in current_missions(self.session, None, timeout_s=2.0):
            if want.intersects(zenoh.KeyExpr(key)):
                self.recorder.on_payload(key, payload)

    @property
    def count(self) -> int:
        return self.recorder.count

    def wait_count(self, n: int, timeout_s: float) -> bool:
        return self.recorder.wait_count(n, timeout_s)

    def close(self) -> int:
        for name in ("sub", "alive_sub"):
            s = getattr(self, name, None)
            if s is not None:
                s.undeclare()
        self.session.close()
        return self.recorder.close()

    def __enter__(self) -> "Recording":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vsfleet record", description=__doc__.splitlines()[0])
    p.add_argument("--out", "-o", required=True, help="MCAP file to write")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--fleet", default=None, help="record vs/<fleet>/** (default fleet: demo)")
    which.add_argument("--key", default=None, help="record this key expression instead, e.g. 'vs/*/pose/*'")
    p.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: at Ctrl-C)")
    p.add_argument("--no-mission-query", action="store_true", help="do not query the mission at start")
    return common_flags(p)


@program(build_parser, log)
def main(args: argparse.Namespace) -> int:
    with refusing(ValueError, zenoh.ZError):
        key_expr = fleet_key_expr(args.fleet, args.key)
        zenoh.KeyExpr(key_expr)
    stop = StopFlag()
    try:
        rec = Recording(zenoh_config(args), args.out, key_expr, query_mission=not args.no_mission_query)
    except SessionError:  # one line from `vsfleet`, like every program's
        raise
    except (OSError, zenoh.ZError) as exc:
        raise Refused(f"cannot record: {exc}") from exc
    log.info("recording %s into %s (Ctrl-C to stop)", key_expr, args.out)
    t_end = time.monotonic() + args.duration if args.duration > 0 else math.inf
    with rec:
        while not stop.wait(min(1.0, max(0.0, t_end - time.monotonic()))):
            if time.monotonic() >= t_end:
                break
    log.info("recorded %d messages into %s", rec.count, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
