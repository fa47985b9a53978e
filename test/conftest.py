"""Suite-wide test settings: deterministic hypothesis runs, and ROS 2 kept on this host."""
import os

from hypothesis import HealthCheck, settings

# Property tests are seeded (derandomize) so CI runs are reproducible; no per-example deadline
# because the CI machine is shared and timing is measured by the benchmark commands instead.
settings.register_profile('tacforce', derandomize=True, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get('HYPOTHESIS_PROFILE', 'tacforce'))

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('MPLBACKEND', 'Agg')
