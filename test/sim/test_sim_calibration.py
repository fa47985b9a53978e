"""Quasi-static calibration simulator: determinism, ranges, flat order, each effect alone."""
import dataclasses

import numpy as np
import pytest
from conftest import stack

from tacforce_ros.sim import load_scene, make_simulator
from tacforce_ros.sim.taxel_response import BASELINE, SPAN

TIP = 'calibration_index_tip_spherical'
FIELDS = ('taxel_counts', 'temperatures', 'ft_wrench', 'true_force', 'q')


def test_no_effects_is_noise_free_and_deterministic(run_scene, hand):
    a = run_scene(TIP, effects={}, steps=400)
    b = run_scene(TIP, effects={}, steps=400)
    for field in FIELDS:
        assert np.array_equal(stack(a, field), stack(b, field)), field
    counts = stack(a, 'taxel_counts').astype(float)
    idle = ~stack(a, 'in_contact')
    assert idle.any() and (~idle).any()
    # Released: every taxel reads its nominal rest value exactly, and the wrench is zero.
    assert np.array_equal(counts[idle], np.broadcast_to(np.rint(BASELINE), counts[idle].shape))
    assert np.all(stack(a, 'ft_wrench')[idle] == 0.0)
    assert np.ptp(stack(a, 'temperatures')) == 0.0
    # Pressed: the F/T force has the magnitude of the true force (a rotation, nothing added).
    pressed = ~idle
    assert np.allclose(np.linalg.norm(stack(a, 'ft_wrench')[pressed, :3], axis=1),
                       np.linalg.norm(stack(a, 'true_force')[pressed], axis=1), atol=1e-12)
    assert all(all(s.delivered.values()) for s in a)


def test_same_seed_identical_different_seed_differs(run_scene):
    a = run_scene(TIP, steps=300, seed=3)
    b = run_scene(TIP, steps=300, seed=3)
    c = run_scene(TIP, steps=300, seed=4)
    for field in FIELDS:
        assert np.array_equal(stack(a, field), stack(b, field)), field
    assert not np.array_equal(stack(a, 'taxel_counts'), stack(c, 'taxel_counts'))
    assert not np.array_equal(stack(a, 'true_force'), stack(c, 'true_force'))


def test_force_on_index_tip_moves_only_its_taxels_unless_crosstalk(run_scene, hand):
    tip = hand.array('index_tip')
    others = np.setdiff1d(np.arange(hand.n_taxels), tip.flat_indices)
    plain = stack(run_scene(TIP, effects={}, steps=400), 'taxel_counts').astype(float)
    assert np.ptp(plain[:, tip.flat_indices], axis=0).max() > 1000
    assert np.ptp(plain[:, others], axis=0).max() == 0
    leaky = stack(run_scene(TIP, effects={'crosstalk': {}}, steps=400), 'taxel_counts')
    moved = np.flatnonzero(np.ptp(leaky.astype(float), axis=0).max(axis=1) > 0)
    neighbours = np.concatenate([hand.array(n).flat_indices for n in tip.neighbours])
    assert set(moved) - set(tip.flat_indices) == set(neighbours)


def test_counts_saturate_inside_16_bits(hand):
    effects = {'taxel_variation': {}, 'taxel_noise': {}}
    scene = dataclasses.replace(load_scene(TIP), effects=effects)
    peaks = []
    for force in ([0.3, 3.5], [200.0, 300.0]):
        crushing = dataclasses.replace(scene, operator={**scene.operator, 'normal_force': force})
        sim = make_simulator(crushing, hand, seed=1)
        counts = np.array([sim.step().taxel_counts for _ in range(400)]).astype(float)
        assert counts.max() <= 65535 and counts.min() >= 0
        peaks.append(counts[:, sim.sensor.array.flat_indices, 2].max())
    # ~100x the force: the taxel saturates near baseline + span instead of growing 100x.
    assert peaks[0] < peaks[1] < 37600 + SPAN[2] * 1.5 + 50


