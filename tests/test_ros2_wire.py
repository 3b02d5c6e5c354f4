"""rmw_zenoh's wire format as services/ros2 writes it: keys, liveliness tokens, QoS chunks,
attachments, interfaces and their RIHS01 hashes. Plain and fast: no zenoh session (zenoh-ext's
serialiser is called directly, as the reference for the attachment's bytes).

The expected layouts are rmw_zenoh's (docs/design.md and liveliness_utils.cpp of ros2/rmw_zenoh):
the examples are the design document's own; the hashes come from rosbags' typestores, never typed
in, but for std_srvs/srv/Trigger, which rosbags lacks: its published hash is the check that the
service is hashed as ROS hashes a service.
"""

from __future__ import annotations

import struct

import pytest
import zenoh.ext
from hypothesis import given
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from schemas.codec import BadInput
from services.ros2 import interfaces, wire

TRIGGER_HASH_PUBLISHED = "RIHS01_eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f"
"""std_srvs/srv/Trigger's hash in Jazzy as ROS publishes it (two public implementations agree on
it): the oracle that the service is hashed as ROS hashes a service, since rosbags has no service types."""

MESSAGES = (
    interfaces.ODOMETRY,
    interfaces.TF_MESSAGE,
    interfaces.JOINT_STATE,
    interfaces.CLOCK,
    interfaces.STRING,
    interfaces.TWIST,
    interfaces.TWIST_STAMPED,
)


@pytest.mark.parametrize("name", MESSAGES)
@pytest.mark.parametrize("store", [Stores.ROS2_JAZZY, Stores.ROS2_KILTED])
def test_message_hashes_are_rosbags_for_jazzy_and_kilted(name, store):
    assert interfaces.interface(name).type_hash == get_typestore(store).hash_rihs01(name)


def test_the_trigger_service_hash_is_the_one_ros_publishes():
    assert interfaces.interface(interfaces.TRIGGER).type_hash == TRIGGER_HASH_PUBLISHED


def test_qos_chunks_are_rmw_zenohs():
    assert wire.SYSTEM_DEFAULT.token_chunk() == "::,10:,:,:,,"  # design.md's example
    assert wire.TF.token_chunk() == "::,100:,:,:,,"
    assert wire.LATCHED.token_chunk() == ":1:,1:,:,:,,"
    assert wire.CLOCK.token_chunk() == "2::,1:,:,:,,"
    assert wire.Qos(depth=wire.RMW_ZENOH_DEFAULT_DEPTH).token_chunk() == "::,:,:,:,,"
    assert wire.Qos(history=wire.History.KEEP_ALL).token_chunk() == "::2,10:,:,:,,"


def test_names_keys_and_mangling():
    assert wire.absolute_namespace("") == "" and wire.absolute_namespace("rh0/") == "/rh0"
    assert wire.full_name("", "odom") == "/odom" and wire.full_name("/rh0", "odom") == "/rh0/odom"
    assert wire.full_name("/rh0", "/tf") == "/tf"
    assert wire.mangle("/rh0/odom") == "%rh0%odom" and wire.mangle("") == "%"
    assert wire.dds_type_name("nav_msgs/msg/Odometry") == "nav_msgs::msg::dds_::Odometry_"
    assert wire.dds_type_name("std_srvs/srv/Trigger") == "std_srvs::srv::dds_::Trigger_"
    odometry = interfaces.interface(interfaces.ODOMETRY)
    assert wire.data_key(7, "/rh0/odom", odometry.name, odometry.type_hash) == (
        f"7/rh0/odom/nav_msgs::msg::dds_::Odometry_/{odometry.type_hash}"
    )


def test_tokens_have_rmw_zenohs_layout():
    node = wire.NodeIdentity(domain=3, zid="aabbcc", namespace="/rh0", name="invent_bridge")
    assert node.token() == "@ros2_lv/3/aabbcc/0/0/NN/%/%rh0/invent_bridge"
    odometry = interfaces.interface(interfaces.ODOMETRY)
    token = node.entity_token(2, wire.EntityKind.PUBLISHER, "/rh0/odom", odometry.name, odometry.type_hash, wire.TF)
    chunks = token.split("/")
    assert chunks == [
        "@ros2_lv",
        "3",
        "aabbcc",
        "0",
        "2",
        "MP",
        "%",
        "%rh0",
        "invent_bridge",
        "%rh0%odom",
        "nav_msgs::msg::dds_::Odometry_",
        odometry.type_hash,
        "::,100:,:,:,,",
    ]
    assert all(chunks), "zenoh refuses empty chunks"


