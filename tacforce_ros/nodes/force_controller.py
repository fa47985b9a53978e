"""force_controller: one finger's closed force loop, from the topics to joint torques.

Runs tacforce_ros/control/finger_session.py (the object the in-process experiments run) with the
paper's law (control/force_controller.py, parameters `force_controller.*`, see
config/params/force_controller.yaml) for the selected finger at `control_rate_hz` on the node
clock (sim time under use_sim_time). Inputs: the joints from /joint_states (their header stamp
is their time), f_d from /force_controller/desired (geometry_msgs/Vector3Stamped, in
force_controller.force_frame), f_hat from /tactile/estimates (the entry of `estimate_array`;
invalid or missing entries count as stale). Output: the finger's four joint torques on
/allegro_driver/torque_command (sensor_msgs/JointState, name and effort), which allegro_driver
sends to the hand; it holds the other joints itself and zeroes a joint whose commands stop.
K_i = 0 is the open-loop baseline.

The controller engages on the first desired force once (closed loop) a valid estimate has
arrived, i.e. once the estimator has tared: until then the finger holds the pose it had at the
first tick with the law's own PD and gravity terms and no force terms (k_i = 0, q_d = that pose,
reported as mode "hold"), so a session starts as a lab run does: clear of the plate, the
estimator tared, then the guarded approach (control/approach.py) brings the tip into contact:
the P term's target moves toward q_d at a bounded speed and stops where the estimate first shows
the touch, and the force command waits for it. The watchdog ramps the force terms to the
contact hold when the estimate goes stale and fades the last command to zero torque when the
joint stream does; every tick is published as tacforce_msgs/ControllerState on
/force_controller/state, and every change of mode or of its cause is logged once.
"""
from __future__ import annotations

import sys
from dataclasses import fields

import numpy as np
from geometry_msgs.msg import Vector3Stamped
from sensor_msgs.msg import JointState
from tacforce_msgs.msg import ControllerState, ForceEstimateArray

from tacforce_ros.control.finger_session import FingerSession
from tacforce_ros.control.force_controller import ControllerConfigError, ForceControllerConfig
from tacforce_ros.devices.allegro import MAX_JOINT_RATE_HZ
from tacforce_ros.rig import RATE_HZ
from tacforce_ros.nodes.node_base import TacforceNode
from tacforce_ros.nodes.parameters import (FRAME_PREFIX, GRAVITY, HAND_CONFIG, ParamSpec,
                                           ParameterError, hand_parameter, kinematics_parameter)
from tacforce_ros.nodes.qos import publisher_qos, subscriber_qos
from tacforce_ros.nodes.realtime import REALTIME_PRIORITY
from tacforce_ros.nodes.runner import run_node
from tacforce_ros.nodes.messages import JointIntake, controller_state, stamp, stamp_ns
from tacforce_ros.topics import (TOPIC_CONTROLLER_STATE, TOPIC_DESIRED, TOPIC_ESTIMATES,
                                 TOPIC_JOINTS, TOPIC_TORQUE_COMMAND, relative)

CONTROLLER_GROUP = 'force_controller'
# A controller's loop on the node clock, at most the hand's joint stream (this node's and
# grasp_controller's).
CONTROL_RATE = ParamSpec('control_rate_hz', RATE_HZ, 'controller loop rate (Hz, node clock), up '
                         'to the 333 Hz joint stream', range=(1.0, MAX_JOINT_RATE_HZ))


def controller_parameters(leave_out: tuple[str, ...] = ()) -> tuple[ParamSpec, ...]:
    """force_controller.* parameters, defaults from ForceControllerConfig (one source), but for
    the fields in `leave_out` (set otherwise by a node that drives several fingers)."""
    defaults = ForceControllerConfig()
    specs = []
    for f in fields(ForceControllerConfig):
        if f.name in leave_out:
            continue
        value = getattr(defaults, f.name)
        value = [float(v) for v in value] if isinstance(value, tuple) else value
        specs.append(ParamSpec(f'{CONTROLLER_GROUP}.{f.name}', value, f.metadata['help']))
    return tuple(specs)


def group_config(params: dict) -> ForceControllerConfig:
    """The law of the node's force_controller.* parameters (the others its defaults), or the
    ParameterError that names the bad one."""
    group = {name.split('.', 1)[1]: value for name, value in params.items()
             if name.startswith(CONTROLLER_GROUP + '.')}
    try:
        return ForceControllerConfig.from_mapping(group)
    except ControllerConfigError as exc:
        raise ParameterError(f'{CONTROLLER_GROUP}.{exc}') from None


