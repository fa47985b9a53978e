"""Quasi-static calibration simulator: the operator presses one array on a push-plate.

No rigid-body dynamics: the operator schedule gives force, contact location and finger pose per
step; the tactile chain turns the contact into counts, and the F/T reading is the same force
expressed in {F} through the hand pose (R_F^0 from the URDF kinematics), plus its effects.
"""
from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from tacforce_ros.hand.description import HandDescription
from tacforce_ros.sim.contact import Contact
from tacforce_ros.sim.effects import Pipeline
from tacforce_ros.sim.operator import OperatorParams, Schedule, draw_schedule
from tacforce_ros.sim.sample import SimSample, StepState
from tacforce_ros.sim.scene import Scene, session_seed
from tacforce_ros.sim.sensors import TactileSensor


class PoseRotation:
    """R_F^0(q): rotation from {F} to the array frame {S0} for a finger pose."""

    def __init__(self, hand: HandDescription, array_frame: str) -> None:
        from tacforce_ros.hand.kinematics import HandKinematics
        self._kinematics = HandKinematics(hand.urdf_path)
        self._from, self._to = hand.ft_frame, array_frame

    def __call__(self, q: np.ndarray) -> np.ndarray:
        return self._kinematics.rotation_between(q, self._from, self._to)


def _pose_rotation(hand: HandDescription, array_frame: str):
    """Kinematics from the URDF; without it (kinematics not installed, no URDF), {F} = {S0}."""
    try:
        return PoseRotation(hand, array_frame)
    except (ImportError, FileNotFoundError, OSError) as exc:
        warnings.warn(f'hand kinematics unavailable ({exc}); F/T wrench given in {{S0}}',
                      stacklevel=3)
        return lambda q: np.eye(3)


class CalibrationSimulator:
    """Simulator for scenes of kind 'calibration' (one step = one 100 Hz tactile frame)."""

    def __init__(self, scene: Scene, hand: HandDescription, seed: int | None = None,
                 pose_rotation=None) -> None:
        self.scene, self.hand = scene, hand
        self.dt = 1.0 / scene.tactile_rate
        self.block_steps = int(round(scene.duration * scene.tactile_rate))
        self.operator = OperatorParams.from_dict(scene.operator)
        self.pipeline = Pipeline.from_scene(scene.effects)
        self.sensor = TactileSensor(hand, scene.array, scene.plate, self.pipeline, self.dt)
        self.rotation = pose_rotation or _pose_rotation(hand, self.sensor.array.frame_id)
        self.reset(seed)

    def reset(self, seed: int | None = None) -> None:
        self.seed = self.scene.seed if seed is None else int(seed)
        self._rng = np.random.default_rng([self.seed, 0])
        self.sensor.reset(self.seed, self.scene.sensor_seed)
        self.step_index = 0
        self._schedule: Schedule | None = None
        self._block_start = 0
        self._rotation_cache: tuple[bytes, np.ndarray] = (b'', np.eye(3))

    def _row(self) -> int:
        k = self.step_index - self._block_start
        if self._schedule is None or k >= self.block_steps:
            start_q = None if self._schedule is None else self._schedule.q[-1]
            self._schedule = draw_schedule(self.operator, self.sensor.array, self.block_steps,
                                           self.dt, self._rng, start_q)
            self._block_start, k = self.step_index, 0
        return k

    def _r_f0(self, q: np.ndarray) -> np.ndarray:
        # The pose holds still through a press: reuse the rotation while q is unchanged.
        key = q.tobytes()
        if key != self._rotation_cache[0]:
            self._rotation_cache = (key, self.rotation(q))
        return self._rotation_cache[1]

    def step(self, joint_torques: np.ndarray | None = None) -> SimSample:
        if joint_torques is not None:
            raise ValueError('calibration scenes are driven by the operator model; '
                             'pass no joint torques')
        k, s = self._row(), self._schedule
        t = self.step_index * self.dt
        force = s.normal_force[k] * s.normal[k] + s.shear[k]
        active = bool(s.normal_force[k] > 0.0)
        state = StepState(t=t, contact=Contact(force, s.point[k], s.normal[k], s.axis[k], active),
                          q=s.q[k], qdot=s.qdot[k])
        self.sensor.measure(state)
        # The F/T sensor carries the plate: it reads the force the array applies to the plate,
        # in {F}; {F}'s origin is on the indenter surface, so the torque there is ~0.
        state.wrench = np.concatenate([self._r_f0(state.q).T @ force, np.zeros(3)])
        self.pipeline.run('wrench', state)
        self.pipeline.run('delivery', state)
        self.step_index += 1
        return SimSample(t=t, taxel_counts=state.counts_out, temperatures=state.temperatures,
                         ft_wrench=state.wrench, ft_status=0,
                         q=state.q, qdot=state.qdot, true_force=force,
                         contact_point=s.point[k], in_contact=active,
                         delivered=state.delivered, pressed_array=self.scene.array)


class PressTour:
    """A calibration scene with `press_tour`: the operator presses each listed array in turn,
    one `duration` block each (starting and ending released), round and round: a check that
    every array's taxels and topic are where the hand description says.

    One CalibrationSimulator per array, each a session of the same hand (sensor_seed) with a
    seed of its own; the whole hand's readings come from the one pressing, so an untouched
    array's reading changes at a block boundary by about its noise and drift (each stop's
    effects advance only while it runs). Time runs on across the stops."""

    def __init__(self, scene: Scene, hand: HandDescription, seed: int | None = None) -> None:
        self.scene, self.hand = scene, hand
        self._stops = [CalibrationSimulator(dataclasses.replace(scene, array=name, press_tour=()),
                                            hand) for name in scene.press_tour]
        self.dt = self._stops[0].dt
        self.block_steps = self._stops[0].block_steps
        self.reset(seed)

    def reset(self, seed: int | None = None) -> None:
        self.seed = self.scene.seed if seed is None else int(seed)
        for stop in self._stops:
            stop.reset(session_seed(self.seed, stop.scene.array, self.scene.plate.name, 0))
        self.step_index = 0

    def step(self, joint_torques: np.ndarray | None = None) -> SimSample:
        stop = self._stops[(self.step_index // self.block_steps) % len(self._stops)]
        sample = dataclasses.replace(stop.step(joint_torques), t=self.step_index * self.dt)
        self.step_index += 1
        return sample
