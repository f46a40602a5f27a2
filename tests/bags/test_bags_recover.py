"""`bptsb bag recover`: rebuilding a bag from the complete chunks of a file left by a killed writer."""

from __future__ import annotations

import argparse
import shutil
import struct
from pathlib import Path

import pytest
from conftest import REPO_ROOT
from rclpy.serialization import serialize_message
from std_msgs.msg import Float64MultiArray

from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.metadata import read_metadata
from bptsb_ros.bags.reader import read_messages
from bptsb_ros.bags.recover import recover_bag
from bptsb_ros.bags.writer import BagWriter
from bptsb_ros.cli import bag_cmd

T0 = 1_800_000_000_000_000_000
PER_CHUNK = 7
CHUNKS = 5


@pytest.fixture(scope="module")
def unfinished(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[int], list[int]]:
    """A bag whose writer flushed CHUNKS chunks and then 'died' (never closed), with the file size after each
    flush and the message count at each flush."""
    path = tmp_path_factory.mktemp("kill") / "run"
    writer = BagWriter(path, flush_period_s=None, custom_data={"loop": "lissajous_closed"})
    writer.add_topic("/a", "std_msgs/msg/Float64MultiArray")
    writer.add_topic("/b", "std_msgs/msg/Float64MultiArray")
    sizes, counts, i = [], [], 0
    for _ in range(CHUNKS):
        for _ in range(PER_CHUNK):
            writer.write("/a" if i % 2 else "/b", serialize_message(Float64MultiArray(data=[float(i)] * 8)),
                         T0 + i * 1000, sequence=i)
            i += 1
        writer.flush()
        sizes.append(writer.mcap_path.stat().st_size)
        counts.append(i)
    # Half a chunk more that never reaches the disk: the writer is abandoned here, like a SIGKILL.
    for _ in range(3):
        writer.write("/a", serialize_message(Float64MultiArray(data=[-1.0])), T0 + i * 1000)
        i += 1
    return path, sizes, counts


def _copy_truncated(src: Path, dst: Path, size: int, torn: bytes = b"") -> Path:
    """Copy the first ``size`` bytes of the unfinished file, then ``torn`` (the start of a record never finished)."""
    dst.mkdir()
    data = (src / "run_0.mcap").read_bytes()[:size]
    (dst / "run_0.mcap").write_bytes(data + torn)
    return dst


@pytest.mark.ros
@pytest.mark.parametrize("cut", [0, 1, 2, 4])
@pytest.mark.parametrize("torn", [b"", b"\x06", struct.pack("<BQ", 0x06, 5000) + b"\x00" * 28])
def test_recovers_exactly_the_complete_chunks(unfinished, tmp_path: Path, cut: int, torn: bytes) -> None:
    src, sizes, counts = unfinished
    bag = _copy_truncated(src, tmp_path / "bag", sizes[cut], torn)
    with pytest.raises(BagError, match="bptsb bag recover"):
        list(read_messages(bag))
    report = recover_bag(bag)
    n = counts[cut]
    assert [f.messages for f in report.files] == [n] and [f.chunks for f in report.files] == [cut + 1]
    # how the scan ended follows from what was torn off: nothing (the file just ends after the cut), a lone
    # opcode byte (no room for a record header) or a header whose length runs past the end
    if not torn:
        expected = "end of file without summary/footer"
    elif len(torn) < 9:
        expected = f"truncated record header at byte {sizes[cut]}"
    else:
        expected = f"truncated record (opcode 0x06, 5000 bytes) at byte {sizes[cut]}"
    assert report.files[0].stop_reason == expected
    assert (bag / "run_0.mcap.damaged").stat().st_size == sizes[cut] + len(torn)
    msgs = list(read_messages(bag))
    assert [m.timestamp_ns for m in msgs] == [T0 + i * 1000 for i in range(n)]
    assert [m.message.data[0] for m in msgs] == [float(i) for i in range(n)]
    meta = read_metadata(bag)
    assert meta.message_count == n and meta.relative_file_paths == ["run_0.mcap"]
    assert sum(t.message_count for t in meta.topics) == n and {t.name for t in meta.topics} == {"/a", "/b"}
    assert meta.custom_data == {"loop": "lissajous_closed"}
    assert meta.starting_time_ns == T0 and meta.duration_ns == (n - 1) * 1000
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        assert sum(c.msgcount for c in reader.connections) == n
        assert len(list(reader.messages())) == n


