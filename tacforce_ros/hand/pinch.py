"""Pinch poses: joint angles at which the thumb and other fingertips hold an object of a given
width between their skins, the fingertip pads facing each other across it.

A pinch is found by least squares over the fingers' joints (scipy's bounded trust-region
solver, the URDF's joint limits as bounds, a fixed set of starting poses so the answer is
reproducible): the fingertip spheres (`tip_radius`) are the object's width apart, each touching
the object where its array is centred (the direction from the tip sphere's centre to the
taxels' mean position). One fingertip against the thumb (the grasp controller's pinch).
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from tacforce_ros.hand.description import HandDescription
from tacforce_ros.hand.kinematics import TIP_LINKS, HandKinematics

STARTS = 12                # starting poses tried per pair (fixed draws, seed 0)
TOLERANCE = 5e-4           # m: largest residual of an accepted pose


class PinchError(ValueError):
    """No pose within the joint limits holds the object as asked."""


def joint_limits(kinematics: HandKinematics) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) of the 16 joints in Allegro order, from the URDF."""
    model = kinematics.model
    order = [model.joints[model.getJointId(n)].idx_q for n in kinematics.joint_names]
    return (np.asarray(model.lowerPositionLimit)[order].copy(),
            np.asarray(model.upperPositionLimit)[order].copy())


def pad(hand: HandDescription, kinematics: HandKinematics, q16: np.ndarray,
        finger: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(tip sphere centre, pad centre, pad outward normal) of a fingertip, base frame."""
    array = hand.array(f'{finger}_tip')
    rotation, origin = kinematics.frame_pose(q16, array.frame_id)
    normal = array.rotations[:, :, 2].mean(axis=0)
    centre = kinematics.frame_pose(q16, TIP_LINKS[finger])[1]
    return (centre, rotation @ array.positions.mean(axis=0) + origin,
            rotation @ (normal / np.linalg.norm(normal)))


def pinch_pose(hand: HandDescription, kinematics: HandKinematics, fingers: tuple[str, ...],
               width: float, tip_radius: float, rest: np.ndarray, local: bool = False
               ) -> np.ndarray:
    """q16: `rest` with the thumb and `fingers` (one other fingertip) set to pinch an object
    `width` m across. `local`: the one pose nearest `rest` (one start, there) instead of the
    best of STARTS. Raises PinchError when no pose within the joint limits does."""
    if len(fingers) != 1 or fingers[0] == 'thumb':
        raise PinchError(f'{list(fingers)}: a pinch pairs the thumb with one other fingertip')
    lower, upper = joint_limits(kinematics)
    q = np.asarray(rest, dtype=np.float64).copy()
    finger = fingers[0]
    free = np.r_[np.arange(16)[kinematics.finger_joints(finger)],
                 np.arange(16)[kinematics.finger_joints('thumb')]]
    rng = np.random.default_rng(0)

    def residuals(x: np.ndarray) -> np.ndarray:
        trial = q.copy()
        trial[free] = x
        c_f, p_f, _ = pad(hand, kinematics, trial, finger)
        c_t, p_t, _ = pad(hand, kinematics, trial, 'thumb')
        axis = (c_t - c_f) / np.linalg.norm(c_t - c_f)
        return np.concatenate([
            np.linalg.norm(c_t - c_f) - np.array([2.0 * tip_radius + width]),
            tip_radius * (axis - _unit(p_f - c_f)),     # touching at the pad's centre
            tip_radius * (-axis - _unit(p_t - c_t))])

    best = None
    for _ in range(1 if local else STARTS):
        start = np.clip(q[free], lower[free], upper[free]) if local else \
            rng.uniform(lower[free], upper[free])
        fit = least_squares(residuals, start, bounds=(lower[free], upper[free]))
        if best is None or fit.cost < best.cost:
            best = fit
    if np.abs(best.fun).max() > TOLERANCE:
        raise PinchError(f'the thumb and {finger} cannot hold {width * 1e3:.1f} mm within '
                         f'their joint limits (worst residual '
                         f'{np.abs(best.fun).max() * 1e3:.1f} mm)')
    q[free] = best.x
    return q

def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def reach(hand: HandDescription, kinematics: HandKinematics, q16: np.ndarray, finger: str,
          point: np.ndarray) -> np.ndarray:
    """q16 with `finger`'s joints moved (least squares from where they are, within the joint
    limits) so its tip sphere's centre is at `point` (base frame)."""
    lower, upper = joint_limits(kinematics)
    joints = kinematics.finger_joints(finger)
    q = np.asarray(q16, dtype=np.float64).copy()

    def residuals(x: np.ndarray) -> np.ndarray:
        trial = q.copy()
        trial[joints] = x
        return pad(hand, kinematics, trial, finger)[0] - point

    fit = least_squares(residuals, np.clip(q[joints], lower[joints], upper[joints]),
                        bounds=(lower[joints], upper[joints]))
    q[joints] = fit.x
    return q


def grasp_poses(hand: HandDescription, kinematics: HandKinematics, fingers: tuple[str, ...],
                width: float, tip_radius: float, rest: np.ndarray, clearance: float
                ) -> dict[str, dict[str, list[float]]]:
    """Per finger (the thumb first): `contact_pose`, the pinch of `width` (pinch_pose), and
    `pose`, the start: each fingertip `clearance` m back from its contact along the line to
    the grasp's centre (reach)."""
    contact = pinch_pose(hand, kinematics, fingers, width, tip_radius, rest)
    tips = {f: pad(hand, kinematics, contact, f)[0] for f in ('thumb', *fingers)}
    others = np.mean([tips[f] for f in fingers], axis=0)
    centre = 0.5 * (tips['thumb'] + others)
    poses = {}
    for finger in ('thumb', *fingers):
        joints = kinematics.finger_joints(finger)
        back = tips[finger] - clearance * _unit(centre - tips[finger])
        start = reach(hand, kinematics, contact, finger, back)
        poses[finger] = {'pose': _rounded(start[joints]),
                         'contact_pose': _rounded(contact[joints])}
    return poses


def _rounded(values: np.ndarray) -> list[float]:
    return [round(float(v), 4) for v in values]
