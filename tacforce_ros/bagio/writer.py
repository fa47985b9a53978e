"""The crash-tolerant bag writer: what `ros2 bag record -s mcap` writes (MCAP files, one unless
split by size or duration, with the ROS 2 profile, and metadata.yaml); it ends an MCAP chunk at
every flush, so a recorder killed with SIGKILL leaves every message up to the last flush in
complete chunks, which `bag_repair` (recording/bag_repair.py) keeps."""
from __future__ import annotations

import io
import shutil
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib.metadata import version
from pathlib import Path
from typing import Any

from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.rosbag2.metadata import dump_qos_v9
from ruamel.yaml import YAML

from tacforce_ros.bagio.layout import (CUSTOM_DATA_PREFIX, ROS_DISTRO, TOPIC_TYPES, BagError,
                                      offered_qos, session_message, typestore)
from tacforce_ros.topics import TOPIC_SESSION

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
