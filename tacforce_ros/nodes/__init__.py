"""tacforce_ros.nodes"""
