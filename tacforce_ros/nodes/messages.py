"""numpy <-> ROS message conversion shared by the driver, estimator and simulator nodes.

Unbounded numeric sequences are filled from numpy through array.array (rclpy's fast path for
them): copying bytes avoids a Python loop per taxel at 100 Hz x 368 taxels. The hot topics of
the estimator skip message objects altogether (nodes/serialized.py).
"""
from __future__ import annotations

import array
from collections.abc import Sequence

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Vector3, Wrench, WrenchStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from tacforce_msgs.msg import ControllerState, TactileArray, TactileHand

from tacforce_ros import message_build as build
from tacforce_ros.hand.description import HandDescription


def _typed(values: np.ndarray, typecode: str, dtype: type) -> array.array:
    out = array.array(typecode)
    out.frombytes(np.ascontiguousarray(values, dtype=dtype).tobytes())
    return out


KIT = build.Kit(Time=Time, Header=Header, Vector3=Vector3, Wrench=Wrench,
                WrenchStamped=WrenchStamped, TactileArray=TactileArray, TactileHand=TactileHand,
                JointState=JointState,
                uint16=lambda v: _typed(v, 'H', np.uint16),
                float32=lambda v: _typed(v, 'f', np.float32),
                float64=lambda v: _typed(v, 'd', np.float64))


def stamp(ns: int) -> Time:
    return build.stamp(KIT, ns)


def stamp_ns(time: Time) -> int:
    return time.sec * 1_000_000_000 + time.nanosec


def vector3(values: Sequence[float]) -> Vector3:
    return build.vector3(KIT, values)


def wrench_stamped(ns: int, frame_id: str, force: Sequence[float],
                   torque: Sequence[float] = (0.0, 0.0, 0.0)) -> WrenchStamped:
    return build.wrench_stamped(KIT, ns, frame_id, force, torque)


def tactile_hand(ns: int, hand: HandDescription, counts: np.ndarray,
                 temperatures: np.ndarray | None, server_time: float,
                 server_sequence: int, frame_prefix: str = '') -> TactileHand:
    """Whole-hand message (message_build.tactile_hand) as rclpy's message class."""
    return build.tactile_hand(KIT, ns, hand, counts, temperatures, server_time, server_sequence,
                              frame_prefix)


def flat_counts(msg: TactileHand, hand: HandDescription) -> np.ndarray:
    """(n_taxels, 3) float64 counts in XELA flat order, read from the message object field by
    field (TactileHandDecoder in nodes/serialized.py reads the same from the bytes); ValueError
    when the message does not match the hand (array names, order or taxel counts)."""
    if len(msg.arrays) != len(hand.arrays):
        raise ValueError(f'{len(msg.arrays)} arrays, the hand has {len(hand.arrays)}')
    counts = np.empty((hand.n_taxels, 3))
    for spec, item in zip(hand.arrays, msg.arrays):
        if item.name != spec.name:
            raise ValueError(f'array {item.name!r} where the hand has {spec.name!r}')
        sizes = [len(item.x), len(item.y), len(item.z)]
        if sizes != [spec.n_taxels] * 3:
            raise ValueError(f'{spec.name}: {sizes} values in x, y, z, expected '
                             f'{spec.n_taxels} each')
        counts[spec.flat_indices] = np.column_stack([np.asarray(item.x), np.asarray(item.y),
                                                     np.asarray(item.z)])
    return counts


def controller_state(ns: int, frame_id: str, finger: str, state, q: np.ndarray,
                     qdot: np.ndarray) -> ControllerState:
    """One finger's control tick (control/force_controller.py's ControllerState, forces in
    `frame_id`) as tacforce_msgs/ControllerState; q and qdot: that finger's joints."""
    msg = ControllerState(finger=finger, mode=state.mode,
                          desired_force=vector3(state.desired_force),
                          estimated_force=vector3(state.estimated_force),
                          integral_error=vector3(state.integral_error),
                          q=np.asarray(q, np.float64).tolist(),
                          qdot=np.asarray(qdot, np.float64).tolist(),
                          tau_cmd=np.asarray(state.tau_cmd, np.float64).tolist(),
                          saturation_scale=float(state.saturation_scale),
                          estimate_fresh=bool(state.estimate_fresh),
                          estimate_age=float(state.estimate_age),
                          joints_fresh=bool(state.joints_fresh))
    msg.header.stamp = stamp(ns)
    msg.header.frame_id = frame_id
    return msg


class JointIntake:
    """/joint_states as the controllers take it: the hand's 16 joints in order, with positions
    and velocities, into `_joints` (q, qdot, header stamp ns); any other message is refused,
    counted in `refused_joint_states` and warned about (throttled). For a TacforceNode with
    `kin` (the hand's kinematics)."""

    def _on_joints(self, msg: JointState) -> None:
        names = self.kin.joint_names
        if list(msg.name) != names or len(msg.position) != len(names) \
                or len(msg.velocity) != len(names):
            self.refused_joint_states = getattr(self, 'refused_joint_states', 0) + 1
            self.get_logger().warn(f'joint state refused ({self.refused_joint_states} so far): '
                                   f'expected the {len(names)} joints {names[0]}.. in order '
                                   'with positions and velocities', throttle_duration_sec=5.0)
            return
        self._joints = (np.asarray(msg.position, np.float64),
                        np.asarray(msg.velocity, np.float64), stamp_ns(msg.header.stamp))
