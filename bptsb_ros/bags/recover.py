"""Rebuild a bag whose recorder was killed before it could finalize it.

A recorder killed outright (SIGKILL, power loss) leaves ``<bag>_0.mcap`` without summary and footer and no
``metadata.yaml``. Its data section is still a sequence of complete records up to the point of the kill:
the writer closes a chunk by size and at least every ``flush_period_s`` and writes it in one piece, so only
the chunk being filled (and possibly one half-written record) is lost.

Recovery scans the data section record by record from the start. It keeps schemas and channels, decompresses
each chunk and checks its CRC, and copies every message of every complete chunk (and any unchunked message)
into a new MCAP file written exactly as :class:`bptsb_ros.bags.writer.BagWriter` writes one: same schemas
and channel metadata (QoS, type hash), same log/publish times and sequence numbers, new chunk and message
indexes, statistics, summary and footer. It stops at the first truncated, unreadable or CRC-failing record.
The damaged original is kept next to it as ``<file>.damaged`` (unless asked to delete it), the rebuilt file
takes its name, and ``metadata.yaml`` is written from the recovered messages. A file that is already complete
is left untouched; only a missing ``metadata.yaml`` is then rebuilt.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import BinaryIO

import yaml
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk

from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.metadata import METADATA_FILENAME, BagMetadata, FileInfo, TopicInfo, write_metadata
from bptsb_ros.bags.qos import qos_profiles_from_value
from bptsb_ros.bags.writer import CUSTOM_DATA_RECORD, DEFAULT_CHUNK_SIZE, McapStream

MAGIC = b"\x89MCAP0\r\n"
_STOP_OPCODES = {Opcode.DATA_END, Opcode.FOOTER}


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


@dataclass
class RecoveryReport:
    """Result of :func:`recover_bag`: the rebuilt metadata and one :class:`FileRecovery` per file."""

    bag_dir: Path
    metadata: BagMetadata
    files: list[FileRecovery] = field(default_factory=list)
    untouched: bool = False

    def summary(self) -> str:
        lines = []
        for f in self.files:
            if f.complete:
                lines.append(f"{f.path.name}: already complete ({f.messages} messages), left as is")
            else:
                lines.append(
                    f"{f.path.name}: recovered {f.messages} messages in {f.chunks} complete chunks from "
                    f"{f.bytes_used} of {f.bytes_total} bytes (stopped: {f.stop_reason}); "
                    + (f"damaged original kept as {f.backup.name}" if f.backup else "damaged original deleted")
                )
        what = "kept" if self.untouched else "wrote"
        lines.append(f"{what} {self.bag_dir / METADATA_FILENAME}: {self.metadata.message_count} messages on "
                     f"{len(self.metadata.topics)} topics")
        return "\n".join(lines)


class _Scan:
    """Copies the readable part of a damaged MCAP data section into an :class:`McapStream`."""

    def __init__(self, out: McapStream) -> None:
        self.out = out
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.custom_data: dict[str, str] = {}
        self.messages = 0
        self.chunks = 0
        self.complete = False

    def run(self, f: BinaryIO, total: int) -> tuple[int, str]:
        """Scan records; return (offset after the last record used, why the scan stopped)."""
        if f.read(len(MAGIC)) != MAGIC:
            raise BagError("not an MCAP file (bad magic bytes)")
        good = len(MAGIC)
        while True:
            head = f.read(9)
            if len(head) == 0:
                return good, "end of file without summary/footer"
            if len(head) < 9:
                return good, f"truncated record header at byte {good}"
            opcode, length = struct.unpack("<BQ", head)
            if length > total - good - 9:
                return good, f"truncated record (opcode 0x{opcode:02x}, {length} bytes) at byte {good}"
            body = f.read(length)
            try:
                self._record(opcode, body)
            except BagError as exc:
                return good, f"{exc} at byte {good}"
            except Exception as exc:  # malformed bytes raise assorted errors inside the mcap parser
                return good, f"unreadable record (opcode 0x{opcode:02x}: {type(exc).__name__}: {exc}) at byte {good}"
            good += 9 + length
            if opcode in _STOP_OPCODES:
                self.complete = self._ends_with_magic(f, total)
                return good, "end of data section"

    @staticmethod
    def _ends_with_magic(f: BinaryIO, total: int) -> bool:
        f.seek(total - len(MAGIC))
        return f.read(len(MAGIC)) == MAGIC

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
            elif record.name == "rosbag2" and "serialized_metadata" in record.metadata:
                custom = (yaml.safe_load(record.metadata["serialized_metadata"]) or {}).get("custom_data") or {}
                self.custom_data.update({str(k): str(v) for k, v in custom.items()})
        elif opcode == Opcode.CHUNK:
            # Decompress and CRC-check the whole chunk before using any record of it.
            records = breakup_chunk(Chunk.read(stream), validate_crc=True)
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
        if known is None:
            info = TopicInfo(
                name=channel.topic, msgtype=schema.name,
                offered_qos_profiles=qos_profiles_from_value(channel.metadata.get("offered_qos_profiles")),
                type_description_hash=channel.metadata.get("topic_type_hash", ""),
                serialization_format=channel.message_encoding,
            )
            schema_id = self.out.add_schema(schema.name, schema.encoding, schema.data.decode())
            self.out.add_channel(info, schema_id, dict(channel.metadata))

    def _message(self, message: Message) -> None:
        channel = self.channels.get(message.channel_id)
        if channel is None:
            raise BagError(f"message on unknown channel {message.channel_id}")
        self.out.add_message(channel.topic, message.data, message.log_time, message.publish_time, message.sequence)
        self.messages += 1


def _bag_files(bag_dir: Path) -> list[Path]:
    listed: list[Path] = []
    meta = bag_dir / METADATA_FILENAME
    if meta.is_file():
        try:
            data = yaml.safe_load(meta.read_text(encoding="utf-8"))
            listed = [bag_dir / p for p in data["rosbag2_bagfile_information"]["relative_file_paths"]]
        except (yaml.YAMLError, KeyError, TypeError):
            listed = []
    files = [p for p in listed if p.is_file()] or sorted(bag_dir.glob("*.mcap"))
    if not files:
        raise BagError(f"no .mcap file in {bag_dir}")
    return files


def recover_file(
    path: Path, *, chunk_size: int = DEFAULT_CHUNK_SIZE, compression: str = "zstd", keep_damaged: bool = True
) -> tuple[FileRecovery, McapStream]:
    """Rebuild one MCAP file in place (see the module docstring); return what was recovered and its topics."""
    total = path.stat().st_size
    tmp = path.with_name(path.name + ".recovering")
    try:
        with open(path, "rb") as f, open(tmp, "wb") as out_file:
            out = McapStream(out_file, chunk_size=chunk_size, compression=compression)
            scan = _Scan(out)
            used, reason = scan.run(f, total)
            if not scan.complete:
                if scan.messages == 0:
                    raise BagError(f"no complete chunk in {path} ({reason}); nothing to recover")
                out.finish(out.bag_metadata(path.name, scan.custom_data))
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if scan.complete:
        tmp.unlink()
        return FileRecovery(path, True, scan.messages, scan.chunks, used, total, reason, scan.custom_data), out
    backup = path.with_name(path.name + ".damaged") if keep_damaged else None
    if backup is not None:
        os.replace(path, backup)
    os.replace(tmp, path)
    return FileRecovery(path, False, scan.messages, scan.chunks, used, total, reason, scan.custom_data, backup), out


def recover_bag(path: str | Path, *, keep_damaged: bool = True, compression: str = "zstd") -> RecoveryReport:
    """Recover a bag directory (or a lone ``.mcap`` file, whose directory is then the bag) in place.

    Rewrites each damaged MCAP file from its complete chunks and writes ``metadata.yaml``. Raises
    :class:`BagError` when the path does not exist or holds no readable MCAP data.
    """
    path = Path(path)
    if not path.exists():
        raise BagError(f"bag not found: {path}")
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
    untouched = all(r.complete for r in report_files) and (bag_dir / METADATA_FILENAME).is_file()
    if not untouched:
        write_metadata(bag_dir, metadata)
    return RecoveryReport(bag_dir, metadata, report_files, untouched)
