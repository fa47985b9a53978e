"""One input sequence through both wirings of the closed-loop core: the force_controller
node as a real process (joints, estimates and commands as messages, the test as the /clock
source) and control.finger_session.FingerSession called in-process. Every tick the node
publishes reports the inputs it acted on (joints, estimate and its freshness, f_d); fed the same,
FingerSession gives the same torques as the node sent to the hand driver, to float rounding. The
sequence engages the law, holds a force, loses the estimate for 0.3 s (the contact hold) and
steps the command after it returns."""
import sys
from pathlib import Path

import numpy as np
import pytest
from geometry_msgs.msg import Vector3, Vector3Stamped
from rclpy.time import Time
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from tacforce_msgs.msg import ControllerState, ForceEstimate, ForceEstimateArray

from tacforce_ros.control.finger_session import FingerSession
from tacforce_ros.control.force_controller import ForceControllerConfig
from tacforce_ros.hand.description import load_hand
from tacforce_ros.hand.kinematics import HandKinematics
from tacforce_ros.nodes.qos import publisher_qos, subscriber_qos
from tacforce_ros.nodes.runner import EXIT_OK
from tacforce_ros.nodes.messages import stamp, stamp_ns
from tacforce_ros.bringup.session_plan import params_file
from tacforce_ros.nodes.sim_world import CLOCK_QOS
from tacforce_ros.topics import (TOPIC_CONTROLLER_STATE, TOPIC_DESIRED, TOPIC_ESTIMATES,
                                 TOPIC_JOINTS, TOPIC_TORQUE_COMMAND)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import (executable, rclpy_node, spin_until, start, stop,  # noqa: E402
                           unique_domain_id)

pytestmark = pytest.mark.ros
DOMAIN = unique_domain_id(offset=59)
HAND = load_hand()
KIN = HandKinematics.for_hand(HAND)
START_NS = 5_000_000_000
TICK_NS = 10_000_000                 # the controller's 100 Hz
TICKS = 200
STALE = range(100, 130)              # ticks without an estimate
STEP_AT = 150
SETTLE_S = 0.03                      # wall time the inputs of a tick get before its /clock


def inputs(k: int, rng: np.random.Generator):
    """Tick k's joints (16), joint velocities, estimate in the array frame (None: none) and
    f_d in {F}."""
    q = np.linspace(0.0, 0.6, 16)
    q[:4] = [0.0, 0.6, 0.6, 0.6] + 0.01 * np.sin(0.05 * k + np.arange(4))
    qdot = np.zeros(16)
    qdot[:4] = 0.0005 * np.cos(0.05 * k + np.arange(4)) / 0.01
    f_d = np.array([0.0, 0.0, -1.0]) if k < STEP_AT else np.array([0.2, 0.0, -1.5])
    estimate = None if k in STALE else np.array([0.1, -0.05, 0.9]) + 0.02 * rng.standard_normal(3)
    return q, qdot, estimate, f_d


def drive(ticks: int, *params: str, frame_of_tick=lambda k: ''):
    """Runs the force_controller node for `ticks` ticks of inputs(k) (the test is its /clock);
    returns what it published per tick (ControllerState, torques), what was sent, its output."""
    proc = start([executable('force_controller'), '--ros-args', '--params-file',
                  params_file('force_controller'), '-p', 'use_sim_time:=true',
                  *[a for p in params for a in ('-p', p)]], DOMAIN)
    states: dict[int, ControllerState] = {}
    torques: dict[int, np.ndarray] = {}
    sent: dict[int, tuple] = {}
    try:
        with rclpy_node('two_wirings_test', DOMAIN) as node:
            clock = node.create_publisher(Clock, '/clock', CLOCK_QOS)
            joints = node.create_publisher(JointState, TOPIC_JOINTS, publisher_qos(TOPIC_JOINTS))
            estimates = node.create_publisher(ForceEstimateArray, TOPIC_ESTIMATES,
                                              publisher_qos(TOPIC_ESTIMATES))
            desired = node.create_publisher(Vector3Stamped, TOPIC_DESIRED,
                                             publisher_qos(TOPIC_DESIRED))
            node.create_subscription(
                ControllerState, TOPIC_CONTROLLER_STATE,
                lambda m: states.__setitem__(stamp_ns(m.header.stamp), m),
                subscriber_qos(TOPIC_CONTROLLER_STATE, depth=TICKS))
            node.create_subscription(
                JointState, TOPIC_TORQUE_COMMAND,
                lambda m: torques.__setitem__(stamp_ns(m.header.stamp), np.array(m.effort)),
                subscriber_qos(TOPIC_TORQUE_COMMAND, depth=TICKS))
            matched = spin_until(node, lambda: all(
                p.get_subscription_count() > 0 for p in (clock, joints, estimates, desired)),
                60.0)
            assert matched, 'the node never subscribed'
            rng = np.random.default_rng(0)
            for k in range(ticks):
                now = START_NS + (k + 1) * TICK_NS
                q, qdot, estimate, f_d = inputs(k, rng)
                sent[now] = (q, qdot, estimate, f_d)
                command = Vector3Stamped(vector=Vector3(x=f_d[0], y=f_d[1], z=f_d[2]))
                command.header.frame_id = frame_of_tick(k)
                desired.publish(command)
                msg = JointState(name=KIN.joint_names, position=q.tolist(),
                                 velocity=qdot.tolist())
                msg.header.stamp = stamp(now - 2_000_000)
                joints.publish(msg)
                if estimate is not None:
                    item = ForceEstimate(name='index_tip', valid=True, status='ok',
                                         force=Vector3(x=estimate[0], y=estimate[1],
                                                       z=estimate[2]))
                    item.header.stamp = stamp(now - 3_000_000)
                    estimates.publish(ForceEstimateArray(estimates=[item]))
                spin_until(node, lambda: False, SETTLE_S)
                clock.publish(Clock(clock=Time(nanoseconds=now).to_msg()))
                spin_until(node, lambda: now in states and now in torques, 10.0)
    finally:
        output = stop(proc)
    assert proc.returncode == EXIT_OK, output[-2000:]
    return states, torques, sent, output


