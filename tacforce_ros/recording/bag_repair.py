"""Make a bag cut off by a crash whole again (what `ros2 bag reindex` and `mcap recover` do
together): every MCAP file that does not end with the MCAP magic is rewritten with each complete
chunk it holds (its schemas, channels and messages; a chunk cut off mid-write is dropped, and
with it only what came after the writer's last flush), an MCAP file left with no message is
removed, and metadata.yaml is rebuilt from the files. The session metadata comes from the old
metadata.yaml where it loads, else from the /session/metadata message the bag starts with.
Complete files are read, never rewritten. ROS-free; the `bag_repair` tool runs it.
"""
from __future__ import annotations

import json
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Header, Message, Schema
from mcap.stream_reader import StreamReader
from ruamel.yaml import YAML

from tacforce_ros.bagio import (CUSTOM_DATA_PREFIX, BagError, FileRecord, TopicRecord,
                                _load_metadata, bag_metadata, mcap_complete, start_mcap,
                                typestore, write_metadata)
from tacforce_ros.topics import TOPIC_SESSION


@dataclass
class FileRepair:
    """What happened to one MCAP file of a bag."""

    path: str
    recovered: bool                # it was cut off and was rewritten
    messages: int                  # messages it holds now
    bytes_dropped: int = 0         # of the cut-off file: what followed its last complete record
    stopped_by: str = ''           # why reading the cut-off file stopped


@dataclass
class BagRepair:
    bag: Path
    files: list[FileRepair] = field(default_factory=list)
    removed: list[str] = field(default_factory=list)     # files left with no message

    @property
    def repaired(self) -> bool:
        return any(f.recovered for f in self.files) or bool(self.removed)


def _file_index(path: Path) -> tuple[int, str]:
    match = re.search(r'_(\d+)\.mcap$', path.name)
    return (int(match.group(1)) if match else -1, path.name)


def _topics_of(channels: dict[int, Channel], schemas: dict[int, Schema]) -> dict[str, TopicRecord]:
    yaml = YAML(typ='safe')
    return {c.topic: TopicRecord(schemas[c.schema_id].name,
                                 yaml.load(c.metadata.get('offered_qos_profiles', '')) or [])
            for c in channels.values()}


def _read_complete(path: Path) -> tuple[FileRecord, dict[str, TopicRecord], bytes | None]:
    """A complete file's counts and times from its summary; the first session message too."""
    with path.open('rb') as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            raise BagError(f'{path}: a complete MCAP file without a summary; not one of ours')
        record = FileRecord(path.name)
        stats = summary.statistics
        for channel_id, count in stats.channel_message_counts.items():
            record.counts[summary.channels[channel_id].topic] = count
        if stats.message_count:
            record.start_ns, record.end_ns = stats.message_start_time, stats.message_end_time
        session = next((message.data for _, channel, message in
                        reader.iter_messages(topics=[TOPIC_SESSION])), None)
        return record, _topics_of(summary.channels, summary.schemas), session


def _recover(path: Path) -> tuple[FileRecord, dict[str, TopicRecord], bytes | None, FileRepair]:
    """Rewrite a cut-off file with its complete records (atomically: a temporary file that
    replaces it)."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    messages: list[Message] = []
    header = ('ros2', 'tacforce_ros bag_repair')
    stopped_by, good_end = 'end of file', 0
    size = path.stat().st_size
    with path.open('rb') as stream:
        reader = StreamReader(stream, skip_magic=False, emit_chunks=False, validate_crcs=True)
        try:
            for record in reader.records:
                if isinstance(record, Header):
                    header = (record.profile, record.library)
                elif isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message):
                    messages.append(record)
                good_end = stream.tell()
        except (McapError, EOFError, struct.error, ValueError) as exc:
            stopped_by = f'{type(exc).__name__}: {exc}'
    file = FileRecord(path.name)
    session = None
    kept = [m for m in messages if m.channel_id in channels]
    if kept:
        topics = _topics_of(channels, schemas)
        tmp = path.with_name(path.name + '.repairing')
        with tmp.open('wb') as out:
            writer, ids = start_mcap(out, topics, header)
            for message in kept:
                topic = channels[message.channel_id].topic
                writer.add_message(ids[topic], message.log_time, message.data,
                                   message.publish_time, message.sequence)
                file.add(topic, message.log_time)
                if topic == TOPIC_SESSION and session is None:
                    session = message.data
            writer.finish()
        tmp.replace(path)
    else:
        topics = {}
    return file, topics, session, FileRepair(path.name, True, len(kept),
                                             max(size - good_end, 0), stopped_by)


def _custom_data(bag: Path, session: bytes | None) -> dict[str, str]:
    try:
        custom = _load_metadata(bag).get('custom_data') or {}
    except (BagError, OSError):
        custom = {}
    if custom or session is None:
        return custom
    text = typestore().deserialize_cdr(session, 'std_msgs/msg/String').data
    return {CUSTOM_DATA_PREFIX + key: str(value) for key, value in json.loads(text).items()}


def repair_bag(bag: str | Path) -> BagRepair:
    """Repair `bag` in place (see the module docstring); BagError if it holds no MCAP file."""
    bag = Path(bag)
    files = sorted(bag.glob('*.mcap'), key=_file_index) if bag.is_dir() else []
    if not files:
        raise BagError(f'{bag}: no .mcap files; not a bag of MCAP files')
    for leftover in [*bag.glob('*.repairing'), *bag.glob('metadata.yaml.tmp')]:
        leftover.unlink()           # a repair or a metadata write interrupted before its rename
    report = BagRepair(bag)
    records: list[FileRecord] = []
    topics: dict[str, TopicRecord] = {}
    session = None
    for path in files:
        if mcap_complete(path):
            record, file_topics, first = _read_complete(path)
            report.files.append(FileRepair(path.name, False, record.message_count))
        else:
            record, file_topics, first, repair = _recover(path)
            report.files.append(repair)
        if not record.message_count:
            path.unlink()
            report.removed.append(path.name)
            continue
        records.append(record)
        topics.update({t: r for t, r in file_topics.items() if t not in topics})
        session = session if session is not None else first
    write_metadata(bag, bag_metadata(records, topics, _custom_data(bag, session)))
    return report
