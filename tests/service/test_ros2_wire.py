"""The ROS 2 wire format (rmw_zenoh): type hashes, CDR against rosbags, keys, tokens, attachment."""

from __future__ import annotations

import contextlib
import math
import struct

import numpy as np
import pytest
import zenoh.ext as zext
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from controller.service.ros2 import cdr, typehash, wire

TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types
POSE_HASH = "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8"
JOINT_HASH = "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
frames = st.text(st.characters(min_codepoint=32, max_codepoint=0x2FF), max_size=40)


def _header(sec: int, nanosec: int, frame: str) -> object:
    return T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame
    )


def _pose_msg(sec: int, nanosec: int, frame: str, p: tuple[float, ...], q: tuple[float, ...]):
    pose = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
        orientation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
    )
    return T["geometry_msgs/msg/PoseStamped"](header=_header(sec, nanosec, frame), pose=pose)


# ---------------------------------------------------------------------------- type hashes


def test_type_hashes_match_the_published_values() -> None:
    assert typehash.type_hash("geometry_msgs/msg/PoseStamped") == POSE_HASH
    assert typehash.type_hash("sensor_msgs/msg/JointState") == JOINT_HASH


@pytest.mark.parametrize("name", sorted(typehash.MSG_DEFINITIONS))
def test_every_type_hash_matches_rosbags(name: str) -> None:
    assert typehash.type_hash(name) == TS.hash_rihs01(name)


def test_type_hash_depends_on_every_field() -> None:
    saved = typehash.MSG_DEFINITIONS["geometry_msgs/msg/Point"]
    try:
        typehash.MSG_DEFINITIONS["geometry_msgs/msg/Point"] = "float64 x\nfloat64 y\nfloat32 z"
        typehash.type_hash.cache_clear()
        assert typehash.type_hash("geometry_msgs/msg/PoseStamped") != POSE_HASH
    finally:
        typehash.MSG_DEFINITIONS["geometry_msgs/msg/Point"] = saved
        typehash.type_hash.cache_clear()
    assert typehash.type_hash("geometry_msgs/msg/PoseStamped") == POSE_HASH


def test_dds_type_names() -> None:
    assert (
        typehash.dds_type_name("geometry_msgs/msg/PoseStamped")
        == "geometry_msgs::msg::dds_::PoseStamped_"
    )
    assert typehash.dds_type_name("sensor_msgs/msg/JointState") == (
        "sensor_msgs::msg::dds_::JointState_"
    )
    with pytest.raises(typehash.TypeHashError):
        typehash.dds_type_name("PoseStamped")
    with pytest.raises(typehash.TypeHashError):
        typehash.type_hash("nav_msgs/msg/Odometry")


# ---------------------------------------------------------------------------- CDR


@settings(max_examples=150, deadline=None)
@given(
    stamp_ns=st.integers(0, 2**31 * 10**9 - 1),
    frame=frames,
    p=st.tuples(finite, finite, finite),
)
def test_pose_stamped_is_byte_identical_to_rosbags(
    stamp_ns: int, frame: str, p: tuple[float, float, float]
) -> None:
    sec, nanosec = divmod(stamp_ns, 10**9)
    ref = bytes(
        TS.serialize_cdr(
            _pose_msg(sec, nanosec, frame, p, (0.0, 0.0, 0.0, 1.0)),
            "geometry_msgs/msg/PoseStamped",
        )
    )
    mine = cdr.PoseStampedEncoder(frame).encode(stamp_ns, p)
    assert mine == ref
    back = cdr.decode_pose_stamped(mine)
    assert (back.sec, back.nanosec, back.frame_id, back.position_m) == (sec, nanosec, frame, p)


@settings(max_examples=150, deadline=None)
@given(
    frame=frames,
    data=st.data(),
    n=st.integers(0, 8),
    has_vel=st.booleans(),
    has_eff=st.booleans(),
)
def test_joint_state_is_byte_identical_to_rosbags(
    frame: str, data: st.DataObject, n: int, has_vel: bool, has_eff: bool
) -> None:
    names = data.draw(st.lists(st.text("abc_0123", min_size=1, max_size=9), min_size=n, max_size=n))
    arr = st.lists(finite, min_size=n, max_size=n)
    pos, vel, eff = data.draw(arr), data.draw(arr), data.draw(arr)
    msg = T["sensor_msgs/msg/JointState"](
        header=_header(12, 34, frame),
        name=names,
        position=np.array(pos, dtype=np.float64),
        velocity=np.array(vel if has_vel else [], dtype=np.float64),
        effort=np.array(eff if has_eff else [], dtype=np.float64),
    )
    ref = bytes(TS.serialize_cdr(msg, "sensor_msgs/msg/JointState"))
    mine = cdr.JointStateEncoder(frame, names).encode(
        12 * 10**9 + 34, pos, vel if has_vel else None, eff if has_eff else None
    )
    assert mine == ref


