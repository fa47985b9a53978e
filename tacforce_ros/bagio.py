"""rosbag2 calibration bags without ROS: topic layout, typestore, message builders, reader and
a crash-tolerant writer.

Layout (docs/CONTRACTS.md): the same topics whether the sync_recorder node or the simulator's
sim_record tool wrote the bag, so training cannot tell lab data from simulated data.

The writer writes what `ros2 bag record -s mcap` would: MCAP files (one, unless split by size
or duration) with the ROS 2 profile and metadata.yaml; it ends an MCAP chunk at every flush, so a
recorder killed with SIGKILL leaves every message up to the last flush in complete chunks, which
`bag_repair` (recording/bag_repair.py) keeps.
"""
from __future__ import annotations

import io
import json
import shutil
import time
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from importlib.metadata import version
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                QosTime)
from mcap.reader import make_reader
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.rosbag2 import Reader, ReaderError
from rosbags.rosbag2.metadata import dump_qos_v9
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from ruamel.yaml import YAML
from ruamel.yaml.error import YAMLError

from tacforce_ros import message_build as build
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


# --- writer ------------------------------------------------------------------------------------

# mcap's default chunk size (rosbag2's MCAP plugin uses 768 KiB); a chunk also ends at every flush.
CHUNK_BYTES = 1 << 20


@dataclass
class FileRecord:
    """What a bag's metadata.yaml says of one of its files."""

    path: str
    counts: dict[str, int] = field(default_factory=dict)
    start_ns: int | None = None
    end_ns: int | None = None

    def add(self, topic: str, stamp_ns: int) -> None:
        self.counts[topic] = self.counts.get(topic, 0) + 1
        self.start_ns = stamp_ns if self.start_ns is None else min(self.start_ns, stamp_ns)
        self.end_ns = stamp_ns if self.end_ns is None else max(self.end_ns, stamp_ns)

    @property
    def message_count(self) -> int:
        return sum(self.counts.values())


@dataclass(frozen=True)
class TopicRecord:
    """A recorded topic: its type, its publishers' offered QoS (metadata version 9 form) and its
    type's hash (RIHS01)."""

    msgtype: str
    offered_qos: list[dict[str, Any]]
    type_hash: str


def topic_records(topics: dict[str, str]) -> dict[str, TopicRecord]:
    store = typestore()
    return {topic: TopicRecord(msgtype, dump_qos_v9(offered_qos(topic)),
                               store.hash_rihs01(msgtype))
            for topic, msgtype in topics.items()}


def _span(start_ns: int | None, end_ns: int | None) -> dict[str, Any]:
    start = start_ns or 0
    return {'starting_time': {'nanoseconds_since_epoch': start},
            'duration': {'nanoseconds': (end_ns or start) - start}}


def bag_metadata(files: Sequence[FileRecord], topics: dict[str, TopicRecord],
                 custom_data: dict[str, str]) -> dict[str, Any]:
    """rosbag2 metadata (version 9) of a bag of MCAP files, the fields `ros2 bag record -s mcap`
    writes."""
    starts = [f.start_ns for f in files if f.start_ns is not None]
    ends = [f.end_ns for f in files if f.end_ns is not None]
    return {
        'version': 9, 'storage_identifier': 'mcap',
        'relative_file_paths': [f.path for f in files],
        **_span(min(starts, default=None), max(ends, default=None)),
        'message_count': sum(f.message_count for f in files),
        'topics_with_message_count': [
            {'topic_metadata': {'name': topic, 'type': record.msgtype,
                                'serialization_format': 'cdr',
                                'offered_qos_profiles': record.offered_qos,
                                'type_description_hash': record.type_hash},
             'message_count': sum(f.counts.get(topic, 0) for f in files)}
            for topic, record in topics.items()],
        'compression_format': '', 'compression_mode': '',
        'files': [{'path': f.path, **_span(f.start_ns, f.end_ns),
                   'message_count': f.message_count} for f in files],
        'custom_data': custom_data or None,
        'ros_distro': ROS_DISTRO,
    }


def _block_yaml() -> YAML:
    """rosbag2's YAML: safe, block style."""
    yaml = YAML(typ='safe')
    yaml.default_flow_style = False
    return yaml


def write_metadata(bag_dir: Path, info: dict[str, Any]) -> None:
    """metadata.yaml, replaced atomically (a reader sees the old or the new, never half)."""
    tmp = bag_dir / 'metadata.yaml.tmp'
    with tmp.open('w', encoding='utf8') as stream:
        _block_yaml().dump({'rosbag2_bagfile_information': info}, stream)
    tmp.replace(bag_dir / 'metadata.yaml')


def _yaml_text(value: Any) -> str:
    stream = io.StringIO()
    _block_yaml().dump(value, stream)
    return stream.getvalue().strip()


