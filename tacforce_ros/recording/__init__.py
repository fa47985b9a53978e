"""tacforce_ros.recording: recording helpers without ROS (approximate-time synchroniser, serialised-message bag writing)."""
