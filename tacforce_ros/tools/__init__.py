"""tacforce_ros.tools"""
