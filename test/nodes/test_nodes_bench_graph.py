"""bench_graph, run as a user runs it: a model list that cannot close the loop, or the magnetic
skin without models trained on it, is refused before any session starts; what it reads from a
recorded closed-loop bag (watchdog ticks, duplicate stamps, missing tactile frames) is checked on
a bag of known content, and what it reads from a fault run on ticks of known content."""
import subprocess

import numpy as np
import pytest

from tacforce_ros import bagio, topics
from tacforce_ros.benchmarks.bench_graph import (crash_metrics, driver_kill_metrics, stream_counts,
                                            watchdog_ticks)
from tacforce_ros.bringup.processes import executable


@pytest.mark.parametrize('models, message', [
    ('models: {thumb_tip: thumb.npz}\n', 'thumb.npz'),
    ('nothing: here\n', 'non-empty "models"')])
def test_a_model_list_that_cannot_close_the_loop_is_refused_first(tmp_path, models, message):
    config = tmp_path / 'models.yaml'
    config.write_text(models)
    done = subprocess.run([str(executable('bench_graph')), '--runs', '1',
                           '--model', str(config), '--out', str(tmp_path / 'out')],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    assert message in done.stderr
    assert not (tmp_path / 'out' / 'closed_loop_0').exists()


def test_the_magnetic_skin_without_a_model_trained_on_it_is_refused_first(tmp_path):
    done = subprocess.run([str(executable('bench_graph')), '--runs', '1',
                           '--skin', 'magnetic', '--out', str(tmp_path / 'out')],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    assert '--skin magnetic needs a --model trained on that skin' in done.stderr
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
                          estimate_age=0.0, joints_fresh=True)

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


def outage_ticks():
    """10 s at 100 Hz: the last estimate is stamped 3.00 s (fresh until 3.04 with a 0.05 s
    timeout), stale from 3.05 (safe ramp, hold from 3.10) until it returns at 5.00 s, tracking
    0.03 N off from 5.30 s."""
    t = np.round(np.arange(1000) * 0.01, 2)
    modes = ['closed_loop'] * 1000
    modes[305:310] = ['safe'] * 5
    modes[310:500] = ['hold'] * 190
    fresh = (t < 3.05) | (t >= 5.0)
    age = np.where(fresh, 0.005, t - 3.0)            # the controller's latest valid estimate
    f_d = np.tile([0.0, 0.0, -1.5], (1000, 1))
    f_hat = f_d + 0.02 * np.sin(t)[:, None]
    f_hat[~fresh] = np.nan
    f_hat[500:530] += 0.3                            # off by 0.3 N for 0.3 s after the return
    f_tilde = np.tile([0.1, 0.0, -1.2], (1000, 1))
    tip = np.zeros((1000, 3))
    return t, modes, fresh, age, f_d, f_hat, f_tilde, tip


def test_crash_metrics_read_the_hold_the_contact_and_the_recovery():
    t, modes, fresh, age, f_d, f_hat, f_tilde, tip = outage_ticks()
    result = crash_metrics(t, modes, fresh, age, f_d, f_hat, f_tilde, tip)
    assert result['last_estimate_s'] == pytest.approx(3.0) and result['estimate_back_s'] == 5.0
    assert result['hold_after_s'] == pytest.approx(0.10)
    assert result['least_normal_force_n'] == pytest.approx(1.2)
    assert result['most_shear_per_normal'] == pytest.approx(0.1 / 1.2)
    # Under 0.05 N on average over 0.5 s only once the 0.3 s off spell has (nearly) left it.
    assert 0.5 < result['tracking_back_after_s'] <= 0.8
    assert result['passed']


def test_the_hold_is_timed_from_the_last_estimate_the_controller_had():
    """The last estimate is the one the first stale tick was aging: 58 ms old there, it was
    stamped 2.992 s, and the hold at 3.10 s came 0.108 s after it (too late)."""
    t, modes, fresh, age, f_d, f_hat, f_tilde, tip = outage_ticks()
    age[305:500] = t[305:500] - 2.992
    result = crash_metrics(t, modes, fresh, age, f_d, f_hat, f_tilde, tip)
    assert result['last_estimate_s'] == pytest.approx(2.992)
    assert result['hold_after_s'] == pytest.approx(0.108) and not result['passed']


def test_an_outage_that_missed_the_held_command_is_not_judged():
    """The command steps 0.5 s after the estimate returned: the recovery would be that step's
    response, so the run is reported as one whose kill landed wrong, not judged."""
    t, modes, fresh, age, f_d, f_hat, f_tilde, tip = outage_ticks()
    f_d[550:] = [0.0, 0.0, -2.0]
    assert 'did not fall inside one held command' in crash_metrics(
        t, modes, fresh, age, f_d, f_hat, f_tilde, tip)['failed']


def test_the_drill_outage_is_judged_and_a_short_stale_blip_before_it_is_reported():
    """An estimate stale for 30 ms just after engaging (session 15's failed fault run judged
    that blip instead of the kill's outage): the longest spell is the drill's."""
    t, modes, fresh, age, f_d, f_hat, f_tilde, tip = outage_ticks()
    fresh[20:23] = False
    modes[22:24] = ['safe'] * 2
    result = crash_metrics(t, modes, fresh, age, f_d, f_hat, f_tilde, tip)
    assert result['last_estimate_s'] == pytest.approx(3.0) and result['passed']
    assert result['other_stale_spells'] == [{'at_s': 0.2, 'lasted_s': pytest.approx(0.03)}]
    fresh[995:] = False                              # and stale at the very end
    result = crash_metrics(t, modes, fresh, age, f_d, f_hat, f_tilde, tip)
    assert result['last_estimate_s'] == pytest.approx(3.0)
    assert len(result['other_stale_spells']) == 2
    fresh[3000 // 10:] = False                       # the drill's outage never ends
    assert 'never returned' in crash_metrics(t, modes, fresh, age, f_d, f_hat, f_tilde,
                                             tip)['failed']


def test_crash_metrics_fail_a_lost_contact_a_late_hold_and_a_missing_outage():
    t, modes, fresh, age, f_d, f_hat, f_tilde, tip = outage_ticks()
    f_tilde[350:360, 2] = 0.0                        # off the plate for 0.1 s
    assert not crash_metrics(t, modes, fresh, age, f_d, f_hat, f_tilde, tip)['passed']
    t, modes, fresh, age, f_d, f_hat, f_tilde, tip = outage_ticks()
    modes[310:312] = ['safe'] * 2                    # hold 20 ms late
    late = crash_metrics(t, modes, fresh, age, f_d, f_hat, f_tilde, tip)
    assert late['hold_after_s'] == pytest.approx(0.12) and not late['passed']
    always_fresh = np.ones(1000, bool)
    assert 'never went stale' in crash_metrics(t, ['closed_loop'] * 1000, always_fresh, age,
                                               f_d, f_d, f_tilde, tip)['failed']


def test_session_figures_are_read_from_its_log_and_tabled_side_by_side(tmp_path):
    """Wall time and CPU per process come from the session tool's own lines; a composed run is
    tabled next to the run of the same seed with one process per node."""
    from tacforce_ros.benchmarks.bench_graph import process_cpu, session_seconds, summary, table
    from tacforce_ros.bringup.processes import CPU_REPORT
    from tacforce_ros.experiments.node_path import session_exit_codes
    (tmp_path / 'session.log').write_text(
        'session closed_loop: started sim_world, tacforce_container\n'
        f'{CPU_REPORT} sim_world=16.6, tacforce_container=30.6\n'
        'session closed_loop: stopped after 34.7 s; exit codes sim_world=0, '
        'tacforce_container=-9\n')
    assert session_seconds(tmp_path) == 34.7
    assert process_cpu(tmp_path) == {'sim_world': 16.6, 'tacforce_container': 30.6}
    assert session_exit_codes(tmp_path) == {'sim_world': 0, 'tacforce_container': -9}
    assert session_exit_codes(tmp_path / 'none') == {}

    def run(composed, cpu):
        return {'run': 0, 'seed': 0, 'composed': composed, 'session_wall_s': 35.0, 'cpu_s': cpu,
                'achieved_real_time_factor': 0.8, 'e_tilde': {'node': 0.07, 'direct': 0.072},
                'e_track': {'node': 0.021, 'direct': 0.022}, 'e_tilde_difference': 0.002,
                'e_track_difference': 0.001,
                'watchdog': {'ticks': 8000, 'safe': 0, 'hold_after_engaging': 0},
                'streams': {}}
    separate = run(False, {'sim_world': 16.0, 'estimator': 3.0, 'allegro_driver': 10.0})
    separate['exit_codes'] = {'sim_world': 0, 'allegro_driver': -9, 'estimator': -2}
    composed = run(True, {'sim_world': 17.0, 'tacforce_container': 30.0})
    composed['exit_codes'] = {'sim_world': 0, 'tacforce_container': 0}
    result = {'lockstep': True, 'sequence': 'paper_70s', 'model': 'm.yaml', 'skin': 'magnetic',
              'closed_loop': [separate], 'closed_loop_composed': [composed],
              'summary': summary([separate]), 'summary_composed': summary([composed]),
              'fault_runs': [{'run': 0, 'seed': 0,
                              'failed': 'session closed_loop: 80 s simulated did not run'}]}
    text = table(result)
    assert 'fault run 0 (seed 0, fault_drill): FAILED: session closed_loop: 80 s' in text
    assert 'fault runs passed: 0 of 1' in text and 'magnetic skin)' in text
    assert '| 0 | 0 | one per node |' in text and '| 0 | 0 | one (composed) |' in text
    assert '| 13 / 16 |' in text and '| 30 / 17 |' in text
    assert 'composed in one process: agree' in text and '1 of 1' in text
    # A node killed at the stop is named; one stopped while Python was starting (-2) is not.
    assert ('did not end cleanly when their session stopped them: closed loop 0: '
            'allegro_driver exit code -9\n' in text + '\n'), text


def test_driver_kill_metrics_read_the_press_while_the_driver_was_down_and_after():
    """Joint states stop from 3.00 to 6.00 s (the driver is down): the press is read before,
    during and after that gap, and tracking from when the joints came back."""
    t, modes, fresh, age, f_d, f_hat, f_tilde, tip = outage_ticks()
    f_hat = f_d + 0.02 * np.sin(t)[:, None]
    f_tilde[300:600, 2] = -1.1                       # the last torque kept: the press holds
    f_tilde[600:650, 2] = -0.2                       # servos off on restart: the press drops
    f_hat[600:700] += 0.3                            # then the loop takes it back
    joints = np.r_[np.arange(0.0, 3.0, 0.003), np.arange(6.0, 10.0, 0.003)]
    result = driver_kill_metrics(t, f_d, f_hat, f_tilde, joints)
    assert result['joints_stopped_s'] == pytest.approx(2.997, abs=2e-3)
    assert result['joints_back_s'] == pytest.approx(6.0) and result['outage_s'] > 2.99
    assert result['normal_force_before_n'] == pytest.approx(1.2)
    assert result['normal_force_during_n'] == pytest.approx([1.1, 1.1])
    assert result['normal_force_after_n'] == pytest.approx([0.2, 1.2])
    assert 1.0 < result['tracking_back_after_s'] <= 1.5
    assert 'failed' in driver_kill_metrics(t, f_d, f_hat, f_tilde, joints[:1])
