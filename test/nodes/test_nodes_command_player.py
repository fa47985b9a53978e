"""command_player as a real process over DDS: values at the right times, ~/start, bad parameters."""
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
import yaml
from geometry_msgs.msg import Vector3Stamped
from rclpy.time import Time
from std_srvs.srv import Trigger

from tacforce_ros.control.command_sequence import ForceSequence
from tacforce_ros.nodes.qos import subscriber_qos
from tacforce_ros.nodes.runner import EXIT_BAD_PARAMETERS, EXIT_OK
from tacforce_ros.paths import config_dir

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import (call_service_once, executable, rclpy_node, spin_until,  # noqa: E402
                           start, stop, unique_domain_id)

pytestmark = pytest.mark.ros
DOMAIN = unique_domain_id(offset=37)
PARAMS = config_dir() / 'params' / 'command_player.yaml'
# The ramp outlasts a stall of this shared machine (up to 1.3 s seen) by enough ticks to fit.
RAMP_S = 2.0
SEQUENCE = {'frame_id': 'ft_sensor', 'segments': [
    {'duration': 0.6, 'force': [0.0, 0.0, 0.0]},
    {'duration': RAMP_S, 'force': [0.0, 0.0, -1.2], 'shape': 'ramp'},
    {'duration': 0.6, 'force': [0.3, -0.2, -2.0]}]}
RATE_HZ = 50      # given as an integer on purpose: a float parameter must accept it


@pytest.fixture(scope='module')
def ros_node():
    with rclpy_node('command_player_test', DOMAIN) as node:
        yield node


@pytest.fixture
def sequence_file(tmp_path):
    path = tmp_path / 'short.yaml'
    path.write_text(yaml.safe_dump(SEQUENCE))
    return path


def play(ros_node, sequence_file, *extra):
    received = []
    sub = ros_node.create_subscription(Vector3Stamped, '/force_controller/desired',
                                       received.append,
                                       subscriber_qos('/force_controller/desired'))
    proc = start([executable('command_player'), '--ros-args', '--params-file', PARAMS,
                  '-p', f'sequence:={sequence_file}', '-p', f'rate_hz:={RATE_HZ}', *extra],
                 DOMAIN)
    return received, sub, proc


def start_when_matched(ros_node, sub):
    """Call ~/start once the player's publisher is matched, so DDS discovery costs no values."""
    assert spin_until(ros_node, lambda: sub.get_publisher_count() > 0, 20.0), \
        'player never appeared'
    return call_service_once(ros_node, Trigger, '/command_player/start', Trigger.Request())


def test_publishes_the_sequence_values_at_their_times(ros_node, sequence_file):
    received, sub, proc = play(ros_node, sequence_file, '-p', 'autostart:=false')
    try:
        assert start_when_matched(ros_node, sub).success
        # Until a value stamped at the sequence's end (the first value is stamped at its t = 0),
        # then 0.5 s more, in which nothing more may come.
        duration = ForceSequence.from_mapping(SEQUENCE).duration

        def played() -> float:
            if not received:
                return 0.0
            return (Time.from_msg(received[-1].header.stamp).nanoseconds
                    - Time.from_msg(received[0].header.stamp).nanoseconds) * 1e-9
        reached = spin_until(ros_node, lambda: played() >= duration - 1e-3, 60.0)
        spin_until(ros_node, lambda: False, 0.5)
        assert proc.poll() is None, 'the player must stay up after the sequence'
    finally:
        output = stop(proc)
        ros_node.destroy_subscription(sub)
    assert reached, f'the sequence never reached its last value; node said:\n{output}'
    assert all(m.header.frame_id == 'ft_sensor' for m in received)
    stamps_ns = np.array([Time.from_msg(m.header.stamp).nanoseconds for m in received])
    stamps = stamps_ns * 1e-9
    values = np.array([[m.vector.x, m.vector.y, m.vector.z] for m in received])
    assert np.all(np.diff(stamps) > 0)
    # The ramp's messages fix the start time: z = -1.2 * (t - t0 - 0.6) / RAMP_S on it. Ticks
    # a stalled machine skips leave fewer of them; three fix the line.
    ramp = (values[:, 2] < -1e-9) & (values[:, 2] > -1.2 + 1e-9)
    assert ramp.sum() >= 3, 'ramp messages missing'
    slope, intercept = np.polyfit(stamps[ramp], values[ramp, 2], 1)
    assert slope == pytest.approx(-1.2 / RAMP_S, rel=1e-3)
    t0 = -intercept / slope - 0.6
    sequence = ForceSequence.from_mapping(SEQUENCE)
    expected = np.array([sequence.force_at(t - t0) for t in stamps])
    np.testing.assert_allclose(values, expected, atol=5e-3)
    # The first value is published at ~/start's first tick (t = 0), the final value once at the
    # end, and never more than one value per period in between (a late timer skips, it does
    # not burst).
    assert stamps[0] - t0 == pytest.approx(0.0, abs=1e-3)
    after_end = (stamps_ns - stamps_ns[0]) * 1e-9 >= sequence.duration
    assert after_end.sum() == 1 and after_end[-1], 'the final value comes once, last'
    assert len(stamps) <= sequence.duration * RATE_HZ + 2
    assert 'sequence finished' in output


