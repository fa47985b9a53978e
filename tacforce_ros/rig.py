"""Facts of the rig, one home each: the hand's firmware limits, the rate everything runs at, and
the calibration plates. Sources are in docs/PROTOCOLS.md and the paper."""
from __future__ import annotations

import numpy as np

# XELA uSkin's highest frame rate; the paper records, estimates and controls at it.
RATE_HZ = 100.0

# Allegro V4 firmware per-joint torque clamps [N m], joints 0-3 of a finger (index, middle and
# ring alike) and of the thumb (docs/PROTOCOLS.md, Allegro V4 CAN).
FINGER_TORQUE_LIMITS = (0.3125, 0.5625, 0.375, 0.2375)
THUMB_TORQUE_LIMITS = (0.4375, 0.3375, 0.225, 0.225)
FINGERS = ('index', 'middle', 'ring', 'thumb')     # the hand's joint order, 4 joints each
TORQUE_LIMITS = np.array(FINGER_TORQUE_LIMITS * 3 + THUMB_TORQUE_LIMITS, dtype=np.float64)
TORQUE_LIMITS.flags.writeable = False


def finger_torque_limits(finger: str) -> np.ndarray:
    """The four clamps of one finger's joints [N m]."""
    index = FINGERS.index(finger)
    return TORQUE_LIMITS[4 * index:4 * index + 4]


# The push-plates (paper Fig. 2d): five for training and the leave-one-plate-out benchmark, the
# spherical one held out for the online and closed-loop tests.
TRAINING_PLATES = ('button', 'flat', 'fillet', 'convex', 'edge')
HELD_OUT_PLATE = 'spherical'
