"""The wire contract: key expressions and msgpack codecs (see docs/protocol.md).

Every payload is a msgpack map. A decoder checks every required field's
presence, type and finiteness, and turns a bad message away with
:class:`WireError` (a ValueError) whose message says why. Messages that steer
the fleet (mission, fault, health, cmd, frame) are closed: an unknown field is
an :class:`UnknownFieldError` that names it. Telemetry (pose, state, truth,
event) carries the protocol version ``v`` it follows: at ``v`` <= PROTOCOL_V an
unknown field is an error too; a newer sender's extra fields are ignored.
Encoders produce exactly what decoders accept (round-trip tested).
"""

from __future__ import annotations

import difflib
import inspect
import itertools
import math
import operator
import re
from dataclasses import dataclass, fields
from functools import cached_property, lru_cache
from typing import Any, Callable, Mapping

import msgpack

from .lazy import lazy_numpy
from . import _core
from .control import CONTROLLERS
from .coreconst import (DECISION_KINDS, FAILURE_MODES, WIRE_MAX_ABS as MAX_ABS, WIRE_MAX_ABS_T as MAX_ABS_T,
                        WIRE_MAX_FRAME_BYTES as MAX_FRAME_BYTES, WIRE_MAX_ROBOTS as MAX_ROBOTS,
                        WIRE_MAX_SRC as MAX_STR, WIRE_PROTOCOL_V as PROTOCOL_V)
from .errors import VsfleetValueError
from .failure import FailurePolicy
from .fit import METRICS  # noqa: F401 (a mission's metric: one of the fit's; re-exported)

np = lazy_numpy(globals())   # numpy on first use: the agent process never loads it (vsfleet.lazy)

NAME_RE = re.compile(r"^[A-Za-z0-9_-]+\Z")  # \Z, not $: $ also matches before a final newline ("cam1\n")
MAX_PAYLOAD_BYTES = 4096          # pose, cmd, state, truth, fault, event
MAX_MISSION_BYTES = 1 << 20       # a mission lists every robot
# MAX_FRAME_BYTES (64 KiB), MAX_ROBOTS (1000), MAX_ABS (1e6) and MAX_ABS_T (1e11) are the core's decoder's
# (vs_wire.h): a frame lists every robot a tracker sees (1000 robots fit); any number field: |v| <= MAX_ABS
# (metres, seconds apart from t, m/s, rad), a time |t| <= MAX_ABS_T; a string field at most MAX_STR (128) characters,
# the core's limit on a frame's src (VS_WIRE_MAX_SRC, bytes: a src is ASCII, check_name)
MAX_OBSTACLES = 256     # a mission's round obstacles
MAX_SHAPES = 4          # a mission's alternative templates (reshape, docs/planning.md)
MAX_TTL_S = 5.0         # a command may keep a robot moving for at most this long
CONTROLLER_NAMES = tuple(sorted(CONTROLLERS))  # a mission's controller: one of vsfleet.control's
FAULT_KINDS = ("none", "stop", "slow", "stall", "wheel")
ON_FAILURE = FAILURE_MODES   # a mission's on_failure: the failure rule's modes (vs_failure.h VS_FAILURE_*)
# PROTOCOL_V (1): the telemetry version (field ``v``) this code writes and reads in full; the core's encoders' too
# (vs_wire.h VS_WIRE_PROTOCOL_V)


class WireError(VsfleetValueError):
    """A message that does not meet the wire contract."""


class UnknownFieldError(WireError):
    """A map with a key the contract does not define (a misspelt key, usually); ``fields`` names them."""

    def __init__(self, message: str, unknown: tuple[str, ...]) -> None:
        super().__init__(message)
        self.fields = unknown


# ---------------------------------------------------------------- key expressions


def check_name(name: str, what: str = "name") -> str:
    """Return ``name`` if it is a single key chunk of [A-Za-z0-9_-], else raise WireError."""
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise WireError(f"{what} must match [A-Za-z0-9_-]+, got {name!r}")
    return name


@dataclass(frozen=True)
class Keys:
    """Key expressions of one fleet: everything lives under ``vs/<fleet>``."""

    fleet: str = "demo"

    def __post_init__(self) -> None:
        check_name(self.fleet, "fleet")

    @property
    def prefix(self) -> str:
        return f"vs/{self.fleet}"

    def pose(self, robot: str = "*") -> str:
        return f"{self.prefix}/pose/{robot}"

    def frame(self, src: str = "*") -> str:
        """One message per tracker frame from source ``src``: every robot it saw."""
        return f"{self.prefix}/frame/{src}"

    def cmd(self, robot: str = "*") -> str:
        return f"{self.prefix}/cmd/{robot}"

    def state(self, robot: str = "*") -> str:
        return f"{self.prefix}/state/{robot}"

    def truth(self, robot: str = "*") -> str:
        return f"{self.prefix}/truth/{robot}"

    def fault(self, robot: str = "*") -> str:
        return f"{self.prefix}/fault/{robot}"

    @property
    def mission(self) -> str:
        return f"{self.prefix}/mission"

    def event(self, robot: str = "*") -> str:
        """Failure-policy decisions of robot ``robot``'s agent (only that login may put here)."""
        return f"{self.prefix}/event/{robot}"

    def contact(self, robot: str = "*") -> str:
        """Contacts of robot ``robot``'s body that a physics engine saw (only the simulated fleet puts here)."""
        return f"{self.prefix}/contact/{robot}"

    def peer(self, robot: str = "*") -> str:
        """Everything agent ``robot`` answers queries on: ``vs/<fleet>/peer/<robot>``."""
        return f"{self.prefix}/peer/{robot}"

    def peer_mission(self, robot: str = "*") -> str:
        """Queryable of agent ``robot``: the newest mission it holds, for late joiners."""
        return f"{self.peer(robot)}/mission"

    def peer_health(self, robot: str = "*") -> str:
        """Queryable of agent ``robot``: its failure-policy state, for an agent that (re)starts."""
        return f"{self.peer(robot)}/health"

    def alive(self, role: str = "*", ident: str = "*") -> str:
        return f"{self.prefix}/alive/{role}/{ident}"

    @property
    def everything(self) -> str:
        return f"{self.prefix}/**"

    def robot_of(self, key: str, kind: str) -> str:
        """The robot id in a concrete key ``vs/<fleet>/<kind>/<robot>``; WireError otherwise."""
        head = f"{self.prefix}/{kind}/"
        if not key.startswith(head):
            raise WireError(f"key {key!r} is not under {head}")
        return check_name(key[len(head):], "robot")

    def peer_of(self, key: str, what: str) -> str:
        """The robot id in a concrete key ``vs/<fleet>/peer/<robot>/<what>``; WireError otherwise."""
        head, tail = f"{self.prefix}/peer/", f"/{what}"
        if not (key.startswith(head) and key.endswith(tail)):
            raise WireError(f"key {key!r} is not {head}<robot>{tail}")
        return check_name(key[len(head):-len(tail)], "robot")


