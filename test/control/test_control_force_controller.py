"""Force control law: each term, saturation and clamps, integral limits, watchdog, closed loop."""
import dataclasses

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tacforce_ros.control.force_controller import (MODE_CLOSED_LOOP,
                                                   MODE_HOLD, MODE_OPEN_LOOP, MODE_SAFE,
                                                   ControllerConfigError, ForceController,
                                                   ForceControllerConfig, saturation_scale)
from tacforce_ros.rig import finger_torque_limits

DT = 0.01   # the paper's 100 Hz control loop


def rot_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class ArmKinematics:
    """A small stand-in for HandKinematics: q-dependent Jacobian of a planar-ish 4-link finger,
    {F} turned 30 deg about z from the base, the array frame turned 90 deg about z from {F}."""

    LINKS = np.array([0.054, 0.0384, 0.0267, 0.0267])   # m, Allegro-like phalanx lengths
    FRAMES = {'hand_root': np.eye(3), 'ft_sensor': rot_z(np.pi / 6),
              'uskin_index_tip': rot_z(np.pi / 6) @ rot_z(np.pi / 2)}   # frame -> base

    def finger_joints(self, finger):
        return slice(0, 4)

    def fingertip_jacobian(self, q16, finger):
        q = q16[:4]
        angles = np.cumsum(q[1:])
        jac = np.zeros((3, 4))
        for j in range(1, 4):       # flexion joints move the tip in the x-z plane
            lever = self.LINKS[j:].copy()
            phi = angles[j - 1:]
            jac[0, j] = -np.sum(lever[:len(phi)] * np.sin(phi))
            jac[2, j] = np.sum(lever[:len(phi)] * np.cos(phi))
        jac[1, 0] = np.sum(self.LINKS[1:] * np.cos(np.r_[0.0, angles[:-1]]))   # abduction
        return jac

    def gravity_torques(self, q16):
        return 0.01 * np.cos(np.arange(16) + q16)

    def rotation_between(self, q16, from_frame, to_frame):
        return self.FRAMES[to_frame].T @ self.FRAMES[from_frame]


KIN = ArmKinematics()
Q16 = np.r_[0.1, 0.5, 0.7, 0.4, np.zeros(12)]
ZERO16 = np.zeros(16)


def config(**changes):
    base = dict(finger='index', force_frame='ft_sensor', estimate_frame='',
                q_d=tuple(Q16[:4]), k_i=(2.0, 2.0, 2.0))
    base.update(changes)
    return ForceControllerConfig(**base)


def expected_open_loop(cfg, q16, qdot16, f_d):
    jac = KIN.fingertip_jacobian(q16, 'index')
    rot = KIN.rotation_between(q16, 'ft_sensor', 'hand_root')
    return (jac.T @ rot @ f_d + KIN.gravity_torques(q16)[:4]
            - np.asarray(cfg.k_d) * qdot16[:4] - np.asarray(cfg.k_p) * (q16[:4] - cfg.q_d))


def test_open_loop_is_exactly_the_feedforward_law():
    cfg = config(k_i=(0.0, 0.0, 0.0), q_d=(0.05, 0.45, 0.75, 0.35))
    ctrl = ForceController(cfg, KIN)
    qdot = np.r_[0.2, -0.1, 0.3, 0.1, np.zeros(12)]
    f_d = np.array([0.3, -0.2, 1.5])
    for k in range(5):      # the estimate must not matter in open loop, even a wild one
        tau, state = ctrl.update(k * DT, Q16, qdot, np.array([9.0, 9.0, 9.0]), 0.0, 0.0, f_d)
    np.testing.assert_allclose(tau, expected_open_loop(cfg, Q16, qdot, f_d), rtol=1e-12)
    assert state.mode == MODE_OPEN_LOOP and state.saturation_scale == 1.0
    np.testing.assert_array_equal(state.integral_error, 0.0)


