"""Rebuild a bag whose recorder was killed before it could finalize it.

A recorder killed outright (SIGKILL, power loss) leaves ``<bag>_0.mcap`` without summary and footer and no
``metadata.yaml``. Its data section is still a sequence of complete records up to the point of the kill:
the writer closes a chunk by size and at least every ``flush_period_s`` and writes it in one piece, so only
the chunk being filled (and possibly one half-written record) is lost.

Recovery scans the data section record by record from the start. It keeps schemas and channels, decompresses
each chunk and checks its CRC, and copies every message of every intact chunk (and any unchunked message)
into a new MCAP file written exactly as :class:`bptsb_ros.bags.writer.BagWriter` writes one: same schemas
and channel metadata (QoS, type hash), same log/publish times and sequence numbers, new chunk and message
indexes, statistics, summary and footer. A truncated, unreadable or CRC-failing record does not end the scan:
it resynchronises on the next intact chunk (a chunk record whose framing is consistent and whose data passes
its CRC) and goes on, so every intact chunk after the damage is kept; what was dropped is reported (byte
range, chunks, messages where countable, and the log times between which the loss lies).

The damaged original is kept next to it as ``<file>.damaged`` (``.damaged.1``, ``.damaged.2``, … when that name
is taken: an earlier backup is never overwritten) unless asked to delete it, and the rebuilt file takes its
name. A file whose data section is intact but whose summary section is unreadable or disagrees with its data
(message or chunk counts, topics) is rebuilt the same way. ``metadata.yaml`` is rewritten whenever it is
missing, unreadable (binary garbage, wrong fields) or disagrees with the recovered files (the old one is kept
as ``metadata.yaml.damaged``). A bag whose files and metadata are all intact and consistent is left untouched.
"""

from __future__ import annotations

import mmap
import os
import struct
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import BinaryIO

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk

from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.metadata import (
    METADATA_FILENAME,
    BagMetadata,
    FileInfo,
    TopicInfo,
    read_metadata,
    write_metadata,
)
from bptsb_ros.bags.publishers import PUBLISHERS_RECORD, PublisherId, names_from_record
from bptsb_ros.bags.qos import qos_profiles_from_value
from bptsb_ros.bags.writer import CUSTOM_DATA_RECORD, DEFAULT_CHUNK_SIZE, McapStream
from bptsb_ros.files.safe_write import UnsafeFileError, open_regular, temp_file_beside
from bptsb_ros.files.untrusted_yaml import UntrustedYamlError, load_untrusted_yaml

MAGIC = b"\x89MCAP0\r\n"
_STOP_OPCODES = {Opcode.DATA_END, Opcode.FOOTER}


@dataclass
class DroppedRegion:
    """Bytes of a damaged file that recovery could not use.

    ``after_ns``/``before_ns``: log time of the last message kept before the region and of the first kept
    after it (None at either end); ``chunks``: chunk records found in it; ``messages``: messages in those
    chunks where they could still be counted (data intact but for the CRC), None when unknown.
    """

    byte_start: int
    byte_end: int
    reason: str
    after_ns: int | None = None
    before_ns: int | None = None
    chunks: int = 0
    messages: int | None = None

    def describe(self, t0: int | None) -> str:
        def rel(ns: int | None, default: str) -> str:
            return default if ns is None or t0 is None else f"{(ns - t0) / 1e9:.6f} s"

        count = "an unknown number of messages" if self.messages is None else f"{self.messages} messages"
        return (f"dropped bytes {self.byte_start}–{self.byte_end} ({self.reason}): {self.chunks} chunk(s), {count}, "
                f"logged between {rel(self.after_ns, 'the start')} and {rel(self.before_ns, 'the end')}")


@dataclass
class FileRecovery:
    """What was recovered from one MCAP file; byte counts are offsets into the damaged file."""

    path: Path
    complete: bool
    messages: int
    chunks: int
    bytes_used: int
    bytes_total: int
    stop_reason: str
    custom_data: dict[str, str] = field(default_factory=dict)
    backup: Path | None = None
    dropped: list[DroppedRegion] = field(default_factory=list)
    first_ns: int | None = None