# ---------------------------------------------------------------- field checks


def _num(m: Mapping[str, Any], name: str) -> float:
    if name not in m:
        raise WireError(f"missing field {name!r}")
    v = m[name]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise WireError(f"field {name!r} must be a number, got {type(v).__name__}")
    v = float(v)
    if not math.isfinite(v):
        raise WireError(f"field {name!r} must be finite, got {v}")
    if abs(v) > (MAX_ABS_T if name in ("t", "effective_t", "why_t", "expired_t") else MAX_ABS):
        raise WireError(f"field {name!r} out of range: {v}")
    return v


def _pos(m: Mapping[str, Any], name: str, allow_zero: bool = False) -> float:
    v = _num(m, name)
    if v < 0.0 or (v == 0.0 and not allow_zero):
        raise WireError(f"field {name!r} must be {'>= 0' if allow_zero else '> 0'}, got {v}")
    return v


def _int(m: Mapping[str, Any], name: str) -> int:
    if name not in m:
        raise WireError(f"missing field {name!r}")
    v = m[name]
    if isinstance(v, bool) or not isinstance(v, int):
        raise WireError(f"field {name!r} must be an integer, got {type(v).__name__}")
    if not (0 <= v < 2**63):
        raise WireError(f"field {name!r} out of range: {v}")
    return v


def _str(m: Mapping[str, Any], name: str) -> str:
    if name not in m:
        raise WireError(f"missing field {name!r}")
    v = m[name]
    if not isinstance(v, str) or not v or len(v) > MAX_STR:
        raise WireError(f"field {name!r} must be a non-empty string of <= {MAX_STR} chars")
    return v


def _opt_bool(m: Mapping[str, Any], name: str, default: bool) -> bool:
    v = m.get(name, default)
    if not isinstance(v, bool):
        raise WireError(f"field {name!r} must be a boolean, got {type(v).__name__}")
    return v


def _opt_int(m: Mapping[str, Any], name: str, default: int) -> int:
    if name not in m or m[name] == default:
        return default
    return _int(m, name)


@lru_cache(maxsize=None)
def _field_names(cls) -> frozenset[str]:
    """A message class's field names (dataclasses.fields walked once per class, not once per message)."""
    return frozenset(f.name for f in fields(cls))


def check_known(m: Mapping[str, Any], known, what: str) -> None:
    """Raise UnknownFieldError naming every key of ``m`` not in ``known`` (with a close match, if any)."""
    extra = sorted((k for k in m if k not in known), key=repr)
    if not extra:
        return
    hints = []
    for k in extra:
        close = difflib.get_close_matches(str(k), sorted(known), n=1, cutoff=0.6)
        hints.append(f"{k!r} (did you mean {close[0]!r}?)" if close else repr(k))
    raise UnknownFieldError(f"unknown field{'s' if len(extra) > 1 else ''} {', '.join(hints)} in {what}; "
                            f"known: {', '.join(sorted(known))}", tuple(str(k) for k in extra))


def _version(m: Mapping[str, Any], cls: type, what: str) -> int:
    """Telemetry's protocol version ``v`` (absent: 1, as before versioning); closed unless newer than ours."""
    v = m.get("v", 1)
    if isinstance(v, bool) or not isinstance(v, int) or not (1 <= v < 2**31):
        raise WireError(f"field 'v' (protocol version) must be an integer >= 1, got {v!r}")
    if v <= PROTOCOL_V:
        check_known(m, _field_names(cls), f"{what} (v{v})")
    return v


def _unique_map(pairs: list[tuple[Any, Any]]) -> dict:
    """A msgpack map as a dict, refusing a key that appears twice (msgpack would keep the last)."""
    try:
        out = dict(pairs)
    except TypeError:  # an unhashable key (a map or an array): not a valid message either
        raise WireError("a msgpack map with an unhashable key") from None
    if len(out) != len(pairs):
        seen: set = set()
        k = next(k for k, _ in pairs if k in seen or seen.add(k))
        raise WireError(f"duplicate key {k!r} in a msgpack map")
    return out


def unpack_map(payload: bytes, limit: int = MAX_PAYLOAD_BYTES) -> dict:
    """Decode a msgpack map, refusing oversize, truncated or non-map payloads."""
    if not isinstance(payload, (bytes, bytearray, memoryview)):
        raise WireError(f"payload must be bytes, got {type(payload).__name__}")
    if len(payload) > limit:
        raise WireError(f"payload of {len(payload)} bytes exceeds the {limit}-byte limit")
    try:
        obj = msgpack.unpackb(bytes(payload), raw=False, strict_map_key=True,
                              object_pairs_hook=_unique_map)
    except WireError:
        raise
    except Exception as exc:  # msgpack raises several unrelated types for bad bytes
        raise WireError(f"not valid msgpack: {type(exc).__name__}: {exc}") from None
    if not isinstance(obj, dict):
        raise WireError(f"payload must be a msgpack map, got {type(obj).__name__}")
    return obj


def _pack(obj: dict) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


# ---------------------------------------------------------------- messages


@dataclass(frozen=True)
class PoseMsg:
    """A tracker's observation of one robot: t [s, tracker clock], pose [m, rad; world]."""

    t: float
    seq: int
    x: float
    y: float
    th: float
    src: str
    v: int = PROTOCOL_V  # telemetry: the protocol version followed


@dataclass(frozen=True)
class FrameMsg:
    """One tracker frame: every robot seen at observation time t [s, tracker clock].

    poses: robot id -> (x, y, th) [m, rad; world], in the order sent. src is the
    tracker's id (the key's last chunk), seq its frame counter.
    """

    t: float
    seq: int
    src: str
    poses: Mapping[str, tuple[float, float, float]]


