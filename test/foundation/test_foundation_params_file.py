"""An installed executable started with --ros-args --params-file takes its parameters from the file
(and only from it: nothing is given with -p here).

The node is asked for its parameter values over its own ~/get_parameters service, and what it
publishes is checked against them; no rate is timed (a shared machine stalls, the values do not).
"""
import sys
from pathlib import Path

import numpy as np
import pytest
import rclpy
import yaml
from geometry_msgs.msg import Vector3Stamped
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import GetParameters
from rclpy.qos import QoSProfile, ReliabilityPolicy

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import (call_service, executable, spin_until, start, stop,  # noqa: E402
                           unique_domain_id)

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
        assert spin_until(node, lambda: len(received) >= 3, 60.0), 'no command arrived'
        names = ['sequence', 'rate_hz', 'frame_id', 'autostart']
        reply = call_service(node, GetParameters, '/command_player/get_parameters',
                             GetParameters.Request(names=names), resend_after=5.0)
    finally:
        output = stop(proc)
        node.destroy_node()
        rclpy.shutdown()
    values = dict(zip(names, reply.values))
    assert values['sequence'].type == ParameterType.PARAMETER_STRING
    assert values['sequence'].string_value == str(sequence), output
    assert values['rate_hz'].type == ParameterType.PARAMETER_DOUBLE
    assert values['rate_hz'].double_value == RATE_HZ
    assert values['frame_id'].string_value == FRAME
    assert values['autostart'].bool_value is True
    # What the node does follows them: the file's frame and the file's sequence.
    assert {m.header.frame_id for m in received} == {FRAME}, output
    np.testing.assert_allclose([received[-1].vector.x, received[-1].vector.y,
                                received[-1].vector.z], [0.1, -0.2, -1.5])
