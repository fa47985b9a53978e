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
from geometry_msgs.msg import Vector3, WrenchStamped
from std_msgs.msg import Header
from tacforce_msgs.msg import TactileArray, TactileHand

from tacforce_ros.hand.description import HandDescription


def stamp(ns: int) -> Time:
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


def stamp_ns(time: Time) -> int:
    return time.sec * 1_000_000_000 + time.nanosec


def _typed(values: np.ndarray, typecode: str, dtype: type) -> array.array:
    out = array.array(typecode)
    out.frombytes(np.ascontiguousarray(values, dtype=dtype).tobytes())
    return out


def vector3(values: Sequence[float]) -> Vector3:
    return Vector3(x=float(values[0]), y=float(values[1]), z=float(values[2]))


def wrench_stamped(ns: int, frame_id: str, force: Sequence[float],
                   torque: Sequence[float] = (0.0, 0.0, 0.0)) -> WrenchStamped:
    msg = WrenchStamped()
    msg.header.stamp = stamp(ns)
    msg.header.frame_id = frame_id
    msg.wrench.force = vector3(force)
    msg.wrench.torque = vector3(torque)
    return msg


def tactile_hand(ns: int, hand: HandDescription, counts: np.ndarray,
                 temperatures: np.ndarray | None, server_time: float,
                 server_sequence: int, frame_prefix: str = '') -> TactileHand:
    """Whole-hand message from XELA's flat (368, 3) counts; one TactileArray per hand array,
    each stamped alike and framed in its array frame {S0} (after `frame_prefix`)."""
    msg = TactileHand()
    msg.header.stamp = stamp(ns)
    msg.header.frame_id = frame_prefix + hand.base_frame
    msg.server_time = float(server_time)
    msg.server_sequence = int(server_sequence) & 0xFFFFFFFF
    per_temp = (hand.split(np.asarray(temperatures)[:, None]) if temperatures is not None
                and np.size(temperatures) else [None] * len(hand.arrays))
    for spec, block, temps in zip(hand.arrays, hand.split(np.asarray(counts)), per_temp):
        item = TactileArray()
        item.header = Header(stamp=msg.header.stamp, frame_id=frame_prefix + spec.frame_id)
        item.name = spec.name
        item.x = _typed(block[:, 0], 'H', np.uint16)
        item.y = _typed(block[:, 1], 'H', np.uint16)
        item.z = _typed(block[:, 2], 'H', np.uint16)
        if temps is not None:
            item.temperature = _typed(temps[:, 0], 'f', np.float32)
        msg.arrays.append(item)
    return msg


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
