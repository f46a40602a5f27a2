"""What a recording lost and how far it has recorded (ROS-free parts): sequence gaps and middleware reports, the
bag's loss entries, the body's published counts against the bag, the launcher's verdict, and the lockstep
acknowledgement read from the stamps of serialized messages."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import serialize_message

from bptsb_ros.bags.loss import recording_loss
from bptsb_ros.bags.metadata import read_metadata
from bptsb_ros.bags.publishers import PublisherId
from bptsb_ros.bags.recording import (
    RECORDING_RECORD,
    SEQUENCE_UNSUPPORTED,
    LossCount,
    StepAck,
    cdr_stamp_ns,
    recorded_loss,
)
from bptsb_ros.bags.writer import BagWriter
from bptsb_ros.cli.launch_cmd import Child, Launcher, _check_recording
from bptsb_ros.ros import messages as m

DT_NS = 10_000_000
BODY = PublisherId("01.aa", "body_sim", "/")


def test_sequence_gaps_and_middleware_reports() -> None:
    loss = LossCount()
    for seq in (1, 2, 3, 7, 8, 12):  # 4-6 and 9-11 never recorded: 6
        loss.see("/clock", "a", seq)
    for seq in (5, 6, 7):  # a publisher first seen at 5 (joined late): nothing lost
        loss.see("/clock", "b", seq)
    loss.see("/x", "a", 0)  # unnumbered
    loss.see("/x", "a", SEQUENCE_UNSUPPORTED)
    loss.lost("/clock", 4)  # the middleware saw part of the same losses
    loss.lost("/diagnostics", 2)
    assert loss.by_topic() == {"/clock": 6, "/diagnostics": 2} and loss.total == 8 and loss.any
    data = loss.custom_data()
    assert recorded_loss(data) == (8, {"/clock": 6, "/diagnostics": 2}, True)
    clean = LossCount()
    assert not clean.any and recorded_loss(clean.custom_data()) == (0, {}, True)
    clean.cut_short = True
    assert clean.any and recorded_loss(clean.custom_data()) == (0, {}, False)
    assert recorded_loss({}) == (None, {}, True)  # a bag of an older recorder
    assert recorded_loss({"dropped_messages": "x"}) == (None, {}, True)


@pytest.mark.ros
def test_stamps_of_serialized_messages_and_the_acknowledgement() -> None:
    clock = serialize_message(m.clock_msg(1234, DT_NS))
    state = serialize_message(m.joint_state(1230, DT_NS, ["a"], position=np.zeros(1)))
    assert cdr_stamp_ns(clock) == 1234 * DT_NS and cdr_stamp_ns(state) == 1230 * DT_NS
    big_endian = b"\x00\x00\x00\x00" + struct.pack(">iI", 3, 5)  # CDR_BE encapsulation, typed here
    assert cdr_stamp_ns(big_endian) == 3_000_000_005
    with pytest.raises(ValueError, match="holds no stamp"):
        cdr_stamp_ns(b"\x00\x01\x00\x00\x01")
    ack = StepAck(["/clock", "/body/positions"])
    ack.see("/clock", clock)
    assert ack.value() is None and ack.due() is None  # /body/positions has nothing yet
    ack.see("/body/positions", state)
    assert ack.due() == 1230 * DT_NS and ack.due() is None  # published once, until it advances
    ack.see("/body/positions", serialize_message(m.joint_state(1240, DT_NS, ["a"], position=np.zeros(1))))
    assert ack.due() == 1234 * DT_NS  # the slower topic now: /clock
    ack.refuse("/clock")
    assert ack.value() == 1240 * DT_NS


def _bag(path: Path, steps: int, custom: dict[str, str]) -> Path:
    with BagWriter(path, custom_data=custom) as w:
        w.add_topic("/clock", "rosgraph_msgs/msg/Clock")
        w.add_topic("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray")
        for k in range(steps):
            w.write("/clock", serialize_message(m.clock_msg(k, DT_NS)), k * DT_NS + 1, publisher=BODY)
        w.write("/clock", serialize_message(m.clock_msg(0, DT_NS)), 1, publisher=PublisherId("01.bb", "forger"))
    return path


@pytest.mark.ros
def test_recording_loss_takes_the_larger_count_per_topic(tmp_path: Path) -> None:
    # the recorder counted 3 on /clock and 1 on /x; the body published 100 /clock (the bag has 90 of them from
    # body_sim; the forger's message does not count) and 2 diagnostics (the bag has none)
    bag = _bag(tmp_path / "b", 90, {**LossCount(gaps={"/clock": 3, "/x": 1}).custom_data()})
    loss = recording_loss(bag, {"/clock": 100, "/diagnostics": 2})
    assert loss.by_topic == {"/clock": 10, "/diagnostics": 2, "/x": 1} and loss.total == 13 and loss.counted == 4
    assert loss.describe() == "lost 13 messages (/clock 10, /diagnostics 2, /x 1)"
    assert recording_loss(bag, {"/clock": 90}).by_topic == {"/clock": 3, "/x": 1}  # the recorder's own count
    clean = _bag(tmp_path / "c", 90, LossCount().custom_data())
    assert not recording_loss(clean, {"/clock": 90}).any
    assert recording_loss(clean, {"/clock": 91}).by_topic == {"/clock": 1}  # the last one never arrived


@pytest.mark.ros
@pytest.mark.parametrize("allow", [False, True])
def test_launcher_verdict_says_ok_only_without_loss(tmp_path: Path, allow: bool) -> None:
    bag = _bag(tmp_path / "b", 90, LossCount().custom_data())
    summary = tmp_path / "body_summary.json"
    body = Child("body_sim", [], tmp_path / "b.log")
    rows = [("body_sim", "ok"), ("recorder", "ok")]
    summary.write_text(json.dumps({"steps": 89, "published_messages": {"/clock": 90}}))
    launcher = Launcher([body], body, None, 1.0)
    assert _check_recording(launcher, rows, bag, summary, allow) == rows and not launcher.failures
    assert json.loads(summary.read_text())["recording"]["dropped_messages"] == 0
    summary.write_text(json.dumps({"steps": 94, "published_messages": {"/clock": 95}}))
    out = _check_recording(launcher, rows, bag, summary, allow)
    verdict = dict(out)["recorder"]
    assert verdict != "ok" and "lost 5 messages (/clock 5)" in verdict
    assert bool(launcher.failures) is not allow and ("allowed by --allow-loss" in verdict) is allow
    assert json.loads(summary.read_text())["recording"] == {
        "dropped_messages": 5, "dropped_by_topic": {"/clock": 5}, "recorder_counted": 0, "recording_complete": True,
        "allowed": allow}
    assert read_metadata(bag).custom_data["dropped_messages"] == "0"  # the bag is left as the recorder wrote it
    # the recorder in the body's process: the loss is on that process's row, and its exit 1 is the loss
    hosted = [("composed", "failed (exit 1)"), ("swg_brain", "ok")]
    launcher.failures[:] = ["composed: failed (exit 1)"]
    out = dict(_check_recording(launcher, hosted, bag, summary, allow, "composed"))
    assert "lost 5 messages (/clock 5)" in out["composed"] and out["swg_brain"] == "ok"
    assert launcher.failures == ([] if allow else ["composed: lost 5 messages (/clock 5) (--allow-loss accepts a "
                                                   "lossy recording)"])


@pytest.mark.ros
def test_bag_info_shows_the_losses(tmp_path: Path) -> None:
    from bptsb_ros.bags.reader import bag_info, format_info

    bag = _bag(tmp_path / "b", 5, LossCount(gaps={"/clock": 3}, cut_short=True).custom_data())
    info = bag_info(bag)
    assert (info.dropped_messages, info.dropped_by_topic, info.recording_complete) == (3, {"/clock": 3}, False)
    assert "Lost messages:     3 (/clock 3); the recorder's final drain was cut short" in format_info(info)
    recorded = LossCount(gaps={"/clock": 2}).custom_data()
    with BagWriter(tmp_path / "rec") as w:  # as the recorder closes a bag: the entries also in an MCAP record
        w.set_custom_data(recorded)
        w.close(records={RECORDING_RECORD: recorded})
    lone = bag_info(tmp_path / "rec" / "rec_0.mcap")  # the MCAP file alone: from its bptsb_ros.recording record
    assert (lone.dropped_messages, lone.dropped_by_topic, lone.recording_complete) == (2, {"/clock": 2}, True)
    old = _bag(tmp_path / "old", 5, {})
    assert bag_info(old).dropped_messages is None and "Lost messages" not in format_info(bag_info(old))


def test_soak_cli_checks_its_arguments(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import argparse

    from bptsb_ros.cli import bench_cmd

    parser = argparse.ArgumentParser()
    bench_cmd.add_arguments(parser)
    out = tmp_path / "soak.json"
    nothing = ["--soak", "--realtime-seconds", "0", "--lockstep-seconds", "0", "--out", str(out)]
    assert bench_cmd.run(parser.parse_args(nothing + ["--workdir", str(tmp_path / "w")])) == 0  # both runs skipped
    report = json.loads(out.read_text())
    assert "realtime" not in report and "lockstep" not in report and report["cpu_count"] >= 1
    capsys.readouterr()
    for bad, message, code in ((["--realtime-seconds", "-1"], "--realtime-seconds must be >= 0", 2),
                               (["--lockstep-busy", "-1"], "must be >= 0", 2),
                               (["--workdir", str(tmp_path)], "exists and is not empty", 1)):  # on disk: runtime
        assert bench_cmd.run(parser.parse_args(nothing + bad)) == code
        assert message in capsys.readouterr().err
