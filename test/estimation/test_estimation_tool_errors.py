"""Tools on bad input and unwritable output: the file and the cause named, exit code 2, no
traceback, and an output folder that cannot be written refused before any work."""
import shutil
import subprocess
import time
import uuid
from pathlib import Path

import pytest

from tacforce_ros import bagio, topics
from tacforce_ros.experiments import reproduce
from tacforce_ros.tools import train


@pytest.fixture(scope='module')
def good_bag(tmp_path_factory):
    path = tmp_path_factory.mktemp('bags') / 'good'
    meta = bagio.session_metadata(array='index_tip', plate='flat', source='sim', seed=0)
    with bagio.CalibrationBagWriter(path, meta) as writer:
        for i in range(50):
            stamp = 10**18 + i * 10**7
            writer.write(topics.TOPIC_WRENCH, stamp,
                         bagio.wrench_stamped(stamp, 'ft_sensor', [0, 0, 1, 0, 0, 0]))
    return path


def damaged(good_bag, tmp_path, damage):
    path = tmp_path / 'bag'
    shutil.copytree(good_bag, path)
    damage(path)
    return path


def truncate(path):
    mcap = next(path.glob('*.mcap'))
    mcap.write_bytes(mcap.read_bytes()[:mcap.stat().st_size // 2])


CASES = {
    'corrupt metadata': (lambda p: (p / 'metadata.yaml').write_text('a: [1\n  : :\n'),
                         'metadata.yaml: not valid YAML'),
    'truncated mcap': (truncate, 'good_0.mcap: incomplete MCAP file'),
    'missing mcap': (lambda p: next(p.glob('*.mcap')).unlink(), 'good_0.mcap: listed in'),
}


@pytest.mark.parametrize('case', CASES)
def test_train_names_the_file_and_the_cause_of_an_unreadable_bag(case, good_bag, tmp_path,
                                                                  capsys):
    damage, message = CASES[case]
    bag = damaged(good_bag, tmp_path, damage)
    assert train.main([str(bag), '--out', str(tmp_path / 'out')]) == 2
    err = capsys.readouterr().err
    assert message in err and str(bag) in err, err


def test_train_on_a_text_file_says_it_is_not_a_npz(tmp_path, capsys):
    text = tmp_path / 'notes.npz'
    text.write_text('pressed the flat plate twice\n')
    assert train.main([str(text), '--out', str(tmp_path / 'out')]) == 2
    err = capsys.readouterr().err
    assert f'{text}: not a readable dataset file (not a .npz file' in err, err


@pytest.fixture
def read_only_folder(tmp_path):
    """A read-only file system where this machine lets us mount one (root may write anywhere
    else), otherwise a folder the kernel refuses files in."""
    mount = tmp_path / 'ro'
    mount.mkdir()
    mounted = subprocess.run(['mount', '-t', 'tmpfs', '-o', 'ro,size=1m', 'tmpfs', str(mount)],
                             capture_output=True).returncode == 0
    try:
        yield mount if mounted else Path('/sys')
    finally:
        if mounted:
            subprocess.run(['umount', str(mount)], check=True)


@pytest.mark.parametrize('tool', [train, reproduce])
def test_an_unwritable_output_folder_is_refused_before_any_work(tool, good_bag,
                                                                 read_only_folder, capsys):
    out = read_only_folder / f'out_{uuid.uuid4().hex[:6]}'
    args = [str(good_bag), '--out', str(out)] if tool is train else ['--quick', '--out', str(out)]
    started = time.monotonic()
    with pytest.raises(SystemExit) as exit_info:
        tool.main(args)
    assert exit_info.value.code == 2
    assert time.monotonic() - started < 10.0, 'refused only after work began'   # work: minutes
    err = capsys.readouterr().err
    assert f'argument --out: {out}: cannot write there' in err, err


@pytest.fixture
def missing_gpu():
    import torch

    if torch.cuda.is_available():
        pytest.skip('this machine has a CUDA GPU')
    return 'cuda'


def test_train_refuses_a_device_it_cannot_train_on_before_reading_the_inputs(
        good_bag, tmp_path, capsys, missing_gpu):
    with pytest.raises(SystemExit) as exit_info:
        train.main([str(good_bag), '--out', str(tmp_path / 'out'), '--kinds', 'M4',
                    '--device', missing_gpu])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "torch device 'cuda': torch" in err and 'sees no CUDA GPU here' in err, err


def test_bench_train_refuses_a_device_it_cannot_train_on(tmp_path, capsys, missing_gpu):
    from tacforce_ros.benchmarks import bench_train

    assert bench_train.main(['--out', str(tmp_path / 'out'), '--device', missing_gpu]) == 2
    assert "torch device 'cuda'" in capsys.readouterr().err
