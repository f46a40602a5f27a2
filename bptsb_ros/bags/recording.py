"""ROS-free logic of the recorder node: its parameters, which topics to record, and with which QoS.

The node (:mod:`bptsb_ros.ros.recorder`) is a thin rclpy adapter over this module and
:class:`bptsb_ros.bags.writer.BagWriter`, so everything here is testable without a ROS graph.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from bptsb_ros.bags.qos import QosProfile
from bptsb_ros.bags.writer import COMPRESSIONS, DEFAULT_CHUNK_SIZE, DEFAULT_FLUSH_PERIOD_S
from bptsb_ros.ros.params import LOG_LEVEL, Param, ParameterError

RECORDER_PARAMS: tuple[Param, ...] = (
    Param("bag_path", "", "Output bag directory (created; must not exist or be empty). Required.", "str"),
    Param("topics", [], "Topics to record (relative names resolve in the recorder's namespace); an empty list "
          "records every topic discovered.", "str_list"),
    Param("exclude_topics", [], "Topics never recorded, also when recording all topics.", "str_list"),
    Param("include_hidden_topics", False, "When recording all topics, also record hidden ones (a name part "
          "starting with '_').", "bool"),
    Param("discovery_period", 0.1, "Seconds between two looks at the ROS graph for new topics.", "float",
          positive=True),
    Param("chunk_size", DEFAULT_CHUNK_SIZE, "MCAP chunk size in bytes (uncompressed) at which a chunk is closed.",
          "int", minimum=1024),
    Param("compression", "zstd", "MCAP chunk compression.", "str", choices=tuple(COMPRESSIONS)),
    Param("flush_period", DEFAULT_FLUSH_PERIOD_S, "Seconds after which the open chunk is closed and written "
          "even if not full: at most this much is lost if the recorder is killed outright.", "float",
          positive=True),
    Param("queue_depth", 0, "History depth of each subscription (messages); 0 keeps all, so that a burst the "
          "executor has not taken yet is never overwritten.", "int", minimum=0),
    Param("drain_quiet", 0.2, "On SIGINT/SIGTERM, keep taking in-flight messages until a wait of this many "
          "seconds brings none (bounded by stop_timeout).", "float", positive=True),
    Param("stop_timeout", 8.0, "Longest time in seconds spent taking in-flight messages after SIGINT/SIGTERM "
          "before the bag is closed (below the launcher's default --grace of 10 s).", "float", positive=True),
    Param("custom_data", [], "'key=value' strings stored in custom_data of metadata.yaml (the recorder adds "
          "log_time: sim or system).", "str_list"),
    LOG_LEVEL,
)


@dataclass(frozen=True)
class RecorderConfig:
    """Validated recorder parameters (see :data:`RECORDER_PARAMS`; times in s, sizes in bytes)."""

    bag_path: str
    topics: tuple[str, ...]
    exclude_topics: frozenset[str]
    include_hidden_topics: bool
    discovery_period: float
    chunk_size: int
    compression: str
    flush_period: float
    queue_depth: int
    drain_quiet: float
    stop_timeout: float
    custom_data: dict[str, str]

    @classmethod
    def from_values(cls, values: dict[str, Any], namespace: str = "/") -> RecorderConfig:
        """Build from validated parameter values (relative topic names resolve in ``namespace``, the node's);
        raise :class:`ParameterError` for a bad value."""
        bag_path = str(values["bag_path"]).strip()
        if not bag_path:
            raise ParameterError("parameter 'bag_path' is required (e.g. -p bag_path:=bags/run1)")
        return cls(
            bag_path=bag_path,
            topics=tuple(dict.fromkeys(absolute_topic(t, "topics", namespace) for t in values["topics"])),
            exclude_topics=frozenset(absolute_topic(t, "exclude_topics", namespace) for t in values["exclude_topics"]),
            include_hidden_topics=bool(values["include_hidden_topics"]),
            discovery_period=float(values["discovery_period"]),
            chunk_size=int(values["chunk_size"]),
            compression=str(values["compression"]),
            flush_period=float(values["flush_period"]),
            queue_depth=int(values["queue_depth"]),
            drain_quiet=float(values["drain_quiet"]),
            stop_timeout=float(values["stop_timeout"]),
            custom_data=parse_custom_data(values["custom_data"]),
        )


def absolute_topic(name: str, param: str = "topics", namespace: str = "/") -> str:
    """``name`` as an absolute topic name (a relative name resolves in ``namespace``); raise for a bad name."""
    name = name.strip()
    if not name or name == "/" or any(c.isspace() for c in name) or "//" in name or name.endswith("/"):
        raise ParameterError(f"parameter '{param}': {name!r} is not a valid topic name")
    if name.startswith("/"):
        return name
    return namespace.rstrip("/") + "/" + name


def parse_custom_data(items: Iterable[str]) -> dict[str, str]:
    """Parse ``key=value`` strings; raise :class:`ParameterError` for an item without ``=`` or an empty key."""
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ParameterError(f"parameter 'custom_data': {item!r} is not of the form key=value")
        out[key.strip()] = value
    return out


def is_hidden(topic: str) -> bool:
    """ROS hides topics with a name part that starts with an underscore."""
    return any(part.startswith("_") for part in topic.split("/"))


def select_topics(
    discovered: Iterable[tuple[str, list[str]]], config: RecorderConfig
) -> dict[str, list[str]]:
    """The discovered ``(topic, types)`` pairs that ``config`` asks to record, as ``{topic: types}``."""
    selected = {}
    for topic, types in discovered:
        if topic in config.exclude_topics or not types:
            continue
        if config.topics:
            if topic not in config.topics:
                continue
        elif is_hidden(topic) and not config.include_hidden_topics:
            continue
        selected[topic] = list(types)
    return selected


def subscription_policies(offered: list[QosProfile]) -> tuple[str, str]:
    """``(reliability, durability)`` to request so that every publisher is matched (rosbag2's rule).

    Reliable only if every publisher offers reliable, transient-local only if every one offers it.
    """
    if not offered:
        return "reliable", "volatile"
    reliability = "reliable" if all(p.reliability == "reliable" for p in offered) else "best_effort"
    durability = "transient_local" if all(p.durability == "transient_local" for p in offered) else "volatile"
    return reliability, durability


def incompatible_offers(offered: list[QosProfile], requested: tuple[str, str]) -> list[QosProfile]:
    """The offered profiles a subscription with ``requested = (reliability, durability)`` cannot match."""
    reliability, durability = requested
    return [
        p for p in offered
        if (reliability == "reliable" and p.reliability == "best_effort")
        or (durability == "transient_local" and p.durability == "volatile")
    ]
