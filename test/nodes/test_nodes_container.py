"""tacforce_container: several nodes in one process, each with its own ROS arguments, as a real
process against a real xela_server emulator; its command line is checked before anything
starts."""
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from tacforce_msgs.msg import ForceEstimateArray

from tacforce_ros.estimation.model_set import write_synthetic_model_set
from tacforce_ros.hand.description import load_hand
from tacforce_ros.nodes.qos import subscriber_qos
from tacforce_ros.nodes.runner import EXIT_BAD_PARAMETERS, EXIT_OK
from tacforce_ros.bringup.session_plan import NodeLaunch, SessionArgs, composed, params_file, plan
from tacforce_ros.nodes.tacforce_container import NODE_CLASSES, node_class, node_groups
from tacforce_ros.sim.emulators.xela_server import XelaServerEmulator
from tacforce_ros.topics import TOPIC_ESTIMATES

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import (executable, rclpy_node, spin_until, start, stop,  # noqa: E402
                           unique_domain_id)

DOMAIN = unique_domain_id(offset=97)
HAND = load_hand()


@pytest.mark.parametrize('args, message', [
    ([], 'usage'), (['estimator'], 'usage'), (['--node'], 'usage'),
    (['--node', 'teleop'], "'teleop': not a node"),
    (['--node', 'estimator', '--node', 'estimator'], 'named twice')])
def test_a_bad_command_line_is_refused_with_the_reason(args, message):
    with pytest.raises(ValueError, match=message):
        node_groups(args)


def test_every_hostable_node_is_the_class_of_its_name():
    assert all(node_class(name).NODE_NAME == name for name in NODE_CLASSES)


def test_a_composed_session_keeps_the_simulator_apart_and_each_node_s_arguments():
    nodes = plan(SessionArgs(mode='closed_loop', session_id='x'))
    sim, container = composed(nodes)
    assert sim.executable == 'sim_world' and container.executable == 'tacforce_container'
    assert [p.executable for p in container.parts] == [n.executable for n in nodes[1:]]
    assert plan(SessionArgs(mode='closed_loop', session_id='x', compose=True)) == [sim,
                                                                                   container]
    groups = node_groups(container.command_args())
    assert [(cls.NODE_NAME, args) for cls, args in groups] == [
        (n.executable, n.ros_args()) for n in nodes[1:]]


@pytest.mark.ros
def test_two_nodes_in_one_process_each_take_only_their_own_parameters(tmp_path):
    models = write_synthetic_model_set(tmp_path / 'models', HAND)
    counts = np.full((HAND.n_taxels, 3), 30000, np.uint16)
    temperatures = np.full(HAND.n_taxels, 300.0)
    sequence = iter(range(1, 10**9))
    source = lambda: (counts + next(sequence) % 7, temperatures, time.time())  # noqa: E731
    with XelaServerEmulator(source, rate_hz=100.0) as server, \
            rclpy_node('container_test', DOMAIN) as node:
        estimates = []
        node.create_subscription(ForceEstimateArray, TOPIC_ESTIMATES, estimates.append,
                                 subscriber_qos(TOPIC_ESTIMATES))
        xela = NodeLaunch('xela_driver', (params_file('xela_driver'),),
                          {'url': f'ws://127.0.0.1:{server.address[1]}'})
        estimator = NodeLaunch('estimator', (params_file('estimator'),),
                               {'model_config': str(models), 'tare_frames': 5})
        container = NodeLaunch('tacforce_container', parts=(xela, estimator))
        proc = start([executable('tacforce_container'), *container.command_args()], DOMAIN)
        try:
            assert spin_until(node, lambda: sum(e.estimates[0].valid for e in estimates) >= 20,
                              60.0), 'no valid estimates from the composed pair'
        finally:
            output = stop(proc)
    assert proc.returncode == EXIT_OK, output
    assert 'tare done from 5 frames' in output          # the estimator's own parameter
    assert 'ignoring parameters' not in output, output   # nobody got the other's


def test_a_composed_node_with_a_bad_parameter_stops_the_container(tmp_path):
    bad = NodeLaunch('estimator', (params_file('estimator'),), {'tare_frames': 0})
    proc = start([executable('tacforce_container'),
                  *NodeLaunch('tacforce_container', parts=(bad,)).command_args()], DOMAIN)
    proc.wait(timeout=60.0)
    output = proc.stdout.read()
    assert proc.returncode == EXIT_BAD_PARAMETERS and 'tare_frames' in output, output
