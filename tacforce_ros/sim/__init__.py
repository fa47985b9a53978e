"""tacforce_ros.sim: scenes, effects and the simulated hand (no ROS)."""
from tacforce_ros.sim.sample import SimSample
from tacforce_ros.sim.scene import Scene, SceneError, list_scenes, load_scene
from tacforce_ros.sim.world import Simulator, make_simulator

__all__ = ['Scene', 'SceneError', 'SimSample', 'Simulator', 'list_scenes', 'load_scene',
           'make_simulator']