def test_the_node_and_the_in_process_session_give_the_same_torques():
    config = ForceControllerConfig.from_yaml(params_file('force_controller'))
    states, torques, sent, output = drive(TICKS)
    ticks = sorted(set(states) & set(torques))
    assert len(ticks) >= 0.9 * TICKS, (len(ticks), output[-2000:])

    session = FingerSession(config, KIN)
    on_time, modes = 0, []
    by_finger_q = {tuple(v[0][:4]): v for v in sent.values()}
    for t in ticks:
        state = states[t]
        # The joints the node acted on (every tick's are distinct), and its estimate as it
        # arrived (the state carries a fresh one rotated into {F}).
        q, qdot, _, _ = by_finger_q[tuple(state.q)]
        f = np.array([state.estimated_force.x, state.estimated_force.y, state.estimated_force.z])
        if state.estimate_fresh:
            f = KIN.rotation_between(q, config.force_frame, config.estimate_frame) @ f
        f_d = np.array([state.desired_force.x, state.desired_force.y, state.desired_force.z])
        tau, replayed, _ = session.update(
            t * 1e-9, q, qdot, f, 0.0 if state.estimate_fresh else np.inf,
            0.0 if state.joints_fresh else np.inf, f_d)
        np.testing.assert_allclose(torques[t], tau, rtol=1e-9, atol=1e-12,
                                   err_msg=f'tick at {t * 1e-9:.2f} s')
        assert replayed.mode == state.mode
        modes.append(state.mode)
        on_time += np.array_equal(q, sent[t][0])
    print(f'{len(ticks)} ticks compared, {on_time} on their own tick\'s joints; modes '
          + ' '.join(f'{m}x{modes.count(m)}' for m in dict.fromkeys(modes)))
    # The sequence went through: the law engaged, held the contact through the outage.
    assert {'closed_loop', 'hold'} <= set(modes), modes
    assert on_time >= 0.8 * len(ticks)


def test_with_a_frame_prefix_the_controller_takes_and_names_its_own_frames():
    """frame_prefix left/: commands in left/ft_sensor are taken, in the bare ft_sensor refused
    (another hand's), and the controller's state is in left/ft_sensor."""
    ticks = 40
    states, _, sent, output = drive(ticks, "frame_prefix:='left/'",
                                    frame_of_tick=lambda k: 'ft_sensor' if k < 20 else
                                    'left/ft_sensor')
    assert "desired force in 'ft_sensor' refused" in output, output[-2000:]
    assert {m.header.frame_id for m in states.values()} == {'left/ft_sensor'}
    taken = [t for t, m in states.items()
             if np.allclose([m.desired_force.x, m.desired_force.y, m.desired_force.z],
                            sent[t][3])]
    first_taken = START_NS + 21 * TICK_NS        # the first prefixed command's tick
    assert taken and min(taken) >= first_taken, (sorted(taken)[:3], first_taken)
    assert len(taken) >= 0.8 * (ticks - 20), len(taken)
