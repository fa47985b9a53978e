"""A bag read by Foxglove's `mcap` reader as Foxglove Studio reads it: the first message of
every channel decoded from the ros2msg schema the file embeds (mcap_ros2), on top of
bagio.reader_counts' per-topic counts (metadata, rosbags, mcap), which must agree."""
from __future__ import annotations

from collections import Counter
from pathlib import Path

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from tacforce_ros import bagio


def readers_agree(bag: Path) -> Counter:
    """The counts per topic, after checking the three readers agree, every file of the folder
    is listed and complete, and every channel decodes from its embedded schema."""
    counts = bagio.reader_counts(bag)
    assert counts['metadata'] == counts['rosbags'] == counts['mcap'], counts
    info = bagio.load_metadata(bag)
    assert sorted(p.name for p in bag.iterdir()) == sorted(
        ['metadata.yaml', *info['relative_file_paths']]), 'a file not listed'
    assert all(bagio.mcap_complete(bag / name) for name in info['relative_file_paths'])
    decoders = DecoderFactory()
    decoded: set[str] = set()
    for name in info['relative_file_paths']:
        with (bag / name).open('rb') as stream:
            for schema, channel, message in make_reader(stream).iter_messages():
                if channel.topic not in decoded:
                    decoder = decoders.decoder_for(channel.message_encoding, schema)
                    assert decoder is not None, (channel.topic, schema.name)
                    decoder(message.data)
                    decoded.add(channel.topic)
    assert decoded == set(counts['mcap'])
    return Counter(counts['rosbags'])
