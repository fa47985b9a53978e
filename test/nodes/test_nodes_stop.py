"""Every node ends when asked (SIGINT or SIGTERM), wherever it is: waiting for a hand that accepts
and never answers, for a hand that is not there, with a XELA server that hangs after streaming;
and a lifecycle driver that ended has left the ROS graph (a node restarted under its name is not
confused with it). How fast they end, at random moments and over many stops, is what `bench_stop`
measures; these tests check that they end at all, cleanly, where each one used to wait for good
or for python-can's and websockets' own 10 s."""
import signal
import socket
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from std_msgs.msg import Float64

from tacforce_ros.hand.description import load_hand
from tacforce_ros.nodes import entry
from tacforce_ros.nodes.qos import RELIABLE_QOS
from tacforce_ros.sim.emulators.xela_server import XelaServerEmulator

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'devices'))
from devices_support import Relay  # noqa: E402
from ros_processes import (OutputLines, executable, rclpy_node, spin_until, start,  # noqa: E402
                           unique_domain_id)

pytestmark = pytest.mark.ros
DOMAIN = unique_domain_id(offset=41)
# Generous bounds on an end that takes well under a second: a stalling host must not fail
# them, a wait of the libraries' own 10 s (or for good) must.
ENDS_WITHIN_S = 8.0
READY_S = 60.0


def ends(proc, signum: int) -> int | None:
    """Send `signum`; the exit code if the process ended within ENDS_WITHIN_S, else None (and
    it is killed)."""
    proc.send_signal(signum)
    try:
        return proc.wait(timeout=ENDS_WITHIN_S)
    except Exception:       # noqa: BLE001 - subprocess.TimeoutExpired: report, then kill
        proc.kill()
        proc.wait()
        return None


def allegro_driver(port: int, *more: str) -> OutputLines:
    return OutputLines(start([executable('allegro_driver'), '--ros-args', '-p',
                              'interface:=socketcand', '-p', f'port:={port}', '-p',
                              'rtr_requests:=false', '-p', 'connect_timeout:=120.0', *more],
                             DOMAIN, start_new_session=True))


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM])
def test_a_driver_waiting_for_a_hand_that_never_answers_ends_when_asked(signum):
    """The hand's socketcand server accepts and says nothing (it hangs): the driver keeps trying
    it (connect_timeout 120 s) and still ends on the signal, exit code 0."""
    with socket.create_server(('127.0.0.1', 0)) as mute:
        mute.settimeout(READY_S)
        driver = allegro_driver(mute.getsockname()[1])
        held = []
        try:
            held.append(mute.accept()[0])       # kept open and silent: no greeting comes
            assert driver.wait_for('did not answer within', READY_S), driver.text()
            held.append(mute.accept()[0])       # it tries again, and waits again
            code = ends(driver.proc, signum)
        finally:
            output = driver.stop()
            for sock in held:
                sock.close()
    assert code == 0, output
    assert 'stopped while waiting for the hand' in output, output


def test_a_driver_waiting_for_a_hand_that_is_not_there_ends_when_asked():
    with socket.socket() as probe:
        probe.bind(('127.0.0.1', 0))
        port = probe.getsockname()[1]
    driver = allegro_driver(port)
    try:
        assert driver.wait_for('waiting for the hand', READY_S), driver.text()
        code = ends(driver.proc, signal.SIGINT)
    finally:
        output = driver.stop()
    assert code == 0, output


def test_a_xela_driver_whose_server_hangs_ends_when_asked():
    """Streaming, then the server hangs (a relay stops forwarding): the driver's closing
    handshake waits its close_timeout, not the library's 10 s."""
    hand = load_hand()
    counts = np.full((hand.n_taxels, 3), 30000, np.uint16)
    temperatures = np.full(hand.n_taxels, 300.0)
    with XelaServerEmulator(lambda: (counts, temperatures, time.time())) as server, \
            Relay(server.address) as relay:
        driver = OutputLines(start([executable('xela_driver'), '--ros-args', '-p',
                                    f'url:=ws://127.0.0.1:{relay.address[1]}'],
                                   DOMAIN, start_new_session=True))
        try:
            assert driver.wait_for('link OK', READY_S), driver.text()
            relay.freeze()
            code = ends(driver.proc, signal.SIGINT)
        finally:
            output = driver.stop()
    assert code == 0, output
    assert 'link counters at close' in output, output


def test_the_simulator_serves_its_hand_until_the_driver_lets_go():
    """A session stops every node at once; the simulated hand, like a real one, is still there
    for a driver that has not yet closed its link (otherwise the driver ends on a lost link, code
    1), and the simulator ends once the driver has gone."""
    with socket.socket() as probe:
        probe.bind(('127.0.0.1', 0))
        port = probe.getsockname()[1]
    sim = OutputLines(start([executable('sim_world'), '--ros-args', '-p', 'xela_port:=0',
                             '-p', 'netft_port:=0', '-p', f'can_port:={port}',
                             '-p', 'report_period:=0.5'], DOMAIN, start_new_session=True))
    try:
        with rclpy_node('sim_probe', DOMAIN) as node:     # running: its timers report
            factors = []
            node.create_subscription(Float64, '/sim_world/real_time_factor', factors.append,
                                     RELIABLE_QOS)
            assert spin_until(node, lambda: factors, READY_S), sim.text()
        deadline = time.monotonic() + READY_S
        while True:
            try:
                link = socket.create_connection(('127.0.0.1', port), timeout=5.0)
                break
            except OSError:
                assert time.monotonic() < deadline and sim.proc.poll() is None, sim.text()
                time.sleep(0.1)
        with link:
            assert link.recv(64).startswith(b'< hi >')
            sim.proc.send_signal(signal.SIGINT)
            assert sim.wait_for('stopped:', READY_S), sim.text()
            time.sleep(0.5)     # without the wait, the simulator had closed and ended by now
            link.sendall(b'< open can0 >')
            assert b'< ok >' in link.recv(64), sim.text()       # still served
            assert sim.proc.poll() is None
        code = sim.proc.wait(timeout=ENDS_WITHIN_S)
    finally:
        output = sim.stop()
    assert code == 0, output


