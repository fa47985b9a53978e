"""rosbag2 calibration bags without ROS: topic layout, typestore, message builders, reader and
a crash-tolerant writer.

Layout (docs/CONTRACTS.md): the same topics whether the sync_recorder node or the simulator's
sim_record tool wrote the bag, so training cannot tell lab data from simulated data.

The writer splits the bag into files (standard rosbag2 multi-file bag) and rewrites
metadata.yaml atomically each time a split closes, so a recorder killed with SIGKILL leaves a bag
that rosbags and `ros2 bag` read up to the last closed split.
"""
from __future__ import annotations

import json
import shutil
import time
from collections.abc import Iterator, Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                QosTime)
from rosbags.rosbag2 import Reader, ReaderError, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from ruamel.yaml import YAML
from ruamel.yaml.error import YAMLError

from tacforce_ros.paths import share_dir
from tacforce_ros.topics import (PUBLISHER_DEPTH, TOPIC_JOINTS, TOPIC_SAMPLE, TOPIC_SESSION,
                                 TOPIC_SIM_CONTACT, TOPIC_TACTILE, TOPIC_WRENCH, qos_kind)

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
_SPLIT_SUFFIX = '.partial'
# An MCAP file starts and ends with these 8 bytes (MCAP specification, "Magic"); a file cut off
# while being written lacks the trailing copy.
MCAP_MAGIC = b'\x89MCAP0\r\n'


# The ROS 2 distribution the bags are written for: the one whose message definitions the
# typestore holds (rosbags would write its own name into the metadata).
ROS_DISTRO = 'kilted'
_INFINITE = QosTime(sec=9223372036, nsec=854775807)    # rmw's "infinite" duration
# What the graph's publishers offer (topics.PUBLISHER_DEPTH), in a bag's metadata.
OFFERED_QOS = Qos(history=QosHistory.KEEP_LAST, depth=PUBLISHER_DEPTH,
                  reliability=QosReliability.RELIABLE, durability=QosDurability.VOLATILE,
                  deadline=_INFINITE, lifespan=_INFINITE, liveliness=QosLiveliness.AUTOMATIC,
                  liveliness_lease_duration=_INFINITE, avoid_ros_namespace_conventions=False)


def offered_qos(topic: str) -> list[Qos]:
    """The offered QoS profiles of a recorded topic: its publishers' (none for the session
    metadata, which the recorder writes itself)."""
    try:
        qos_kind(topic)
    except KeyError:
        return []
    return [OFFERED_QOS]


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


# --- message builders (rosbags dataclasses) -------------------------------------------------

def _stamp(stamp_ns: int):
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return typestore().types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec)


def header(stamp_ns: int, frame_id: str):
    return typestore().types['std_msgs/msg/Header'](stamp=_stamp(stamp_ns), frame_id=frame_id)


def tactile_array(stamp_ns: int, name: str, frame_id: str, counts: np.ndarray,
                  temperatures: np.ndarray | None):
    """counts (n, 3) uint16 for one array; temperatures (n,) kelvin or None."""
    counts = np.asarray(counts, dtype=np.uint16)
    temps = (np.zeros(0, np.float32) if temperatures is None
             else np.asarray(temperatures, dtype=np.float32))
    return typestore().types['tacforce_msgs/msg/TactileArray'](
        header=header(stamp_ns, frame_id), name=name,
        x=np.ascontiguousarray(counts[:, 0]), y=np.ascontiguousarray(counts[:, 1]),
        z=np.ascontiguousarray(counts[:, 2]), temperature=temps)


def tactile_hand(stamp_ns: int, hand, counts: np.ndarray, temperatures: np.ndarray | None,
                 server_time: float, server_sequence: int):
    """Whole-hand frame from XELA's flat (368, 3) counts, split by the hand description."""
    per_array = hand.split(np.asarray(counts))
    per_temp = (hand.split(np.asarray(temperatures)[:, None]) if temperatures is not None
                else [None] * len(hand.arrays))
    arrays = [tactile_array(stamp_ns, a.name, a.frame_id, c,
                            None if t is None else t[:, 0])
              for a, c, t in zip(hand.arrays, per_array, per_temp)]
    return typestore().types['tacforce_msgs/msg/TactileHand'](
        header=header(stamp_ns, hand.base_frame), server_time=float(server_time),
        server_sequence=int(server_sequence) & 0xFFFFFFFF, arrays=arrays)


