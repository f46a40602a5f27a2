"""Read rosbag2 MCAP bags (a bag directory with ``metadata.yaml``, or a single ``.mcap`` file).

Every chunk's CRC is verified before any message is read: a damaged chunk is an error naming the chunk, its
byte offset and its time range (``bptsb bag recover`` rebuilds the file from the intact chunks), or, with
``skip_damaged=True`` (``--skip-damaged``), skipped with a warning on stderr.

Messages come back as ``(topic, msgtype, timestamp_ns, message)`` with the message deserialized from its CDR
bytes (no ROS graph needed): by rclpy where it is installed, else by rosbags from the bag's own schema
(:mod:`bptsb_ros.bags.decode`: same field names and values, so no ROS install is needed to analyse a bag), or as
raw bytes with ``raw=True``. :func:`read_arrays` stacks given topics into numpy arrays for analysis.
"""

from __future__ import annotations

import datetime as _dt
import struct
import sys
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, ChunkIndex, Message, Schema
from mcap.stream_reader import get_chunk_data_stream
from mcap.summary import Summary

from bptsb_ros.bags.decode import MessageDecoder
from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.metadata import METADATA_FILENAME, BagMetadata, TopicInfo, bag_file, read_metadata
from bptsb_ros.bags.publishers import PUBLISHERS_RECORD, PublisherId, names_from_record
from bptsb_ros.bags.qos import qos_profiles_from_value
from bptsb_ros.bags.recording import RECORDING_RECORD, recorded_loss
from bptsb_ros.files.untrusted_yaml import UntrustedYamlError, load_untrusted_yaml, printable


class BagMessage(NamedTuple):
    """One message: ``timestamp_ns`` is the receive (log) time in ns; ``message`` is an rclpy or rosbags message
    (:mod:`bptsb_ros.bags.decode`), or the CDR bytes."""

    topic: str
    msgtype: str
    timestamp_ns: int
    message: Any


@dataclass
class TopicSeries:
    """A topic as arrays: ``t_ns`` (K,) int64 receive times in ns, ``values`` (K, ...) float64, one row a message."""

    topic: str
    msgtype: str
    t_ns: np.ndarray
    values: np.ndarray

    @property
    def t_s(self) -> np.ndarray:
        """Receive times in seconds relative to the first message, (K,) float64."""
        return (self.t_ns - self.t_ns[0]) / 1e9 if len(self.t_ns) else np.zeros(0)


@dataclass(frozen=True)
class PublisherCount:
    """``count`` messages of ``topic`` came from ``publisher`` (None: the bag does not say who sent them)."""

    topic: str
    publisher: PublisherId | None
    count: int


@dataclass
class BagInfo:
    """Summary of a bag, as ``ros2 bag info`` shows it. Times in ns since the Unix epoch, sizes in bytes."""

    path: Path
    files: list[Path]
    size_bytes: int
    storage_identifier: str
    ros_distro: str
    start_ns: int
    end_ns: int
    message_count: int
    topics: list[TopicInfo]
    chunk_count: int
    chunk_compressions: list[str] = field(default_factory=list)
    profile: str = ""
    library: str = ""
    damaged_chunks: list[str] = field(default_factory=list)
    #: messages per topic and publisher, from the MCAP channels (publisher None: not recorded)
    publishers: list[PublisherCount] = field(default_factory=list)
    #: messages the recorder lost (None: it did not count, an older recorder), per topic, and whether its final
    #: drain completed (``custom_data`` ``dropped_messages``, ``dropped_by_topic``, ``recording_complete``)
    dropped_messages: int | None = None
    dropped_by_topic: dict[str, int] = field(default_factory=dict)
    recording_complete: bool = True

    @property
    def duration_ns(self) -> int:
        return self.end_ns - self.start_ns