@dataclass
class RecoveryReport:
    """Result of :func:`recover_bag`: the rebuilt metadata and one :class:`FileRecovery` per file."""

    bag_dir: Path
    metadata: BagMetadata
    files: list[FileRecovery] = field(default_factory=list)
    untouched: bool = False
    metadata_problem: str = ""
    metadata_backup: Path | None = None

    def summary(self) -> str:
        lines = []
        for f in self.files:
            if f.complete:
                lines.append(f"{f.path.name}: already complete ({f.messages} messages), left as is")
                continue
            lines.append(
                f"{f.path.name}: recovered {f.messages} messages in {f.chunks} complete chunks from "
                f"{f.bytes_used} of {f.bytes_total} bytes ({f.stop_reason}); "
                + (f"damaged original kept as {f.backup.name}" if f.backup else "damaged original deleted")
            )
            lines += [f"  {d.describe(f.first_ns)}" for d in f.dropped]
        if self.untouched:
            lines.append(f"kept {self.bag_dir / METADATA_FILENAME}: {self.metadata.message_count} messages on "
                         f"{len(self.metadata.topics)} topics, consistent with the files")
        else:
            why = f" ({self.metadata_problem})" if self.metadata_problem else ""
            old = f"; the old one is kept as {self.metadata_backup.name}" if self.metadata_backup else ""
            lines.append(f"wrote {self.bag_dir / METADATA_FILENAME}{why}: {self.metadata.message_count} messages on "
                         f"{len(self.metadata.topics)} topics{old}")
        return "\n".join(lines)