def test_an_ended_lifecycle_driver_leaves_the_ros_graph():
    """rclpy's lifecycle node keeps its node alive until garbage collection, which the process
    no longer waits for: the driver destroys it, so the graph does not list a node that ended
    (for the 20 s of its DDS lease)."""
    with rclpy_node('stop_probe', DOMAIN) as probe:
        def listed() -> bool:
            return any(name == 'stop_probe_subject' for name, _ in
                       probe.get_node_names_and_namespaces())

        driver = OutputLines(start([executable('ft_bridge'), '--ros-args', '-p',
                                    'autostart:=false', '-r', '__node:=stop_probe_subject'],
                                   DOMAIN, start_new_session=True))
        try:
            assert spin_until(probe, listed, READY_S), driver.text()
            assert ends(driver.proc, signal.SIGINT) == 0, driver.text()
            assert spin_until(probe, lambda: not listed(), 10.0), 'still listed after 10 s'
        finally:
            driver.stop()


# A node whose stop never ends (its leave_safe blocks), run as a process the way the node
# executables run (nodes/entry.py around run_node).
STUCK_NODE = """
import time
from tacforce_ros.nodes import entry
from tacforce_ros.nodes.qos import RELIABLE_QOS
from tacforce_ros.nodes.node_base import TacforceNode
from tacforce_ros.nodes.runner import run_node

class Stuck(TacforceNode):
    NODE_NAME = 'stuck_at_stop'
    def on_built(self):
        self.get_logger().info('built')
    def leave_safe(self):
        time.sleep(600)         # a stop that hangs

import sys, types
sys.modules['tacforce_ros.nodes.stuck'] = types.SimpleNamespace(
    main=lambda: sys.exit(run_node(Stuck, ['stuck'])))
entry.run('stuck')
"""


def test_a_stop_that_hangs_is_ended_with_every_thread_s_stack():
    """Past runner.STOP_LIMIT_S the stop's watchdog writes where each thread was and ends the
    process with EXIT_STOP_STUCK, before `session` (10 s) or ros2 launch would kill it."""
    from tacforce_ros.nodes.runner import EXIT_STOP_STUCK, STOP_LIMIT_S
    node = OutputLines(start([sys.executable, '-c', STUCK_NODE], DOMAIN, start_new_session=True))
    try:
        assert node.wait_for('built', READY_S) is not None, node.text()
        node.proc.send_signal(signal.SIGINT)
        signalled = time.monotonic()
        code = node.proc.wait(timeout=STOP_LIMIT_S + 20.0)
        took = time.monotonic() - signalled
    finally:
        output = node.stop()
    assert code == EXIT_STOP_STUCK, output
    assert took >= STOP_LIMIT_S - 0.5, took
    assert 'Timeout' in output and 'in leave_safe' in output, output


def test_every_node_executable_starts_through_the_entry_module():
    """setup.py installs each node's executable through nodes/entry.py (the prompt stop while
    loading, the prompt end after), and each entry runs that node's module."""
    from importlib import import_module
    from importlib.metadata import distribution
    scripts = {ep.name: ep.value for ep in distribution('tacforce-ros').entry_points
               if ep.group == 'console_scripts' and ep.value.startswith('tacforce_ros.nodes')}
    assert scripts and all(value == f'tacforce_ros.nodes.entry:{name}'
                           for name, value in scripts.items()), scripts
    for name in scripts:
        assert getattr(entry, name).args == (name,)         # runs the module of its name
        assert callable(import_module(f'tacforce_ros.nodes.{name}').main)


def test_bench_stop_writes_every_stop_and_its_table(tmp_path):
    """The stop benchmark itself, briefly: each stop of its subject is recorded with its
    condition and how it ended, and the table counts them."""
    import json
    import subprocess
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'integration'))
    from graph_support import free_ports
    done = subprocess.run([str(executable('bench_stop')), '--subjects', 'ft_bridge', '--stops',
                           '3', '--out', str(tmp_path), '--domain', str(DOMAIN), '--ports',
                           *map(str, free_ports(offset=11))],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    result = json.loads((tmp_path / 'bench_stop.json').read_text())
    stops = result['stops']
    assert [(s['subject'], s['device']) for s in stops] == [('ft_bridge', 'streaming')] * 3
    assert [s['moment'] for s in stops] == ['starting', 'unconfigured', 'inactive']
    assert [s['signal'] for s in stops] == ['SIGINT', 'SIGTERM', 'SIGINT']
    for stop in stops:          # each ended on its signal, none had to be killed
        assert not stop['killed'] and stop['stop_s'] is not None, stop
        assert stop['exit_code'] in (0, -signal.SIGINT, -signal.SIGTERM), stop
    assert result['summary']['ft_bridge']['stops'] == 3
    assert '| ft_bridge | 3 | 3 of 3 | 0 |' in (tmp_path / 'bench_stop.md').read_text()
