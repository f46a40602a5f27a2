"""Publisher identities in bags (planted with the package's writer): per-publisher channels, what replay uses
(the body's own messages), what it reports (foreign, duplicate) and when it refuses (two different body states for
one step); bags without identities; recovery keeps them; metadata.yaml cannot point outside its bag."""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from bptsb_ros.analysis.bag_run import read_run
from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.publishers import PublisherId
from bptsb_ros.bags.reader import bag_info, format_info, read_messages, read_published
from bptsb_ros.bags.recover import recover_bag
from bptsb_ros.bags.writer import BagWriter
from bptsb_ros.cli import replay_cmd
from bptsb_ros.ros import messages as m

pytestmark = pytest.mark.ros  # every test here builds ROS 2 messages (rclpy and the message packages)

DT_NS = 10_000_000
STEPS = 20
BODY = PublisherId("01.0f.aa.00.00.00.00.00.00.00.00.00.00.00.01.03", "body_sim", "/")
FORGER = PublisherId("01.0f.bb.00.00.00.00.00.00.00.00.00.00.00.01.03", "forger", "/evil")
BODY_TWIN = PublisherId("01.0f.cc.00.00.00.00.00.00.00.00.00.00.00.01.03", "body_sim", "/")  # a forged name


def _state(k: int) -> np.ndarray:
    """Positions (3, 2) [m] of step k: mass 2 moves 1 mm per step."""
    return np.array([[-1.0, 0.0], [1.0, 0.0], [0.0, 0.001 * k]])


def _bag(path: Path, extra: list[tuple[int, np.ndarray, PublisherId | None]] = (),
         body: PublisherId | None = BODY) -> Path:
    """A bag of /body/positions for steps 0..STEPS from ``body`` (None: no identities), plus ``extra`` messages
    (step, positions, publisher), each written right after the body's message of that step."""
    from rclpy.serialization import serialize_message

    with BagWriter(path) as w:
        w.add_topic("/body/positions", "geometry_msgs/msg/PoseArray")
        for k in range(STEPS + 1):
            w.write("/body/positions", serialize_message(m.pose_array(k, DT_NS, _state(k), "msdn")), k * DT_NS + 1,
                    publisher=body)
            for step, pos, who in extra:
                if step == k:
                    w.write("/body/positions", serialize_message(m.pose_array(step, DT_NS, pos, "msdn")),
                            k * DT_NS + 2, publisher=who)
    return path


