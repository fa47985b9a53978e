"""One finger's session: start-pose hold, engagement, the law, and one transition per change."""
import numpy as np

from tacforce_ros.control.finger_session import FingerSession
from tacforce_ros.control.force_controller import (MODE_CLOSED_LOOP, MODE_HOLD, MODE_OPEN_LOOP,
                                                   ForceController)

from test_control_force_controller import DT, KIN, Q16, ZERO16, config

F_D = np.array([0.0, 0.0, 1.0])
FRESH = np.array([0.0, 0.0, 0.8])
NONE = np.full(3, np.nan)


def test_holds_the_start_pose_until_a_command_and_a_fresh_estimate():
    session = FingerSession(config(), KIN)
    start = Q16.copy()
    # No command: the finger holds where it was at the first tick, whatever the estimate says.
    tau, state, transition = session.update(0.0, start, ZERO16, FRESH, 0.0, 0.0, None)
    hold = ForceController(config(k_i=(0.0,) * 3, q_d=tuple(start[:4])), KIN)
    expected, _ = hold.update(0.0, start, ZERO16, NONE, np.inf, 0.0, np.zeros(3))
    np.testing.assert_allclose(tau, expected, rtol=1e-12)
    assert state.mode == MODE_HOLD and not session.engaged
    assert str(transition) == 'controller start -> hold: start pose hold, no desired force yet'
    # A command, but the estimate is stale: still holding, and now waiting for the estimate.
    _, state, transition = session.update(DT, start, ZERO16, FRESH, 0.2, 0.0, F_D)
    assert state.mode == MODE_HOLD and not session.engaged
    assert transition.reason == 'start pose hold, waiting for a valid estimate'
    _, state, transition = session.update(2 * DT, start, ZERO16, FRESH, 0.2, 0.0, F_D)
    assert transition is None                       # the same cause is not repeated
    # A fresh estimate: the law runs from this tick.
    tau, state, transition = session.update(3 * DT, start, ZERO16, FRESH, 0.0, 0.0, F_D)
    assert session.engaged and state.mode == MODE_CLOSED_LOOP
    assert str(transition) == 'controller hold -> closed_loop: streams fresh'
    law = ForceController(config(), KIN)
    expected, _ = law.update(3 * DT, start, ZERO16, FRESH, 0.0, 0.0, F_D)
    np.testing.assert_allclose(tau, expected, rtol=1e-12)


def test_open_loop_engages_on_the_command_alone():
    session = FingerSession(config(k_i=(0.0,) * 3), KIN)
    session.update(0.0, Q16, ZERO16, NONE, np.inf, 0.0, None)
    _, state, transition = session.update(DT, Q16, ZERO16, NONE, np.inf, 0.0, F_D)
    assert session.engaged and state.mode == MODE_OPEN_LOOP
    assert transition.mode == MODE_OPEN_LOOP


def test_each_change_of_mode_or_cause_is_one_transition_with_its_reason():
    session = FingerSession(config(ramp_time=0.05), KIN)
    log = []
    inputs = ([(FRESH, 0.0, 0.0)] * 5 + [(FRESH, 0.08, 0.0)] * 10   # estimate goes stale
              + [(FRESH, 0.0, 0.0)] * 10                             # it returns
              + [(FRESH, 0.0, 0.5)] * 10)                            # the joints go stale
    for k, (f_hat, f_age, q_age) in enumerate(inputs):
        _, _, transition = session.update(k * DT, Q16, ZERO16, f_hat, f_age, q_age, F_D)
        if transition is not None:
            log.append(str(transition))
    assert log == [
        'controller start -> closed_loop: streams fresh',
        'controller closed_loop -> safe: estimate stale: age 0.080 s > 0.05 s',
        'controller safe -> hold: estimate stale: age 0.080 s > 0.05 s',
        'controller hold -> closed_loop: streams fresh',
        'controller closed_loop -> safe: joints stale: age 0.500 s > 0.02 s']


def test_the_start_hold_is_never_reported_engaged_while_it_recovers_from_stale_joints():
    """Stale joints during the start hold ramp it out (`safe`); when they return it ramps back in
    and is still the hold, not the law: a reader takes the first tick in neither mode as the
    moment the controller engaged (node_path.node_trace, bench_graph)."""
    session = FingerSession(config(), KIN)
    modes = []
    for k, q_age in enumerate([0.0] * 3 + [0.5] * 3 + [0.0] * 10):
        _, state, _ = session.update(k * DT, Q16, ZERO16, NONE, np.inf, q_age, F_D)
        modes.append(state.mode)
    assert not session.engaged
    assert set(modes) == {MODE_HOLD, 'safe'} and modes[-1] == MODE_HOLD, modes
