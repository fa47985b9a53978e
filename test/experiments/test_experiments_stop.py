"""The main job stops when it is asked to: SIGTERM or SIGINT to its process group (a Ctrl-C, a
CI runner's cancel) ends `reproduce` and its workers."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest


def children(pid: int) -> list[int]:
    found = []
    for entry in Path('/proc').iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / 'stat').read_text().rsplit(')', 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                found.append(int(entry.name))
    return found


def group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.mark.skipif(not Path('/proc').is_dir(), reason='reads the process table in /proc')
@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGINT])
def test_reproduce_and_its_workers_stop_on_a_signal_to_the_group(tmp_path, sig):
    proc = subprocess.Popen([sys.executable, '-m', 'tacforce_ros.experiments.reproduce',
                             '--quick', '--out', str(tmp_path)], start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120.0
        while len(children(proc.pid)) < 2 and time.monotonic() < deadline:
            assert proc.poll() is None, 'reproduce ended before its workers started'
            time.sleep(0.2)
        assert len(children(proc.pid)) >= 2, 'the workers did not start'
        time.sleep(2.0)                     # the workers are in their first units
        os.killpg(proc.pid, sig)
        proc.wait(timeout=30)
        deadline = time.monotonic() + 10.0
        while group_alive(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not group_alive(proc.pid), 'a worker outlived the job'
    finally:
        if group_alive(proc.pid):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