def test_string_is_byte_identical_to_rosbags() -> None:
    for text in ("", "IDLE", '{"state":"FAULT","reason":"node 3 stale"}', "é"):
        msg = T["std_msgs/msg/String"](data=text)
        assert cdr.encode_string(text) == bytes(TS.serialize_cdr(msg, "std_msgs/msg/String"))


def test_encoders_refuse_non_finite_values() -> None:
    with pytest.raises(cdr.CdrError):
        cdr.PoseStampedEncoder("world").encode(1, (0.0, math.nan, 1.0))
    enc = cdr.JointStateEncoder("world", ["a", "b"])
    with pytest.raises(cdr.CdrError):
        enc.encode(1, [1.0, math.inf])
    with pytest.raises(cdr.CdrError):
        enc.encode(1, [1.0, 2.0], [0.0, 0.0], [1.0, math.nan])
    with pytest.raises(cdr.CdrError):
        enc.encode(1, [1.0])


@settings(max_examples=100, deadline=None)
@given(lin=st.tuples(finite, finite, finite), ang=st.tuples(finite, finite, finite))
def test_twist_from_rosbags_decodes(lin: tuple[float, ...], ang: tuple[float, ...]) -> None:
    v3 = T["geometry_msgs/msg/Vector3"]
    msg = T["geometry_msgs/msg/Twist"](linear=v3(*lin), angular=v3(*ang))
    for little in (True, False):
        data = TS.serialize_cdr(msg, "geometry_msgs/msg/Twist", little_endian=little)
        got = cdr.decode_twist(bytes(data))
        assert (got.linear, got.angular) == (lin, ang)


def test_pose_stamped_big_endian_from_rosbags_decodes() -> None:
    msg = _pose_msg(3, 4, "map", (1.0, 2.0, 3.0), (0.0, 0.0, 0.0, 1.0))
    data = TS.serialize_cdr(msg, "geometry_msgs/msg/PoseStamped", little_endian=False)
    got = cdr.decode_pose_stamped(bytes(data))
    assert (got.sec, got.nanosec, got.frame_id, got.position_m) == (3, 4, "map", (1.0, 2.0, 3.0))


def _good_pose() -> bytes:
    return bytes(
        TS.serialize_cdr(
            _pose_msg(1, 2, "world", (0.1, 0.2, 0.3), (0.0, 0.0, 0.0, 1.0)),
            "geometry_msgs/msg/PoseStamped",
        )
    )


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b"", "shorter than the CDR header"),
        (b"\x00\x01", "shorter than the CDR header"),
        (b"\x00\x07\x00\x00" + bytes(60), "not plain CDR"),
        (_good_pose()[:40], "truncated"),
        (_good_pose()[:4] + b"\x00" * 8 + b"\xff\xff\xff\x7f", "frame_id length"),
        (_good_pose() + bytes(8), "bytes after the message"),
        (bytes(cdr.MAX_POSE_STAMPED_BYTES + 1), "at most"),
        (_good_pose()[:-8] + struct.pack("<d", math.nan), "not finite"),
        (_good_pose()[:4] + struct.pack("<iII", 1, 2, 3) + b"ab\x01" + bytes(57), "NUL"),
        (_good_pose()[:4] + struct.pack("<iII", 1, 2, 3) + b"\xff\xfe\x00" + bytes(57), "UTF-8"),
    ],
)
def test_malformed_pose_stamped_is_refused_by_name(payload: bytes, reason: str) -> None:
    with pytest.raises(cdr.CdrError, match=reason):
        cdr.decode_pose_stamped(payload)


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b"\x00\x01\x00\x00" + bytes(40), "truncated"),
        (b"\x00\x01\x00\x00" + bytes(60), "at most"),
        (b"\x00\x01\x00\x00" + struct.pack("<6d", 0, 0, math.inf, 0, 0, 0), "not finite"),
        (b"\x01\x01\x00\x00" + bytes(48), "not plain CDR"),
    ],
)
def test_malformed_twist_is_refused_by_name(payload: bytes, reason: str) -> None:
    with pytest.raises(cdr.CdrError, match=reason):
        cdr.decode_twist(payload)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=400))
def test_random_bytes_never_raise_anything_but_cdr_error(data: bytes) -> None:
    for decode in (cdr.decode_pose_stamped, cdr.decode_twist):
        with contextlib.suppress(cdr.CdrError):
            decode(data)


