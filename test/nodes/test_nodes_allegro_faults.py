"""allegro_driver as a real process against the emulated hand over socketcand on loopback: a
closed link ends it with code 1 in either mode (no hang, no spin), a silent hand is warned
about, asked for its stream again, and made safe; alone, it takes joint torques from its topic
and zeroes them when the commands stop."""
import re
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from sensor_msgs.msg import JointState

from tacforce_ros.nodes.qos import publisher_qos
from tacforce_ros.nodes.runner import EXIT_FAILURE
from tacforce_ros.sim.emulators.allegro import AllegroEmulator
from tacforce_ros.topics import TOPIC_TORQUE_COMMAND

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'devices'))
from devices_support import wait_until  # noqa: E402
from ros_processes import (OutputLines, executable, rclpy_node, start,  # noqa: E402
                           unique_domain_id)

pytestmark = pytest.mark.ros
DOMAIN = unique_domain_id(offset=71)
POSE = np.linspace(0.0, 0.6, 16)
STARTED = 'Allegro SAH040X1'
WARN_AFTER_S = 0.2


def driver(hand: AllegroEmulator, control: str, silent_timeout: float) -> OutputLines:
    host, port = hand.address
    params = ['interface:=socketcand', 'channel:=can0', f'host:={host}', f'port:={port}',
              'rtr_requests:=false', f'control:={control}', 'diagnostics_period:=0.0',
              f'silent_warn_after:={WARN_AFTER_S}', f'silent_timeout:={silent_timeout}']
    proc = start([executable('allegro_driver'), '--ros-args',
                  *[a for p in params for a in ('-p', p)]], DOMAIN)
    return OutputLines(proc)


@pytest.mark.parametrize('control', ['off', 'torque'])
def test_a_closed_link_ends_the_driver_with_an_error(control):
    with AllegroEmulator(lambda: POSE, lambda tau: None) as hand:
        out = driver(hand, control, silent_timeout=10.0)
        try:
            assert out.wait_for(STARTED, 60.0), out.text()[-2000:]
            time.sleep(0.3)
            hand.close()                       # the socketcand server goes away
            closed = time.monotonic()
            code = out.proc.wait(timeout=15.0)
            exited = time.monotonic() - closed
        finally:
            text = out.stop()
    print(f'control {control}: exited {exited:.3f} s after the link closed')
    assert code == EXIT_FAILURE, text[-2000:]
    assert 'link lost' in text and 'Allegro link failed' in text, text[-2000:]


def reported_silence(out: OutputLines, text: str, since: float) -> float:
    """The silence [s] the driver states in its first line containing `text` after `since`."""
    line = next(line for t, line in out.lines if t >= since and text in line)
    return float(re.search(r'no joint data for ([0-9.]+) s', line).group(1))


def test_a_silent_hand_is_warned_about_asked_again_and_made_safe_without_control():
    timeout = 3.0
    with AllegroEmulator(lambda: POSE, lambda tau: None) as hand:
        out = driver(hand, 'off', timeout)
        try:
            assert out.wait_for(STARTED, 60.0), out.text()[-2000:]
            # Servos on when the driver activates, just after that line (configure's).
            assert wait_until(lambda: hand.servo_on, 10.0), out.text()[-2000:]
            # A board that lost its stream period: only a new SET_PERIOD brings it back.
            # Lines from here on only: a stall of this host can make the driver see a short
            # silence at start-up too (seen: "joint stream back after 1.20 s" before the test
            # had silenced anything).
            hand.forget_stream()
            silent = time.monotonic()
            warned = out.wait_for('hand silent', 30.0, since=silent)
            back = out.wait_for('joint stream back', 30.0, since=silent)
            assert warned and back, out.text()[-2000:]
            assert hand.period_ms == 3 and hand.servo_on, out.text()[-2000:]
            hand.pause_stream()                # a hand that ignores the requests
            paused = time.monotonic()
            safe = out.wait_for('servos switched off', 60.0, since=paused)
            assert safe, out.text()[-2000:]
            assert wait_until(lambda: not hand.servo_on, 30.0) and np.all(hand.torques == 0)
            hand.pause_stream(False)
            assert out.wait_for('servos stay off', 30.0, since=paused), out.text()[-2000:]
            warned_at = reported_silence(out, 'hand silent', silent)
            safe_at = reported_silence(out, 'servos switched off', paused)
            assert out.proc.poll() is None, 'control off: the driver keeps running'
        finally:
            text = out.stop()
    print(f'warned {warned - silent:.3f} s after the hand fell silent (silent_warn_after '
          f'{WARN_AFTER_S}), servos off {safe - paused:.3f} s after (silent_timeout {timeout}); '
          f'the driver counted {warned_at:.2f} s and {safe_at:.2f} s of silence')
    # Bounds from below only: a stalled host delays the verdicts, never hastens them (0.01: the
    # log's rounding).
    assert safe - paused > timeout - 0.05, text[-2000:]
    assert warned_at >= WARN_AFTER_S - 0.01 and safe_at >= timeout - 0.01, text[-2000:]


