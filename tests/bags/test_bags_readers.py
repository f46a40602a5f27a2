"""A bag recorded by ``bptsb launch`` is read by other tools: every message of every topic deserializes with
``rosbags``' ``AnyReader.deserialize`` (strict about CDR: no more than 3 bytes after the content) and with
``mcap_ros2``'s decoder (from the bag's own schemas), and both count what the bag's metadata counts; with the
recorder in a process of its own and in the body's process."""

from __future__ import annotations

from collections import Counter

import pytest
from ros_live import bptsb

pytestmark = pytest.mark.slow  # each test here runs a launched loop of several seconds

pytest.importorskip("rclpy")
pytest.importorskip("rosbags.highlevel")
pytest.importorskip("mcap_ros2.decoder")


@pytest.mark.parametrize("recorder", [[], ["--recorder-in-body"]], ids=["recorder_process", "recorder_in_body"])
def test_every_message_of_a_launched_bag_reads_with_rosbags_and_mcap_ros2(tmp_path, fresh_ros, recorder):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from bptsb_ros.bags.reader import bag_info

    # a domain where no earlier test can have left a killed node's participant behind: the body would take its
    # stale swg_brain publisher for the brain and send the first tick before the real brain hears /clock
    _, ros_env = fresh_ros
    bag = tmp_path / "bag"
    out = bptsb(["launch", "lissajous_open", "--duration", "0.5", "--perturb-at", "0.2", "--perturb-sigma", "0.01",
                 "--bag", str(bag), *recorder,
                 "--param", "body_sim:command_timeout:=30.0"],  # a slow brain start is no fault here
                ros_env)
    assert out.returncode == 0, out.stdout[-4000:]
    expected = {t.name: t.message_count for t in bag_info(bag).topics if t.message_count}
    assert {"/clock", "/body/positions", "/body/mass_states", "/body/spring_lengths", "/body/rest_length",
            "/body/external_force", "/body/markers", "/body/perturbation", "/brain/rest_length",
            "/diagnostics"} <= set(expected)
    seen: Counter = Counter()
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for connection, _time, raw in reader.messages():
            reader.deserialize(raw, connection.msgtype)  # raises on a message size mismatch
            seen[connection.topic] += 1
    assert dict(seen) == expected
    decoded: Counter = Counter()
    for path in sorted(bag.glob("*.mcap")):
        with path.open("rb") as stream:
            for _schema, channel, _message, msg in make_reader(
                    stream, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
                assert msg is not None
                decoded[channel.topic] += 1
    assert dict(decoded) == expected
