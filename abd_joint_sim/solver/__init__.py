"""The compiled step: `Solver` (solver.py) over the model's `ModelData` (model_data.py),
the step kernel (step.py: forces, bdf.py prediction, newton.py over the terms, velocities
and joint angles), the linear solve (linsolve.py) and the screw retraction (retraction.py).
"""
