"""The estimator node as a real process over DDS: it tares on its first frames, then every frame's
estimates and per-array wrenches equal the model set's own estimate with that tare; a frame that
does not match the hand is dropped (logged) and the stream goes on; ~/tare re-tares; without
frames the estimates turn invalid ("stale")."""
import sys
from pathlib import Path

import numpy as np
import pytest
from geometry_msgs.msg import WrenchStamped
from std_srvs.srv import Trigger
from tacforce_msgs.msg import ForceEstimateArray, TactileHand

from tacforce_ros.hand.description import load_hand
from tacforce_ros.nodes.qos import publisher_qos
from tacforce_ros.nodes.runner import EXIT_OK
from tacforce_ros.nodes.messages import stamp_ns, tactile_hand
from tacforce_ros.estimation.model_set import load_model_set, write_synthetic_model_set
from tacforce_ros.bringup.session_plan import params_file

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import (call_service, executable, rclpy_node, spin_until, start,  # noqa: E402
                           stop, unique_domain_id)

pytestmark = pytest.mark.ros
DOMAIN = unique_domain_id(offset=47)
HAND = load_hand()
TARE_FRAMES = 5


@pytest.fixture(scope='module')
def models(tmp_path_factory):
    return write_synthetic_model_set(tmp_path_factory.mktemp('models'), HAND)


