"""The ROS-free interface of the live nodes: parameter specs and their validation (:mod:`~.params`), the topic
table and stamp arithmetic (:mod:`~.topics`), and the source parameters that name a node's agent
(:mod:`~.source`). ``live/``, ``bags/``, ``analysis/`` and ``ros/`` read them; nothing here imports rclpy.
"""