def mcap_files(path: str | Path) -> list[Path]:
    """The MCAP files of a bag: the ones listed in ``metadata.yaml`` of a bag directory, or the file itself."""
    path = Path(path)
    if path.is_file():
        return [path]
    if not path.exists():
        raise BagError(f"bag not found: {path}")
    metadata = read_metadata(path)
    if metadata.storage_identifier != "mcap":
        raise BagError(f"{path} uses storage {metadata.storage_identifier!r}; only 'mcap' bags are supported")
    files = [bag_file(path, rel) for rel in metadata.relative_file_paths]
    if not files:
        raise BagError(f"{path}/{METADATA_FILENAME} lists no storage file")
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise BagError(f"{path}/{METADATA_FILENAME} lists files that do not exist: {', '.join(missing)}")
    return files


@dataclass(frozen=True)
class DamagedChunk:
    """A chunk whose bytes do not match its CRC (or cannot be read): ``index`` counts from 1 in file order,
    ``offset`` is its byte offset, ``start_ns``/``end_ns`` the log times of its first and last message."""

    file: Path
    index: int
    count: int
    offset: int
    start_ns: int
    end_ns: int
    reason: str
    file_start_ns: int = 0

    def describe(self) -> str:
        rel = f"{(self.start_ns - self.file_start_ns) / 1e9:.6f}–{(self.end_ns - self.file_start_ns) / 1e9:.6f} s"
        return (f"chunk {self.index} of {self.count} at byte {self.offset} (messages logged {rel} after the start, "
                f"log times {self.start_ns}–{self.end_ns} ns) is damaged: {self.reason}")


