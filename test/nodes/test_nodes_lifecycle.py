"""The drivers as managed (lifecycle) nodes, driven the way `ros2 lifecycle set` drives them
(lifecycle_msgs services of a real process, on loopback): with autostart false a driver starts
unconfigured and publishes nothing; configure opens the device, activate starts the stream (the
hand's servos on) and the link's reports on /diagnostics, deactivate stops it (servos off; the
link says once, STALE, that it is inactive), activate starts it again, cleanup closes
the device, shutdown finalizes; a configure that cannot reach the device fails, says why, and
leaves the node unconfigured; with autostart (as launch starts every node at once) the driver
waits up to connect_timeout for a hand that is not there yet; the end of the process leaves an
active hand safe."""
import contextlib
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from sensor_msgs.msg import JointState
from tacforce_msgs.msg import TactileHand

from tacforce_ros.hand.description import load_hand
from tacforce_ros.nodes.qos import subscriber_qos
from tacforce_ros.bringup.session_plan import params_file
from tacforce_ros.sim.emulators.allegro import AllegroEmulator
from tacforce_ros.sim.emulators.xela_server import XelaServerEmulator
from tacforce_ros.topics import TOPIC_DIAGNOSTICS, TOPIC_JOINTS, TOPIC_TACTILE

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import (OutputLines, call_service, executable, rclpy_node,  # noqa: E402
                           spin_until, start, unique_domain_id)

pytestmark = pytest.mark.ros
QUIET_S = 1.0       # a stopped stream: nothing arrives for this long


class Lifecycle:
    """The lifecycle services of one node, called from the test's node."""

    def __init__(self, node, name: str) -> None:
        self.node, self.name = node, name

    def state(self) -> str:
        return call_service(self.node, GetState, f'/{self.name}/get_state', GetState.Request(),
                            resend_after=2.0).current_state.label

    def change(self, transition: int) -> bool:
        request = ChangeState.Request(transition=Transition(id=transition))
        return call_service(self.node, ChangeState, f'/{self.name}/change_state', request,
                            timeout=30.0).success


def _arrives(node, received: list, timeout: float = 10.0) -> bool:
    """A message arrives within `timeout`."""
    before = len(received)
    return spin_until(node, lambda: len(received) > before, timeout)


def _soon(node, done) -> bool:
    """done() within 5 s: the emulated hand reads the driver's frames from its own socket."""
    return spin_until(node, done, 5.0)


def _quiet(node, received: list) -> bool:
    """Nothing arrives over QUIET_S (after what was in flight)."""
    spin_until(node, lambda: False, 0.3)
    before = len(received)
    spin_until(node, lambda: False, QUIET_S)
    return len(received) == before


def closed_port() -> tuple[str, int]:
    """A loopback port an emulated hand served and no longer does."""
    with AllegroEmulator(lambda: np.zeros(16), lambda tau: None) as gone:
        return gone.address


def allegro_driver(host: str, port: int, domain: int, autostart: bool, *more: str
                   ) -> OutputLines:
    params = ['interface:=socketcand', 'channel:=can0', f'host:={host}', f'port:={port}',
              'rtr_requests:=false', 'control:=off', f'autostart:={str(autostart).lower()}',
              *more]
    return OutputLines(start([executable('allegro_driver'), '--ros-args', '--params-file',
                              params_file('allegro_driver'),
                              *[a for p in params for a in ('-p', p)]], domain))


@contextlib.contextmanager
def hand_and_probe(domain: int):
    """An emulated hand, and a test node that keeps every joint state the driver publishes."""
    with AllegroEmulator(lambda: np.linspace(0.0, 0.6, 16), lambda tau: None) as hand, \
            rclpy_node('lifecycle_test', domain) as node:
        received: list = []
        node.create_subscription(JointState, TOPIC_JOINTS, received.append,
                                 subscriber_qos(TOPIC_JOINTS))
        yield hand, node, received


