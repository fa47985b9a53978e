"""allegro_driver: Allegro Hand V4 over CAN -> /joint_states, and the fingertip force controller.

Joint states (sensor_msgs/JointState, 16 joints in Allegro order, position rad, velocity rad/s by
finite differences on the node clock, effort = last commanded torque N m) are published for
every complete FINGER_POSE cycle (333 Hz at `position_period_ms` = 3); under sim time a cycle
arriving before the node clock has moved since the previous one is the same instant and is not
published (counted as same_stamp in the link report).

`control` = force runs one finger's closed loop (tacforce_ros/control/finger_session.py: the same
object the in-process experiments run) with the paper's law (control/force_controller.py,
parameters `force_controller.*`, see config/params/force_controller.yaml) for the selected finger at
`control_rate_hz` on the node clock (sim time under use_sim_time): f_d from
/force_controller/desired (geometry_msgs/Vector3Stamped, in force_controller.force_frame),
f_hat from /tactile/estimates (the entry of `estimate_array`; invalid or missing entries count as
stale). K_i = 0 is the open-loop baseline. The other fingers hold the pose they had at start-up
(gravity + PD, `others_kp`/`others_kd`). The force controller engages on the first desired
force once (closed loop) a valid estimate has arrived, i.e. once the estimator has tared: until
then the finger holds the pose it had at start-up with the law's own PD and gravity terms and no
force terms (k_i = 0, q_d = that pose, reported as mode "hold"), so a session starts as a lab
run does: clear of the plate, the estimator tared, then q_d brings the tip into contact. The
controller's watchdog ramps the force terms to a position hold when the estimate goes stale and
fades the last command to zero torque when the joint stream does; every tick is published as
tacforce_msgs/ControllerState on /force_controller/state, and every change of mode or of its
cause is logged once.
`control` = off (calibration sessions) only publishes joint states and never commands torque.
On shutdown the driver stops the stream, sends zero torque and switches the servos off.

Faults (README, fault table): a lost link (socketcand connection closed, CAN error) is logged at
ERROR, the hand made safe as far as the bus still allows, and the node exits with code 1 in
either mode (restart it, or let launch respawn it). A silent hand (link up, no joint data): WARN
after `silent_warn_after` and the stream requested again; after `silent_timeout` zero torque and
servos off, logged at ERROR; with `control` = force the node then exits with code 1, with
`control` = off it keeps asking for the stream and publishes again when it returns.
"""
from __future__ import annotations

import sys
from dataclasses import fields

import can
import numpy as np
from geometry_msgs.msg import Vector3Stamped
from rclpy.clock import Clock, ClockType
from sensor_msgs.msg import JointState
from tacforce_msgs.msg import ControllerState, ForceEstimateArray

from tacforce_ros.control.finger_session import FingerSession
from tacforce_ros.control.force_controller import ControllerConfigError, ForceControllerConfig
from tacforce_ros.devices.allegro import (N_JOINTS, AllegroConfig, AllegroError, AllegroV4Driver,
                                          JointSample)
from tacforce_ros.devices.polling import LinkLost
from tacforce_ros.hand.description import HandConfigError, load_hand
from tacforce_ros.hand.kinematics import HandKinematics
from tacforce_ros.nodes.common import (REALTIME_PRIORITY, ParameterError, ParamSpec,
                                       TacforceNode, publisher_qos, run_node, subscriber_qos)
from tacforce_ros.nodes.link_status import STATUS_PARAMETERS, LinkStatusReporter
from tacforce_ros.nodes.messages import stamp, stamp_ns, vector3
from tacforce_ros.topics import (TOPIC_CONTROLLER_STATE, TOPIC_DESIRED, TOPIC_ESTIMATES,
                                 TOPIC_JOINTS)

CONTROLLER_GROUP = 'force_controller'
# The Allegro's joint stream: one FINGER_POSE cycle every 3 ms.
MAX_CONTROL_RATE_HZ = 1000.0 / 3.0
# Wall-time period of the check that ends the node on a lost link (and, under force control, on
# a hand the driver made safe): the exit follows the fault within this.
LINK_CHECK_PERIOD_S = 0.05

