"""grasp_controller: the hand holding an object between the thumb and another fingertip, through
the action tacforce_msgs/action/Grasp on ~/grasp.

Runs tacforce_ros/control/grasp.py's GraspController (the object the in-process experiments
run; docs/GRASP.md) at `control_rate_hz` on the node clock (sim time under use_sim_time), with
each fingertip's law from the `force_controller.*` parameters (defaults: the single finger's,
config/params/force_controller.yaml; the thumb's gains from its own file) and the grasp's from
`grasp.*`. Inputs: the joints on /joint_states (their header stamp is their time), each
fingertip's estimate from /tactile/estimates (entry `<finger>_tip`; invalid or missing entries
count as stale). Output, while a goal runs: the grasp's joint torques on
/allegro_driver/torque_command (allegro_driver holds every joint nobody commands), and every
tick one tacforce_msgs/ControllerState per fingertip on /grasp_controller/state (forces in the
hand's base frame).

A goal is accepted and then checked: one that cannot run (no fingers, a finger that is not a
fingertip or has no model in `model_config`, no thumb, more than one finger against the thumb,
targets that are not 4 angles per finger, a grip outside 0.3 N to what the joints can press at
the pose, a mass the grip cannot carry, no fresh joint states, a grasp already running) ends
aborted with outcome FAILED and the reason: a ROS 2 goal rejection carries no reason, so the
check runs after acceptance (as nav2's servers report theirs in the result). A new goal does not
preempt a running one (a grasp handed from one goal to the next would restart its approach on a
held object): cancel first. A running grasp:
* holds `hold_time` s at its grip with every fingertip's estimate fresh, then releases:
  succeeded, HELD;
* is canceled: released, canceled, RELEASED;
* loses the object (every fingertip's estimate below half its touch force for
  `grasp.drop_time`): released, aborted, FAILED with the reason;
* is stopped with the node: released, aborted, FAILED.
Feedback every `feedback_period` s: the phase, the grip asked and each fingertip's stage, mode,
forces and freshness. Releasing opens the grasp: each of its fingers goes back to, and holds, the
pose it had when the goal started (clear of the object) by its law's PD and gravity terms alone
(mode "hold" on /grasp_controller/state), until the next goal; the fingers do not fall limp onto
the object. A stale fingertip holds (its watchdog), the others go on.
"""
from __future__ import annotations

import sys
import time
from dataclasses import fields

import numpy as np
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.task import Future
from sensor_msgs.msg import JointState
from tacforce_msgs.action import Grasp
from tacforce_msgs.msg import ControllerState, FingerGrasp, ForceEstimateArray

from tacforce_ros.control.force_controller import (MODE_HOLD, MODE_OPEN_LOOP,
                                                   ControllerConfigError, ForceControllerConfig)
from tacforce_ros.control.grasp import (PHASE_DROPPED, PHASE_HOLDING, GraspConfig,
                                        GraspController, GraspGoal, GraspGoalError,
                                        finger_configs)
from tacforce_ros.devices.allegro_codec import N_JOINTS
from tacforce_ros.estimation.model_set import (ModelConfigError, default_model_config,
                                               model_files)
from tacforce_ros.hand.pinch import pad
from tacforce_ros.nodes.force_controller import (CONTROL_RATE, CONTROLLER_GROUP,
                                                 controller_parameters, group_config)
from tacforce_ros.nodes.messages import JointIntake, controller_state, stamp, stamp_ns, vector3
from tacforce_ros.nodes.node_base import TacforceNode
from tacforce_ros.nodes.parameters import (FRAME_PREFIX, GRAVITY, HAND_CONFIG, ParamSpec,
                                           ParameterError, hand_parameter, kinematics_parameter)
from tacforce_ros.nodes.qos import publisher_qos, subscriber_qos
from tacforce_ros.nodes.realtime import REALTIME_PRIORITY
from tacforce_ros.nodes.runner import run_node
from tacforce_ros.rig import FINGERS, finger_torque_limits
from tacforce_ros.topics import (TOPIC_ESTIMATES, TOPIC_GRASP_STATE, TOPIC_JOINTS,
                                 TOPIC_TORQUE_COMMAND, relative)

GRASP_GROUP = 'grasp'
STOPPED = 'grasp_controller stopped: released'    # the reason of a goal ended by the node's stop
LEAVE_WAIT_S = 1.0     # wall s a stopping node gives a running goal's result to go out
ZERO = np.zeros(3)
# Set per fingertip (ForceControllerConfig.pressing_with, the goal's targets), not parameters.
PER_FINGER = ('finger', 'force_frame', 'estimate_frame', 'q_d')
ACTION = '~/grasp'


