"""What one simulator step produces (SimSample) and the mutable state effects work on."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tacforce_ros.sim.contact import Contact

STREAMS = ('tactile', 'ft', 'joints')


@dataclass
class SimSample:
    """One simulator step.

    Sign convention: `true_force` is the contact force between the scene's array and the plate
    or object, expressed in {S0}, as the force the array applies to it: the quantity the lab
    pipeline gets by projecting the F/T reading into {S0} (paper, section IV-A step 3), so the
    estimator's target, the controller's f_d and this ground truth share one sign.

    `tactile_fresh` is True on steps where a new 100 Hz tactile frame was produced (every step in
    calibration scenes; every (physics_rate / 100)-th step in closed-loop scenes). Between frames,
    `taxel_counts`, `temperatures` and `contact_point` repeat the last frame, as a 100 Hz device
    would.
    """
    t: float
    taxel_counts: np.ndarray     # (368, 3) uint16, XELA flat order
    temperatures: np.ndarray     # (368,) float64, kelvin
    ft_wrench: np.ndarray        # (6,) float64, N and N m in {F}
    ft_status: int               # RDT status word
    q: np.ndarray                # (16,) rad
    qdot: np.ndarray             # (16,) rad/s
    true_force: np.ndarray       # (3,) N in {S0}
    contact_point: np.ndarray    # (3,) m in {S0}, on the skin, at the last tactile frame
    in_contact: bool
    delivered: dict[str, bool]
    tactile_fresh: bool = True
    pressed_array: str = ''      # the array in contact ('' = the scene's; press tours change it)

    @property
    def ft_counts(self) -> np.ndarray:
        """(6,) int32 RDT counts (Fx..Tz) of ft_wrench; computed when asked (the emulator
        asks, the in-process experiments never do)."""
        return ft_counts(self.ft_wrench)


def checked_torques(command: np.ndarray | None) -> np.ndarray:
    """A simulator step's 16 joint torques (N m, Allegro order): None is zero torque."""
    torque = np.zeros(16) if command is None else np.asarray(command, np.float64)
    if torque.shape != (16,) or not np.isfinite(torque).all():
        raise ValueError('joint_torques must be 16 finite values (N m), Allegro order')
    return torque


# Net F/T defaults (docs/PROTOCOLS.md section 3): counts per N and per N m.
COUNTS_PER_FORCE = 1e6
COUNTS_PER_TORQUE = 1e6
_COUNTS_SCALE = np.array([COUNTS_PER_FORCE] * 3 + [COUNTS_PER_TORQUE] * 3)
_INT32 = np.iinfo(np.int32)


def ft_counts(wrench: np.ndarray) -> np.ndarray:
    """(6,) N, N m -> RDT int32 counts at the Net F/T default resolution."""
    return np.clip(np.rint(np.asarray(wrench) * _COUNTS_SCALE), _INT32.min, _INT32.max
                   ).astype(np.int32)


@dataclass
class StepState:
    """Working state of one step; effect hooks read and replace its fields."""
    t: float
    contact: Contact | None       # closed loop: set on tactile-frame steps only
    depth: float = 0.0
    taxel_force: np.ndarray | None = None     # (n, 3) force on each taxel, in {S0}
    local_force: np.ndarray | None = None     # (n, 3) per-taxel force in its own frame
    counts: np.ndarray | None = None          # (368, 3) float counts
    temperatures: np.ndarray | None = None    # (368,) K
    counts_out: np.ndarray | None = None      # (368, 3) uint16, what the device sends
    wrench: np.ndarray | None = None          # (6,) in {F}
    torque: np.ndarray | None = None          # (16,) N m
    q: np.ndarray | None = None
    qdot: np.ndarray | None = None
    delivered: dict[str, bool] = field(default_factory=lambda: dict.fromkeys(STREAMS, True))
