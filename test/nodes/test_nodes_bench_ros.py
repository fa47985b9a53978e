"""bench_ros, run as a user runs it: a part that fails is reported in the JSON and the table with
its reason, the other parts keep their results, and the command exits non-zero."""
import json
import socket
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import ros_env, unique_domain_id  # noqa: E402

DOMAIN = unique_domain_id(offset=29)


def test_a_failed_part_keeps_the_other_parts_results(tmp_path):
    # The hand emulator cannot listen on a port another socket holds: the controller part fails.
    with socket.socket() as taken:
        taken.bind(('127.0.0.1', 0))
        can_port = taken.getsockname()[1]
        out = tmp_path / 'bench_ros.json'
        done = subprocess.run(
            [sys.executable, '-m', 'tacforce_ros.tools.bench_ros', '--parts', 'estimator',
             'controller', '--latency-seconds', '1', '--rates', '100', '--seconds', '0.5',
             '--realtime-priority', '0', '--domain', str(DOMAIN),
             '--ports', str(can_port - 2), str(can_port - 1), str(can_port), '--out', str(out)],
            capture_output=True, text=True, timeout=600, env=ros_env(DOMAIN))
    assert done.returncode != 0, done.stdout[-2000:]
    assert 'controller failed' in done.stderr, done.stderr[-2000:]
    result = json.loads(out.read_text())
    assert result['estimator']['latency']['frames'] == 100, result['estimator']
    assert 'sim_world was not ready' in result['controller']['failed']
    assert 'controller | FAILED: RuntimeError: sim_world was not ready' in result['table']
