"""rosbag2-compatible MCAP bags without a ROS installation: write, read, inspect and recover.

A bag is a directory ``<name>/`` holding ``metadata.yaml`` (rosbag2 Jazzy format, version 9) and
``<name>_0.mcap`` (profile ``ros2``, ``cdr`` messages, ``ros2msg`` schemas with full definitions, chunked and
indexed), readable by ``ros2 bag``, Foxglove, the ``mcap`` library and ``rosbags``.

- :class:`BagWriter` (:mod:`.writer`) writes one; the recorder node (:mod:`bptsb_ros.ros.recorder`) uses it.
- :func:`read_messages`, :func:`read_arrays`, :func:`bag_info` (:mod:`.reader`) read one back, decoding messages
  with rclpy where it is installed and with rosbags from the bag's own schemas where it is not (:mod:`.decode`).
- :func:`recover_bag` (:mod:`.recover`) rebuilds one left unfinished by a killed recorder.
"""

from bptsb_ros.bags.errors import BagError, MessageDefinitionError
from bptsb_ros.bags.metadata import BagMetadata, TopicInfo, read_metadata
from bptsb_ros.bags.qos import QosProfile
from bptsb_ros.bags.reader import BagInfo, BagMessage, TopicSeries, bag_info, read_arrays, read_messages
from bptsb_ros.bags.recover import RecoveryReport, recover_bag
from bptsb_ros.bags.writer import BagWriter

__all__ = [
    "BagError", "BagInfo", "BagMessage", "BagMetadata", "BagWriter", "MessageDefinitionError", "QosProfile",
    "RecoveryReport", "TopicInfo", "TopicSeries", "bag_info", "read_arrays", "read_messages", "read_metadata",
    "recover_bag",
]