def test_allegro_driver_through_its_lifecycle_switches_servos_and_stream():
    domain = unique_domain_id(offset=61)
    with hand_and_probe(domain) as (hand, node, received):
        host, port = hand.address
        health: list = []       # (level, message) of the driver's link on /diagnostics
        node.create_subscription(
            DiagnosticArray, TOPIC_DIAGNOSTICS,
            lambda msg: health.extend((s.level, s.message) for s in msg.status
                                      if s.name == '/allegro_driver: device link'),
            subscriber_qos(TOPIC_DIAGNOSTICS))
        out = allegro_driver(host, port, domain, autostart=False)
        life = Lifecycle(node, 'allegro_driver')
        try:
            assert life.state() == 'unconfigured', out.text()
            assert _quiet(node, received) and not hand.servo_on and hand.period_ms == 0

            assert life.change(Transition.TRANSITION_CONFIGURE), out.text()
            assert life.state() == 'inactive'
            assert _quiet(node, received) and not hand.servo_on and hand.period_ms == 0

            for round_ in range(2):        # activate, deactivate, and once more
                assert life.change(Transition.TRANSITION_ACTIVATE), out.text()
                assert life.state() == 'active'
                assert _arrives(node, received), (round_, out.text())
                assert _soon(node, lambda: hand.servo_on and hand.period_ms > 0)
                assert spin_until(node, lambda: health and health[-1][0] == DiagnosticStatus.OK,
                                  10.0), health[-3:]
                assert life.change(Transition.TRANSITION_DEACTIVATE), out.text()
                assert life.state() == 'inactive'
                assert _quiet(node, received), f'joint states while inactive (round {round_})'
                assert _soon(node, lambda: not hand.servo_on and hand.period_ms == 0)
                # The link says once that it is inactive, and no ERROR for the stopped stream.
                assert health[-1] == (DiagnosticStatus.STALE,
                                      'inactive (lifecycle): nothing published'), health[-3:]

            assert life.change(Transition.TRANSITION_CLEANUP), out.text()
            assert life.state() == 'unconfigured'
            assert life.change(Transition.TRANSITION_UNCONFIGURED_SHUTDOWN), out.text()
            assert life.state() == 'finalized'
        finally:
            text = out.stop()
    assert out.proc.returncode == 0, text
    assert 'link counters at close' in text, text


def test_xela_driver_publishes_only_while_active():
    domain = unique_domain_id(offset=62)
    hand = load_hand()
    counts = np.full((hand.n_taxels, 3), 30000, np.uint16)
    temperatures = np.full(hand.n_taxels, 300.0)
    server = XelaServerEmulator(lambda: (counts, temperatures, time.time()))
    try:
        with rclpy_node('lifecycle_test', domain) as node:
            received: list = []
            node.create_subscription(TactileHand, TOPIC_TACTILE, received.append,
                                     subscriber_qos(TOPIC_TACTILE))
            out = OutputLines(start([
                executable('xela_driver'), '--ros-args', '--params-file',
                params_file('xela_driver'), '-p', f'url:=ws://127.0.0.1:{server.address[1]}',
                '-p', 'autostart:=false'], domain))
            life = Lifecycle(node, 'xela_driver')
            try:
                assert life.state() == 'unconfigured', out.text()
                assert life.change(Transition.TRANSITION_CONFIGURE), out.text()
                assert _quiet(node, received), 'frames while inactive'
                assert life.change(Transition.TRANSITION_ACTIVATE), out.text()
                assert _arrives(node, received), out.text()
                assert life.change(Transition.TRANSITION_DEACTIVATE), out.text()
                assert _quiet(node, received), 'frames after deactivate'
                assert life.change(Transition.TRANSITION_ACTIVATE), out.text()
                assert _arrives(node, received), out.text()
                assert life.change(Transition.TRANSITION_ACTIVE_SHUTDOWN), out.text()
                assert life.state() == 'finalized'
                assert _quiet(node, received), 'frames after shutdown'
            finally:
                text = out.stop()
    finally:
        server.close()
    assert out.proc.returncode == 0, text


def test_xela_driver_publishes_nothing_from_the_other_hands_sensor():
    """A left hand's uSkin (XR23AHLCPP) read with the right hand's description: its frames would
    put every reading on the wrong taxel; none is published, the log and /diagnostics say why."""
    domain = unique_domain_id(offset=69)
    hand = load_hand()
    counts = np.full((hand.n_taxels, 3), 30000, np.uint16)
    temperatures = np.full(hand.n_taxels, 300.0)
    server = XelaServerEmulator(lambda: (counts, temperatures, time.time()), model='XR23AHLCPP')
    try:
        with rclpy_node('lifecycle_test', domain) as node:
            received: list = []
            errors: list = []
            node.create_subscription(TactileHand, TOPIC_TACTILE, received.append,
                                     subscriber_qos(TOPIC_TACTILE))
            node.create_subscription(
                DiagnosticArray, TOPIC_DIAGNOSTICS,
                lambda msg: errors.extend(s.message for s in msg.status
                                          if s.level == DiagnosticStatus.ERROR),
                subscriber_qos(TOPIC_DIAGNOSTICS))
            out = OutputLines(start([
                executable('xela_driver'), '--ros-args', '--params-file',
                params_file('xela_driver'), '-p', f'url:=ws://127.0.0.1:{server.address[1]}'],
                domain))
            try:
                assert out.wait_for('frames dropped', 30.0) is not None, out.text()
                assert spin_until(node, lambda: any('XR23AHLCPP' in e for e in errors), 10.0), \
                    errors
                assert not received
            finally:
                text = out.stop()
    finally:
        server.close()
    assert 'reports sensor XR23AHLCPP, but hand_config describes XR23AHRCPP' in text, text