@pytest.mark.parametrize('term', ['force', 'gravity', 'damping', 'stiffness'])
def test_each_term_alone(term):
    cfg = config(k_i=(0.0, 0.0, 0.0))
    ctrl = ForceController(cfg, KIN)
    f_d, q, qdot = np.zeros(3), Q16.copy(), ZERO16.copy()
    gravity = KIN.gravity_torques(q)[:4]
    if term == 'force':
        f_d = np.array([0.0, 0.0, 1.0])
        want = KIN.fingertip_jacobian(q, 'index').T @ KIN.FRAMES['ft_sensor'] @ f_d + gravity
    elif term == 'gravity':
        want = gravity
    elif term == 'damping':
        qdot[:4] = [0.5, -0.5, 1.0, 2.0]
        want = gravity - np.asarray(cfg.k_d) * qdot[:4]
    else:
        q[:4] += [0.05, -0.1, 0.1, 0.02]
        want = KIN.gravity_torques(q)[:4] - np.asarray(cfg.k_p) * (q[:4] - cfg.q_d)
    tau, _ = ctrl.update(0.0, q, qdot, np.zeros(3), 0.0, 0.0, f_d)
    np.testing.assert_allclose(tau, want, rtol=1e-12, atol=1e-15)


def test_integral_term_adds_ki_times_integral_of_error():
    cfg = config(k_i=(1.0, 2.0, 3.0), integral_rate_limit=10.0)
    ctrl = ForceController(cfg, KIN)
    f_d, f_hat = np.array([0.2, 0.1, 1.0]), np.array([0.1, 0.0, 0.8])
    for k in range(11):
        tau, state = ctrl.update(k * DT, Q16, ZERO16, f_hat, 0.0, 0.0, f_d)
    integral = 10 * DT * (f_d - f_hat)
    np.testing.assert_allclose(state.integral_error, integral, rtol=1e-9)
    f_cmd = f_d + np.array([1.0, 2.0, 3.0]) * integral
    np.testing.assert_allclose(tau, expected_open_loop(cfg, Q16, ZERO16, f_cmd), rtol=1e-9)
    assert state.mode == MODE_CLOSED_LOOP


@given(f=st.lists(st.floats(-60.0, 60.0), min_size=3, max_size=3),
       q=st.lists(st.floats(-0.4, 1.5), min_size=4, max_size=4),
       qdot=st.lists(st.floats(-5.0, 5.0), min_size=4, max_size=4))
def test_saturation_keeps_direction_within_every_limit(f, q, qdot):
    cfg = config(k_i=(0.0, 0.0, 0.0))
    ctrl = ForceController(cfg, KIN)
    q16 = np.r_[q, np.zeros(12)]
    qdot16 = np.r_[qdot, np.zeros(12)]
    tau, state = ctrl.update(0.0, q16, qdot16, np.zeros(3), 0.0, 0.0, np.asarray(f))
    raw = state.tau_unsaturated
    limits = np.minimum(0.35, finger_torque_limits('index'))
    assert np.all(np.abs(tau) <= limits * (1 + 1e-12))
    assert np.max(np.abs(tau)) <= 0.35 * (1 + 1e-12)
    # Same direction: tau = s * raw with one s in (0, 1], so every component ratio is unchanged.
    np.testing.assert_allclose(tau, state.saturation_scale * raw, rtol=1e-12, atol=1e-15)
    assert 0.0 < state.saturation_scale <= 1.0
    if state.saturation_scale < 1.0:    # saturated: some joint sits exactly on its limit
        assert np.isclose(np.max(np.abs(tau) / limits), 1.0)


def test_firmware_clamp_of_a_weak_joint_scales_the_whole_finger():
    limits = np.minimum(0.35, finger_torque_limits('index'))     # joint 3: 0.2375 Nm
    raw = np.array([0.1, 0.2, 0.1, 0.3])    # within the 0.35 cap, over joint 3's clamp
    scale = saturation_scale(raw, limits)
    assert scale == pytest.approx(0.2375 / 0.3)
    np.testing.assert_allclose(scale * raw, [0.2375 / 3, 0.2375 * 2 / 3, 0.2375 / 3, 0.2375])
    assert saturation_scale(np.array([0.1, 0.1, 0.1, 0.1]), limits) == 1.0
    thumb = ForceControllerConfig(finger='thumb').joint_torque_limits
    np.testing.assert_allclose(thumb, [0.35, 0.3375, 0.225, 0.225])


