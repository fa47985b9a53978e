"""sim_world's lockstep as a real process over DDS: simulated time waits for a slow consumer (a
stand-in recorder publishing /calibration/sample stamped with its clock, as slowly as a starved
node), the achieved factor is published and warned about, a consumer that stops is released
after lockstep_silence, and the scene ends (time stands still, "scene done:") at stop_after."""
import sys
import time
from pathlib import Path

import pytest
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64
from tacforce_msgs.msg import CalibrationSample

from tacforce_ros.nodes.qos import RELIABLE_QOS, publisher_qos
from tacforce_ros.nodes.messages import stamp, stamp_ns
from tacforce_ros.bringup.session_plan import SCENE_DONE_MARKER
from tacforce_ros.nodes.sim_world import CLOCK_QOS
from tacforce_ros.paths import config_dir
from tacforce_ros.sim.lockstep import JOIN_INTERVALS, PERIOD_WINDOW
from tacforce_ros.topics import TOPIC_SAMPLE

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import (OutputLines, executable, rclpy_node, spin_until, start,  # noqa: E402
                           unique_domain_id)

pytestmark = pytest.mark.ros
DOMAIN = unique_domain_id(offset=67)
STEP_NS = 10_000_000            # calibration scenes step at the tactile rate, 100 Hz
SLACK_NS = 2_000_000            # lockstep_slack's default
CONSUMER_WALL_S = 0.04          # the slow consumer: one sample per 40 ms of wall time
SLOW_SAMPLES = 60
STOP_AFTER_S = 6.0


def sample(stamp_ns: int) -> CalibrationSample:
    message = CalibrationSample()
    message.header.stamp = stamp(stamp_ns)
    return message


def test_simulated_time_waits_for_a_slow_consumer_then_releases_it_and_ends():
    proc = start([executable('sim_world'), '--ros-args', '--params-file',
                  config_dir() / 'params' / 'sim_world.yaml',
                  '-p', 'scene:=calibration_index_tip_spherical', '-p', 'xela_port:=0',
                  '-p', 'netft_port:=0', '-p', 'can_port:=0', '-p', 'report_period:=1.0',
                  '-p', f'stop_after:={STOP_AFTER_S}'], DOMAIN)
    output = OutputLines(proc)
    clocks: list[int] = []
    factors: list[float] = []
    try:
        with rclpy_node('lockstep_probe', DOMAIN) as node:
            node.create_subscription(Clock, '/clock', lambda m: clocks.append(stamp_ns(m.clock)),
                                     CLOCK_QOS)
            node.create_subscription(Float64, '/sim_world/real_time_factor',
                                     lambda m: factors.append(m.data), RELIABLE_QOS)
            samples = node.create_publisher(CalibrationSample, TOPIC_SAMPLE,
                                            publisher_qos(TOPIC_SAMPLE))
            assert spin_until(node, lambda: samples.get_subscription_count() > 0 and clocks,
                              60.0), output.text()

            # The slow consumer: one sample per simulated step, stamped with the step's time
            # (as the recorder stamps a sample with its tactile frame's), CONSUMER_WALL_S
            # apart. The samples' period is the tactile frame period, known to the gate, so it
            # holds time from the first one; from the 2 * JOIN_INTERVALS-th on (the time a
            # learnt period would have joined) no /clock may pass the gate's rule: one period
            # + slack + two steps past the newest stamp (or the time reached then, which the
            # consumer must first catch up with).
            sent: list[int] = [clocks[-1]]
            samples.publish(sample(sent[-1]))
            beyond: list[int] = []
            joined_at = None
            while len(sent) < SLOW_SAMPLES:
                wall = time.monotonic()
                seen = len(clocks)
                spin_until(node, lambda: time.monotonic() - wall >= CONSUMER_WALL_S, 10.0)
                if joined_at is not None:
                    recent = sent[-PERIOD_WINDOW - 1:]
                    intervals = sorted(b - a for a, b in zip(recent, recent[1:]))
                    limit = max(joined_at, sent[-1] + intervals[len(intervals) // 2]
                                + SLACK_NS + 2 * STEP_NS)
                    beyond += [c - limit for c in clocks[seen:]]
                if clocks[-1] >= sent[-1] + STEP_NS:
                    sent.append(sent[-1] + STEP_NS)
                    samples.publish(sample(sent[-1]))
                if len(sent) == 2 * JOIN_INTERVALS:      # sim_world has the first ones by now
                    joined_at, joined_wall = clocks[-1], time.monotonic()
            slow_wall = time.monotonic()
            assert beyond and max(beyond) <= 0, max(beyond)
            # Held by the consumer: far below the real_time_factor of 1 asked for.
            simulated = (clocks[-1] - joined_at) * 1e-9
            assert simulated < 0.5 * (slow_wall - joined_wall), (simulated, slow_wall - joined_wall)
            assert spin_until(node, lambda: factors and factors[-1] < 0.9, 10.0), factors
            assert output.wait_for('simulation slower than asked', 10.0), output.text()

            # The consumer stops: released after lockstep_silence (1 s), time runs again.
            assert output.wait_for('silent for', 10.0, since=slow_wall), output.text()
            released_at = clocks[-1]
            assert output.wait_for(SCENE_DONE_MARKER, 60.0), output.text()
            spin_until(node, lambda: False, 0.5)
            assert clocks[-1] > released_at
            assert clocks[-1] * 1e-9 == pytest.approx(STOP_AFTER_S + STEP_NS * 1e-9, abs=0.02)
            # After the scene: time stands still, the node keeps running until stopped.
            done_clock = len(clocks)
            spin_until(node, lambda: False, 1.0)
            assert all(c == clocks[done_clock - 1] for c in clocks[done_clock:])
            assert proc.poll() is None
    finally:
        text = output.stop()
    assert proc.returncode == 0, text
    print(f'\nlockstep: {len(sent)} samples {CONSUMER_WALL_S * 1e3:g} ms apart (wall); once '
          f'joined, simulated time moved {simulated:.2f} s in {slow_wall - joined_wall:.2f} s; '
          f'/clock at most {-max(beyond) * 1e-6:.1f} ms inside the gate rule; achieved factors '
          f'{[round(f, 2) for f in factors]}')