def test_foreign_publishers_are_ignored_and_reported(tmp_path: Path) -> None:
    forged = [(k, np.full((3, 2), 9.0), FORGER) for k in (3, 4, 5)]
    repeat = [(7, _state(7), BODY)]  # the body's own state of step 7, once more: a duplicate
    bag = _bag(tmp_path / "b", forged + repeat)
    run = read_run(bag)
    assert run.steps.tolist() == list(range(STEPS + 1))
    np.testing.assert_array_equal(run.positions, np.stack([_state(k) for k in range(STEPS + 1)]))
    report = run.provenance.to_dict()
    assert report["checked"] is True
    assert report["foreign"] == {"/body/positions": {"/evil/forger": 3}} and report["foreign_messages"] == 3
    assert report["duplicates"] == {"/body/positions": 1}
    assert report["used"] == {"/body/positions": {"/body_sim": STEPS + 2}}
    # the bag itself: one channel per publisher, named in its metadata; readers that merge by topic see all 25
    with open(bag / "b_0.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    names = {c.id: (c.metadata["publisher_node"], c.metadata["publisher_namespace"]) for c in summary.channels.values()}
    assert sorted(names.values()) == [("body_sim", "/"), ("forger", "/evil")]
    assert sorted(summary.statistics.channel_message_counts.values()) == [3, STEPS + 2]
    assert len(list(read_messages(bag))) == STEPS + 5
    assert "/body/positions: /body_sim [01.0f.aa" in format_info(bag_info(bag))


def test_two_different_body_states_for_one_step_fail_loudly(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # a second publisher named /body_sim on the body's only topic: nothing tells which one is the body
    bag = _bag(tmp_path / "twin", [(5, _state(5) + 0.5, BODY_TWIN)])
    with pytest.raises(BagError, match=r"2 publishers named /body_sim sent /body/positions: 01\.0f\.aa.* \(21 "
                                       r"messages\), 01\.0f\.cc.* \(1 messages\); which one is /body_sim cannot"):
        read_run(bag)
    same_gid = _bag(tmp_path / "same", [(5, _state(5) + 0.5, BODY)])  # the body itself says two things
    with pytest.raises(BagError, match=r"two different /body/positions messages for the same step \(stamp 50000000 "
                                       r"ns\), from /body_sim \[01\.0f\.aa.*\] and /body_sim \[01\.0f\.aa"):
        read_run(same_gid)
    parser = argparse.ArgumentParser()  # `bptsb replay BAG`, as the CLI dispatches it
    replay_cmd.add_arguments(parser)
    code = replay_cmd.run(parser.parse_args([str(bag), "--out", str(tmp_path / "o"), "--task", "locomotion",
                                             "--no-gif"]))
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1 and "2 publishers named /body_sim sent /body/positions" in err, err


def test_bag_without_identities_is_read_with_a_warning(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = _bag(tmp_path / "old", body=None)
    assert all(p.publisher is None for p in read_published(bag))
    run = read_run(bag)
    assert run.provenance.checked is False and run.steps.tolist() == list(range(STEPS + 1))
    from bptsb_ros.analysis.replay import replay

    metrics = replay(bag, tmp_path / "out", gif=False)  # no task: no metric, no plots
    assert metrics["publishers"]["checked"] is False
    assert "publishers cannot be checked" in capsys.readouterr().err
    assert "Publishers:        not recorded" in format_info(bag_info(bag))
    conflicting = _bag(tmp_path / "old2", [(4, _state(4) + 1.0, None)], body=None)
    with pytest.raises(BagError, match="the bag does not record their publishers"):
        read_run(conflicting)


def test_recovery_keeps_the_publishers(tmp_path: Path) -> None:
    bag = _bag(tmp_path / "r", [(k, np.full((3, 2), 9.0), FORGER) for k in (1, 2)])
    mcap = bag / "r_0.mcap"
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) - 200])  # the summary and footer torn off
    (bag / "metadata.yaml").unlink()
    recover_bag(bag)
    assert Counter(p.publisher for p in read_published(bag)) == {BODY: STEPS + 1, FORGER: 2}


@pytest.mark.parametrize("name, ok", [
    ("b_0.mcap", True), ("./b_0.mcap", True),  # what rosbag2 writes, and the same name spelled with ./
    ("../b/b_0.mcap", False),  # names this very file, through the parent: refused all the same
    ("../../etc/passwd", False), ("/etc/passwd", False), ("", False), ("link_0.mcap", False),
])
def test_metadata_cannot_point_outside_the_bag(tmp_path: Path, name: str, ok: bool) -> None:
    bag = _bag(tmp_path / "b")
    outside = tmp_path / "outside.mcap"
    outside.write_bytes((bag / "b_0.mcap").read_bytes())
    (bag / "link_0.mcap").symlink_to(outside)  # inside the bag by name, outside by what it leads to
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text().replace("path: b_0.mcap", f"path: '{name}'")
                    .replace("- b_0.mcap", f"- '{name}'"))
    if ok:
        assert bag_info(bag).message_count == STEPS + 1 and len(read_run(bag).steps) == STEPS + 1
        return
    for read in (bag_info, read_run, lambda b: list(read_messages(b))):
        with pytest.raises(BagError, match="not a file name inside the bag directory|leads outside the bag"):
            read(bag)


# one process per participant: the GIDs of one process share their first 12 bytes (the DDS GUID prefix)
NS_BODY = PublisherId("01.0f.aa.00.00.00.00.00.00.00.00.00.00.00.01.03", "body_sim", "/robot1")
NS_BODY_LENGTHS = PublisherId("01.0f.aa.00.00.00.00.00.00.00.00.00.00.00.02.03", "body_sim", "/robot1")
OTHER_NS = PublisherId("01.0f.dd.00.00.00.00.00.00.00.00.00.00.00.01.03", "body_sim", "/evil")
ROOT_NS = PublisherId("01.0f.ee.00.00.00.00.00.00.00.00.00.00.00.01.03", "body_sim", "/")
SAME_NAME = PublisherId("01.0f.ff.00.00.00.00.00.00.00.00.00.00.00.01.03", "body_sim", "/robot1")