def test_rate_limiter_bounds_how_fast_the_integral_moves():
    cfg = config(integral_rate_limit=0.5, integral_limit=100.0)
    ctrl = ForceController(cfg, KIN)
    f_d = np.array([0.0, 0.0, 1.0])
    ctrl.update(0.0, Q16, ZERO16, f_d, 0.0, 0.0, f_d)
    _, state = ctrl.update(DT, Q16, ZERO16, np.array([-50.0, 80.0, 1.1]), 0.0, 0.0, f_d)
    np.testing.assert_allclose(state.integral_error, [0.5 * DT, -0.5 * DT, -0.1 * DT])


def test_integral_holds_while_no_force_is_commanded():
    ctrl = ForceController(config(), KIN)
    f_hat, f_d = np.array([0.1, -0.2, 0.3]), np.array([0.0, 0.0, 0.5])
    for k in range(5):
        _, state = ctrl.update(k * DT, Q16, ZERO16, f_hat, 0.0, 0.0, np.zeros(3))
    np.testing.assert_array_equal(state.integral_error, np.zeros(3))
    assert state.mode == MODE_CLOSED_LOOP
    _, state = ctrl.update(5 * DT, Q16, ZERO16, f_hat, 0.0, 0.0, f_d)
    assert np.all(state.integral_error != 0.0)
    _, held = ctrl.update(6 * DT, Q16, ZERO16, f_hat, 0.0, 0.0, np.zeros(3))
    np.testing.assert_array_equal(held.integral_error, state.integral_error)


def test_integral_is_bounded_under_persistent_error_and_recovers_after_saturation():
    cfg = config(k_i=(10.0, 10.0, 10.0), integral_limit=1.0, integral_rate_limit=2.0)
    ctrl = ForceController(cfg, KIN)
    f_d = np.array([0.0, 0.0, 4.0])
    saturated_ticks = 0
    for k in range(500):    # 5 s of an estimate stuck at zero: the error never goes away
        tau, state = ctrl.update(k * DT, Q16, ZERO16, np.zeros(3), 0.0, 0.0, f_d)
        assert np.all(np.abs(state.integral_error) <= 1.0 + 1e-12)
        saturated_ticks += state.saturation_scale < 1.0
    assert saturated_ticks > 100, 'the scenario must drive the finger into saturation'
    # Conditional integration stopped the integral before its clamp: windup is only what it took
    # to reach the saturation boundary.
    assert state.integral_error[2] < 0.9
    # The estimate now reads far above f_d: the command leaves saturation almost at once.
    t0 = 500 * DT
    for k in range(100):
        _, state = ctrl.update(t0 + k * DT, Q16, ZERO16, np.array([0.0, 0.0, 6.0]), 0.0, 0.0, f_d)
        if state.saturation_scale == 1.0:
            break
    assert k * DT <= 0.1, f'took {k * DT:.2f} s to leave saturation'