@dataclass(frozen=True)
class CmdMsg:
    """Wheel ground speeds [m/s] for one robot, answering frame ``seq``; valid for ttl [s]."""

    t: float
    seq: int
    vl: float
    vr: float
    ttl: float


@dataclass(frozen=True)
class StateMsg:
    """An agent's view at frame ``seq``: fitted (x, y, th) and desired (gx, gy, gth) structure poses."""

    t: float
    seq: int
    x: float
    y: float
    th: float
    gx: float
    gy: float
    gth: float
    cost: float
    err: float
    used: tuple[str, ...]
    rejected: int
    complete: bool = True  # optional field: False when the frame ran on its deadline
    mission: int = -1      # optional field: version of the mission used (-1 = not sent)
    shape: int = 0         # optional field: the structure's shape (0: the template; k: the mission's k-th reshape)
    v: int = PROTOCOL_V    # telemetry: the protocol version followed


TRUTH_WHY = ("idle", "commanded", "expired", "fault")


@dataclass(frozen=True)
class TruthMsg:
    """simfleet's ground truth for one robot at sim time t [s]: pose [m, rad; world], applied wheel speeds [m/s].

    why: what sets the wheels (TRUTH_WHY: idle before any command, commanded, expired after the
    command's ttl, fault overriding a fresh command), in force since sim time why_t [s];
    expired_t: sim time [s] of the robot's latest command expiry (0.0: none yet), so a receiver
    that missed messages still learns of it; rejected: bad messages simfleet counted so far.
    Optional: a message without them (an older simfleet) decodes with why "", why_t 0.0,
    expired_t 0.0 and rejected -1 (not sent).
    """

    t: float
    x: float
    y: float
    th: float
    vl: float
    vr: float
    why: str = ""
    why_t: float = 0.0
    expired_t: float = 0.0
    rejected: int = -1
    v: int = PROTOCOL_V  # telemetry: the protocol version followed


@dataclass(frozen=True)
class FaultMsg:
    """A fault to inject into one simulated robot.

    kind: none (clear), stop (both wheels 0), slow (both wheels x factor),
    stall (stop for ``duration``), wheel (left wheel x factor: 0 = one wheel dead).
    duration [s]: 0 = until cleared.
    """

    kind: str
    factor: float
    duration: float


# the failure rule's decisions (vsfleet.coreconst.DECISION_KINDS, in vs_failure.h's code order), then the
# structure's own: blocked (it stands short of the goal; dev = how far from the goal [m]; why: BLOCKED_WHY) and
# unblocked (it goes on again; dev = how far from the goal it is then [m])
EVENT_KINDS = (*DECISION_KINDS, "blocked", "unblocked")
# why a structure is blocked: no_path (no way to the goal around the obstacles for any shape the mission allows: it
# stops at the closest safe pose) or stuck (the way goes on, but the safety filter or the clearance barrier has held
# the structure in place for the stall watch's time: docs/planning.md, "The stall watch")
BLOCKED_WHY = ("no_path", "stuck")


@dataclass(frozen=True)
class EventMsg:
    """A failure-policy decision by agent ``by`` at frame ``seq`` (tracker time t [s]).

    kind: fail, drop, rejoin or recover (robot: the robot decided on; dev [m]: its deviation at that
    frame), or blocked / unblocked (robot: the agent's own; dev [m]: how far from the goal the structure
    stands). why: for blocked, one of BLOCKED_WHY; "" for every other kind. Optional on the wire (sent only
    with blocked): a blocked event without it (an older agent) decodes with why "".
    """

    t: float
    seq: int
    robot: str
    kind: str
    dev: float
    by: str
    v: int = PROTOCOL_V  # telemetry: the protocol version followed
    why: str = ""


def decode_event(payload: bytes) -> EventMsg:
    m = unpack_map(payload)
    v = _version(m, EventMsg, "an event")
    kind = _str(m, "kind")
    if kind not in EVENT_KINDS:
        raise WireError(f"unknown event kind {kind!r}; expected one of {EVENT_KINDS}")
    robot, by = _str(m, "robot"), _str(m, "by")
    check_name(robot, "robot")
    check_name(by, "by")
    dev = m.get("dev")
    dev = math.inf if dev == "inf" else _pos({"dev": dev}, "dev", allow_zero=True)
    why = m.get("why", "")
    if why != "" and (kind != "blocked" or why not in BLOCKED_WHY):
        raise WireError(f"field 'why' of a {kind!r} event must be "
                        + (f"one of {BLOCKED_WHY}" if kind == "blocked" else "absent") + f", got {why!r}")
    return EventMsg(t=_num(m, "t"), seq=_int(m, "seq"), robot=robot, kind=kind, dev=dev, by=by, v=v, why=why)


CONTACT_KINDS = ("robot", "obstacle")


@dataclass(frozen=True)
class ContactMsg:
    """A contact that began: the simulated fleet's physics engine saw robot ``robot``'s body touch ``other`` at
    sim time t [s], at (x, y) [m; world], ``depth`` [m] into each other when first seen. kind "robot": other
    is a robot id; kind "obstacle": other is the obstacle's index in the mission, as a string."""

    t: float
    robot: str
    kind: str
    other: str
    x: float
    y: float
    depth: float
    v: int = PROTOCOL_V  # telemetry: the protocol version followed


def decode_contact(payload: bytes) -> ContactMsg:
    m = unpack_map(payload)
    v = _version(m, ContactMsg, "a contact")
    kind = _str(m, "kind")
    if kind not in CONTACT_KINDS:
        raise WireError(f"unknown contact kind {kind!r}; expected one of {CONTACT_KINDS}")
    robot, other = _str(m, "robot"), _str(m, "other")
    check_name(robot, "robot")
    if kind == "robot":
        check_name(other, "other")
    elif not (other.isdigit() and len(other) <= 6):
        raise WireError(f"field 'other' of an obstacle contact must be its index, got {other!r}")
    return ContactMsg(t=_num(m, "t"), robot=robot, kind=kind, other=other, x=_num(m, "x"), y=_num(m, "y"),
                      depth=_pos(m, "depth", allow_zero=True), v=v)


