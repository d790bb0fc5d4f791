"""How ROS 2 topics look on Zenoh under rmw_zenoh: keys, liveliness tokens, attachments, CDR.

Checked against the rmw_zenoh_cpp sources of the released humble (0.1.9) and jazzy
(0.2.10) branches, ``src/detail/liveliness_utils.cpp``, ``attachment_helpers.cpp`` and
``rmw_publisher_data.cpp`` (docs/ros2.md lists what was checked and how):

- data key: ``<domain>/<topic without leading slash>/<pkg>::msg::dds_::<Name>_/<hash>``,
  the hash ``RIHS01_<sha256 hex>`` on jazzy, ``TypeHashNotSupported`` on humble;
- liveliness token: ``@ros2_lv/<domain>/<zid>/<nid>/<eid>/<MP|MS|NN>/<enclave>/<namespace>/
  <node>/<topic>/<type>/<hash>/<qos>``, every name with ``/`` written as ``%``;
- attachment: int64 sequence number, int64 source timestamp [ns since the epoch] and the
  16-byte publisher GID as a zenoh-ext sequence (33 bytes). Releases before humble 0.1.2 and
  jazzy 0.2.4 wrote a string key before each value (``Attachment.KEYED``);
- the GID: XXH3-128 of the entity's liveliness token, low 64 bits first.

Payloads are CDR (encapsulation header + fields), serialised by ``rosbags`` typestores.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from enum import Enum
from typing import Any

import xxhash
import zenoh
import zenoh.ext as zext
from rosbags.typesys import Stores, get_typestore

ADMIN_SPACE = "@ros2_lv"
HUMBLE_HASH = "TypeHashNotSupported"
DISTROS = ("jazzy", "humble")
GID_SIZE = 16
MAX_ROS_PAYLOAD_BYTES = 1 << 16  # a PoseStamped or an Odometry is < 1 KiB; refuse anything huge
TWIST = "geometry_msgs/msg/Twist"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
POSE_TYPES = (POSE_STAMPED, ODOMETRY)
_NAME_RE = re.compile(r"^(/[A-Za-z_][A-Za-z0-9_]*)+$|^/$")
_STORES = {"jazzy": Stores.ROS2_JAZZY, "humble": Stores.ROS2_HUMBLE}
_TYPESTORES: dict[str, Any] = {}


class RosNameError(ValueError):
    """A ROS namespace or topic name that is not absolute, or has characters ROS refuses."""


class RosMessageError(ValueError):
    """A ROS payload that is not a valid CDR message of the expected type."""


class Attachment(Enum):
    """Attachment layouts: CURRENT (humble >= 0.1.2, jazzy >= 0.2.4) or KEYED (older releases)."""

    CURRENT = "current"
    KEYED = "keyed"


def typestore(distro: str):
    """The rosbags typestore of ``distro`` (jazzy or humble), built once."""
    if distro not in _STORES:
        raise ValueError(f"distro must be one of {DISTROS}, got {distro!r}")
    if distro not in _TYPESTORES:
        _TYPESTORES[distro] = get_typestore(_STORES[distro])
    return _TYPESTORES[distro]


def dds_type_name(ros_type: str) -> str:
    """``geometry_msgs/msg/Twist`` -> ``geometry_msgs::msg::dds_::Twist_`` (rmw_zenoh's type chunk)."""
    pkg, kind, name = ros_type.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def type_hash(ros_type: str, distro: str) -> str:
    """The type hash chunk: RIHS01 from the distro's message definitions, or humble's placeholder."""
    if distro == "humble":
        return HUMBLE_HASH
    return typestore(distro).hash_rihs01(ros_type)


def resolve_topic(namespace: str, topic: str) -> str:
    """Absolute topic name: ``topic`` if it starts with ``/``, else ``<namespace>/<topic>``."""
    check_name(namespace, "namespace")
    full = topic if topic.startswith("/") else (namespace.rstrip("/") + "/" + topic)
    return check_name(full, "topic")


def check_name(name: str, what: str) -> str:
    """An absolute ROS name (``/`` or ``/a/b_c``), else RosNameError."""
    if not isinstance(name, str) or not _NAME_RE.match(name):
        raise RosNameError(f"{what} must be an absolute ROS name like /r1 or /r1/cmd_vel, got {name!r}")
    return name


def data_keyexpr(domain: int, topic: str, ros_type: str, distro: str) -> str:
    """The key rmw_zenoh publishes ``topic`` of ``ros_type`` on, in ``domain``."""
    return f"{int(domain)}/{check_name(topic, 'topic').strip('/')}/{dds_type_name(ros_type)}/{type_hash(ros_type, distro)}"


def mangle(name: str) -> str:
    """A ROS name as one key chunk: every ``/`` becomes ``%``."""
    return name.replace("/", "%")


def qos_chunk(depth: int = 10, reliable: bool = True, volatile: bool = True) -> str:
    """rmw_zenoh's QoS chunk; fields equal to its defaults (reliable, volatile, keep last 42,
    infinite deadline/lifespan/lease, automatic liveliness) are left empty, as it writes them."""
    rel = "" if reliable else "2"
    dur = "" if volatile else "1"
    dep = "" if depth == 42 else str(int(depth))
    return f"{rel}:{dur}:,{dep}:,:,:,,"


@dataclass(frozen=True)
class Node:
    """A ROS node as the liveliness space shows it: zid [hex], node id, namespace, name."""

    domain: int
    zid: str
    nid: int
    namespace: str
    name: str
    enclave: str = "/"

    def token(self) -> str:
        """The node's ``NN`` liveliness token."""
        return "/".join([ADMIN_SPACE, str(self.domain), self.zid, str(self.nid), str(self.nid), "NN",
                         mangle(self.enclave), mangle(check_name(self.namespace, "namespace")),
                         mangle(self.name)])

    def endpoint_token(self, kind: str, eid: int, topic: str, ros_type: str, distro: str,
                       qos: str = qos_chunk()) -> str:
        """The liveliness token of a publisher (``MP``) or subscription (``MS``) of this node."""
        if kind not in ("MP", "MS"):
            raise ValueError(f"endpoint kind must be MP or MS, got {kind!r}")
        return "/".join([ADMIN_SPACE, str(self.domain), self.zid, str(self.nid), str(eid), kind,
                         mangle(self.enclave), mangle(check_name(self.namespace, "namespace")),
                         mangle(self.name), mangle(check_name(topic, "topic")),
                         dds_type_name(ros_type), type_hash(ros_type, distro), qos])


def gid_of(token: str) -> bytes:
    """The 16-byte GID rmw_zenoh derives from an entity's liveliness token (XXH3-128, low half first)."""
    return xxhash.xxh3_128_intdigest(token.encode()).to_bytes(GID_SIZE, "little")


def encode_attachment(seq: int, source_timestamp_ns: int, gid: bytes,
                      layout: Attachment = Attachment.CURRENT) -> bytes:
    """The attachment every rmw_zenoh sample carries, serialised with zenoh-ext (see module doc)."""
    if len(gid) != GID_SIZE:
        raise ValueError(f"gid must be {GID_SIZE} bytes, got {len(gid)}")
    values: tuple = (zext.Int64(seq), zext.Int64(source_timestamp_ns), bytes(gid))
    if layout is Attachment.KEYED:
        values = ("sequence_number", values[0], "source_timestamp", values[1], "source_gid", values[2])
    return zext.z_serialize(values).to_bytes()


def decode_attachment(data: bytes, layout: Attachment = Attachment.CURRENT) -> tuple[int, int, bytes]:
    """(sequence number, source timestamp [ns], gid) from an attachment; ValueError if malformed."""
    try:
        if layout is Attachment.KEYED:
            k1, seq, k2, ts, k3, gid = zext.z_deserialize(
                tuple[str, zext.Int64, str, zext.Int64, str, bytes], zenoh.ZBytes(data))
            if (k1, k2, k3) != ("sequence_number", "source_timestamp", "source_gid"):
                raise ValueError(f"unexpected attachment keys {(k1, k2, k3)}")
        else:
            seq, ts, gid = zext.z_deserialize(tuple[zext.Int64, zext.Int64, bytes], zenoh.ZBytes(data))
    except zext.ZDeserializeError as exc:
        raise ValueError(f"not an rmw_zenoh attachment: {exc}") from None
    if len(gid) != GID_SIZE:
        raise ValueError(f"attachment gid of {len(gid)} bytes, expected {GID_SIZE}")
    return int(seq), int(ts), bytes(gid)


def encode_twist(v_m_s: float, w_rad_s: float, distro: str) -> bytes:
    """CDR of geometry_msgs/Twist: linear.x = v [m/s], angular.z = w [rad/s, CCW]; the rest 0."""
    ts = typestore(distro)
    vec = ts.types["geometry_msgs/msg/Vector3"]
    msg = ts.types[TWIST](linear=vec(x=float(v_m_s), y=0.0, z=0.0), angular=vec(x=0.0, y=0.0, z=float(w_rad_s)))
    return bytes(ts.serialize_cdr(msg, TWIST))


def decode_twist(payload: bytes, distro: str) -> tuple[float, float]:
    """(linear.x [m/s], angular.z [rad/s]) of a CDR Twist (tests and tools)."""
    msg = _deserialize(payload, TWIST, distro)
    return float(msg.linear.x), float(msg.angular.z)


def yaw_of(qx: float, qy: float, qz: float, qw: float) -> float:
    """Heading [rad, CCW from +x] of a quaternion: rotation about z of its ZYX Euler angles.

    RosMessageError for a non-finite quaternion or one far from unit norm (a lost track)."""
    n2 = qx * qx + qy * qy + qz * qz + qw * qw
    if not math.isfinite(n2) or abs(n2 - 1.0) > 0.1:
        raise RosMessageError(f"orientation is not a unit quaternion (|q|^2 = {n2!r})")
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


@dataclass(frozen=True)
class StampedPose:
    """A planar pose from a ROS message: t [s since the epoch, header stamp], x, y [m], th [rad]
    in the message's ``frame_id``."""

    t: float
    x: float
    y: float
    th: float
    frame_id: str


def _deserialize(payload: bytes, ros_type: str, distro: str):
    if not isinstance(payload, (bytes, bytearray, memoryview)):
        raise RosMessageError(f"payload must be bytes, got {type(payload).__name__}")
    payload = bytes(payload)
    if len(payload) > MAX_ROS_PAYLOAD_BYTES:
        raise RosMessageError(f"payload of {len(payload)} bytes exceeds {MAX_ROS_PAYLOAD_BYTES}")
    if len(payload) < 4 or payload[0] != 0 or payload[1] not in (0, 1):
        raise RosMessageError("no CDR encapsulation header (00 00 or 00 01)")
    try:
        return typestore(distro).deserialize_cdr(payload, ros_type)
    except Exception as exc:  # rosbags raises struct.error, IndexError, ValueError... for bad bytes
        raise RosMessageError(f"not a CDR {ros_type}: {type(exc).__name__}: {exc}") from None


def decode_pose(payload: bytes, ros_type: str, distro: str) -> StampedPose:
    """A PoseStamped or Odometry (its ``pose.pose``) as a StampedPose; RosMessageError if malformed.

    Refused: bad CDR, a non-finite or out-of-range position or stamp, a non-unit quaternion."""
    if ros_type not in POSE_TYPES:
        raise RosMessageError(f"unsupported pose type {ros_type!r}; expected one of {POSE_TYPES}")
    msg = _deserialize(payload, ros_type, distro)
    pose = msg.pose.pose if ros_type == ODOMETRY else msg.pose
    stamp = msg.header.stamp
    if not (0 <= stamp.nanosec < 1_000_000_000) or stamp.sec <= 0:
        raise RosMessageError(f"header stamp {stamp.sec}.{stamp.nanosec:09d} is not a time since the epoch")
    t = stamp.sec + stamp.nanosec * 1e-9
    x, y = float(pose.position.x), float(pose.position.y)
    for name, v in (("position.x", x), ("position.y", y)):
        if not math.isfinite(v) or abs(v) > 1e6:
            raise RosMessageError(f"{name} = {v!r} is not finite or beyond 1e6 m")
    q = pose.orientation
    return StampedPose(t=t, x=x, y=y, th=yaw_of(q.x, q.y, q.z, q.w), frame_id=str(msg.header.frame_id))


def ros_type_of_key(key: str) -> tuple[str, str]:
    """(ROS type, hash chunk) of a concrete data key ``<domain>/<topic...>/<dds type>/<hash>``."""
    parts = key.split("/")
    if len(parts) < 4:
        raise RosMessageError(f"key {key!r} is not <domain>/<topic>/<type>/<hash>")
    dds, hash_chunk = parts[-2], parts[-1]
    m = re.match(r"^([A-Za-z0-9_]+)::(msg)::dds_::([A-Za-z0-9]+)_$", dds)
    if not m:
        raise RosMessageError(f"key {key!r} has no DDS type chunk")
    return f"{m.group(1)}/{m.group(2)}/{m.group(3)}", hash_chunk