def frames(seed: int, rest: np.ndarray, count: int, press: float = 0.0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [np.clip(np.round(rest + press * rng.uniform(0, 1, rest.shape)
                             + rng.normal(0, 2, rest.shape)), 0, 65535).astype(np.uint16)
            for _ in range(count)]


def test_estimates_follow_the_model_set_with_the_node_tare(models, tmp_path):
    reference = load_model_set(models, HAND)
    rest = HAND.merge([b.x_offset for b in reference.estimator.bundles]) + 30.0   # drifted
    proc = start([executable('estimator'), '--ros-args', '--params-file',
                  params_file('estimator'), '-p', f'model_config:={models}',
                  '-p', f'tare_frames:={TARE_FRAMES}', '-p', 'marker_rate_hz:=0.0',
                  '-p', 'frozen_frames:=0', '-p', 'out_of_range:=0.0'], DOMAIN)
    output = ''
    try:
        with rclpy_node('estimator_node_test', DOMAIN) as node:
            estimates, wrenches = {}, {}
            node.create_subscription(
                ForceEstimateArray, '/tactile/estimates',
                lambda m: estimates.__setitem__(stamp_ns(m.header.stamp), m), 100)
            for k, array in enumerate(HAND.arrays):
                node.create_subscription(
                    WrenchStamped, f'/tactile/{array.name}/wrench',
                    lambda m, k=k: wrenches.setdefault(stamp_ns(m.header.stamp), {}).__setitem__(
                        k, m), 100)
            publisher = node.create_publisher(TactileHand, '/tactile/raw',
                                              publisher_qos('/tactile/raw'))
            assert spin_until(node, lambda: publisher.get_subscription_count() > 0, 30.0)
            stamp = [1_000_000_000]

            def send(counts: np.ndarray, arrays=None) -> int:
                stamp[0] += 10_000_000
                msg = tactile_hand(stamp[0], HAND, counts, None, 0.0, 1)
                if arrays is not None:
                    msg.arrays = msg.arrays[:arrays]
                publisher.publish(msg)
                spin_until(node, lambda: False, 0.02)
                return stamp[0]

            def check(sent: dict[int, np.ndarray]) -> None:
                assert spin_until(node, lambda: all(s in estimates for s in sent), 30.0)
                for s, counts in sent.items():
                    expected = reference.estimate(counts)
                    got = estimates[s].estimates
                    assert [e.name for e in got] == [a.name for a in HAND.arrays]
                    assert all(e.valid and e.status == 'ok' for e in got)
                    force = np.array([[e.force.x, e.force.y, e.force.z] for e in got])
                    np.testing.assert_allclose(force, expected.force, rtol=0, atol=1e-9)
                    np.testing.assert_allclose([e.ood_score for e in got], expected.ood_score,
                                               rtol=1e-6)
                    assert spin_until(node, lambda: len(wrenches.get(s, ())) == len(got), 30.0)
                    for k, wrench in wrenches[s].items():
                        assert wrench.header.frame_id == HAND.arrays[k].frame_id
                        np.testing.assert_array_equal(
                            [wrench.wrench.force.x, wrench.wrench.force.y,
                             wrench.wrench.force.z], force[k])

            # Identical rest frames: whichever of them the node tares on, its tare is `rest`.
            rest = frames(1, rest, 1)[0]
            first = send(rest)
            assert spin_until(node, lambda: send(rest) in estimates, 30.0)
            assert first not in estimates       # nothing published before the tare
            reference.set_tare(rest[None].astype(np.float64))
            pressed = {send(c): c for c in frames(2, rest, 5, press=400.0)}
            check(pressed)

            refused = send(frames(3, rest, 1)[0], arrays=len(HAND.arrays) - 1)
            after = {send(c): c for c in frames(4, rest, 3, press=400.0)}
            check(after)
            assert refused not in estimates

            assert call_service(node, Trigger, '/estimator/tare', Trigger.Request(),
                                resend_after=5.0).success       # a second tare is harmless
            rest = frames(5, rest - 55.0, 1)[0]
            reference.set_tare(rest[None].astype(np.float64))
            at_rest = reference.estimate(rest).force

            def retared() -> bool:      # estimates go on meanwhile, with the old tare
                s = send(rest)
                spin_until(node, lambda: s in estimates, 1.0)
                return s in estimates and np.allclose(
                    [[e.force.x, e.force.y, e.force.z] for e in estimates[s].estimates],
                    at_rest, rtol=0, atol=1e-9)

            assert spin_until(node, retared, 30.0)
            check({send(c): c for c in frames(6, rest, 3, press=400.0)})

            estimates.clear()
            assert spin_until(node, lambda: any(
                m.estimates[0].status == 'stale' for m in estimates.values()), 30.0)
            stale = [m for m in estimates.values() if m.estimates[0].status == 'stale']
            assert all(not e.valid and e.ood_score == np.inf for m in stale for e in m.estimates)
    finally:
        output = stop(proc)
    assert proc.returncode == EXIT_OK, output      # SIGINT: a clean stop
    assert 'tactile frame refused' in output and 'arrays, the hand has' in output, output


def test_low_pass_estimates_are_the_core_filter_on_the_frames_received(models):
    """lowpass_hz on: each estimate equals the core estimator's with the same low-pass, fed the
    frames the node received (a best-effort loss would change the filter state, so the
    reference skips what the node did not get), and the group delay is logged."""
    reference = load_model_set(models, HAND)
    reference.estimator.set_lowpass(10.0, 100.0, 2)
    rest = HAND.merge([b.x_offset for b in reference.estimator.bundles])
    proc = start([executable('estimator'), '--ros-args', '--params-file',
                  params_file('estimator'), '-p', f'model_config:={models}',
                  '-p', f'tare_frames:={TARE_FRAMES}', '-p', 'marker_rate_hz:=0.0',
                  '-p', 'frozen_frames:=0', '-p', 'out_of_range:=0.0',
                  '-p', 'lowpass_hz:=10.0'], DOMAIN)
    try:
        with rclpy_node('estimator_lowpass_test', DOMAIN) as node:
            estimates = {}
            node.create_subscription(
                ForceEstimateArray, '/tactile/estimates',
                lambda m: estimates.__setitem__(stamp_ns(m.header.stamp), m), 100)
            publisher = node.create_publisher(TactileHand, '/tactile/raw',
                                              publisher_qos('/tactile/raw'))
            assert spin_until(node, lambda: publisher.get_subscription_count() > 0, 30.0)
            rest = frames(1, rest, 1)[0]
            sent = {}
            stamp = 1_000_000_000
            # Rest until the tare is done and estimates flow, then a press (a step), held.
            for counts in [rest] * 200 + frames(2, rest, 1, press=400.0) * 30:
                stamp += 10_000_000
                publisher.publish(tactile_hand(stamp, HAND, counts, None, 0.0, 1))
                sent[stamp] = counts
                spin_until(node, lambda: False, 0.02)
            assert spin_until(node, lambda: max(sent) in estimates, 30.0), 'no estimate of the end'
    finally:
        output = stop(proc)
    assert proc.returncode == EXIT_OK, output
    assert 'input low-pass 10 Hz, order 2 at 100 frames/s: group delay 21.8 ms' in output, output
    received = sorted(s for s in sent if s in estimates)
    reference.set_tare(rest[None].astype(np.float64))
    got = np.array([[[e.force.x, e.force.y, e.force.z] for e in estimates[s].estimates]
                    for s in received])
    expected = np.array([reference.estimate(sent[s]).force.copy() for s in received])
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    # The press reached the estimate through the filter: a ramp over frames, not one jump.
    z = got[-30:, 0, 2]
    assert np.count_nonzero(np.abs(np.diff(z)) > 1e-6) >= 3