class _McapFile:
    """An open, finalized MCAP file with its summary."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._file = open(path, "rb")  # closed in close()
        try:
            self.reader = SeekingReader(self._file, validate_crcs=True)
            self.header = self.reader.get_header()
            summary = self.reader.get_summary()
        except (McapError, ValueError, EOFError, OSError, StopIteration) as exc:
            self._file.close()
            raise BagError(
                f"{path} is not a complete MCAP file ({type(exc).__name__}: {exc}). If the recorder was killed, "
                f"`bptsb bag recover {path.parent if path.parent.name else path}` restores its complete chunks."
            ) from None
        except Exception as exc:  # the mcap parser raises assorted errors on garbage (struct, Unicode, ...)
            self._file.close()
            raise BagError(f"{path} is not a valid MCAP file: {type(exc).__name__}: {exc}") from None
        if summary is None:
            self._file.close()
            raise BagError(f"{path} has no summary section; run `bptsb bag recover` on it to index it")
        self.summary: Summary = summary

    def damaged_chunks(self) -> list[DamagedChunk]:
        """Every chunk of the summary whose record cannot be read or whose data fails its CRC."""
        indexes = sorted(self.summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
        stats = self.summary.statistics
        file_start = stats.message_start_time if stats is not None and stats.message_count else 0
        out = []
        for i, ci in enumerate(indexes, start=1):
            reason = self._chunk_problem(ci)
            if reason:
                out.append(DamagedChunk(self.path, i, len(indexes), ci.chunk_start_offset, ci.message_start_time,
                                        ci.message_end_time, reason, file_start))
        return out

    def _chunk_problem(self, ci: ChunkIndex) -> str:
        try:
            self._file.seek(ci.chunk_start_offset)
            head = self._file.read(9)
            if len(head) < 9:
                return "the file ends inside it"
            opcode, length = struct.unpack("<BQ", head)
            if opcode != Opcode.CHUNK:
                return f"the chunk index points at a record of opcode 0x{opcode:02x}, not a chunk"
            body = self._file.read(length)
            if len(body) < length:
                return "the file ends inside it"
            chunk = Chunk.read(ReadDataStream(BytesIO(body)))
            get_chunk_data_stream(chunk, validate_crc=True)
        except Exception as exc:  # CRC mismatch, bad compression, malformed fields: the mcap parser's errors vary
            return printable(f"{type(exc).__name__}: {str(exc)[:160]}")
        return ""

    def publishers(self) -> dict[int, PublisherId | None]:
        """Channel id -> the publisher its metadata names (None: not recorded), with the node names of the
        ``bptsb_ros.publishers`` record where it has them."""
        names: dict[str, str] = {}
        if any(PublisherId.from_channel_metadata(ch.metadata) for ch in self.summary.channels.values()):
            try:
                for record in self.reader.iter_metadata():
                    if record.name == PUBLISHERS_RECORD:
                        names.update(names_from_record(record.metadata))
            except Exception:  # noqa: BLE001 - an unreadable record: keep the names of the channels
                names = {}
        out: dict[int, PublisherId | None] = {}
        for cid, ch in self.summary.channels.items():
            publisher = PublisherId.from_channel_metadata(ch.metadata)
            out[cid] = None if publisher is None else publisher.renamed(names.get(publisher.gid, ""))
        return out

    def drop_chunks(self, damaged: list[DamagedChunk]) -> bool:
        """Leave ``damaged`` out of the summary the reader iterates; False when no chunk is left."""
        offsets = {d.offset for d in damaged}
        self.summary.chunk_indexes[:] = [c for c in self.summary.chunk_indexes if c.chunk_start_offset not in offsets]
        return bool(self.summary.chunk_indexes)

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> _McapFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def damaged_chunk_error(damaged: list[DamagedChunk]) -> BagError:
    """The error for damaged chunks: names each one and says what to do."""
    where = damaged[0].file
    bag = where.parent if where.parent.name else where
    return BagError(f"{where}: " + "; ".join(d.describe() for d in damaged)
                    + f". Run `bptsb bag recover {bag}` to rebuild the file from its intact chunks, or read past the "
                    "damage with --skip-damaged")


def _topics_of(summary: Summary) -> dict[str, str]:
    return {ch.topic: summary.schemas[ch.schema_id].name if ch.schema_id else "" for ch in summary.channels.values()}


def topic_publishers(path: str | Path) -> dict[str, dict[str, tuple[PublisherId, int]]]:
    """topic -> GID -> (the publisher, its message count) of every publisher a channel of the bag names (from
    the MCAP summaries; channels without publisher identities are left out)."""
    out: dict[str, dict[str, tuple[PublisherId, int]]] = {}
    for file in mcap_files(path):
        with _McapFile(file) as mf:
            stats = mf.summary.statistics
            for cid, publisher in mf.publishers().items():
                if publisher is None:
                    continue
                topic = mf.summary.channels[cid].topic
                n = stats.channel_message_counts.get(cid, 0) if stats is not None else 0
                old = out.setdefault(topic, {}).get(publisher.gid)
                out[topic][publisher.gid] = (publisher, n + (old[1] if old else 0))
    return out


def list_topics(path: str | Path) -> dict[str, str]:
    """Map each topic of a bag to its ``pkg/msg/Type``."""
    topics: dict[str, str] = {}
    for file in mcap_files(path):
        with _McapFile(file) as mf:
            topics.update(_topics_of(mf.summary))
    return topics


def read_messages(
    path: str | Path,
    topics: Iterable[str] | None = None,
    *,
    raw: bool = False,
    start_ns: int | None = None,
    end_ns: int | None = None,
    skip_damaged: bool = False,
    decoder: str = "auto",
) -> Iterator[BagMessage]:
    """Iterate the messages of a bag: in receive-time order within each MCAP file, file after file (the files
    of a bag written by one recorder follow each other in time). Every message of a topic comes back, whoever
    published it; :func:`read_published` also says who did.

    :param path: bag directory or ``.mcap`` file.
    :param topics: topics to read (all when ``None``); a topic the bag does not have raises :class:`BagError`.
    :param raw: yield the CDR bytes instead of deserialized messages.
    :param start_ns: first receive time to include (ns, inclusive).
    :param end_ns: receive time to stop at (ns, exclusive).
    :param skip_damaged: skip chunks that fail their CRC check (with a warning on stderr) instead of raising
        :class:`BagError` naming them.
    :param decoder: ``auto`` (rclpy where it knows the message type, else rosbags), ``rclpy`` or ``rosbags``
        (:mod:`bptsb_ros.bags.decode`).
    """
    decode = MessageDecoder(decoder)
    for schema, channel, message, _ in _records(path, topics, start_ns, end_ns, skip_damaged):
        yield _decode(schema, channel, message, raw, decode)


class PublishedMessage(NamedTuple):
    """A message and who published it: ``publisher`` is None when the bag does not say (its channel has no
    ``publisher_gid``: see :mod:`bptsb_ros.bags.publishers`)."""

    message: BagMessage
    publisher: PublisherId | None


def read_published(
    path: str | Path,
    topics: Iterable[str] | None = None,
    *,
    raw: bool = False,
    skip_damaged: bool = False,
    decoder: str = "auto",
) -> Iterator[PublishedMessage]:
    """Like :func:`read_messages`, with each message's publisher (GID and node, from its channel)."""
    decode = MessageDecoder(decoder)
    for schema, channel, message, publisher in _records(path, topics, None, None, skip_damaged):
        yield PublishedMessage(_decode(schema, channel, message, raw, decode), publisher)


