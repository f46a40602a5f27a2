"""ROS-free writer of rosbag2 bag directories with one MCAP file (``<bag>/metadata.yaml`` + ``<bag>/<bag>_0.mcap``).

The MCAP file follows what ``rosbag2_storage_mcap`` (Jazzy) writes: profile ``ros2``; one schema per message type
with encoding ``ros2msg`` and the full definition text (see :mod:`bptsb_ros.bags.msgdefs`); channels with message
encoding ``cdr`` and channel metadata ``offered_qos_profiles`` (YAML) and ``topic_type_hash`` (``RIHS01_...``);
messages with log time = receive time; a ``rosbag2`` metadata record holding the serialized bag metadata; chunk
indexes, message indexes, statistics and summary offsets. A message written with its publisher's identity goes to
the channel of its (topic, publisher), whose metadata also names the publisher (:mod:`bptsb_ros.bags.publishers`);
one written without goes to the topic's plain channel. A topic that never got a message still gets its plain
channel when the bag is closed.

Chunks are compressed with zstd by default (every MCAP reader — rosbag2, Foxglove, ``mcap``, ``rosbags`` —
supports it; rosbag2 writes uncompressed chunks unless told otherwise). A chunk is closed when it reaches
``chunk_size`` bytes or when ``flush_period_s`` has passed since the last flush, so a writer killed outright
loses at most that much: every closed chunk is complete on disk and :mod:`bptsb_ros.bags.recover` restores it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from types import TracebackType
from typing import IO, Any

from mcap.writer import CompressionType, Writer

from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.metadata import BagMetadata, FileInfo, TopicInfo, write_metadata
from bptsb_ros.bags.msgdefs import MessageDefinition, message_definition, normalize_type, type_description_hash
from bptsb_ros.bags.publishers import PUBLISHERS_RECORD, PublisherId, base_channel_metadata
from bptsb_ros.bags.qos import QosProfile, qos_profiles_to_yaml
from bptsb_ros.files.safe_write import UnsafeFileError, open_for_writing

DEFAULT_CHUNK_SIZE = 768 * 1024  # bytes, the rosbag2_storage_mcap default
DEFAULT_FLUSH_PERIOD_S = 1.0
COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


def _version(dist: str) -> str:
    try:
        return version(dist)
    except PackageNotFoundError:
        return "dev"


CUSTOM_DATA_RECORD = "bptsb_ros.custom_data"
LIBRARY = f"bptsb_ros {_version('bptsb_ros')} (rosbag2_storage_mcap layout), python mcap {_version('mcap')}"


def mcap_filename(bag_dir: Path, index: int = 0) -> str:
    """rosbag2's storage file name: ``<bag name>_<index>.mcap``."""
    return f"{bag_dir.name}_{index}.mcap"


def check_stream_options(chunk_size: int, compression: str) -> None:
    """Raise :class:`BagError` for an unknown ``compression`` or a non-positive ``chunk_size``."""
    if compression not in COMPRESSIONS:
        raise BagError(f"unknown chunk compression {compression!r}; choose one of {sorted(COMPRESSIONS)}")
    if chunk_size <= 0:
        raise BagError(f"chunk_size must be positive, got {chunk_size}")


