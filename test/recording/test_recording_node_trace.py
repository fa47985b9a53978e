"""A closed-loop bag as sync_recorder writes it, read back as a trace on the sequence's clock
(tacforce_ros/experiments/node_path.py): the clock starts at the first recorded f_d, the F/T
is zeroed on its readings before the controller engaged, and f_hat is NaN where the controller
had no fresh estimate. Bags without what that needs are refused, saying why."""
import numpy as np
import pytest

from tacforce_ros import bagio, topics
from tacforce_ros.control.command_sequence import ForceSequence
from tacforce_ros.experiments.node_path import NodePathUnavailable, node_trace
from tacforce_ros.nodes.sync_recorder import (BAG_TOPICS, TOPIC_CONTROLLER_STATE,
                                              TOPIC_DESIRED)

MS = 1_000_000
START_NS = 3_000 * MS            # simulated time of the player's first command
BIAS = np.array([0.2, -0.25, 0.1])
SEQUENCE = ForceSequence.from_mapping({'frame_id': 'ft_sensor', 'segments': [
    {'duration': 1.0, 'force': [0.0, 0.0, 0.0]},
    {'duration': 2.0, 'force': [0.0, 0.0, -2.0]}]})


def vector(types, xyz):
    return types['geometry_msgs/msg/Vector3'](x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))


def controller_state(types, stamp_ns, f_d, f_hat, fresh, mode=None):
    empty = np.zeros(0, np.float64)
    return types['tacforce_msgs/msg/ControllerState'](
        header=bagio.header(stamp_ns, 'ft_sensor'), finger='index',
        mode=mode or ('closed_loop' if fresh else 'hold'), desired_force=vector(types, f_d),
        estimated_force=vector(types, f_hat), integral_error=vector(types, (0, 0, 0)),
        q=empty, qdot=empty, tau_cmd=empty, saturation_scale=1.0, estimate_fresh=fresh,
        estimate_age=0.005 if fresh else float('inf'), joints_fresh=True)


def write_bag(path, ft_from_ns, commands=True, safe_at_ns=None):
    types = bagio.typestore().types
    meta = bagio.session_metadata(array='index_tip', plate='spherical', source='sim')
    with bagio.CalibrationBagWriter(path, meta, topics=BAG_TOPICS) as writer:
        if safe_at_ns is not None:      # a watchdog tick of the start hold, before engaging
            writer.write(TOPIC_CONTROLLER_STATE, safe_at_ns, controller_state(
                types, safe_at_ns, (0, 0, 0), (0, 0, 0), False, mode='safe'))
        # F/T at 1 kHz: its bias, plus the press once the sequence's 1 s of zero is over.
        for t_ns in range(ft_from_ns, START_NS + 3_000 * MS, MS):
            force = BIAS + (SEQUENCE.force_at((t_ns - START_NS) * 1e-9) if t_ns >= START_NS
                            else 0.0)
            writer.write(topics.TOPIC_WRENCH, t_ns,
                         bagio.wrench_stamped(t_ns, 'ft_sensor', [*force, 0.0, 0.0, 0.0]))
        if not commands:
            return
        for k in range(300):                          # 100 Hz ticks over the 3 s sequence
            t_ns = START_NS + k * 10 * MS
            f_d = SEQUENCE.force_at(k * 0.01)
            writer.write(TOPIC_DESIRED, t_ns, types['geometry_msgs/msg/Vector3Stamped'](
                header=bagio.header(t_ns, 'ft_sensor'), vector=vector(types, f_d)))
            fresh = k % 10 != 0                       # every tenth tick without an estimate
            writer.write(TOPIC_CONTROLLER_STATE, t_ns,
                         controller_state(types, t_ns, f_d, f_d + [0.0, 0.0, 0.05], fresh))


def test_trace_starts_at_the_first_command_with_the_ft_zeroed_before_it(tmp_path):
    write_bag(tmp_path / 'bag', ft_from_ns=START_NS - 1_000 * MS)
    trace, start = node_trace(tmp_path / 'bag', SEQUENCE, tare_frames=50)
    assert start == pytest.approx(START_NS * 1e-9)
    np.testing.assert_allclose(trace.t, np.arange(300) * 0.01, atol=1e-9)
    np.testing.assert_allclose(trace.f_d, [SEQUENCE.force_at(t) for t in trace.t])
    # Zeroed: the bias is gone, the press is what remains (interpolated at the ticks).
    np.testing.assert_allclose(trace.f_tilde, trace.f_d, atol=1e-9)
    stale = np.arange(300) % 10 == 0
    assert np.isnan(trace.f_hat[stale]).all()
    np.testing.assert_allclose(trace.f_hat[~stale], trace.f_d[~stale] + [0.0, 0.0, 0.05])


def test_a_watchdog_tick_of_the_start_hold_is_not_the_engagement(tmp_path):
    """The F/T is zeroed before the first tick in open or closed loop; a `safe` tick while the
    start pose is held (stale joints at start-up) comes before that, and before the F/T."""
    write_bag(tmp_path / 'bag', ft_from_ns=START_NS - 700 * MS, safe_at_ns=START_NS - 800 * MS)
    trace, _ = node_trace(tmp_path / 'bag', SEQUENCE, tare_frames=50)
    np.testing.assert_allclose(trace.f_tilde, trace.f_d, atol=1e-9)


@pytest.mark.parametrize('ft_from_ns, commands, words', [
    (START_NS + 20 * MS, True, 'F/T readings before the controller engaged'),
    (START_NS - 1_000 * MS, False, 'not a closed-loop run')])
def test_bags_without_what_the_trace_needs_are_refused(tmp_path, ft_from_ns, commands, words):
    write_bag(tmp_path / 'bag', ft_from_ns, commands)
    with pytest.raises(NodePathUnavailable, match=words):
        node_trace(tmp_path / 'bag', SEQUENCE, tare_frames=50)
