"""The ROS-free rosbag2 MCAP writer: what the mcap reader, rosbags and our reader see in its bags."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, PoseArray
from mcap.reader import make_reader
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from visualization_msgs.msg import Marker, MarkerArray

from bptsb_ros.bags import msgdefs
from bptsb_ros.bags.errors import BagError, MessageDefinitionError
from bptsb_ros.bags.metadata import read_metadata
from bptsb_ros.bags.qos import INFINITE_NS, QosProfile, qos_profiles_from_value, qos_profiles_to_yaml
from bptsb_ros.bags.reader import bag_info, format_info, list_topics, read_arrays, read_messages
from bptsb_ros.bags.writer import BagWriter

T0 = 1_700_000_000_000_000_000
N = 25
DT_NS = 10_000_000
BEST_EFFORT = QosProfile(history="keep_last", depth=1, reliability="best_effort", deadline_ns=INFINITE_NS)


def _messages(i: int) -> dict[str, object]:
    array = Float64MultiArray(data=[float(i), 2.0 * i, 3.0 * i, 4.0 * i])
    array.layout.dim = [MultiArrayDimension(label="mass", size=2, stride=4),
                        MultiArrayDimension(label="xy", size=2, stride=2)]
    poses = PoseArray(poses=[Pose(position=Point(x=float(i), y=float(k), z=0.0)) for k in range(3)])
    poses.header.frame_id = "world"
    markers = MarkerArray(markers=[Marker(id=k, type=Marker.SPHERE, ns="masses") for k in range(2)])
    clock = Clock(clock=Time(sec=i // 100, nanosec=(i % 100) * DT_NS))
    return {"/body/state": array, "/body/positions": poses, "/body/markers": markers, "/clock": clock}


TYPES = {
    "/body/state": "std_msgs/msg/Float64MultiArray",
    "/body/positions": "geometry_msgs/msg/PoseArray",
    "/body/markers": "visualization_msgs/msg/MarkerArray",
    "/clock": "rosgraph_msgs/msg/Clock",
}


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("bags") / "demo"
    with BagWriter(path, chunk_size=4096, custom_data={"agent": "runs/x"}) as writer:
        for topic, msgtype in TYPES.items():
            writer.add_topic(topic, msgtype, qos_profiles=[BEST_EFFORT] if topic == "/clock" else None)
        for i in range(N):
            for topic, msg in _messages(i).items():
                writer.write(topic, serialize_message(msg), T0 + i * DT_NS, publish_time_ns=T0 + i * DT_NS - 5)
    return path


@pytest.mark.ros
def test_layout_and_metadata_yaml(bag: Path) -> None:
    assert sorted(p.name for p in bag.iterdir()) == ["demo_0.mcap", "metadata.yaml"]
    raw = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert raw["version"] == 9 and raw["storage_identifier"] == "mcap" and raw["ros_distro"]
    assert raw["relative_file_paths"] == ["demo_0.mcap"]
    assert raw["message_count"] == 4 * N
    assert raw["duration"] == {"nanoseconds": (N - 1) * DT_NS}
    assert raw["starting_time"] == {"nanoseconds_since_epoch": T0}
    assert raw["files"][0] == {"path": "demo_0.mcap", "starting_time": {"nanoseconds_since_epoch": T0},
                               "duration": {"nanoseconds": (N - 1) * DT_NS}, "message_count": 4 * N}
    assert raw["compression_format"] == "" and raw["compression_mode"] == ""
    assert raw["custom_data"] == {"agent": "runs/x"}
    topics = {t["topic_metadata"]["name"]: t for t in raw["topics_with_message_count"]}
    assert set(topics) == set(TYPES)
    clock = topics["/clock"]
    assert clock["message_count"] == N
    assert clock["topic_metadata"]["type"] == "rosgraph_msgs/msg/Clock"
    assert clock["topic_metadata"]["serialization_format"] == "cdr"
    assert clock["topic_metadata"]["type_description_hash"].startswith("RIHS01_")
    qos = clock["topic_metadata"]["offered_qos_profiles"]
    assert qos[0]["reliability"] == "best_effort" and qos[0]["deadline"] == {"sec": 9223372036, "nsec": 854775807}
    meta = read_metadata(bag)
    assert meta.topics[3].offered_qos_profiles == [BEST_EFFORT]


@pytest.mark.ros
def test_mcap_reader_sees_ros2_profile_schemas_indexes(bag: Path) -> None:
    with open(bag / "demo_0.mcap", "rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        summary = reader.get_summary()
        assert summary is not None
        messages = list(reader.iter_messages(log_time_order=True))
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert header.profile == "ros2" and "bptsb_ros" in header.library
    schemas = {s.name: s for s in summary.schemas.values()}
    assert set(schemas) == set(TYPES.values())
    assert all(s.encoding == "ros2msg" for s in schemas.values())
    marker_text = schemas["visualization_msgs/msg/MarkerArray"].data.decode()
    assert marker_text.startswith("Marker[] markers")
    for dep in ("visualization_msgs/Marker", "std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/Pose"):
        assert f"\n{'=' * 80}\nMSG: {dep}\n" in marker_text
    for channel in summary.channels.values():
        assert channel.message_encoding == "cdr"
        assert channel.metadata["topic_type_hash"] == msgdefs.type_description_hash(TYPES[channel.topic])
        profiles = qos_profiles_from_value(channel.metadata["offered_qos_profiles"])
        assert profiles == ([BEST_EFFORT] if channel.topic == "/clock" else [QosProfile()])
    stats = summary.statistics
    assert stats.message_count == 4 * N and stats.channel_count == 4 and stats.schema_count == 4
    assert stats.message_start_time == T0 and stats.message_end_time == T0 + (N - 1) * DT_NS
    assert set(stats.channel_message_counts.values()) == {N}
    assert len(summary.chunk_indexes) > 1 and stats.chunk_count == len(summary.chunk_indexes)
    assert all(ci.compression == "zstd" and ci.message_index_offsets for ci in summary.chunk_indexes)
    assert [m.log_time for _, _, m in messages] == sorted(T0 + i * DT_NS for i in range(N) for _ in TYPES)
    assert all(m.publish_time == m.log_time - 5 for _, _, m in messages)
    rosbag2 = yaml.safe_load(metadata["rosbag2"]["serialized_metadata"])
    assert rosbag2["message_count"] == 4 * N and rosbag2["version"] == 9


@pytest.mark.ros
def test_rosbags_reads_and_deserializes(bag: Path) -> None:
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        connections = {c.topic: c for c in reader.connections}
        assert {t: c.msgtype for t, c in connections.items()} == TYPES
        assert all(c.msgcount == N for c in connections.values())
        for conn in connections.values():
            # rosbags hashes the definition it parsed from our schema: equal to the installed type hash
            # only if the full definition (every nested type) is there and correct.
            assert reader.typestore.hash_rihs01(conn.msgtype) == msgdefs.type_description_hash(conn.msgtype)
        seen: dict[str, list] = {t: [] for t in TYPES}
        for conn, timestamp, rawdata in reader.messages():
            seen[conn.topic].append((timestamp, reader.deserialize(rawdata, conn.msgtype)))
    assert [t for t, _ in seen["/clock"]] == [T0 + i * DT_NS for i in range(N)]
    assert [m.clock.nanosec for _, m in seen["/clock"]] == [(i % 100) * DT_NS for i in range(N)]
    assert list(seen["/body/state"][7][1].data) == [7.0, 14.0, 21.0, 28.0]
    assert seen["/body/positions"][3][1].poses[2].position.y == 2.0
    assert seen["/body/positions"][3][1].header.frame_id == "world"
    assert [m.id for m in seen["/body/markers"][0][1].markers] == [0, 1]


@pytest.mark.ros
def test_our_reader_messages_arrays_and_info(bag: Path) -> None:
    msgs = list(read_messages(bag, ["/body/markers"]))
    assert len(msgs) == N and msgs[4].msgtype == "visualization_msgs/msg/MarkerArray"
    assert msgs[4].timestamp_ns == T0 + 4 * DT_NS and msgs[4].message.markers[1].ns == "masses"
    raw = next(read_messages(bag / "demo_0.mcap", "/clock", raw=True))
    assert isinstance(raw.message, bytes)
    window = list(read_messages(bag, ["/clock"], start_ns=T0 + 5 * DT_NS, end_ns=T0 + 8 * DT_NS))
    assert [m.timestamp_ns for m in window] == [T0 + k * DT_NS for k in (5, 6, 7)]

    arrays = read_arrays(bag, ["/body/state", "/body/positions", "/clock"])
    state = arrays["/body/state"]
    assert state.values.shape == (N, 2, 2) and state.t_ns.dtype == np.int64
    np.testing.assert_array_equal(state.values[:, 1, 1], 4.0 * np.arange(N))
    np.testing.assert_allclose(state.t_s, np.arange(N) * DT_NS / 1e9)
    assert arrays["/body/positions"].values.shape == (N, 3, 3)
    np.testing.assert_allclose(arrays["/clock"].values, (np.arange(N) % 100) * DT_NS / 1e9)
    custom = read_arrays(bag, ["/body/markers"], converters={"/body/markers": lambda m: np.array(len(m.markers))})
    np.testing.assert_array_equal(custom["/body/markers"].values, np.full(N, 2.0))
    with pytest.raises(BagError, match="no default array conversion"):
        read_arrays(bag, ["/body/markers"])

    info = bag_info(bag)
    assert info.message_count == 4 * N and info.duration_ns == (N - 1) * DT_NS
    assert {t.name: t.message_count for t in info.topics} == dict.fromkeys(TYPES, N)
    text = format_info(info)
    for needle in ("Files:             demo_0.mcap", "Storage id:        mcap", "Messages:          100",
                   "Duration:          0.240000000s", "Type: visualization_msgs/msg/MarkerArray | Count: 25"):
        assert needle in text
    single = bag_info(bag / "demo_0.mcap")
    assert single.message_count == 4 * N and single.ros_distro == info.ros_distro
    assert list_topics(bag) == TYPES


def test_message_definition_matches_rosbag2_layout() -> None:
    share = msgdefs.find_share_dir("rosgraph_msgs")
    clock = (share / "msg" / "Clock.msg").read_text()
    time = (msgdefs.find_share_dir("builtin_interfaces") / "msg" / "Time.msg").read_text()
    definition = msgdefs.message_definition("rosgraph_msgs/msg/Clock")
    assert definition.encoding == "ros2msg"
    assert definition.text == clock + "\n" + "=" * 80 + "\nMSG: builtin_interfaces/Time\n" + time
    # Each nested type appears once, depth first, dependencies in sorted order.
    text = msgdefs.message_definition("geometry_msgs/PoseArray").text
    assert [line for line in text.splitlines() if line.startswith("MSG: ")] == [
        "MSG: geometry_msgs/Pose", "MSG: geometry_msgs/Point", "MSG: geometry_msgs/Quaternion",
        "MSG: std_msgs/Header", "MSG: builtin_interfaces/Time"]


def test_qos_yaml_roundtrip_and_old_versions() -> None:
    profiles = [BEST_EFFORT, QosProfile(durability="transient_local", lifespan_ns=1_500_000_000)]
    assert qos_profiles_from_value(qos_profiles_to_yaml(profiles)) == profiles
    v8 = ("- history: 1\n  depth: 5\n  reliability: 2\n  durability: 1\n  deadline: {sec: 2147483647, nsec: "
          "4294967295}\n  lifespan: {sec: 0, nsec: 0}\n  liveliness: 1\n  liveliness_lease_duration: {sec: 0, nsec: 0}"
          "\n  avoid_ros_namespace_conventions: false")
    (old,) = qos_profiles_from_value(v8)
    assert (old.history, old.depth, old.reliability, old.durability, old.liveliness) == (
        "keep_last", 5, "best_effort", "transient_local", "automatic")
    assert old.deadline_ns == INFINITE_NS
    with pytest.raises(BagError, match="malformed QoS profile"):
        qos_profiles_from_value([{"history": "keep_last"}])


@pytest.mark.ros
def test_writer_and_reader_reject_bad_input(bag: Path, tmp_path: Path) -> None:
    with pytest.raises(BagError, match="already exists"):
        BagWriter(bag)
    with BagWriter(tmp_path / "b") as writer:
        with pytest.raises(MessageDefinitionError, match="not a ROS 2 message type name"):
            writer.add_topic("/x", "Float64")
        with pytest.raises(MessageDefinitionError, match="no_such_pkg"):
            writer.add_topic("/x", "no_such_pkg/msg/Thing")
        with pytest.raises(BagError, match="must be absolute"):
            writer.add_topic("x", "std_msgs/msg/Float64")
        writer.add_topic("/x", "std_msgs/msg/Float64")
        with pytest.raises(BagError, match="already added with type"):
            writer.add_topic("/x", "std_msgs/msg/String")
        with pytest.raises(BagError, match="call add_topic first"):
            writer.write("/y", b"\x00\x01\x00\x00", T0)
    with pytest.raises(BagError, match="already closed"):
        writer.write("/x", b"", T0)
    with pytest.raises(BagError, match="unknown chunk compression"):
        BagWriter(tmp_path / "c", compression="gzip")

    with pytest.raises(BagError, match="bag not found"):
        list(read_messages(tmp_path / "missing"))
    with pytest.raises(BagError, match="topic\\(s\\) not in bag .*: /nope; available: /body/state"):
        list(read_messages(bag, ["/body/state", "/nope"]))
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(BagError, match="metadata.yaml is missing.*bptsb bag recover"):
        bag_info(empty)
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"this is not an mcap file at all" * 10)
    with pytest.raises(BagError, match="garbage.mcap is not a"):
        list(read_messages(garbage))
    (empty / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: 9}\n")
    with pytest.raises(BagError, match="malformed rosbag2 metadata"):
        bag_info(empty)


def test_bad_writer_options_create_nothing(tmp_path: Path) -> None:
    for kwargs in ({"compression": "gzip"}, {"chunk_size": 0}):
        with pytest.raises(BagError):
            BagWriter(tmp_path / "bad" / "bag", **kwargs)
        assert not (tmp_path / "bad" / "bag").exists()


@pytest.mark.ros
def test_joint_state_arrays_take_the_filled_field(tmp_path: Path) -> None:
    from sensor_msgs.msg import JointState

    bag = tmp_path / "js"
    with BagWriter(bag) as writer:
        for i in range(3):
            writer.write_message("/force", JointState(name=["a", "b"], effort=[float(i), -1.0]), 10 + i)
            writer.write_message("/state", JointState(position=[1.0], velocity=[2.0], effort=[3.0]), 10 + i)
            writer.write_message("/empty", JointState(name=["a"]), 10 + i)
    arrays = read_arrays(bag, ["/force", "/state"])
    assert arrays["/force"].values.tolist() == [[0.0, -1.0], [1.0, -1.0], [2.0, -1.0]]
    assert arrays["/state"].values.tolist() == [[1.0]] * 3
    with pytest.raises(BagError, match="no position, velocity or effort"):
        read_arrays(bag, ["/empty"])


# A whole offered profile as rosbag2 Jazzy writes it (metadata version 9: lower-case policy names, durations as
# {sec, nsec}), typed here from rosbag2's format, not produced by our code.
LATCHED_KEEP_ALL = QosProfile(history="keep_all", depth=0, reliability="reliable", durability="transient_local",
                              deadline_ns=1_500_000_000, lifespan_ns=INFINITE_NS, liveliness="automatic",
                              liveliness_lease_duration_ns=250_000_000)
LATCHED_KEEP_ALL_RAW = {
    "history": "keep_all", "depth": 0, "reliability": "reliable", "durability": "transient_local",
    "deadline": {"sec": 1, "nsec": 500_000_000}, "lifespan": {"sec": 9223372036, "nsec": 854775807},
    "liveliness": "automatic", "liveliness_lease_duration": {"sec": 0, "nsec": 250_000_000},
    "avoid_ros_namespace_conventions": False,
}
KEEP_LAST_7_RAW = {
    "history": "keep_last", "depth": 7, "reliability": "best_effort", "durability": "volatile",
    "deadline": {"sec": 0, "nsec": 0}, "lifespan": {"sec": 0, "nsec": 0}, "liveliness": "system_default",
    "liveliness_lease_duration": {"sec": 0, "nsec": 0}, "avoid_ros_namespace_conventions": False,
}


@pytest.mark.ros
def test_whole_qos_profiles_in_raw_metadata_and_mcap_channels(tmp_path: Path) -> None:
    """Every field of two offered profiles, read from metadata.yaml and the MCAP channel metadata directly."""
    bag = tmp_path / "qos"
    with BagWriter(bag) as writer:
        writer.add_topic("/latched", "std_msgs/msg/Float64MultiArray",
                         qos_profiles=[LATCHED_KEEP_ALL, QosProfile(depth=7, reliability="best_effort")])
        writer.write("/latched", serialize_message(Float64MultiArray(data=[1.0])), T0)
    raw = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    (topic,) = raw["topics_with_message_count"]
    assert topic["topic_metadata"]["offered_qos_profiles"] == [LATCHED_KEEP_ALL_RAW, KEEP_LAST_7_RAW]
    with open(bag / "qos_0.mcap", "rb") as f:
        (channel,) = make_reader(f).get_summary().channels.values()
    text = channel.metadata["offered_qos_profiles"]
    assert isinstance(text, str) and yaml.safe_load(text) == [LATCHED_KEEP_ALL_RAW, KEEP_LAST_7_RAW]


@pytest.mark.ros
def test_qos_from_rclpy_keeps_every_policy() -> None:
    """A recorder stores what rclpy reports for a publisher: every policy, lower-case, depth as given."""
    from rclpy.duration import Duration
    from rclpy.qos import QoSDurabilityPolicy, QoSHistoryPolicy, QoSLivelinessPolicy, QoSProfile, QoSReliabilityPolicy

    offered = QoSProfile(history=QoSHistoryPolicy.KEEP_ALL, depth=0, reliability=QoSReliabilityPolicy.RELIABLE,
                         durability=QoSDurabilityPolicy.TRANSIENT_LOCAL, deadline=Duration(seconds=1.5),
                         lifespan=Duration(nanoseconds=INFINITE_NS), liveliness=QoSLivelinessPolicy.AUTOMATIC,
                         liveliness_lease_duration=Duration(nanoseconds=250_000_000))
    assert QosProfile.from_rclpy(offered).to_dict() == LATCHED_KEEP_ALL_RAW
    keep_last = QoSProfile(history=QoSHistoryPolicy.KEEP_LAST, depth=7, reliability=QoSReliabilityPolicy.BEST_EFFORT,
                           durability=QoSDurabilityPolicy.VOLATILE)
    assert QosProfile.from_rclpy(keep_last).to_dict() == KEEP_LAST_7_RAW
