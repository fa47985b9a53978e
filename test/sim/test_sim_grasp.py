"""Grasp scenes: the object's surface, the fixture and its hand-over, each fingertip's own skin
and ground truth, the opt-in disturbances, and the scenes' poses fitting their objects."""
import dataclasses

import mujoco
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tacforce_ros.hand.kinematics import HandKinematics
from tacforce_ros.hand.pinch import pad
from tacforce_ros.sim import load_scene, make_simulator
from tacforce_ros.sim.grasp import DROP_DISTANCE, signed_distance
from tacforce_ros.sim.scene import GraspObject, SceneError, list_scenes

GRASPS = [name for name in list_scenes() if name.startswith('grasp_')]
OBJECTS = {
    'sphere': GraspObject('s', 'sphere', (0.02,), 0.05, 1.0, None, 0.0, 'test'),
    'box': GraspObject('b', 'box', (0.01, 0.02, 0.03), 0.05, 1.0, None, 0.0, 'test'),
    'cylinder': GraspObject('c', 'cylinder', (0.01, 0.03), 0.05, 1.0, None, 0.0, 'test'),
}
unit = st.tuples(*[st.floats(-1.0, 1.0)] * 3).map(np.array).filter(
    lambda v: np.linalg.norm(v) > 0.1).map(lambda v: v / np.linalg.norm(v))


@given(st.sampled_from(sorted(OBJECTS)), unit, st.floats(0.001, 0.02))
def test_a_point_out_along_the_normal_is_that_far_from_the_surface(shape, direction, out):
    obj = OBJECTS[shape]
    # A point on the surface: from inside, along `direction`, to where the distance is 0.
    low, high = 0.0, 0.1
    for _ in range(60):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if signed_distance(obj, middle * direction)[0] < 0 else \
            (low, middle)
    surface = high * direction
    _, normal = signed_distance(obj, surface + 1e-9 * direction)
    distance, again = signed_distance(obj, surface + out * normal)
    assert distance == pytest.approx(out, abs=1e-6)
    np.testing.assert_allclose(again, normal, atol=1e-6)


def test_the_shipped_grasp_scenes_load_with_sourced_objects():
    assert {'grasp_golf_ball', 'grasp_gelatin_box', 'grasp_marker', 'grasp_tennis_ball',
            'grasp_foam_brick'} <= set(GRASPS)
    shapes = set()
    for name in GRASPS:
        scene = load_scene(name)
        obj = scene.grasp_object
        assert scene.kind == 'grasp' and scene.array == 'thumb_tip'
        assert obj.source and ('estimate' in obj.source or 'YCB' in obj.source)
        shapes.add((obj.shape, obj.stiffness is None))
    assert {('sphere', True), ('box', True), ('cylinder', True), ('sphere', False),
            ('box', False)} <= shapes


@pytest.mark.parametrize('name', GRASPS)
def test_the_contact_poses_pinch_the_object_at_its_width(hand, name):
    """The nominal tips (URDF sphere + the scenes' 4 mm of skin) at the contact poses are the
    object's width apart (hand/pinch.py solved them to 0.5 mm)."""
    scene = load_scene(name)
    kin = HandKinematics.for_hand(hand)
    q = np.asarray(scene.grasp['hand_pose'], dtype=np.float64).copy()
    for finger, poses in scene.grasp['fingers'].items():
        q[kin.finger_joints(finger)] = poses['contact_pose']
    thumb, index = pad(hand, kin, q, 'thumb')[0], pad(hand, kin, q, 'index')[0]
    gap = np.linalg.norm(thumb - index) - 2 * (scene.grasp['tip_radius'] + 0.004)
    assert gap == pytest.approx(scene.grasp_object.width, abs=1e-3)


def test_a_bad_grasp_field_is_refused_by_name(tmp_path):
    fingers = ('grasp: {fingers: {index: {pose: [0, 0, 0, 0], contact_pose: [0, 0, 0, 0]}}}\n')
    # A child's fingers merge with its parent's (the thumb stays) ...
    child = tmp_path / 'child.yaml'
    child.write_text('extends: grasp_golf_ball\n' + fingers)
    assert list(load_scene(child).grasp['fingers']) == ['thumb', 'index']
    # ... but a scene naming no thumb at all is refused.
    bad = tmp_path / 'nothumb.yaml'
    bad.write_text('extends: _grasp\ngrasp_object: golf_ball\n' + fingers)
    with pytest.raises(SceneError, match='must name the thumb'):
        load_scene(bad)
    size = tmp_path / 'size.yaml'
    size.write_text('extends: grasp_golf_ball\ngrasp_objects: {golf_ball: {size: [0.1, 0.2]}}\n')
    with pytest.raises(SceneError, match='"size" must be 1 positive numbers'):
        load_scene(size)
    push = tmp_path / 'push.yaml'
    push.write_text('extends: grasp_golf_ball\ngrasp: {disturbances: {push: {at: 1.0}}}\n')
    with pytest.raises(SceneError, match='disturbances.push.duration'):
        load_scene(push)


def scene_with(name, **grasp):
    scene = load_scene(name)
    return dataclasses.replace(scene, grasp={**scene.grasp, **grasp})


