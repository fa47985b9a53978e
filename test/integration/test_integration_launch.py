"""The launch files under the real `ros2 launch`, where it is installed (a full ROS 2 install; it
is not on PyPI, so this project's own machines skip these): a bad argument ends the launch
before any process starts, naming the argument, exit code 1; a node that fails while the session
runs ends it with exit code 1, naming the node. `ROS2_LAUNCH` may name another command that runs
`ros2 launch` (e.g. a script that puts an upstream launch checkout on PYTHONPATH)."""
import os
import shlex
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from graph_support import free_ports, ros_env, unique_domain_id  # noqa: E402

pytestmark = pytest.mark.ros
def _launch_command() -> list[str] | None:
    """The command that runs `ros2 launch` with this package found, or None."""
    if os.environ.get('ROS2_LAUNCH'):
        return shlex.split(os.environ['ROS2_LAUNCH'])
    if shutil.which('ros2') is None:
        return None
    found = subprocess.run(['ros2', 'pkg', 'prefix', 'tacforce_ros'], capture_output=True,
                           timeout=60)
    return ['ros2', 'launch'] if found.returncode == 0 else None


COMMAND = _launch_command()
if COMMAND is None:
    pytest.skip('`ros2 launch` with tacforce_ros is not installed (ROS2_LAUNCH may name a '
                'command that runs it)', allow_module_level=True)
DOMAIN = unique_domain_id(offset=93)
STARTED = 'process started with pid'


def launch(tmp_path, *arguments: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run([*COMMAND, 'tacforce_ros', *arguments, f'out:={tmp_path / "bags"}'],
                          capture_output=True, text=True, timeout=timeout,
                          env=ros_env(DOMAIN), start_new_session=True)


@pytest.mark.parametrize('arguments, message', [
    (('calibration.launch.py', 'array:=palm_nosuch'),
     "array: 'palm_nosuch' is not an array of the right hand"),
    (('calibration.launch.py', 'model:=models.yaml'),
     'model: not an argument of this launch file'),
    (('closed_loop.launch.py', 'seed:=abc'), "seed:='abc': expected an integer"),
    (('closed_loop.launch.py', 'sim:=false', 'seed:=3'), 'seed: only simulation reads it'),
    (('two_hands_sim.launch.py', 'hand_side:=left'), 'hand_side: not an argument'),
    (('grasp.launch.py', 'grip:=strong'), "grip:='strong': expected a number"),
    (('grasp.launch.py', 'sim:=false', 'hold_time:=3'), 'hold_time: only simulation reads it'),
    (('grasp.launch.py', 'object:=egg'), 'grasp_egg'),
    (('closed_loop.launch.py', 'object:=golf_ball'), 'object: not an argument')])
def test_a_bad_argument_starts_nothing_and_names_itself(tmp_path, arguments, message):
    done = launch(tmp_path, *arguments)
    output = done.stdout + done.stderr
    assert done.returncode == 1, output
    assert message in output, output
    assert STARTED not in output, output


def test_a_node_that_fails_ends_the_launch_non_zero_naming_it(tmp_path):
    """The simulated hand's port is taken: sim_world exits 1, and so does the launch, after
    stopping the rest."""
    xela, netft, can = free_ports(offset=9)
    with socket.create_server(('127.0.0.1', can)):
        done = launch(tmp_path, 'closed_loop.launch.py', f'xela_port:={xela}',
                      f'netft_port:={netft}', f'can_port:={can}', timeout=180.0)
    output = done.stdout + done.stderr
    assert done.returncode == 1, output
    assert '/sim_world exited with code 1' in output, output
    assert 'process has died' not in output.split('/sim_world exited with code 1')[1], output


def test_a_simulated_grasp_ends_the_launch_cleanly_when_its_client_has_the_result(tmp_path):
    """grasp.launch.py with a hold time: grasp_client gets HELD and exits 0, which shuts the
    launch down; every node stops cleanly and the launch exits 0."""
    xela, netft, can = free_ports(offset=10)
    done = launch(tmp_path, 'grasp.launch.py', 'hold_time:=1.5', f'xela_port:={xela}',
                  f'netft_port:={netft}', f'can_port:={can}', timeout=300.0)
    output = done.stdout + done.stderr
    assert done.returncode == 0, output[-4000:]
    assert 'grasp held: held' in output, output[-4000:]
    finished = [line for line in output.splitlines()
                if 'grasp_client' in line and 'process has finished cleanly' in line]
    assert finished and 'shutting down' in output.split(finished[0])[1], output[-4000:]
    assert 'process has died' not in output, output[-4000:]
