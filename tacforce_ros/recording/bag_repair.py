"""Make a bag cut off by a crash whole again (what `ros2 bag reindex` and `mcap recover` do
together): every MCAP file that does not end with the MCAP magic, or whose summary cannot be
read, is rewritten with each complete chunk it holds (its own schemas, channels and messages,
copied as they are; a chunk cut off mid-write is dropped, and with it only what came after the
writer's last flush), an MCAP file left with no message is removed, and metadata.yaml is rebuilt
from the files; a bag with no complete message at all is refused. The session metadata comes
from the old metadata.yaml where it loads, else from the /session/metadata message the bag
starts with. Complete files are read, never rewritten. ROS-free; the `bag_repair` tool runs it.
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
                                load_metadata, bag_metadata, mcap_complete, mcap_writer,
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


def _topic_record(channel: Channel, schema: Schema) -> TopicRecord:
    qos = YAML(typ='safe').load(channel.metadata.get('offered_qos_profiles', '')) or []
    return TopicRecord(schema.name, qos, channel.metadata.get('topic_type_hash', ''))


def _read_complete(path: Path) -> tuple[FileRecord, dict[str, TopicRecord], bytes | None]:
    """A complete file's counts and times from its summary; the first session message too.
    McapError when the summary cannot be read."""
    with path.open('rb') as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            raise McapError('no summary with statistics')
        record = FileRecord(path.name)
        stats = summary.statistics
        for channel_id, count in stats.channel_message_counts.items():
            record.counts[summary.channels[channel_id].topic] = count
        if stats.message_count:
            record.start_ns, record.end_ns = stats.message_start_time, stats.message_end_time
        session = next((message.data for _, channel, message in
                        reader.iter_messages(topics=[TOPIC_SESSION])), None)
        topics = {c.topic: _topic_record(c, summary.schemas[c.schema_id])
                  for c in summary.channels.values()}
        return record, topics, session


def _recover(path: Path) -> tuple[FileRecord, dict[str, TopicRecord], bytes | None, FileRepair]:
    """Rewrite a cut-off file with its complete records, as they are (schemas, channels and
    messages copied, not rebuilt), into a temporary file that then replaces it."""
    file = FileRecord(path.name)
    topics: dict[str, TopicRecord] = {}
    session = None
    stopped_by, good_end = 'end of file', 0
    size = path.stat().st_size
    tmp = path.with_name(path.name + '.repairing')
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    schema_ids: dict[int, int] = {}       # this file's ids -> the rewritten file's
    channel_ids: dict[int, int] = {}
    with path.open('rb') as stream, tmp.open('wb') as out:
        writer = None
        reader = StreamReader(stream, skip_magic=False, emit_chunks=False, validate_crcs=True)
        try:
            for record in reader.records:
                if isinstance(record, Header):
                    writer = mcap_writer(out, record.profile, record.library)
                elif isinstance(record, Schema) and writer is not None:
                    schemas[record.id] = record
                    schema_ids[record.id] = writer.register_schema(record.name, record.encoding,
                                                                   record.data)
                elif isinstance(record, Channel) and record.schema_id in schema_ids:
                    channels[record.id] = record
                    channel_ids[record.id] = writer.register_channel(
                        record.topic, record.message_encoding, schema_ids[record.schema_id],
                        record.metadata)
                    topics[record.topic] = _topic_record(record, schemas[record.schema_id])
                elif isinstance(record, Message) and record.channel_id in channel_ids:
                    writer.add_message(channel_ids[record.channel_id], record.log_time,
                                       record.data, record.publish_time, record.sequence)
                    topic = channels[record.channel_id].topic
                    file.add(topic, record.log_time)
                    if topic == TOPIC_SESSION and session is None:
                        session = record.data
                good_end = stream.tell()
        except (McapError, EOFError, struct.error, ValueError) as exc:
            stopped_by = f'{type(exc).__name__}: {exc}'
        if writer is not None:
            writer.finish()
    if file.message_count:
        tmp.replace(path)
    else:
        tmp.unlink()
    return file, topics, session, FileRepair(path.name, True, file.message_count,
                                             max(size - good_end, 0), stopped_by)


def _custom_data(bag: Path, session: bytes | None) -> dict[str, str]:
    try:
        custom = load_metadata(bag).get('custom_data') or {}
    except (BagError, OSError):
        custom = {}
    if custom or session is None:
        return custom
    try:
        text = typestore().deserialize_cdr(session, 'std_msgs/msg/String').data
        fields = json.loads(text)
    except Exception:   # noqa: BLE001 - an unreadable session message: no custom data
        return {}
    return {CUSTOM_DATA_PREFIX + key: str(value) for key, value in fields.items()}


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
        try:
            if not mcap_complete(path):
                raise McapError('it does not end with the MCAP magic')
            record, file_topics, first = _read_complete(path)
            report.files.append(FileRepair(path.name, False, record.message_count))
        except (McapError, EOFError, struct.error, ValueError, OSError):
            # OSError: a file shorter than a footer cannot be seeked back from its end.
            record, file_topics, first, repair = _recover(path)
            report.files.append(repair)
        if not record.message_count:
            report.removed.append(path.name)
            continue
        records.append(record)
        topics.update({t: r for t, r in file_topics.items() if t not in topics})
        session = session if session is not None else first
    if not records:
        raise BagError(f'{bag}: no complete message in any MCAP file (cut off before the '
                       'first flush?); nothing to keep, nothing changed')
    for name in report.removed:
        (bag / name).unlink()
    write_metadata(bag, bag_metadata(records, topics, _custom_data(bag, session)))
    return report