def test_waits_for_the_start_service_when_not_autostarting(ros_node, sequence_file):
    received, sub, proc = play(ros_node, sequence_file, '-p', 'autostart:=false')
    try:
        assert spin_until(ros_node, lambda: sub.get_publisher_count() > 0, 20.0)
        spin_until(ros_node, lambda: False, 0.5)
        assert received == [], 'published before ~/start'
        reply = start_when_matched(ros_node, sub)
        assert reply.success and reply.message.startswith('started')
        assert spin_until(ros_node, lambda: len(received) >= 5, 30.0)
        assert received[0].vector.z == 0.0
        assert start_when_matched(ros_node, sub).message.startswith('restarted')
    finally:
        output = stop(proc)
        ros_node.destroy_subscription(sub)
    assert proc.returncode == EXIT_OK, output


def test_sequence_waits_for_its_subscribers(ros_node, sequence_file):
    received, sub, proc = play(ros_node, sequence_file, '-p', 'min_subscribers:=2')
    second = None
    try:
        assert spin_until(ros_node, lambda: sub.get_publisher_count() > 0, 20.0)
        spin_until(ros_node, lambda: False, 1.0)
        assert received == [], 'played with one subscriber of the two it waits for'
        second = ros_node.create_subscription(Vector3Stamped, '/force_controller/desired',
                                              lambda msg: None,
                                              subscriber_qos('/force_controller/desired'))
        assert spin_until(ros_node, lambda: len(received) >= 5, 20.0)
    finally:
        output = stop(proc)
        ros_node.destroy_subscription(sub)
        if second is not None:
            ros_node.destroy_subscription(second)
    # The sequence started from its beginning once both listened.
    assert received[0].vector.z == 0.0 and 'waiting for 2 subscribers' in output, output


@pytest.mark.parametrize('override, words', [
    ('rate_hz:=-1', ['rate_hz', '-1', 'outside']),
    ('sequence:=no_such_sequence', ['sequence', 'no_such_sequence']),
])
def test_bad_parameter_exits_non_zero_naming_it(override, words):
    proc = start([executable('command_player'), '--ros-args', '--params-file', PARAMS,
                  '-p', override], DOMAIN)
    try:
        proc.wait(timeout=30.0)
    finally:
        output = stop(proc)
    assert proc.returncode == EXIT_BAD_PARAMETERS, output
    assert all(word in output for word in words), output


def test_follows_sim_time_from_clock(ros_node, sequence_file):
    """With use_sim_time the sequence runs on /clock: here sim time runs 2x slower than wall
    time, so wall-clock timing would put the values far off the sim stamps."""
    from rosgraph_msgs.msg import Clock
    clock_pub = ros_node.create_publisher(Clock, '/clock', 10)
    received, sub, proc = play(ros_node, sequence_file, '-p', 'use_sim_time:=true')
    sim_ns = start_ns = 1000 * 10**9
    try:
        started = time.monotonic()
        while time.monotonic() < started + 60.0 and not (received
                                                         and received[-1].vector.x == 0.3):
            # Half a simulated second per wall second, on the wall clock.
            sim_ns = start_ns + int((time.monotonic() - started) * 0.5e9)
            clock_pub.publish(Clock(clock=Time(nanoseconds=sim_ns).to_msg()))
            rclpy.spin_once(ros_node, timeout_sec=0.005)
    finally:
        output = stop(proc)
        ros_node.destroy_subscription(sub)
        ros_node.destroy_publisher(clock_pub)
    assert received and received[-1].vector.x == 0.3, output
    stamps = np.array([Time.from_msg(m.header.stamp).nanoseconds for m in received]) * 1e-9
    assert np.all((stamps >= 1000.0) & (stamps <= sim_ns * 1e-9)), 'stamps are not sim time'
    values = np.array([m.vector.z for m in received])
    ramp = (values < -1e-9) & (values > -1.2 + 1e-9)
    slope, _ = np.polyfit(stamps[ramp], values[ramp], 1)
    assert slope == pytest.approx(-1.2 / RAMP_S, rel=0.05), 'the ramp must run on sim time'


def test_loop_starts_the_sequence_over(ros_node, sequence_file):
    received, sub, proc = play(ros_node, sequence_file, '-p', 'autostart:=false',
                               '-p', 'loop:=true')
    try:
        assert start_when_matched(ros_node, sub).success
        # Past the last segment (x = 0.3) and back into the first one (all zero) again.
        looped = spin_until(ros_node, lambda: any(m.vector.x == 0.3 for m in received)
                            and received[-1].vector.z == 0.0, 60.0)
    finally:
        output = stop(proc)
        ros_node.destroy_subscription(sub)
    assert looped, output
    assert 'sequence finished' not in output