def _controller_parameters() -> tuple[ParamSpec, ...]:
    """force_controller.* parameters, defaults from ForceControllerConfig (one source)."""
    defaults = ForceControllerConfig()
    specs = []
    for f in fields(ForceControllerConfig):
        value = getattr(defaults, f.name)
        value = [float(v) for v in value] if isinstance(value, tuple) else value
        specs.append(ParamSpec(f'{CONTROLLER_GROUP}.{f.name}', value, f.metadata['help']))
    return tuple(specs)


class JointVelocity:
    """Joint velocity from positions: finite differences on the caller's clock, low-passed
    (first order, `cutoff_hz`) because position counts and arrival stamps are both coarse (and
    under sim time the clock ticks in 1 ms steps); samples sharing a time stamp are skipped."""

    def __init__(self, cutoff_hz: float) -> None:
        self.tau_s = 1.0 / (2.0 * np.pi * cutoff_hz)
        self._q: np.ndarray | None = None
        self._t_ns = 0
        self.qdot = np.zeros(N_JOINTS)

    def update(self, q: np.ndarray, t_ns: int) -> np.ndarray:
        if self._q is None:
            self._q, self._t_ns = q, t_ns
        elif t_ns > self._t_ns:
            dt = (t_ns - self._t_ns) * 1e-9
            alpha = dt / (self.tau_s + dt)
            self.qdot = self.qdot + alpha * ((q - self._q) / dt - self.qdot)
            self._q, self._t_ns = q, t_ns
        return self.qdot


