"""The left hand (config/hand/allegro_left_uskin.yaml, config/urdf/allegro_left_uskin.urdf) is the
mirror image of the right through the hand's xz plane (M = diag(1, -1, 1)): every link, array
frame and taxel of the left hand sits where M puts the right hand's, its frames are right-handed
with z out and x distal (R_left = M R_right M), at the same joint angles except the finger
abductions (joint_0/4/8 keep axis +z as in the vendor's left description, so their angles
change sign). Its flat order is XELA's left map, and it loads, simulates and compiles alike."""
import mujoco
import numpy as np
import pytest

from tacforce_ros.hand.description import hand_config, load_hand
from tacforce_ros.hand.kinematics import HandKinematics

RIGHT = load_hand(hand_config('right'))
LEFT = load_hand(hand_config('left'))
KIN_R = HandKinematics.for_hand(RIGHT)
KIN_L = HandKinematics.for_hand(LEFT)
M = np.diag([1.0, -1.0, 1.0])
ABDUCTION = [0, 4, 8]


def mirrored_q(q: np.ndarray) -> np.ndarray:
    out = q.copy()
    out[ABDUCTION] *= -1.0
    return out


def random_q(seed: int) -> np.ndarray:
    lower, upper = KIN_R.model.lowerPositionLimit, KIN_R.model.upperPositionLimit
    return np.random.default_rng(seed).uniform(lower, upper)


def test_the_left_hand_is_its_own_sensor_with_the_same_arrays():
    assert (LEFT.side, LEFT.sensor_model) == ('left', 'XR23AHLCPP')
    assert LEFT.urdf_path.name == 'allegro_left_uskin.urdf'
    assert [(a.name, a.module_code, a.kind, a.parent_link, a.frame_id) for a in LEFT.arrays] == \
        [(a.name, a.module_code, a.kind, a.parent_link, a.frame_id) for a in RIGHT.arrays]
    assert sorted(np.concatenate([a.flat_indices for a in LEFT.arrays])) == list(range(368))
    # Samples of XELA's left map (xela_apps l_server_model_joint_map.yaml, entry i =
    # x_taxel_0_<module>_<type>_<k>): 82 = index tip taxel 1, 65 = its taxel 2, 221 = palm 53
    # taxel 24, 101 = palm 51 taxel 1, 290 = ring middle (31) taxel 13.
    for name, k, index in (('index_tip', 1, 82), ('index_tip', 2, 65),
                           ('palm_ring_side', 24, 221), ('palm_index_side', 1, 101),
                           ('ring_middle', 13, 290)):
        assert LEFT.array(name).flat_indices[k - 1] == index, (name, k)


def test_each_taxel_is_the_mirror_of_the_right_hands_in_its_array_frame():
    for left, right in zip(LEFT.arrays, RIGHT.arrays):
        np.testing.assert_allclose(left.positions, right.positions @ M, atol=1e-12,
                                   err_msg=left.name)
        np.testing.assert_allclose(left.rotations, M @ right.rotations @ M, atol=1e-12,
                                   err_msg=left.name)


@pytest.mark.parametrize('seed', range(4))
def test_every_frame_of_the_left_hand_is_the_mirror_of_the_right(seed):
    q = random_q(seed)
    frames = ([a.frame_id for a in RIGHT.arrays] + [a.parent_link for a in RIGHT.arrays]
              + [RIGHT.ft_frame, RIGHT.rig_frame('thumb'), 'link_15.0_tip', 'link_12.0',
                 'link_13.0'])
    for frame in frames:
        R_r, p_r = KIN_R.frame_pose(q, frame)
        R_l, p_l = KIN_L.frame_pose(mirrored_q(q), frame)
        # 1e-9: the URDFs write pi with 10 digits
        np.testing.assert_allclose(p_l, M @ p_r, atol=1e-9, err_msg=frame)
        np.testing.assert_allclose(R_l, M @ R_r @ M, atol=1e-9, err_msg=frame)
        assert np.linalg.det(R_l) == pytest.approx(1.0)


def test_the_left_index_finger_is_on_the_minus_y_side_and_flexes_like_the_right():
    q = np.zeros(16)
    assert KIN_L.frame_pose(q, 'link_3.0_tip')[1][1] < -0.04 < 0.04 < \
        KIN_R.frame_pose(q, 'link_3.0_tip')[1][1]
    q[1:4] = 0.6                 # flexion: towards the palm side (+x) on both hands
    assert KIN_L.frame_pose(q, 'link_3.0_tip')[1][0] > 0.03
    assert KIN_R.frame_pose(q, 'link_3.0_tip')[1][0] > 0.03


def test_gravity_torques_mirror_and_mujoco_agrees_with_the_kinematics():
    q = random_q(7)
    tau_r, tau_l = KIN_R.gravity_torques(q), KIN_L.gravity_torques(mirrored_q(q))
    # Gravity along -z lies in the mirror plane: the same torques, the abductions' mirrored.
    np.testing.assert_allclose(tau_l, mirrored_q(tau_r), atol=1e-9)
    mj = mujoco.MjModel.from_xml_path(str(LEFT.urdf_path))
    data = mujoco.MjData(mj)
    for i, name in enumerate(KIN_L.joint_names):
        data.qpos[mj.jnt_qposadr[mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, name)]] = q[i]
    mujoco.mj_forward(mj, data)
    for frame in [a.frame_id for a in LEFT.arrays] + [LEFT.ft_frame]:
        body = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_BODY, frame)
        R, p = KIN_L.frame_pose(q, frame)
        np.testing.assert_allclose(data.xpos[body], p, atol=1e-9, err_msg=frame)
        np.testing.assert_allclose(data.xmat[body].reshape(3, 3), R, atol=1e-9, err_msg=frame)
