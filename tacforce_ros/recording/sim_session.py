"""A simulated calibration session written as the lab recorder writes one (docs/CONTRACTS.md):
the same topics, plus /sim/contact_force (ground truth in {S0}); session metadata says source
'sim', the scene and the seed. A message the transport effect drops is not written, as in a lab
recording. Used by `sim_record` and `campaign run --sim`.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from tacforce_ros import bagio, topics
from tacforce_ros.hand.description import HandDescription
from tacforce_ros.sim import load_scene, make_simulator
from tacforce_ros.sim.scene import calibration_scene_name, session_seed


def record_session(path: Path, hand: HandDescription, array: str, plate: str,
                   session: int, seconds: float, base_seed: int, progress: tqdm) -> Path:
    """Session `session` of `array` on `plate` as a bag at `path`."""
    scene = load_scene(calibration_scene_name(array, plate))
    seed = session_seed(base_seed, array, plate, session)
    sim = make_simulator(scene, hand, seed=seed)
    taxel_array = hand.array(array)
    joint_names = [f'joint_{i}.0' for i in range(16)]
    metadata = bagio.session_metadata(
        array=array, plate=plate, hand_side=hand.side, source='sim', scene=scene.name,
        seed=seed, operator_notes=f'simulated operator, session {session}')
    start_ns = time.time_ns()
    with bagio.CalibrationBagWriter(path, metadata) as writer:
        for k in range(int(round(seconds / sim.dt))):
            sample = sim.step()
            stamp = start_ns + int(round(sample.t * 1e9))
            tactile = wrench = joints = None
            if sample.delivered['tactile']:
                tactile = bagio.tactile_hand(stamp, hand, sample.taxel_counts,
                                             sample.temperatures, sample.t + start_ns * 1e-9, k)
                writer.write(topics.TOPIC_TACTILE, stamp, tactile)
            if sample.delivered['ft']:
                wrench = bagio.wrench_stamped(stamp, hand.ft_frame, sample.ft_wrench)
                writer.write(topics.TOPIC_WRENCH, stamp, wrench)
            if sample.delivered['joints']:
                joints = bagio.joint_state(stamp, joint_names, sample.q, sample.qdot)
                writer.write(topics.TOPIC_JOINTS, stamp, joints)
            if tactile is not None and wrench is not None and joints is not None:
                pressed = tactile.arrays[hand.index(array)]
                writer.write(topics.TOPIC_SAMPLE, stamp,
                             bagio.calibration_sample(stamp, pressed, wrench, joints))
            truth = np.concatenate([sample.true_force, np.zeros(3)])
            writer.write(topics.TOPIC_SIM_CONTACT, stamp,
                         bagio.wrench_stamped(stamp, taxel_array.frame_id, truth))
            progress.update(1)
    return path
