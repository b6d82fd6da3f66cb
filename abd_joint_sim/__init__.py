"""abd_joint_sim: affine bodies joined by revolute joints, driven by joint torques (UID 668).

The physics core (this package minus `ros/` and `record/`) is pure numpy/scipy and never
imports rclpy. Start with `Scene.from_yaml(path)` and `World(scene)`.
"""
from .errors import SceneError, SimulationError
from .model import Model, compile_scene
from .scene import Scene
from .state import Control, State
from .world import StepReport, World

__all__ = ['Scene', 'World', 'Model', 'State', 'Control', 'StepReport', 'compile_scene',
           'SceneError', 'SimulationError']