def encode_event(msg: EventMsg) -> bytes:
    names, values = message_fields(EventMsg)
    d = dict(zip(names, values(msg)))
    if not math.isfinite(d["dev"]):
        d["dev"] = "inf"  # a robot not seen in the frame
    if not d["why"]:
        del d["why"]   # sent with blocked only
    return _pack(d)


@dataclass(frozen=True)
class HealthMsg:
    """An agent's failure-policy state after frame ``seq`` (tracker time t [s]) of mission ``mission``.

    failed, dropped: robot ids; since: robot id -> tracker time [s] its current
    non-compliance (or, once dropped, compliance) began.
    """

    t: float
    seq: int
    mission: int
    failed: tuple[str, ...]
    dropped: tuple[str, ...]
    since: tuple[tuple[str, float], ...]


def _robot_list(m: Mapping[str, Any], name: str) -> tuple[str, ...]:
    v = m.get(name)
    if not isinstance(v, list) or len(v) > MAX_ROBOTS:
        raise WireError(f"field {name!r} must be a list of at most {MAX_ROBOTS} robot ids")
    return tuple(check_name(r, name) for r in v)


def decode_health(payload: bytes) -> HealthMsg:
    m = unpack_map(payload, MAX_MISSION_BYTES)
    check_known(m, {"t", "seq", "mission", "failed", "dropped", "since"}, "a health answer")
    since = m.get("since")
    if not isinstance(since, Mapping) or len(since) > MAX_ROBOTS:
        raise WireError("field 'since' must be a map of robot id -> time")
    pairs = tuple(sorted((check_name(r, "since"), _num({"t": since[r]}, "t")) for r in since))
    return HealthMsg(t=_num(m, "t"), seq=_int(m, "seq"), mission=_int(m, "mission"),
                     failed=_robot_list(m, "failed"), dropped=_robot_list(m, "dropped"), since=pairs)


def encode_health(msg: HealthMsg) -> bytes:
    return _pack({"t": msg.t, "seq": msg.seq, "mission": msg.mission, "failed": list(msg.failed),
                  "dropped": list(msg.dropped), "since": dict(msg.since)})


_MESSAGE_FIELDS: dict[type, tuple[tuple[str, ...], Callable[[Any], tuple]]] = {}


def message_fields(cls: type) -> tuple[tuple[str, ...], Callable[[Any], tuple]]:
    """A message dataclass's field names, in order, and a getter of all their values as a tuple: built once per
    class (dataclasses.fields walks the class's fields on every call)."""
    hit = _MESSAGE_FIELDS.get(cls)
    if hit is None:
        names = tuple(f.name for f in fields(cls))
        if len(names) > 1:
            values = operator.attrgetter(*names)
        else:   # attrgetter of one name gives the value itself, and takes no empty list
            def values(msg: Any, names: tuple[str, ...] = names) -> tuple:
                return tuple(getattr(msg, n) for n in names)
        hit = _MESSAGE_FIELDS[cls] = (names, values)
    return hit


def encode(msg: Any, **changes: Any) -> bytes:
    """msgpack map of a message dataclass (tuples become arrays, as msgpack packs them). ``changes``: fields
    sent with other values, as ``encode(dataclasses.replace(msg, **changes))`` without building that message."""
    names, values = message_fields(type(msg))
    out = dict(zip(names, values(msg)))
    if changes:
        unknown = changes.keys() - out.keys()
        if unknown:
            raise TypeError(f"{type(msg).__name__} has no field {', '.join(sorted(unknown))}")
        out.update(changes)
    return _pack(out)


def decode_pose(payload: bytes) -> PoseMsg:
    m = unpack_map(payload)
    v = _version(m, PoseMsg, "a pose")
    return PoseMsg(t=_num(m, "t"), seq=_int(m, "seq"), x=_num(m, "x"), y=_num(m, "y"),
                   th=_num(m, "th"), src=_str(m, "src"), v=v)


def encode_frame(msg: FrameMsg) -> bytes:
    """msgpack map {t, seq, src, poses: {robot: [x, y, th]}} (floats as float64)."""
    return _pack({"t": float(msg.t), "seq": int(msg.seq), "src": msg.src,
                  "poses": {r: [float(p[0]), float(p[1]), float(p[2])] for r, p in msg.poses.items()}})


# every robot id at once: the ids joined by NUL (no id may hold one: the count of NULs is checked too)
_IDS_RE = re.compile(r"[A-Za-z0-9_-]+(?:\x00[A-Za-z0-9_-]+)*")


def _frame_pose_error(poses: dict) -> str:
    """Why a frame's poses are refused: the first robot id or pose that is not valid."""
    for robot, p in poses.items():
        if not isinstance(robot, str) or not NAME_RE.match(robot):
            return f"robot id must match [A-Za-z0-9_-]+, got {robot!r}"
        if not isinstance(p, list) or len(p) != 3:
            return f"pose of {robot!r} must be [x, y, th]"
        for v in p:
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                return f"pose of {robot!r} must hold numbers, got {type(v).__name__}"
    return "invalid poses"


def decode_frame(payload: bytes) -> FrameMsg:
    """A frame, every field checked (docs/protocol.md, "Frames"); WireError otherwise.

    Refused: a payload over MAX_FRAME_BYTES, a missing or mistyped field, an unknown
    field, more than MAX_ROBOTS robots, a robot id that is not a key chunk or that is
    listed twice, a pose that is not three finite numbers within MAX_ABS.
    """
    m = unpack_map(payload, MAX_FRAME_BYTES)
    check_known(m, {"t", "seq", "src", "poses"}, "a frame")
    t, seq, src = _num(m, "t"), _int(m, "seq"), check_name(_str(m, "src"), "src")
    poses = m.get("poses")
    if not isinstance(poses, dict):
        raise WireError("field 'poses' must be a map {robot: [x, y, th]}")
    if len(poses) > MAX_ROBOTS:
        raise WireError(f"a frame lists {len(poses)} robots, more than {MAX_ROBOTS}")
    ids, values = list(poses), list(poses.values())
    # the fast path checks every robot at once; _frame_pose_error names the first bad one
    joined = "\x00".join(ids) if set(map(type, ids)) == {str} else None
    if ids and not (joined is not None and _IDS_RE.fullmatch(joined) and joined.count("\x00") == len(ids) - 1
                    and set(map(type, values)) == {list} and set(map(len, values)) == {3}
                    and set(map(type, itertools.chain.from_iterable(values))) <= {float, int}):
        raise WireError(_frame_pose_error(poses))
    xyth = np.array(values, dtype=float).reshape(len(ids), 3)
    bad = ~(np.abs(xyth) <= MAX_ABS)  # NaN compares False: caught too
    if bad.any():
        i = int(np.flatnonzero(bad.any(axis=1))[0])
        raise WireError(f"pose of {ids[i]!r} holds {values[i]!r}: not finite or beyond {MAX_ABS:g}")
    out = dict(zip(ids, map(tuple, xyth.tolist())))
    return FrameMsg(t=t, seq=seq, src=src, poses=out)