class AllegroDriver(TacforceNode):
    """Allegro V4 joint states and torque control with the fingertip force controller."""

    NODE_NAME = 'allegro_driver'
    PARAMETERS = (
        ParamSpec('interface', 'pcan', 'python-can interface',
                  choices=('pcan', 'socketcan', 'socketcand', 'kvaser', 'virtual')),
        ParamSpec('channel', 'PCAN_USBBUS1', 'python-can channel (socketcand: its CAN name)'),
        ParamSpec('host', '127.0.0.1', 'socketcand server address (interface socketcand only)'),
        ParamSpec('port', 29536, 'socketcand server port (interface socketcand only)',
                  range=(1, 65535)),
        ParamSpec('bitrate', 1_000_000, 'CAN bit rate (pcan, kvaser)', range=(10_000, 1_000_000)),
        ParamSpec('rtr_requests', True, 'ask HAND_INFO/SERIAL with RTR frames (socketcand '
                  'carries none: false)'),
        ParamSpec('position_period_ms', 3, 'FINGER_POSE stream period (ms)', range=(1, 100)),
        ParamSpec('hand_config', '', 'hand description YAML; empty = the default hand'),
        ParamSpec('control', 'force', 'force: run the force controller; off: joint states '
                  'only, no torque ever sent', choices=('force', 'off')),
        ParamSpec('control_rate_hz', 100.0, 'controller loop rate (Hz, node clock), up to the '
                  '333 Hz joint stream', range=(1.0, MAX_CONTROL_RATE_HZ)),
        ParamSpec('estimate_array', 'index_tip', 'array whose estimate closes the loop'),
        ParamSpec('gravity', [0.0, 0.0, -9.81], 'gravity in the hand base frame (m/s^2), from '
                  'the mounting', range=(-20.0, 20.0)),
        ParamSpec('velocity_cutoff_hz', 30.0, 'low-pass cutoff of the joint velocity (Hz)',
                  range=(1.0, 150.0)),
        ParamSpec('others_kp', 1.0, 'stiffness holding the other fingers (N m/rad)',
                  range=(0.0, 10.0)),
        ParamSpec('others_kd', 0.03, 'damping of the other fingers (N m s/rad)',
                  range=(0.0, 1.0)),
        ParamSpec('clock_timeout', 30.0, 'use_sim_time: longest wait for the first /clock '
                  'before the hand is opened (s, wall)', range=(0.1, 600.0)),
        ParamSpec('silent_warn_after', 0.5, 'no joint data for this long with the link up: '
                  'warn and ask for the stream again (s, wall)', range=(0.01, 10.0)),
        ParamSpec('silent_timeout', 2.0, 'no joint data for this long: zero torque and servos '
                  'off (s, wall; above silent_warn_after)', range=(0.02, 60.0)),
    ) + STATUS_PARAMETERS + (REALTIME_PRIORITY,) + _controller_parameters()

    def __init__(self, **node_options) -> None:
        super().__init__(**node_options)
        p = self.params
        try:
            self.hand = load_hand(p['hand_config'] or None)
            self.kin = HandKinematics.for_hand(self.hand, gravity=np.asarray(p['gravity']))
        except (HandConfigError, OSError, ValueError) as exc:
            raise ParameterError(f'hand_config/gravity: {exc}') from None
        self.session: FingerSession | None = None
        if p['control'] == 'force':
            self.session = FingerSession(self._controller_config(), self.kin)
        self.joint_publisher = self.create_publisher(JointState, TOPIC_JOINTS,
                                                     publisher_qos(TOPIC_JOINTS))
        self.velocity = JointVelocity(p['velocity_cutoff_hz'])
        self._joints: tuple[np.ndarray, np.ndarray, int] | None = None   # q, qdot, node ns
        self._q_hold: np.ndarray | None = None
        self._tau = np.zeros(N_JOINTS)
        self._desired: np.ndarray | None = None      # None until the first command
        self._estimate: tuple[np.ndarray, int] | None = None     # f_hat, stamp ns
        self.refused_commands = 0
        if not p['silent_warn_after'] < p['silent_timeout']:
            raise ParameterError(f'silent_timeout: {p["silent_timeout"]} must be above '
                                 f'silent_warn_after ({p["silent_warn_after"]})')
        if self.session is not None:
            self.create_subscription(Vector3Stamped, TOPIC_DESIRED, self._on_desired,
                                     subscriber_qos(TOPIC_DESIRED))
            self.create_subscription(ForceEstimateArray, TOPIC_ESTIMATES, self._on_estimates,
                                     subscriber_qos(TOPIC_ESTIMATES))
            self.state_publisher = self.create_publisher(ControllerState, TOPIC_CONTROLLER_STATE,
                                                         publisher_qos(TOPIC_CONTROLLER_STATE))
        # Servos on (the end of the hand's start-up) only once this node can stamp and time, and
        # as its last step, with every topic in place: in simulation that is when simulated time
        # starts, so control acts from its first step (on a loaded 2-core host the ROS entities
        # above took up to a second, which simulated time ran through without joint states).
        self.wait_for_clock(p['clock_timeout'])
        try:
            self.driver = AllegroV4Driver(self._driver_config())
        except (AllegroError, can.CanError, OSError, ValueError) as exc:
            raise ParameterError(f'interface/channel/host/port: hand not reachable: {exc}'
                                 ) from None
        self.driver.add_callback(self._on_joints)
        self.status = LinkStatusReporter(
            self, self.driver, f'Allegro {self.driver.serial}',
            # Without control a hand made safe still streams what calibration needs.
            failure=lambda: (f'hand made safe: {self.driver.safe_stop}'
                             if self.driver.safe_stop and self.session is not None else ''))
        self.driver.start()
        self.create_timer(LINK_CHECK_PERIOD_S, self._check_hand,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        if self.session is not None:
            self.create_timer(1.0 / p['control_rate_hz'], self._control)
        info = self.driver.hand_info
        self.get_logger().info(
            f'Allegro {self.driver.serial} ({info.side}, fw 0x{info.firmware_version:04x}) on '
            f'{p["interface"]}:{p["channel"]}; control '
            + (f'force on {self.session.config.finger} at {p["control_rate_hz"]:g} Hz, '
               f'{"open loop" if self.session.controller.open_loop else "closed loop"} with '
               f'{p["estimate_array"]}' if self.session else 'off (joint states only)'))

    def _controller_config(self) -> ForceControllerConfig:
        group = {name.split('.', 1)[1]: value for name, value in self.params.items()
                 if name.startswith(CONTROLLER_GROUP + '.')}
        try:
            config = ForceControllerConfig.from_mapping(group)
        except ControllerConfigError as exc:
            raise ParameterError(f'{CONTROLLER_GROUP}.{exc}') from None
        array = self.params['estimate_array']
        if array not in {a.name for a in self.hand.arrays}:
            raise ParameterError(f'estimate_array: {array!r} is not an array of the hand')
        expected = self.hand.array(array).frame_id
        if config.estimate_frame != expected:
            raise ParameterError(f'{CONTROLLER_GROUP}.estimate_frame: {config.estimate_frame!r}'
                                 f' but the estimates of {array} are in {expected!r}')
        for name in ('base_frame', 'force_frame'):
            if not self.kin.has_frame(getattr(config, name)):
                raise ParameterError(f'{CONTROLLER_GROUP}.{name}: {getattr(config, name)!r} is '
                                     'not a frame of the URDF')
        return config

    def _driver_config(self) -> AllegroConfig:
        p = self.params
        if p['interface'] == 'socketcand':
            bus = {'host': p['host'], 'port': p['port'], 'tcp_tune': True}
        elif p['interface'] in ('pcan', 'kvaser'):
            bus = {'bitrate': p['bitrate']}
        else:
            bus = {}
        return AllegroConfig(interface=p['interface'], channel=p['channel'], bus_kwargs=bus,
                             position_period_ms=p['position_period_ms'],
                             rtr_requests=p['rtr_requests'],
                             silent_warn_after=p['silent_warn_after'],
                             silent_timeout=p['silent_timeout'])

    # --- the hand's health (its events are logged by LinkStatusReporter) ---------------------

    def _check_hand(self) -> None:
        """Ends the node (exit code 1, via run_node) on a lost link, and under force control
        on a hand the driver made safe: a controller cannot act on either."""
        if self.driver.fatal_error is not None:
            raise RuntimeError(f'Allegro link failed: {self.driver.fatal_error}')
        if self.session is not None and self.driver.safe_stop:
            raise RuntimeError(f'force control ended: {self.driver.safe_stop}')

    # --- inputs (joint callback runs in the driver's thread) --------------------------------

    def _on_joints(self, sample: JointSample) -> None:
        now = self.new_stamp_ns(TOPIC_JOINTS)
        if now is None:
            return      # no valid stamp yet, or the same instant as the previous cycle
        q = sample.positions
        qdot = self.velocity.update(q, now).copy()
        if self._q_hold is None:
            self._q_hold = q.copy()
        self._joints = (q, qdot, now)
        msg = JointState(name=self.kin.joint_names, position=q.tolist(),
                         velocity=qdot.tolist(), effort=self._tau.tolist())
        msg.header.stamp = stamp(now)
        self.joint_publisher.publish(msg)

    def _on_desired(self, msg: Vector3Stamped) -> None:
        frame = self.session.config.force_frame
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
        if self._joints is None or self.driver.fatal_error is not None or self.driver.safe_stop:
            return      # nothing to act on yet, or _check_hand is about to end the node
        now = self.now_ns()
        q, qdot, q_ns = self._joints
        estimate = self._estimate
        f_hat, f_age = ((estimate[0], (now - estimate[1]) * 1e-9) if estimate is not None
                        else (np.full(3, np.nan), float('inf')))
        tau_finger, state, transition = self.session.update(
            now * 1e-9, q, qdot, f_hat, f_age, (now - q_ns) * 1e-9, self._desired)
        if transition is not None:
            self.get_logger().info(str(transition))
        tau = state.hold_gain * self._hold_others(q, qdot)
        tau[self.session.joints] = tau_finger
        try:
            self.driver.set_torques(tau)
        except LinkLost as error:
            raise RuntimeError(f'Allegro link failed: {error}') from None
        except AllegroError:
            # The polling thread made the hand safe after this tick's check: the same end.
            if self.driver.safe_stop:
                raise RuntimeError(f'force control ended: {self.driver.safe_stop}') from None
            raise
        self._tau = tau
        self.state_publisher.publish(self._state_message(now, state, q, qdot))

    def _hold_others(self, q: np.ndarray, qdot: np.ndarray) -> np.ndarray:
        p = self.params
        return (self.kin.gravity_torques(q) - p['others_kd'] * qdot
                - p['others_kp'] * (q - self._q_hold))

    def _state_message(self, now: int, state, q: np.ndarray, qdot: np.ndarray
                       ) -> ControllerState:
        joints = self.session.joints
        msg = ControllerState(finger=self.session.config.finger, mode=state.mode,
                              desired_force=vector3(state.desired_force),
                              estimated_force=vector3(state.estimated_force),
                              integral_error=vector3(state.integral_error),
                              q=q[joints].tolist(), qdot=qdot[joints].tolist(),
                              tau_cmd=state.tau_cmd.tolist(),
                              saturation_scale=float(state.saturation_scale),
                              estimate_fresh=state.estimate_fresh,
                              joints_fresh=state.joints_fresh)
        msg.header.stamp = stamp(now)
        msg.header.frame_id = self.session.config.force_frame
        return msg

    def on_shutdown(self) -> None:
        self.driver.close()          # stream off, zero torque, servos off
        self.status.final_report()


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(AllegroDriver, args))


if __name__ == '__main__':
    main()