def test_a_silent_hand_ends_torque_control():
    with AllegroEmulator(lambda: POSE, lambda tau: None) as hand:
        out = driver(hand, 'torque', silent_timeout=1.0)
        try:
            assert out.wait_for(STARTED, 60.0), out.text()[-2000:]
            hand.pause_stream()
            code = out.proc.wait(timeout=60.0)
        finally:
            text = out.stop()
        assert wait_until(lambda: not hand.servo_on, 30.0) and np.all(hand.torques == 0)
    assert code == EXIT_FAILURE, text[-2000:]
    assert 'hand silent' in text and 'torque control ended' in text, text[-2000:]


def test_the_driver_alone_takes_joint_torques_and_zeroes_them_when_commands_stop():
    """A user's controller: torques on /allegro_driver/torque_command reach the hand (firmware
    clamps applied); a command naming no joint of the hand is refused whole; when commands stop
    the commanded joints get zero torque after command_timeout, the servos stay on and the
    uncommanded joints keep their hold; commands that return act again."""
    names = [f'joint_{k}.0' for k in range(4)]
    wanted = np.array([0.1, -0.1, 0.05, 0.2])
    timeout = 0.2
    with AllegroEmulator(lambda: POSE, lambda tau: None) as hand, \
            rclpy_node('torque_user', DOMAIN) as node:
        host, port = hand.address
        params = ['interface:=socketcand', 'channel:=can0', f'host:={host}', f'port:={port}',
                  'rtr_requests:=false', 'control:=torque', f'command_timeout:={timeout}']
        out = OutputLines(start([executable('allegro_driver'), '--ros-args',
                                 *[a for p in params for a in ('-p', p)]], DOMAIN))
        publisher = node.create_publisher(JointState, TOPIC_TORQUE_COMMAND,
                                          publisher_qos(TOPIC_TORQUE_COMMAND))

        def command(efforts, joint_names=names):
            publisher.publish(JointState(name=joint_names, effort=list(map(float, efforts))))
            rclpy.spin_once(node, timeout_sec=0.01)

        def commanding_until(done, seconds):
            deadline = time.monotonic() + seconds
            while not done() and time.monotonic() < deadline:
                command(wanted)
            return done()

        try:
            assert out.wait_for(STARTED, 60.0), out.text()[-2000:]
            held = wait_until(lambda: hand.servo_on and np.any(hand.torques[4:] != 0), 30.0)
            assert held, 'the uncommanded joints are not held'
            assert commanding_until(
                lambda: np.allclose(hand.torques[:4], wanted, atol=0.01), 30.0), hand.torques
            last_command = time.monotonic()
            command([0.1], ['wrist'])                          # refused whole
            assert wait_until(lambda: np.all(hand.torques[:4] == 0), 30.0), hand.torques
            zeroed = time.monotonic() - last_command
            assert out.wait_for('torque command refused', 30.0), out.text()[-2000:]
            assert hand.servo_on and np.any(hand.torques[4:] != 0)
            assert out.wait_for('torque commands stopped', 30.0), out.text()[-2000:]
            assert commanding_until(
                lambda: np.allclose(hand.torques[:4], wanted, atol=0.01), 30.0), hand.torques
            assert out.wait_for('torque commands back', 30.0), out.text()[-2000:]
        finally:
            text = out.stop()
    print(f'zero torque {zeroed:.3f} s after the last command (command_timeout {timeout} s)')
    assert zeroed >= timeout - 0.02, text[-2000:]      # not before its time (a lower bound)