def test_taxels_at_rest_are_as_noisy_as_the_public_recordings_of_a_real_skin(run_scene, hand):
    """Each taxel's rms at rest, in whole counts, spreads over the taxels as in imanlab's uSkin
    recordings (median 1.0 / 0.9 / 3.1, 90th percentile 1.9 / 1.7 / 7.6 counts on X / Y / Z),
    and a taxel keeps its level from session to session: it is the hand's."""
    rest = np.setdiff1d(np.arange(hand.n_taxels), hand.array('index_tip').flat_indices)
    levels = []
    for seed in (1, 2):
        counts = stack(run_scene(TIP, effects={'taxel_noise': {}}, steps=2000, seed=seed),
                       'taxel_counts')[:, rest].astype(float)
        assert np.all(counts == np.rint(counts))
        levels.append(np.std(counts, axis=0))                  # (taxels, 3)
    median, p90 = np.median(levels[0], axis=0), np.percentile(levels[0], 90, axis=0)
    np.testing.assert_allclose(median, (1.0, 0.9, 3.1), rtol=0.12)
    np.testing.assert_allclose(p90, (1.9, 1.7, 7.6), rtol=0.2)
    # Below about half a count the rounding, not the noise, sets what a channel shows.
    audible = levels[0] > 0.5
    np.testing.assert_allclose(levels[1][audible], levels[0][audible], rtol=0.15)


# effect -> (fields it must change, fields it must leave alone)
EFFECT_FIELDS = {
    'taxel_variation': ({'taxel_counts'}, {'temperatures', 'ft_wrench', 'true_force'}),
    'deformation': ({'taxel_counts'}, {'temperatures', 'ft_wrench', 'true_force'}),
    'hysteresis': ({'taxel_counts'}, {'temperatures', 'ft_wrench', 'true_force'}),
    'taxel_noise': ({'taxel_counts'}, {'temperatures', 'ft_wrench', 'true_force'}),
    'temperature_drift': ({'taxel_counts', 'temperatures'}, {'ft_wrench', 'true_force'}),
    'crosstalk': ({'taxel_counts'}, {'temperatures', 'ft_wrench', 'true_force'}),
    'ft_noise': ({'ft_wrench'}, {'taxel_counts', 'temperatures', 'true_force'}),
    'transport': ({'taxel_counts'}, {'true_force'}),
}


@pytest.mark.parametrize('effect', sorted(EFFECT_FIELDS))
def test_each_effect_changes_what_it_should_and_nothing_else(run_scene, effect):
    changes, keeps = EFFECT_FIELDS[effect]
    params = {'drop': {'tactile': 0.2, 'ft': 0.2, 'joints': 0.2}} if effect == 'transport' else {}
    plain = run_scene(TIP, effects={}, steps=500)
    alone = run_scene(TIP, effects={effect: params}, steps=500)
    for field in changes:
        assert not np.array_equal(stack(plain, field), stack(alone, field)), field
    for field in keeps:
        assert np.array_equal(stack(plain, field), stack(alone, field)), field
    if effect == 'transport':
        assert not all(all(s.delivered.values()) for s in alone)


def test_deformation_turns_nothing_on_a_flat_array(run_scene):
    name = 'calibration_index_middle_button'
    plain = stack(run_scene(name, effects={}, steps=300), 'taxel_counts')
    deformed = stack(run_scene(name, effects={'deformation': {}}, steps=300), 'taxel_counts')
    assert np.array_equal(plain, deformed)


def test_operator_pauses_and_force_ranges(run_scene):
    samples = run_scene('calibration_index_middle_flat', effects={}, steps=3000)
    force = stack(samples, 'true_force')
    normal = force[:, 2]   # flat pad: the outward normal is +z of {S0}
    shear = np.linalg.norm(force[:, :2], axis=1)
    contact = stack(samples, 'in_contact')
    assert 0.3 < contact.mean() < 0.9                     # static segments exist
    assert 2.5 < normal.max() < 3.5 * 1.3 + 1e-9
    assert np.all(shear[contact] <= 0.4 * normal[contact] + 1e-9)
    assert shear.max() > 0.1 * normal.max()


