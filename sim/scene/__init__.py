"""The scene and what is in it: where the task lies on the robot, the obstacles, the arm's clearance
from them, the perturbations of a run, and a run's setup resolved from all of these.

- ``sim.scene.placement``: the task space on the robot (``Placement``), reach and the start pose;
- ``sim.scene.obstacles``: task-space obstacles as MuJoCo geoms, and the arm's contacts with them;
- ``sim.scene.collision``: whole-arm clearance, velocity dampers for the IK (compiled in
  ``sim.scene._collision_kernel``);
- ``sim.scene.perturbations``: pushes, start offsets, goal shifts, joint-velocity noise;
- ``sim.scene.setup``: ``RunSetup``, the scene, placement, start, goal and obstacles of one run.

The lowest group of ``sim``: it imports no other group (pyproject.toml's import contracts).
"""