class _Scan:
    """Copies the readable part of a damaged MCAP data section into an :class:`McapStream`."""

    def __init__(self, out: McapStream) -> None:
        self.out = out
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.publishers: dict[int, PublisherId | None] = {}
        self.custom_data: dict[str, str] = {}
        self.messages = 0
        self.chunks = 0
        self.complete = False
        self.dropped: list[DroppedRegion] = []

    def run(self, f: BinaryIO, total: int) -> tuple[int, str]:
        """Scan records, resynchronising past damage; return (bytes used, how the scan ended)."""
        if f.read(len(MAGIC)) != MAGIC:
            raise BagError("not an MCAP file (bad magic bytes)")
        if total <= len(MAGIC):
            return len(MAGIC), "end of file without summary/footer"
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
            return self._scan(data, total)

    def _scan(self, data: mmap.mmap, total: int) -> tuple[int, str]:
        pos, used = len(MAGIC), len(MAGIC)
        while pos < total:
            reason = ""
            chunk_framed = False
            if total - pos < 9:
                reason = "truncated record header"
            else:
                opcode, length = struct.unpack_from("<BQ", data, pos)
                if length > total - pos - 9:
                    reason = f"truncated record (opcode 0x{opcode:02x}, {length} bytes)"
                else:
                    body = data[pos + 9:pos + 9 + length]
                    try:
                        self._record(opcode, body)
                    except BagError as exc:
                        reason = str(exc)
                    except Exception as exc:  # malformed bytes raise assorted errors inside the mcap parser
                        reason = f"unreadable record (opcode 0x{opcode:02x}: {type(exc).__name__}: {exc})"
                    chunk_framed = opcode == Opcode.CHUNK
            if not reason:
                pos += 9 + length
                used += 9 + length
                if opcode in _STOP_OPCODES:
                    self.complete = not self.dropped and self._ends_with_magic(data, total)
                    return used, "end of data section" + (f"; {len(self.dropped)} damaged region(s) dropped"
                                                          if self.dropped else "")
                continue
            region = DroppedRegion(pos, total, f"{reason[:200]} at byte {pos}", after_ns=self.out.end_ns)
            nxt = _next_chunk(data, pos + 1, total)
            if chunk_framed:
                region.chunks = 1
                region.messages = _count_messages(body)
                if region.messages is None:  # the chunk's message index records, if they survived, still count
                    region.messages = _count_indexed(data, pos + 9 + length, total if nxt is None else nxt)
            self.dropped.append(region)
            if nxt is None:
                return used, region.reason if len(self.dropped) == 1 else f"{len(self.dropped)} damaged regions"
            region.byte_end = nxt
            region.before_ns = struct.unpack_from("<Q", data, nxt + 9)[0]  # the next intact chunk's first log time
            pos = nxt
        return used, "end of file without summary/footer" + (f"; {len(self.dropped)} damaged region(s) dropped"
                                                             if self.dropped else "")

    @staticmethod
    def _ends_with_magic(data: mmap.mmap, total: int) -> bool:
        return data[total - len(MAGIC):total] == MAGIC

    def _record(self, opcode: int, body: bytes) -> None:
        stream = ReadDataStream(BytesIO(body))
        if opcode == Opcode.SCHEMA:
            self._schema(Schema.read(stream))
        elif opcode == Opcode.CHANNEL:
            self._channel(Channel.read(stream))
        elif opcode == Opcode.MESSAGE:
            self._message(Message.read(stream, len(body)))
        elif opcode == Opcode.METADATA:
            record = Metadata.read(stream)
            if record.name == CUSTOM_DATA_RECORD:
                self.custom_data.update(record.metadata)
                self.out.add_metadata(record.name, record.metadata)
            elif record.name == PUBLISHERS_RECORD:  # node names learnt after the publishers' first messages
                for gid, name in names_from_record(record.metadata).items():
                    self.out.name_publisher(PublisherId(gid).renamed(name))
            elif record.name == "rosbag2" and "serialized_metadata" in record.metadata:
                try:
                    parsed = load_untrusted_yaml(record.metadata["serialized_metadata"], "rosbag2 metadata record")
                except UntrustedYamlError:
                    parsed = None
                custom = parsed.get("custom_data") if isinstance(parsed, dict) else None
                if isinstance(custom, dict):
                    self.custom_data.update({str(k): str(v) for k, v in custom.items()})
        elif opcode == Opcode.CHUNK:
            # Decompress and CRC-check the whole chunk before using any record of it.
            records = breakup_chunk(Chunk.read(stream), validate_crc=True)
            known = set(self.channels)
            for record in records:  # check every message's channel first: a chunk is kept whole or not at all
                if isinstance(record, Channel):
                    known.add(record.id)
                elif isinstance(record, Message) and record.channel_id not in known:
                    raise BagError(f"message on unknown channel {record.channel_id}")
            for record in records:
                if isinstance(record, Schema):
                    self._schema(record)
                elif isinstance(record, Channel):
                    self._channel(record)
                elif isinstance(record, Message):
                    self._message(record)
            self.chunks += 1

    def _schema(self, schema: Schema) -> None:
        self.schemas[schema.id] = schema

    def _channel(self, channel: Channel) -> None:
        if channel.id in self.channels:
            return
        schema = self.schemas.get(channel.schema_id)
        if schema is None:
            raise BagError(f"channel {channel.topic} refers to unknown schema {channel.schema_id}")
        known = self.out.topics.get(channel.topic)
        if known is not None and known.msgtype != schema.name:
            raise BagError(f"topic {channel.topic} appears with two types ({known.msgtype}, {schema.name})")
        self.channels[channel.id] = channel
        publisher = PublisherId.from_channel_metadata(channel.metadata)
        self.publishers[channel.id] = publisher
        info = TopicInfo(
            name=channel.topic, msgtype=schema.name,
            offered_qos_profiles=qos_profiles_from_value(channel.metadata.get("offered_qos_profiles")),
            type_description_hash=channel.metadata.get("topic_type_hash", ""),
            serialization_format=channel.message_encoding,
        )
        schema_id = self.out.add_schema(schema.name, schema.encoding, schema.data.decode())
        self.out.add_channel(info, schema_id, dict(channel.metadata), publisher)

    def _message(self, message: Message) -> None:
        channel = self.channels.get(message.channel_id)
        if channel is None:
            raise BagError(f"message on unknown channel {message.channel_id}")
        self.out.add_message(channel.topic, message.data, message.log_time, message.publish_time, message.sequence,
                             self.publishers[message.channel_id])
        self.messages += 1


_COMPRESSIONS = (b"", b"zstd", b"lz4")


def _plausible_chunk(data: mmap.mmap, pos: int, total: int) -> bool:
    """The bytes at ``pos`` frame a chunk record whose fields agree with its length (cheap pre-check)."""
    if total - pos < 9 + 32 + 8:
        return False
    length = struct.unpack_from("<Q", data, pos + 1)[0]
    if length > total - pos - 9:
        return False
    # body: message_start_time, message_end_time, uncompressed_size (u64), uncompressed_crc, compression length (u32)
    start, end, _size, _crc, clen = struct.unpack_from("<QQQII", data, pos + 9)
    if start > end or clen > 8 or total - pos < 9 + 32 + clen + 8:
        return False
    if data[pos + 41:pos + 41 + clen] not in _COMPRESSIONS:
        return False
    records = struct.unpack_from("<Q", data, pos + 41 + clen)[0]
    return 32 + clen + 8 + records == length


