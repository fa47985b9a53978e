"""grasp_controller as a real process, through its Grasp action: every goal that cannot run ends
FAILED with its reason, a second goal while one runs is refused, a cancel releases (RELEASED,
canceled) and parks the fingers at their start poses, a hold time ends HELD, an object lost from
every fingertip ends the goal FAILED as dropped, and a controller stopped mid-goal still answers
it (FAILED). The test is the hand and the estimator: it publishes the joints of the golf ball's
pinch pose (config/scenes/grasp_golf_ball.yaml) and each fingertip's estimate over DDS, from a
Python timer, so the node is given stale limits a loaded machine cannot trip."""
import sys
from pathlib import Path

import numpy as np
import pytest
import rclpy
import yaml
from action_msgs.msg import GoalStatus
from geometry_msgs.msg import Vector3
from rclpy.action import ActionClient
from sensor_msgs.msg import JointState
from tacforce_msgs.action import Grasp
from tacforce_msgs.msg import ForceEstimate, ForceEstimateArray

from tacforce_ros.control.grasp import approach_targets
from tacforce_ros.estimation.model_set import default_model_config
from tacforce_ros.hand.description import load_hand
from tacforce_ros.hand.kinematics import HandKinematics
from tacforce_ros.hand.pinch import joint_limits
from tacforce_ros.nodes.messages import stamp
from tacforce_ros.nodes.qos import publisher_qos, subscriber_qos
from tacforce_ros.nodes.runner import EXIT_OK
from tacforce_ros.bringup.session_plan import params_file
from tacforce_ros.sim import load_scene
from tacforce_ros.topics import TOPIC_ESTIMATES, TOPIC_JOINTS, TOPIC_TORQUE_COMMAND

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import (OutputLines, executable, rclpy_node, spin_until,  # noqa: E402
                           start, unique_domain_id)

pytestmark = pytest.mark.ros
DOMAIN = unique_domain_id(offset=73)
HAND = load_hand()
KIN = HandKinematics.for_hand(HAND)
SCENE = load_scene('grasp_golf_ball')
FINGERS = ('thumb', 'index')
WAIT_S = 60.0          # wall-clock bound on any one wait (a loaded machine)
# The test's timers publish only while it spins: freshness limits far above its gaps.
LENIENT = ['-p', 'force_controller.joints_timeout:=1.0',
           '-p', 'force_controller.estimate_timeout:=1.0']


def pinch_pose() -> np.ndarray:
    q = np.asarray(SCENE.grasp['hand_pose'], np.float64).copy()
    for finger, poses in SCENE.grasp['fingers'].items():
        q[KIN.finger_joints(finger)] = poses['pose']
    return q


def targets(fingers=FINGERS) -> list[float]:
    lower, upper = joint_limits(KIN)
    poses = {f: (SCENE.grasp['fingers'][f]['pose'], SCENE.grasp['fingers'][f]['contact_pose'])
             for f in fingers}
    found = approach_targets(poses, KIN, lower, upper)
    return [v for f in fingers for v in found[f]]


def goal(fingers=FINGERS, grip=1.0, angles=None) -> Grasp.Goal:
    return Grasp.Goal(fingers=list(fingers), grip_force=grip, object_mass=0.0, hold_time=0.0,
                      targets=targets(fingers) if angles is None else angles)


class Hand:
    """The test's side: joints at 200 Hz, each fingertip's estimate (N in its array frame) at
    100 Hz, and the torques the node sends."""

    def __init__(self, node) -> None:
        self.node = node
        self.q = pinch_pose()
        self.force = dict.fromkeys(FINGERS, np.zeros(3))
        self.torques: list[JointState] = []
        self.joints = node.create_publisher(JointState, TOPIC_JOINTS, publisher_qos(TOPIC_JOINTS))
        self.estimates = node.create_publisher(ForceEstimateArray, TOPIC_ESTIMATES,
                                               publisher_qos(TOPIC_ESTIMATES))
        node.create_subscription(JointState, TOPIC_TORQUE_COMMAND, self.torques.append,
                                 subscriber_qos(TOPIC_TORQUE_COMMAND, depth=100))
        node.create_timer(0.005, self._joints)
        node.create_timer(0.01, self._estimates)

    def _now(self):
        return stamp(self.node.get_clock().now().nanoseconds)

    def _joints(self) -> None:
        msg = JointState(name=KIN.joint_names, position=self.q.tolist(),
                         velocity=[0.0] * 16)
        msg.header.stamp = self._now()
        self.joints.publish(msg)

    def _estimates(self) -> None:
        items = []
        for finger, force in self.force.items():
            item = ForceEstimate(name=f'{finger}_tip', valid=True, status='ok',
                                 force=Vector3(x=float(force[0]), y=float(force[1]),
                                               z=float(force[2])))
            item.header.stamp = self._now()
            items.append(item)
        self.estimates.publish(ForceEstimateArray(estimates=items))