def decode_frame_core(payload: bytes, src: str | None = None) -> FrameMsg:
    """decode_frame in the compiled core (vsfleet/_core/vs_wire.c, docs/decoder.md): the same FrameMsg, bit for bit,
    for every payload decode_frame accepts, WireError for every one it refuses (tests/test_core_wire.py).
    src: the key's last chunk, which the frame's src must equal (None: any)."""
    t, seq, got, ids, xyth = _core.decode_frame(payload, src)
    xs = iter(memoryview(xyth).cast("d").tolist())
    return FrameMsg(t=t, seq=seq, src=got, poses=dict(zip(ids, zip(xs, xs, xs))))


def decode_cmd(payload: bytes) -> CmdMsg:
    m = unpack_map(payload)
    check_known(m, _field_names(CmdMsg), "a command")
    ttl = _pos(m, "ttl")
    if ttl > MAX_TTL_S:
        raise WireError(f"field 'ttl' must be <= {MAX_TTL_S} s, got {ttl}")
    return CmdMsg(t=_num(m, "t"), seq=_int(m, "seq"), vl=_num(m, "vl"), vr=_num(m, "vr"), ttl=ttl)


def decode_state(payload: bytes) -> StateMsg:
    m = unpack_map(payload)
    v = _version(m, StateMsg, "a state")
    used = m.get("used")
    if not isinstance(used, list) or not all(isinstance(u, str) and NAME_RE.match(u) for u in used):
        raise WireError("field 'used' must be a list of robot ids")
    return StateMsg(t=_num(m, "t"), seq=_int(m, "seq"), x=_num(m, "x"), y=_num(m, "y"),
                    th=_num(m, "th"), gx=_num(m, "gx"), gy=_num(m, "gy"), gth=_num(m, "gth"),
                    cost=_pos(m, "cost", allow_zero=True), err=_pos(m, "err", allow_zero=True),
                    used=tuple(used), rejected=_int(m, "rejected"),
                    complete=_opt_bool(m, "complete", True), mission=_opt_int(m, "mission", -1),
                    shape=_opt_int(m, "shape", 0), v=v)


def decode_truth(payload: bytes) -> TruthMsg:
    m = unpack_map(payload)
    v = _version(m, TruthMsg, "a truth")
    why = m.get("why", "")
    if why != "" and why not in TRUTH_WHY:
        raise WireError(f"field 'why' must be one of {TRUTH_WHY}, got {why!r}")
    return TruthMsg(t=_num(m, "t"), x=_num(m, "x"), y=_num(m, "y"), th=_num(m, "th"),
                    vl=_num(m, "vl"), vr=_num(m, "vr"), why=why,
                    why_t=_num(m, "why_t") if "why_t" in m else 0.0,
                    expired_t=_num(m, "expired_t") if "expired_t" in m else 0.0,
                    rejected=_opt_int(m, "rejected", -1), v=v)


def decode_fault(payload: bytes) -> FaultMsg:
    m = unpack_map(payload)
    check_known(m, {"kind", "factor", "duration"}, "a fault")
    kind = _str(m, "kind")
    if kind not in FAULT_KINDS:
        raise WireError(f"unknown fault kind {kind!r}; expected one of {FAULT_KINDS}")
    return FaultMsg(kind=kind, factor=_pos(m, "factor", allow_zero=True),
                    duration=_pos(m, "duration", allow_zero=True))


# ---------------------------------------------------------------- mission


@dataclass(frozen=True)
class RobotSpec:
    """One robot of a mission: its point [m; structure frame], its envelope, and its body.

    radius [m]: the robot's body, a disc about its tracked point (finite, > 0); None: a
    point robot (no body), as before bodies existed.
    """

    p: tuple[float, float]
    wheel_base: float
    wheel_speed_max: float
    wheel_accel_max: float
    radius: float | None = None


