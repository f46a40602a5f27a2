"""Who published each recorded message (ROS-free): publisher identities in the MCAP file of a bag.

DDS tells a subscriber, per message, the GID of the writer that sent it (``rmw_message_info_t.publisher_gid``),
and the ROS graph maps a GID to its node (``get_publishers_info_by_topic``: ``endpoint_gid``, node name and
namespace). The recorder (:mod:`bptsb_ros.ros.recorder`) keeps both, in a layout every MCAP reader reads:

* **one MCAP channel per (topic, publisher)**: the usual rosbag2 channel metadata (``offered_qos_profiles``,
  ``topic_type_hash``) plus ``publisher_gid`` (the 16 GID bytes as dotted hex, as ``ros2 topic info -v`` prints
  them), ``publisher_node`` and ``publisher_namespace`` (as the graph named the publisher when its first message
  arrived; empty if the graph had not named it yet). A message's channel says who sent it. Readers that merge by
  topic (Foxglove, ``ros2 bag play``, rosbags) see the topic's messages as usual.
* a metadata record ``bptsb_ros.publishers`` (written when the bag is closed): GID -> fully qualified node name
  (``/namespace/node``) as finally known; it names publishers the graph had not named yet at their first message.

A channel without ``publisher_gid`` (a bag recorded before this layout, by ``ros2 bag record``, or written
without identities) holds messages whose publisher is unknown: readers report that publishers cannot be checked.
Node names are not authenticated (anyone on the domain can name a node ``body_sim``; SROS2 authenticates), but
GIDs keep two publishers apart even when they share a name.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

GID_KEY = "publisher_gid"
NODE_KEY = "publisher_node"
NAMESPACE_KEY = "publisher_namespace"
PUBLISHER_KEYS = (GID_KEY, NODE_KEY, NAMESPACE_KEY)
PUBLISHERS_RECORD = "bptsb_ros.publishers"
#: what the ROS graph reports as the node name of an endpoint whose node it has not discovered yet
UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"
#: longest GID text / node name kept from a bag (untrusted data)
MAX_NAME = 256


def gid_text(raw: bytes | bytearray | list[int]) -> str:
    """GID bytes as dotted lowercase hex (``01.0f.78...``), the form ``ros2 topic info -v`` prints."""
    return bytes(raw).hex(".")


def full_name(namespace: str, node: str) -> str:
    """Fully qualified node name: ``/node`` in the root namespace, ``/ns/node`` else; '' for an unnamed node."""
    if not node or node == UNKNOWN_NODE:
        return ""
    return f"{namespace.rstrip('/')}/{node}"


def split_name(name: str) -> tuple[str, str]:
    """``/ns/node`` -> (``/ns``, ``node``); ``/node`` -> (``/``, ``node``); '' -> ('', '')."""
    if not name:
        return "", ""
    namespace, _, node = name.rpartition("/")
    return namespace or "/", node


@dataclass(frozen=True)
class PublisherId:
    """One publisher (DDS writer) of a topic: ``gid`` dotted hex, its node's ``node`` name and ``namespace``
    (both '' when the graph has not named it)."""

    gid: str
    node: str = ""
    namespace: str = ""

    @property
    def name(self) -> str:
        """Fully qualified node name, or ``unnamed publisher <gid>`` when the node is unknown."""
        return full_name(self.namespace, self.node) or f"unnamed publisher {self.gid}"

    def channel_metadata(self) -> dict[str, str]:
        """The channel metadata entries of this publisher."""
        return {GID_KEY: self.gid, NODE_KEY: self.node, NAMESPACE_KEY: self.namespace}

    def renamed(self, name: str) -> PublisherId:
        """This publisher with the fully qualified node ``name`` (kept as is when ``name`` is empty)."""
        if not name:
            return self
        namespace, node = split_name(name)
        return PublisherId(self.gid, node, namespace)

    @classmethod
    def from_channel_metadata(cls, metadata: Mapping[str, str]) -> PublisherId | None:
        """The publisher a channel's metadata names, or None for a channel without ``publisher_gid``."""
        gid = str(metadata.get(GID_KEY, ""))[:MAX_NAME]
        if not gid:
            return None
        node = str(metadata.get(NODE_KEY, ""))[:MAX_NAME]
        return cls(gid, "" if node == UNKNOWN_NODE else node, str(metadata.get(NAMESPACE_KEY, ""))[:MAX_NAME])


def base_channel_metadata(metadata: Mapping[str, str]) -> dict[str, str]:
    """A channel's metadata without the publisher entries (what every channel of the topic shares)."""
    return {k: v for k, v in metadata.items() if k not in PUBLISHER_KEYS}


def names_from_record(record: Mapping[str, str]) -> dict[str, str]:
    """GID -> fully qualified node name from a ``bptsb_ros.publishers`` record (bounded, untrusted)."""
    return {str(gid)[:MAX_NAME]: str(name)[:MAX_NAME] for gid, name in record.items() if str(name).startswith("/")}