def send(node, client, request) -> tuple:
    """Send a goal and wait for its acceptance: (goal handle, feedback list)."""
    feedback = []
    future = client.send_goal_async(request, feedback_callback=lambda m: feedback.append(
        m.feedback))
    assert spin_until(node, future.done, WAIT_S), 'no answer to the goal'
    handle = future.result()
    assert handle.accepted
    return handle, feedback


def result_of(node, handle):
    future = handle.get_result_async()
    assert spin_until(node, future.done, WAIT_S), 'no result'
    response = future.result()
    return response.status, response.result


def two_fingertip_models(folder: Path) -> Path:
    default = default_model_config(HAND)
    files = yaml.safe_load(Path(default).read_text())['models']
    models = folder / 'models.yaml'
    models.write_text(yaml.safe_dump({'models': {
        f'{f}_tip': str(Path(default).parent / files[f'{f}_tip']) for f in FINGERS}}))
    return models


def start_controller(models: Path):
    return start([executable('grasp_controller'), '--ros-args', '--params-file',
                  params_file('grasp_controller'), '-p', f'model_config:={models}', *LENIENT],
                 DOMAIN)


@pytest.fixture(scope='module')
def graph(tmp_path_factory):
    """The node with models for the thumb and the index fingertip only, and the test's node."""
    process = start_controller(two_fingertip_models(tmp_path_factory.mktemp('grasp_models')))
    proc = OutputLines(process)
    try:
        with rclpy_node('grasp_action_test', DOMAIN) as node:
            hand = Hand(node)
            client = ActionClient(node, Grasp, '/grasp_controller/grasp')
            assert spin_until(node, client.server_is_ready, WAIT_S), proc.text()[-2000:]
            # The action server can be found before the node has the joint stream: a goal
            # then is refused for 'no joint states yet', which no test here asks about.
            assert spin_until(node, lambda: hand.joints.get_subscription_count() > 0
                              and hand.estimates.get_subscription_count() > 0, WAIT_S)
            spin_until(node, lambda: False, 0.2)       # a few dozen joint frames delivered
            yield node, client, hand, proc
    finally:
        output = proc.stop()
        assert process.returncode == EXIT_OK, output[-2000:]


@pytest.mark.parametrize('request_, reason', [
    (goal(fingers=()), 'no fingers'),
    (goal(fingers=('thumb', 'pinky'), angles=[0.0] * 8), "['pinky'] are not fingertips"),
    (goal(fingers=('thumb', 'middle'), angles=targets()), "['middle'] have no force model here"),
    (goal(fingers=('index', 'thumb', 'index'), angles=[0.0] * 12), 'each named once'),
    (goal(fingers=('thumb', 'index'), angles=[0.0] * 5), 'targets: 5 angles for 2 fingers'),
    (goal(grip=0.1), 'outside the safe range 0.3-'),
    (goal(grip=20.0), 'would need more than its torque limit'),
    (Grasp.Goal(fingers=list(FINGERS), grip_force=1.0, object_mass=0.1, targets=targets()),
     'cannot carry 0.1 kg'),
], ids=['empty', 'not_a_fingertip', 'no_model', 'twice', 'targets', 'grip_low', 'grip_high',
        'too_heavy'])
def test_a_goal_that_cannot_run_ends_failed_with_its_reason(graph, request_, reason):
    node, client, _, _ = graph
    handle, _ = send(node, client, request_)
    status, result = result_of(node, handle)
    assert status == GoalStatus.STATUS_ABORTED
    assert result.outcome == Grasp.Result.FAILED
    assert result.reason.startswith('refused: ') and reason in result.reason, result.reason