class ForceControllerNode(JointIntake, TacforceNode):
    """The fingertip force controller of one finger, between the topics and the hand driver."""

    NODE_NAME = 'force_controller'
    PARAMETERS = (
        HAND_CONFIG, FRAME_PREFIX,
        CONTROL_RATE,
        ParamSpec('estimate_array', 'index_tip', 'array whose estimate closes the loop'),
        GRAVITY,
        REALTIME_PRIORITY,
    ) + controller_parameters()

    def __init__(self, **node_options) -> None:
        super().__init__(**node_options)
        p = self.params
        self.hand = hand_parameter(p)
        self.kin = kinematics_parameter(self.hand, p)
        self.session = FingerSession(self._controller_config(), self.kin)
        self.joint_names = self.kin.joint_names[self.session.joints]
        self._joints: tuple[np.ndarray, np.ndarray, int] | None = None   # q, qdot, stamp ns
        self._desired: np.ndarray | None = None      # None until the first command
        self._estimate: tuple[np.ndarray, int] | None = None     # f_hat, stamp ns
        self.refused_commands = 0
        self.refused_joint_states = 0
        self.create_subscription(JointState, relative(TOPIC_JOINTS), self._on_joints,
                                 subscriber_qos(TOPIC_JOINTS, depth=1))
        self.create_subscription(Vector3Stamped, relative(TOPIC_DESIRED), self._on_desired,
                                 subscriber_qos(TOPIC_DESIRED))
        self.create_subscription(ForceEstimateArray, relative(TOPIC_ESTIMATES),
                                 self._on_estimates,
                                 subscriber_qos(TOPIC_ESTIMATES, depth=1))
        self.torque_publisher = self.create_publisher(JointState, relative(TOPIC_TORQUE_COMMAND),
                                                      publisher_qos(TOPIC_TORQUE_COMMAND))
        self.state_publisher = self.create_publisher(ControllerState,
                                                     relative(TOPIC_CONTROLLER_STATE),
                                                     publisher_qos(TOPIC_CONTROLLER_STATE))
        self.create_timer(1.0 / p['control_rate_hz'], self._control)
        self.get_logger().info(
            f'force control of {self.session.config.finger} at {p["control_rate_hz"]:g} Hz, '
            f'{"open loop" if self.session.controller.open_loop else "closed loop"} with '
            f'{p["estimate_array"]}; torques to {self.topic_name(TOPIC_TORQUE_COMMAND)}')

    def _controller_config(self) -> ForceControllerConfig:
        config = group_config(self.params)
        array = self.params['estimate_array']
        if array not in {a.name for a in self.hand.arrays}:
            raise ParameterError(f'estimate_array: {array!r} is not an array of the hand')
        if self.hand.array(array).finger != config.finger:
            raise ParameterError(f'estimate_array: {array} is not on the controlled finger '
                                 f'({CONTROLLER_GROUP}.finger: {config.finger})')
        rig = self.hand.rig_frame(config.finger)
        if config.force_frame != rig:
            raise ParameterError(f'{CONTROLLER_GROUP}.force_frame: {config.force_frame!r} but '
                                 f'the rig for the {config.finger} is {rig!r} (hand rig_frames)')
        expected = self.hand.array(array).frame_id
        if config.estimate_frame != expected:
            raise ParameterError(f'{CONTROLLER_GROUP}.estimate_frame: {config.estimate_frame!r}'
                                 f' but the estimates of {array} are in {expected!r}')
        for name in ('base_frame', 'force_frame'):
            if not self.kin.has_frame(getattr(config, name)):
                raise ParameterError(f'{CONTROLLER_GROUP}.{name}: {getattr(config, name)!r} is '
                                     'not a frame of the URDF')
        return config

    # --- inputs ------------------------------------------------------------------------------

    def _on_desired(self, msg: Vector3Stamped) -> None:
        frame = self.frame(self.session.config.force_frame)
        if msg.header.frame_id not in ('', frame):
            self.refused_commands += 1
            self.get_logger().warn(f'desired force in {msg.header.frame_id!r} refused: the '
                                   f'controller takes {frame!r} ({self.refused_commands} so far)',
                                   throttle_duration_sec=5.0)
            return
        desired = np.array([msg.vector.x, msg.vector.y, msg.vector.z])
        if np.all(np.isfinite(desired)):
            self._desired = desired

    def _on_estimates(self, msg: ForceEstimateArray) -> None:
        item = next((e for e in msg.estimates if e.name == self.params['estimate_array']), None)
        if item is None or not item.valid:
            self._estimate = None          # invalid or stale: the watchdog takes over
            return
        self._estimate = (np.array([item.force.x, item.force.y, item.force.z]),
                          stamp_ns(item.header.stamp))

    # --- control tick ------------------------------------------------------------------------

    def _control(self) -> None:
        if self._joints is None:
            return      # nothing to act on yet
        now = self.now_ns()
        q, qdot, q_ns = self._joints
        estimate = self._estimate
        f_hat, f_age = ((estimate[0], (now - estimate[1]) * 1e-9) if estimate is not None
                        else (np.full(3, np.nan), float('inf')))
        tau, state, transition = self.session.update(
            now * 1e-9, q, qdot, f_hat, f_age, (now - q_ns) * 1e-9, self._desired)
        if transition is not None:
            self.get_logger().info(str(transition))
        command = JointState(name=self.joint_names, effort=tau.tolist())
        command.header.stamp = stamp(now)
        self.torque_publisher.publish(command)
        joints = self.session.joints
        self.state_publisher.publish(controller_state(
            now, self.frame(self.session.config.force_frame), self.session.config.finger, state,
            q[joints], qdot[joints]))

def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(ForceControllerNode, args))


if __name__ == '__main__':
    main()
