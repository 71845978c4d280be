"""A task with objects as a dm_env environment: the scene built around the arm, the object where the user
puts it and the goal with it (``sim.run.tasks``), the reward the task's success predicate, the episode
ended on success (``sim.control.object_task``).

    env = make_task_environment("pour", field, target=(0.45, -0.35))
    ts = env.reset()
    while not ts.last():
        ts = env.step(ts.observation["field_velocity"])     # the learned motion; ts.reward: 1.0 on success
"""

from __future__ import annotations

from collections.abc import Sequence

from lfd.demos import DemoSet, load_demos
from lfd.errors import ConfigError
from lfd.field import Field
from robots import load_robot
from sim.control.env import FieldEnvironment, make_environment
from sim.run.tasks import TASK_DEMOS, TASKS, plan_task, shifted
from sim.scene.collision import Clearance
from sim.scene.perturbations import Perturbation
from sim.scene.setup import RunSetup


def make_task_environment(task: str, learner_field: Field | None = None, *, demos: str | DemoSet | None = None,
                          target: Sequence[float] | None = None, robot: str = "panda",
                          perturbations: Sequence[Perturbation] = (), seed: int | None = None,
                          start_radius: float = 0.0, control_hz: float = 500.0,
                          duration_s: float | None = None) -> FieldEnvironment:
    """The dm_env environment of ``task`` (module docstring).

    Parameters
    ----------
    task : str
        ``pour``, ``place`` or ``lid`` (``sim.run.tasks.TASKS``; the lid's box runs where its demos do,
        ``sim.run.tasks.shifted``).
    learner_field : Field, optional
        The learned motion (trained on ``demos``): the ``field_velocity`` observation, moved to the
        task's goal (``Field.toward``).
    demos : str or DemoSet, optional
        The task's demos (default its RoboTasks9 ones, ``sim.run.tasks.TASK_DEMOS``): where it runs.
    target : sequence of float, optional
        X, Y[, Z]: where the object stands, m, the robot's base frame (default its nominal place).
    robot : str
        A built-in arm, torque-driven, on a table.
    perturbations, seed, start_radius, control_hz, duration_s : as ``sim.make_environment``.

    Returns
    -------
    FieldEnvironment
        Its reward is 1.0 where the task's predicate holds, 0.0 elsewhere; the first such step is LAST.
    """
    if task not in TASKS:
        raise ConfigError(f"unknown task '{task}'; known: {', '.join(TASKS)}")
    demo_set = load_demos(demos or TASK_DEMOS[task]) if not isinstance(demos, DemoSet) else demos
    planned = plan_task(task, demo_set, None if target is None else tuple(float(v) for v in target))
    planned, shift = shifted(planned, demo_set.name, None)
    arm = planned.with_scene(load_robot(robot, demo_set.frame if demo_set.has_orientation else None,
                                        actuation="torque", table=True))
    goal = tuple(float(v) for v in planned.goal)
    setup = RunSetup.resolve(arm, demo_set, goal=goal, shift=shift)
    planned = planned.timed(float(setup.demo_t[-1]))   # the release and the judging follow the run's demo
    field = None if learner_field is None else learner_field.toward(planned.goal)
    return make_environment(setup, learner_field=field, perturbations=(*perturbations, *planned.events()),
                            clearance=Clearance(), on_reset=planned.on_reset(arm), seed=seed,
                            start_radius=start_radius, control_hz=control_hz, duration_s=duration_s,
                            success=planned.check(arm.mj_model, arm))
