"""rclpy nodes, thin over the pipeline stages, and the launcher/player that replace ros2 launch/bag play."""
