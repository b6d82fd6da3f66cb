"""abd_joint_sim: affine bodies joined by revolute joints, driven by joint torques (UID 668).

The physics core (this package minus `ros/` and `record/`) is numpy plus numba-compiled
kernels (docs/physics-code.md) and never imports rclpy. Start with `Scene.from_yaml(path)`
and `World(scene)`.
"""
from .jit import cache  # noqa: F401  (first: numba's cache locator must precede every kernel)
from .errors import SceneError, SimulationError
from .model import Model, compile_scene
from .scene import Scene
from .state import Control, State
from .world import Status, StepReport, World

__all__ = ['Scene', 'World', 'Model', 'State', 'Control', 'StepReport', 'Status', 'compile_scene',
           'SceneError', 'SimulationError']
