"""tacforce_ros.estimation"""
