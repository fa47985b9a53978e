"""One builder per message the package writes, for both message libraries it writes them with:
rclpy's generated classes (the nodes, nodes/messages.py) and rosbags' dataclasses (bags written
without ROS, bagio/layout.py). A Kit holds one library's constructors and how it takes a numeric
sequence; the builders decide the fields. No rclpy here."""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

Array = Callable[[np.ndarray], Any]     # numpy values -> what the library's sequence field takes


@dataclass(frozen=True)
class Kit:
    Time: Callable[..., Any]
    Header: Callable[..., Any]
    Vector3: Callable[..., Any]
    Wrench: Callable[..., Any]
    WrenchStamped: Callable[..., Any]
    TactileArray: Callable[..., Any]
    TactileHand: Callable[..., Any]
    JointState: Callable[..., Any]
    uint16: Array
    float32: Array
    float64: Array


INT32 = (-2**31, 2**31 - 1)     # builtin_interfaces/Time.sec: a stamp beyond 2038 does not fit


def stamp(kit: Kit, ns: int):
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    if not INT32[0] <= sec <= INT32[1]:     # the wire would wrap it silently
        raise ValueError(f'stamp {ns} ns: {sec} s does not fit builtin_interfaces/Time (int32)')
    return kit.Time(sec=sec, nanosec=nanosec)


def header(kit: Kit, ns: int, frame_id: str):
    return kit.Header(stamp=stamp(kit, ns), frame_id=frame_id)


def vector3(kit: Kit, values: Sequence[float]):
    return kit.Vector3(x=float(values[0]), y=float(values[1]), z=float(values[2]))


def wrench_stamped(kit: Kit, ns: int, frame_id: str, force: Sequence[float],
                   torque: Sequence[float] = (0.0, 0.0, 0.0)):
    return kit.WrenchStamped(header=header(kit, ns, frame_id),
                             wrench=kit.Wrench(force=vector3(kit, force),
                                               torque=vector3(kit, torque)))


def tactile_hand(kit: Kit, ns: int, hand, counts: np.ndarray, temperatures: np.ndarray | None,
                 server_time: float, server_sequence: int, frame_prefix: str = ''):
    """Whole-hand message from XELA's flat (368, 3) counts; one TactileArray per array of the
    hand description, each stamped alike and framed in its array frame {S0} (after
    `frame_prefix`); temperatures (368,) kelvin or None (or empty: the server sent none)."""
    time = stamp(kit, ns)
    per_temp = (hand.split(np.asarray(temperatures)[:, None])
                if temperatures is not None and np.size(temperatures)
                else [None] * len(hand.arrays))
    none = np.zeros(0, np.float32)
    arrays = [kit.TactileArray(header=kit.Header(stamp=time, frame_id=frame_prefix + spec.frame_id),
                               name=spec.name, x=kit.uint16(block[:, 0]),
                               y=kit.uint16(block[:, 1]), z=kit.uint16(block[:, 2]),
                               temperature=kit.float32(none if temps is None else temps[:, 0]))
              for spec, block, temps in zip(hand.arrays, hand.split(np.asarray(counts)),
                                            per_temp)]
    return kit.TactileHand(header=kit.Header(stamp=time, frame_id=frame_prefix + hand.base_frame),
                           server_time=float(server_time),
                           server_sequence=int(server_sequence) & 0xFFFFFFFF, arrays=arrays)


def joint_state(kit: Kit, ns: int, names: Sequence[str], position: np.ndarray,
                velocity: np.ndarray | None = None, effort: np.ndarray | None = None):
    empty = np.zeros(0, np.float64)
    return kit.JointState(header=header(kit, ns, ''), name=list(names),
                          position=kit.float64(position),
                          velocity=kit.float64(empty if velocity is None else velocity),
                          effort=kit.float64(empty if effort is None else effort))
