"""The grasp controller: goals refused with their reason, the shared internal-force integral, a
stale fingertip's hold, a drop, the slip reaction; on the real hand's kinematics."""
import dataclasses

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tacforce_ros.control.force_controller import (MODE_CLOSED_LOOP, MODE_HOLD,
                                                   ForceControllerConfig, shipped_params_file)
from tacforce_ros.control.grasp import (PHASE_CLOSING, PHASE_DROPPED, PHASE_HOLDING,
                                        GraspConfig, GraspController, GraspGoal, GraspGoalError,
                                        max_grip)
from tacforce_ros.hand.description import load_hand
from tacforce_ros.hand.kinematics import HandKinematics
from tacforce_ros.hand.pinch import pad
from tacforce_ros.sim import load_scene

HAND = load_hand()
GRAVITY = (9.81, 0.0, 0.0)                  # the grasp scenes' palm-down mount
KIN = HandKinematics.for_hand(HAND, gravity=GRAVITY)
SCENE = load_scene('grasp_golf_ball')
DT = 0.01
ZERO16 = np.zeros(16)


def configs(fingers=('thumb', 'index'), **changes):
    base = ForceControllerConfig.from_yaml(shipped_params_file())
    return {f: dataclasses.replace(base.pressing_with(HAND.array(f'{f}_tip'), HAND.base_frame),
                                   **changes) for f in fingers}


def controller(fingers=('thumb', 'index'), **changes):
    return GraspController(configs(fingers), KIN, lambda q, f: pad(HAND, KIN, q, f)[0],
                           GraspConfig(gravity=GRAVITY, **changes))


def contact_q():
    """The golf ball scene's contact pose of the pinch."""
    q = np.asarray(SCENE.grasp['hand_pose'], dtype=np.float64).copy()
    for finger, poses in SCENE.grasp['fingers'].items():
        q[KIN.finger_joints(finger)] = poses['contact_pose']
    return q


def goal(fingers=('thumb', 'index'), grip=1.0, mass=0.0, through=0.0):
    """Targets at the contact poses (the approach has nowhere to go: the ramp starts at once),
    or `through` rad further on each flexion joint."""
    q = contact_q()
    return GraspGoal(fingers=fingers, grip=grip, mass=mass,
                     targets={f: tuple(q[KIN.finger_joints(f)] + [0.0, through, through, through])
                              for f in fingers if f in ('thumb', 'index', 'middle', 'ring')})


def test_each_bad_goal_is_refused_with_its_reason():
    grasp = controller()
    q = contact_q()
    cases = [
        (goal(fingers=()), 'no fingers'),
        (dataclasses.replace(goal(), fingers=('thumb', 'pinky')), "['pinky'] are not fingertips"),
        (dataclasses.replace(goal(), fingers=('thumb', 'middle')), "['middle'] have no force "
                                                                   'model'),
        (dataclasses.replace(goal(), fingers=('index',)), 'opposes the thumb'),
        (goal(grip=0.1), 'outside the safe range 0.3-'),
        (goal(grip=50.0), 'torque limit'),
        (goal(grip=float('nan')), 'outside the safe range'),
        (goal(grip=0.5, mass=0.5), 'cannot carry 0.5 kg'),
        (goal(mass=-1.0), 'must be a number >= 0'),
    ]
    three = controller(fingers=('thumb', 'index', 'middle'))
    with pytest.raises(GraspGoalError, match='more than one fingertip against the thumb'):
        three.start(dataclasses.replace(goal(), fingers=('thumb', 'index', 'middle'), targets={
            **goal().targets, 'middle': tuple(q[4:8])}), q)
    for bad, reason in cases:
        with pytest.raises(GraspGoalError, match=None) as error:
            grasp.start(bad, q)
        assert reason in str(error.value), (reason, str(error.value))
    assert grasp.goal is None            # nothing started


def test_the_safe_range_says_how_much_the_torque_limit_allows():
    grasp = controller()
    q = contact_q()
    with pytest.raises(GraspGoalError) as error:
        grasp.start(goal(grip=50.0), q)
    directions = grasp._directions(('thumb', 'index'), q)
    top = max_grip(KIN, q, ('thumb', 'index'), directions, np.zeros(3), 0.35)
    assert f'0.3-{top:.2f} N' in str(error.value)
    # At that grip a joint is at its limit, and none over it.
    worst = 0.0
    for finger in ('thumb', 'index'):
        joints = KIN.finger_joints(finger)
        tau = (KIN.fingertip_jacobian(q, finger).T @ (top * directions[finger])
               + KIN.gravity_torques(q)[joints])
        limits = np.minimum(0.35, configs()[finger].joint_torque_limits)
        assert np.all(np.abs(tau) <= limits + 1e-9)
        worst = max(worst, float(np.max(np.abs(tau) / limits)))
    assert worst == pytest.approx(1.0)


