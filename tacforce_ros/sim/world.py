"""One entry point for every kind of simulator: make_simulator(scene) -> Simulator."""
from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np

from tacforce_ros.hand.description import HandDescription, load_hand
from tacforce_ros.sim.sample import SimSample
from tacforce_ros.sim.scene import Scene, load_scene


class Simulator(Protocol):
    """Calibration (quasi-static), closed-loop or grasp (MuJoCo) simulation behind one
    interface."""
    scene: Scene
    hand: HandDescription
    dt: float     # s per step: 1/100 in calibration scenes, 1/physics_rate in closed loop

    def reset(self, seed: int | None = None) -> None: ...

    def step(self, joint_torques: np.ndarray | None = None) -> SimSample: ...


def make_simulator(scene: Scene | str | Path, hand: HandDescription | None = None,
                   seed: int | None = None) -> Simulator:
    """Build the simulator a scene needs (scene may be a Scene, a scene name or a YAML path)."""
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    hand = load_hand() if hand is None else hand
    if scene.kind == 'calibration':
        from tacforce_ros.sim.calibration import CalibrationSimulator, PressTour
        return (PressTour if scene.press_tour else CalibrationSimulator)(scene, hand, seed)
    if scene.kind == 'grasp':
        from tacforce_ros.sim.grasp import GraspSimulator
        return GraspSimulator(scene, hand, seed)
    from tacforce_ros.sim.closed_loop import ClosedLoopSimulator
    return ClosedLoopSimulator(scene, hand, seed)
