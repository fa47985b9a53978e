"""grasp_client: sends one tacforce_msgs/action/Grasp goal to grasp_controller and ends with its
outcome: exit code 0 when the grasp held or was released on request, 1 when it failed (refused,
dropped), so a session that runs it ends non-zero on a failed grasp.

The goal is the parameters': `fingers`, `grip_force`, `object_mass`, `hold_time` and `targets` (4
joint angles per finger, in the order of `fingers`). In simulation `scene` (a grasp scene) gives
what the operator would know: each finger's target from the scene's start and contact poses
(control.grasp.approach_targets, as the in-process grasp takes them) and, with `object_mass` < 0,
the object's mass. It is sent at `start_time` on the node clock (simulated time in simulation:
the estimator tares while the fingers hold their start poses), once the server is there; the
feedback is logged every `log_period` s. On SIGINT or SIGTERM a running goal is canceled first.
"""
from __future__ import annotations

import sys
import time

import numpy as np
from action_msgs.msg import GoalStatus
from rclpy.action import ActionClient
from tacforce_msgs.action import Grasp

from tacforce_ros.control.grasp import approach_targets
from tacforce_ros.hand.pinch import joint_limits
from tacforce_ros.nodes.grasp_controller import STOPPED
from tacforce_ros.nodes.node_base import TacforceNode
from tacforce_ros.nodes.parameters import (GRAVITY, HAND_CONFIG, ParamSpec, ParameterError,
                                           hand_parameter, kinematics_parameter)
from tacforce_ros.nodes.runner import EXIT_FAILURE, EXIT_OK, run_node
from tacforce_ros.sim.scene import SceneError, load_scene

CANCEL_WAIT_S = 2.0     # wall s a stopping client waits for its cancel to be answered
OUTCOMES = {Grasp.Result.HELD: 'held', Grasp.Result.RELEASED: 'released',
            Grasp.Result.FAILED: 'failed'}


