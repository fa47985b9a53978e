"""Hand kinematics and gravity over the URDF with Pinocchio, in Allegro joint order.

All poses and Jacobians are in the hand base frame (the URDF root). q16 is always in Allegro
order joint_0.0 .. joint_15.0 (index, middle, ring, thumb); Pinocchio's own joint order (by URDF
tree) is mapped once at construction.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin

from tacforce_ros.hand.description import HandConfigError, HandDescription

from tacforce_ros.rig import FINGERS
N_JOINTS = 16
TIP_LINKS = {finger: f'link_{4 * i + 3}.0_tip' for i, finger in enumerate(FINGERS)}


class HandKinematics:
    """Frame poses, fingertip Jacobians and gravity torques of one hand URDF."""

    def __init__(self, urdf_path: str | Path,
                 gravity: np.ndarray = (0.0, 0.0, -9.81)) -> None:
        """`gravity` [m/s^2] in the base frame: set it from how the hand is mounted."""
        self.model = pin.buildModelFromUrdf(str(urdf_path))
        self.model.gravity.linear = np.asarray(gravity, dtype=np.float64).reshape(3)
        self.data = self.model.createData()
        self.joint_names = [f'joint_{i}.0' for i in range(N_JOINTS)]
        missing = [n for n in self.joint_names if not self.model.existJointName(n)]
        if missing or self.model.nq != N_JOINTS or self.model.nv != N_JOINTS:
            raise ValueError(f'{urdf_path}: not a 16-joint Allegro hand '
                             f'(nq={self.model.nq}, missing joints {missing})')
        # Allegro index -> Pinocchio configuration index (revolute joints: nq == nv == 1 each).
        self._to_pin = np.array([self.model.joints[self.model.getJointId(n)].idx_q
                                 for n in self.joint_names], dtype=np.int64)
        self._frame_ids: dict[str, int] = {}
        self._tip_frames = {f: self._frame_id(link) for f, link in TIP_LINKS.items()}
        self._q_last: np.ndarray | None = None   # the q of data's frame placements
        self._q16_bytes = b''                       # the last q16 asked about, and its q
        self._q_pin = np.zeros(N_JOINTS)

    @classmethod
    def for_hand(cls, hand: HandDescription, **kwargs) -> 'HandKinematics':
        """Kinematics of `hand`'s URDF, refusing a URDF that lacks a frame the hand names."""
        if not Path(hand.urdf_path).is_file():
            raise HandConfigError(f'urdf: {hand.urdf_path} does not exist')
        kin = cls(hand.urdf_path, **kwargs)
        for field, frame in (('base_frame', hand.base_frame), ('ft_frame', hand.ft_frame)):
            if not kin.has_frame(frame):
                raise HandConfigError(f'{field}: frame {frame!r} is not in {hand.urdf_path}')
        for a in hand.arrays:
            for field, frame in (('frame_id', a.frame_id), ('parent_link', a.parent_link)):
                if not kin.has_frame(frame):
                    raise HandConfigError(f'arrays ({a.name}).{field}: {frame!r} is not in '
                                          f'{hand.urdf_path}')
            if kin.parent_link(a.frame_id) != a.parent_link:
                raise HandConfigError(f'arrays ({a.name}).parent_link: {a.frame_id!r} hangs on '
                                      f'{kin.parent_link(a.frame_id)!r} in the URDF, not '
                                      f'{a.parent_link!r}')
        return kin

    # ------------------------------------------------------------------ queries

    def parent_link(self, frame: str) -> str:
        """Name of the URDF link a fixed frame hangs on (through its fixed joint)."""
        frames = self.model.frames
        parent = frames[self._frame_id(frame)].parentFrame
        while frames[parent].type != pin.FrameType.BODY and parent != 0:
            parent = frames[parent].parentFrame
        return frames[parent].name

    def finger_joints(self, finger: str) -> slice:
        """Slice of q16 driving one finger: index 0:4, middle 4:8, ring 8:12, thumb 12:16."""
        if finger not in FINGERS:
            raise ValueError(f'unknown finger {finger!r}; expected one of {FINGERS}')
        start = 4 * FINGERS.index(finger)
        return slice(start, start + 4)

    def has_frame(self, frame: str) -> bool:
        return self.model.existFrame(frame)

    def frame_pose(self, q16: np.ndarray, frame: str) -> tuple[np.ndarray, np.ndarray]:
        """(R, p) of `frame` in the base frame: p_base = R @ p_frame + p."""
        placement = self._placement(q16, self._frame_id(frame))
        return placement.rotation.copy(), placement.translation.copy()

    def rotation_between(self, q16: np.ndarray, from_frame: str, to_frame: str) -> np.ndarray:
        """R mapping vectors in `from_frame` into `to_frame`, e.g. R^0_F = (q, 'ft_sensor',
        'uskin_index_tip')."""
        r_from = self._placement(q16, self._frame_id(from_frame)).rotation
        r_to = self.data.oMf[self._frame_id(to_frame)].rotation   # same kinematics pass
        return r_to.T @ r_from

    def fingertip_jacobian(self, q16: np.ndarray, finger: str,
                           point: np.ndarray | None = None) -> np.ndarray:
        """(3, 4) translation Jacobian of a point on the finger's tip link, base frame.

        `point` is given in the tip link frame (default: its origin, the fingertip centre).
        Columns follow the finger's joints in Allegro order.
        """
        cols = self._to_pin[self.finger_joints(finger)]
        frame_id = self._tip_frames[finger]
        q = self._pin_q(q16)
        jac = pin.computeFrameJacobian(self.model, self.data, q, frame_id,
                                       pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        # It ran the joints' forward kinematics at q: the frames follow from those, so the
        # frame poses read next at this q (the controller's R^0_F) need no pass of their own.
        pin.updateFramePlacements(self.model, self.data)
        self._q_last = q
        linear, angular = jac[:3, cols], jac[3:, cols]   # copies (cols is an index array)
        if point is None:
            return linear
        # Velocity of a point offset by r (base axes) from the frame origin: v + w x r.
        r = self.data.oMf[frame_id].rotation @ np.asarray(point, dtype=np.float64).reshape(3)
        return linear - _skew(r) @ angular

    def gravity_torques(self, q16: np.ndarray) -> np.ndarray:
        """(16,) joint torques [N m] that hold the hand still against gravity."""
        tau = pin.computeGeneralizedGravity(self.model, self.data, self._pin_q(q16))
        return tau[self._to_pin].copy()

    # ------------------------------------------------------------------ internals

    def _frame_id(self, frame: str) -> int:
        frame_id = self._frame_ids.get(frame)
        if frame_id is None:    # looked up by name once: the controller asks every tick
            if not self.model.existFrame(frame):
                raise KeyError(f'frame {frame!r} is not in the URDF')
            frame_id = self._frame_ids[frame] = self.model.getFrameId(frame)
        return frame_id

    def _pin_q(self, q16: np.ndarray) -> np.ndarray:
        """q16 checked and in Pinocchio's joint order. A controller tick asks several
        questions at one q: the same q16 returns the same array, checked once."""
        q16 = np.asarray(q16, dtype=np.float64)
        if q16.shape != (N_JOINTS,):
            raise ValueError(f'q16 must have shape ({N_JOINTS},), got {q16.shape}')
        key = q16.tobytes()
        if key == self._q16_bytes:
            return self._q_pin
        if not np.isfinite(q16).all():
            raise ValueError('q16 contains non-finite values')
        q = np.empty(N_JOINTS)
        q[self._to_pin] = q16
        self._q16_bytes, self._q_pin = key, q
        return q

    def _placement(self, q16: np.ndarray, frame_id: int) -> pin.SE3:
        q = self._pin_q(q16)
        # Several frames are usually read at one q (R^0_F needs two): run kinematics once per q.
        if q is not self._q_last:
            pin.framesForwardKinematics(self.model, self.data, q)
            self._q_last = q
        return self.data.oMf[frame_id]


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
