"""tacforce_ros.bringup: starting and stopping a session's processes (no rclpy here)."""