class McapStream:
    """An MCAP ``ros2``-profile stream of schemas, channels and messages, with per-topic bookkeeping.

    Shared by :class:`BagWriter` and the recovery tool so both write identical files. Times are in ns. Channels
    are keyed by (topic, publisher GID), '' for the topic's plain channel; each is registered when its first
    message (or :meth:`add_channel`) needs it.
    """

    def __init__(
        self, stream: IO[bytes], *, chunk_size: int, compression: str, custom_data: dict[str, str] | None = None
    ) -> None:
        check_stream_options(chunk_size, compression)
        self._stream = stream
        self._writer = Writer(stream, chunk_size=chunk_size, compression=COMPRESSIONS[compression])
        self._writer.start(profile="ros2", library=LIBRARY)
        if custom_data:
            # Written up front so that a recovered bag keeps it; metadata.yaml gets it again on close.
            self._writer.add_metadata(CUSTOM_DATA_RECORD, dict(custom_data))
        self._schemas: dict[str, int] = {}
        self._topic_schema: dict[str, int] = {}
        self._topic_metadata: dict[str, dict[str, str]] = {}
        self._channels: dict[tuple[str, str], int] = {}
        self.topics: dict[str, TopicInfo] = {}
        #: publisher GID -> identity (the latest name known), for the ``bptsb_ros.publishers`` record
        self.publishers: dict[str, PublisherId] = {}
        #: messages per (topic, publisher GID), '' for messages without an identity
        self.channel_counts: dict[tuple[str, str], int] = {}
        self.start_ns: int | None = None
        self.end_ns: int | None = None
        self.message_count = 0

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        self._writer.add_metadata(name, dict(data))

    def add_schema(self, name: str, encoding: str, text: str) -> int:
        if name not in self._schemas:
            self._schemas[name] = self._writer.register_schema(name=name, encoding=encoding, data=text.encode())
        return self._schemas[name]

    def add_topic(self, info: TopicInfo, schema_id: int, metadata: dict[str, str]) -> None:
        """Add a topic (its channels are registered when needed); adding a known topic again is a no-op."""
        if info.name not in self.topics:
            self.topics[info.name] = info
            self._topic_schema[info.name] = schema_id
            self._topic_metadata[info.name] = base_channel_metadata(metadata)

    def add_channel(self, info: TopicInfo, schema_id: int, metadata: dict[str, str],
                    publisher: PublisherId | None = None) -> None:
        """Add the topic if new and register the channel of (topic, ``publisher``) now."""
        self.add_topic(info, schema_id, metadata)
        self._channel(info.name, publisher)

    def name_publisher(self, publisher: PublisherId) -> None:
        """Record (or update) the node name of a publisher GID for the ``bptsb_ros.publishers`` record."""
        known = self.publishers.get(publisher.gid)
        if known is None or publisher.node:
            self.publishers[publisher.gid] = publisher

    def _channel(self, topic: str, publisher: PublisherId | None) -> int:
        key = (topic, publisher.gid if publisher is not None else "")
        channel_id = self._channels.get(key)
        if channel_id is None:
            metadata = dict(self._topic_metadata[topic])
            if publisher is not None:
                metadata.update(publisher.channel_metadata())
                self.name_publisher(publisher)
            channel_id = self._channels[key] = self._writer.register_channel(
                topic=topic, message_encoding=self.topics[topic].serialization_format,
                schema_id=self._topic_schema[topic], metadata=metadata,
            )
        return channel_id

    def add_message(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int, sequence: int,
                    publisher: PublisherId | None = None) -> None:
        """Append one message to the channel of (topic, ``publisher``)."""
        if topic not in self.topics:
            raise BagError(f"topic {topic!r} was not added to the bag; call add_topic first")
        if log_time_ns < 0:
            raise BagError(f"negative timestamp {log_time_ns} ns on {topic}")
        self._writer.add_message(
            channel_id=self._channel(topic, publisher), log_time=log_time_ns, data=data,
            publish_time=publish_time_ns, sequence=sequence & 0xFFFFFFFF,
        )
        key = (topic, publisher.gid if publisher is not None else "")
        self.channel_counts[key] = self.channel_counts.get(key, 0) + 1
        self.topics[topic].message_count += 1
        self.message_count += 1
        self.start_ns = log_time_ns if self.start_ns is None else min(self.start_ns, log_time_ns)
        self.end_ns = log_time_ns if self.end_ns is None else max(self.end_ns, log_time_ns)

    def flush(self) -> None:
        """Close the open chunk (if it holds messages) and push everything to the OS."""
        self._writer.flush()

    def bag_metadata(self, relative_path: str, custom_data: dict[str, str]) -> BagMetadata:
        start = self.start_ns or 0
        duration = (self.end_ns - start) if self.end_ns is not None else 0
        return BagMetadata(
            starting_time_ns=start, duration_ns=duration, message_count=self.message_count,
            topics=list(self.topics.values()),
            files=[FileInfo(relative_path, start, duration, self.message_count)],
            custom_data=dict(custom_data),
        )

    def finish(self, metadata: BagMetadata, records: dict[str, dict[str, str]] | None = None) -> None:
        """Give every topic without a channel its plain one, write the ``bptsb_ros.publishers`` record (when a
        message had an identity), ``records`` (name -> string map), the ``rosbag2`` metadata record, the summary
        and the footer."""
        channelled = {topic for topic, _ in self._channels}
        for topic in self.topics:
            if topic not in channelled:
                self._channel(topic, None)
        if self.publishers:
            self._writer.add_metadata(PUBLISHERS_RECORD, {gid: p.name for gid, p in sorted(self.publishers.items())})
        for name, data in (records or {}).items():
            self._writer.add_metadata(name, dict(data))
        self._writer.add_metadata("rosbag2", {"serialized_metadata": metadata.to_yaml(root=False)})
        self._writer.finish()
        self._stream.flush()


