"""rmw_zenoh's byte layout: keys, liveliness tokens, attachments and CDR, checked against
independent sources: zenoh-ros2-sdk (its own attachment, token and type-hash code), literal
strings and byte layouts read from the rmw_zenoh_cpp humble 0.1.9 / jazzy 0.2.10 sources, and
hand-packed bytes (struct), never against this module's own encoder alone."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import pytest

from vsfleet.fleetctl import rmw_zenoh as rz

MSGS = Path(__file__).parent / "data" / "ros2_msgs"
TWIST_RIHS01 = "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"  # reported by ROS 2 jazzy
import pamoja.ros2 as pamoja  # a second independent implementation (Rust core, its own CDR code)
import zenoh_ros2_sdk  # noqa: F401  (the dev extra installs it; a missing one must fail, not skip)


@pytest.mark.parametrize("distro, domain, topic, key", [
    ("jazzy", 0, "/r1/cmd_vel", f"0/r1/cmd_vel/geometry_msgs::msg::dds_::Twist_/{TWIST_RIHS01}"),
    ("humble", 7, "/cmd_vel", "7/cmd_vel/geometry_msgs::msg::dds_::Twist_/TypeHashNotSupported"),
])
def test_data_key_is_domain_topic_dds_type_and_hash_per_distro(distro, domain, topic, key):
    assert rz.data_keyexpr(domain, topic, rz.TWIST, distro) == key
    from zenoh_ros2_sdk.keyexpr import topic_keyexpr
    from zenoh_ros2_sdk.utils import ros2_to_dds_type
    assert key == topic_keyexpr(domain, topic, ros2_to_dds_type(rz.TWIST), rz.type_hash(rz.TWIST, distro))


@pytest.mark.parametrize("ros_type", [rz.TWIST, rz.POSE_STAMPED, rz.ODOMETRY])
def test_rihs01_hash_from_rosbags_equals_the_sdks_own_computation_from_msg_files(ros_type):
    from zenoh_ros2_sdk.message_registry import MessageRegistry
    from zenoh_ros2_sdk.utils import get_type_hash, load_dependencies_recursive
    reg = MessageRegistry(str(MSGS))
    definition = reg.get_msg_file_path(ros_type).read_text()
    sdk_hash = get_type_hash(ros_type, definition, load_dependencies_recursive(ros_type, definition, reg))
    assert rz.type_hash(ros_type, "jazzy") == sdk_hash
    assert rz.type_hash(ros_type, "humble") == "TypeHashNotSupported"
    if ros_type == rz.TWIST:
        assert sdk_hash == TWIST_RIHS01


def test_liveliness_tokens_have_the_documented_format_and_the_sdk_parses_them():
    node = rz.Node(domain=0, zid="1f2e3d4c", nid=0, namespace="/r1", name="vsfleet_bridge_r1")
    assert node.token() == "@ros2_lv/0/1f2e3d4c/0/0/NN/%/%r1/vsfleet_bridge_r1"
    mp = node.endpoint_token("MP", 1, "/r1/cmd_vel", rz.TWIST, "jazzy")
    assert mp == ("@ros2_lv/0/1f2e3d4c/0/1/MP/%/%r1/vsfleet_bridge_r1/%r1%cmd_vel/"
                  f"geometry_msgs::msg::dds_::Twist_/{TWIST_RIHS01}/::,10:,:,:,,")
    humble = rz.Node(3, "ab", 0, "/", "n").endpoint_token("MS", 2, "/vicon/r1/pose", rz.POSE_STAMPED, "humble")
    assert humble == ("@ros2_lv/3/ab/0/2/MS/%/%/n/%vicon%r1%pose/geometry_msgs::msg::dds_::PoseStamped_/"
                      "TypeHashNotSupported/::,10:,:,:,,")
    from zenoh_ros2_sdk.discovery import _parse_liveliness_keyexpr
    from zenoh_ros2_sdk.qos import QosProfile
    parsed = _parse_liveliness_keyexpr(mp)
    assert parsed["kind"] == "MP" and parsed["qualified_name"] == "/r1/cmd_vel"
    assert parsed["namespace"] == "/r1" and parsed["node_name"] == "vsfleet_bridge_r1"
    assert parsed["dds_type"] == "geometry_msgs::msg::dds_::Twist_" and parsed["type_hash"] == TWIST_RIHS01
    # rmw_zenoh elides QoS fields equal to its defaults (reliable, volatile, keep last 42, infinite, automatic)
    assert QosProfile.decode(parsed["qos"]) == QosProfile(history_depth=10)
    assert parsed["qos"] == QosProfile(history_depth=10).encode(default=QosProfile(history_depth=42))
    for bad in ("r1", "/r1/", "/1x", "/a b"):
        with pytest.raises(rz.RosNameError):
            rz.Node(0, "ab", 0, bad, "n").token()


def test_qos_chunk_elides_defaults_like_rmw_zenoh():
    assert rz.qos_chunk() == "::,10:,:,:,,"
    assert rz.qos_chunk(depth=42) == "::,:,:,:,,"
    assert rz.qos_chunk(depth=1, reliable=False, volatile=False) == "2:1:,1:,:,:,,"


def test_attachment_is_two_int64_then_a_16_byte_gid_sequence_33_bytes_and_the_sdk_reads_it():
    gid = bytes(range(16))
    a = rz.encode_attachment(42, 1_700_000_000_123_456_789, gid)
    assert a == struct.pack("<qqB", 42, 1_700_000_000_123_456_789, 16) + gid
    from zenoh_ros2_sdk.attachment import Attachment
    parsed = Attachment.from_bytes(a)
    assert (parsed.sequence_id, parsed.timestamp_ns, parsed.gid) == (42, 1_700_000_000_123_456_789, gid)
    # and ours reads the SDK's
    assert rz.decode_attachment(Attachment(7, 99, gid).to_bytes()) == (7, 99, gid)


def test_keyed_attachment_of_older_releases_puts_a_string_before_each_value():
    gid = b"\xaa" * 16
    a = rz.encode_attachment(3, 4, gid, rz.Attachment.KEYED)

    def s(x: bytes) -> bytes:
        return bytes([len(x)]) + x
    assert a == (s(b"sequence_number") + struct.pack("<q", 3) + s(b"source_timestamp") + struct.pack("<q", 4)
                 + s(b"source_gid") + s(gid))
    assert rz.decode_attachment(a, rz.Attachment.KEYED) == (3, 4, gid)
    with pytest.raises(ValueError):
        rz.decode_attachment(a)  # the current layout refuses it
    with pytest.raises(ValueError):
        rz.encode_attachment(1, 1, b"short")


def test_gid_is_xxh3_128_of_the_token_low_half_first_and_differs_per_entity():
    import xxhash
    token = "@ros2_lv/0/ab/0/1/MP/%/%/n/%cmd_vel/geometry_msgs::msg::dds_::Twist_/TypeHashNotSupported/::,10:,:,:,,"
    h = xxhash.xxh3_128(token.encode())
    assert rz.gid_of(token) == h.digest()[8:][::-1] + h.digest()[:8][::-1]  # canonical digest is big-endian
    assert rz.gid_of(token) != rz.gid_of(token.replace("/1/MP", "/2/MP"))


@pytest.mark.parametrize("distro", rz.DISTROS)
def test_twist_cdr_is_an_encapsulation_header_and_six_float64(distro):
    b = rz.encode_twist(0.25, -1.5, distro)
    assert b == b"\x00\x01\x00\x00" + struct.pack("<6d", 0.25, 0.0, 0.0, 0.0, 0.0, -1.5)
    assert len(b) == 52
    assert rz.decode_twist(b, distro) == (0.25, -1.5)


def pose_stamped_cdr(sec, nanosec, frame_id, x, y, q):
    """A PoseStamped packed by hand: CDR little endian, strings with length + NUL, doubles 8-aligned
    (offsets count from after the 4-byte encapsulation header)."""
    body = struct.pack("<iI", sec, nanosec)
    fid = frame_id.encode() + b"\0"
    body += struct.pack("<I", len(fid)) + fid
    body += b"\0" * (-len(body) % 8)
    body += struct.pack("<7d", x, y, 0.0, *q)
    return b"\x00\x01\x00\x00" + body


@pytest.mark.parametrize("distro", rz.DISTROS)
def test_hand_packed_posestamped_decodes_to_stamp_position_and_yaw(distro):
    yaw = 2.5
    b = pose_stamped_cdr(1_796_000_000, 500_000_000, "world", 1.5, -2.0, (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)))
    p = rz.decode_pose(b, rz.POSE_STAMPED, distro)
    assert p.t == pytest.approx(1_796_000_000.5, abs=1e-6)
    assert (p.x, p.y, p.frame_id) == (1.5, -2.0, "world")
    assert p.th == pytest.approx(yaw, abs=1e-12)


def test_yaw_of_quaternions_including_a_tilted_one():
    assert rz.yaw_of(0, 0, 0, 1) == 0.0
    assert rz.yaw_of(0, 0, 1, 0) == pytest.approx(math.pi)
    assert rz.yaw_of(0, 0, -math.sin(0.3), math.cos(0.3)) == pytest.approx(-0.6)
    # roll of 0.2 about x after a yaw of 1.0 about z (q = qz * qx): yaw still 1.0
    cz, sz, cx, sx = math.cos(0.5), math.sin(0.5), math.cos(0.1), math.sin(0.1)
    assert rz.yaw_of(cz * sx, sz * sx, sz * cx, cz * cx) == pytest.approx(1.0)
    for q in ((0, 0, 0, 0), (float("nan"), 0, 0, 1), (0, 0, 2, 0)):
        with pytest.raises(rz.RosMessageError):
            rz.yaw_of(*q)


GOOD = pose_stamped_cdr(1_796_000_000, 0, "world", 1.0, 2.0, (0, 0, 0, 1))


@pytest.mark.parametrize("payload, why", [
    (b"", "empty"),
    (b"\x00\x01\x00\x00", "header only"),
    (GOOD[:30], "truncated"),
    (b"\x01\x01\x00\x00" + GOOD[4:], "not a CDR header"),
    (b"\x00\x01\x00\x00" + b"\xff" * 300, "garbage"),
    (pose_stamped_cdr(0, 0, "world", 1.0, 2.0, (0, 0, 0, 1)), "stamp zero"),
    (pose_stamped_cdr(1_796_000_000, 2_000_000_000, "w", 1.0, 2.0, (0, 0, 0, 1)), "nanosec >= 1e9"),
    (pose_stamped_cdr(1_796_000_000, 0, "w", float("nan"), 2.0, (0, 0, 0, 1)), "NaN x"),
    (pose_stamped_cdr(1_796_000_000, 0, "w", 1.0, 1e9, (0, 0, 0, 1)), "y beyond range"),
    (pose_stamped_cdr(1_796_000_000, 0, "w", 1.0, 2.0, (0, 0, 0, 0)), "zero quaternion (lost track)"),
    (b"\x00\x01\x00\x00" + b"\x00" * (rz.MAX_ROS_PAYLOAD_BYTES + 1), "oversize"),
])
def test_malformed_pose_messages_raise_ros_message_error(payload, why):
    with pytest.raises(rz.RosMessageError):
        rz.decode_pose(payload, rz.POSE_STAMPED, "jazzy")


def test_key_type_chunk_is_parsed_and_odd_keys_refused():
    key = rz.data_keyexpr(0, "/r2/odom", rz.ODOMETRY, "jazzy")
    assert rz.ros_type_of_key(key) == (rz.ODOMETRY, rz.type_hash(rz.ODOMETRY, "jazzy"))
    for bad in ("0/x", "0/a/b/c", "0/odom/nav_msgs::srv::dds_::X_/h"):
        with pytest.raises(rz.RosMessageError):
            rz.ros_type_of_key(bad)


# ---------------------------------------------------------------- against pamoja-ros2 (no rosbags inside)


def test_twist_cdr_and_jazzy_key_match_pamoja_ros2():
    assert bytes(pamoja.twist_to_cdr((0.25, 0.0, 0.0), (0.0, 0.0, -1.5))) == rz.encode_twist(0.25, -1.5, "jazzy")
    assert pamoja.twist_from_cdr(rz.encode_twist(0.1, 0.2, "humble")) == ((0.1, 0.0, 0.0), (0.0, 0.0, 0.2))
    for topic in ("/cmd_vel", "/r1/cmd_vel"):
        assert rz.data_keyexpr(3, topic, rz.TWIST, "jazzy") == pamoja.entity_key(
            3, topic, rz.TWIST, rz.type_hash(rz.TWIST, "jazzy"))
    assert pamoja.dds_type_name(rz.POSE_STAMPED) == rz.dds_type_name(rz.POSE_STAMPED)
    assert pamoja.percent_mangle("/vicon/r1/pose") == rz.mangle("/vicon/r1/pose")
    assert pamoja.type_hash_digest(rz.type_hash(rz.ODOMETRY, "jazzy")) is not None  # a well-formed RIHS01


def test_a_posestamped_written_by_pamojas_cdr_writer_decodes():
    w = pamoja.CdrWriter()  # writes the encapsulation header and aligns each primitive itself
    w.write_i32(1_796_000_000)
    w.write_u32(250_000_000)
    w.write_u32(4)  # frame_id "map": length with the NUL, then the 4 bytes
    w.write_u32(int.from_bytes(b"map\0", "little"))
    for v in (1.5, -2.0, 0.1, 0.0, 0.0, math.sin(0.35), math.cos(0.35)):
        w.write_f64(v)
    p = rz.decode_pose(bytes(w.bytes), rz.POSE_STAMPED, "jazzy")
    assert (p.t, p.x, p.y, p.frame_id) == (1_796_000_000.25, 1.5, -2.0, "map")
    assert p.th == pytest.approx(0.7, abs=1e-12)