@pytest.mark.ros
def test_corrupt_chunk_is_dropped_and_every_later_chunk_kept(unfinished, tmp_path: Path) -> None:
    src, sizes, counts = unfinished
    bag = _copy_truncated(src, tmp_path / "bag", sizes[-1])
    data = bytearray((bag / "run_0.mcap").read_bytes())
    middle = (sizes[2] + sizes[3]) // 2  # inside the 4th chunk's compressed data
    data[middle:middle + 8] = b"\xff" * 8
    (bag / "run_0.mcap").write_bytes(bytes(data))
    report = recover_bag(bag, keep_damaged=False)
    kept = list(range(counts[2])) + list(range(counts[3], counts[4]))  # chunks 1-3 and 5, not chunk 4
    assert report.files[0].messages == len(kept) and report.files[0].chunks == CHUNKS - 1
    [dropped] = report.files[0].dropped
    assert (dropped.byte_start, dropped.byte_end) == (sizes[2], sizes[3]) and dropped.chunks == 1
    assert dropped.messages == PER_CHUNK  # counted from the chunk's surviving message index records
    assert (dropped.after_ns, dropped.before_ns) == (T0 + (counts[2] - 1) * 1000, T0 + counts[3] * 1000)
    assert not (bag / "run_0.mcap.damaged").exists()
    assert [m.timestamp_ns for m in read_messages(bag)] == [T0 + i * 1000 for i in kept]


@pytest.mark.ros
def test_complete_bag_is_left_alone_and_bad_input(unfinished, tmp_path: Path) -> None:
    good = tmp_path / "good"
    with BagWriter(good) as writer:
        writer.write_message("/c", Float64MultiArray(data=[1.0]), T0)
    before = (good / "good_0.mcap").read_bytes()
    report = recover_bag(good)
    assert report.files[0].complete and report.untouched
    assert (good / "good_0.mcap").read_bytes() == before
    (good / "metadata.yaml").unlink()  # killed between finishing the file and writing metadata.yaml
    assert recover_bag(good).metadata.message_count == 1 and read_metadata(good).topics[0].name == "/c"

    with pytest.raises(BagError, match="bag not found"):
        recover_bag(tmp_path / "missing")
    (tmp_path / "nomcap").mkdir()
    with pytest.raises(BagError, match="no .mcap file"):
        recover_bag(tmp_path / "nomcap")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "bad_0.mcap").write_bytes(b"garbage" * 20)
    with pytest.raises(BagError, match="not an MCAP file"):
        recover_bag(bad)
    src, sizes, _ = unfinished
    header_only = _copy_truncated(src, tmp_path / "header_only", 40)
    with pytest.raises(BagError, match="nothing to recover"):
        recover_bag(header_only)
    assert not list(header_only.glob("*.recovering"))


@pytest.mark.ros
def test_cli_recover_and_info(unfinished, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src, sizes, counts = unfinished
    bag = tmp_path / "bag"
    shutil.copytree(src, bag)
    parser = argparse.ArgumentParser()
    bag_cmd.add_arguments(parser)
    assert bag_cmd.run(parser.parse_args(["info", str(bag)])) == 1
    assert "bptsb bag recover" in capsys.readouterr().err
    assert bag_cmd.run(parser.parse_args(["recover", str(bag)])) == 0
    out = capsys.readouterr().out
    assert f"recovered {counts[-1]} messages in {CHUNKS} complete chunks" in out
    assert bag_cmd.run(parser.parse_args(["info", str(bag)])) == 0
    out = capsys.readouterr().out
    assert f"Messages:          {counts[-1]}" in out and "Topic: /a" in out
    assert bag_cmd.run(parser.parse_args(["recover", str(tmp_path / "nope")])) == 1
    assert "bag not found" in capsys.readouterr().err


def test_a_fifo_as_the_mcap_is_refused_without_blocking(tmp_path: Path) -> None:
    """A FIFO named like the bag's file blocked `bag recover` in open() forever; run in a child with a timeout so
    the old behaviour fails the test instead of hanging it."""
    import os
    import subprocess
    import sys

    bag = tmp_path / "bag"
    bag.mkdir()
    os.mkfifo(bag / "bag_0.mcap")
    code = "from bptsb_ros.cli import main; import sys; sys.exit(main(sys.argv[1:]))"
    for target in (bag, bag / "bag_0.mcap"):
        out = subprocess.run([sys.executable, "-c", code, "bag", "recover", str(target)], capture_output=True,
                             text=True, timeout=60, env={**os.environ, "PYTHONPATH": str(REPO_ROOT)})
        assert out.returncode == 1 and "Traceback" not in out.stderr, out.stderr[-2000:]
        # the bag directory lists the FIFO as its file; the FIFO itself is neither a directory nor a file
        why = "bag_0.mcap is not a regular file" if target == bag else "is neither a bag directory nor a regular .mcap"
        assert why in out.stderr, out.stderr
        assert len(out.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in bag.iterdir()) == ["bag_0.mcap"]  # nothing written beside it
    with pytest.raises(BagError, match=r"bag_0.mcap is a FIFO \(named pipe\), not a regular file"):
        from bptsb_ros.bags.recover import recover_file

        recover_file(bag / "bag_0.mcap")
