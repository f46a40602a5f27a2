"""ROS 2 nodes of bptsb_ros: thin rclpy adapters over the ROS-free core (:mod:`bptsb_ros.live`, whose
``channels`` and ``safety`` modules hold the command rules).

Nodes (each a module with ``main(args=None) -> int``, run as ``python -m bptsb_ros.ros.<node>``,
``bptsb run <node>`` or ``ros2 run bptsb_ros <node>``): ``body_sim``, ``swg_brain``,
``feedback_brain``, ``mlp_brain``, ``task_input``, ``recorder``. Shared pieces: ``topics`` (names,
stamps; ROS-free), ``messages`` (QoS, conversions), ``params`` (declared, validated parameters),
``agent_source`` (which agent a node runs), ``brain_node`` and ``runtime`` (node skeleton and process
lifecycle). ``TOPICS.md`` documents every topic. This package imports nothing at import time, so ROS-free
modules stay so.
"""