def mcap_writer(stream, profile: str = 'ros2',
                library: str = f'tacforce_ros, mcap {version("mcap")}') -> McapWriter:
    """A started MCAP writer on `stream` as every bag file is written: CHUNK_BYTES chunks, no
    compression (the recorder shares the loop's cores)."""
    writer = McapWriter(stream, chunk_size=CHUNK_BYTES, compression=CompressionType.NONE)
    writer.start(profile=profile, library=library)
    return writer


def start_mcap(stream, topics: dict[str, TopicRecord]) -> tuple[McapWriter, dict[str, int]]:
    """An MCAP writer on `stream` with the ROS 2 profile, a ros2msg schema per type (the full
    definition, as rosbag2 embeds it, so Foxglove and rosbags decode without ROS) and a cdr
    channel per topic with its offered QoS; returns it and the channel id of each topic."""
    store = typestore()
    writer = mcap_writer(stream)
    schemas: dict[str, int] = {}
    channels = {}
    for topic, record in topics.items():
        if record.msgtype not in schemas:
            msgdef, _ = store.generate_msgdef(record.msgtype, ros_version=2)
            schemas[record.msgtype] = writer.register_schema(record.msgtype, 'ros2msg',
                                                             msgdef.encode())
        channels[topic] = writer.register_channel(
            topic, 'cdr', schemas[record.msgtype],
            {'offered_qos_profiles': _yaml_text(record.offered_qos),
             'topic_type_hash': record.type_hash})
    return writer, channels


class CalibrationBagWriter:
    """A rosbag2 bag of MCAP files, as `ros2 bag record -s mcap` writes one: one file unless
    `max_bag_size` (bytes, checked as chunks reach the file) or `max_bag_duration` (s of log
    time) splits it, metadata.yaml rewritten whenever a file opens or closes.

    Crash safety is MCAP's own: messages are written in chunks, and a chunk ends (it and all
    before it are on disk, readable after a SIGKILL) at every `flush()`: by the writes, once
    `flush_seconds` of wall time have passed since the last, and by a recorder's timer of that
    period, so a quiet stream still reaches the disk. A bag cut off by a crash is made whole by
    `bag_repair`. Use as a context manager; `close()` ends the bag.
    """

    def __init__(self, path: str | Path, metadata: dict[str, Any], *,
                 topics: dict[str, str] | None = None, flush_seconds: float = 1.0,
                 max_bag_size: int = 0, max_bag_duration: float = 0.0,
                 started_ns: int | None = None) -> None:
        if flush_seconds <= 0 or max_bag_size < 0 or max_bag_duration < 0:
            raise ValueError('flush_seconds must be > 0, max_bag_size and max_bag_duration >= 0 '
                             f'(0: no split); got {flush_seconds}, {max_bag_size}, '
                             f'{max_bag_duration}')
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f'{self.path} exists already; refusing to overwrite a bag')
        self.path.mkdir(parents=True)
        self.metadata = dict(metadata)
        self.custom_data = {CUSTOM_DATA_PREFIX + key: str(value)
                            for key, value in self.metadata.items()}
        self.topics = topic_records(TOPIC_TYPES if topics is None else topics)
        self.flush_seconds = float(flush_seconds)
        self.max_bag_size = int(max_bag_size)
        self.max_bag_duration_ns = round(max_bag_duration * 1e9)
        self.files: list[FileRecord] = []
        self._writer: McapWriter | None = None
        self._stream = None
        try:
            self._open_file()
            # started_ns: the recorder's clock (sim time under use_sim_time), else wall time.
            self.write(TOPIC_SESSION, time.time_ns() if started_ns is None else started_ns,
                       session_message(self.metadata))
            self.flush()        # the schemas, channels and session metadata on disk at once
        except BaseException:
            # A bag that could not start leaves nothing behind.
            if self._stream is not None:
                self._stream.close()
            shutil.rmtree(self.path, ignore_errors=True)
            raise

    def _open_file(self) -> None:
        name = f'{self.path.name}_{len(self.files)}.mcap'
        self._stream = (self.path / name).open('xb')
        self.files.append(FileRecord(name))
        self._writer, self._channels = start_mcap(self._stream, self.topics)
        self._flushed = time.monotonic()
        self._write_metadata()

    def _close_file(self) -> None:
        writer, self._writer = self._writer, None
        if writer is None:
            return
        try:
            writer.finish()
        finally:
            self._stream.close()
            self._write_metadata()

    def _write_metadata(self) -> None:
        write_metadata(self.path, bag_metadata(self.files, self.topics, self.custom_data))

    def write(self, topic: str, stamp_ns: int, msg) -> None:
        """Serialise one rosbags message and write it."""
        self.write_serialized(topic, stamp_ns,
                              typestore().serialize_cdr(msg, self._topic(topic).msgtype))

    def write_serialized(self, topic: str, stamp_ns: int, data: bytes | memoryview) -> None:
        """Write one CDR-serialised message (e.g. as an rclpy raw subscription receives it)."""
        if self._writer is None:
            raise BagError(f'bag {self.path} is closed')
        self._topic(topic)
        stamp_ns = int(stamp_ns)
        if self._split_due(stamp_ns):
            self._close_file()
            self._open_file()
        self._writer.add_message(self._channels[topic], stamp_ns, bytes(data), stamp_ns)
        self.files[-1].add(topic, stamp_ns)
        self.flush_if_due()

    def _topic(self, topic: str) -> TopicRecord:
        record = self.topics.get(topic)
        if record is None:
            raise BagError(f'topic {topic} is not part of this bag ({sorted(self.topics)})')
        return record

    def _split_due(self, stamp_ns: int) -> bool:
        current = self.files[-1]
        if not current.message_count:
            return False
        return ((self.max_bag_duration_ns > 0
                 and stamp_ns - current.start_ns >= self.max_bag_duration_ns)
                or (self.max_bag_size > 0 and self._stream.tell() >= self.max_bag_size))

    def flush_if_due(self) -> None:
        """flush() once `flush_seconds` have passed since the last."""
        if self._writer is not None and time.monotonic() - self._flushed >= self.flush_seconds:
            self.flush()

    def flush(self) -> None:
        """End the current chunk and hand it to the file: what was written so far survives a
        crash of this process."""
        if self._writer is not None:
            self._writer.flush()
            self._flushed = time.monotonic()

    def close(self) -> None:
        self._close_file()

    def __enter__(self) -> CalibrationBagWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def load_metadata(bag_dir: Path) -> dict[str, Any]:
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


