"""sim: run a learned velocity field on a MuJoCo arm in closed loop, perturb it, score it, film it.

The whole job in one call (``sim.pipeline``; ``scripts/demo_arm.py`` is its command line)::

    import sim
    report = sim.run_job(sim.ArmJob(robot="panda", learners=("contraction",), scenarios=("push",)))

Step by step::

    import lfd, sim
    from robots import load_robot

    demos = lfd.load_demos("spiral")
    field = lfd.train("contraction", demos)
    exp = sim.Experiment(load_robot("panda", actuation="torque"), demos)   # placement + reach check
    result = exp.run(field, "push")               # scenarios: sim.SCENARIOS
    print(result.metrics)                          # sim.metrics: tracking, imitation, recovery, ...
    exp.render(result, "push.mp4")

As a dm_env environment (for RL; gymnasium through ``shimmy.DmControlCompatibilityV0``)::

    env = sim.make_environment("panda", demos="spiral", learner_field=None, seed=0)
    ts = env.step(v)                               # v: task velocity, shape (d,)

The top level is what a user of the arm needs (``__all__``); the lower layer lives in its modules:
``sim.task`` (``ArmPhysics``, ``FieldTrackingTask``), ``sim.env`` (``FieldEnvironment``, the dm_env
environment with the loop's lean step), ``sim.loop`` (the closed loop),
``sim.controller`` (twist -> IK -> actuators), ``sim.render`` (videos), ``sim.metrics`` (scores),
``sim.obstacles`` (obstacles as MuJoCo geoms, contacts), ``sim.collision`` (whole-arm collision
dampers in the IK, the hand margin), ``sim.errors`` (``SimError`` and its kinds).
"""

from __future__ import annotations

from sim.gl import select_backend

select_backend()  # MUJOCO_GL must be set before mujoco (or dm_control) is imported

from lfd.lazy import lazy_getattr  # noqa: E402
from sim.errors import SimError  # noqa: E402

# The names below are imported on first use (PEP 562): ``import sim.cli`` (``lfd-demo-arm``) does not pay
# for mujoco and torch before its main has taken over Ctrl-C and SIGTERM (lfd.interrupts).
# public name -> the module that defines it
_LAZY: dict[str, str] = {
    "SCENARIOS": "sim.experiment", "Experiment": "sim.experiment", "RunResult": "sim.experiment",
    "GoalShift": "sim.perturbations", "JointVelocityNoise": "sim.perturbations", "Push": "sim.perturbations",
    "StartOffset": "sim.perturbations",
    "ArmJob": "sim.pipeline", "JobReport": "sim.pipeline", "PushSpec": "sim.pipeline", "run_job": "sim.pipeline",
    "Placement": "sim.placement",
    "OBSERVATION_KEYS": "sim.task", "make_environment": "sim.task",
}

TYPE_CHECKING = False
if TYPE_CHECKING:
    from sim.experiment import SCENARIOS, Experiment, RunResult
    from sim.perturbations import GoalShift, JointVelocityNoise, Push, StartOffset
    from sim.pipeline import ArmJob, JobReport, PushSpec, run_job
    from sim.placement import Placement
    from sim.task import OBSERVATION_KEYS, make_environment


# ``import sim; sim.loop`` worked when this file imported its modules eagerly
__getattr__ = lazy_getattr("sim", _LAZY)


__all__ = [
    "ArmJob", "Experiment", "GoalShift", "JobReport", "JointVelocityNoise", "OBSERVATION_KEYS", "Placement",
    "Push", "PushSpec", "RunResult", "SCENARIOS", "SimError", "StartOffset", "make_environment", "run_job",
]
