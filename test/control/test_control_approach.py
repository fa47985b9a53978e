"""The guarded approach: the law's position target moves toward q_d at a bounded speed and stops
where the estimate first shows the touch; blind (open loop, a stale estimate) it moves slowly, on
to q_d; in closed loop the force command waits for the touch."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tacforce_ros.control.approach import GuardedApproach
from tacforce_ros.control.finger_session import FingerSession
from tacforce_ros.control.force_controller import ControllerConfigError, ForceController

from test_control_force_controller import DT, KIN, Q16, ZERO16, config

START = np.array([0.0, 0.55, 0.55, 0.55])
GOAL = np.array([0.0, 0.8, 0.8, 0.8])
NOTHING = np.array([0.0, 0.0, 0.02])        # a fresh estimate out of contact
TOUCHING = np.array([0.0, 0.0, 0.3])


def test_the_target_moves_while_feeling_nothing_and_stops_at_the_touch():
    approach = GuardedApproach(START, GOAL, speed=0.2, blind_speed=0.05)
    assert np.array_equal(approach.update(0.0, True, False), START)    # no time has passed
    np.testing.assert_allclose(approach.update(0.5, True, False), START + 0.1 * np.r_[0, 1, 1, 1])
    # The touch: the target stays where the last tick put it, for good.
    np.testing.assert_allclose(approach.update(1.0, True, True), START + 0.1 * np.r_[0, 1, 1, 1])
    assert approach.touched_at == 1.0 and approach.done
    np.testing.assert_allclose(approach.update(5.0, False, False),
                               START + 0.1 * np.r_[0, 1, 1, 1])


def test_what_cannot_be_felt_is_approached_slowly_all_the_way():
    approach = GuardedApproach(START, GOAL, speed=0.2, blind_speed=0.05)
    approach.update(0.0, False, False)
    np.testing.assert_allclose(approach.update(1.0, False, False), START + 0.05 * np.r_[0, 1, 1, 1])
    assert np.array_equal(approach.update(60.0, False, False), GOAL) and approach.done
    assert approach.touched_at is None


def test_bad_speeds_or_poses_are_refused():
    with pytest.raises(ValueError, match='blind_speed'):
        GuardedApproach(START, GOAL, speed=0.05, blind_speed=0.2)
    with pytest.raises(ValueError, match='finite'):
        GuardedApproach(START, GOAL[:3], speed=0.2, blind_speed=0.05)
    with pytest.raises(ControllerConfigError, match='blind_speed'):
        config(approach_speed=0.05, blind_speed=0.2)
    with pytest.raises(ControllerConfigError, match='touch_force'):
        config(touch_force=0.0)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=8, max_size=8),
       st.floats(0.01, 2.0), st.floats(0.05, 1.0),
       st.lists(st.tuples(st.floats(0.0, 0.2), st.booleans(), st.booleans()), min_size=1,
                max_size=40))
def test_the_target_never_outruns_its_speed_and_stays_on_the_line(poses, speed, share, ticks):
    start, goal = np.array(poses[:4]), np.array(poses[4:])
    approach = GuardedApproach(start, goal, speed, speed * share)
    t, previous = 0.0, approach.update(0.0, True, False)
    moving = goal != start
    for dt, feels, touch in ticks:
        t += dt
        q = approach.update(t, feels, touch)
        assert np.abs(q - previous).max() <= speed * dt * (1 + 1e-9) + 1e-12
        if approach.touched_at is not None and approach.touched_at < t:
            assert np.array_equal(q, previous)              # stopped at the touch
        along = (q - start)[moving] / (goal - start)[moving]
        assert np.all(along >= -1e-9) and np.all(along <= 1 + 1e-9)    # never past q_goal
        previous = q


def held_at_start() -> tuple[FingerSession, np.ndarray, np.ndarray]:
    """A closed-loop session at START after its first tick (the start pose hold, no command
    yet), the joints and the force it will be commanded."""
    cfg = config(q_d=tuple(GOAL), approach_speed=0.2, blind_speed=0.05, touch_force=0.15)
    session = FingerSession(cfg, KIN)
    q = Q16.copy()
    q[:4] = START
    session.update(0.0, q, ZERO16, NOTHING, 0.0, 0.0, None)
    return session, q, np.array([0.0, 0.0, 1.0])


def test_the_session_engages_at_its_pose_and_presses_only_from_the_touch():
    session, q, f_d = held_at_start()
    log = []
    tau, state, transition = session.update(DT, q, ZERO16, NOTHING, 0.0, 0.0, f_d)
    log.append(str(transition))
    # Engaged: the law aims at where the finger is, with no force command before the touch.
    law = ForceController(config(q_d=tuple(START)), KIN)
    expected, _ = law.update(DT, q, ZERO16, NOTHING, 0.0, 0.0, np.zeros(3))
    np.testing.assert_allclose(tau, expected, rtol=1e-12)
    for k in range(2, 40):
        _, state, transition = session.update(k * DT, q, ZERO16, NOTHING, 0.0, 0.0, f_d)
        assert not state.desired_force.any()
        log += [str(transition)] if transition else []
    for k in range(40, 60):
        _, state, transition = session.update(k * DT, q, ZERO16, TOUCHING, 0.0, 0.0, f_d)
        assert np.array_equal(state.desired_force, f_d)             # pressing from the touch
        log += [str(transition)] if transition else []
    np.testing.assert_allclose(session.approach.q_ref, START + 0.2 * 0.38 * np.r_[0, 1, 1, 1])
    assert log == ['controller hold -> closed_loop: approaching q_d at 0.2 rad/s',
                   'controller closed_loop -> closed_loop: touched: |f_hat| 0.30 N, force '
                   'control from here',
                   'controller closed_loop -> closed_loop: streams fresh']


def test_a_target_at_q_d_before_any_touch_says_so_and_hands_over_to_force_control():
    session, q, f_d = held_at_start()
    log, pressing = [], []
    for k in range(1, 200):     # 0.25 rad at 0.2 rad/s: q_d after 1.25 s, never a touch
        _, state, transition = session.update(k * DT, q, ZERO16, NOTHING, 0.0, 0.0, f_d)
        log += [str(transition)] if transition else []
        pressing.append(bool(state.desired_force.any()))
    assert session.approach.touched_at is None
    np.testing.assert_array_equal(session.approach.q_ref, GOAL)
    assert log == ['controller hold -> closed_loop: approaching q_d at 0.2 rad/s',
                   'controller closed_loop -> closed_loop: at q_d without a touch: |f_hat| '
                   '0.02 N < 0.15 N, force control from here',
                   'controller closed_loop -> closed_loop: streams fresh']
    assert pressing.index(True) == 125 and all(pressing[125:])


def test_open_loop_feels_nothing_so_it_closes_slowly_with_the_command_as_given():
    cfg = config(k_i=(0.0,) * 3, q_d=tuple(GOAL), approach_speed=0.2, blind_speed=0.05)
    session = FingerSession(cfg, KIN)
    q = Q16.copy()
    q[:4] = START
    f_d = np.array([0.0, 0.0, 1.0])
    session.update(0.0, q, ZERO16, TOUCHING, np.inf, 0.0, None)
    for k in range(1, 101):
        _, state, _ = session.update(k * DT, q, ZERO16, TOUCHING, np.inf, 0.0, f_d)
        assert np.array_equal(state.desired_force, f_d)
    np.testing.assert_allclose(session.approach.q_ref, START + 0.99 * 0.05 * np.r_[0, 1, 1, 1])
    assert session.approach.touched_at is None