def _next_chunk(data: mmap.mmap, start: int, total: int) -> int | None:
    """Offset of the next intact chunk record at or after ``start`` (framing consistent, CRC valid), or None."""
    pos = data.find(bytes([Opcode.CHUNK]), start)
    while pos != -1:
        if _plausible_chunk(data, pos, total):
            length = struct.unpack_from("<Q", data, pos + 1)[0]
            try:
                breakup_chunk(Chunk.read(ReadDataStream(BytesIO(data[pos + 9:pos + 9 + length]))), validate_crc=True)
                return pos
            except Exception:  # noqa: BLE001, S112 - not an intact chunk: keep looking
                pass
        pos = data.find(bytes([Opcode.CHUNK]), pos + 1)
    return None


def _count_messages(body: bytes) -> int | None:
    """Messages in a chunk record body whose data decompresses but fails its CRC; None when unreadable."""
    try:
        return sum(isinstance(r, Message) for r in breakup_chunk(Chunk.read(ReadDataStream(BytesIO(body)))))
    except Exception:  # noqa: BLE001 - damaged beyond counting
        return None


def _count_indexed(data: mmap.mmap, pos: int, end: int) -> int | None:
    """Messages listed by the message index records that follow a chunk (from ``pos``), or None if none do."""
    count, seen = 0, False
    while end - pos >= 9 + 6:
        opcode, length = struct.unpack_from("<BQ", data, pos)
        if opcode != Opcode.MESSAGE_INDEX or length > end - pos - 9:
            break
        entries = struct.unpack_from("<I", data, pos + 9 + 2)[0]
        if entries % 16 or 2 + 4 + entries != length:
            break
        count, seen = count + entries // 16, True
        pos += 9 + length
    return count if seen else None


def _unused_backup(path: Path) -> Path:
    """``<path>.damaged``, or ``.damaged.1``, ``.damaged.2``, … : a name no earlier backup holds."""
    candidate = path.with_name(path.name + ".damaged")
    n = 0
    while candidate.exists():
        n += 1
        candidate = path.with_name(f"{path.name}.damaged.{n}")
    return candidate


def _summary_problem(path: Path, scan: _Scan) -> str:
    """Why the summary section of a file with an intact data section cannot be trusted ('' when it can)."""
    try:
        with open(path, "rb") as f:
            summary = SeekingReader(f).get_summary()
    except Exception as exc:  # noqa: BLE001 - the mcap parser raises assorted errors on damaged summaries
        return f"summary section unreadable ({type(exc).__name__}: {str(exc)[:120]})"
    if summary is None:
        return "no summary section"
    stats = summary.statistics
    if stats is None or stats.message_count != scan.messages:
        return (f"summary counts {None if stats is None else stats.message_count} messages, the data section "
                f"{scan.messages}")
    if len(summary.chunk_indexes) != scan.chunks:
        return f"summary indexes {len(summary.chunk_indexes)} chunks, the data section holds {scan.chunks}"
    topics = {ch.topic for ch in summary.channels.values()}
    if topics != set(scan.out.topics):
        return "summary channels differ from the data section's"
    return ""


def _metadata_problem(bag_dir: Path, recovered: BagMetadata) -> str:
    """Why ``metadata.yaml`` must be rewritten ('' when it is readable and agrees with the recovered files)."""
    if not (bag_dir / METADATA_FILENAME).is_file():
        return "it was missing"
    try:
        meta = read_metadata(bag_dir)
    except BagError as exc:
        return f"it was unreadable: {str(exc).split('; run `bptsb bag recover')[0][:160]}"
    if meta.relative_file_paths != recovered.relative_file_paths:
        return "its file list disagreed with the bag's files"
    if meta.message_count != recovered.message_count:
        return f"it counted {meta.message_count} messages, the files hold {recovered.message_count}"
    counts = {t.name: (t.msgtype, t.message_count) for t in meta.topics}
    if counts != {t.name: (t.msgtype, t.message_count) for t in recovered.topics}:
        return "its topics or per-topic counts disagreed with the files"
    return ""


def _bag_files(bag_dir: Path) -> list[Path]:
    listed: list[Path] = []
    meta = bag_dir / METADATA_FILENAME
    if meta.is_file():
        try:
            listed = [bag_dir / p for p in read_metadata(bag_dir).relative_file_paths
                      if (bag_dir / p).resolve().parent == bag_dir.resolve()]  # never a file outside the bag
        except BagError:
            listed = []
    files = [p for p in listed if p.is_file() and p.suffix == ".mcap"] or sorted(bag_dir.glob("*.mcap"))
    if not files:
        raise BagError(f"no .mcap file in {bag_dir}")
    for file in files:  # a FIFO would block the open, a device never end
        if not file.is_file():
            raise BagError(f"{file} is not a regular file")
    return files