def _grasp_parameters() -> tuple[ParamSpec, ...]:
    """grasp.* parameters, defaults from GraspConfig (one source); gravity is the node's own."""
    defaults = GraspConfig()
    return tuple(ParamSpec(f'{GRASP_GROUP}.{f.name}', getattr(defaults, f.name),
                           f.metadata['help']) for f in fields(GraspConfig) if f.name != 'gravity')


class _Running:
    """The goal being run: its handle, what the controller got, and how it ends."""

    def __init__(self, handle, goal: GraspGoal, hold_time: float, done: Future,
                 start: np.ndarray) -> None:
        self.handle = handle
        self.goal = goal
        self.hold_time = hold_time
        self.done = done
        self.start = start              # q16 when the goal started: where a release goes back
        self.held = 0.0                 # s at the grip so far
        self.last_t: float | None = None
        self.next_feedback = -np.inf


class GraspControllerNode(JointIntake, TacforceNode):
    """Thumb-and-fingertip grasps under force control, as a ROS 2 action server."""

    NODE_NAME = 'grasp_controller'
    PARAMETERS = (
        HAND_CONFIG, FRAME_PREFIX,
        CONTROL_RATE,
        ParamSpec('model_config', '', 'the estimator\'s models YAML: the fingertips with a model '
                  'may grasp; empty: the hand\'s default (config/models/)'),
        ParamSpec('feedback_period', 0.1, 'action feedback every this many seconds (node clock)',
                  range=(0.0, 10.0)),
        GRAVITY,
        REALTIME_PRIORITY,
    ) + controller_parameters(leave_out=PER_FINGER) + _grasp_parameters()

    def __init__(self, **node_options) -> None:
        super().__init__(**node_options)
        p = self.params
        self.hand = hand_parameter(p)
        self.kin = kinematics_parameter(self.hand, p)
        configs = self._finger_configs()
        try:
            grasp = GraspConfig(gravity=tuple(p['gravity']), **{
                name.split('.', 1)[1]: value for name, value in p.items()
                if name.startswith(GRASP_GROUP + '.')})
        except ValueError as exc:
            raise ParameterError(f'{GRASP_GROUP}.{exc}') from None
        self.controller = GraspController(
            configs, self.kin, lambda q, f: pad(self.hand, self.kin, q, f)[0], grasp)
        self._joints: tuple[np.ndarray, np.ndarray, int] | None = None   # q, qdot, stamp ns
        self._estimates: dict[str, tuple[np.ndarray, int]] = {}          # f_hat, stamp ns
        self._running: _Running | None = None
        self._parked: dict[str, np.ndarray] = {}    # finger -> the pose it holds after a grasp
        self.refused_joint_states = 0
        self.create_subscription(JointState, relative(TOPIC_JOINTS), self._on_joints,
                                 subscriber_qos(TOPIC_JOINTS, depth=1))
        self.create_subscription(ForceEstimateArray, relative(TOPIC_ESTIMATES),
                                 self._on_estimates, subscriber_qos(TOPIC_ESTIMATES, depth=1))
        self.torque_publisher = self.create_publisher(JointState, relative(TOPIC_TORQUE_COMMAND),
                                                      publisher_qos(TOPIC_TORQUE_COMMAND))
        self.state_publisher = self.create_publisher(ControllerState,
                                                     relative(TOPIC_GRASP_STATE),
                                                     publisher_qos(TOPIC_GRASP_STATE))
        self.server = ActionServer(self, Grasp, ACTION, execute_callback=self._execute,
                                   goal_callback=lambda _goal: GoalResponse.ACCEPT,
                                   cancel_callback=lambda _handle: CancelResponse.ACCEPT)
        self.create_timer(1.0 / p['control_rate_hz'], self._control)
        self.get_logger().info(
            f'grasps of {", ".join(sorted(configs))} on {self.resolve_action_name()} at '
            f'{p["control_rate_hz"]:g} Hz, '
            f'{"open loop" if not any(configs["thumb"].k_i) else "closed loop"}; torques to '
            f'{self.topic_name(TOPIC_TORQUE_COMMAND)}')

    def resolve_action_name(self) -> str:
        return f'{self.get_fully_qualified_name()}/grasp'

    def _finger_configs(self) -> dict[str, ForceControllerConfig]:
        """Each fingertip's law (force_controller.*, on that fingertip, in the base frame), for
        the fingertips the estimator has a model of."""
        base = group_config(self.params)
        models_yaml = self.params['model_config'] or str(default_model_config(self.hand))
        try:
            modelled = model_files(models_yaml)
        except ModelConfigError as exc:
            raise ParameterError(f'model_config: {exc}') from None
        fingers = [f for f in FINGERS if f'{f}_tip' in modelled]
        if 'thumb' not in fingers:
            raise ParameterError(f'model_config: {models_yaml} has no model for thumb_tip: no '
                                 'grasp can run (every grasp opposes the thumb)')
        try:
            return finger_configs(base, self.hand, fingers)
        except ControllerConfigError as exc:
            raise ParameterError(f'{CONTROLLER_GROUP}: {exc}') from None

    # --- inputs ------------------------------------------------------------------------------

    def _on_estimates(self, msg: ForceEstimateArray) -> None:
        for item in msg.estimates:
            finger = item.name.removesuffix('_tip')
            if finger not in self.controller.configs or item.name != f'{finger}_tip':
                continue
            if item.valid:
                self._estimates[finger] = (np.array([item.force.x, item.force.y, item.force.z]),
                                           stamp_ns(item.header.stamp))
            else:
                self._estimates.pop(finger, None)    # stale: its watchdog takes over

    # --- goals -------------------------------------------------------------------------------

    async def _execute(self, handle) -> Grasp.Result:
        request = handle.request
        goal, hold_time, refusal = self._goal(request)
        if refusal:
            return self._finish(handle, Grasp.Result.FAILED, f'refused: {refusal}', 0.0, 0.0)
        done = Future()
        self._running = _Running(handle, goal, hold_time, done, self._joints[0].copy())
        self._parked = {}
        self.get_logger().info(f'grasp with {", ".join(goal.fingers)} at {goal.grip:g} N'
                               + (f', {goal.mass:g} kg' if goal.mass else '')
                               + (f', for {hold_time:g} s' if hold_time else ', until canceled'))
        outcome, reason, grip, held = await done
        return self._finish(handle, outcome, reason, grip, held)

    def _goal(self, request) -> tuple[GraspGoal | None, float, str]:
        """The core's goal from the request, the hold time, and the refusal ('' if none)."""
        if self._running is not None:
            return None, 0.0, ('a grasp is running (with '
                               f'{", ".join(self._running.goal.fingers)}); cancel it first')
        if self._joints is None:
            return None, 0.0, f'no joint states yet on {self.topic_name(TOPIC_JOINTS)}'
        age = (self.now_ns() - self._joints[2]) * 1e-9
        limit = min(c.joints_timeout for c in self.controller.configs.values())
        if age > limit:
            return None, 0.0, (f'the joint states on {self.topic_name(TOPIC_JOINTS)} are '
                               f'{age:.3f} s old (more than {limit:g} s)')
        fingers = tuple(request.fingers)
        targets = np.asarray(request.targets, np.float64)
        if targets.size != 4 * len(fingers):
            return None, 0.0, (f'targets: {targets.size} angles for {len(fingers)} fingers; '
                               'give 4 per finger, in the order of fingers')
        hold_time = float(request.hold_time)
        if not (np.isfinite(hold_time) and hold_time >= 0.0):
            return None, 0.0, f'hold_time {hold_time!r} s: must be >= 0 (0: until canceled)'
        goal = GraspGoal(fingers=fingers, grip=float(request.grip_force),
                         targets={f: tuple(targets[4 * i:4 * i + 4])
                                  for i, f in enumerate(fingers)},
                         mass=float(request.object_mass))
        try:
            self.controller.start(goal, self._joints[0])
        except GraspGoalError as exc:
            return None, 0.0, str(exc)
        return goal, hold_time, ''

    def _finish(self, handle, outcome: int, reason: str, grip: float, held: float
                ) -> Grasp.Result:
        result = Grasp.Result(outcome=outcome, reason=reason, grip_force=float(grip),
                              held_time=float(held))
        if outcome == Grasp.Result.HELD:
            handle.succeed()
        elif outcome == Grasp.Result.RELEASED and handle.is_cancel_requested:
            handle.canceled()
        else:
            handle.abort()
        if outcome == Grasp.Result.FAILED:     # one severity per call site (rclpy's logger)
            self.get_logger().warning(f'grasp ended: {reason}')
        else:
            self.get_logger().info(f'grasp ended: {reason}')
        return result

    def _end(self, outcome: int, reason: str) -> None:
        """Release the running grasp (its fingers park at their start poses) and hand its
        outcome to its execute callback."""
        running = self._running
        grip = self.controller.grip
        self._parked = {f: running.start[self.kin.finger_joints(f)].copy()
                        for f in self.controller.sessions}
        self.controller.release()
        self._running = None
        running.done.set_result((outcome, reason, grip, running.held))

    def _park(self, now: int, q: np.ndarray, qdot: np.ndarray) -> None:
        """The released fingers back at their start poses: each finger's law's PD toward it
        plus gravity, within its torque limits; one 'hold' tick per finger on the state topic."""
        gravity = np.asarray(self.kin.gravity_torques(q), np.float64)
        names, efforts = [], []
        base = self.frame(self.hand.base_frame)
        for finger, target in self._parked.items():
            cfg = self.controller.configs[finger]
            joints = self.kin.finger_joints(finger)
            limit = np.minimum(cfg.torque_cap, finger_torque_limits(finger))
            tau = np.clip(gravity[joints] + np.asarray(cfg.k_p) * (target - q[joints])
                          - np.asarray(cfg.k_d) * qdot[joints], -limit, limit)
            names += list(self.kin.joint_names[joints])
            efforts += tau.tolist()
            msg = ControllerState(finger=finger, mode=MODE_HOLD, desired_force=vector3(ZERO),
                                  estimated_force=vector3(np.full(3, np.nan)),
                                  integral_error=vector3(ZERO), q=q[joints].tolist(),
                                  qdot=qdot[joints].tolist(), tau_cmd=tau.tolist(),
                                  saturation_scale=1.0, estimate_fresh=False,
                                  estimate_age=float('inf'), joints_fresh=True)
            msg.header.stamp = stamp(now)
            msg.header.frame_id = base
            self.state_publisher.publish(msg)
        command = JointState(name=names, effort=efforts)
        command.header.stamp = stamp(now)
        self.torque_publisher.publish(command)

    # --- control tick ------------------------------------------------------------------------

    def _control(self) -> None:
        running = self._running
        if self._joints is None:
            return
        now = self.now_ns()
        q, qdot, q_ns = self._joints
        if running is None:
            if self._parked:
                self._park(now, q, qdot)
            return
        if running.handle.is_cancel_requested:
            self._end(Grasp.Result.RELEASED, 'canceled: released')
            return
        t = now * 1e-9
        estimates = {f: (f_hat, (now - ns) * 1e-9) for f, (f_hat, ns) in self._estimates.items()}
        tau, state = self.controller.update(t, q, qdot, estimates, (now - q_ns) * 1e-9)
        for line in state.transitions:
            self.get_logger().info(line)
        joints = [j for f in state.fingers for j in range(N_JOINTS)[self.kin.finger_joints(f)]]
        command = JointState(name=[self.kin.joint_names[j] for j in joints],
                             effort=[float(tau[j]) for j in joints])
        command.header.stamp = stamp(now)
        self.torque_publisher.publish(command)
        base = self.frame(self.hand.base_frame)
        for finger, fs in state.fingers.items():
            self.state_publisher.publish(controller_state(
                now, base, finger, fs.controller, q[self.kin.finger_joints(finger)],
                qdot[self.kin.finger_joints(finger)]))
        # Held: at the grip, every fingertip on a fresh estimate (a stale one holds blind).
        fresh = all(fs.controller.estimate_fresh or fs.controller.mode == MODE_OPEN_LOOP
                    for fs in state.fingers.values())
        if running.last_t is not None and state.phase == PHASE_HOLDING and fresh:
            running.held += max(0.0, t - running.last_t)
        running.last_t = t
        if t >= running.next_feedback:
            running.handle.publish_feedback(self._feedback(state))
            running.next_feedback = t + self.params['feedback_period']
        if state.phase == PHASE_DROPPED:
            self._end(Grasp.Result.FAILED, state.reason)
        elif running.hold_time and running.held >= running.hold_time:
            self._end(Grasp.Result.HELD, f'held {running.held:.2f} s at '
                      f'{self.controller.grip:.2f} N, then released')

    def _feedback(self, state) -> Grasp.Feedback:
        return Grasp.Feedback(phase=state.phase, reason=state.reason,
                              grip_force=float(state.grip), fingers=[
                                  FingerGrasp(finger=f, stage=s.stage, mode=s.controller.mode,
                                              desired_force=vector3(s.desired),
                                              estimated_force=vector3(s.estimate),
                                              normal_force=float(s.normal),
                                              grip_force=float(s.grip),
                                              estimate_fresh=bool(s.controller.estimate_fresh))
                                  for f, s in state.fingers.items()])

    def leave_safe(self) -> None:
        running = self._running
        if running is None:
            return
        self._end(Grasp.Result.FAILED, STOPPED)
        # The spin has ended: let the goal's execute callback finish, so its client gets the
        # result (aborted) instead of waiting for one that never comes.
        deadline = time.monotonic() + LEAVE_WAIT_S
        while running.handle.is_active and time.monotonic() < deadline and self.executor:
            self.executor.spin_once(timeout_sec=0.02)
        for _ in range(5):      # the result's answer on its way
            self.executor.spin_once(timeout_sec=0.01)


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(GraspControllerNode, args))


if __name__ == '__main__':
    main()