# ---------------------------------------------------------------------------- keys and tokens

ZID = "7ad9d4a6f3c1b2e0d5a4c3b2a1908070"
PT = "geometry_msgs::msg::dds_::PoseStamped_"


def test_topic_key_expressions() -> None:
    assert wire.topic_key(0, "/cablebot/pose", PT, POSE_HASH) == f"0/cablebot/pose/{PT}/{POSE_HASH}"
    assert wire.topic_key(42, "/pose", PT, POSE_HASH) == f"42/pose/{PT}/{POSE_HASH}"
    for bad in ("pose", "/a//b", "/", "/a/"):
        with pytest.raises(wire.WireError):
            wire.topic_key(0, bad, PT, POSE_HASH)


def test_qos_strings_leave_rmw_zenoh_defaults_empty() -> None:
    assert wire.qos_keyexpr(wire.Qos()) == "::,10:,:,:,,"
    assert wire.qos_keyexpr(wire.Qos(depth=42)) == "::,:,:,:,,"
    best_effort = wire.Qos(wire.BEST_EFFORT, wire.TRANSIENT_LOCAL, wire.KEEP_ALL, 5)
    assert wire.qos_keyexpr(best_effort) == "2:1:2,5:,:,:,,"


def test_liveliness_tokens_golden() -> None:
    assert wire.node_token(0, ZID, 0, "/cablebot", "cablebot") == (
        f"@ros2_lv/0/{ZID}/0/0/NN/%/%cablebot/cablebot"
    )
    assert wire.node_token(3, ZID, 0, "/", "rig") == f"@ros2_lv/3/{ZID}/0/0/NN/%/%/rig"
    pub = wire.endpoint_token(
        wire.PUBLISHER, 0, ZID, 0, 1, "/cablebot", "cablebot", "/cablebot/pose", PT, POSE_HASH,
        wire.Qos(),
    )  # fmt: skip
    assert pub == (
        f"@ros2_lv/0/{ZID}/0/1/MP/%/%cablebot/cablebot/%cablebot%pose/{PT}/{POSE_HASH}/::,10:,:,:,,"
    )
    sub = wire.endpoint_token(
        wire.SUBSCRIPTION, 0, ZID, 0, 4, "/cablebot", "cablebot", "/cablebot/goal_pose", PT,
        POSE_HASH, wire.Qos(),
    )  # fmt: skip
    assert sub.startswith(f"@ros2_lv/0/{ZID}/0/4/MS/%/%cablebot/cablebot/%cablebot%goal_pose/")
    with pytest.raises(wire.WireError):
        wire.endpoint_token("NN", 0, ZID, 0, 1, "/", "n", "/t", PT, POSE_HASH, wire.Qos())


def test_tokens_have_the_parts_rmw_zenoh_parses() -> None:
    """rmw_zenoh splits a token on '/' and refuses empty parts; an endpoint has 13."""
    pub = wire.endpoint_token(
        wire.PUBLISHER, 0, ZID, 0, 1, "/", "cablebot", "/pose", PT, POSE_HASH, wire.Qos()
    )
    parts = pub.split("/")
    assert len(parts) == 13 and all(parts)
    assert len(wire.node_token(0, ZID, 0, "/", "cablebot").split("/")) == 9


def test_gids_are_16_bytes_and_differ_per_entity() -> None:
    a = wire.gid("@ros2_lv/0/z/0/1/MP/x")
    assert len(a) == 16 and a == wire.gid("@ros2_lv/0/z/0/1/MP/x")
    assert a != wire.gid("@ros2_lv/0/z/0/2/MP/x")


def test_attachment_golden_and_as_zenoh_serializes_it() -> None:
    gid = bytes(range(16))
    att = wire.encode_attachment(5, -7, gid)
    assert att.hex() == (
        "0500000000000000" "f9ffffffffffffff" "10" "000102030405060708090a0b0c0d0e0f"
    )  # fmt: skip
    # zenoh-cpp's serializer writes std::array<uint8_t, 16> as a sequence: zenoh.ext agrees.
    ref = zext.z_serialize((zext.Int64(5), zext.Int64(-7), gid)).to_bytes()
    assert att == ref
    assert wire.decode_attachment(att) == (5, -7, gid)
    with pytest.raises(wire.WireError):
        wire.encode_attachment(1, 2, bytes(15))
    with pytest.raises(wire.WireError):
        wire.decode_attachment(att[:-1])
    with pytest.raises(wire.WireError):
        wire.decode_attachment(att[:16] + b"\x0f" + gid)