@dataclass(frozen=True)
class Mission:
    """A versioned mission; every agent switches to it at tracker time ``effective_t`` [s].

    Exactly one of ``goal`` (x, y, th), ``path`` ((x, y, th), ...) or ``twist``
    (vx, vy, w) [structure frame] is set. ``failure``: (name, value) pairs of
    FailurePolicy thresholds [m, s, ratio] (see :func:`failure_names`);
    ``controller_gains``: (name, value) pairs of the controller's factory gains
    (see :func:`controller_gain_names`). Both sorted by name; absent ones take
    the code's defaults. Every agent builds the same policy and controller from them.
    ``obstacles``: round obstacles (x, y, r) [m; world frame], in the order sent (their
    index names them); () when the mission has none.
    """

    version: int
    metric: str
    robots: tuple[tuple[str, RobotSpec], ...]  # sorted by robot id: the fit's order
    speed_max: float
    turn_rate_max: float
    effective_t: float
    goal: tuple[float, float, float] | None = None
    path: tuple[tuple[float, float, float], ...] | None = None
    twist: tuple[float, float, float] | None = None
    controller: str | None = None
    on_failure: str = "hold"
    failure: tuple[tuple[str, float], ...] = ()
    controller_gains: tuple[tuple[str, float], ...] = ()
    obstacles: tuple[tuple[float, float, float], ...] = ()
    # reshape (docs/planning.md, "Shapes"), used in a room only: the smallest scale (0, 1] the template may
    # shrink to (None: it may not), and alternative templates as (name, points (x, y) [m; structure frame] in
    # the robots' sorted order), in the order they may be taken
    scale_min: float | None = None
    shapes: tuple[tuple[str, tuple[tuple[float, float], ...]], ...] = ()

    @cached_property
    def robot_ids(self) -> tuple[str, ...]:
        """The robots' ids, sorted (the fit's order); computed once per mission."""
        return tuple(r for r, _ in self.robots)

    def spec(self, robot: str) -> RobotSpec:
        for r, s in self.robots:
            if r == robot:
                return s
        raise KeyError(robot)

    @property
    def radii(self) -> tuple[float, ...]:
        """Every robot's body radius [m] in mission (sorted id) order; 0.0 for a point robot."""
        return tuple(0.0 if s.radius is None else s.radius for _, s in self.robots)

    def to_dict(self) -> dict:
        d: dict[str, Any] = {
            "version": self.version, "metric": self.metric,
            "robots": {r: _spec_dict(s) for r, s in self.robots},
            "speed_max": self.speed_max, "turn_rate_max": self.turn_rate_max,
            "effective_t": self.effective_t, "on_failure": self.on_failure,
        }
        if self.goal is not None:
            d["goal"] = {"x": self.goal[0], "y": self.goal[1], "th": self.goal[2]}
        if self.path is not None:
            d["path"] = [list(p) for p in self.path]
        if self.twist is not None:
            d["twist"] = {"vx": self.twist[0], "vy": self.twist[1], "w": self.twist[2]}
        if self.controller is not None:
            d["controller"] = self.controller
        if self.failure:
            d["failure"] = dict(self.failure)
        if self.controller_gains:
            d["controller_gains"] = dict(self.controller_gains)
        if self.obstacles:  # left out when there are none: such a mission encodes as before
            d["obstacles"] = [list(o) for o in self.obstacles]
        if self.scale_min is not None:   # the reshape fields, likewise left out when absent
            d["scale_min"] = self.scale_min
        if self.shapes:
            d["shapes"] = [{"name": name, "points": {r: list(p) for (r, _), p in zip(self.robots, pts)}}
                           for name, pts in self.shapes]
        return d


def _spec_dict(s: RobotSpec) -> dict[str, Any]:
    d: dict[str, Any] = {"p": list(s.p), "wheel_base": s.wheel_base, "wheel_speed_max": s.wheel_speed_max,
                         "wheel_accel_max": s.wheel_accel_max}
    if s.radius is not None:  # left out for a point robot: such a mission encodes as before
        d["radius"] = s.radius
    return d


MISSION_FIELDS = frozenset(f.name for f in fields(Mission))
ROBOT_SPEC_FIELDS = frozenset(f.name for f in fields(RobotSpec))


def failure_names() -> tuple[str, ...]:
    """The thresholds a mission's ``failure`` may set: every FailurePolicy field but ``mode`` (on_failure)."""
    return tuple(f.name for f in fields(FailurePolicy) if f.name != "mode")


def controller_gain_names(controller: str | None) -> tuple[str, ...]:
    """The numeric keyword gains of ``controller``'s factory and of make_controller (deadband_m), sorted.

    Read from the signatures, so a new controller's gains are known at once. None is the
    default controller. WireError for an unknown controller.
    """
    from .control import CONTROLLERS, DEFAULT_CONTROLLER, make_controller

    name = DEFAULT_CONTROLLER if controller is None else controller
    if name not in CONTROLLERS:
        raise WireError(f"field 'controller' must be one of {tuple(sorted(CONTROLLERS))}, got {name!r}")
    params = [*inspect.signature(CONTROLLERS[name]).parameters.values(),
              *(q for q in inspect.signature(make_controller).parameters.values() if q.name != "name")]
    return tuple(sorted({q.name for q in params
                         if q.kind in (q.POSITIONAL_OR_KEYWORD, q.KEYWORD_ONLY)
                         and isinstance(q.default, (int, float)) and not isinstance(q.default, bool)}))


def _named_numbers(v: Any, what: str, known: tuple[str, ...]) -> tuple[tuple[str, float], ...]:
    """A map {name: finite number} with names from ``known`` as sorted (name, value) pairs."""
    if not isinstance(v, Mapping):
        raise WireError(f"field {what!r} must be a map of name -> number")
    check_known(v, known, f"{what!r}")
    return tuple(sorted((k, _num(v, k)) for k in v))


def failure_from_dict(v: Any) -> tuple[tuple[str, float], ...]:
    """A mission's ``failure`` map {threshold: value} as sorted pairs, checked as FailurePolicy checks them."""
    pairs = _named_numbers(v, "failure", failure_names())
    try:
        FailurePolicy(**dict(pairs))
    except (ValueError, TypeError) as exc:
        raise WireError(f"field 'failure': {exc}") from None
    return pairs


def controller_gains_from_dict(v: Any, controller: str | None) -> tuple[tuple[str, float], ...]:
    """A mission's ``controller_gains`` map as sorted pairs, checked by building the controller with them."""
    from .control import DEFAULT_CONTROLLER, make_controller

    pairs = _named_numbers(v, "controller_gains", controller_gain_names(controller))
    try:
        make_controller(controller or DEFAULT_CONTROLLER, **dict(pairs))  # the factory checks the ranges
    except (ValueError, TypeError) as exc:
        raise WireError(f"field 'controller_gains': {exc}") from None
    return pairs


def _triple(v: Any, what: str) -> tuple[float, float, float]:
    if not isinstance(v, (list, tuple)) or len(v) != 3:
        raise WireError(f"{what} must be [x, y, th]")
    return (_num({"x": v[0]}, "x"), _num({"y": v[1]}, "y"), _num({"th": v[2]}, "th"))


def obstacles_from_list(v: Any) -> tuple[tuple[float, float, float], ...]:
    """A mission's ``obstacles`` [[x, y, r], ...] [m; world] as a tuple of (x, y, r); WireError otherwise.

    At most MAX_OBSTACLES; x, y finite within MAX_ABS; r finite, > 0 and within MAX_ABS.
    """
    if not isinstance(v, (list, tuple)):
        raise WireError(f"field 'obstacles' must be a list of [x, y, r], got {type(v).__name__}")
    if len(v) > MAX_OBSTACLES:
        raise WireError(f"{len(v)} obstacles exceed the limit of {MAX_OBSTACLES}")
    out = []
    for i, o in enumerate(v):
        if not isinstance(o, (list, tuple)) or len(o) != 3:
            raise WireError(f"obstacle {i} must be [x, y, r], got {o!r}")
        try:
            out.append((_num({"x": o[0]}, "x"), _num({"y": o[1]}, "y"), _pos({"r": o[2]}, "r")))
        except WireError as exc:
            raise WireError(f"obstacle {i}: {exc}") from None
    return tuple(out)


