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

from sim.gl import select_backend

select_backend()  # MUJOCO_GL must be set before mujoco (or dm_control) is imported

from sim.errors import SimError  # noqa: E402
from sim.experiment import SCENARIOS, Experiment, RunResult  # noqa: E402
from sim.perturbations import GoalShift, JointVelocityNoise, Push, StartOffset  # noqa: E402
from sim.pipeline import ArmJob, JobReport, PushSpec, run_job  # noqa: E402
from sim.placement import Placement  # noqa: E402
from sim.task import OBSERVATION_KEYS, make_environment  # noqa: E402

__all__ = [
    "ArmJob", "Experiment", "GoalShift", "JobReport", "JointVelocityNoise", "OBSERVATION_KEYS", "Placement",
    "Push", "PushSpec", "RunResult", "SCENARIOS", "SimError", "StartOffset", "make_environment", "run_job",
]