def recover_file(
    path: Path, *, chunk_size: int = DEFAULT_CHUNK_SIZE, compression: str = "zstd", keep_damaged: bool = True
) -> tuple[FileRecovery, McapStream]:
    """Rebuild one MCAP file in place (see the module docstring); return what was recovered and its topics."""
    try:
        source = open_regular(path)
    except UnsafeFileError as err:
        raise BagError(str(err)) from None
    total = os.fstat(source.fileno()).st_size
    try:
        out_file, tmp = temp_file_beside(path, suffix=".recovering")
    except BaseException:
        source.close()
        raise
    try:
        with source as f, out_file:
            out = McapStream(out_file, chunk_size=chunk_size, compression=compression)
            scan = _Scan(out)
            used, reason = scan.run(f, total)
            if scan.complete:
                problem = _summary_problem(path, scan)
                if problem:
                    scan.complete, reason = False, f"data section intact, {problem}: summary rebuilt"
            if not scan.complete:
                if scan.messages == 0:
                    raise BagError(f"no complete chunk in {path} ({reason}); nothing to recover")
                out.finish(out.bag_metadata(path.name, scan.custom_data))
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    first = out.start_ns
    if scan.complete:
        tmp.unlink()
        return FileRecovery(path, True, scan.messages, scan.chunks, used, total, reason, scan.custom_data,
                            first_ns=first), out
    backup = _unused_backup(path) if keep_damaged else None
    if backup is not None:
        os.replace(path, backup)
    os.replace(tmp, path)
    return FileRecovery(path, False, scan.messages, scan.chunks, used, total, reason, scan.custom_data, backup,
                        scan.dropped, first), out


def recover_bag(path: str | Path, *, keep_damaged: bool = True, compression: str = "zstd") -> RecoveryReport:
    """Recover a bag directory (or a lone ``.mcap`` file, whose directory is then the bag) in place.

    Rewrites each damaged MCAP file from its complete chunks and writes ``metadata.yaml``. Raises
    :class:`BagError` when the path does not exist or holds no readable MCAP data.
    """
    path = Path(path)
    if not path.exists():
        raise BagError(f"bag not found: {path}")
    if not (path.is_dir() or path.is_file()):
        raise BagError(f"{path} is neither a bag directory nor a regular .mcap file")
    bag_dir = path.parent if path.is_file() else path
    files = [path] if path.is_file() else _bag_files(path)
    report_files: list[FileRecovery] = []
    topics: dict[str, TopicInfo] = {}
    infos: list[FileInfo] = []
    custom: dict[str, str] = {}
    for file in files:
        try:
            recovery, stream = recover_file(file, keep_damaged=keep_damaged, compression=compression)
        except BagError as exc:
            raise BagError(f"cannot recover {file}: {exc}") from None
        report_files.append(recovery)
        custom.update(recovery.custom_data)
        for name, info in stream.topics.items():
            merged = topics.setdefault(name, TopicInfo(
                name, info.msgtype, 0, info.offered_qos_profiles, info.type_description_hash,
                info.serialization_format))
            merged.message_count += info.message_count
        start = stream.start_ns or 0
        infos.append(FileInfo(file.name, start, (stream.end_ns or start) - start, stream.message_count))
    starts = [i.starting_time_ns for i in infos if i.message_count]
    ends = [i.starting_time_ns + i.duration_ns for i in infos if i.message_count]
    start = min(starts, default=0)
    metadata = BagMetadata(
        starting_time_ns=start, duration_ns=max(ends, default=0) - start,
        message_count=sum(i.message_count for i in infos), topics=list(topics.values()),
        files=infos,
        custom_data=custom,
    )
    problem = _metadata_problem(bag_dir, metadata)
    untouched = all(r.complete for r in report_files) and not problem
    meta_backup = None
    if not untouched:
        old = bag_dir / METADATA_FILENAME
        if problem and old.is_file():
            meta_backup = _unused_backup(old)
            os.replace(old, meta_backup)
        write_metadata(bag_dir, metadata)
    return RecoveryReport(bag_dir, metadata, report_files, untouched, problem, meta_backup)
