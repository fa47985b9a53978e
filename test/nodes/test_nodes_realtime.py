"""realtime_priority: every thread of a node's process (rclpy's and the DDS layer's) runs
SCHED_FIFO at the given priority; where the system refuses, the node warns and runs normally."""
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import OutputLines, executable, start, unique_domain_id  # noqa: E402

DOMAIN = unique_domain_id(offset=67)

# A process with rclpy initialised (its DDS threads exist) and one thread of its own.
CHILD = textwrap.dedent('''
    import os, threading, rclpy
    from tacforce_ros.nodes.realtime import use_realtime_scheduling
    rclpy.init(domain_id=%d)
    node = rclpy.create_node('realtime_probe')
    idle = threading.Event()
    threading.Thread(target=idle.wait, daemon=True).start()
    try:
        use_realtime_scheduling(7)
    except OSError as exc:
        print('refused', exc)
    else:
        tasks = os.listdir('/proc/self/task')
        policies = {os.sched_getscheduler(int(t)) for t in tasks}
        priorities = {os.sched_getparam(int(t)).sched_priority for t in tasks}
        late = []   # a thread started afterwards inherits it
        thread = threading.Thread(target=lambda: late.append(os.sched_getscheduler(0)))
        thread.start()
        thread.join()
        print('threads', len(tasks), policies == {os.SCHED_FIFO}, priorities == {7},
              late == [os.SCHED_FIFO])
    idle.set()
    node.destroy_node()
    rclpy.shutdown()
''')


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='SCHED_FIFO is Linux')
def test_every_thread_of_the_process_runs_fifo_at_the_priority():
    out = subprocess.run([sys.executable, '-c', CHILD % (150 + os.getpid() % 50)],
                         capture_output=True, text=True, timeout=60, check=True).stdout.split()
    if out[0] == 'refused':
        pytest.skip(f'this machine refuses SCHED_FIFO: {" ".join(out[1:])}')
    assert out[0] == 'threads' and int(out[1]) >= 3   # main, ours, and the DDS layer's
    assert out[2:] == ['True', 'True', 'True']


def _fifo_allowed() -> bool:
    probe = [sys.executable, '-c',
             'import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))']
    return subprocess.run(probe, capture_output=True, timeout=30).returncode == 0


@pytest.mark.ros
@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='SCHED_FIFO is Linux')
def test_the_estimator_node_applies_its_realtime_priority():
    if not _fifo_allowed():
        pytest.skip('this machine refuses SCHED_FIFO')
    out = OutputLines(start([executable('estimator'), '--ros-args', '-p',
                             'realtime_priority:=5'], DOMAIN))
    proc = out.proc
    try:
        deadline, policies = time.monotonic() + 30.0, set()
        while time.monotonic() < deadline and proc.poll() is None:
            tasks = os.listdir(f'/proc/{proc.pid}/task')
            try:
                policies = {(os.sched_getscheduler(int(t)),
                             os.sched_getparam(int(t)).sched_priority) for t in tasks}
            except ProcessLookupError:
                continue
            if policies == {(os.SCHED_FIFO, 5)} and len(tasks) >= 3:
                break
            time.sleep(0.2)
        # A stop while the node is still being built ends the build there: the node says so
        # once built.
        out.wait_for('threads run SCHED_FIFO at priority 5', 30.0)
    finally:
        output = out.stop()
    assert policies == {(os.SCHED_FIFO, 5)}, output[-800:]
    assert 'threads run SCHED_FIFO at priority 5' in output
