"""Reading a bag: its metadata, its files checked complete, its messages, and its message counts
as three readers see them."""
from __future__ import annotations

from collections import Counter
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from rosbags.rosbag2 import Reader, ReaderError
from ruamel.yaml import YAML
from ruamel.yaml.error import YAMLError

from tacforce_ros.bagio.layout import CUSTOM_DATA_PREFIX, MCAP_MAGIC, BagError, typestore


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