@pytest.mark.parametrize('stale', ['estimate', 'joints'])
def test_stale_stream_ramps_to_safe_within_ramp_time(stale):
    cfg = config(ramp_time=0.05, estimate_timeout=0.05, joints_timeout=0.02)
    ctrl = ForceController(cfg, KIN)
    f_d = np.array([0.0, 0.0, 1.5])
    for k in range(50):
        tau, state = ctrl.update(k * DT, Q16, ZERO16, f_d * 0.9, 0.0, 0.0, f_d)
    assert state.mode == MODE_CLOSED_LOOP and np.any(state.integral_error != 0)
    integral = state.integral_error
    t_stale = 50 * DT
    # The contact hold where the finger is, at rest: the law with the latched command.
    hold = (KIN.gravity_torques(Q16)[:4] + KIN.fingertip_jacobian(Q16, 'index').T
            @ (KIN.rotation_between(Q16, cfg.force_frame, cfg.base_frame)
               @ (f_d + np.asarray(cfg.k_i) * integral))
            - np.asarray(cfg.k_p) * (Q16[:4] - np.asarray(cfg.q_d)))
    distances, t = [], t_stale
    while t <= t_stale + 0.1 + 1e-9:
        age = t - t_stale + 0.06     # the last message is already past its timeout
        f_age, q_age = (age, 0.0) if stale == 'estimate' else (0.0, age)
        tau, state = ctrl.update(t, Q16, ZERO16, f_d * 0.9, f_age, q_age, f_d)
        target = hold if stale == 'estimate' else np.zeros(4)
        distances.append((t - t_stale, np.linalg.norm(tau - target), state.mode))
        t += DT
    safe_at = min(dt for dt, dist, _ in distances if dist < 1e-12)
    assert safe_at <= cfg.ramp_time + 1e-9, distances
    assert all(a[1] >= b[1] - 1e-12 for a, b in zip(distances, distances[1:])), 'not monotone'
    final_mode = distances[-1][2]
    assert final_mode == (MODE_HOLD if stale == 'estimate' else MODE_SAFE)
    # Frozen in the hold (the law resumes with it), forgotten once the torque faded out.
    np.testing.assert_array_equal(state.integral_error,
                                  integral if stale == 'estimate' else 0.0)
    assert not (state.estimate_fresh if stale == 'estimate' else state.joints_fresh)


@given(intervals=st.lists(st.floats(0.008, 0.012), min_size=60, max_size=60),
       last=st.floats(0.0, 0.01), estimate_timeout=st.sampled_from([0.03, 0.05]),
       ramp_time=st.sampled_from([0.02, 0.035, 0.05]))
def test_the_hold_comes_within_timeout_ramp_and_one_tick_of_the_last_estimate(
        intervals, last, estimate_timeout, ramp_time):
    """The watchdog's bound, whatever the ticks' phase and jitter (8-12 ms apart, as under
    simulated time's 2 ms steps): the first tick in the hold is at most estimate_timeout +
    ramp_time + the longest tick interval after the last estimate."""
    cfg = config(estimate_timeout=estimate_timeout, ramp_time=ramp_time)
    ctrl = ForceController(cfg, KIN)
    f_d = np.array([0.0, 0.0, 1.5])
    t_last = 0.3 + last                      # the estimate stops coming after this stamp
    t, hold_at = 0.0, None
    for k in range(30):                      # engaged, closed loop
        ctrl.update(k * DT, Q16, ZERO16, f_d * 0.9, 0.0, 0.0, f_d)
    t = 30 * DT
    for interval in intervals:
        t += interval
        _, state = ctrl.update(t, Q16, ZERO16, f_d * 0.9, t - min(t, t_last), 0.0, f_d)
        if state.mode == MODE_HOLD:
            hold_at = t
            break
    assert hold_at is not None
    assert hold_at - t_last <= estimate_timeout + ramp_time + max(intervals) + 1e-9


def test_the_shipped_watchdog_holds_within_what_the_fault_drill_asks():
    """The shipped timeout and ramp leave one control tick (its period, plus one step of the
    closed-loop scene's simulated clock) inside the hold the fault drill asks for."""
    import yaml

    from tacforce_ros.bringup.session_plan import params_file
    from tacforce_ros.sim.scene import load_scene
    from tacforce_ros.benchmarks.bench_graph import HOLD_WITHIN_S, LOOP_SCENE
    shipped = ForceControllerConfig.from_yaml(params_file('force_controller'))
    node = yaml.safe_load(params_file('force_controller').read_text())
    rate = node['/**/force_controller']['ros__parameters']['control_rate_hz']
    tick = 1.0 / rate + 1.0 / load_scene(LOOP_SCENE).physics_rate
    assert shipped.estimate_timeout + shipped.ramp_time + tick <= HOLD_WITHIN_S


finite = st.floats(-1.0, 1.0)


def run_until_stale(ctrl, q, qdot, f_d, f_hats):
    """Fresh ticks with the given estimates; returns the last command and the next tick's time."""
    tau = np.zeros(4)
    for k, f_hat in enumerate(f_hats):
        tau, _ = ctrl.update(k * DT, q, qdot, np.asarray(f_hat), 0.0, 0.0, f_d)
    return tau, len(f_hats) * DT


