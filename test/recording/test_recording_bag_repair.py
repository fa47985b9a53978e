"""Bags as `ros2 bag record -s mcap` writes them, and their repair after a crash
(bagio.CalibrationBagWriter, recording/bag_repair.py): files split by size and by duration; a file
cut off anywhere after a flush keeps every message written up to that flush and nothing invented;
earlier files are left as they were; the session metadata survives a lost metadata.yaml; rosbags,
Foxglove's mcap reader and the metadata agree on every repaired bag."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tacforce_ros import bagio, topics
from tacforce_ros.hand.description import load_hand
from tacforce_ros.recording.bag_repair import repair_bag

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bag_readers import readers_agree  # noqa: E402
from ros_processes import executable  # noqa: E402

HAND = load_hand()
META = bagio.session_metadata(array='index_middle', plate='convex', source='sim', seed=3)
T0 = 5_000_000_000


def tactile(k: int):
    t = T0 + k * 10_000_000
    counts = np.full((HAND.n_taxels, 3), 30000 + k % 1000)
    return t, bagio.tactile_hand(t, HAND, counts, None, t * 1e-9, k)


def wrench(k: int):
    t = T0 + k * 10_000_000 + 1
    return t, bagio.wrench_stamped(t, 'ft_sensor', [0, 0, 0.01 * k, 0, 0, 0])


def write(path, n, flush_every=None, **options):
    """n tactile frames and n wrenches; returns the writer (closed) and, per flush, the file
    size and how many messages had been written by then."""
    flushes = []
    with bagio.CalibrationBagWriter(path, META, started_ns=T0, flush_seconds=3600.0,
                                    **options) as writer:
        for k in range(n):
            writer.write(topics.TOPIC_TACTILE, *tactile(k))
            writer.write(topics.TOPIC_WRENCH, *wrench(k))
            if flush_every and (k + 1) % flush_every == 0:
                writer.flush()
                flushes.append((writer._stream.tell(), 1 + 2 * (k + 1)))
    return writer, flushes


def test_one_file_by_default_and_splits_by_duration_and_by_size(tmp_path):
    single, _ = write(tmp_path / 'single', 300)
    assert [f.path for f in single.files] == ['single_0.mcap']
    assert readers_agree(tmp_path / 'single') == {topics.TOPIC_SESSION: 1,
                                                  topics.TOPIC_TACTILE: 300,
                                                  topics.TOPIC_WRENCH: 300}
    by_time, _ = write(tmp_path / 'by_time', 300, max_bag_duration=1.0)     # 3 s of log time
    assert len(by_time.files) == 3
    assert all(f.end_ns - f.start_ns < 1_000_000_000 for f in by_time.files)
    by_size, _ = write(tmp_path / 'by_size', 600, max_bag_size=bagio.CHUNK_BYTES)
    assert len(by_size.files) >= 2
    for bag in ('by_time', 'by_size'):
        counts = readers_agree(tmp_path / bag)
        assert counts[topics.TOPIC_TACTILE] == counts[topics.TOPIC_WRENCH] > 0
    info = bagio.load_metadata(tmp_path / 'by_time')
    assert info['ros_distro'] == bagio.ROS_DISTRO and info['storage_identifier'] == 'mcap'
    assert bagio.read_session_metadata(tmp_path / 'by_time')['plate'] == 'convex'


@pytest.fixture(scope='module')
def written(tmp_path_factory):
    path = tmp_path_factory.mktemp('bags') / 'cut'
    writer, flushes = write(path, 120, flush_every=10)
    return path, flushes, (path / 'cut_0.mcap').read_bytes()


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(after=st.integers(0, 11), extra=st.floats(0.0, 1.0))
def test_a_file_cut_after_a_flush_keeps_every_message_up_to_it(written, tmp_path_factory,
                                                               after, extra):
    path, flushes, data = written
    # Cut somewhere between flush `after` and the next one (or the end of the file).
    size, kept_at_least = flushes[after]
    upto = flushes[after + 1][0] if after + 1 < len(flushes) else len(data)
    cut = size + int(extra * (upto - size - 1))
    bag = tmp_path_factory.mktemp('cut') / 'cut'
    bag.mkdir()
    (bag / 'cut_0.mcap').write_bytes(data[:cut])
    (bag / 'metadata.yaml').write_bytes((path / 'metadata.yaml').read_bytes())
    report = repair_bag(bag)
    assert report.repaired and report.files[0].messages >= kept_at_least
    messages = list(bagio.read_messages(bag))
    assert len(messages) >= kept_at_least
    # What is kept is what was written, in order: the session message, then the frames 0..k.
    frames = [m for topic, _, m in messages if topic == topics.TOPIC_TACTILE]
    assert [m.server_sequence for m in frames] == list(range(len(frames)))
    readers_agree(bag)


def test_earlier_files_stay_as_they_were_and_the_session_survives_a_lost_metadata(tmp_path):
    bag = tmp_path / 'split'
    writer, _ = write(bag, 300, max_bag_duration=1.0)
    first, last = bag / writer.files[0].path, bag / writer.files[-1].path
    first_bytes = first.read_bytes()
    last.write_bytes(last.read_bytes()[:last.stat().st_size // 2])
    (bag / 'metadata.yaml').unlink()
    (bag / 'metadata.yaml.tmp').write_text('a metadata write cut off\n')
    report = repair_bag(bag)
    assert [f.recovered for f in report.files] == [False, False, True]
    assert first.read_bytes() == first_bytes
    assert bagio.read_session_metadata(bag)['plate'] == 'convex'
    counts = readers_agree(bag)
    assert 200 <= counts[topics.TOPIC_TACTILE] < 300


def test_a_whole_bag_is_left_whole_and_the_tool_says_so(tmp_path):
    bag = tmp_path / 'whole'
    write(bag, 50)
    before = {p.name: p.read_bytes() for p in bag.glob('*.mcap')}
    out = subprocess.run([executable('bag_repair'), str(bag)], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0 and 'already whole' in out.stdout, out.stdout + out.stderr
    assert {p.name: p.read_bytes() for p in bag.glob('*.mcap')} == before
    readers_agree(bag)


def test_the_tool_refuses_a_folder_that_is_not_a_bag(tmp_path):
    out = subprocess.run([executable('bag_repair'), str(tmp_path)], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 2 and 'no .mcap files' in out.stderr, out.stderr


@pytest.mark.parametrize('keep', [0, 8, 40])
def test_a_bag_cut_before_its_first_flush_is_refused_and_left_as_it_was(tmp_path, keep):
    """Nothing complete to keep (an empty file, the magic alone, the header): the tool says so
    (exit code 2) and changes nothing."""
    bag = tmp_path / 'early'
    write(bag, 5)
    mcap = bag / 'early_0.mcap'
    mcap.write_bytes(mcap.read_bytes()[:keep])
    before = {p.name: p.read_bytes() for p in bag.iterdir()}
    out = subprocess.run([executable('bag_repair'), str(bag)], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 2 and 'no complete message' in out.stderr, out.stdout + out.stderr
    assert {p.name: p.read_bytes() for p in bag.iterdir()} == before
