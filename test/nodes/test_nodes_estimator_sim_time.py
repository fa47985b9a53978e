"""The estimator under use_sim_time, as a real process with the test as the /clock source: its
stale watchdog runs on simulated time (a frozen clock never turns the estimates stale however
much wall time passes; advancing it does, stamped in simulated time), frames bring it back, and
SIGINT stops it cleanly, whichever executor the node spins."""
import sys
from pathlib import Path

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.time import Time
from rosgraph_msgs.msg import Clock
from tacforce_msgs.msg import ForceEstimateArray, TactileHand

from tacforce_ros.hand.description import load_hand
from tacforce_ros.nodes.qos import publisher_qos
from tacforce_ros.nodes.runner import EXIT_OK, events_executor
from tacforce_ros.nodes.messages import stamp_ns, tactile_hand
from tacforce_ros.estimation.model_set import write_synthetic_model_set
from tacforce_ros.bringup.session_plan import params_file
from tacforce_ros.nodes.sim_world import CLOCK_QOS

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import (executable, rclpy_node, spin_until, start, stop,  # noqa: E402
                           unique_domain_id)

pytestmark = pytest.mark.ros
DOMAIN = unique_domain_id(offset=53)
HAND = load_hand()
CLOCK_START_NS = 7_000_000_000
STALE_TIMEOUT_S = 0.025


def test_stale_watchdog_follows_the_simulated_clock(tmp_path):
    models = write_synthetic_model_set(tmp_path / 'models', HAND)
    proc = start([executable('estimator'), '--ros-args', '--params-file',
                  params_file('estimator'), '-p', f'model_config:={models}',
                  '-p', 'use_sim_time:=true', '-p', 'tare_at_start:=false',
                  '-p', f'stale_timeout:={STALE_TIMEOUT_S}', '-p', 'marker_rate_hz:=0.0',
                  '-p', 'frozen_frames:=0', '-p', 'out_of_range:=0.0'], DOMAIN)
    try:
        with rclpy_node('estimator_sim_time_test', DOMAIN) as node:
            received: list[ForceEstimateArray] = []
            node.create_subscription(ForceEstimateArray, '/tactile/estimates', received.append,
                                     100)
            clock = node.create_publisher(Clock, '/clock', CLOCK_QOS)
            frames = node.create_publisher(TactileHand, '/tactile/raw',
                                           publisher_qos('/tactile/raw'))
            assert spin_until(node, lambda: frames.get_subscription_count() > 0
                              and clock.get_subscription_count() > 0, 30.0), 'never matched'
            now = [CLOCK_START_NS]
            counts = np.full((HAND.n_taxels, 3), 20000, np.uint16)

            def tick(with_frame: bool) -> None:
                """10 ms of simulated time: /clock, then (maybe) a frame stamped with it."""
                now[0] += 10_000_000
                clock.publish(Clock(clock=Time(nanoseconds=now[0]).to_msg()))
                if with_frame:
                    frames.publish(tactile_hand(now[0], HAND, counts, None, 0.0, 1))
                spin_until(node, lambda: False, 0.01)

            def statuses() -> set[str]:
                return {m.estimates[0].status for m in received}

            # Frames flowing: valid estimates (a stale one may come first, from the jump of the
            # clock from 0 to CLOCK_START_NS before any frame).
            for _ in range(30):
                tick(with_frame=True)
            assert spin_until(node, lambda: 'ok' in statuses(), 30.0), statuses()
            # Frames stop, the clock stands still: 0.6 s of wall time, 24 stale timeouts of
            # wall time, yet nothing stale (estimates of the last frames may still come: a
            # stalled host delays them).
            spin_until(node, lambda: False, 0.3)
            received.clear()
            spin_until(node, lambda: False, 0.6)
            assert 'stale' not in statuses(), [m.estimates[0].status for m in received]
            # The simulated clock moves on without frames: stale, stamped in simulated time.
            for _ in range(8):
                tick(with_frame=False)
            assert spin_until(node, lambda: 'stale' in statuses(), 30.0), statuses()
            stale = [m for m in received if m.estimates[0].status == 'stale']
            assert all(not e.valid for m in stale for e in m.estimates)
            first_stale_ns = min(stamp_ns(m.header.stamp) for m in stale)
            assert first_stale_ns >= CLOCK_START_NS + 300_000_000 + STALE_TIMEOUT_S * 1e9 - 1
            assert first_stale_ns <= now[0]
            # Frames return: valid again.
            received.clear()
            for _ in range(10):
                tick(with_frame=True)
            assert spin_until(node, lambda: any(m.estimates[0].status == 'ok'
                                                for m in received[-3:]), 30.0), statuses()
    finally:
        output = stop(proc)
    assert proc.returncode == EXIT_OK, output
    assert 'Traceback' not in output, output


def test_executor_falls_back_where_rclpy_has_no_events_executor(monkeypatch):
    with rclpy_node('estimator_executor_test', DOMAIN):
        events = events_executor()
        assert not isinstance(events, SingleThreadedExecutor)     # this machine: Kilted
        events.shutdown()
        monkeypatch.setitem(sys.modules, 'rclpy.experimental', None)   # import fails: Humble
        fallback = events_executor()
        assert isinstance(fallback, SingleThreadedExecutor)
        fallback.shutdown()
