"""QoS profiles in the form rosbag2 Jazzy stores them (metadata version 9: policy names, not numbers)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import yaml

from bptsb_ros.bags.errors import BagError
from bptsb_ros.files.untrusted_yaml import UntrustedYamlError, bounded_repr, load_untrusted_yaml

NS_PER_S = 1_000_000_000
#: RMW_DURATION_INFINITE (ns); written as ``{sec: 9223372036, nsec: 854775807}``.
INFINITE_NS = 2**63 - 1

# rmw enum values, for reading metadata written before version 9 (numbers instead of names).
_HISTORY = {0: "system_default", 1: "keep_last", 2: "keep_all", 3: "unknown"}
_RELIABILITY = {0: "system_default", 1: "reliable", 2: "best_effort", 3: "unknown", 4: "best_available"}
_DURABILITY = {0: "system_default", 1: "transient_local", 2: "volatile", 3: "unknown", 4: "best_available"}
_LIVELINESS = {0: "system_default", 1: "automatic", 3: "manual_by_topic", 4: "unknown", 5: "best_available"}
# Durations some Foxy-era RMWs reported for "infinite"; rosbag2 maps them to RMW_DURATION_INFINITE too.
_FOXY_INFINITE = {(0x7FFFFFFF, 0xFFFFFFFF), (0x7FFFFFFF, 0x7FFFFFFF)}


@dataclass(frozen=True)
class QosProfile:
    """One offered QoS profile. Durations are in nanoseconds; 0 means the RMW default."""

    history: str = "keep_last"
    depth: int = 10
    reliability: str = "reliable"
    durability: str = "volatile"
    deadline_ns: int = 0
    lifespan_ns: int = 0
    liveliness: str = "system_default"
    liveliness_lease_duration_ns: int = 0
    avoid_ros_namespace_conventions: bool = False

    def to_dict(self) -> dict[str, Any]:
        """Return the rosbag2 v9 mapping (key order as rosbag2 writes it)."""
        return {
            "history": self.history,
            "depth": self.depth,
            "reliability": self.reliability,
            "durability": self.durability,
            "deadline": _duration_to_dict(self.deadline_ns),
            "lifespan": _duration_to_dict(self.lifespan_ns),
            "liveliness": self.liveliness,
            "liveliness_lease_duration": _duration_to_dict(self.liveliness_lease_duration_ns),
            "avoid_ros_namespace_conventions": self.avoid_ros_namespace_conventions,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> QosProfile:
        """Parse a rosbag2 QoS mapping of any metadata version (policy names or rmw enum numbers)."""
        try:
            return cls(
                history=_policy(data["history"], _HISTORY),
                depth=int(data["depth"]),
                reliability=_policy(data["reliability"], _RELIABILITY),
                durability=_policy(data["durability"], _DURABILITY),
                deadline_ns=_duration_from_dict(data["deadline"]),
                lifespan_ns=_duration_from_dict(data["lifespan"]),
                liveliness=_policy(data["liveliness"], _LIVELINESS),
                liveliness_lease_duration_ns=_duration_from_dict(data["liveliness_lease_duration"]),
                avoid_ros_namespace_conventions=bool(data["avoid_ros_namespace_conventions"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise BagError(f"malformed QoS profile {bounded_repr(data)}: {bounded_repr(exc)}") from None

    @classmethod
    def from_rclpy(cls, profile: Any) -> QosProfile:
        """Convert an ``rclpy.qos.QoSProfile`` (duck-typed: enum ``.name`` and ``Duration.nanoseconds``)."""
        return cls(
            history=profile.history.name.lower(),
            depth=int(profile.depth),
            reliability=profile.reliability.name.lower(),
            durability=profile.durability.name.lower(),
            deadline_ns=int(profile.deadline.nanoseconds),
            lifespan_ns=int(profile.lifespan.nanoseconds),
            liveliness=profile.liveliness.name.lower(),
            liveliness_lease_duration_ns=int(profile.liveliness_lease_duration.nanoseconds),
            avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
        )


def _policy(value: Any, numbers: dict[int, str]) -> str:
    if isinstance(value, bool):
        raise ValueError(f"bad QoS policy {value!r}")
    if isinstance(value, int):
        return numbers.get(value, "unknown")
    return str(value).lower()


def _duration_to_dict(ns: int) -> dict[str, int]:
    return {"sec": ns // NS_PER_S, "nsec": ns % NS_PER_S}


def _duration_from_dict(data: dict[str, Any]) -> int:
    sec, nsec = int(data["sec"]), int(data["nsec"])
    if (sec, nsec) in _FOXY_INFINITE or sec * NS_PER_S + nsec >= INFINITE_NS:
        return INFINITE_NS
    return sec * NS_PER_S + nsec


def qos_profiles_to_list(profiles: list[QosProfile]) -> list[dict[str, Any]]:
    """The ``offered_qos_profiles`` value of ``metadata.yaml`` (version 9: a YAML list)."""
    return [p.to_dict() for p in profiles]


def qos_profiles_to_yaml(profiles: list[QosProfile]) -> str:
    """The ``offered_qos_profiles`` MCAP channel metadata value: the same list, serialized as YAML text."""
    if not profiles:
        return ""
    return yaml.safe_dump(qos_profiles_to_list(profiles), sort_keys=False, default_flow_style=False).rstrip("\n")


def qos_profiles_from_value(value: Any) -> list[QosProfile]:
    """Parse ``offered_qos_profiles`` given as a YAML list (v9), YAML text (v4–v8 and MCAP metadata) or empty."""
    if value in (None, ""):
        return []
    if isinstance(value, str):
        try:  # untrusted bag data: bounded size and alias expansion
            value = load_untrusted_yaml(value, "offered_qos_profiles")
        except UntrustedYamlError as exc:
            raise BagError(str(exc)) from None
        if value is None:
            return []
    if not isinstance(value, list):
        raise BagError(f"offered_qos_profiles must be a list, got {type(value).__name__}")
    return [QosProfile.from_dict(item) for item in value]
