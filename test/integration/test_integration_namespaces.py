"""Two simulated hands in one ROS graph, the left hand in /left and the right in /right
(session_plan's `hand_side` and `namespace`, as `session --hand-side --namespace` and the launch
files' `hand_side:=`, `namespace:=` start them): each simulator, its drivers and estimator (a
model of that hand on every array) run in its hand's namespace, with its own /clock remapped into
it, and each estimator publishes its own hand's 18 wrench topics under its namespace and nothing
in the other's or in the root namespace; every frame id a hand's nodes publish carries its frame
prefix (left/, right/); /diagnostics, shared, names each device link by its node's full name."""
import sys
from pathlib import Path

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import WrenchStamped
from tacforce_msgs.msg import TactileHand

from tacforce_ros.hand.description import hand_config, load_hand
from tacforce_ros.nodes.qos import subscriber_qos
from tacforce_ros.topics import (TOPIC_DIAGNOSTICS, TOPIC_ESTIMATES, TOPIC_TACTILE, TOPIC_WRENCH,
                                 array_wrench_topic)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from graph_support import (Graph, graph_nodes, session_args, synthetic_model_set,  # noqa: E402
                           unique_domain_id, wait_until, with_overrides)

pytestmark = pytest.mark.ros
DOMAIN = unique_domain_id(offset=87)
# The hand's driver too: simulated time starts when its servos are on.
NODES = ('sim_world', 'xela_driver', 'ft_bridge', 'estimator', 'allegro_driver')
HANDS = {'/left': 'left', '/right': 'right'}       # namespace: hand side (and frame prefix)
TIMEOUT_S = 180.0


def test_two_hands_in_their_namespaces_publish_only_their_own_wrenches(tmp_path):
    hands = {ns: load_hand(hand_config(side)) for ns, side in HANDS.items()}
    hand = hands['/right']            # both hands have the same arrays and frame names
    graphs = []
    rclpy.init(domain_id=DOMAIN)
    probe = rclpy.create_node('namespaces_probe')
    received = {(ns, a.name): 0 for ns in HANDS for a in hand.arrays}
    frames: dict[str, set[str]] = {ns: set() for ns in HANDS}   # every frame id each hand sent

    def receiver(key):
        def receive(msg: WrenchStamped) -> None:
            received[key] += 1
            frames[key[0]].add(msg.header.frame_id)
        return receive

    def tactile(ns):
        def receive(msg: TactileHand) -> None:
            frames[ns].update([msg.header.frame_id] + [a.header.frame_id for a in msg.arrays])
        return receive

    health: set[str] = set()
    probe.create_subscription(DiagnosticArray, TOPIC_DIAGNOSTICS,
                              lambda msg: health.update(s.name for s in msg.status),
                              subscriber_qos(TOPIC_DIAGNOSTICS))
    for ns, name in received:
        topic = array_wrench_topic(name)
        probe.create_subscription(WrenchStamped, ns + topic, receiver((ns, name)),
                                  subscriber_qos(topic))
    for ns in HANDS:
        probe.create_subscription(TactileHand, ns + TOPIC_TACTILE, tactile(ns),
                                  subscriber_qos(TOPIC_TACTILE))
        probe.create_subscription(WrenchStamped, ns + TOPIC_WRENCH,
                                  lambda msg, ns=ns: frames[ns].add(msg.header.frame_id),
                                  subscriber_qos(TOPIC_WRENCH))
    try:
        for offset, (ns, side) in enumerate(HANDS.items()):
            models = synthetic_model_set(tmp_path / f'models_{side}', hands[ns])
            # Free-running: the graph has no controller for lockstep to wait for.
            args = session_args('closed_loop', offset=7 + offset, namespace=ns, lockstep=False,
                                hand_side=side, frame_prefix=f'{side}/')
            nodes = [n for n in graph_nodes(args) if n.executable in NODES]
            # synthetic models' spreads are a few counts, the simulator's noise more: their
            # range is no calibration of these frames
            graphs.append(Graph(with_overrides(nodes, estimator={'model_config': str(models),
                                                                 'out_of_range': 0.0}),
                                DOMAIN, tmp_path / f'logs{offset}'))
        expected = {ns: {f'{side}/' + f for f in [hand.base_frame, hand.ft_frame]
                         + [a.frame_id for a in hand.arrays]} for ns, side in HANDS.items()}
        assert wait_until(lambda: all(count >= 20 for count in received.values())
                          and all(expected[ns] <= frames[ns] for ns in HANDS), TIMEOUT_S,
                          lambda: rclpy.spin_once(probe, timeout_sec=0.05)), (
            sorted(k for k, v in received.items() if v < 20),
            {ns: expected[ns] - frames[ns] for ns in HANDS},
            '\n'.join(g.logs() for g in graphs))
        names = {name for name, _ in probe.get_topic_names_and_types()}
        for a in hand.arrays:
            assert array_wrench_topic(a.name) not in names, 'a wrench in the root namespace'
            for ns in HANDS:
                publishers = probe.get_publishers_info_by_topic(ns + array_wrench_topic(a.name))
                assert [(p.node_name, p.node_namespace) for p in publishers] == \
                    [('estimator', ns)], publishers
        assert {'/left/clock', '/right/clock'} <= names
        for ns in HANDS:        # and nothing else: no bare frame, none of the other hand's
            assert frames[ns] == expected[ns], (ns, frames[ns] ^ expected[ns])
        assert TOPIC_ESTIMATES not in names
        for ns in HANDS:
            publishers = probe.get_publishers_info_by_topic(ns + TOPIC_ESTIMATES)
            assert [(p.node_name, p.node_namespace) for p in publishers] == [('estimator', ns)]
        # One /diagnostics for both hands, each device link under its node's full name.
        links = {f'{ns}/{driver}: device link' for ns in HANDS
                 for driver in ('xela_driver', 'allegro_driver')}
        assert wait_until(lambda: links <= health, 10.0,
                          lambda: rclpy.spin_once(probe, timeout_sec=0.05)), health
    finally:
        probe.destroy_node()
        rclpy.shutdown()
        codes = [g.stop() for g in graphs]
    assert all(c == 0 for graph_codes in codes for c in graph_codes.values()), codes