def check_clear_of_obstacles(robots: tuple[tuple[str, RobotSpec], ...],
                             obstacles: tuple[tuple[float, float, float], ...],
                             poses: tuple[tuple[float, float, float], ...],
                             what: Callable[[int], str] = lambda w: f"pose {w}") -> None:
    """WireError if, with the structure at any of ``poses`` (x, y, th) [m, rad; world], a robot's
    body is inside an obstacle: the distance from its point to the obstacle's centre is below
    r + its radius (0 for a point robot). The message names the pose (``what(index)``), the
    obstacle (index, x, y, r) and the robot; the first such pose, then obstacle, then robot.
    """
    if not obstacles or not robots or not poses:
        return
    pts = [s.p for _, s in robots]
    rad = [0.0 if s.radius is None else s.radius for _, s in robots]
    reach = max(math.hypot(x, y) + r for (x, y), r in zip(pts, rad))  # every body lies within this of the pose
    margin = 1e-6  # the filters below keep a margin for rounding: the last check is the exact one
    # 1. only an obstacle within reach of a pose can hold a body there: the obstacles in a grid of cells at least
    # that wide, so that a pose looks only at the 3 x 3 cells round its own
    r_obs = max(o[2] for o in obstacles)
    cell = reach + r_obs + margin
    grid: dict[tuple[int, int], list[int]] = {}
    for j, (ox, oy, _r) in enumerate(obstacles):
        grid.setdefault((math.floor(ox / cell), math.floor(oy / cell)), []).append(j)
    # 2. only a robot whose point lies within r + its radius of an obstacle's centre (in the structure frame) can
    # be inside it: the points in a grid of cells at least that wide
    near_m = r_obs + max(rad) + margin
    points: dict[tuple[int, int], list[int]] = {}
    for i, (qx, qy) in enumerate(pts):
        points.setdefault((math.floor(qx / near_m), math.floor(qy / near_m)), []).append(i)
    for w, (x, y, th) in enumerate(poses):
        cx, cy = math.floor(x / cell), math.floor(y / cell)
        near = sorted(j for dx in (-1, 0, 1) for dy in (-1, 0, 1) for j in grid.get((cx + dx, cy + dy), ()))
        turned = False
        for j in near:   # the first obstacle, then robot, of the first pose
            ox, oy, r = obstacles[j]
            if not math.hypot(ox - x, oy - y) < reach + r + margin:
                continue
            if not turned:
                cw, sw, turned = math.cos(th), math.sin(th), True
            bx, by = cw * (ox - x) + sw * (oy - y), cw * (oy - y) - sw * (ox - x)   # the centre, structure frame
            px0, py0 = math.floor(bx / near_m), math.floor(by / near_m)
            for i in sorted(i for dx in (-1, 0, 1) for dy in (-1, 0, 1) for i in points.get((px0 + dx, py0 + dy), ())):
                # 3. exactly, in the world frame: distance < r + radius is inside
                (qx, qy), ri = pts[i], rad[i]
                px, py = x + cw * qx - sw * qy, y + sw * qx + cw * qy
                d = math.hypot(px - ox, py - oy)
                if d < r + ri:
                    rid, spec = robots[i]
                    body = f"body radius {spec.radius:g} m" if spec.radius is not None else "a point robot"
                    raise WireError(
                        f"{what(w)} puts robot {rid!r} ({body}) inside obstacle {j} (x {ox:g}, y {oy:g}, r {r:g}): "
                        f"its point ({px:.4g}, {py:.4g}) is {d:.4g} m from the obstacle's centre, "
                        f"less than {r + ri:.4g} m")


def _bodies_apart(robots: tuple[tuple[str, RobotSpec], ...], points, what: str) -> None:
    """WireError when two robots' bodies overlap with their points at ``points`` (n, 2) [m] (sorted order)."""
    for i in range(len(robots)):
        for j in range(i + 1, len(robots)):
            (ri, si), (rj, sj) = robots[i], robots[j]
            reach = (si.radius or 0.0) + (sj.radius or 0.0)
            d = math.hypot(points[i][0] - points[j][0], points[i][1] - points[j][1])
            if d <= reach or d == 0.0:
                raise WireError(f"{what}: the bodies of robots {ri!r} and {rj!r} overlap ({d:.4g} m apart, "
                                f"radii {si.radius or 0.0:g} and {sj.radius or 0.0:g} m)")


def _scale_min(v: Any, robots: tuple[tuple[str, RobotSpec], ...]) -> float:
    """A mission's ``scale_min``: a number in (0, 1] at which no two robots' bodies overlap."""
    s = _num({"scale_min": v}, "scale_min")
    if not 0.0 < s <= 1.0:
        raise WireError(f"field 'scale_min' must be in (0, 1], got {s}")
    _bodies_apart(robots, [(sp.p[0] * s, sp.p[1] * s) for _, sp in robots], f"field 'scale_min' {s:g}")
    return s


def shapes_from_list(v: Any, robots: tuple[tuple[str, RobotSpec], ...]) -> tuple:
    """A mission's ``shapes`` [{name, points: {robot: [x, y]}}] as ((name, points in sorted robot order), ...):
    at most MAX_SHAPES, names distinct, every robot of the mission given a point and no other, the bodies
    apart."""
    if not isinstance(v, (list, tuple)) or not v:
        raise WireError("field 'shapes' must be a non-empty list of {name, points}")
    if len(v) > MAX_SHAPES:
        raise WireError(f"{len(v)} shapes exceed the limit of {MAX_SHAPES}")
    ids = [r for r, _ in robots]
    out, names = [], set()
    for i, sh in enumerate(v):
        if not isinstance(sh, Mapping):
            raise WireError(f"shapes[{i}] must be a map {{name, points}}")
        check_known(sh, ("name", "points"), f"shapes[{i}]")
        name = _str(sh, "name")
        check_name(name, f"shapes[{i}] name")
        if name in names:
            raise WireError(f"shapes[{i}]: the name {name!r} is taken twice")
        names.add(name)
        pts = sh.get("points")
        if not isinstance(pts, Mapping):
            raise WireError(f"shape {name!r}: 'points' must be a map of robot id -> [x, y]")
        if set(pts) != set(ids):
            missing, extra = sorted(set(ids) - set(pts)), sorted(set(pts) - set(ids), key=str)
            raise WireError(f"shape {name!r} must give every robot of the mission a point and no other "
                            f"(missing {missing}, unknown {extra})")
        xy = []
        for r in ids:
            p = pts[r]
            if not isinstance(p, (list, tuple)) or len(p) != 2:
                raise WireError(f"shape {name!r}: robot {r!r}'s point must be [x, y]")
            xy.append((_num({"p": p[0]}, "p"), _num({"p": p[1]}, "p")))
        _bodies_apart(robots, xy, f"shape {name!r}")
        out.append((name, tuple(xy)))
    return tuple(out)


