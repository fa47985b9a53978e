"""Calibration sessions simulated in-process -> CalibrationDataset (pipeline steps 1-3), no bag.

The direct path of `reproduce`: the simulator sim_record drives, with its streams going straight
into the estimation's preprocessing (low-pass, resampling onto the tactile stamps, projection of
the F/T force into {S0} with R^0_F(q) from the nominal kinematics) instead of through a bag.
Messages the transport effect drops are left out of their stream, as a recorder would miss them.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from tacforce_ros.estimation.bag_dataset import streams_dataset
from tacforce_ros.estimation.dataset import CalibrationDataset, DatasetError
from tacforce_ros.sim import load_scene, make_simulator
from tacforce_ros.sim.scene import Scene, calibration_scene_name, session_seed

if TYPE_CHECKING:
    from tacforce_ros.hand.description import HandDescription
    from tacforce_ros.hand.kinematics import HandKinematics


def simulate_calibration(hand: HandDescription, kinematics: HandKinematics,
                         scene_name: str | Scene, seed: int, seconds: float, start: float = 0.0,
                         zero_phase_tactile: bool = True) -> CalibrationDataset:
    """Simulate `scene_name` (or a Scene as loaded and changed) with `seed` and keep the stamps
    in [start, seconds] (simulated s).

    Stamps are the simulator's time at the end of each step, as sim_world stamps its messages,
    so a window cut from a node-recorded bag can be reproduced here exactly.
    `zero_phase_tactile` False keeps the tactile frames as the estimator receives them online
    (the force, the reference, is filtered either way).
    """
    scene = scene_name if isinstance(scene_name, Scene) else load_scene(scene_name)
    sim = make_simulator(scene, hand, seed=seed)
    array = hand.array(scene.array)
    rows = array.flat_indices
    times: dict[str, list[float]] = {'tactile': [], 'ft': [], 'joints': []}
    values: dict[str, list[np.ndarray]] = {'tactile': [], 'ft': [], 'joints': []}
    for _ in range(int(round(seconds / sim.dt))):
        sample = sim.step()
        stamp = sample.t + sim.dt
        if stamp < start:
            continue
        for stream, value in (('tactile', lambda: sample.taxel_counts[rows]),
                              ('ft', lambda: sample.ft_wrench[:3]), ('joints', lambda: sample.q)):
            if sample.delivered[stream]:
                times[stream].append(stamp)
                values[stream].append(np.asarray(value(), dtype=np.float64))
    for stream, samples in values.items():
        if len(samples) < 2:
            raise DatasetError(f'{scene.name} seed {seed}: only {len(samples)} {stream} samples')
    stream = {s: (np.asarray(times[s]), np.stack(values[s])) for s in times}
    # A calibration scene steps physics at the tactile rate and samples the F/T every step.
    return streams_dataset(hand, kinematics, array.name, stream['tactile'], stream['ft'],
                           stream['joints'], plate=scene.plate.name, source='sim',
                           rates=(scene.tactile_rate, scene.physics_rate),
                           zero_phase_tactile=zero_phase_tactile)


def simulate_session(hand: HandDescription, kinematics: HandKinematics, array: str, plate: str,
                     session: int, seconds: float, base_seed: int) -> CalibrationDataset:
    """One operator session of `array` on `plate`, seeded exactly as sim_record seeds it."""
    return simulate_calibration(hand, kinematics, calibration_scene_name(array, plate),
                                session_seed(base_seed, array, plate, session), seconds)
