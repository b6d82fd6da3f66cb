"""The joints of a scene that carry a term: what each term's `from_scene` selects."""
from __future__ import annotations

import numpy as np


def joints(scene, model, sliding: bool, has=None) -> np.ndarray:
    """(n,) int64 indices of the scene's prismatic (sliding) or revolute joints for which
    has(joint) holds (every one of them without `has`); `model.joint_slides` gives the type."""
    return np.array([k for k, j in enumerate(scene.joints)
                     if model.joint_slides[k] == sliding and (has is None or has(j))], np.int64)
