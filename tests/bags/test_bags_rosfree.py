"""Bags without ROS: the rosbags decoder gives the messages rclpy gives, and replay/IPC run with rclpy unimportable.

The bag is written here with the live nodes' own message builders (rclpy serializes them); each message is then
decoded by rclpy and by rosbags from the bag's schema text, and the two must agree field by field (names, types
of scalars, every value). The subprocess test blocks every ROS Python package with a meta-path finder installed
by a ``sitecustomize`` of its own, so the package cannot import rclpy or a message package by any route.
"""

from __future__ import annotations

import array
import dataclasses
import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT as REPO
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PointStamped, Vector3Stamped
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Image
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from bptsb_ros.bags.decode import MessageDecoder, check_typesdict
from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.msgdefs import MessageDefinition
from bptsb_ros.bags.publishers import PublisherId
from bptsb_ros.bags.reader import read_arrays, read_messages, read_published
from bptsb_ros.bags.writer import BagWriter
from bptsb_ros.cli import main
from bptsb_ros.interface.topics import dt_to_ns, input_names, spring_names
from bptsb_ros.ros import messages as m

DT_NS = dt_to_ns(0.01)
BODY = PublisherId("01.0f.aa.00.00.00.00.00.00.00.00.00.00.00.01.03", "body_sim", "/")
FORGER = PublisherId("01.0f.bb.00.00.00.00.00.00.00.00.00.00.00.01.03", "forger", "/evil")


def _positions(k: int) -> np.ndarray:
    """(3, 2) planted positions of step k [m]."""
    return np.array([[-1.0, 0.0], [1.0, 0.0], [0.2 * np.cos(0.1 * k), 0.2 * np.sin(0.2 * k)]])


def _every_type(k: int) -> dict[str, object]:
    """One message of every type the recorder records (built as the nodes build them), stamped at step k."""
    pos = _positions(k)
    springs, fixed = np.array([[0, 2], [1, 2]]), np.array([True, True, False])
    diag = DiagnosticArray(status=[DiagnosticStatus(level=DiagnosticStatus.WARN, name="body_sim: loop",
                                                    message=f"step {k}", hardware_id="msdn",
                                                    values=[KeyValue(key="steps", value=str(k))])])
    diag.header.stamp = m.stamp(k, DT_NS)
    wind = Vector3Stamped()
    wind.header.stamp = m.stamp(k, DT_NS)
    wind.vector.x, wind.vector.y = 0.5 * k, -0.25
    image = Image(height=2, width=3, step=3, encoding="mono8", is_bigendian=0,
                  data=bytes(range(k % 200, k % 200 + 6)))
    image.header.stamp = m.stamp(k, DT_NS)
    point = PointStamped()
    point.point.x, point.point.y, point.point.z = 1.5, -k * 0.125, 3.0
    grid = Float64MultiArray(data=[float(k), 2.0, 3.0, 4.0, 5.0, 6.0])
    grid.layout.dim = [MultiArrayDimension(label="mass", size=3, stride=6),
                       MultiArrayDimension(label="xy", size=2, stride=2)]
    return {
        "/clock": m.clock_msg(k, DT_NS),
        "/body/positions": m.pose_array(k, DT_NS, pos, "msdn"),
        "/body/mass_states": m.joint_state(k, DT_NS, ["m2x", "m2y"], position=pos[2], velocity=pos[2] * 2,
                                           effort=np.array([0.0, -9.81])),
        "/body/spring_lengths": m.joint_state(k, DT_NS, spring_names(2), position=np.array([1.1, 0.9 + k / 100])),
        "/body/markers": m.body_markers(k, DT_NS, pos, springs, fixed, 2, np.array([0.05, -0.3]), "msdn", 0.1),
        "/diagnostics": diag,
        "/env/wind": wind,
        "/camera/image": image,
        "/task/input": m.joint_state(k, DT_NS, input_names(1), position=np.array([k / 10])),
        "/debug/point": point,
        "/debug/grid": grid,
    }


