"""An installed executable started with --ros-args --params-file takes its parameters from the file
(and only from it: nothing is given with -p here)."""
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
import yaml
from geometry_msgs.msg import Vector3Stamped
from rclpy.qos import QoSProfile, ReliabilityPolicy

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import executable, spin_until, start, stop, unique_domain_id  # noqa: E402

RATE_HZ = 40.0            # differs from the node's default (100 Hz)
FRAME = 'params_file_frame'   # differs from the default (the sequence's own frame)


@pytest.mark.ros
def test_parameters_come_from_the_params_file(tmp_path):
    sequence = tmp_path / 'constant.yaml'
    sequence.write_text(yaml.safe_dump({'frame_id': 'ft_sensor', 'segments': [
        {'duration': 30.0, 'force': [0.1, -0.2, -1.5]}]}))
    params = tmp_path / 'params.yaml'
    params.write_text(yaml.safe_dump({'command_player': {'ros__parameters': {
        'sequence': str(sequence), 'rate_hz': RATE_HZ, 'frame_id': FRAME, 'autostart': True}}}))
    domain = unique_domain_id(offset=11)
    rclpy.init(domain_id=domain)
    node = rclpy.create_node('params_file_listener')
    received = []
    node.create_subscription(Vector3Stamped, '/force_controller/desired', received.append,
                             QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    proc = start([executable('command_player'), '--ros-args', '--params-file', params], domain)
    try:
        assert spin_until(node, lambda: len(received) >= 3, 30.0), 'no command arrived'
        first = len(received)
        started = time.monotonic()
        spin_until(node, lambda: False, 2.0)
        rate = (len(received) - first) / (time.monotonic() - started)
    finally:
        output = stop(proc)
        node.destroy_node()
        rclpy.shutdown()
    assert {m.header.frame_id for m in received} == {FRAME}, output
    np.testing.assert_allclose([received[-1].vector.x, received[-1].vector.y,
                                received[-1].vector.z], [0.1, -0.2, -1.5])
    # 40 Hz from the file, not the 100 Hz default (wide band: the machine is shared).
    assert 25.0 < rate < 55.0, f'measured {rate:.1f} Hz'
