"""The whole hand over DDS in simulation, with the shipped models: sim_world runs the press tour
(every array pressed in turn on the flat plate, 4 s each) -> xela_driver -> estimator with the
default model list. A third-party subscriber sees every array's wrench topic; a press on an
array shows on that array's topic and on no other array's beyond its noise and the skin's
crosstalk to the arrays next to it (the simulator couples neighbours, as the real skin does).
"""
import sys
from pathlib import Path

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import WrenchStamped
from rclpy.qos import QoSProfile, ReliabilityPolicy
from tacforce_msgs.msg import ForceEstimateArray

from tacforce_ros.estimation.model_set import default_model_config, model_files
from tacforce_ros.hand.description import load_hand
from tacforce_ros.nodes.qos import subscriber_qos
from tacforce_ros.nodes.messages import stamp_ns
from tacforce_ros.sim import load_scene

sys.path.insert(0, str(Path(__file__).resolve().parent))
from graph_support import (Graph, graph_nodes, session_args, unique_domain_id,  # noqa: E402
                           wait_while_progressing, with_overrides)

pytestmark = pytest.mark.ros
DOMAIN = unique_domain_id(offset=93)
NODES = ('sim_world', 'xela_driver', 'estimator')
STALLED_AFTER_S = 60.0
TIMEOUT_S = 900.0
PRESSED_N = 1.0            # the tour presses 1.5-3 N (config/scenes/press_tour.yaml)
# What an array not pressed may show: its estimate's noise (peaks of ~0.1 N over a block with
# the shipped models) and the skin's crosstalk from a press next to it (~0.15 N); a sixth of
# the weakest press the tour makes.
ELSEWHERE_N = 0.25
EDGE_S = 0.3               # judged: each block less this at both ends (stamps, clock offsets)
# Simulated time runs free here, so a frame late on a loaded machine is rightly flagged stale
# (CI once saw one such spell on all 18 arrays at once); the test is about where a press shows,
# so it allows stale spells over this fraction of the lap's estimates, and nothing else invalid.
STALE_FRACTION = 0.02


def test_a_press_on_any_array_shows_on_its_own_topic(tmp_path):
    hand = load_hand()
    tour = load_scene('press_tour')
    assert sorted(tour.press_tour) == sorted(a.name for a in hand.arrays)
    assert sorted(model_files(default_model_config(hand))) == sorted(tour.press_tour)
    nodes = [n for n in graph_nodes(session_args('closed_loop', offset=3))
             if n.executable in NODES]
    # Free-running simulated time (a calibration scene holds time only for a recorder): a frame
    # late on a loaded machine is not what this test is about, so staleness waits longer.
    nodes = with_overrides(nodes, sim_world={'scene': 'press_tour', 'lockstep': False,
                                             'real_time_factor': 2.0},
                           estimator={'stale_timeout': 0.5})
    lap = tour.duration * len(tour.press_tour)
    forces = {a.name: [] for a in hand.arrays}
    truth, invalid, published = [], [], []
    running = Graph(nodes, DOMAIN, tmp_path / 'logs')
    rclpy.init(domain_id=DOMAIN)
    node = rclpy.create_node('press_tour_probe')
    qos = QoSProfile(depth=400, reliability=ReliabilityPolicy.RELIABLE)

    def receiver(name):
        return lambda m: forces[name].append(
            (stamp_ns(m.header.stamp) * 1e-9, m.wrench.force.x, m.wrench.force.y,
             m.wrench.force.z))

    def estimates(msg: ForceEstimateArray):
        t = stamp_ns(msg.header.stamp) * 1e-9
        published.append(t)
        invalid.extend((t, e.name, e.status) for e in msg.estimates if not e.valid)

    subs = [node.create_subscription(WrenchStamped, f'/tactile/{a.name}/wrench',
                                     receiver(a.name), qos) for a in hand.arrays]
    subs.append(node.create_subscription(
        WrenchStamped, '/sim/contact_force',
        lambda m: truth.append((stamp_ns(m.header.stamp) * 1e-9, m.header.frame_id,
                                np.linalg.norm([m.wrench.force.x, m.wrench.force.y,
                                                m.wrench.force.z]))), qos))
    subs.append(node.create_subscription(ForceEstimateArray, '/tactile/estimates', estimates,
                                         subscriber_qos('/tactile/estimates')))

    def judged_end():
        """The end of the first whole tour (every array's topic heard from its start)."""
        starts = [f[0][0] for f in forces.values() if f]
        return len(starts) == len(forces) and \
            np.ceil(max(starts) / tour.duration) * tour.duration + lap
    try:
        assert wait_while_progressing(
            lambda: judged_end() and min(f[-1][0] for f in forces.values()) > judged_end() + 0.5,
            lambda: sum(len(f) for f in forces.values()), STALLED_AFTER_S, TIMEOUT_S,
            lambda: rclpy.spin_once(node, timeout_sec=0.02)), running.logs()
    finally:
        for sub in subs:
            node.destroy_subscription(sub)
        node.destroy_node()
        rclpy.shutdown()
        codes = running.stop()
    assert all(c == 0 for c in codes.values()), (codes, running.logs())
    end = judged_end()
    start = end - lap
    judged = [i for i in invalid if start <= i[0] < end]
    assert all(status == 'stale' for _, _, status in judged), judged[:5]
    stale = len({t for t, _, _ in judged})
    assert stale <= STALE_FRACTION * sum(start <= t < end for t in published), (stale, judged[:5])
    series = {name: np.asarray(f) for name, f in forces.items()}
    # Each array's estimate relative to its own reading over the lap (pressed 1/18 of it): the
    # tare taken at start-up may have caught a press; the response to a press may not.
    deviation = {}
    for name, s in series.items():
        inside = (s[:, 0] >= start) & (s[:, 0] < end)
        deviation[name] = (s[inside, 0],
                           np.linalg.norm(s[inside, 1:] - np.median(s[inside, 1:], axis=0), axis=1))
    truth = [(t, frame, f) for t, frame, f in truth if start <= t < end]
    pressed_peak, worst_elsewhere = {}, {}
    first_block = int(round(start / tour.duration))
    for block in range(first_block, first_block + len(tour.press_tour)):
        pressed = tour.press_tour[block % len(tour.press_tour)]
        lo, hi = block * tour.duration + EDGE_S, (block + 1) * tour.duration - EDGE_S
        frames = {frame for t, frame, f in truth if lo <= t < hi}
        assert frames == {hand.array(pressed).frame_id}, (pressed, frames)
        peak = {name: d[(t >= lo) & (t < hi)].max() for name, (t, d) in deviation.items()}
        elsewhere = max((v, n) for n, v in peak.items() if n != pressed)
        pressed_peak[pressed], worst_elsewhere[pressed] = peak[pressed], elsewhere
        assert peak[pressed] > PRESSED_N, (pressed, peak[pressed])
        assert elsewhere[0] < ELSEWHERE_N, (pressed, elsewhere)
    weakest, elsewhere = min(pressed_peak.values()), max(worst_elsewhere.values())
    print(f'\npress tour: the weakest press read {weakest:.2f} N on its own topic; the most '
          f'another array showed {elsewhere[0]:.2f} N ({elsewhere[1]}); {stale} stale estimates')
