"""``metadata.yaml`` of a rosbag2 bag directory, in the format rosbag2 Jazzy writes (version 9)."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any

import yaml

from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.qos import QosProfile, qos_profiles_from_value, qos_profiles_to_list
from bptsb_ros.files.safe_write import write_atomic
from bptsb_ros.files.untrusted_yaml import UntrustedYamlError, bounded_repr, load_untrusted_yaml

METADATA_FILENAME = "metadata.yaml"
METADATA_VERSION = 9
ROOT_KEY = "rosbag2_bagfile_information"
MAX_METADATA_BYTES = 16 << 20
"""Largest ``metadata.yaml`` read [bytes]."""
MAX_METADATA_NODES = 1_000_000
"""Most YAML nodes a ``metadata.yaml`` may expand to (aliases counted at every use)."""


@dataclass
class TopicInfo:
    """One recorded topic: name, ``pkg/msg/Type``, offered QoS profiles, RIHS01 type hash, message count."""

    name: str
    msgtype: str
    message_count: int = 0
    offered_qos_profiles: list[QosProfile] = field(default_factory=list)
    type_description_hash: str = ""
    serialization_format: str = "cdr"


@dataclass
class FileInfo:
    """One storage file of the bag; times in nanoseconds (start since the Unix epoch)."""

    path: str
    starting_time_ns: int
    duration_ns: int
    message_count: int


@dataclass
class BagMetadata:
    """Content of ``metadata.yaml``; times in nanoseconds (start since the Unix epoch)."""

    starting_time_ns: int
    duration_ns: int
    message_count: int
    topics: list[TopicInfo]
    files: list[FileInfo]
    storage_identifier: str = "mcap"
    compression_format: str = ""
    compression_mode: str = ""
    custom_data: dict[str, str] = field(default_factory=dict)
    ros_distro: str = field(default_factory=lambda: os.environ.get("ROS_DISTRO", "jazzy"))
    version: int = METADATA_VERSION

    @property
    def relative_file_paths(self) -> list[str]:
        return [f.path for f in self.files]

    @property
    def end_time_ns(self) -> int:
        return self.starting_time_ns + self.duration_ns

    def to_dict(self) -> dict[str, Any]:
        """The mapping under ``rosbag2_bagfile_information`` (also the MCAP ``rosbag2`` metadata record)."""
        return {
            "version": self.version,
            "storage_identifier": self.storage_identifier,
            "duration": {"nanoseconds": self.duration_ns},
            "starting_time": {"nanoseconds_since_epoch": self.starting_time_ns},
            "message_count": self.message_count,
            "topics_with_message_count": [
                {
                    "topic_metadata": {
                        "name": t.name,
                        "type": t.msgtype,
                        "serialization_format": t.serialization_format,
                        "offered_qos_profiles": qos_profiles_to_list(t.offered_qos_profiles),
                        "type_description_hash": t.type_description_hash,
                    },
                    "message_count": t.message_count,
                }
                for t in self.topics
            ],
            "compression_format": self.compression_format,
            "compression_mode": self.compression_mode,
            "relative_file_paths": self.relative_file_paths,
            "files": [
                {
                    "path": f.path,
                    "starting_time": {"nanoseconds_since_epoch": f.starting_time_ns},
                    "duration": {"nanoseconds": f.duration_ns},
                    "message_count": f.message_count,
                }
                for f in self.files
            ],
            "custom_data": dict(self.custom_data) or None,
            "ros_distro": self.ros_distro,
        }

    def to_yaml(self, *, root: bool = True) -> str:
        """Serialize; ``root=False`` leaves out the ``rosbag2_bagfile_information`` key (MCAP metadata record)."""
        data = {ROOT_KEY: self.to_dict()} if root else self.to_dict()
        return yaml.safe_dump(data, sort_keys=False, default_flow_style=False)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> BagMetadata:
        """Parse the mapping under ``rosbag2_bagfile_information`` (rosbag2 metadata versions 4 to 9)."""
        try:
            version = int(data["version"])
            topics = [
                TopicInfo(
                    name=str(item["topic_metadata"]["name"]),
                    msgtype=str(item["topic_metadata"]["type"]),
                    message_count=int(item["message_count"]),
                    offered_qos_profiles=qos_profiles_from_value(item["topic_metadata"].get("offered_qos_profiles")),
                    type_description_hash=str(item["topic_metadata"].get("type_description_hash") or ""),
                    serialization_format=str(item["topic_metadata"]["serialization_format"]),
                )
                for item in data.get("topics_with_message_count") or []
            ]
            if data.get("files"):
                files = [
                    FileInfo(
                        path=str(f["path"]),
                        starting_time_ns=int(f["starting_time"]["nanoseconds_since_epoch"]),
                        duration_ns=int(f["duration"]["nanoseconds"]),
                        message_count=int(f["message_count"]),
                    )
                    for f in data["files"]
                ]
            else:  # versions before 5 list only the paths
                files = [FileInfo(str(p), 0, 0, 0) for p in data.get("relative_file_paths") or []]
            return cls(
                starting_time_ns=int(data["starting_time"]["nanoseconds_since_epoch"]),
                duration_ns=int(data["duration"]["nanoseconds"]),
                message_count=int(data["message_count"]),
                topics=topics,
                files=files,
                storage_identifier=str(data["storage_identifier"]),
                compression_format=str(data.get("compression_format") or ""),
                compression_mode=str(data.get("compression_mode") or ""),
                custom_data={str(k): str(v) for k, v in (data.get("custom_data") or {}).items()},
                ros_distro=str(data.get("ros_distro") or ""),
                version=version,
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise BagError(f"malformed rosbag2 metadata: missing or bad field {bounded_repr(exc, 120)}") from None


def write_metadata(bag_dir: str | Path, metadata: BagMetadata) -> Path:
    """Write ``<bag_dir>/metadata.yaml`` atomically (:func:`~bptsb_ros.files.safe_write.write_atomic`: a regular file
    only, a temporary file + rename) and return its path."""
    return write_atomic(Path(bag_dir) / METADATA_FILENAME, metadata.to_yaml())


def read_metadata(bag_dir: str | Path) -> BagMetadata:
    """Read ``<bag_dir>/metadata.yaml``; raise :class:`BagError` with a hint when it is missing or malformed."""
    bag_dir = Path(bag_dir)
    path = bag_dir / METADATA_FILENAME
    if not bag_dir.is_dir():
        raise BagError(f"bag directory not found: {bag_dir}")
    if not path.is_file():
        raise BagError(
            f"{path} is missing: the recording was not finalized (recorder killed?). "
            f"Run `bptsb bag recover {bag_dir}` to rebuild it from the readable chunks."
        )
    hint = f"run `bptsb bag recover {bag_dir}` to rebuild it from the .mcap file"
    try:
        data = load_untrusted_yaml(path.read_bytes(), str(path), max_bytes=MAX_METADATA_BYTES,
                                   max_nodes=MAX_METADATA_NODES)
    except UntrustedYamlError as exc:
        raise BagError(f"{exc}; {hint}") from None
    except OSError as exc:
        raise BagError(f"cannot read {path}: {exc.strerror or exc}") from None
    if not isinstance(data, dict) or not isinstance(data.get(ROOT_KEY), dict):
        raise BagError(f"{path} has no '{ROOT_KEY}' mapping (not rosbag2 metadata); {hint}")
    try:
        return BagMetadata.from_dict(data[ROOT_KEY])
    except BagError as exc:
        raise BagError(f"{path}: {exc}; {hint}") from None


def bag_file(bag_dir: str | Path, relative: str) -> Path:
    """The storage file that ``metadata.yaml`` names ``relative`` (data, never a path to follow anywhere), inside
    ``bag_dir``. Raise :class:`BagError` for a name that is empty, absolute, has a ``..`` part, or resolves
    (through symbolic links) outside the bag directory: ``bag info`` and ``replay`` never read such a file."""
    bag_dir = Path(bag_dir)
    text = str(relative)
    parts = PurePosixPath(text).parts + PureWindowsPath(text).parts
    if (not text.strip() or "\0" in text or PurePosixPath(text).is_absolute() or PureWindowsPath(text).is_absolute()
            or PureWindowsPath(text).drive or ".." in parts):
        raise BagError(f"{bag_dir / METADATA_FILENAME} lists the storage file {bounded_repr(text, 120)}, which is "
                       "not a file name inside the bag directory; refusing to read it")
    path = bag_dir / text
    try:
        inside = path.resolve().is_relative_to(bag_dir.resolve())
    except (OSError, RuntimeError):  # a symbolic link loop
        inside = False
    if not inside:
        raise BagError(f"{bag_dir / METADATA_FILENAME} lists the storage file {bounded_repr(text, 120)}, which leads "
                       "outside the bag directory (a symbolic link); refusing to read it")
    return path