@pytest.mark.parametrize('array', ['thumb_distal', 'palm_center', 'ring_tip'])
def test_every_array_is_pressed_with_its_own_finger_in_range(run_scene, hand, array):
    """Any array has a calibration scene; the operator bends only the finger carrying it (none
    for a palm pad), inside the URDF's joint limits, and only that array's taxels respond."""
    from tacforce_ros.hand.kinematics import HandKinematics
    samples = run_scene(f'calibration_{array}_convex', effects={}, steps=3000)
    q = stack(samples, 'q')
    taxel_array = hand.array(array)
    moved = np.flatnonzero(np.ptp(q, axis=0) > 1e-9)
    if taxel_array.finger is None:
        assert moved.size == 0
    else:
        joints = HandKinematics(hand.urdf_path).finger_joints(taxel_array.finger)
        assert set(moved) <= set(range(16)[joints]) and moved.size > 0
    lower, upper = _joint_limits(hand)
    assert np.all(q >= lower - 1e-9) and np.all(q <= upper + 1e-9)
    counts = stack(samples, 'taxel_counts').astype(float)
    others = np.setdiff1d(np.arange(hand.n_taxels), taxel_array.flat_indices)
    assert np.ptp(counts[:, taxel_array.flat_indices], axis=0).max() > 100
    assert np.ptp(counts[:, others], axis=0).max() == 0


def _joint_limits(hand):
    import xml.etree.ElementTree as ElementTree
    joints = {j.get('name'): j.find('limit') for j in
              ElementTree.parse(hand.urdf_path).getroot().iter('joint') if j.get('type') != 'fixed'}
    names = [f'joint_{i}.0' for i in range(16)]
    return (np.array([float(joints[n].get('lower')) for n in names]),
            np.array([float(joints[n].get('upper')) for n in names]))


def test_sessions_share_the_hand_and_a_sensor_seed_makes_another(hand):
    """Per-taxel parameters belong to the physical sensor (sensor_seed), not to the session."""
    def hand_parameters(scene, seed):
        sim = make_simulator(scene, hand, seed=seed)
        params = sim.sensor.ctx.params
        drift = next(e for e in sim.pipeline.effects if e.name == 'temperature_drift')
        crosstalk = next(e for e in sim.pipeline.effects if e.name == 'crosstalk')
        return [params.baseline, params.slope, params.coupling, drift._drift,
                crosstalk._weights]

    scene = load_scene('calibration_index_tip_flat')
    first, second = hand_parameters(scene, 1), hand_parameters(scene, 2)
    for a, b in zip(first, second):
        assert np.array_equal(a, b)
    other_hand = dataclasses.replace(scene, sensor_seed=scene.sensor_seed + 1)
    for a, b in zip(first, hand_parameters(other_hand, 1)):
        assert not np.allclose(a, b)
    # The session seed still changes what differs between sessions (noise, operator).
    a, b = (make_simulator(scene, hand, seed=s) for s in (1, 2))
    assert not np.array_equal(a.step().taxel_counts, b.step().taxel_counts)


def test_a_press_tour_presses_each_array_in_turn(hand):
    """press_tour: one block of `duration` per array, each starting and ending released, the
    sample naming the array in contact, and only that array's taxels responding."""
    from tacforce_ros.sim import load_scene
    scene = dataclasses.replace(load_scene('press_tour'), effects={},
                                press_tour=('thumb_tip', 'palm_center', 'index_middle'))
    sim = make_simulator(scene, hand, seed=2)
    block = int(round(scene.duration * scene.tactile_rate))
    samples = [sim.step() for _ in range(4 * block)]
    assert np.allclose(np.diff([s.t for s in samples]), sim.dt)      # time runs on
    for k, name in enumerate(('thumb_tip', 'palm_center', 'index_middle', 'thumb_tip')):
        part = samples[k * block:(k + 1) * block]
        assert {s.pressed_array for s in part} == {name}
        force = np.linalg.norm(stack(part, 'true_force'), axis=1)
        assert force[0] == force[-1] == 0.0 and force.max() > 1.0
        counts = stack(part, 'taxel_counts').astype(float)
        rows = hand.array(name).flat_indices
        others = np.setdiff1d(np.arange(hand.n_taxels), rows)
        assert np.ptp(counts[:, rows], axis=0).max() > 100
        assert np.ptp(counts[:, others], axis=0).max() == 0
