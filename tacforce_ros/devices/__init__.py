"""tacforce_ros.devices"""