def mission_from_dict(m: Mapping[str, Any]) -> Mission:
    """Validate a mission map (from msgpack or a scenario file) into a Mission."""
    if not isinstance(m, Mapping):
        raise WireError("mission must be a map")
    check_known(m, MISSION_FIELDS, "a mission")
    metric = _str(m, "metric")
    if metric not in METRICS:
        raise WireError(f"unknown metric {metric!r}; expected one of {METRICS}")
    robots_in = m.get("robots")
    if not isinstance(robots_in, Mapping) or not robots_in:
        raise WireError("field 'robots' must be a non-empty map of robot id -> spec")
    if len(robots_in) > MAX_ROBOTS:
        raise WireError(f"{len(robots_in)} robots exceed the limit of {MAX_ROBOTS}")
    robots = []
    for rid in robots_in:
        check_name(rid, "robot id")
    for rid in sorted(robots_in):
        spec = robots_in[rid]
        if not isinstance(spec, Mapping):
            raise WireError(f"robot {rid!r}: spec must be a map")
        check_known(spec, ROBOT_SPEC_FIELDS, f"robot {rid!r}")
        p = spec.get("p")
        if not isinstance(p, (list, tuple)) or len(p) != 2:
            raise WireError(f"robot {rid!r}: 'p' must be [x, y]")
        try:
            robots.append((rid, RobotSpec(
                p=(_num({"p": p[0]}, "p"), _num({"p": p[1]}, "p")),
                wheel_base=_pos(spec, "wheel_base"), wheel_speed_max=_pos(spec, "wheel_speed_max"),
                wheel_accel_max=_pos(spec, "wheel_accel_max"),
                radius=_pos(spec, "radius") if "radius" in spec else None)))
        except WireError as exc:
            raise WireError(f"robot {rid!r}: {exc}") from None
    points: dict[tuple[float, float], str] = {}
    for rid, spec in robots:
        if spec.p in points:
            raise WireError(f"robots {points[spec.p]!r} and {rid!r} share the template point {list(spec.p)}")
        points[spec.p] = rid
    targets = [k for k in ("goal", "path", "twist") if m.get(k) is not None]
    if len(targets) != 1:
        raise WireError(f"a mission needs exactly one of goal, path, twist; got {targets or 'none'}")
    goal = path = twist = None
    if "goal" in targets:
        g = m["goal"]
        if not isinstance(g, Mapping):
            raise WireError("field 'goal' must be a map {x, y, th}")
        check_known(g, ("x", "y", "th"), "'goal'")
        goal = (_num(g, "x"), _num(g, "y"), _num(g, "th"))
    elif "path" in targets:
        p = m["path"]
        if not isinstance(p, (list, tuple)) or not p or len(p) > 10000:
            raise WireError("field 'path' must be a non-empty list of [x, y, th]")
        path = tuple(_triple(w, "each path waypoint") for w in p)
    else:
        tw = m["twist"]
        if not isinstance(tw, Mapping):
            raise WireError("field 'twist' must be a map {vx, vy, w}")
        check_known(tw, ("vx", "vy", "w"), "'twist'")
        twist = (_num(tw, "vx"), _num(tw, "vy"), _num(tw, "w"))
    controller = m.get("controller")
    if controller is not None and controller not in CONTROLLER_NAMES:
        raise WireError(f"field 'controller' must be one of {CONTROLLER_NAMES}, got {controller!r}")
    on_failure = m.get("on_failure", "hold")
    if on_failure not in ON_FAILURE:
        raise WireError(f"field 'on_failure' must be one of {ON_FAILURE}, got {on_failure!r}")
    failure = failure_from_dict(m["failure"]) if m.get("failure") is not None else ()
    gains = (controller_gains_from_dict(m["controller_gains"], controller)
             if m.get("controller_gains") is not None else ())
    obstacles = obstacles_from_list(m["obstacles"]) if m.get("obstacles") is not None else ()
    robots = tuple(robots)
    scale_min = _scale_min(m["scale_min"], robots) if m.get("scale_min") is not None else None
    shapes = shapes_from_list(m["shapes"], robots) if m.get("shapes") is not None else ()
    if goal is not None:
        check_clear_of_obstacles(robots, obstacles, (goal,), lambda w: "the goal")
    elif path is not None:  # every waypoint: the structure rests at none of them inside an obstacle
        check_clear_of_obstacles(robots, obstacles, path, lambda w: f"path waypoint {w}")
    return Mission(version=_int(m, "version"), metric=metric, robots=robots,
                   speed_max=_pos(m, "speed_max", allow_zero=True),
                   turn_rate_max=_pos(m, "turn_rate_max", allow_zero=True),
                   effective_t=_num(m, "effective_t"), goal=goal, path=path, twist=twist,
                   controller=controller, on_failure=on_failure, failure=failure, controller_gains=gains,
                   obstacles=obstacles, scale_min=scale_min, shapes=shapes)


def encode_mission(mission: Mission) -> bytes:
    return _pack(mission.to_dict())


def decode_mission(payload: bytes) -> Mission:
    return mission_from_dict(unpack_map(payload, MAX_MISSION_BYTES))


DECODERS = {
    "frame": decode_frame, "pose": decode_pose, "cmd": decode_cmd, "state": decode_state, "truth": decode_truth,
    "fault": decode_fault, "mission": decode_mission, "event": decode_event, "contact": decode_contact,
    "health": decode_health,
}