@given(q=st.lists(finite, min_size=4, max_size=4), qdot=st.lists(finite, min_size=4, max_size=4),
       f_d=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
       f_hats=st.lists(st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
                       min_size=1, max_size=30),
       k_p=st.lists(st.floats(0.0, 1.0), min_size=4, max_size=4),
       k_i=st.floats(0.0, 5.0))
def test_stale_joints_never_raise_any_joints_torque(q, qdot, f_d, f_hats, k_p, k_i):
    """With stale joints every feedback term is evaluated at an old q; the command of the last
    fresh tick fades: per joint |tau| never rises above its value then and is 0 after ramp_time."""
    ctrl = ForceController(config(k_p=tuple(k_p), k_i=(k_i,) * 3), KIN)
    q16 = np.r_[q, np.zeros(12)]
    qdot16 = np.r_[qdot, np.zeros(12)]
    tau0, t_stale = run_until_stale(ctrl, q16, qdot16, np.asarray(f_d), f_hats)
    previous = np.abs(tau0)
    for k in range(8):       # the last joint message stays what it was
        tau, state = ctrl.update(t_stale + k * DT, q16, qdot16, np.asarray(f_hats[-1]), 0.0,
                                 0.03 + k * DT, np.asarray(f_d))
        assert np.all(np.abs(tau) <= previous + 1e-12), (tau, previous)
        previous = np.abs(tau)
        assert state.mode == MODE_SAFE and state.reason.startswith('joints stale')
    np.testing.assert_array_equal(tau, 0.0)


@given(q=st.lists(finite, min_size=4, max_size=4), qdot=st.lists(finite, min_size=4, max_size=4),
       f_d=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
       f_hats=st.lists(st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
                       min_size=1, max_size=30),
       k_i=st.floats(0.1, 5.0))
def test_stale_estimate_moves_each_torque_only_between_the_law_and_the_hold(
        q, qdot, f_d, f_hats, k_i):
    """Estimate stale, joints fresh: the command blends from the law's torque to the contact
    hold's, so no joint's |torque| leaves the range between the two (q as it was)."""
    ctrl = ForceController(config(k_i=(k_i,) * 3), KIN)
    q16 = np.r_[q, np.zeros(12)]
    qdot16 = np.r_[qdot, np.zeros(12)]
    tau0, t_stale = run_until_stale(ctrl, q16, qdot16, np.asarray(f_d), f_hats)
    taus = [ctrl.update(t_stale + k * DT, q16, qdot16, np.full(3, np.nan), np.inf, 0.0,
                        np.asarray(f_d)) for k in range(8)]
    hold = taus[-1][0]
    assert taus[-1][1].mode == MODE_HOLD and taus[-1][1].reason == 'no valid estimate'
    bound = np.maximum(np.abs(tau0), np.abs(hold)) + 1e-12
    for tau, _ in taus:
        assert np.all(np.abs(tau) <= bound), (tau, tau0, hold)


def test_the_hold_keeps_pressing_and_the_law_resumes_without_a_step():
    """A stale estimate: at the same pose the hold gives the torque of the law's last fresh
    tick (its force command and its PD toward q_d), whatever f_d does meanwhile, and the
    integral it froze is the law's again when the estimate returns."""
    # q_d beyond the pose, as on a plate: the PD term is part of the press.
    ctrl = ForceController(config(k_i=(2.0, 2.0, 2.0), q_d=(0.0, 0.8, 0.8, 0.8)), KIN)
    f_d = np.array([0.0, 0.0, 1.5])
    for k in range(30):
        law, state = ctrl.update(k * DT, Q16, ZERO16, f_d * 0.8, 0.0, 0.0, f_d)
    assert state.saturation_scale == 1.0 and np.any(state.integral_error != 0)
    integral = state.integral_error
    for k in range(30, 50):       # stale; f_d changes meanwhile
        hold, state = ctrl.update(k * DT, Q16, ZERO16, f_d, 0.2, 0.0, 2 * f_d)
    assert state.mode == MODE_HOLD
    np.testing.assert_array_equal(state.integral_error, integral)
    np.testing.assert_allclose(hold, law, atol=1e-12)
    for k in range(50, 56):       # back, no error: after the ramp in, the law as it was
        back, state = ctrl.update(k * DT, Q16, ZERO16, f_d, 0.0, 0.0, f_d)
    assert state.mode == MODE_CLOSED_LOOP and state.force_gain == 1.0
    np.testing.assert_array_equal(state.integral_error, integral)
    np.testing.assert_allclose(back, law, atol=1e-12)


