"""Closing the loop: the command of one control step, the step itself, the dm_control task and
environment, and the loop that runs it fast.

- ``sim.control.controller``: task velocity -> twist -> differential IK -> actuator command
  (``FieldController``; compiled in ``sim.control._control_kernel``, its parameter layout in
  ``sim.control._kernel_layout``);
- ``sim.control.step``: the control step once (``ControlStep``: measure, command, perturb, advance);
- ``sim.control.task``: the dm_control Physics and Task (``ArmPhysics``, ``FieldTrackingTask``);
- ``sim.control.env``: the dm_env environment (``make_environment``, ``FieldEnvironment``);
- ``sim.control.loop``: the closed loop, run and recorded (``execute``, ``RunTrace``).

Above ``sim.scene``, below ``sim.media`` and ``sim.run`` (pyproject.toml's import contracts).
"""
