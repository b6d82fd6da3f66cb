"""Error and stability studies of abd_joint_sim (see docs/studies.md)."""