TYPES = {
    "/clock": "rosgraph_msgs/msg/Clock", "/body/positions": "geometry_msgs/msg/PoseArray",
    "/body/mass_states": "sensor_msgs/msg/JointState", "/body/spring_lengths": "sensor_msgs/msg/JointState",
    "/body/markers": "visualization_msgs/msg/MarkerArray", "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
    "/env/wind": "geometry_msgs/msg/Vector3Stamped", "/camera/image": "sensor_msgs/msg/Image",
    "/task/input": "sensor_msgs/msg/JointState", "/debug/point": "geometry_msgs/msg/PointStamped",
    "/debug/grid": "std_msgs/msg/Float64MultiArray",
}
STEPS = 6


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rosfree") / "every_type"
    with BagWriter(path, chunk_size=2048) as w:
        for topic, msgtype in TYPES.items():
            w.add_topic(topic, msgtype)
        for k in range(STEPS):
            for topic, msg in _every_type(k).items():
                w.write(topic, serialize_message(msg), (k + 1) * DT_NS, publisher=BODY)
        w.write("/body/positions", serialize_message(m.pose_array(2, DT_NS, _positions(0) + 7, "msdn")),
                STEPS * DT_NS + 1, publisher=FORGER)
    return path


def _plain(value: object) -> object:
    """A message as nested dicts/lists of Python scalars, with rclpy's and rosbags' containers made alike:
    ``array.array``/numpy arrays become lists, a 1-byte ``bytes`` (rclpy's ``byte`` field) an int. Scalars keep
    their Python type, so an int read as a float (or a float32 widened differently) would differ."""
    if isinstance(value, np.ndarray | array.array | list | tuple):
        return [_plain(v) for v in (value.tolist() if hasattr(value, "tolist") else value)]
    if isinstance(value, bytes):
        return value[0] if len(value) == 1 else list(value)
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, str | int | float | bool):
        return value
    if hasattr(value, "get_fields_and_field_types"):  # an rclpy message
        cls = type(value)
        name = f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}"
        fields = list(value.get_fields_and_field_types())
    elif dataclasses.is_dataclass(value):  # a rosbags message; its constants (and __msgtype__) have defaults
        name = value.__msgtype__
        fields = [f.name for f in dataclasses.fields(value) if f.default is dataclasses.MISSING]
    else:
        raise AssertionError(f"unexpected value {value!r}")
    return {"__type__": name, **{f: _plain(getattr(value, f)) for f in fields}}


