"""tacforce_ros.recording: recording helpers without ROS (approximate-time synchroniser,
bag writing from serialised messages)."""