def _records(
    path: str | Path, topics: Iterable[str] | None, start_ns: int | None, end_ns: int | None, skip_damaged: bool
) -> Iterator[tuple[Schema | None, Channel, Message, PublisherId | None]]:
    files = mcap_files(path)
    wanted = None if topics is None else list(dict.fromkeys([topics] if isinstance(topics, str) else topics))
    if wanted is not None:
        available = list_topics(path)
        unknown = [t for t in wanted if t not in available]
        if unknown:
            raise BagError(f"topic(s) not in bag {path}: {', '.join(unknown)}; available: {', '.join(available)}")
    for file in files:
        with _McapFile(file) as mf:
            damaged = mf.damaged_chunks()
            if damaged and not skip_damaged:
                raise damaged_chunk_error(damaged)
            for d in damaged:
                print(f"warning: {file}: skipping {d.describe()}", file=sys.stderr, flush=True)
            if damaged and not mf.drop_chunks(damaged):
                continue
            try:
                publishers = mf.publishers()
                for schema, channel, message in mf.reader.iter_messages(
                    topics=wanted, starting_at=start_ns, ending_before=end_ns, log_time_order=True
                ):
                    yield schema, channel, message, publishers.get(channel.id)
            except BagError:
                raise
            except Exception as exc:
                raise BagError(f"error reading {file}: {type(exc).__name__}: {exc}") from None


def _decode(
    schema: Schema | None, channel: Channel, message: Message, raw: bool, decode: MessageDecoder
) -> BagMessage:
    msgtype = schema.name if schema is not None else ""
    if raw:
        return BagMessage(channel.topic, msgtype, message.log_time, message.data)
    if channel.message_encoding != "cdr":
        raise BagError(f"topic {channel.topic} has message encoding {channel.message_encoding!r}, not 'cdr'")
    if schema is None:
        raise BagError(f"topic {channel.topic} has no schema: its messages cannot be decoded (raw=True reads them)")
    return BagMessage(channel.topic, msgtype, message.log_time, decode(schema, message.data))


# -- arrays ------------------------------------------------------------------------------------------------------

def _multiarray(msg: Any) -> np.ndarray:
    data = np.asarray(msg.data, dtype=np.float64)
    dims = [d.size for d in msg.layout.dim]
    if dims and msg.layout.data_offset == 0 and int(np.prod(dims)) == data.size:
        return data.reshape(dims)
    return data


def _xyz(p: Any) -> list[float]:
    return [p.x, p.y, p.z]


def _joint_state(msg: Any) -> np.ndarray:
    """The first non-empty of position, velocity and effort (force commands fill only effort)."""
    for name in ("position", "velocity", "effort"):
        values = getattr(msg, name)
        if len(values):
            return np.asarray(values, dtype=np.float64)
    raise BagError("JointState message with no position, velocity or effort values; pass converters={topic: fn}")