class BagWriter:
    """Write a rosbag2 bag directory (storage ``mcap``, serialization ``cdr``).

    Example::

        with BagWriter("bags/run1") as bag:
            bag.add_topic("/clock", "rosgraph_msgs/msg/Clock", qos_profiles=[QosProfile(reliability="best_effort")])
            bag.write("/clock", cdr_bytes, log_time_ns=time.time_ns())

    :param bag_path: the bag directory to create; it must not exist or be empty.
    :param chunk_size: close a chunk once it holds this many uncompressed bytes.
    :param compression: chunk compression, ``"zstd"`` (default), ``"lz4"`` or ``"none"``.
    :param flush_period_s: also close the open chunk once this many seconds (of ``clock``) have passed since the
        last flush, bounding what a SIGKILL loses; ``None`` disables time-based flushing.
    :param custom_data: string key/values stored in ``custom_data`` of ``metadata.yaml``.
    :param clock: monotonic clock in seconds used for time-based flushing.
    """

    def __init__(
        self,
        bag_path: str | Path,
        *,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        compression: str = "zstd",
        flush_period_s: float | None = DEFAULT_FLUSH_PERIOD_S,
        custom_data: dict[str, str] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.path = Path(bag_path)
        if self.path.exists() and (not self.path.is_dir() or any(self.path.iterdir())):
            raise BagError(f"output bag {self.path} already exists and is not an empty directory")
        if flush_period_s is not None and flush_period_s <= 0:
            raise BagError(f"flush_period_s must be positive or None, got {flush_period_s}")
        check_stream_options(chunk_size, compression)  # before anything is created on disk
        created = not self.path.exists()
        self.path.mkdir(parents=True, exist_ok=True)
        self.mcap_path = self.path / mcap_filename(self.path)
        try:
            self._file = open_for_writing(self.mcap_path)  # closed in close()
        except UnsafeFileError as err:
            raise BagError(str(err)) from None
        try:
            self._mcap = McapStream(self._file, chunk_size=chunk_size, compression=compression,
                                    custom_data=custom_data)
        except BaseException:
            self._file.close()
            self.mcap_path.unlink(missing_ok=True)
            if created:
                self.path.rmdir()
            raise
        self._flush_period_s = flush_period_s
        self._clock = clock
        self._last_flush = clock()
        self._custom_data = dict(custom_data or {})
        self._closed = False

    @property
    def topics(self) -> dict[str, TopicInfo]:
        """Topics added so far, by name, with their current message counts."""
        return self._mcap.topics

    @property
    def message_count(self) -> int:
        return self._mcap.message_count

    @property
    def closed(self) -> bool:
        return self._closed

    def add_topic(
        self,
        name: str,
        msgtype: str,
        *,
        qos_profiles: list[QosProfile] | None = None,
        type_hash: str | None = None,
        definition: MessageDefinition | None = None,
    ) -> None:
        """Add a topic of type ``pkg/msg/Type``.

        ``qos_profiles`` are the publishers' offered profiles (default: one reliable, volatile, keep-last-10
        profile); ``type_hash`` defaults to the installed type description hash and ``definition`` to the full
        definition read from the installed ``.msg`` files. Adding a topic twice with the same type is a no-op.
        """
        self._check_open()
        if not name.startswith("/"):
            raise BagError(f"topic names must be absolute (start with '/'): {name!r}")
        msgtype = normalize_type(msgtype)
        existing = self._mcap.topics.get(name)
        if existing is not None:
            if existing.msgtype != msgtype:
                raise BagError(f"topic {name} already added with type {existing.msgtype}, not {msgtype}")
            return
        definition = definition or message_definition(msgtype)
        profiles = list(qos_profiles) if qos_profiles is not None else [QosProfile()]
        info = TopicInfo(
            name=name, msgtype=msgtype, offered_qos_profiles=profiles,
            type_description_hash=type_description_hash(msgtype) if type_hash is None else type_hash,
        )
        schema_id = self._mcap.add_schema(msgtype, definition.encoding, definition.text)
        self._mcap.add_topic(info, schema_id, {
            "offered_qos_profiles": qos_profiles_to_yaml(profiles),
            "topic_type_hash": info.type_description_hash,
        })

    def write(
        self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int | None = None, sequence: int = 0,
        publisher: PublisherId | None = None,
    ) -> None:
        """Append one CDR-serialized message; ``log_time_ns`` is the receive time (ns), ``publish_time_ns``
        the send time (defaults to the receive time), ``sequence`` the publisher's sequence number and
        ``publisher`` who sent it (its channel of the topic; None: the topic's plain channel)."""
        self._check_open()
        self._mcap.add_message(
            topic, bytes(data), int(log_time_ns),
            int(log_time_ns if publish_time_ns is None else publish_time_ns), int(sequence), publisher,
        )
        self.flush_if_due()

    def name_publisher(self, publisher: PublisherId) -> None:
        """Tell the bag the node name of a publisher GID learnt after its first message (the closing
        ``bptsb_ros.publishers`` record keeps it)."""
        self._check_open()
        self._mcap.name_publisher(publisher)

    @property
    def publisher_counts(self) -> dict[tuple[str, str], int]:
        """Messages written per (topic, publisher GID), '' for those without an identity."""
        return dict(self._mcap.channel_counts)

    def set_custom_data(self, values: dict[str, str]) -> None:
        """Add or replace ``custom_data`` entries of ``metadata.yaml`` (written on close)."""
        self._check_open()
        self._custom_data.update({str(k): str(v) for k, v in values.items()})

    def write_message(self, topic: str, msg: Any, log_time_ns: int) -> None:
        """Serialize an rclpy message object with CDR and append it; adds the topic from the message type if new."""
        from rclpy.serialization import serialize_message

        if topic not in self._mcap.topics:
            cls = type(msg)
            pkg, namespace = cls.__module__.split(".")[:2]
            self.add_topic(topic, f"{pkg}/{namespace}/{cls.__name__}")
        self.write(topic, serialize_message(msg), log_time_ns)

    def flush_if_due(self) -> bool:
        """Flush if ``flush_period_s`` has passed since the last flush; return whether it flushed."""
        if self._closed or self._flush_period_s is None:
            return False
        if self._clock() - self._last_flush < self._flush_period_s:
            return False
        self.flush()
        return True

    def flush(self) -> None:
        """Close the open chunk and hand everything written so far to the OS (survives a SIGKILL)."""
        self._check_open()
        self._mcap.flush()
        self._last_flush = self._clock()

    def metadata(self) -> BagMetadata:
        """The bag metadata as of now."""
        return self._mcap.bag_metadata(self.mcap_path.name, self._custom_data)

    def close(self, records: dict[str, dict[str, str]] | None = None) -> BagMetadata:
        """Finish the MCAP file (``records``: extra metadata records, name -> string map; summary, indexes,
        footer) and write ``metadata.yaml``. Idempotent."""
        if self._closed:
            return self.metadata()
        metadata = self.metadata()
        try:
            self._mcap.finish(metadata, records)
        finally:
            self._file.close()
            self._closed = True
        write_metadata(self.path, metadata)
        return metadata

    def _check_open(self) -> None:
        if self._closed:
            raise BagError(f"bag {self.path} is already closed")

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
