"""Kinematics over the URDF: hand-computed poses, finite differences, MuJoCo agreement, refusals."""
import re

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from tacforce_ros.hand.description import HandConfigError, load_hand
from tacforce_ros.hand.kinematics import HandKinematics
from tacforce_ros.rig import FINGERS

HAND = load_hand()
KIN = HandKinematics.for_hand(HAND)
URDF_TEXT = HAND.urdf_path.read_text()
# Joint limits as written in the URDF (docs/PROTOCOLS.md section 2), Allegro order.
LOWER, UPPER = np.array([[float(v) for v in re.search(
    rf'<joint name="joint_{i}.0" type="revolute">.*?lower="([-\d.]+)" upper="([-\d.]+)"',
    URDF_TEXT, re.S).groups()] for i in range(16)]).T

# Classic Allegro link offsets [m] (read off the URDF by hand).
FINGER_BASE_Y, FINGER_BASE_Z, FINGER_TILT = 0.0435, -0.001542, np.deg2rad(5.0)
SEGMENTS = (0.0164, 0.054, 0.0384)
TIP = 0.0267


def random_q(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(LOWER, UPPER)


def test_joint_order_and_finger_slices():
    assert KIN.joint_names == [f'joint_{i}.0' for i in range(16)]
    assert [KIN.finger_joints(f) for f in FINGERS] == [slice(0, 4), slice(4, 8), slice(8, 12),
                                                        slice(12, 16)]
    assert np.all(LOWER < UPPER) and LOWER[12] == 0.263 and UPPER[15] == 1.719
    with pytest.raises(ValueError, match='pinky'):
        KIN.finger_joints('pinky')


def test_index_tip_at_zero_is_the_sum_of_link_offsets():
    R, p = KIN.frame_pose(np.zeros(16), 'link_3.0_tip')
    length = sum(SEGMENTS) + TIP
    expected = [0.0, FINGER_BASE_Y + length * np.sin(FINGER_TILT),
                FINGER_BASE_Z + length * np.cos(FINGER_TILT)]
    np.testing.assert_allclose(p, expected, atol=1e-12)
    np.testing.assert_allclose(R, Rotation.from_euler('x', -FINGER_TILT).as_matrix(), atol=1e-12)
    _, p_middle = KIN.frame_pose(np.zeros(16), 'link_7.0_tip')
    np.testing.assert_allclose(p_middle, [0.0, 0.0, 0.0007 + length], atol=1e-12)


def test_single_joint_rotates_the_tip_about_its_axis():
    theta = 0.7
    q = np.zeros(16)
    q[3] = theta                                     # index distal joint only
    tilt = Rotation.from_euler('x', -FINGER_TILT)
    pivot = np.array([0.0, FINGER_BASE_Y, FINGER_BASE_Z]) + tilt.apply([0, 0, sum(SEGMENTS)])
    axis = tilt.apply([0.0, 1.0, 0.0])
    expected = pivot + Rotation.from_rotvec(theta * axis).apply(tilt.apply([0, 0, TIP]))
    np.testing.assert_allclose(KIN.frame_pose(q, 'link_3.0_tip')[1], expected, atol=1e-12)
    # Joints of other fingers leave the index tip alone.
    q_other = q.copy()
    q_other[4:] = random_q(1)[4:]
    np.testing.assert_allclose(KIN.frame_pose(q_other, 'link_3.0_tip')[1], expected, atol=1e-12)


def test_array_frames_follow_the_s0_convention():
    q = random_q(2)
    for a in HAND.arrays:
        R_link, p_link = KIN.frame_pose(q, a.parent_link)
        R, p = KIN.frame_pose(q, a.frame_id)
        # z: palmar side of the link (+x; the palm faces +x too); x: distal (+z), except the
        # modules turned by 180 deg (middle-phalanx modules x1, palm 52 and 53).
        np.testing.assert_allclose(R_link.T @ R[:, 2], [1, 0, 0], atol=1e-9)
        turned = a.module_code in ('11', '21', '31', '52', '53')
        np.testing.assert_allclose((R_link.T @ R[:, 0])[2], -1.0 if turned else 1.0, atol=1e-9)
        if a.kind == 'fingertip':
            np.testing.assert_allclose(p, p_link, atol=1e-12)              # cap centre = tip frame


def test_rotation_between_composes_frame_poses():
    q = random_q(3)
    R_tip, _ = KIN.frame_pose(q, 'uskin_index_tip')
    R_ft, _ = KIN.frame_pose(q, 'ft_sensor')
    R_0F = KIN.rotation_between(q, 'ft_sensor', 'uskin_index_tip')
    np.testing.assert_allclose(R_0F, R_tip.T @ R_ft, atol=1e-12)
    np.testing.assert_allclose(R_0F @ KIN.rotation_between(q, 'uskin_index_tip', 'ft_sensor'),
                               np.eye(3), atol=1e-12)
    np.testing.assert_allclose(R_ft, np.eye(3), atol=1e-12)    # default rig: axes of the base


def _fd_jacobian(q, finger, point):
    cols = range(*KIN.finger_joints(finger).indices(16))
    frame = f'link_{4 * FINGERS.index(finger) + 3}.0_tip'
    h = 1e-6
    J = np.empty((3, 4))
    for c, j in enumerate(cols):
        dq = np.zeros(16)
        dq[j] = h
        points = [R @ point + p for R, p in (KIN.frame_pose(q + dq, frame),
                                             KIN.frame_pose(q - dq, frame))]
        J[:, c] = (points[0] - points[1]) / (2 * h)
    return J


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31), finger=st.sampled_from(FINGERS),
       offset=st.lists(st.floats(-0.02, 0.02), min_size=3, max_size=3))
