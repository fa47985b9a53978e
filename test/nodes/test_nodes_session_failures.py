"""The `session` tool, run as a user runs it, when sim_world cannot start: the session ends at
once with an error naming the node, and stops the nodes started beside it (as launch's
OnProcessExit -> Shutdown does)."""
import socket
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import executable, ros_env, unique_domain_id  # noqa: E402

DOMAIN = unique_domain_id(offset=31)


def test_a_simulator_that_cannot_listen_ends_the_session_naming_it(tmp_path):
    with socket.socket() as taken:          # the hand emulator's port is held by another socket
        taken.bind(('127.0.0.1', 0))
        can_port = taken.getsockname()[1]
        done = subprocess.run(
            [str(executable('session')), 'calibration',
             '--out', str(tmp_path / 'out'), '--duration', '60',
             '--ports', str(can_port - 2), str(can_port - 1), str(can_port)],
            capture_output=True, text=True, timeout=120, env=ros_env(DOMAIN))
    assert done.returncode == 1, done.stdout[-2000:] + done.stderr[-2000:]
    assert 'session: sim_world exited early (code 1)' in done.stderr, done.stderr[-2000:]
    stopped = done.stdout.split('session calibration: stopped after ')[1]
    assert float(stopped.split(' s;')[0]) < 60.0, done.stdout[-2000:]     # not its --duration
    assert 'xela_driver=' in stopped and 'sim_world=1' in stopped, stopped
    log = (tmp_path / 'out' / 'logs' / 'sim_world.log').read_text()
    assert 'Address already in use' in log


def test_an_unknown_array_starts_nothing_and_names_the_argument(tmp_path):
    done = subprocess.run(
        [str(executable('session')), 'calibration', '--array',
         'palm_nosuch', '--out', str(tmp_path / 'out'), '--duration', '60'],
        capture_output=True, text=True, timeout=120, env=ros_env(DOMAIN))
    assert done.returncode == 2, done.stdout + done.stderr
    assert "array: 'palm_nosuch' is not an array of the right hand" in done.stderr
    assert not (tmp_path / 'out' / 'logs').exists(), 'a node was started'