def touch_all(grasp, q, f_hats, ticks=200):
    """Run ticks with the given estimates (finger -> base-frame-free array-frame vectors)."""
    state = None
    for k in range(ticks):
        _, state = grasp.update(k * DT, q, ZERO16, {f: (v, 0.0) for f, v in f_hats.items()}, 0.0)
    return state


def array_force(q, finger, base_force):
    """A force given in the base frame, in the finger's array frame (what its estimate reads)."""
    frame = HAND.array(f'{finger}_tip').frame_id
    return KIN.rotation_between(q, HAND.base_frame, frame) @ base_force


def test_the_fingers_integrate_one_internal_error_and_stay_balanced():
    grasp = controller()
    q = contact_q()
    grasp.start(goal(grip=1.0), q)
    d = grasp._directions(('thumb', 'index'), q)
    # The thumb's estimate reads 0.3 N more than the index's: their mean is what is regulated.
    reads = {'thumb': array_force(q, 'thumb', 0.9 * d['thumb']),
             'index': array_force(q, 'index', 0.5 * d['index'])}
    state = touch_all(grasp, q, reads)
    assert state.phase == PHASE_HOLDING
    thumb = state.fingers['thumb'].controller.integral_error
    index = state.fingers['index'].controller.integral_error
    np.testing.assert_allclose(thumb, -index, atol=1e-9)        # equal and opposite
    assert thumb @ d['thumb'] > 0.0                               # pressing more: 0.7 < 1 N


@given(st.floats(0.0, 2.0), st.floats(0.0, 2.0))
def test_integrals_stay_equal_and_opposite_for_any_pair_of_reads(a, b):
    grasp = controller()
    q = contact_q()
    grasp.start(goal(grip=1.0), q)
    d = grasp._directions(('thumb', 'index'), q)
    reads = {'thumb': array_force(q, 'thumb', a * d['thumb']),
             'index': array_force(q, 'index', b * d['index'])}
    state = touch_all(grasp, q, reads, ticks=60)
    np.testing.assert_allclose(state.fingers['thumb'].controller.integral_error,
                               -state.fingers['index'].controller.integral_error, atol=1e-9)


def test_no_command_before_a_finger_touches_and_the_ramp_is_bounded():
    grasp = controller()
    q = contact_q()
    grasp.start(goal(grip=2.0, through=0.1), q)
    d = grasp._directions(('thumb', 'index'), q)
    nothing = {f: array_force(q, f, np.zeros(3)) for f in ('thumb', 'index')}
    state = touch_all(grasp, q, nothing, ticks=5)
    assert state.phase == PHASE_CLOSING
    assert all(np.all(s.desired == 0.0) for s in state.fingers.values())
    touch = {f: array_force(q, f, 0.3 * d[f]) for f in ('thumb', 'index')}
    grips = []
    for k in range(5, 150):
        _, state = grasp.update(k * DT, q, ZERO16, {f: (v, 0.0) for f, v in touch.items()}, 0.0)
        grips.append(state.fingers['index'].grip)
    grips = np.array(grips)
    # From the touch (0.3 N read) at no more than force_rate, up to the grip.
    started = grips[grips > 0.0]
    assert started[0] == pytest.approx(0.3, abs=0.02)
    assert np.all(np.diff(started) <= grasp.config.force_rate * DT + 1e-9)
    assert started[-1] == pytest.approx(2.0)


