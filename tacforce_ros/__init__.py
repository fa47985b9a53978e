"""tacforce_ros: tactile force estimation and fingertip force control (see README.md)."""
