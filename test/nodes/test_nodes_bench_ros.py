"""bench_ros, run as a user runs it: a part that fails is reported in the JSON and the table with
its reason, the other parts keep their results, and the command exits non-zero."""
import json
import socket
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import executable, ros_env, unique_domain_id  # noqa: E402

DOMAIN = unique_domain_id(offset=29)


def test_a_failed_part_keeps_the_other_parts_results(tmp_path):
    # The hand emulator cannot listen on a port another socket holds: the controller part fails.
    with socket.socket() as taken:
        taken.bind(('127.0.0.1', 0))
        can_port = taken.getsockname()[1]
        out = tmp_path / 'bench_ros.json'
        done = subprocess.run(
            [str(executable('bench_ros')), '--parts', 'estimator',
             'controller', '--latency-seconds', '1', '--rates', '100', '--seconds', '0.5',
             '--realtime-priority', '0', '--domain', str(DOMAIN),
             '--ports', str(can_port - 2), str(can_port - 1), str(can_port), '--out', str(out)],
            capture_output=True, text=True, timeout=600, env=ros_env(DOMAIN))
    assert done.returncode != 0, done.stdout[-2000:]
    assert 'controller failed' in done.stderr, done.stderr[-2000:]
    result = json.loads(out.read_text())
    assert result['estimator']['latency']['frames'] == 100, result['estimator']
    assert 'sim_world exited with code 1' in result['controller']['failed']
    assert 'controller | FAILED: RuntimeError: sim_world exited with code 1' in result['table']


def test_the_real_time_part_starts_the_estimator_on_the_normal_scheduler(tmp_path, monkeypatch):
    """A child process inherits the scheduling policy of the thread that starts it: the probe
    goes SCHED_FIFO only after the estimator has started (the node raises itself), and is back
    on the normal scheduler when the part ends."""
    import argparse
    import os

    import pytest

    from tacforce_ros.nodes.realtime import use_realtime_scheduling
    from tacforce_ros.benchmarks import bench_ros
    try:
        use_realtime_scheduling(50)
    except OSError as exc:
        pytest.skip(f'SCHED_FIFO not allowed here ({exc})')
    try:
        child = subprocess.Popen(['sleep', '5'])
        assert os.sched_getscheduler(child.pid) == os.SCHED_FIFO      # inherited
        child.kill()
        child.wait()
    finally:
        use_realtime_scheduling(0)
    policies = {}

    def start_nodes(nodes, *args, **kwargs):
        policies['at start'] = os.sched_getscheduler(0)
        return [('estimator', subprocess.Popen(['sleep', '30']))]

    def bench_estimator(*args, **kwargs):
        policies['measuring'] = os.sched_getscheduler(0)
        raise RuntimeError('stop here')

    def stop_nodes(procs, grace):
        for _, proc in procs:
            proc.kill()
            proc.wait()
        return {}

    monkeypatch.setattr(bench_ros, 'start_nodes', start_nodes)
    monkeypatch.setattr(bench_ros, 'bench_estimator', bench_estimator)
    monkeypatch.setattr(bench_ros, 'stop_nodes', stop_nodes)
    (tmp_path / 'logs').mkdir()
    (tmp_path / 'logs' / 'estimator.log').write_text('')
    args = argparse.Namespace(realtime_priority=50, rates=[100.0], seconds=0.1,
                              reliable_wrenches=False, latency_seconds=0.1)
    with pytest.raises(RuntimeError, match='stop here'):
        bench_ros.run_realtime_estimator(None, bench_ros.load_hand(), args, {}, tmp_path)
    assert policies == {'at start': os.SCHED_OTHER, 'measuring': os.SCHED_FIFO}
    assert os.sched_getscheduler(0) == os.SCHED_OTHER
