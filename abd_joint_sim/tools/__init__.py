"""Command-line tools around sim_node's bags, without DDS (see docs/replay.md).

* ``run_headless``: run a scene with a torque/enable schedule (a small YAML, or the commands
  of a recorded bag) as fast as possible and record the same bag sim_node records.
* ``replay_check``: re-simulate a bag's recorded commands with its stored scene and
  parameters and compare the joint states with the recorded ones.

Shared pieces: :mod:`.schedule` (commands over time: the schedule YAML), :mod:`.bagrun`
(a recorded bag as scene + parameters + commands + joint states), :mod:`.sim` (the
headless stepping loop, applying commands at step boundaries exactly as sim_node does, and
the recorder that writes sim_node's bag layout).
"""