#: Default message -> array conversions, by message type.
CONVERTERS: dict[str, Callable[[Any], np.ndarray]] = {
    **{f"std_msgs/msg/{k}MultiArray": _multiarray for k in (
        "Float64", "Float32", "Int8", "Int16", "Int32", "Int64", "UInt8", "UInt16", "UInt32", "UInt64", "Byte")},
    **{f"std_msgs/msg/{k}": (lambda m: np.asarray(m.data, dtype=np.float64)) for k in (
        "Float64", "Float32", "Int8", "Int16", "Int32", "Int64", "UInt8", "UInt16", "UInt32", "UInt64", "Bool")},
    "rosgraph_msgs/msg/Clock": lambda m: np.asarray(m.clock.sec + m.clock.nanosec * 1e-9),
    "geometry_msgs/msg/PoseArray": lambda m: np.asarray([_xyz(p.position) for p in m.poses], dtype=np.float64)
    .reshape(-1, 3),
    "geometry_msgs/msg/Point": lambda m: np.asarray(_xyz(m), dtype=np.float64),
    "geometry_msgs/msg/Vector3": lambda m: np.asarray(_xyz(m), dtype=np.float64),
    "geometry_msgs/msg/PointStamped": lambda m: np.asarray(_xyz(m.point), dtype=np.float64),
    "geometry_msgs/msg/Vector3Stamped": lambda m: np.asarray(_xyz(m.vector), dtype=np.float64),
    "sensor_msgs/msg/JointState": _joint_state,
}


def to_array(msgtype: str, msg: Any) -> np.ndarray:
    """Convert one message with the default converter of its type (see :data:`CONVERTERS`).

    MultiArrays give their data (reshaped to the layout when it describes it), scalars a 0-d array, PoseArray the
    positions (n, 3), Point/Vector3 (3,), Clock the time in s, JointState the first non-empty of position,
    velocity and effort (a message with none raises :class:`BagError`; choose a field with ``converters``).
    """
    try:
        convert = CONVERTERS[msgtype]
    except KeyError:
        raise BagError(f"no default array conversion for {msgtype}; pass converters={{topic: fn}}") from None
    return convert(msg)


def read_arrays(
    path: str | Path,
    topics: Iterable[str],
    *,
    converters: dict[str, Callable[[Any], np.ndarray]] | None = None,
    skip_damaged: bool = False,
    decoder: str = "auto",
) -> dict[str, TopicSeries]:
    """Read topics into stacked arrays: ``{topic: TopicSeries}`` with ``values`` of shape (K, ...).

    ``converters`` maps a topic to a function ``message -> ndarray`` overriding :func:`to_array`. Every message
    of a topic must convert to the same shape. ``decoder``: as for :func:`read_messages`.
    """
    topics = [topics] if isinstance(topics, str) else list(topics)
    converters = converters or {}
    rows: dict[str, list[np.ndarray]] = {t: [] for t in topics}
    times: dict[str, list[int]] = {t: [] for t in topics}
    types: dict[str, str] = dict.fromkeys(topics, "")
    for topic, msgtype, t_ns, msg in read_messages(path, topics, skip_damaged=skip_damaged, decoder=decoder):
        convert = converters.get(topic)
        rows[topic].append(np.asarray(convert(msg) if convert else to_array(msgtype, msg), dtype=np.float64))
        times[topic].append(t_ns)
        types[topic] = msgtype
    result = {}
    for topic in topics:
        shapes = {r.shape for r in rows[topic]}
        if len(shapes) > 1:
            raise BagError(f"messages on {topic} convert to different shapes {sorted(shapes)}; cannot stack")
        values = np.stack(rows[topic]) if rows[topic] else np.zeros((0,))
        result[topic] = TopicSeries(topic, types[topic], np.asarray(times[topic], dtype=np.int64), values)
    return result


# -- info --------------------------------------------------------------------------------------------------------