def test_a_stale_fingertip_holds_while_the_other_goes_on():
    grasp = controller()
    q = contact_q()
    grasp.start(goal(grip=1.0), q)
    d = grasp._directions(('thumb', 'index'), q)
    reads = {f: array_force(q, f, 1.0 * d[f]) for f in ('thumb', 'index')}
    state = touch_all(grasp, q, reads)
    assert state.phase == PHASE_HOLDING
    for k in range(200, 230):      # the index's estimate stops coming
        _, state = grasp.update(k * DT, q, ZERO16, {'thumb': (reads['thumb'], 0.0),
                                                    'index': (reads['index'], (k - 199) * DT)},
                                0.0)
    assert state.fingers['index'].controller.mode == MODE_HOLD
    assert state.fingers['thumb'].controller.mode == MODE_CLOSED_LOOP
    assert state.phase == PHASE_HOLDING
    # Neither integrates meanwhile: the thumb's error alone would be the single finger's law.
    integral = state.fingers['thumb'].controller.integral_error.copy()
    for k in range(230, 240):
        _, state = grasp.update(k * DT, q, ZERO16, {'thumb': (0.5 * reads['thumb'], 0.0),
                                                    'index': (reads['index'], 1.0)}, 0.0)
    np.testing.assert_array_equal(state.fingers['thumb'].controller.integral_error, integral)


def test_a_drop_ends_the_grasp_with_its_reason():
    grasp = controller()
    q = contact_q()
    grasp.start(goal(grip=1.0), q)
    d = grasp._directions(('thumb', 'index'), q)
    state = touch_all(grasp, q, {f: array_force(q, f, 1.0 * d[f]) for f in ('thumb', 'index')})
    assert state.phase == PHASE_HOLDING
    gone = {f: (array_force(q, f, np.zeros(3)), 0.0) for f in ('thumb', 'index')}
    for k in range(200, 205):
        _, state = grasp.update(k * DT, q, ZERO16, gone, 0.0)
    assert state.phase == PHASE_HOLDING          # 0.04 s without a touch: not yet
    for k in range(205, 215):
        _, state = grasp.update(k * DT, q, ZERO16, gone, 0.0)
    assert state.phase == PHASE_DROPPED
    assert state.reason == 'dropped: no finger has felt the object since 2.00 s'


def test_a_saturated_finger_stops_both_integrals_so_they_stay_balanced():
    grasp = controller()
    q = contact_q()
    top = max_grip(KIN, q, ('thumb', 'index'), controller()._directions(('thumb', 'index'), q),
                   np.zeros(3), 0.35)
    grasp.start(goal(grip=0.95 * top), q)
    d = grasp._directions(('thumb', 'index'), q)
    # The estimates read far less than the grip: the integral pushes the torque to its limit.
    reads = {f: (array_force(q, f, 0.1 * d[f]), 0.0) for f in ('thumb', 'index')}
    saturated = False
    for k in range(600):
        _, state = grasp.update(k * DT, q, ZERO16, reads, 0.0)
        saturated |= any(s.controller.saturation_scale < 1.0 for s in state.fingers.values())
    assert saturated
    np.testing.assert_allclose(state.fingers['thumb'].controller.integral_error,
                               -state.fingers['index'].controller.integral_error, atol=1e-9)


def test_stale_joints_keep_the_grip_line_and_raise_nothing():
    grasp = controller()
    q = contact_q()
    grasp.start(goal(grip=1.0), q)
    d = grasp._directions(('thumb', 'index'), q)
    reads = {f: (array_force(q, f, 1.0 * d[f]), 0.0) for f in ('thumb', 'index')}
    touch_all(grasp, q, {f: v for f, (v, _) in reads.items()})
    line = {f: v.copy() for f, v in grasp.directions.items()}
    moved = q.copy()
    moved[:4] += 0.3
    tau, state = grasp.update(2.0, moved, ZERO16, reads, 1.0)      # joints 1 s old
    assert np.all(np.isfinite(tau))
    for f in line:
        np.testing.assert_array_equal(grasp.directions[f], line[f])


def test_a_rising_tangential_share_raises_the_grip_within_its_bound():
    grasp = controller()
    q = contact_q()
    grasp.start(goal(grip=1.0), q)
    d = grasp._directions(('thumb', 'index'), q)
    side = np.cross(d['index'], [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    steady = {f: array_force(q, f, 1.0 * d[f] + 0.2 * side) for f in ('thumb', 'index')}
    state = touch_all(grasp, q, steady)
    assert state.phase == PHASE_HOLDING and state.grip == 1.0   # a constant share is no slip
    slipping = {f: (array_force(q, f, 1.0 * d[f] + 0.6 * side), 0.0) for f in ('thumb', 'index')}
    for k in range(200, 400):
        _, state = grasp.update(k * DT, q, ZERO16, slipping, 0.0)
    assert state.reason.startswith('slip at thumb, index: grip')
    assert state.grip == pytest.approx(grasp.top)       # raised, as far as the joints allow
