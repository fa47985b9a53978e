"""tacforce_ros.hand"""
