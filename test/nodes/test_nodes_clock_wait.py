"""Drivers under use_sim_time stamp nothing before the first /clock: xela_driver as a real
process reading a real xela_server emulator, with the test as the clock source."""
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from rclpy.time import Time
from rosgraph_msgs.msg import Clock
from tacforce_msgs.msg import TactileHand

from tacforce_ros.hand.description import load_hand
from tacforce_ros.nodes.qos import subscriber_qos
from tacforce_ros.nodes.runner import EXIT_OK
from tacforce_ros.nodes.sim_world import CLOCK_QOS
from tacforce_ros.paths import config_dir
from tacforce_ros.sim.emulators.xela_server import XelaServerEmulator
from tacforce_ros.topics import TOPIC_TACTILE

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import (executable, rclpy_node, spin_until, start, stop,  # noqa: E402
                           unique_domain_id)

pytestmark = pytest.mark.ros
DOMAIN = unique_domain_id(offset=61)
HAND = load_hand()
CLOCK_START_NS = 5_000_000_000


def test_xela_driver_waits_for_the_first_clock(tmp_path):
    counts = np.full((HAND.n_taxels, 3), 32000, np.uint16)
    temperatures = np.full(HAND.n_taxels, 300.0)
    source = lambda: (counts, temperatures, time.time())    # noqa: E731 - own clock: Unix
    with XelaServerEmulator(source, rate_hz=100.0) as server, \
            rclpy_node('clock_wait_test', DOMAIN) as node:
        frames = []
        node.create_subscription(TactileHand, TOPIC_TACTILE, frames.append,
                                 subscriber_qos(TOPIC_TACTILE))
        clock = node.create_publisher(Clock, '/clock', CLOCK_QOS)
        proc = start([executable('xela_driver'), '--ros-args', '--params-file',
                      config_dir() / 'params' / 'xela_driver.yaml', '-p', 'use_sim_time:=true',
                      '-p', f'url:=ws://127.0.0.1:{server.address[1]}',
                      '-p', 'server_clock:=own'], DOMAIN)
        try:
            # Connected and receiving (the server logs what it sent), yet nothing published.
            assert spin_until(node, lambda: len(server.sent_log) > 50, 60.0), 'never connected'
            spin_until(node, lambda: False, 0.5)    # the driver's reads of those frames
            assert frames == [], 'frames published before any /clock'
            # 10 ms clock ticks until 50 frames came (bounded: 60 s of wall time).
            now, deadline = CLOCK_START_NS, time.monotonic() + 60.0
            while len(frames) < 50 and time.monotonic() < deadline:
                clock.publish(Clock(clock=Time(nanoseconds=now).to_msg()))
                now += 10_000_000
                spin_until(node, lambda: False, 0.01)
        finally:
            output = stop(proc)
    assert proc.returncode == EXIT_OK, output
    assert len(frames) >= 50, f'only {len(frames)} frames once the clock ran'
    stamps = [Time.from_msg(f.header.stamp).nanoseconds for f in frames]
    assert min(stamps) >= CLOCK_START_NS
    assert 'dropped' in output and 'came before it' in output, output