def test_a_configure_that_cannot_reach_the_hand_fails_and_says_why():
    domain = unique_domain_id(offset=63)
    host, port = closed_port()
    with rclpy_node('lifecycle_test', domain) as node:
        out = allegro_driver(host, port, domain, autostart=False)
        life = Lifecycle(node, 'allegro_driver')
        try:
            assert not life.change(Transition.TRANSITION_CONFIGURE)
            assert life.state() == 'unconfigured'
            assert out.wait_for('configure failed', 5.0) is not None, out.text()
        finally:
            text = out.stop()
    assert 'hand not reachable' in text, text
    assert out.proc.returncode == 0, text


def test_the_end_of_the_process_leaves_an_active_hand_safe():
    """SIGINT to an active hand driver (autostart, as launch starts it): shutdown from active
    stops the stream and switches the servos off before the process ends."""
    domain = unique_domain_id(offset=64)
    with hand_and_probe(domain) as (hand, node, received):
        host, port = hand.address
        out = allegro_driver(host, port, domain, autostart=True)
        try:
            assert _arrives(node, received, 30.0), out.text()
            assert _soon(node, lambda: hand.servo_on and hand.period_ms > 0)
        finally:
            text = out.stop()
        assert out.proc.returncode == 0, text
        assert _soon(node, lambda: not hand.servo_on and hand.period_ms == 0), text


def test_an_autostarting_driver_waits_for_a_hand_that_comes_up_later():
    """launch starts the driver and the simulator together: the hand's port is closed at first,
    and the driver takes the hand when it answers."""
    domain = unique_domain_id(offset=65)
    host, port = closed_port()
    with rclpy_node('lifecycle_test', domain) as node:
        received: list = []
        node.create_subscription(JointState, TOPIC_JOINTS, received.append,
                                 subscriber_qos(TOPIC_JOINTS))
        out = allegro_driver(host, port, domain, True, 'connect_timeout:=60.0')
        try:
            assert out.wait_for('waiting for the hand', 30.0) is not None, out.text()
            assert not _arrives(node, received, 1.0)
            with AllegroEmulator(lambda: np.zeros(16), lambda tau: None, port=port) as hand:
                assert _arrives(node, received, 30.0), out.text()
                assert _soon(node, lambda: hand.servo_on)
                text = out.stop()
        finally:
            text = out.stop()
    assert out.proc.returncode == 0, text


def test_a_hand_of_the_other_side_is_refused():
    """The left hand's description against a hand that says (HAND_INFO) it is a right hand."""
    from tacforce_ros.hand.description import hand_config
    domain = unique_domain_id(offset=67)
    with AllegroEmulator(lambda: np.zeros(16), lambda tau: None) as hand:
        host, port = hand.address
        out = allegro_driver(host, port, domain, True, f"hand_config:='{hand_config('left')}'")
        assert out.proc.wait(timeout=60.0) == 2, out.stop()
        text = out.stop()
        assert not hand.servo_on
    assert "left hand's description, but the hand on the bus is a right hand" in text, text


def test_a_driver_waiting_for_its_hand_stops_at_once_on_sigint():
    domain = unique_domain_id(offset=68)
    host, port = closed_port()
    out = allegro_driver(host, port, domain, True, 'connect_timeout:=60.0')
    try:
        assert out.wait_for('waiting for the hand', 30.0) is not None, out.text()
        out.proc.send_signal(2)
        assert out.proc.wait(timeout=5.0) == 0, out.text()
    finally:
        text = out.stop()
    assert 'stopped while waiting for the hand: not started' in text, text


def test_an_autostarting_driver_gives_up_after_connect_timeout():
    domain = unique_domain_id(offset=66)
    host, port = closed_port()
    out = allegro_driver(host, port, domain, True, 'connect_timeout:=1.0')
    assert out.proc.wait(timeout=60.0) == 2, out.stop()
    text = out.stop()
    assert 'hand not reachable' in text, text
