"""allegro_driver: the Allegro Hand V4 over CAN -> /joint_states, and joint torques from a topic.

The hand and nothing else, as a ros2_control hardware interface is: controllers are other nodes
(force_controller, or yours). Joint states (sensor_msgs/JointState, 16 joints in Allegro order,
position rad, velocity rad/s by finite differences on the node clock, effort = the torque last
sent N m) are published for every complete FINGER_POSE cycle (333 Hz at `position_period_ms` =
3); under sim time a cycle arriving before the node clock has moved since the previous one is the
same instant and is not published (counted as same_stamp in the link report).

`control` = torque: joint torques come on /allegro_driver/torque_command (sensor_msgs/JointState:
`name` the commanded joints, `effort` their torques N m; other fields ignored). Each command is
sent to the hand as it arrives, with the firmware's per-joint clamps. A joint never commanded
holds the pose it had at start-up (gravity + PD, `others_kp`/`others_kd`), so fingers nobody
controls stay where they are. A joint whose commands stop (none for `command_timeout` s on the
node clock) gets zero torque: the driver's own loop (`control_rate_hz`) checks, so zero torque
follows the last command within `command_timeout` + 1/`control_rate_hz`; the servos stay on and
the joint stream goes on, and the joint takes commands again as soon as they return. The stop
and the return are logged once each. A command naming an unknown joint, or with a non-finite
torque or mismatched lengths, is refused whole, counted and logged (throttled).
`control` = off (calibration sessions) only publishes joint states and never commands torque.
A managed (lifecycle) node (nodes/managed_driver.py): configure opens the bus and identifies the
hand (servos off), activate starts the joint stream and switches the servos on (joints nobody
commands hold the pose of that moment), deactivate stops the stream, sends zero torque and
switches the servos off (torque commands are ignored while inactive), cleanup closes the bus.
Shutdown, and the end of the process, do whatever of these is due. With autostart, configure
waits (under sim time for the first /clock, then) up to `connect_timeout` for a hand that does not
answer yet; asked for over the lifecycle service it tries once.

Faults (README, fault table): a lost link (socketcand connection closed, CAN error) is logged at
ERROR, the hand made safe as far as the bus still allows, and the node exits with code 1 in
either mode (restart it, or let launch respawn it). A silent hand (link up, no joint data): WARN
after `silent_warn_after` and the stream requested again; after `silent_timeout` zero torque and
servos off, logged at ERROR; with `control` = torque the node then exits with code 1, with
`control` = off it keeps asking for the stream and publishes again when it returns.
"""
from __future__ import annotations

import sys
import time

import can
import numpy as np
from rclpy.clock import Clock, ClockType
from sensor_msgs.msg import JointState

from tacforce_ros.devices.allegro import (MAX_JOINT_RATE_HZ, AllegroConfig, AllegroV4Driver,
                                          JointSample)
from tacforce_ros.devices.allegro_codec import N_JOINTS, AllegroError
from tacforce_ros.devices.polling import LinkLost
from tacforce_ros.nodes.node_base import StopRequested
from tacforce_ros.nodes.parameters import (GRAVITY, HAND_CONFIG, ParamSpec, ParameterError,
                                           hand_parameter, kinematics_parameter)
from tacforce_ros.nodes.qos import publisher_qos, subscriber_qos
from tacforce_ros.nodes.realtime import REALTIME_PRIORITY
from tacforce_ros.nodes.runner import run_node
from tacforce_ros.nodes.link_status import STATUS_PARAMETERS
from tacforce_ros.nodes.managed_driver import AUTOSTART, ManagedDriver
from tacforce_ros.nodes.messages import stamp
from tacforce_ros.rig import RATE_HZ
from tacforce_ros.topics import TOPIC_JOINTS, TOPIC_TORQUE_COMMAND, relative

# Wall-time period of the check that ends the node on a lost link (and, under force control, on
# a hand the driver made safe): the exit follows the fault within this.
LINK_CHECK_PERIOD_S = 0.05
CONNECT_RETRY_S = 0.2          # wall s between attempts to reach the hand at start-up


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


