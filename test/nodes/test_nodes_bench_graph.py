"""bench_graph, run as a user runs it: a model list that cannot close the loop is refused before
any session starts; what it reads from a recorded closed-loop bag (watchdog ticks, duplicate
stamps, missing tactile frames) is checked on a bag of known content."""
import subprocess
import sys

import numpy as np
import pytest

from tacforce_ros import bagio, topics
from tacforce_ros.tools.bench_graph import stream_counts, watchdog_ticks


@pytest.mark.parametrize('models, message', [
    ('models: {thumb_tip: thumb.npz}\n', 'thumb.npz'),
    ('nothing: here\n', 'non-empty "models"')])
def test_a_model_list_that_cannot_close_the_loop_is_refused_first(tmp_path, models, message):
    config = tmp_path / 'models.yaml'
    config.write_text(models)
    done = subprocess.run([sys.executable, '-m', 'tacforce_ros.tools.bench_graph', '--runs', '1',
                           '--model', str(config), '--out', str(tmp_path / 'out')],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    assert message in done.stderr
    assert not (tmp_path / 'out' / 'closed_loop_0').exists()


def test_watchdog_ticks_and_stream_counts_read_from_a_bag(tmp_path):
    store = bagio.typestore()
    state_type = store.types['tacforce_msgs/msg/ControllerState']
    vector = store.types['geometry_msgs/msg/Vector3']

    def state(stamp_ns: int, mode: str):
        zero = np.zeros(4)
        return state_type(header=bagio.header(stamp_ns, 'ft_sensor'), finger='index', mode=mode,
                          desired_force=vector(0.0, 0.0, 0.0),
                          estimated_force=vector(0.0, 0.0, 0.0),
                          integral_error=vector(0.0, 0.0, 0.0), q=zero, qdot=zero,
                          tau_cmd=zero, saturation_scale=1.0, estimate_fresh=True,
                          joints_fresh=True)

    from tacforce_ros.hand.description import load_hand
    hand = load_hand()
    counts = np.zeros((hand.n_taxels, 3), np.uint16)
    types = {**bagio.TOPIC_TYPES,
             topics.TOPIC_CONTROLLER_STATE: 'tacforce_msgs/msg/ControllerState'}
    modes = ['hold', 'safe', 'hold', 'closed_loop', 'safe', 'closed_loop', 'hold', 'closed_loop']
    with bagio.CalibrationBagWriter(tmp_path / 'bag', bagio.session_metadata(array='index_tip'),
                                    topics=types) as bag:
        for k, mode in enumerate(modes):
            bag.write(topics.TOPIC_CONTROLLER_STATE, k, state(k * 10_000_000, mode))
        # tactile frames 10 ms apart: one stamp repeated, two frames missing before 60 ms
        for k, (sequence, stamp) in enumerate([(1, 10), (2, 20), (5, 20), (6, 30), (9, 60)]):
            bag.write(topics.TOPIC_TACTILE, 100 + k,
                      bagio.tactile_hand(stamp * 1_000_000, hand, counts, None, 0.0, sequence))
        for k, stamp in enumerate([1, 2, 2, 2, 3]):
            bag.write(topics.TOPIC_WRENCH, 200 * (k > 0) + k,
                      bagio.wrench_stamped(stamp * 1_000_000, 'ft_sensor', [0.0] * 6))
    assert watchdog_ticks(tmp_path / 'bag') == {'ticks': 8, 'safe': 2, 'hold_after_engaging': 1}
    streams = stream_counts(tmp_path / 'bag')
    assert streams[topics.TOPIC_TACTILE] == {'messages': 5, 'duplicate_stamps': 1,
                                             'log_time_zero': 0, 'missing_frames': 2}
    assert streams[topics.TOPIC_WRENCH] == {'messages': 5, 'duplicate_stamps': 2,
                                            'log_time_zero': 1}
    assert streams[topics.TOPIC_CONTROLLER_STATE] == {'messages': 8, 'duplicate_stamps': 0,
                                                      'log_time_zero': 1}