def wrench_stamped(stamp_ns: int, frame_id: str, wrench: Sequence[float]):
    types = typestore().types
    vec = types['geometry_msgs/msg/Vector3']
    w = [float(v) for v in wrench]
    return types['geometry_msgs/msg/WrenchStamped'](
        header=header(stamp_ns, frame_id),
        wrench=types['geometry_msgs/msg/Wrench'](force=vec(x=w[0], y=w[1], z=w[2]),
                                                 torque=vec(x=w[3], y=w[4], z=w[5])))


def joint_state(stamp_ns: int, names: Sequence[str], position: np.ndarray,
                velocity: np.ndarray | None = None, effort: np.ndarray | None = None):
    empty = np.zeros(0, np.float64)
    return typestore().types['sensor_msgs/msg/JointState'](
        header=header(stamp_ns, ''), name=list(names),
        position=np.asarray(position, np.float64),
        velocity=empty if velocity is None else np.asarray(velocity, np.float64),
        effort=empty if effort is None else np.asarray(effort, np.float64))


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


# --- writer ------------------------------------------------------------------------------------

class CalibrationBagWriter:
    """rosbag2 (mcap) writer that closes a split every `split_seconds` of wall time.

    Each split is written by rosbags into a hidden folder, then moved into the bag and listed in
    a merged metadata.yaml (atomic rename). Use as a context manager; `close()` ends the bag.
    """

    def __init__(self, path: str | Path, metadata: dict[str, Any], *,
                 split_seconds: float = 2.0, topics: dict[str, str] | None = None,
                 storage: StoragePlugin = StoragePlugin.MCAP,
                 started_ns: int | None = None) -> None:
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f'{self.path} exists already; refusing to overwrite a bag')
        self.path.mkdir(parents=True)
        self.metadata = dict(metadata)
        self.split_seconds = float(split_seconds)
        self.topics = dict(TOPIC_TYPES if topics is None else topics)
        self.storage = storage
        self._splits: list[dict[str, Any]] = []
        self._writer: Writer | None = None
        self._connections: dict[str, Any] = {}
        self._split_started = 0.0
        self._open_split()
        # started_ns: the recorder's clock (sim time under use_sim_time), else wall time.
        self.write(TOPIC_SESSION, time.time_ns() if started_ns is None else started_ns,
                   session_message(self.metadata))

    def _split_dir(self, index: int) -> Path:
        return self.path / f'.{self.path.name}_{index}{_SPLIT_SUFFIX}'

    def _open_split(self) -> None:
        writer = Writer(self._split_dir(len(self._splits)), version=9,
                        storage_plugin=self.storage)
        for key, value in self.metadata.items():
            writer.set_custom_data(CUSTOM_DATA_PREFIX + key, str(value))
        writer.open()
        store = typestore()
        self._connections = {topic: writer.add_connection(topic, msgtype, typestore=store,
                                                          offered_qos_profiles=offered_qos(topic))
                             for topic, msgtype in self.topics.items()}
        self._writer = writer
        self._split_started = time.monotonic()

    def _close_split(self) -> None:
        writer, self._writer = self._writer, None
        if writer is None:
            return
        writer.close()
        index = len(self._splits)
        split_dir = self._split_dir(index)
        info = _load_metadata(split_dir)
        if info['message_count']:
            (source,) = info['relative_file_paths']
            name = f'{self.path.name}_{index}{Path(source).suffix}'
            (split_dir / source).replace(self.path / name)
            info['relative_file_paths'] = [name]
            info['files'][0]['path'] = name
            self._splits.append(info)
            self._write_merged_metadata()
        shutil.rmtree(split_dir)

    def _write_merged_metadata(self) -> None:
        if not self._splits:
            return
        merged = {**_merge_metadata(self._splits), 'ros_distro': ROS_DISTRO}
        tmp = self.path / 'metadata.yaml.tmp'
        yaml = YAML(typ='safe')
        yaml.default_flow_style = False
        with tmp.open('w', encoding='utf8') as stream:
            yaml.dump({'rosbag2_bagfile_information': merged}, stream)
        tmp.replace(self.path / 'metadata.yaml')

    def write(self, topic: str, stamp_ns: int, msg) -> None:
        """Serialise one rosbags message and write it."""
        self.write_serialized(topic, stamp_ns,
                              typestore().serialize_cdr(msg, self._connection(topic).msgtype))

    def write_serialized(self, topic: str, stamp_ns: int, data: bytes | memoryview) -> None:
        """Write one CDR-serialised message (e.g. as an rclpy raw subscription receives it)."""
        if self._writer is None:
            raise BagError(f'bag {self.path} is closed')
        self._writer.write(self._connection(topic), int(stamp_ns), data)
        self.flush_if_due()

    def _connection(self, topic: str):
        connection = self._connections.get(topic)
        if connection is None:
            raise BagError(f'topic {topic} is not part of this bag ({sorted(self.topics)})')
        return connection

    def flush_if_due(self) -> None:
        """Close the split once it is `split_seconds` old; call it from a timer too, so a quiet
        stream still reaches the disk."""
        if self._writer is not None and time.monotonic() - self._split_started >= self.split_seconds:
            self.flush()

    def flush(self) -> None:
        """Close the current split (it becomes readable) and open the next one."""
        self._close_split()
        self._open_split()

    def close(self) -> None:
        self._close_split()

    def __enter__(self) -> CalibrationBagWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _load_metadata(bag_dir: Path) -> dict[str, Any]:
    path = bag_dir / 'metadata.yaml'
    try:
        with path.open(encoding='utf8') as stream:
            return YAML(typ='safe').load(stream)['rosbag2_bagfile_information']
    except YAMLError as exc:
        where = getattr(exc, 'problem_mark', None)
        raise BagError(f'{path}: not valid YAML ({getattr(exc, "problem", None) or exc}'
                       + (f', line {where.line + 1}' if where else '') + ')') from None
    except (KeyError, TypeError):
        raise BagError(f'{path}: no rosbag2_bagfile_information; not rosbag2 metadata') from None


