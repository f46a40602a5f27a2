"""ROS 2 nodes of bptsb_ros: thin rclpy adapters over the ROS-free core."""
