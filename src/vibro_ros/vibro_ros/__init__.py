"""ROS 2 plumbing of vibro: topics, QoS, node support, bag I/O (imports rclpy; algorithm packages never do)."""
