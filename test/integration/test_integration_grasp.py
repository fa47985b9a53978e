"""A grasp through the real node graph over DDS, as `session grasp` starts it: sim_world with the
golf ball's grasp scene and its device emulators, xela_driver, estimator (the shipped models),
allegro_driver, grasp_controller and the grasp_client that sends the scene's goal (1 N) at the
scene's `goal_at`, and sync_recorder. The fixture lets go of the ball at the scene's hand-over;
from the bag (experiments/node_path.grasp_node_trace, as the main job reads its node-graph
grasp): the ball stays in the pinch, each fingertip's commanded force is held within 0.15 N
of its simulated contact force, and the first touch stays within 1.25x the command."""
import sys
import time
from pathlib import Path

import pytest

from tacforce_ros.experiments.grasp import grasp_metrics
from tacforce_ros.experiments.node_path import grasp_node_trace
from tacforce_ros.hand.description import load_hand
from tacforce_ros.hand.kinematics import HandKinematics

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bag_readers import readers_agree  # noqa: E402
from graph_support import (Graph, graph_nodes, session_args, unique_domain_id,  # noqa: E402
                           wait_while_progressing)

pytestmark = pytest.mark.ros
DOMAIN = unique_domain_id(offset=61)
SCENE = 'grasp_golf_ball'
GRIP_N = 1.0
TOLERANCE_N = 0.15
# Wall-time bounds: no progress of the scene for STALLED_AFTER_S fails the run; TIMEOUT_S ends it.
STALLED_AFTER_S, TIMEOUT_S = 60.0, 900.0
HAND = load_hand()


def test_the_node_graph_holds_a_golf_ball_at_1_n(tmp_path):
    args = session_args('grasp', offset=4, out=str(tmp_path / 'bags'), grasp_object='golf_ball',
                        grip=GRIP_N, sim_duration=11.0)
    nodes = graph_nodes(args)
    assert [n.executable for n in nodes if n.finishes] == ['grasp_client']
    running = Graph(nodes, DOMAIN, tmp_path / 'logs')
    log = tmp_path / 'logs' / 'sim_world.log'
    text = lambda: log.read_text(errors='replace') if log.is_file() else ''  # noqa: E731
    try:
        done = wait_while_progressing(lambda: 'scene done:' in text(),
                                      lambda: len(text()), STALLED_AFTER_S, TIMEOUT_S,
                                      lambda: time.sleep(0.2))
        assert done, running.logs()
    finally:
        codes = running.stop()
    assert all(c == 0 for c in codes.values()), (codes, running.logs())
    client = (tmp_path / 'logs' / 'grasp_client.log').read_text()
    assert 'sending the goal' in client and 'canceling the goal' in client, client[-2000:]

    (bag,) = (tmp_path / 'bags').iterdir()
    readers_agree(bag)
    trace = grasp_node_trace(bag, HAND, HandKinematics.for_hand(HAND), SCENE, GRIP_N)
    metrics = grasp_metrics(trace)
    print(f'\nnode-graph grasp of the golf ball at {GRIP_N:g} N: {metrics}')
    assert not metrics['dropped']
    assert metrics['finger_error_mean_n'] <= TOLERANCE_N
    assert max(metrics['peak_over_command'].values()) <= 1.25