def test_the_attachment_is_zenoh_ext_serialised_and_33_bytes():
    gid = bytes(range(16))
    encoded = wire.Attachment(7, 1_700_000_000_123, gid).encode()
    reference = zenoh.ext.z_serialize((zenoh.ext.Int64(7), zenoh.ext.Int64(1_700_000_000_123), gid)).to_bytes()
    assert encoded == reference and len(encoded) == wire.ATTACHMENT_LENGTH == 33
    assert wire.Attachment.decode(encoded) == wire.Attachment(7, 1_700_000_000_123, gid)


@given(st.integers(0, 2**63 - 1), st.integers(0, 2**63 - 1), st.binary(min_size=16, max_size=16))
def test_attachments_round_trip(sequence_number, timestamp_ns, gid):
    attachment = wire.Attachment(sequence_number, timestamp_ns, gid)
    assert wire.Attachment.decode(attachment.encode()) == attachment


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (None, "no attachment"),
        (b"", "0 bytes"),
        (bytes(32), "32 bytes"),
        (bytes(34), "34 bytes"),
        (struct.pack("<qqB", 1, 1, 15) + bytes(16), "GID of 15 bytes"),
        (struct.pack("<qqB", -1, 1, 16) + bytes(16), "negative"),
    ],
)
def test_a_wrong_attachment_is_bad_input(data, reason):
    with pytest.raises(BadInput, match=reason):
        wire.Attachment.decode(data)


def test_a_publishers_sequence_counts_from_one_with_one_gid():
    token = "@ros2_lv/0/aa/0/1/MP/%/%/n/%odom/nav_msgs::msg::dds_::Odometry_/RIHS01_x/::,10:,:,:,,"
    sequence = wire.Sequence(wire.gid_of(token))
    attachments = [wire.Attachment.decode(sequence.next(100 + k)) for k in range(3)]
    assert [a.sequence_number for a in attachments] == [1, 2, 3]
    assert {a.gid for a in attachments} == {wire.gid_of(token)} and len(wire.gid_of(token)) == 16
    assert wire.gid_of(token) != wire.gid_of(token.replace("/1/MP", "/2/MP"))


def test_cdr_round_trips_and_malformed_cdr_is_bad_input():
    twist = interfaces.message_class(interfaces.TWIST)
    vector = interfaces.message_class("geometry_msgs/msg/Vector3")
    message = twist(linear=vector(0.5, 0.0, 0.0), angular=vector(0.0, 0.0, -1.0))
    data = interfaces.serialize(message)
    assert data[:4] == b"\x00\x01\x00\x00", "little-endian CDR with its encapsulation header"
    assert interfaces.deserialize(data, interfaces.TWIST) == message
    for malformed in (b"", data[:10], b"\x07\x07\x00\x00" + data[4:], b"garbage"):
        with pytest.raises(BadInput, match="malformed CDR"):
            interfaces.deserialize(malformed, interfaces.TWIST)
    response = interfaces.message_class(interfaces.TRIGGER_RESPONSE)(success=True, message="ok")
    assert interfaces.deserialize(interfaces.serialize(response), interfaces.TRIGGER_RESPONSE) == response


def test_a_humble_graph_writes_no_type_hash():
    from services.config import load_config
    from services.ros2.graph import PUBLICATIONS, bridge_graph

    humble = bridge_graph(load_config(overrides={"ros2.distro": "humble"}), environ={"ROS_DOMAIN_ID": "3"})
    assert humble.key(PUBLICATIONS["odom"]) == "3/odom/nav_msgs::msg::dds_::Odometry_/TypeHashNotSupported"
    jazzy = bridge_graph(load_config(), environ={})
    assert jazzy.key(PUBLICATIONS["odom"]).endswith(interfaces.interface(interfaces.ODOMETRY).type_hash)


@pytest.mark.parametrize("text", ["-1", "233", "one", "1.5"])
def test_a_ros_domain_outside_0_to_232_is_a_configuration_error(text):
    from services.config import ConfigError
    from services.ros2.graph import ros_domain

    with pytest.raises(ConfigError, match="ROS_DOMAIN_ID"):
        ros_domain({"ROS_DOMAIN_ID": text})
    assert ros_domain({}) == 0 and ros_domain({"ROS_DOMAIN_ID": "232"}) == 232