def _check_files(bag_dir: Path, info: dict[str, Any]) -> None:
    """Every file the metadata lists is there, and an MCAP file is complete: names the file."""
    for name in info.get('relative_file_paths') or []:
        file = bag_dir / name
        if not file.is_file():
            raise BagError(f'{file}: listed in {bag_dir / "metadata.yaml"} but missing')
        if file.suffix == '.mcap':
            with file.open('rb') as stream:
                stream.seek(max(file.stat().st_size - len(MCAP_MAGIC), 0))
                if stream.read() != MCAP_MAGIC:
                    raise BagError(f'{file}: incomplete MCAP file (it does not end with the MCAP '
                                   'magic: cut off while being written, or truncated)')


def _merge_metadata(splits: list[dict[str, Any]]) -> dict[str, Any]:
    """One rosbag2 metadata record for several single-file splits of the same topics."""
    starts = [s['starting_time']['nanoseconds_since_epoch'] for s in splits]
    ends = [st + s['duration']['nanoseconds'] for st, s in zip(starts, splits)]
    counts: dict[str, int] = {}
    topic_meta: dict[str, Any] = {}
    for split in splits:
        for entry in split['topics_with_message_count']:
            name = entry['topic_metadata']['name']
            topic_meta.setdefault(name, entry['topic_metadata'])
            counts[name] = counts.get(name, 0) + entry['message_count']
    merged = dict(splits[0])
    merged.update({
        'relative_file_paths': [p for s in splits for p in s['relative_file_paths']],
        'files': [f for s in splits for f in s['files']],
        'starting_time': {'nanoseconds_since_epoch': min(starts)},
        'duration': {'nanoseconds': max(ends) - min(starts)},
        'message_count': sum(s['message_count'] for s in splits),
        'topics_with_message_count': [
            {'topic_metadata': topic_meta[name], 'message_count': counts[name]}
            for name in topic_meta],
    })
    return merged


# --- reader ------------------------------------------------------------------------------------

def read_session_metadata(path: str | Path) -> dict[str, Any]:
    """Session metadata of a calibration bag (from the bag's custom_data)."""
    path = Path(path)
    if not (path / 'metadata.yaml').is_file():
        raise BagError(f'{path} is not a rosbag2 folder (no metadata.yaml)')
    custom = _load_metadata(path).get('custom_data') or {}
    meta = {key[len(CUSTOM_DATA_PREFIX):]: value for key, value in custom.items()
            if key.startswith(CUSTOM_DATA_PREFIX)}
    if not meta:
        raise BagError(f'{path} has no tacforce session metadata; not a calibration bag')
    return meta


def read_messages(path: str | Path, topics: Sequence[str] | None = None
                  ) -> Iterator[tuple[str, int, Any]]:
    """Yield (topic, log time ns, deserialised message) in time order."""
    path = Path(path)
    if not (path / 'metadata.yaml').is_file():
        raise BagError(f'{path} is not a rosbag2 folder (no metadata.yaml)')
    _check_files(path, _load_metadata(path))
    store = typestore()
    try:
        with Reader(path) as reader:
            connections = [c for c in reader.connections if topics is None or c.topic in topics]
            for connection, stamp, raw in reader.messages(connections=connections):
                yield connection.topic, stamp, store.deserialize_cdr(raw, connection.msgtype)
    except ReaderError as exc:
        raise BagError(f'{path}: unreadable bag ({exc})') from None