def bag_info(path: str | Path) -> BagInfo:
    """Gather what ``ros2 bag info`` shows: from ``metadata.yaml`` for a bag directory, from the MCAP summary
    for a single file (chunk counts and compression always come from the MCAP summaries)."""
    path = Path(path)
    files = mcap_files(path)
    metadata: BagMetadata | None = read_metadata(path) if path.is_dir() else None
    chunk_count, compressions, topics, damaged = 0, set(), {}, []
    by_publisher: dict[tuple[str, str], PublisherCount] = {}
    start, end, count, profile, library = None, None, 0, "", ""
    for file in files:
        with _McapFile(file) as mf:
            summary, profile, library = mf.summary, mf.header.profile, mf.header.library
            chunk_count += len(summary.chunk_indexes)
            damaged += [d.describe() for d in mf.damaged_chunks()]
            compressions.update(ci.compression or "none" for ci in summary.chunk_indexes)
            stats = summary.statistics
            if stats is not None and stats.message_count:
                start = stats.message_start_time if start is None else min(start, stats.message_start_time)
                end = stats.message_end_time if end is None else max(end, stats.message_end_time)
                count += stats.message_count
            publishers = mf.publishers()
            for cid, ch in summary.channels.items():
                publisher = publishers.get(cid)
                key = (ch.topic, publisher.gid if publisher else "")
                n = stats.channel_message_counts.get(cid, 0) if stats is not None else 0
                old = by_publisher.get(key)
                by_publisher[key] = PublisherCount(ch.topic, publisher, n + (old.count if old else 0))
                info = topics.setdefault(ch.topic, TopicInfo(
                    name=ch.topic, msgtype=summary.schemas[ch.schema_id].name if ch.schema_id else "",
                    offered_qos_profiles=qos_profiles_from_value(ch.metadata.get("offered_qos_profiles")),
                    type_description_hash=ch.metadata.get("topic_type_hash", ""),
                    serialization_format=ch.message_encoding,
                ))
                if stats is not None:
                    info.message_count += stats.channel_message_counts.get(cid, 0)
    custom = metadata.custom_data if metadata is not None else _recording_record(files[0])
    dropped, by_topic, complete = recorded_loss(custom)
    loss = {"dropped_messages": dropped, "dropped_by_topic": by_topic, "recording_complete": complete}
    if metadata is not None:
        return BagInfo(
            path=path, files=files, size_bytes=sum(f.stat().st_size for f in files),
            storage_identifier=metadata.storage_identifier, ros_distro=metadata.ros_distro,
            start_ns=metadata.starting_time_ns, end_ns=metadata.end_time_ns, message_count=metadata.message_count,
            topics=metadata.topics, chunk_count=chunk_count, chunk_compressions=sorted(compressions),
            profile=profile, library=library, damaged_chunks=damaged, publishers=list(by_publisher.values()), **loss,
        )
    return BagInfo(
        path=path, files=files, size_bytes=sum(f.stat().st_size for f in files), storage_identifier="mcap",
        ros_distro=_ros_distro_record(files[0]), start_ns=start or 0, end_ns=end or 0, message_count=count,
        topics=list(topics.values()),
        chunk_count=chunk_count, chunk_compressions=sorted(compressions), profile=profile, library=library,
        damaged_chunks=damaged, publishers=list(by_publisher.values()), **loss,
    )


def _recording_record(file: Path) -> dict[str, str]:
    """The recorder's loss entries (``bptsb_ros.recording`` record) of a lone MCAP file; {} without them."""
    with _McapFile(file) as mf:
        try:
            for record in mf.reader.iter_metadata():
                if record.name == RECORDING_RECORD:
                    return {str(k)[:64]: str(v)[:4096] for k, v in record.metadata.items()}
        except Exception:  # noqa: BLE001 - an unreadable record: no loss entries
            return {}
    return {}