def test_fingertip_jacobian_matches_finite_differences(seed, finger, offset):
    q = random_q(seed)
    point = np.array(offset)
    np.testing.assert_allclose(KIN.fingertip_jacobian(q, finger),
                               _fd_jacobian(q, finger, np.zeros(3)), atol=1e-8)
    np.testing.assert_allclose(KIN.fingertip_jacobian(q, finger, point),
                               _fd_jacobian(q, finger, point), atol=1e-8)


def _potential_energy(q16):
    return pin.computePotentialEnergy(KIN.model, KIN.data, KIN._pin_q(q16))


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_gravity_torques_are_the_gradient_of_potential_energy(seed):
    q = random_q(seed)
    h = 1e-6
    grad = np.array([(_potential_energy(q + h * e) - _potential_energy(q - h * e)) / (2 * h)
                     for e in np.eye(16)])
    tau = KIN.gravity_torques(q)
    np.testing.assert_allclose(tau, grad, atol=1e-9)
    assert np.abs(tau).max() > 1e-3          # the masses make gravity matter


def test_gravity_follows_the_mounting():
    q = random_q(5)
    flipped = HandKinematics(HAND.urdf_path, gravity=(0.0, 0.0, 9.81))
    np.testing.assert_allclose(flipped.gravity_torques(q), -KIN.gravity_torques(q), atol=1e-12)


def test_mujoco_compiles_keeps_frames_and_agrees():
    mj = mujoco.MjModel.from_xml_path(str(HAND.urdf_path))
    data = mujoco.MjData(mj)
    q = random_q(6)
    for i, name in enumerate(KIN.joint_names):
        data.qpos[mj.jnt_qposadr[mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, name)]] = q[i]
    mujoco.mj_forward(mj, data)
    for frame in [a.frame_id for a in HAND.arrays] + [HAND.ft_frame, 'link_15.0_tip']:
        body = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_BODY, frame)
        assert body >= 0, frame
        R, p = KIN.frame_pose(q, frame)
        np.testing.assert_allclose(data.xpos[body], p, atol=1e-9)
        np.testing.assert_allclose(data.xmat[body].reshape(3, 3), R, atol=1e-9)
    # Same masses and inertias: MuJoCo's bias force at rest is the gravity torque.
    dof = [mj.jnt_dofadr[mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, n)]
           for n in KIN.joint_names]
    np.testing.assert_allclose(data.qfrc_bias[dof], KIN.gravity_torques(q), atol=1e-9)


def test_bad_q_is_refused():
    with pytest.raises(ValueError, match=r'\(16,\)'):
        KIN.frame_pose(np.zeros(15), 'ft_sensor')
    with pytest.raises(ValueError, match='non-finite'):
        KIN.gravity_torques(np.full(16, np.nan))
    with pytest.raises(KeyError, match='uskin_pinky'):
        KIN.frame_pose(np.zeros(16), 'uskin_pinky')


def _hand_with_urdf(tmp_path, edit):
    (tmp_path / 'urdf').mkdir()
    (tmp_path / 'urdf' / 'allegro_right_uskin.urdf').write_text(edit(URDF_TEXT))
    (tmp_path / 'hand').mkdir()
    yaml_path = tmp_path / 'hand' / 'h.yaml'
    shipped = HAND.urdf_path.parent.parent / 'hand' / 'allegro_right_uskin.yaml'
    yaml_path.write_text(shipped.read_text())
    return load_hand(yaml_path)


@pytest.mark.parametrize('edit, message', [
    (lambda t: t.replace('uskin_index_middle"', 'uskin_index_mid"'),
     r'arrays \(index_middle\)\.frame_id: .uskin_index_middle. is not in'),
    (lambda t: t.replace('<parent link="link_2.0"/><child link="uskin_index_middle"/>',
                         '<parent link="link_1.0"/><child link="uskin_index_middle"/>'),
     r'arrays \(index_middle\)\.parent_link: .uskin_index_middle. hangs on .link_1.0.'),
    (lambda t: t.replace('"ft_sensor"', '"ft"'), r'ft_frame: frame .ft_sensor. is not in'),
])
def test_urdf_missing_hand_frames_is_refused(tmp_path, edit, message):
    hand = _hand_with_urdf(tmp_path, edit)
    with pytest.raises(HandConfigError, match=message):
        HandKinematics.for_hand(hand)


def test_urdf_that_is_not_an_allegro_is_refused(tmp_path):
    hand = _hand_with_urdf(tmp_path, lambda t: t.replace('joint_7.0"', 'joint_seven"'))
    with pytest.raises(ValueError, match=r"missing joints \['joint_7.0'\]"):
        HandKinematics.for_hand(hand)
    missing = load_hand(tmp_path / 'hand' / 'h.yaml')
    (tmp_path / 'urdf' / 'allegro_right_uskin.urdf').unlink()
    with pytest.raises(HandConfigError, match='urdf: .* does not exist'):
        HandKinematics.for_hand(missing)
