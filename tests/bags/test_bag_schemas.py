"""A bag's schemas are untrusted data: what they may declare is bounded before rosbags builds anything from them
(huge fixed arrays, tens of thousands of fields), a known type defined otherwise than the installed message is
refused (rclpy and the bag's own schema would decode it differently), a message without the fields its type should
have is one line, not a traceback, and control bytes of a bag never reach the terminal. Every hostile schema is
planted in a bag written here."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import serialize_message

from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.msgdefs import MessageDefinition, message_definition
from bptsb_ros.bags.reader import read_messages
from bptsb_ros.bags.writer import BagWriter
from bptsb_ros.cli import main
from bptsb_ros.ros import messages as m

DT_NS = 10_000_000
POSES = "geometry_msgs/msg/PoseArray"


def _bag(path: Path, definition: MessageDefinition | None = None, msgtype: str = POSES,
         topic: str = "/body/positions", steps: int = 3) -> Path:
    """A bag of ``steps`` body positions (CDR of the installed PoseArray) under the schema ``definition``."""
    with BagWriter(path) as w:
        w.add_topic(topic, msgtype, definition=definition, type_hash="")
        for k in range(steps):
            pos = np.array([[0.0, 0.0], [1.0, 0.5 * k]])
            w.write(topic, serialize_message(m.pose_array(k, DT_NS, pos, "msdn")), k * DT_NS + 1)
    return path


def _custom(text: str, name: str = "lab_msgs/msg/Big") -> MessageDefinition:
    return MessageDefinition(name, "ros2msg", text)


@pytest.mark.ros
@pytest.mark.parametrize("text, why", [
    ("string[200000000] s\n", r"declares a fixed array of 200,000,000 elements; the most read is 1,000,000"),
    ("string[4096] s\n", r"expands to more than 1,000 fields"),
    ("lab_msgs/Part[64] parts\n" + "=" * 80 + "\nMSG: lab_msgs/Part\n" + "string a\nstring b\n" * 10,
     r"expands to more than 1,000 fields"),
    ("".join(f"float64 f{i}\n" for i in range(60_000)), r"declares 60,000 fields and constants; the most read is "
                                                        r"2,000"),
])
@pytest.mark.parametrize("name", ["lab_msgs/msg/Big", POSES])
def test_what_a_schema_may_declare_is_bounded_before_rosbags_builds_it(tmp_path, text, why, name, capsys):
    bag = _bag(tmp_path / "bag", _custom(text, name), msgtype=name, topic="/big")
    t0 = time.perf_counter()
    for decoder in ("auto", "rosbags"):
        with pytest.raises(BagError, match=why) as err:
            list(read_messages(bag, decoder=decoder))
        assert "\n" not in str(err.value)
    assert time.perf_counter() - t0 < 20  # rosbags took 20 s for string[4096] alone, 150 s for 60,000 fields


def test_installed_messages_are_within_the_bounds():
    from rosbags import typesys

    from bptsb_ros.bags.decode import MAX_SCHEMA_FIELDS, MAX_SCHEMA_LINES, declaration_lines, schema_size

    for name in ("visualization_msgs/msg/InteractiveMarkerUpdate", "visualization_msgs/msg/MarkerArray", POSES,
                 "sensor_msgs/msg/JointState", "diagnostic_msgs/msg/DiagnosticArray"):
        text = message_definition(name).text
        assert declaration_lines(text, "ros2msg") <= MAX_SCHEMA_LINES / 10
        assert schema_size(typesys.get_types_from_msg(text, name), name) <= MAX_SCHEMA_FIELDS / 10


def _swapped_point() -> MessageDefinition:
    text = message_definition(POSES).text
    point = "MSG: geometry_msgs/Point\n"
    head, tail = text.split(point)
    body, rest = tail.split("=" * 80, 1)
    assert "float64 x" in body and "float64 y" in body
    body = body.replace("float64 x", "float64 @").replace("float64 y", "float64 x").replace("float64 @", "float64 y")
    return MessageDefinition(POSES, "ros2msg", head + point + body + "=" * 80 + rest)


@pytest.mark.ros
def test_a_known_type_defined_otherwise_than_installed_is_refused(tmp_path, capsys):
    """x and y of Point swapped in the bag's schema: rclpy would read the bytes as the installed Point, rosbags as
    the bag's; instead both refuse, naming the difference (comments alone would not count)."""
    bag = _bag(tmp_path / "swapped", _swapped_point())
    for decoder in ("auto", "rclpy", "rosbags"):
        with pytest.raises(BagError, match=r"schema of geometry_msgs/msg/PoseArray defines it differently from the "
                                           r"installed geometry_msgs/msg/PoseArray: geometry_msgs/msg/Point has the "
                                           r"fields y, x, z, the installed one x, y, z"):
            list(read_messages(bag, decoder=decoder))
    assert main(["replay", str(bag), "--out", str(tmp_path / "out"), "--no-gif"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "defines it differently" in err
    commented = message_definition(POSES).text.replace("\n", "  # a comment of another distribution\n", 3)
    assert len(list(read_messages(_bag(tmp_path / "comments", MessageDefinition(POSES, "ros2msg", commented)),
                                  decoder="rosbags"))) == 3
    flat = _bag(tmp_path / "flat", MessageDefinition(POSES, "ros2msg", "float64 x\n"))  # no header, no poses
    with pytest.raises(BagError, match=r"PoseArray has the fields x, the installed one header, poses"):
        list(read_messages(flat))


@pytest.mark.ros
def test_a_message_without_its_fields_is_one_line_without_ros(tmp_path, capsys, monkeypatch):
    """Where the type is not installed (no ROS), the bag's schema is all there is: a PoseArray without header is
    one line from replay and ipc, as is a body topic of another type."""
    import bptsb_ros.bags.decode as decode
    from bptsb_ros.bags.errors import MessageDefinitionError

    def not_installed(name):
        raise MessageDefinitionError(f"{name} is not installed here")

    monkeypatch.setattr(decode, "message_definition", not_installed)
    monkeypatch.setattr(decode, "get_message_class", not_installed)
    headless = MessageDefinition(POSES, "ros2msg", "geometry_msgs/Pose[] poses\n" + "=" * 80
                                 + "\nMSG: geometry_msgs/Pose\nfloat64 a\n")
    bag = tmp_path / "headless"
    with BagWriter(bag) as w:
        w.add_topic("/body/positions", POSES, definition=headless, type_hash="")
        for k in range(3):
            w.write("/body/positions", b"\x00\x01\x00\x00" + np.array([1, 0], "<u4").tobytes()  # 1 pose, padding
                    + np.array([0.5 * k], "<f8").tobytes(), k + 1)
    for argv in (["replay", str(bag), "--out", str(tmp_path / "r"), "--no-gif"],
                 ["ipc", "--bag", str(bag), "--out", str(tmp_path / "i")]):
        assert main(argv) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and ("a /body/positions message does not hold what a geometry_msgs/msg/PoseArray "
                                         "holds (AttributeError") in err, err
    other = _bag(tmp_path / "other", _custom("float64 x\n", "lab_msgs/msg/Fake"), msgtype="lab_msgs/msg/Fake")
    assert main(["replay", str(other), "--out", str(tmp_path / "o"), "--no-gif"]) == 1
    err = capsys.readouterr().err
    assert "/body/positions is of type lab_msgs/msg/Fake, not geometry_msgs/msg/PoseArray" in err


@pytest.mark.ros
def test_control_bytes_of_a_bag_never_reach_the_terminal(tmp_path, capsys):
    """A topic named with a terminal's escape sequences (set the title, colour, reverse the text) and a schema whose
    parse error quotes such bytes: every line printed has them escaped."""
    evil = "/x\x1b]0;pwned\x07\x1b[31m\u202e"
    bag = _bag(tmp_path / "bag", topic=evil)
    with BagWriter(tmp_path / "schema") as w:
        w.add_topic("/bad", "lab_msgs/msg/Bad", type_hash="",
                    definition=_custom("float64[ \x1b]2;title\x07\x1b[2J\n", "lab_msgs/msg/Bad"))
        w.write("/bad", b"\x00\x01\x00\x00" + bytes(8), 1)
    for argv in (["bag", "info", str(bag)], ["replay", str(bag), "--out", str(tmp_path / "o"), "--no-gif"]):
        main(argv)
        out, err = capsys.readouterr()
        assert not any(c in out + err for c in "\x1b\x07\u202e"), argv
        assert "/x\\x1b]0;pwned\\x07\\x1b[31m\\u202e" in out + err, argv
    with pytest.raises(BagError) as err:
        list(read_messages(tmp_path / "schema", decoder="rosbags"))
    assert "\x1b" in str(err.value)  # the parser quotes the schema's bytes...
    from bptsb_ros.cli.options import fail

    assert fail("replay", err.value) == 1  # ...and the one line printed escapes them
    shown = capsys.readouterr().err
    assert "\x1b" not in shown and "\\x1b]2;title\\x07" in shown and shown.count("\n") == 1
