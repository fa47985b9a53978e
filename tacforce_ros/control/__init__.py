"""tacforce_ros.control"""