def _typed(value: object) -> object:
    """``_plain`` with each scalar's type next to it."""
    if isinstance(value, dict):
        return {k: _typed(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_typed(v) for v in value]
    return (type(value).__name__, value)


@pytest.mark.ros
def test_rosbags_decodes_every_recorded_type_as_rclpy_does(bag: Path) -> None:
    by_rclpy = list(read_published(bag, decoder="rclpy"))
    by_rosbags = list(read_published(bag, decoder="rosbags"))
    assert len(by_rclpy) == len(by_rosbags) == STEPS * len(TYPES) + 1
    assert {type(p.message.message).__module__.split(".")[0] for p in by_rosbags} == {"rosbags"}
    for (ros_msg, ros_pub), (rb_msg, rb_pub) in zip(by_rclpy, by_rosbags):
        assert (ros_msg.topic, ros_msg.msgtype, ros_msg.timestamp_ns) == (rb_msg.topic, rb_msg.msgtype,
                                                                          rb_msg.timestamp_ns)
        assert ros_pub == rb_pub and ros_pub in (BODY, FORGER)
        assert _typed(_plain(rb_msg.message)) == _typed(_plain(ros_msg.message)), ros_msg.topic
    # and both are the messages written, as rclpy round-trips them without our reader (float32 fields such as
    # marker colours come back rounded to float32)
    planted = [_plain(deserialize_message(serialize_message(msg), type(msg)))
               for k in range(STEPS) for msg in _every_type(k).values()]
    assert [_plain(p.message.message) for p in by_rosbags[:-1]] == planted


@pytest.mark.ros
def test_a_bag_recorded_through_dds_decodes_alike() -> None:
    """The example bag was recorded live (the bytes as DDS delivered them, not as rclpy serializes them here)."""
    bag = REPO / "bags" / "lissajous_closed_example"
    topics = ["/diagnostics", "/brain/rest_length"]
    by_rclpy = list(read_published(bag, topics, decoder="rclpy"))
    by_rosbags = list(read_published(bag, topics, decoder="rosbags"))
    assert len(by_rclpy) == len(by_rosbags) == 3 + 402  # the counts bag info lists
    for (ros_msg, ros_pub), (rb_msg, rb_pub) in zip(by_rclpy, by_rosbags):
        assert ros_msg[:3] == rb_msg[:3] and ros_pub == rb_pub
        assert _typed(_plain(rb_msg.message)) == _typed(_plain(ros_msg.message)), ros_msg.topic


@pytest.mark.ros
def test_the_comparison_sees_a_one_value_difference(bag: Path) -> None:
    """The field-by-field comparison above is not vacuous: one changed float in one marker colour shows."""
    msg = next(p.message.message for p in read_published(bag, ["/body/markers"], decoder="rosbags"))
    before = _typed(_plain(msg))
    msg.markers[0].colors[1].g += 2.0 ** -20
    assert _typed(_plain(msg)) != before
    assert _typed({"a": [1]}) != _typed({"a": [1.0]})  # an int read as a float would show


@pytest.mark.ros
def test_arrays_and_auto_decoder_agree_with_planted_values(bag: Path) -> None:
    topics = ["/body/positions", "/body/mass_states", "/task/input", "/debug/grid", "/clock", "/env/wind"]
    ros = read_arrays(bag, topics, decoder="rclpy")
    rb = read_arrays(bag, topics, decoder="rosbags")
    auto = read_arrays(bag, topics)
    for topic in topics:
        assert np.array_equal(ros[topic].values, rb[topic].values) and np.array_equal(ros[topic].t_ns, rb[topic].t_ns)
        assert np.array_equal(auto[topic].values, ros[topic].values)
    expected = np.stack([np.c_[_positions(k), np.zeros(3)] for k in range(STEPS)] + [np.c_[_positions(0) + 7,
                                                                                            np.zeros(3)]])
    assert np.array_equal(rb["/body/positions"].values, expected)
    assert np.array_equal(rb["/debug/grid"].values[4], np.array([[4.0, 2.0], [3.0, 4.0], [5.0, 6.0]]))
    assert np.array_equal(rb["/clock"].values, np.arange(STEPS) * DT_NS * 1e-9)  # the converter: sec + nanosec·1e-9
    assert np.array_equal(rb["/task/input"].values[:, 0], np.arange(STEPS) / 10)


@pytest.mark.ros
def test_a_custom_type_decodes_from_the_schema_text_alone(tmp_path: Path) -> None:
    """A type no package installs: its definition is only in the bag. auto falls back to rosbags (rclpy has no
    class for it); the CDR bytes are packed here by hand (little-endian, encapsulation 00 01 00 00)."""
    definition = MessageDefinition("lab_msgs/msg/Trial", "ros2msg",
                                   "uint32 id\nstring label\nfloat64[] scores\nlab_msgs/Gain gain\n"
                                   + "=" * 80 + "\nMSG: lab_msgs/Gain\nfloat32 k\nint8 sign\n")
    body = struct.pack("<I", 7) + struct.pack("<I", 4) + b"abc\x00" + struct.pack("<I", 2)
    body += struct.pack("<dd", 0.5, -2.25) + struct.pack("<fb", 1.5, -1)
    with BagWriter(tmp_path / "bag") as w:
        w.add_topic("/trial", "lab_msgs/msg/Trial", definition=definition, type_hash="")
        w.write("/trial", b"\x00\x01\x00\x00" + body, 5)
    for decoder in ("auto", "rosbags"):
        (msg,) = [x.message for x in read_messages(tmp_path / "bag", decoder=decoder)]
        assert (msg.id, msg.label, msg.scores.tolist(), msg.gain.k, msg.gain.sign) == (7, "abc", [0.5, -2.25], 1.5, -1)
    with pytest.raises(BagError, match="lab_msgs/msg/Trial is not an installed ROS 2 message"):
        list(read_messages(tmp_path / "bag", decoder="rclpy"))


def test_bad_schemas_and_messages_are_one_line_errors(tmp_path: Path) -> None:
    with BagWriter(tmp_path / "bag") as w:
        w.add_topic("/bad", "lab_msgs/msg/Bad", definition=MessageDefinition("lab_msgs/msg/Bad", "ros2msg",
                                                                             "float64[ x\n"), type_hash="")
        w.write("/bad", b"\x00\x01\x00\x00" + bytes(8), 1)
        w.add_topic("/short", "std_msgs/msg/Float64MultiArray")
        w.write("/short", b"\x00\x01\x00\x00\x01\x00\x00\x00", 2)  # one layout dim announced, none there
    with pytest.raises(BagError, match="schema of lab_msgs/msg/Bad cannot be parsed") as err:
        list(read_messages(tmp_path / "bag", ["/bad"], decoder="rosbags"))
    assert "\n" not in str(err.value)
    with pytest.raises(BagError, match="a std_msgs/msg/Float64MultiArray message cannot be decoded"):
        list(read_messages(tmp_path / "bag", ["/short"], decoder="rosbags"))
    with pytest.raises(BagError, match="unknown message decoder 'ros1'"):
        MessageDecoder("ros1")


@pytest.mark.parametrize("text, why", [
    ("lab_msgs/Loop child\n", r"nests types more than 32 deep \(a type that contains itself\?\)"),
    ("lab_msgs/Missing child\n", "cannot be used: KeyError"),  # a nested type the schema never defines
])
def test_a_schema_whose_deserialiser_cannot_be_built_is_one_error(text, why) -> None:
    from mcap.records import Schema

    from bptsb_ros.bags.decode import rosbags_decoder

    schema = Schema(id=1, name="lab_msgs/msg/Loop", encoding="ros2msg", data=text.encode())
    with pytest.raises(BagError, match=f"schema of lab_msgs/msg/Loop {why}"):
        rosbags_decoder(schema)


def test_schema_names_that_would_be_code_are_refused() -> None:
    """rosbags compiles parsed types into Python source; a name that is not an identifier never reaches it."""
    field = (1, ("float64", 0))  # Nodetype.BASE
    check_typesdict({"lab_msgs/msg/Ok": ([], [("x", field)])}, "lab_msgs/msg/Ok")
    for typs in ({"lab_msgs/msg/Ok": ([], [("x=0;import os#", field)])},
                 {"lab_msgs/msg/X:pass": ([], [("x", field)])},
                 {"lab_msgs/msg/Ok": ([], [("x", (2, "a/msg/B]);x=(0"))])},
                 {"lab_msgs/msg/Ok": ([("C)#", "uint8", 1)], [])}):
        with pytest.raises(BagError, match="not a plain identifier"):
            check_typesdict(typs, "lab_msgs/msg/Ok")
    # constant values and bounds are written into the generated source as they are: plain literals only
    ok = {"lab_msgs/msg/Ok": ([("A", "uint8", 1), ("B", "float64", 0.5), ("S", "string", "x')#"),
                               ("T", "bool", True)], [("x", (3, ((1, ("float64", 0)), 4))), ("s", (1, ("string", 8)))])}
    check_typesdict(ok, "lab_msgs/msg/Ok")
    for typs, why in (({"lab_msgs/msg/Ok": ([("C", "uint8", object())], [])}, "not a number, boolean or string"),
                      ({"lab_msgs/msg/Ok": ([], [("x", (3, ((1, ("float64", 0)), "4]+[0")))])}, "not a whole number"),
                      ({"lab_msgs/msg/Ok": ([], [("s", (1, ("string", 8.5)))])}, "not a whole number")):
        with pytest.raises(BagError, match=why):
            check_typesdict(typs, "lab_msgs/msg/Ok")


# -- replay and ipc with rclpy unimportable -------------------------------------------------------------------

#: installed by the subprocess's sitecustomize: refuses every ROS 2 Python package (rclpy, its rmw/rcl/rosidl
#: layers, ament_index_python and every *_msgs / *_interfaces message package)
_BLOCK_ROS = '''
import sys
from importlib.abc import MetaPathFinder

class _NoRos(MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        top = name.partition(".")[0]
        if (top in ("rclpy", "rpyutils", "ament_index_python") or top.startswith(("rcl", "rmw", "rosidl"))
                or top.endswith(("_msgs", "_interfaces"))):
            raise ImportError(f"{name} is blocked: this interpreter has no ROS 2")
        return None

sys.meta_path.insert(0, _NoRos())
'''

_RUN_WITHOUT_ROS = '''
import json, sys
from bptsb_ros.cli import main
from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.reader import read_messages
codes = [main(a) for a in json.loads(sys.argv[1])]
ros = sorted(n for n in sys.modules if n.partition(".")[0] in ("rclpy", "std_msgs", "geometry_msgs", "sensor_msgs"))
try:
    list(read_messages(sys.argv[2], decoder="rclpy"))
    rclpy_refused = False
except BagError as err:
    rclpy_refused = "needs rclpy" in str(err)
print(json.dumps({"codes": codes, "ros_modules": ros, "rosbags": "rosbags.typesys" in sys.modules,
                  "rclpy_refused": rclpy_refused}))
'''


def _narma_bag(path: Path) -> None:
    """A NARMA-loop bag (τ = 20 steps, the default, 40 blocks) with publisher identities and one forged body message."""
    tau, blocks = 20, 40
    u01 = np.random.default_rng(5).uniform(0, 1, blocks)
    springs, fixed = np.array([[0, 1], [1, 2], [0, 2]]), np.array([True, False, False])
    rng = np.random.default_rng(6)
    with BagWriter(path, chunk_size=16384, custom_data={"loop": "narma", "mode": "lockstep"}) as w:
        for topic, msgtype in (("/body/positions", "geometry_msgs/msg/PoseArray"),
                               ("/task/input", "sensor_msgs/msg/JointState"),
                               ("/body/markers", "visualization_msgs/msg/MarkerArray")):
            w.add_topic(topic, msgtype)
        for k in range(blocks * tau + 1):
            u = u01[max(k - 1, 0) // tau]
            pos = np.array([[0.0, 0.0], [u + 0.1 * rng.normal(), u ** 2], [0.5, 0.3 * u + 0.01 * rng.normal()]])
            w.write("/body/positions", serialize_message(m.pose_array(k, DT_NS, pos, "msdn")), k * DT_NS,
                    publisher=BODY)
            w.write("/task/input", serialize_message(m.joint_state(k, DT_NS, input_names(1), position=np.array([u]))),
                    k * DT_NS, publisher=PublisherId("01.0f.dd.00.00.00.00.00.00.00.00.00.00.00.01.03", "task_input"))
            if k == 0:
                markers = m.body_markers(k, DT_NS, pos, springs, fixed, 2, np.zeros(3), "msdn", 0.1)
                w.write("/body/markers", serialize_message(markers), 0, publisher=BODY)
            if k == 17:
                w.write("/body/positions", serialize_message(m.pose_array(k, DT_NS, pos + 9, "msdn")), k * DT_NS + 1,
                        publisher=FORGER)


def _cut_copies(bag: Path, *dirs: Path) -> None:
    """Copies of the bag's MCAP file cut at 60 % (a killed recorder: no summary, no metadata.yaml)."""
    data = (bag / "bag_0.mcap").read_bytes()
    for d in dirs:
        d.mkdir()
        (d / "bag_0.mcap").write_bytes(data[: len(data) * 3 // 5])


@pytest.mark.slow
@pytest.mark.ros
def test_replay_and_ipc_run_without_rclpy_and_match_the_ros_path(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    _narma_bag(bag)
    _cut_copies(bag, tmp_path / "cut_ros", tmp_path / "cut_rosfree")
    shim = tmp_path / "no_ros"
    shim.mkdir()
    (shim / "sitecustomize.py").write_text(_BLOCK_ROS)
    env = {k: v for k, v in os.environ.items() if k not in ("AMENT_PREFIX_PATH", "PYTHONPATH")}
    env["PYTHONPATH"] = os.pathsep.join([str(shim), str(REPO)])

    def args(tag: str) -> list[list[str]]:
        return [["replay", str(bag), "--out", str(tmp_path / f"replay_{tag}"), "--task", "narma", "--no-gif"],
                ["ipc", "--bag", str(bag), "--out", str(tmp_path / f"ipc_{tag}"), "--max-degree", "2",
                 "--max-delay", "2", "--washout", "5", "--surrogates", "5"],
                ["bag", "recover", str(tmp_path / f"cut_{tag}")],
                ["replay", str(tmp_path / f"cut_{tag}"), "--out", str(tmp_path / f"replay_cut_{tag}"), "--no-gif"]]

    # the shim works: rclpy is there for this interpreter but not behind it
    probe = subprocess.run([sys.executable, "-c", "import rclpy"], env=env, capture_output=True, text=True,
                           timeout=60)
    assert probe.returncode != 0 and "rclpy is blocked" in probe.stderr
    done = subprocess.run([sys.executable, "-c", _RUN_WITHOUT_ROS, json.dumps(args("rosfree")), str(bag)], env=env,
                          capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report == {"codes": [0, 0, 0, 0], "ros_modules": [], "rosbags": True, "rclpy_refused": True}
    assert [main(a) for a in args("ros")] == [0, 0, 0, 0]
    assert (tmp_path / "cut_rosfree" / "bag_0.mcap").read_bytes() == (tmp_path / "cut_ros" / "bag_0.mcap").read_bytes()
    for tag in ("replay", "ipc", "replay_cut"):
        name = "ipc.json" if tag == "ipc" else "metrics.json"
        ros = json.loads((tmp_path / f"{tag}_ros" / name).read_text())
        free = json.loads((tmp_path / f"{tag}_rosfree" / name).read_text())
        for data in (ros, free):  # output paths and the IPC's own run time differ by construction
            data.pop("files", None), data.get("settings", {}).pop("seconds", None)
            data["bag"] = Path(data.get("bag") or "x").name.replace("_rosfree", "_ros")
        assert free == ros
    metrics = json.loads((tmp_path / "replay_rosfree" / "metrics.json").read_text())
    assert metrics["recorded_steps"] == 801 and metrics["publishers"]["foreign"] == {"/body/positions": {
        "/evil/forger": 1}}
    cut = json.loads((tmp_path / "replay_cut_rosfree" / "metrics.json").read_text())
    assert 0 < cut["recorded_steps"] < 801 and cut["missing_steps"] == 0  # the intact chunks: a prefix of the run
    assert sorted(p.name for p in (tmp_path / "replay_rosfree").iterdir()) == sorted(
        p.name for p in (tmp_path / "replay_ros").iterdir())