def test_reason_names_the_stale_stream_and_its_age():
    ctrl = ForceController(config(), KIN)
    f_d = np.array([0.0, 0.0, 1.0])
    _, state = ctrl.update(0.0, Q16, ZERO16, f_d, 0.0, 0.0, f_d)
    assert state.reason == 'streams fresh'
    _, state = ctrl.update(DT, Q16, ZERO16, f_d, 0.08, 0.0, f_d)
    assert state.reason == 'estimate stale: age 0.080 s > 0.05 s'
    _, state = ctrl.update(2 * DT, Q16, ZERO16, f_d, 0.0, 0.5, f_d)
    assert state.reason == 'joints stale: age 0.500 s > 0.02 s'
    _, state = ctrl.update(3 * DT, np.full(16, np.nan), ZERO16, f_d, 0.0, 0.0, f_d)
    assert state.reason == 'joints not finite'


def test_non_finite_estimate_is_treated_as_stale_and_recovery_ramps_in():
    ctrl = ForceController(config(ramp_time=0.05), KIN)
    f_d = np.array([0.0, 0.0, 1.0])
    ctrl.update(0.0, Q16, ZERO16, f_d, 0.0, 0.0, f_d)
    _, state = ctrl.update(DT, Q16, ZERO16, np.array([np.nan, 0.0, 1.0]), 0.0, 0.0, f_d)
    assert state.mode == MODE_SAFE and not state.estimate_fresh
    assert state.force_gain == pytest.approx(1.0 - DT / 0.05)
    for k in range(2, 10):
        _, state = ctrl.update(k * DT, Q16, ZERO16, np.array([np.nan] * 3), 0.0, 0.0, f_d)
    assert state.mode == MODE_HOLD
    gains = []
    for k in range(10, 20):
        _, state = ctrl.update(k * DT, Q16, ZERO16, f_d, 0.0, 0.0, f_d)
        gains.append(state.force_gain)
    assert gains[0] == pytest.approx(DT / 0.05) and gains[-1] == 1.0
    assert state.mode == MODE_CLOSED_LOOP


