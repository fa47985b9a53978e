"""`session calibration` in simulation, as a user runs it: the bag it leaves is readable by
rosbags with every recorded topic and the session metadata."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tacforce_ros.bagio import read_messages, read_session_metadata
from tacforce_ros.hand.description import load_hand
from tacforce_ros.topics import (TOPIC_JOINTS, TOPIC_SAMPLE, TOPIC_SESSION, TOPIC_SIM_CONTACT,
                                 TOPIC_TACTILE, TOPIC_WRENCH)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from graph_support import free_ports, unique_domain_id  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import executable, ros_env  # noqa: E402

pytestmark = pytest.mark.ros
# Wall seconds of the session. The graph's start-up comes out of them: on a host that stalled
# ~1 s every second it took 8-10 s (the recorder's first /clock 7 s after launch, the F/T
# stream matched 2.5 s later), which left a 10 s session with no wrench recorded.
SECONDS = 30.0


@pytest.fixture(scope='module')
def session_bag(tmp_path_factory):
    out = tmp_path_factory.mktemp('calibration')
    result = subprocess.run(
        [executable('session'), 'calibration', '--array', 'index_tip', '--plate', 'flat',
         '--out', out, '--duration', str(SECONDS),
         '--ports', *[str(p) for p in free_ports(offset=0)]],
        env=ros_env(unique_domain_id(offset=71)), capture_output=True, text=True, timeout=300)
    logs = '\n'.join(p.read_text()[-800:] for p in sorted((out / 'logs').glob('*.log')))
    assert result.returncode == 0, result.stdout + result.stderr + logs
    bags = [p for p in out.iterdir() if p.is_dir() and p.name != 'logs']
    assert len(bags) == 1 and str(bags[0].resolve()) in result.stdout
    return bags[0]


def test_metadata_names_the_simulated_session(session_bag):
    meta = read_session_metadata(session_bag)
    assert (meta['array'], meta['plate'], meta['source']) == ('index_tip', 'flat', 'sim')
    assert meta['scene'] == 'calibration_index_tip_flat'


def test_every_stream_is_recorded_and_decodes(session_bag):
    hand = load_hand()
    # The simulator's ground truth is recorded too; a calibration session has no controller.
    counts = dict.fromkeys((TOPIC_TACTILE, TOPIC_WRENCH, TOPIC_JOINTS, TOPIC_SAMPLE,
                            TOPIC_SESSION, TOPIC_SIM_CONTACT), 0)
    tactile_stamps, pressed = [], []
    for topic, _, msg in read_messages(session_bag):
        counts[topic] += 1
        if topic == TOPIC_TACTILE:
            assert [a.name for a in msg.arrays] == [a.name for a in hand.arrays]
            assert [a.header.frame_id for a in msg.arrays] == [a.frame_id for a in hand.arrays]
            tactile_stamps.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
        elif topic == TOPIC_SAMPLE:
            assert msg.tactile.name == 'index_tip'
            pressed.append(np.linalg.norm([msg.wrench.wrench.force.x, msg.wrench.wrench.force.y,
                                           msg.wrench.wrench.force.z]))
    assert all(counts.values()), counts
    # Simulated time at the scene's 100 Hz: a wall-clock load spike must not show in the stamps.
    rate = (len(tactile_stamps) - 1) / (tactile_stamps[-1] - tactile_stamps[0])
    assert 80.0 < rate < 105.0, rate
    # The operator model presses the plate: the F/T reading is not just noise.
    assert max(pressed) > 0.3