class AllegroDriver(ManagedDriver):
    """Allegro V4 joint states, and joint torques from /allegro_driver/torque_command."""

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
        HAND_CONFIG,
        ParamSpec('control', 'torque', 'torque: joint torques from the torque_command topic; '
                  'off: joint states only, no torque ever sent', choices=('torque', 'off')),
        ParamSpec('control_rate_hz', RATE_HZ, 'rate of the driver\'s own loop (holds, command '
                  'timeouts) on the node clock (Hz)', range=(1.0, MAX_JOINT_RATE_HZ)),
        ParamSpec('command_timeout', 0.05, 'a joint without a torque command for this long '
                  'gets zero torque (s, node clock)', range=(0.001, 10.0)),
        GRAVITY,
        ParamSpec('velocity_cutoff_hz', 30.0, 'low-pass cutoff of the joint velocity (Hz)',
                  range=(1.0, 150.0)),
        ParamSpec('others_kp', 1.0, 'stiffness holding the joints nobody commands (N m/rad)',
                  range=(0.0, 10.0)),
        ParamSpec('others_kd', 0.03, 'damping of the joints nobody commands (N m s/rad)',
                  range=(0.0, 1.0)),
        ParamSpec('clock_timeout', 30.0, 'use_sim_time: longest wait for the first /clock '
                  'before the hand is opened (s, wall)', range=(0.1, 600.0)),
        ParamSpec('connect_timeout', 30.0, 'autostart: longest wait for the hand to answer '
                  '(s, wall; a hand or bus still coming up is tried again)', range=(0.1, 600.0)),
        ParamSpec('silent_warn_after', 0.5, 'no joint data for this long with the link up: '
                  'warn and ask for the stream again (s, wall)', range=(0.01, 10.0)),
        ParamSpec('silent_timeout', 2.0, 'no joint data for this long: zero torque and servos '
                  'off (s, wall; above silent_warn_after)', range=(0.02, 60.0)),
    ) + STATUS_PARAMETERS + (REALTIME_PRIORITY, AUTOSTART)

    def __init__(self, **node_options) -> None:
        super().__init__(**node_options)
        p = self.params
        self.hand = hand_parameter(p)
        self.kin = kinematics_parameter(self.hand, p)
        if not p['silent_warn_after'] < p['silent_timeout']:
            raise ParameterError(f'silent_timeout: {p["silent_timeout"]} must be above '
                                 f'silent_warn_after ({p["silent_warn_after"]})')
        self.controlled = p['control'] == 'torque'
        self._joint_index = {name: k for k, name in enumerate(self.kin.joint_names)}
        self.joint_publisher = self.create_lifecycle_publisher(JointState, relative(TOPIC_JOINTS),
                                                               publisher_qos(TOPIC_JOINTS))
        self.refused_commands = 0
        self._reset_control()
        if self.controlled:
            self.create_subscription(JointState, relative(TOPIC_TORQUE_COMMAND), self._on_command,
                                     subscriber_qos(TOPIC_TORQUE_COMMAND))
        self.driver: AllegroV4Driver | None = None
        self._hand_timers = []

    def _reset_control(self) -> None:
        """What activating starts from: no joint state yet, no command ever, the hold pose
        taken from the first joint state."""
        self.velocity = JointVelocity(self.params['velocity_cutoff_hz'])
        self._joints: tuple[np.ndarray, np.ndarray, int] | None = None   # q, qdot, node ns
        self._q_hold: np.ndarray | None = None
        self._tau = np.zeros(N_JOINTS)
        self._command = np.zeros(N_JOINTS)                # last commanded torque per joint
        self._command_ns = np.full(N_JOINTS, -1, np.int64)   # its time; -1: never commanded
        self._timed_out = np.zeros(N_JOINTS, bool)
        self._commanded_since_tick = False

    # --- the lifecycle (nodes/managed_driver.py) ----------------------------------------------

    def open_device(self) -> None:
        """Open the bus and identify the hand (HAND_INFO, SERIAL), servos off."""
        p = self.params
        # Only once this node can stamp and time: in simulation, simulated time starts with
        # the hand's stream, and a transition asked for over a service cannot wait for /clock
        # (this node's own executor delivers it).
        if self.autostarting:
            self.wait_for_clock(p['clock_timeout'])
        elif self.get_parameter('use_sim_time').value and self.now_ns() <= 0:
            raise RuntimeError('no /clock yet (use_sim_time is true: is the simulator running?)')
        self.driver = self._open_hand(p['connect_timeout'] if self.autostarting else 0.0)
        side = self.driver.hand_info.side
        if side != self.hand.side:      # (a failed configure closes the driver)
            raise ParameterError(f'hand_config: {self.hand.side} hand\'s description, but the '
                                 f'hand on the bus is a {side} hand (HAND_INFO)')
        self.driver.add_callback(self._on_joints)
        self.report_link(
            self.driver, f'Allegro {self.driver.serial}',
            node_counters=lambda: {'refused_commands': self.refused_commands},
            # Without control a hand made safe still streams what calibration needs.
            failure=lambda: (f'hand made safe: {self.driver.safe_stop}'
                             if self.driver.safe_stop and self.controlled else ''))
        self.driver.start()
        self._hand_timers = [self.create_timer(LINK_CHECK_PERIOD_S, self._check_hand,
                                               clock=Clock(clock_type=ClockType.STEADY_TIME))]
        if self.controlled:
            self._hand_timers.append(self.create_timer(1.0 / p['control_rate_hz'], self._tick))
        info = self.driver.hand_info
        self.get_logger().info(
            f'Allegro {self.driver.serial} ({info.side}, fw 0x{info.firmware_version:04x}) on '
            f'{p["interface"]}:{p["channel"]}; '
            + (f'joint torques from {self.topic_name(TOPIC_TORQUE_COMMAND)} (zero after '
               f'{p["command_timeout"]:g} s without)' if self.controlled
               else 'control off (joint states only)'))

    def start_device(self) -> None:
        """Servos on and the joint stream started, as the last step (every topic in place)."""
        self._reset_control()
        self.driver.servos_on()

    def stop_device(self) -> None:
        self.driver.servos_off()      # stream off, zero torque, servos off
        self._tau = np.zeros(N_JOINTS)

    def close_device(self) -> None:
        for timer in self._hand_timers:
            self.destroy_timer(timer)
        self._hand_timers = []
        if self.driver is not None:
            self.driver.close()

    def _open_hand(self, patience: float) -> AllegroV4Driver:
        """The hand's driver, tried again for up to `patience` wall seconds while the hand, its
        bus or an emulator does not answer yet: the launch files start every node at once. (In
        simulation the first /clock already means the emulators listen: sim_world binds them
        before its clock runs.)"""
        deadline = time.monotonic() + patience
        while True:
            try:
                return AllegroV4Driver(self._driver_config(), servos_on=False)
            except ValueError as exc:          # the configuration, not the hand: no retry
                raise ParameterError(f'interface/channel/host/port: {exc}') from None
            except (AllegroError, can.CanError, OSError) as exc:
                if time.monotonic() >= deadline:
                    raise ParameterError(f'interface/channel/host/port: hand not reachable: '
                                         f'{exc}') from None
                self.get_logger().info(f'waiting for the hand: {exc}',
                                       throttle_duration_sec=5.0)
            if self.stop_event.wait(CONNECT_RETRY_S):
                raise StopRequested('stopped while waiting for the hand')

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
        """Ends the node (exit code 1, via run_node) on a lost link, and under torque control
        on a hand the driver made safe: no command can act on either."""
        if self.driver.fatal_error is not None:
            raise RuntimeError(f'Allegro link failed: {self.driver.fatal_error}')
        if self.controlled and self.driver.safe_stop:
            raise RuntimeError(f'torque control ended: {self.driver.safe_stop}')

    # --- inputs (joint callback runs in the driver's thread) --------------------------------

    def _on_joints(self, sample: JointSample) -> None:
        if not self.active:
            return
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

    def _on_command(self, msg: JointState) -> None:
        if not self.active:
            self.get_logger().warning('torque command ignored: the driver is not active',
                                      throttle_duration_sec=5.0)
            return
        joints = [self._joint_index.get(name) for name in msg.name]
        effort = np.asarray(msg.effort, dtype=np.float64)
        if (None in joints or len(joints) != len(effort) or len(set(joints)) != len(joints)
                or not np.all(np.isfinite(effort))):
            self.refused_commands += 1
            self.get_logger().warn(
                f'torque command refused ({self.refused_commands} so far): names must be joints '
                f'of the hand, once each, with one finite effort each; got {list(msg.name)} '
                f'and {len(effort)} efforts', throttle_duration_sec=5.0)
            return
        now = self.now_ns()
        self._command[joints] = effort
        self._command_ns[joints] = now
        self._commanded_since_tick = True
        self._send(now)

    # --- torque out --------------------------------------------------------------------------

    def _tick(self) -> None:
        """The driver's own loop: sends holds and command timeouts when no command did."""
        if self.active and not self._commanded_since_tick:
            self._send(self.now_ns())
        self._commanded_since_tick = False

    def _send(self, now: int) -> None:
        if self._joints is None or self.driver.fatal_error is not None or self.driver.safe_stop:
            return      # nothing to act on yet, or _check_hand is about to end the node
        q, qdot, _ = self._joints
        p = self.params
        never = self._command_ns < 0
        timed_out = ~never & (now - self._command_ns > p['command_timeout'] * 1e9)
        self._log_timeouts(timed_out)
        hold = (self.kin.gravity_torques(q) - p['others_kd'] * qdot
                - p['others_kp'] * (q - self._q_hold))
        tau = np.where(never, hold, np.where(timed_out, 0.0, self._command))
        try:
            self.driver.set_torques(tau)
        except LinkLost as error:
            raise RuntimeError(f'Allegro link failed: {error}') from None
        except AllegroError:
            # The polling thread made the hand safe after this tick's check: the same end.
            if self.driver.safe_stop:
                raise RuntimeError(f'torque control ended: {self.driver.safe_stop}') from None
            raise
        self._tau = tau

    def _log_timeouts(self, timed_out: np.ndarray) -> None:
        stopped, resumed = timed_out & ~self._timed_out, ~timed_out & self._timed_out
        names = self.kin.joint_names
        if stopped.any():
            self.get_logger().warning(
                f'torque commands stopped for {self.params["command_timeout"]:g} s: zero torque '
                f'on {[names[k] for k in np.flatnonzero(stopped)]} (servos stay on)')
        if resumed.any():
            self.get_logger().info(
                f'torque commands back on {[names[k] for k in np.flatnonzero(resumed)]}')
        self._timed_out = timed_out


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(AllegroDriver, args))


if __name__ == '__main__':
    main()
