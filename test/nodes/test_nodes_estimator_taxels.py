"""The estimator node with faulty taxels in its input (a real process over DDS): a stuck, a dead and
a clipped taxel, one after another on three arrays, each make their array's estimate invalid with
a status naming the taxel, while the other arrays stay valid; /diagnostics says WARN naming each,
and OK again once the frames are healthy."""
import sys
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from tacforce_msgs.msg import ForceEstimateArray, TactileHand

from tacforce_ros.bringup.session_plan import params_file
from tacforce_ros.estimation.model_set import load_model_set, write_synthetic_model_set
from tacforce_ros.hand.description import load_hand
from tacforce_ros.nodes.messages import stamp_ns, tactile_hand
from tacforce_ros.nodes.qos import publisher_qos, subscriber_qos
from tacforce_ros.nodes.runner import EXIT_OK

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import (executable, rclpy_node, spin_until, start, stop,  # noqa: E402
                           unique_domain_id)

pytestmark = pytest.mark.ros
DOMAIN = unique_domain_id(offset=53)
HAND = load_hand()
# (array, taxel, how its reading goes wrong, the status the estimate must carry)
FAULTS = [('index_middle', 4, 'stuck', 'taxel 4 frozen'),
          ('thumb_tip', 2, 'dead', 'taxel 2 clipped (reads 0)'),
          ('ring_distal', 1, 'clipped', 'taxel 1 clipped (reads 65535)')]


def test_faulty_taxels_are_named_on_the_estimates_and_on_diagnostics(tmp_path):
    models = write_synthetic_model_set(tmp_path / 'models', HAND)
    rest = HAND.merge([b.x_offset for b in load_model_set(models, HAND).estimator.bundles])
    rng = np.random.default_rng(0)
    proc = start([executable('estimator'), '--ros-args', '--params-file',
                  params_file('estimator'), '-p', f'model_config:={models}',
                  '-p', 'tare_frames:=5', '-p', 'marker_rate_hz:=0.0',
                  '-p', 'diagnostics_period:=0.5',
                  # the synthetic models' spreads are a few counts: their range is not the test
                  '-p', 'out_of_range:=0.0'], DOMAIN)
    output = ''
    try:
        with rclpy_node('estimator_taxels_test', DOMAIN) as node:
            estimates, diagnostics = {}, []
            node.create_subscription(
                ForceEstimateArray, '/tactile/estimates',
                lambda m: estimates.__setitem__(stamp_ns(m.header.stamp), m), 200)
            node.create_subscription(DiagnosticArray, '/diagnostics', diagnostics.append,
                                     subscriber_qos('/diagnostics'))
            publisher = node.create_publisher(TactileHand, '/tactile/raw',
                                              publisher_qos('/tactile/raw'))
            assert spin_until(node, lambda: publisher.get_subscription_count() > 0, 30.0)
            stamp = [1_000_000_000]

            def send(fault=None, held=None) -> int:
                frame = np.round(rest + rng.normal(0.0, (1.0, 0.9, 3.1), rest.shape))
                if fault is not None:
                    array, taxel, kind, _ = fault
                    row = HAND.array(array).flat_indices[taxel]
                    frame[row] = {'stuck': held, 'dead': 0.0}.get(kind, frame[row])
                    if kind == 'clipped':
                        frame[row, 2] = 65535.0
                stamp[0] += 10_000_000
                publisher.publish(tactile_hand(stamp[0], HAND, frame.astype(np.uint16), None,
                                               0.0, 1))
                spin_until(node, lambda: False, 0.01)
                return stamp[0]

            assert spin_until(node, lambda: send() in estimates, 30.0), 'no estimates'
            names = [a.name for a in HAND.arrays]
            for fault in FAULTS:
                k = names.index(fault[0])
                held = np.round(rest[HAND.array(fault[0]).flat_indices[fault[1]]])
                sent = [send(fault, held) for _ in range(40)]     # > the 25 frozen frames
                assert spin_until(node, lambda: sent[-1] in estimates, 30.0)
                last = estimates[sent[-1]].estimates
                assert not last[k].valid and last[k].status == fault[3], last[k]
                assert all(e.valid and e.status == 'ok' for i, e in enumerate(last) if i != k)

            def warned(fault) -> bool:
                return any(s.level == DiagnosticStatus.WARN and s.name.endswith(': taxels')
                           and f'{fault[0]}: {fault[3]}' in s.message
                           for m in diagnostics for s in m.status)

            assert spin_until(node, lambda: all(warned(f) for f in FAULTS), 10.0), diagnostics
            diagnostics.clear()
            for _ in range(120):                                 # 1.2 s of healthy frames
                send()
            assert spin_until(node, lambda: any(
                s.level == DiagnosticStatus.OK and s.message == 'no faulty taxel'
                for m in diagnostics for s in m.status), 10.0), diagnostics
    finally:
        output = stop(proc)
    assert proc.returncode == EXIT_OK, output
    assert 'index_middle: taxel 4 frozen; its estimate is invalid' in output, output