def test_the_fixture_holds_the_object_until_the_hand_over_then_it_falls(hand):
    sim = make_simulator(scene_with('grasp_golf_ball', hand_over=0.3), hand, seed=0)
    start = sim.step().object_position
    for _ in range(250):
        sample = sim.step()
    assert sample.held_by_fixture and np.linalg.norm(sample.object_position - start) < 5e-4
    assert not sample.dropped
    for _ in range(150):
        sample = sim.step()          # no finger holds it: 0.1 s of free fall is ~49 mm
    assert not sample.held_by_fixture and sample.dropped
    down = (sample.object_position - start) @ np.array([1.0, 0.0, 0.0])
    assert down > DROP_DISTANCE


def test_each_fingertip_reads_its_own_contact_and_its_own_truth(hand):
    """Pushed onto the fixture-held ball, only the pressing fingertip's array reads a force
    (rows of the whole-hand frame), and its ground truth, in its {S0}, is that force."""
    scene = scene_with('grasp_golf_ball', hand_over=100.0)
    quiet = {'kinematic_mismatch': {}, 'contact_offset': {}}   # the hand's tips, no noise
    sim = make_simulator(dataclasses.replace(scene, effects=quiet), hand, seed=0)
    kin = HandKinematics.for_hand(hand, gravity=tuple(scene.grasp['gravity']))
    rest = sim.step()
    index = kin.finger_joints('index')
    # Close the index alone: gravity compensation and a PD toward a pose through the ball.
    target = 2.0 * sim.contact_pose['index'] - sim.start_pose['index']
    for _ in range(1500):
        q, qdot = sim.data.qpos[:16].copy(), sim.data.qvel[:16].copy()
        tau = kin.gravity_torques(q)
        tau[index] += 0.5 * (target - q[index]) - 0.02 * qdot[index]
        tau[kin.finger_joints('thumb')] += 0.3 * (sim.start_pose['thumb'] - q[12:]) \
            - 0.01 * qdot[12:]
        sample = sim.step(tau)
    assert sample.finger_contact == {'thumb': False, 'index': True}
    truth = sample.finger_forces['index']
    assert np.linalg.norm(truth) > 0.1 and np.all(sample.finger_forces['thumb'] == 0.0)
    rows = {f: hand.array(f'{f}_tip').flat_indices for f in ('index', 'thumb')}
    moved = np.abs(sample.taxel_counts.astype(float) - rest.taxel_counts.astype(float))
    assert moved[rows['index']].max() > 50 and moved[rows['thumb']].max() == 0
    # The array's {S0} truth is the base-frame truth turned into that frame.
    frame = sim.data.xmat[sim.model.body(hand.array('index_tip').frame_id).id].reshape(3, 3)
    np.testing.assert_allclose(frame @ truth, sample.finger_forces_base['index'], atol=1e-9)


def test_added_mass_and_a_push_are_opt_in_and_act_when_scheduled(hand):
    plain = make_simulator(scene_with('grasp_golf_ball', hand_over=0.0), hand, seed=0)
    heavier = make_simulator(scene_with('grasp_golf_ball', hand_over=0.0, disturbances={
        'added_mass': {'at': 0.05, 'mass': 0.05}}), hand, seed=0)
    body = plain.body
    for _ in range(49):             # 0.049 s: before `at`, the same mass and the same fall
        plain.step()
        heavier.step()
    assert heavier.model.body_mass[body] == plain.model.body_mass[body]
    np.testing.assert_array_equal(heavier.data.xpos[body], plain.data.xpos[body])
    for _ in range(51):
        plain.step()
        heavier.step()
    assert heavier.model.body_mass[body] == pytest.approx(plain.model.body_mass[body] + 0.05)
    pushed = make_simulator(scene_with('grasp_golf_ball', hand_over=0.0, disturbances={
        'push': {'at': 0.0, 'duration': 0.05, 'force': [0.0, 1.0, 0.0]}}), hand, seed=0)
    for _ in range(100):
        pushed.step()
    sideways = pushed.data.xpos[body][1] - plain.data.xpos[body][1]
    # 1 N for 0.05 s on 46 g: 1.09 m/s, then 0.05 s coasting: ~8 mm.
    assert sideways == pytest.approx(0.05 / 0.04593 * (0.025 + 0.05), rel=0.05)


def test_a_scene_whose_poses_do_not_fit_its_object_is_refused(hand):
    scene = load_scene('grasp_golf_ball')
    bigger = dataclasses.replace(scene, grasp_object=dataclasses.replace(
        scene.grasp_object, size=(0.03,)))
    with pytest.raises(SceneError, match='golf_ball is 60.0 mm across'):
        make_simulator(bigger, hand, seed=0)


def test_the_object_model_is_a_free_body_with_the_scene_mass(hand):
    sim = make_simulator(load_scene('grasp_gelatin_box'), hand, seed=0)
    body = sim.model.body('grasp_object')
    assert body.mass[0] == pytest.approx(0.097)
    joint = sim.model.jnt_type[sim.model.body_jntadr[body.id]]
    assert joint == mujoco.mjtJoint.mjJNT_FREE


def test_a_scene_without_gravity_is_refused(hand):
    with pytest.raises(SceneError, match='gravity is zero'):
        make_simulator(scene_with('grasp_golf_ball', gravity=[0.0, 0.0, 0.0]), hand, seed=0)