def test_a_second_goal_is_refused_and_a_cancel_releases(graph):
    node, client, hand, proc = graph
    hand.force = dict.fromkeys(FINGERS, np.zeros(3))
    first, feedback = send(node, client, goal())
    assert spin_until(node, lambda: len(feedback) >= 3, WAIT_S), proc.text()[-2000:]
    assert feedback[-1].phase == 'closing'
    assert [f.finger for f in feedback[-1].fingers] == list(FINGERS)
    assert all(f.stage == 'approach' and f.estimate_fresh for f in feedback[-1].fingers)
    second, _ = send(node, client, goal())
    status, result = result_of(node, second)
    assert (status, result.outcome) == (GoalStatus.STATUS_ABORTED, Grasp.Result.FAILED)
    assert 'a grasp is running' in result.reason, result.reason
    assert spin_until(node, lambda: len(hand.torques) > 5, WAIT_S)
    names = [n for f in FINGERS for n in KIN.joint_names[KIN.finger_joints(f)]]
    assert sorted(hand.torques[-1].name) == sorted(names)
    cancel = first.cancel_goal_async()
    assert spin_until(node, cancel.done, WAIT_S)
    status, result = result_of(node, first)
    assert (status, result.outcome) == (GoalStatus.STATUS_CANCELED, Grasp.Result.RELEASED), (
        result, proc.text()[-3000:])
    # Released, the fingers are held at the pose they had when the goal started (the joints
    # stand still there here: the law's PD adds nothing to gravity), not dropped limp.
    count = len(hand.torques)
    assert spin_until(node, lambda: len(hand.torques) > count + 5, WAIT_S)
    parked = hand.torques[-1]
    assert sorted(parked.name) == sorted(names)
    gravity = KIN.gravity_torques(hand.q)
    expected = {n: gravity[KIN.joint_names.index(n)] for n in names}
    assert np.allclose([parked.effort[parked.name.index(n)] for n in names],
                       [np.clip(expected[n], -0.35, 0.35) for n in names], atol=1e-6)


def test_a_hold_time_at_the_grip_ends_held(graph):
    node, client, hand, _ = graph
    hand.force = {f: np.array([0.0, 0.0, 0.8]) for f in FINGERS}
    request = goal()
    request.hold_time = 0.3
    handle, feedback = send(node, client, request)
    status, result = result_of(node, handle)
    assert (status, result.outcome) == (GoalStatus.STATUS_SUCCEEDED, Grasp.Result.HELD), result
    assert result.held_time >= 0.3 and result.reason.startswith('held '), result.reason
    assert 'holding' in [f.phase for f in feedback]


def test_an_object_lost_from_every_fingertip_ends_the_goal_as_dropped(graph):
    node, client, hand, proc = graph
    hand.force = {f: np.array([0.0, 0.0, 0.8]) for f in FINGERS}     # both touch at once
    handle, feedback = send(node, client, goal())
    assert spin_until(node, lambda: feedback and feedback[-1].phase in ('ramping', 'holding'),
                      WAIT_S), [f.phase for f in feedback]
    hand.force = dict.fromkeys(FINGERS, np.zeros(3))                  # gone from both
    status, result = result_of(node, handle)
    assert (status, result.outcome) == (GoalStatus.STATUS_ABORTED, Grasp.Result.FAILED)
    assert result.reason.startswith('dropped: no finger has felt the object'), result.reason
    rclpy.spin_once(node, timeout_sec=0.1)


def test_a_controller_stopped_mid_goal_still_answers_it(graph):
    """SIGINT while a goal runs: the goal ends aborted, FAILED, and its client hears it. (Last
    in the module: it stops the module's controller, whose exit code the fixture then checks.)"""
    node, client, hand, proc = graph
    hand.force = dict.fromkeys(FINGERS, np.zeros(3))
    handle, feedback = send(node, client, goal())
    assert spin_until(node, lambda: feedback, WAIT_S)
    answer = handle.get_result_async()
    proc.proc.send_signal(2)
    assert spin_until(node, answer.done, WAIT_S), proc.text()[-2000:]
    response = answer.result()
    assert response.status == GoalStatus.STATUS_ABORTED
    assert response.result.outcome == Grasp.Result.FAILED
    assert response.result.reason == 'grasp_controller stopped: released'
