"""Recorded streams -> CalibrationDataset: pipeline steps 1-3, for a calibration bag (rosbag2,
docs/CONTRACTS.md) and for the simulator's streams in process alike (streams_dataset).

Tactile frames of the pressed array, the F/T wrench and the joint states are low-passed on their
own time bases, resampled onto the tactile stamps, and the force is projected into the array frame
with R^0_F(t) from the kinematics. Malformed tactile frames (wrong taxel count) are counted and
dropped.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from tacforce_ros.estimation.dataset import CalibrationDataset, DatasetError
from tacforce_ros.hand.description import side_of
from tacforce_ros.estimation.preprocessing import common_span, lowpass, project_force, resample

if TYPE_CHECKING:
    from tacforce_ros.hand.description import HandDescription
    from tacforce_ros.hand.kinematics import HandKinematics


@dataclass
class BagStreams:
    """Raw streams of one bag for one array; times in s from the header stamps."""

    tactile_time: list[float]
    tactile: list[np.ndarray]
    wrench_time: list[float]
    force: list[np.ndarray]
    joint_time: list[float]
    joints: list[np.ndarray]
    dropped: int = 0


def _seconds(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def read_streams(path: str | Path, array_name: str, n_taxels: int,
                 joint_names: list[str]) -> BagStreams:
    from tacforce_ros import bagio, topics

    streams = BagStreams([], [], [], [], [], [])
    wanted = [topics.TOPIC_TACTILE, topics.TOPIC_WRENCH, topics.TOPIC_JOINTS]
    for topic, _, msg in bagio.read_messages(path, wanted):
        if topic == topics.TOPIC_TACTILE:
            entry = next((a for a in msg.arrays if a.name == array_name), None)
            if entry is None or not len(entry.x) == len(entry.y) == len(entry.z) == n_taxels:
                streams.dropped += 1
                continue
            streams.tactile_time.append(_seconds(msg.header.stamp))
            streams.tactile.append(np.stack([entry.x, entry.y, entry.z], axis=1))
        elif topic == topics.TOPIC_WRENCH:
            f = msg.wrench.force
            streams.wrench_time.append(_seconds(msg.header.stamp))
            streams.force.append(np.array([f.x, f.y, f.z]))
        else:
            order = {name: i for i, name in enumerate(msg.name)}
            if not set(joint_names) <= set(order):
                streams.dropped += 1
                continue
            streams.joint_time.append(_seconds(msg.header.stamp))
            streams.joints.append(np.array([msg.position[order[n]] for n in joint_names]))
    return streams


def _rate(time: np.ndarray) -> float:
    return 1.0 / float(np.median(np.diff(time)))


def _increasing(time: list[float], values: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Sorted by stamp, duplicate stamps dropped (interpolation needs strictly increasing)."""
    time_arr = np.asarray(time, dtype=np.float64)
    order = np.argsort(time_arr, kind='stable')
    time_arr = time_arr[order]
    keep = np.concatenate(([True], np.diff(time_arr) > 0.0))
    return time_arr[keep], np.asarray(values, dtype=np.float64)[order][keep]


def dataset_from_bag(path: str | Path, hand: HandDescription,
                     kinematics: HandKinematics) -> tuple[CalibrationDataset, int]:
    """One calibration bag -> (dataset of its pressed array, messages dropped as malformed)."""
    from tacforce_ros.bagio import read_session_metadata

    meta = read_session_metadata(path)
    side = side_of(meta.get('hand_side'))
    if side != hand.side:
        raise DatasetError(f'{path}: a bag of the {side} hand, read with the {hand.side} hand\'s '
                           'description')
    array = hand.array(meta.get('array', ''))
    streams = read_streams(path, array.name, array.n_taxels, list(kinematics.joint_names))
    for name, samples in (('tactile', streams.tactile), ('wrench', streams.force),
                          ('joint', streams.joints)):
        if len(samples) < 2:
            raise DatasetError(f'{path}: only {len(samples)} {name} messages for {array.name}')
    dataset = streams_dataset(hand, kinematics, array.name,
                              _increasing(streams.tactile_time, streams.tactile),
                              _increasing(streams.wrench_time, streams.force),
                              _increasing(streams.joint_time, streams.joints),
                              plate=str(meta.get('plate', '')),
                              source=str(meta.get('source', 'lab')))
    return dataset, streams.dropped


Stream = tuple[np.ndarray, np.ndarray]      # (T,) increasing stamps [s], (T, ...) values


def streams_dataset(hand: HandDescription, kinematics: HandKinematics, array_name: str,
                    tactile: Stream, force: Stream, joints: Stream, plate: str, source: str,
                    rates: tuple[float, float] | None = None,
                    zero_phase_tactile: bool = True) -> CalibrationDataset:
    """The one chain from one array's recorded streams to its training set: tactile (n, 3)
    counts, F/T force (3,) in the sensor frame and joint positions (16,), each on its own
    stamps. Each stream is low-passed at its own rate (`rates`: tactile and force in Hz, when
    the recorder knows them; else measured from the stamps), the force and joints are resampled
    onto the tactile stamps they span, and the force is projected into the array frame {S0}.
    `zero_phase_tactile` False keeps the frames as the estimator receives them online."""
    array = hand.array(array_name)
    (t_tac, frames), (t_ft, wrench), (t_q, q) = tactile, force, joints
    tactile_rate, force_rate = rates if rates is not None else (_rate(t_tac), _rate(t_ft))
    frames = lowpass(frames, fs=tactile_rate) if zero_phase_tactile else frames
    wrench = lowpass(wrench, fs=force_rate)
    start, stop = common_span(t_tac, t_ft, t_q)
    inside = (t_tac >= start) & (t_tac <= stop)
    base = t_tac[inside]
    wrench = resample(base, t_ft, wrench)
    q = resample(base, t_q, q)
    rotations = np.stack([kinematics.rotation_between(row, hand.ft_frame, array.frame_id)
                          for row in q])
    n = base.size
    return CalibrationDataset(array=array.name, X=frames[inside],
                              F=project_force(wrench, rotations), plates=np.full(n, plate),
                              sessions=np.zeros(n, dtype=np.int64), time=base - base[0],
                              source=source, hand_side=hand.side)
