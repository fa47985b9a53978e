"""tacforce_ros.sim"""