def mcap_complete(file: Path) -> bool:
    """An MCAP file ends with the magic; one cut off while being written does not."""
    with file.open('rb') as stream:
        stream.seek(max(file.stat().st_size - len(MCAP_MAGIC), 0))
        return stream.read() == MCAP_MAGIC


def _check_files(bag_dir: Path, info: dict[str, Any]) -> None:
    """Every file the metadata lists is there, and an MCAP file is complete: names the file."""
    for name in info.get('relative_file_paths') or []:
        file = bag_dir / name
        if not file.is_file():
            raise BagError(f'{file}: listed in {bag_dir / "metadata.yaml"} but missing')
        if file.suffix == '.mcap' and not mcap_complete(file):
            raise BagError(f'{file}: incomplete MCAP file (it does not end with the MCAP magic: '
                           'cut off while being written, or truncated); `bag_repair '
                           f'{bag_dir}` keeps every complete chunk and rewrites the metadata')


# --- reader ------------------------------------------------------------------------------------

def read_session_metadata(path: str | Path) -> dict[str, Any]:
    """Session metadata of a calibration bag (from the bag's custom_data)."""
    path = Path(path)
    if not (path / 'metadata.yaml').is_file():
        raise BagError(f'{path} is not a rosbag2 folder (no metadata.yaml)')
    custom = load_metadata(path).get('custom_data') or {}
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
    _check_files(path, load_metadata(path))
    store = typestore()
    try:
        with Reader(path) as reader:
            connections = [c for c in reader.connections if topics is None or c.topic in topics]
            for connection, stamp, raw in reader.messages(connections=connections):
                yield connection.topic, stamp, store.deserialize_cdr(raw, connection.msgtype)
    except ReaderError as exc:
        raise BagError(f'{path}: unreadable bag ({exc})') from None


def bag_files(path: str | Path) -> list[str]:
    """The files of a bag, as its metadata.yaml lists them."""
    return list(load_metadata(Path(path)).get('relative_file_paths') or [])


def reader_counts(path: str | Path) -> dict[str, dict[str, int]]:
    """Messages per topic of a bag as three readers count them: its metadata.yaml, rosbags
    (the reader training uses) and Foxglove's `mcap` reader, file by file. Equal counts say the
    bag is what ROS tools expect; BagError for an unreadable bag."""
    path = Path(path)
    info = load_metadata(path)
    _check_files(path, info)
    metadata = {entry['topic_metadata']['name']: entry['message_count']
                for entry in info['topics_with_message_count'] if entry['message_count']}
    by_rosbags: Counter = Counter()
    try:
        with Reader(path) as reader:
            for connection, _, _ in reader.messages():
                by_rosbags[connection.topic] += 1
    except ReaderError as exc:
        raise BagError(f'{path}: unreadable bag ({exc})') from None
    by_mcap: Counter = Counter()
    for name in info['relative_file_paths']:
        with (path / name).open('rb') as stream:
            for _, channel, _ in make_reader(stream).iter_messages():
                by_mcap[channel.topic] += 1
    return {'metadata': metadata, 'rosbags': dict(by_rosbags), 'mcap': dict(by_mcap)}
