"""A calibration bag's layout: its topics and their types, the QoS it records them with, the
session metadata, the typestore (tacforce_msgs from their .msg text) and the message builders
for rosbags' dataclasses. The same topics whether the sync_recorder node or the simulator's
sim_record tool wrote the bag, so training cannot tell lab data from simulated data
(docs/CONTRACTS.md)."""
from __future__ import annotations

import json
import time
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                QosTime)
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from tacforce_ros import message_build as build
from tacforce_ros.paths import share_dir
from tacforce_ros.topics import (KEPT, KEPT_DEPTH, PUBLISHER_DEPTH, TOPIC_JOINTS, TOPIC_SAMPLE,
                                 TOPIC_SESSION, TOPIC_SIM_CONTACT, TOPIC_TACTILE, TOPIC_WRENCH,
                                 qos_kind)

TOPIC_TYPES = {
    TOPIC_TACTILE: 'tacforce_msgs/msg/TactileHand',
    TOPIC_WRENCH: 'geometry_msgs/msg/WrenchStamped',
    TOPIC_JOINTS: 'sensor_msgs/msg/JointState',
    TOPIC_SAMPLE: 'tacforce_msgs/msg/CalibrationSample',
    TOPIC_SESSION: 'std_msgs/msg/String',
    TOPIC_SIM_CONTACT: 'geometry_msgs/msg/WrenchStamped',
}

METADATA_KEYS = ('array', 'plate', 'hand_side', 'operator_notes', 'source', 'scene', 'seed',
                 'started')
CUSTOM_DATA_PREFIX = 'tacforce.'
# An MCAP file starts and ends with these 8 bytes (MCAP specification, "Magic"); a file cut off
# while being written lacks the trailing copy.
MCAP_MAGIC = b'\x89MCAP0\r\n'


# The ROS 2 distribution the bags are written for: the one whose message definitions the
# typestore holds (rosbags would write its own name into the metadata).
ROS_DISTRO = 'kilted'
_INFINITE = QosTime(sec=9223372036, nsec=854775807)    # rmw's "infinite" duration
# What the graph's publishers offer (topics.PUBLISHER_DEPTH; KEPT topics: KEPT_DEPTH,
# transient-local), in a bag's metadata.
def _offered(depth: int, durability: QosDurability) -> Qos:
    return Qos(history=QosHistory.KEEP_LAST, depth=depth, reliability=QosReliability.RELIABLE,
               durability=durability, deadline=_INFINITE, lifespan=_INFINITE,
               liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=_INFINITE,
               avoid_ros_namespace_conventions=False)


OFFERED_QOS = _offered(PUBLISHER_DEPTH, QosDurability.VOLATILE)
KEPT_OFFERED_QOS = _offered(KEPT_DEPTH, QosDurability.TRANSIENT_LOCAL)


def offered_qos(topic: str) -> list[Qos]:
    """The offered QoS profiles of a recorded topic: its publishers' (none for the session
    metadata, which the recorder writes itself)."""
    try:
        kind = qos_kind(topic)
    except KeyError:
        return []
    return [KEPT_OFFERED_QOS if kind == KEPT else OFFERED_QOS]


class BagError(RuntimeError):
    """A bag that is missing, unreadable or not a calibration bag."""


def msg_dir() -> Path:
    """Folder with tacforce_msgs' .msg files: the source tree, else the installed share."""
    source = share_dir() / 'msg'
    if source.is_dir():
        return source
    from ament_index_python.packages import get_package_share_directory
    return Path(get_package_share_directory('tacforce_msgs')) / 'msg'


@lru_cache(maxsize=1)
def typestore():
    """ROS 2 Kilted typestore with tacforce_msgs registered from the .msg text."""
    store = get_typestore(Stores.ROS2_KILTED)
    types = {}
    for path in sorted(msg_dir().glob('*.msg')):
        types.update(get_types_from_msg(path.read_text(), f'tacforce_msgs/msg/{path.stem}'))
    store.register(types)
    return store


# Message builders for rosbags' dataclasses (message_build.py decides the fields).

@lru_cache(maxsize=1)
def kit() -> build.Kit:
    """The message builders' constructors for rosbags' dataclasses (message_build.py)."""
    types = typestore().types
    return build.Kit(Time=types['builtin_interfaces/msg/Time'], Header=types['std_msgs/msg/Header'],
                     Vector3=types['geometry_msgs/msg/Vector3'],
                     Wrench=types['geometry_msgs/msg/Wrench'],
                     WrenchStamped=types['geometry_msgs/msg/WrenchStamped'],
                     TactileArray=types['tacforce_msgs/msg/TactileArray'],
                     TactileHand=types['tacforce_msgs/msg/TactileHand'],
                     JointState=types['sensor_msgs/msg/JointState'],
                     uint16=lambda v: np.ascontiguousarray(v, dtype=np.uint16),
                     float32=lambda v: np.ascontiguousarray(v, dtype=np.float32),
                     float64=lambda v: np.ascontiguousarray(v, dtype=np.float64))


def header(stamp_ns: int, frame_id: str):
    return build.header(kit(), stamp_ns, frame_id)


def tactile_hand(stamp_ns: int, hand, counts: np.ndarray, temperatures: np.ndarray | None,
                 server_time: float, server_sequence: int):
    """Whole-hand frame from XELA's flat (368, 3) counts, split by the hand description."""
    return build.tactile_hand(kit(), stamp_ns, hand, counts, temperatures, server_time,
                              server_sequence)


def wrench_stamped(stamp_ns: int, frame_id: str, wrench: Sequence[float]):
    """wrench: force then torque, six values."""
    return build.wrench_stamped(kit(), stamp_ns, frame_id, wrench[:3], wrench[3:6])


def joint_state(stamp_ns: int, names: Sequence[str], position: np.ndarray,
                velocity: np.ndarray | None = None, effort: np.ndarray | None = None):
    return build.joint_state(kit(), stamp_ns, names, position, velocity, effort)


def calibration_sample(stamp_ns: int, tactile, wrench, joints):
    return typestore().types['tacforce_msgs/msg/CalibrationSample'](
        header=header(stamp_ns, tactile.header.frame_id), tactile=tactile, wrench=wrench,
        joints=joints)


def session_message(metadata: dict[str, Any]):
    return typestore().types['std_msgs/msg/String'](data=json.dumps(metadata, sort_keys=True))


def session_metadata(**fields: Any) -> dict[str, Any]:
    """Session metadata with every key of the contract present (unknown keys refused)."""
    unknown = set(fields) - set(METADATA_KEYS)
    if unknown:
        raise ValueError(f'unknown session metadata keys {sorted(unknown)}; '
                         f'expected {list(METADATA_KEYS)}')
    meta = {key: fields.get(key, '') for key in METADATA_KEYS}
    meta['started'] = meta['started'] or time.strftime('%Y-%m-%dT%H:%M:%S%z')
    return meta