def _ns_bag(path: Path, forged: list[tuple[int, np.ndarray, PublisherId]], lengths: bool = True) -> Path:
    """A run in namespace /robot1: /robot1/body/positions (and /robot1/body/spring_lengths, from the same process)
    for steps 0..STEPS, plus ``forged`` positions (stamp [ns], positions, publisher) on the body's topic."""
    from rclpy.serialization import serialize_message

    topic = "/robot1/body/positions"
    with BagWriter(path, custom_data={"namespace": "/robot1", "loop": "lissajous_open"}) as w:
        w.add_topic(topic, "geometry_msgs/msg/PoseArray")
        if lengths:
            w.add_topic("/robot1/body/spring_lengths", "sensor_msgs/msg/JointState")
        for k in range(STEPS + 1):
            w.write(topic, serialize_message(m.pose_array(k, DT_NS, _state(k), "msdn")), k * DT_NS + 1,
                    publisher=NS_BODY)
            if lengths:
                msg = m.joint_state(k, DT_NS, ["s0"], position=np.array([1.0 + k]))
                w.write("/robot1/body/spring_lengths", serialize_message(msg), k * DT_NS + 1, publisher=NS_BODY_LENGTHS)
        for i, (stamp_ns, pos, who) in enumerate(forged):
            msg = m.pose_array(0, DT_NS, pos, "msdn")
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
            w.write(topic, serialize_message(msg), (STEPS + 1) * DT_NS + i, publisher=who)
    return path


def test_a_body_sim_of_another_namespace_is_foreign(tmp_path: Path) -> None:
    # named body_sim, but /evil/body_sim and /body_sim are not the run's /robot1/body_sim
    who = [OTHER_NS] * 5 + [ROOT_NS] * 3
    forged = [((STEPS + 1 + j) * DT_NS, np.full((3, 2), 9.0), p) for j, p in enumerate(who)]
    run = read_run(_ns_bag(tmp_path / "ns", forged))
    assert run.steps.tolist() == list(range(STEPS + 1))
    report = run.provenance.to_dict()
    assert report["foreign"] == {"/robot1/body/positions": {"/evil/body_sim": 5, "/body_sim": 3}}
    assert report["used"]["/robot1/body/positions"] == {"/robot1/body_sim": STEPS + 1}


@pytest.mark.parametrize("offset", [STEPS + 5, 0.5], ids=["after the end", "half a step off"])
def test_a_same_named_publisher_of_another_process_is_not_the_body(tmp_path: Path, offset: float,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    stamps = [int((offset + j) * DT_NS) for j in range(10)]
    run = read_run(_ns_bag(tmp_path / "twin", [(s, np.full((3, 2), 9.0), SAME_NAME) for s in stamps]))
    assert run.steps.tolist() == list(range(STEPS + 1))  # the forger's 10 stamps add no step
    np.testing.assert_array_equal(run.positions, np.stack([_state(k) for k in range(STEPS + 1)]))
    report = run.provenance.to_dict()
    assert report["foreign"] == {"/robot1/body/positions": {f"/robot1/body_sim [{SAME_NAME.gid}]": 10}}
    line = report["shared_names"]["/robot1/body/positions"]
    assert f"used {NS_BODY.gid} ({STEPS + 1} messages" in line and f"ignored {SAME_NAME.gid} (10 messages)" in line
    from bptsb_ros.analysis.replay import replay

    replay(tmp_path / "twin", tmp_path / "out", gif=False)
    err = capsys.readouterr().err
    assert "2 publishers are named /robot1/body_sim" in err and err.count("\n") == len(err.splitlines())
    # without the body's other topic nothing tells the two apart: refused, naming both
    with pytest.raises(BagError, match=rf"2 publishers named /robot1/body_sim sent /robot1/body/positions: "
                                       rf"{NS_BODY.gid} \(21 messages\), {SAME_NAME.gid} \(10 messages\)"):
        read_run(_ns_bag(tmp_path / "alone", [(s, np.full((3, 2), 9.0), SAME_NAME) for s in stamps], lengths=False))