def _ros_distro_record(file: Path) -> str:
    """``ros_distro`` from the ``rosbag2`` metadata record rosbag2 (and our writer) put in the MCAP file."""
    with _McapFile(file) as mf:
        for record in mf.reader.iter_metadata():
            if record.name == "rosbag2" and "serialized_metadata" in record.metadata:
                try:  # untrusted bag data: bounded size and alias expansion
                    data = load_untrusted_yaml(record.metadata["serialized_metadata"], "rosbag2 metadata record")
                except UntrustedYamlError:
                    return ""
                distro = data.get("ros_distro") if isinstance(data, dict) else None
                return distro[:64] if isinstance(distro, str) else ""
    return ""


def _human_size(n: int) -> str:
    size = float(n)
    for unit in ("B", "KiB", "MiB", "GiB"):
        if size < 1024 or unit == "GiB":
            return f"{size:.1f} {unit}" if unit != "B" else f"{n} B"
        size /= 1024
    raise AssertionError("unreachable")


def _stamp(ns: int) -> str:
    when = _dt.datetime.fromtimestamp(ns // 1_000_000_000, tz=_dt.UTC)
    return f"{when:%b %d %Y %H:%M:%S}.{ns % 1_000_000_000:09d} UTC ({ns // 1_000_000_000}.{ns % 1_000_000_000:09d})"


def _publisher_lines(counts: list[PublisherCount]) -> list[str]:
    """``Publishers:`` lines (topic: node (GID) count, ...) when the bag records who sent its messages."""
    if not any(c.publisher is not None for c in counts):
        return ["Publishers:        not recorded (messages cannot be attributed to their senders)"]
    lines = []
    for topic in dict.fromkeys(c.topic for c in counts):
        parts = [f"{c.publisher.name} [{c.publisher.gid}] {c.count}" if c.publisher else f"unknown {c.count}"
                 for c in counts if c.topic == topic and (c.count or c.publisher)]
        if parts:
            lines.append(("Publishers:        " if not lines else " " * 19) + f"{topic}: " + ", ".join(parts))
    return lines


def format_info(info: BagInfo) -> str:
    """Render :class:`BagInfo` the way ``ros2 bag info`` lays it out."""
    pad = " " * 19
    lines = [
        f"Files:             {info.files[0].name}",
        *[pad + f.name for f in info.files[1:]],
        f"Bag size:          {_human_size(info.size_bytes)}",
        f"Storage id:        {info.storage_identifier}",
        f"ROS Distro:        {info.ros_distro or 'unknown'}",
        f"Duration:          {info.duration_ns / 1e9:.9f}s",
        f"Start:             {_stamp(info.start_ns)}",
        f"End:               {_stamp(info.end_ns)}",
        f"Messages:          {info.message_count}",
        f"Chunks:            {info.chunk_count} ({', '.join(info.chunk_compressions) or 'none'})",
        f"MCAP profile:      {info.profile} ({info.library})",
    ]
    width = max((len(t.name) for t in info.topics), default=0)
    for i, t in enumerate(info.topics):
        head = "Topic information: " if i == 0 else pad
        lines.append(f"{head}Topic: {t.name:<{width}} | Type: {t.msgtype} | Count: {t.message_count} | "
                     f"Serialization Format: {t.serialization_format}")
    if not info.topics:
        lines.append("Topic information: (none)")
    lines += _publisher_lines(info.publishers)
    if info.dropped_messages is not None:
        parts = ", ".join(f"{t} {n}" for t, n in info.dropped_by_topic.items())
        lines.append(f"Lost messages:     {info.dropped_messages}" + (f" ({parts})" if parts else "")
                     + ("" if info.recording_complete else "; the recorder's final drain was cut short"))
    for i, text in enumerate(info.damaged_chunks):
        lines.append(("DAMAGED:           " if i == 0 else pad) + text)
    if info.damaged_chunks:
        lines.append(pad + f"run `bptsb bag recover {info.path}` to rebuild the bag from its intact chunks")
    return "\n".join(printable(line) for line in lines)  # names and types are the bag's data: control bytes escaped