def test_estimate_frame_is_rotated_into_the_force_frame():
    cfg = config(estimate_frame='uskin_index_tip', k_i=(1.0, 1.0, 1.0))
    ctrl = ForceController(cfg, KIN)
    f_hat_array = np.array([1.0, 0.0, 0.0])     # x of the array frame is y of {F} (90 deg)
    f_d = np.array([0.0, 0.0, 0.5])
    ctrl.update(0.0, Q16, ZERO16, f_hat_array, 0.0, 0.0, f_d)
    _, state = ctrl.update(DT, Q16, ZERO16, f_hat_array, 0.0, 0.0, f_d)
    np.testing.assert_allclose(state.estimated_force, [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(state.integral_error, [0.0, -DT, 0.5 * DT], atol=1e-12)


def simulate_contact(cfg, torque_gain, seconds=6.0):
    """Static plant: the finger rests on a rigid surface at q_d; actuators deliver
    torque_gain * tau; the fingertip force is whatever balances the torque beyond gravity
    (least squares through J^T); the estimator sees it exactly, one tick late."""
    ctrl = ForceController(cfg, KIN)
    jac_t = KIN.fingertip_jacobian(Q16, 'index').T
    to_f = KIN.rotation_between(Q16, 'hand_root', 'ft_sensor')
    gravity = KIN.gravity_torques(Q16)[:4]
    f_d = np.array([0.3, -0.2, 1.5])
    f_true = np.zeros(3)
    errors = []
    for k in range(int(seconds / DT)):
        tau, _ = ctrl.update(k * DT, Q16, ZERO16, f_true, DT, 0.0, f_d)
        f_base, *_ = np.linalg.lstsq(jac_t, torque_gain * tau - gravity, rcond=None)
        f_true = to_f @ f_base
        errors.append(np.mean(np.abs(f_d - f_true)))
    return np.asarray(errors)


def test_integral_feedback_removes_a_torque_gain_error_open_loop_cannot():
    closed = simulate_contact(config(k_i=(2.0, 2.0, 2.0)), torque_gain=0.8)
    open_loop = simulate_contact(config(k_i=(0.0, 0.0, 0.0)), torque_gain=0.8)
    assert open_loop[-1] > 0.05, 'the plant error must show in open loop'
    assert closed[-1] < 1e-3 and closed[-1] < 0.02 * open_loop[-1]
    exact = simulate_contact(config(k_i=(0.0, 0.0, 0.0)), torque_gain=1.0)
    assert exact[-1] < 1e-9, 'with a perfect plant the open loop law is exact'


@pytest.mark.parametrize('changes, field', [
    (dict(k_i=(1.0, 1.0)), 'k_i'), (dict(k_p=(1.0, -1.0, 1.0, 1.0)), 'k_p'),
    (dict(ramp_time=0.0), 'ramp_time'), (dict(finger='pinky'), 'finger'),
    (dict(torque_cap=float('nan')), 'torque_cap')])
def test_bad_configuration_is_refused_naming_the_field(changes, field):
    with pytest.raises(ControllerConfigError, match=field):
        ForceControllerConfig(**changes)


def test_parameter_file_loads_and_unknown_keys_are_refused(tmp_path):
    from tacforce_ros.paths import config_dir
    cfg = ForceControllerConfig.from_yaml(config_dir() / 'params' / 'force_controller.yaml')
    assert cfg.torque_cap == 0.35 and cfg.finger == 'index'
    assert dataclasses.replace(cfg, k_i=(0.0, 0.0, 0.0)).k_i == (0.0, 0.0, 0.0)
    with pytest.raises(ControllerConfigError, match='kp'):
        ForceControllerConfig.from_mapping({'kp': [1, 1, 1, 1]})


def test_pressing_with_another_fingertip_keeps_the_law_and_gives_the_thumb_its_own_gains(
        monkeypatch):
    from tacforce_ros.control import force_controller
    from tacforce_ros.hand.description import load_hand
    hand = load_hand()
    base = ForceControllerConfig.from_yaml(force_controller.config_dir() / 'params'
                                           / 'force_controller.yaml')
    open_loop = dataclasses.replace(base, k_i=(0.0, 0.0, 0.0))
    ring = open_loop.pressing_with(hand.array('ring_tip'), 'ft_sensor')
    assert (ring.finger, ring.estimate_frame, ring.force_frame) == ('ring', 'uskin_ring_tip',
                                                                    'ft_sensor')
    assert dataclasses.replace(ring, finger='index', estimate_frame=base.estimate_frame) == \
        open_loop
    thumb = open_loop.pressing_with(hand.array('thumb_tip'), 'ft_sensor_thumb')
    own = ForceControllerConfig.from_yaml(force_controller.finger_params_file('thumb'))
    assert (thumb.k_p, thumb.k_d, thumb.q_d) == (own.k_p, own.k_d, own.q_d) != (
        base.k_p, base.k_d, base.q_d)
    assert thumb.k_i == (0.0, 0.0, 0.0) and thumb.force_frame == 'ft_sensor_thumb'
    with pytest.raises(ControllerConfigError, match='not a fingertip array'):
        base.pressing_with(hand.array('thumb_distal'), 'ft_sensor')
    monkeypatch.setattr(force_controller, 'finger_params_file',
                        lambda finger: force_controller.Path('/nonexistent.yaml'))
    with pytest.raises(ControllerConfigError, match='the thumb needs its own in'):
        base.pressing_with(hand.array('thumb_tip'), 'ft_sensor_thumb')
