"""Damaged bags: chunk CRCs are verified on read, recovery keeps every intact chunk and
rebuilds a damaged summary or metadata.yaml, and an earlier ``.damaged`` backup is never overwritten."""

from __future__ import annotations

import argparse
import struct
from pathlib import Path

import pytest
from rclpy.serialization import serialize_message
from std_msgs.msg import Float64MultiArray

from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.metadata import read_metadata
from bptsb_ros.bags.reader import bag_info, read_messages
from bptsb_ros.bags.recover import recover_bag
from bptsb_ros.bags.writer import BagWriter
from bptsb_ros.cli import bag_cmd

pytestmark = pytest.mark.ros  # every test here builds ROS 2 messages (rclpy and the message packages)

T0 = 1_800_000_000_000_000_000
PER_CHUNK, CHUNKS = 5, 4


@pytest.fixture
def bag(tmp_path: Path) -> tuple[Path, list[int]]:
    """A complete bag of CHUNKS uncompressed chunks of PER_CHUNK messages (value i at T0 + i µs); the byte
    offset where each chunk starts."""
    path = tmp_path / "run"
    starts = []
    with BagWriter(path, flush_period_s=None, compression="none") as w:
        w.add_topic("/x", "std_msgs/msg/Float64MultiArray")
        for c in range(CHUNKS):
            starts.append(w.mcap_path.stat().st_size)
            for j in range(PER_CHUNK):
                i = c * PER_CHUNK + j
                w.write("/x", serialize_message(Float64MultiArray(data=[float(i)])), T0 + i * 1000, sequence=i)
            w.flush()
    return path, starts


def _flip_bit_in_value(path: Path, value: float) -> None:
    """Flip one low mantissa bit of the float64 ``value`` where it is stored: the CRC is all that can tell."""
    data = bytearray(path.read_bytes())
    at = data.index(struct.pack("<d", value))
    data[at] ^= 0x01
    path.write_bytes(bytes(data))


def _cli(args: list[str]) -> int:
    parser = argparse.ArgumentParser()
    bag_cmd.add_arguments(parser)
    return bag_cmd.run(parser.parse_args(args))


def test_reader_verifies_chunk_crcs(bag, capsys) -> None:
    path, starts = bag
    _flip_bit_in_value(path / "run_0.mcap", 7.0)  # message 7 lives in chunk 2
    with pytest.raises(BagError) as err:
        list(read_messages(path))
    text = str(err.value)
    assert f"chunk 2 of {CHUNKS} at byte {starts[1]}" in text and "0.000005–0.000009 s" in text
    assert "bptsb bag recover" in text and "--skip-damaged" in text
    kept = list(read_messages(path, skip_damaged=True))
    assert [m.message.data[0] for m in kept] == [float(i) for i in range(20) if not 5 <= i < 10]
    assert "warning:" in capsys.readouterr().err
    assert len(bag_info(path).damaged_chunks) == 1
    assert _cli(["info", str(path)]) == 0 and "DAMAGED:" in capsys.readouterr().out


def test_recover_drops_only_the_damaged_chunk(bag) -> None:
    path, _ = bag
    _flip_bit_in_value(path / "run_0.mcap", 7.0)
    report = recover_bag(path)
    [file] = report.files
    assert not file.complete and file.messages == 15 and file.chunks == 3
    [dropped] = file.dropped
    assert dropped.messages == PER_CHUNK and (dropped.after_ns, dropped.before_ns) == (T0 + 4000, T0 + 10000)
    assert [m.message.data[0] for m in read_messages(path)] == [float(i) for i in range(20) if not 5 <= i < 10]
    assert read_metadata(path).message_count == 15


def test_damaged_summary_is_rebuilt(bag, capsys) -> None:
    path, _ = bag
    mcap = path / "run_0.mcap"
    data = bytearray(mcap.read_bytes())
    summary_start = struct.unpack_from("<Q", data, len(data) - 8 - 20)[0]  # footer: summary_start, offset, crc
    data[summary_start:summary_start + 16] = b"\xee" * 16
    mcap.write_bytes(bytes(data))
    assert _cli(["info", str(path)]) == 1 and "bptsb bag recover" in capsys.readouterr().err
    report = recover_bag(path)
    assert not report.files[0].complete and "summary" in report.files[0].stop_reason
    assert report.files[0].messages == 20 and not report.files[0].dropped
    assert len(list(read_messages(path))) == 20 and bag_info(path).message_count == 20


@pytest.mark.parametrize("garbage", [bytes(range(256)) * 4, b"rosbag2_bagfile_information: {version: 9}\n",
                                     None])
def test_garbage_metadata_gives_one_line_and_is_rebuilt(bag, capsys, garbage) -> None:
    path, _ = bag
    meta = path / "metadata.yaml"
    if garbage is None:  # well-formed but wrong: it claims one message too many
        meta.write_text(meta.read_text().replace("message_count: 20", "message_count: 21", 1))
    else:
        meta.write_bytes(garbage)
    before = meta.read_bytes()
    if garbage is not None:
        assert _cli(["info", str(path)]) == 1
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "Traceback" not in err and "bptsb bag recover" in err, err
    report = recover_bag(path)
    assert not report.untouched and report.metadata_problem
    assert (path / "metadata.yaml.damaged").read_bytes() == before
    assert read_metadata(path).message_count == 20 and report.files[0].complete
    assert recover_bag(path).untouched  # now consistent: left alone


def test_second_recover_keeps_the_first_backup(bag) -> None:
    path, _ = bag
    mcap = path / "run_0.mcap"
    _flip_bit_in_value(mcap, 7.0)
    first = mcap.read_bytes()
    recover_bag(path)
    data = mcap.read_bytes()  # the rebuilt file then loses its summary and footer (a killed copy, say)
    second = data[:struct.unpack_from("<Q", data, len(data) - 8 - 20)[0]]
    mcap.write_bytes(second)
    report = recover_bag(path)
    assert report.files[0].backup == path / "run_0.mcap.damaged.1"
    assert (path / "run_0.mcap.damaged").read_bytes() == first
    assert (path / "run_0.mcap.damaged.1").read_bytes() == second
    assert [m.message.data[0] for m in read_messages(path)] == [float(i) for i in range(20) if not 5 <= i < 10]
