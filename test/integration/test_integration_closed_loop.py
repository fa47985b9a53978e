"""The closed loop through the real node graph over DDS (its must-show): sim_world with the
project's closed-loop scene on the spherical plate, its device emulators, xela_driver,
ft_bridge, estimator (the default model of config/models/), allegro_driver, force_controller
(config/params/force_controller.yaml), command_player and sync_recorder, as `session closed_loop`
starts them. A 2 N press is held within 0.2 N of the simulator's ground truth.

The command: f_d = 0 while the finger holds its start pose clear of the plate and the estimator
tares, a 1 s ramp to 2 N into the plate (-z in {F}), then HOLD_S of 2 N. Judged over the last
WINDOW_S of the hold (the first seconds are the approach and the integral settling), on the
recorded bag: the F/T reading (the paper's ground truth f~, in {F} as f_d; zeroed before the
press while the finger is clear of the plate) against the recorded f_d, as
tacforce_ros/experiments/node_path.py reads a node run.
"""
import sys
from pathlib import Path

import numpy as np
import pytest
import rclpy
import yaml
from tacforce_msgs.msg import ControllerState

from tacforce_ros import bagio
from tacforce_ros.control.command_sequence import ForceSequence
from tacforce_ros.experiments.closed_loop import trace_metrics
from tacforce_ros.experiments.node_path import node_trace
from tacforce_ros.experiments.settings import tare_frames
from tacforce_ros.nodes.qos import subscriber_qos
from tacforce_ros.nodes.messages import stamp_ns
from tacforce_ros.topics import TOPIC_CONTROLLER_STATE as TOPIC_STATE

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bag_readers import readers_agree  # noqa: E402
from graph_support import (Graph, graph_nodes, session_args, unique_domain_id,  # noqa: E402
                           wait_while_progressing, with_overrides)

pytestmark = pytest.mark.ros
DOMAIN = unique_domain_id(offset=89)
TARGET_N = 2.0
TOLERANCE_N = 0.2
ZERO_S, RAMP_S, HOLD_S, WINDOW_S = 3.0, 1.0, 10.0, 5.0
# At most real time: sim_world's lockstep holds simulated time for the controller, the estimate
# and the joint stream, so two shared cores make the run slower, not different.
REAL_TIME_FACTOR = 1.0
# Wall-time bounds: no controller tick for STALLED_AFTER_S fails the run; TIMEOUT_S ends it.
STALLED_AFTER_S, TIMEOUT_S = 60.0, 1200.0


def press_sequence(path: Path) -> Path:
    path.write_text(yaml.safe_dump({'frame_id': 'ft_sensor', 'segments': [
        {'duration': ZERO_S, 'force': [0.0, 0.0, 0.0]},
        {'duration': RAMP_S, 'force': [0.0, 0.0, -TARGET_N], 'shape': 'ramp'},
        {'duration': HOLD_S, 'force': [0.0, 0.0, -TARGET_N]}]}))
    return path


def seconds(header) -> float:
    return stamp_ns(header.stamp) * 1e-9


def test_node_graph_holds_a_2_n_press_within_0_2_n(tmp_path):
    args = session_args('closed_loop', offset=2, out=str(tmp_path / 'bags'),
                        real_time_factor=REAL_TIME_FACTOR)
    sequence = press_sequence(tmp_path / 'press.yaml')
    nodes = with_overrides(graph_nodes(args), command_player={'sequence': str(sequence)})
    running = Graph(nodes, DOMAIN, tmp_path / 'logs')
    states: list[ControllerState] = []
    rclpy.init(domain_id=DOMAIN)
    probe = rclpy.create_node('closed_loop_probe')
    probe.create_subscription(ControllerState, TOPIC_STATE, states.append,
                              subscriber_qos(TOPIC_STATE))
    try:
        # Until the controller has played the whole sequence (simulated time), for as long as
        # simulated time advances: a starved machine runs the simulation slower than asked
        # (0.03x seen here), which must make the run slower, not different.
        def finished() -> bool:
            engaged = [s for s in states if s.desired_force.z < 0.0]
            return bool(engaged) and seconds(states[-1].header) > (
                seconds(engaged[0].header) + RAMP_S + HOLD_S)
        assert wait_while_progressing(
            finished, lambda: len(states), STALLED_AFTER_S, TIMEOUT_S,
            lambda: rclpy.spin_once(probe, timeout_sec=0.05)), \
            ([s.mode for s in states[-5:]], running.logs())
    finally:
        probe.destroy_node()
        rclpy.shutdown()
        codes = running.stop()
    assert all(c == 0 for c in codes.values()), (codes, running.logs())

    (bag,) = (tmp_path / 'bags').iterdir()
    # The session's bag is one MCAP file that rosbags, Foxglove's mcap reader and its metadata
    # read alike (per-topic counts).
    assert len(bagio.bag_files(bag)) == 1
    readers_agree(bag)
    trace, _ = node_trace(bag, ForceSequence.load(sequence), tare_frames())
    hold_end = ZERO_S + RAMP_S + HOLD_S
    window = (hold_end - WINDOW_S, hold_end - 0.1)
    inside = (trace.t >= window[0]) & (trace.t <= window[1])
    metrics = trace_metrics([trace], window)
    print(f'\nnode-graph 2 N hold over t = {window[0]:g}..{window[1]:g} s of the sequence '
          f'(simulated): e~ {metrics["e_tilde_mean"]} N (F/T zeroed before the press), '
          f'e_track {metrics["e_track_mean"]} N (None: no fresh estimate), mean f~ '
          f'{np.round(trace.f_tilde[inside].mean(axis=0), 3)} N, estimate fresh on '
          f'{metrics["estimate_coverage"]:.1%} of the ticks; controller modes: '
          f'{sorted({s.mode for s in states})}, {sum(s.mode == "safe" for s in states)} '
          f'ticks safe')
    # Enough ticks to judge the hold by; the rate itself is bench_graph's to measure (a CI host
    # at load 5.4 recorded 385 of the window's 490 ticks: lockstep lets simulated time run up
    # to a period and a little ahead of a starved controller, whose timer then skips a tick).
    assert metrics['samples'] >= 0.5 * (window[1] - window[0]) * 100
    assert np.allclose(trace.f_d[inside], [0.0, 0.0, -TARGET_N])
    # The loop runs closed on a fresh estimate, but for a rare watchdog trip of a starved
    # process, and holds that estimate on f_d ...
    assert metrics['estimate_coverage'] >= 0.95
    assert metrics['e_track_mean'] <= 0.05
    # ... and the force on the plate is the commanded one.
    assert metrics['e_tilde_mean'] <= TOLERANCE_N