class GraspClient(TacforceNode):
    """One Grasp goal, its feedback logged, its outcome as the exit code."""

    NODE_NAME = 'grasp_client'
    PARAMETERS = (
        ParamSpec('action', 'grasp_controller/grasp', 'the Grasp action server (relative: in '
                  'this node\'s namespace)'),
        ParamSpec('fingers', ['thumb', 'index'], 'the fingertips: thumb and one other'),
        ParamSpec('grip_force', 1.0, 'grip force (N)', range=(0.0, 100.0)),
        ParamSpec('object_mass', 0.0, 'object mass (kg); < 0: the scene object\'s',
                  range=(-1.0, 100.0)),
        ParamSpec('hold_time', 0.0, 'hold this long at the grip, then release (s); 0: until '
                  'this node stops', range=(0.0, 1e6)),
        ParamSpec('targets', [0.0], 'joint targets, 4 per finger in the order of fingers (rad); '
                  'ignored when scene is set'),
        ParamSpec('scene', '', 'a grasp scene (simulation): the targets, and the mass when '
                  'object_mass < 0, from it'),
        ParamSpec('start_time', 0.0, 'send the goal once the node clock reads this (s)',
                  range=(0.0, 1e9)),
        ParamSpec('log_period', 1.0, 'log the feedback every this many seconds (node clock)',
                  range=(0.1, 3600.0)),
        HAND_CONFIG, GRAVITY,
    )

    def __init__(self, **node_options) -> None:
        super().__init__(**node_options)
        p = self.params
        self.goal = Grasp.Goal(fingers=list(p['fingers']), grip_force=float(p['grip_force']),
                               object_mass=max(0.0, float(p['object_mass'])),
                               hold_time=float(p['hold_time']),
                               targets=[float(v) for v in p['targets']])
        if p['scene']:
            self._from_scene(p['scene'])
        self.client = ActionClient(self, Grasp, p['action'])
        self._sent = False
        self._handle = None
        self._next_log = -np.inf
        self.create_timer(0.05, self._send)
        self.get_logger().info(
            f'will send at t = {p["start_time"]:g} s to {p["action"]}: '
            f'{list(self.goal.fingers)} at {self.goal.grip_force:g} N, '
            f'{self.goal.object_mass:g} kg, hold {self.goal.hold_time:g} s, targets '
            f'{np.round(self.goal.targets, 3).tolist()}')

    def _from_scene(self, name: str) -> None:
        try:
            scene = load_scene(name)
        except (SceneError, OSError) as exc:
            raise ParameterError(f'scene: {exc}') from None
        if scene.kind != 'grasp':
            raise ParameterError(f'scene: {name!r} is a {scene.kind} scene, not a grasp')
        fingers = list(self.goal.fingers)
        poses = scene.grasp['fingers']
        if sorted(poses) != sorted(fingers):
            raise ParameterError(f'fingers: {fingers}, but scene {name} poses {sorted(poses)}')
        kinematics = kinematics_parameter(hand_parameter(self.params), self.params)
        lower, upper = joint_limits(kinematics)
        targets = approach_targets({f: (poses[f]['pose'], poses[f]['contact_pose'])
                                    for f in fingers}, kinematics, lower, upper)
        self.goal.targets = [v for f in fingers for v in targets[f]]
        if self.params['object_mass'] < 0:
            self.goal.object_mass = float(scene.grasp_object.mass)

    def _send(self) -> None:
        if self._sent or self.now_ns() * 1e-9 < self.params['start_time']:
            return
        if not self.client.server_is_ready():
            self.get_logger().info(f'waiting for {self.params["action"]}',
                                   throttle_duration_sec=5.0)
            return
        self._sent = True
        self.get_logger().info('sending the goal')
        future = self.client.send_goal_async(self.goal, feedback_callback=self._on_feedback)
        future.add_done_callback(self._on_response)

    def _on_response(self, future) -> None:
        handle = future.result()
        if not handle.accepted:
            self.get_logger().error('goal rejected')
            self.finish(EXIT_FAILURE)
            return
        self._handle = handle
        handle.get_result_async().add_done_callback(self._on_result)

    def _on_feedback(self, message) -> None:
        t = self.now_ns() * 1e-9
        if t < self._next_log:
            return
        self._next_log = t + self.params['log_period']
        fb = message.feedback
        fingers = '; '.join(f'{f.finger} {f.stage} {f.mode} normal {f.normal_force:.2f} N of '
                            f'{f.grip_force:.2f}' for f in fb.fingers)
        self.get_logger().info(f'{fb.phase} at {fb.grip_force:.2f} N ({fb.reason}): {fingers}')

    def _on_result(self, future) -> None:
        response = future.result()
        result = response.result
        self._handle = None
        text = (f'{OUTCOMES.get(result.outcome, result.outcome)}: {result.reason} (grip '
                f'{result.grip_force:.2f} N, held {result.held_time:.2f} s)')
        # Stopped together (a session's end stops every node at once), the controller may
        # answer the goal as stopped before this client's cancel: that is the session's end,
        # not a failed grasp.
        both_stopping = self.stop_event.is_set() and result.reason == STOPPED
        if not both_stopping and (
                result.outcome not in (Grasp.Result.HELD, Grasp.Result.RELEASED)
                or response.status not in (GoalStatus.STATUS_SUCCEEDED,
                                           GoalStatus.STATUS_CANCELED)):
            self.get_logger().error(f'grasp {text}')
            self.finish(EXIT_FAILURE)
        else:
            self.get_logger().info(f'grasp {text}')
            self.finish(EXIT_OK)

    def leave_safe(self) -> None:
        if self._handle is not None:
            self.get_logger().info('stopping: canceling the goal')
            cancel = self._handle.cancel_goal_async()
            # The spin has ended: give the request its answer before the node goes.
            deadline = time.monotonic() + CANCEL_WAIT_S
            while not cancel.done() and time.monotonic() < deadline and self.executor:
                self.executor.spin_once(timeout_sec=0.02)
        elif not self._sent and self.now_ns() * 1e-9 >= self.params['start_time']:
            # Due, and never sent: no server answered (a wrong action name, another namespace).
            self.get_logger().error(f'stopping: the goal was never sent, no server on '
                                    f'{self.params["action"]}')
            self.exit_code = max(self.exit_code, EXIT_FAILURE)


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(GraspClient, args))


if __name__ == '__main__':
    main()
