"""sim: run a learned velocity field on a MuJoCo arm in closed loop, perturb it, score it, film it.

The whole job in one call (``sim.pipeline``; ``lfd-demo-arm`` is its command line)::

    import sim
    report = sim.run_job(sim.ArmJob(robot="panda", learners=("contraction",), scenarios=("push",)))

Step by step::

    import lfd, sim
    from robots import load_robot

    demos = lfd.load_demos("spiral")
    field = lfd.train("contraction", demos)
    exp = sim.Experiment(load_robot("panda", actuation="torque"), demos)   # sim.RunSetup: placement, reach
    result = exp.run(field, "push")               # scenarios: sim.SCENARIOS
    print(result.metrics)                          # sim.metrics: tracking, imitation, recovery, ...
    exp.render(result, "push.mp4")

As a dm_env environment (for RL; gymnasium through ``shimmy.DmControlCompatibilityV0``)::

    env = sim.make_environment("panda", demos="spiral", learner_field=None, seed=0)
    ts = env.step(v)                               # v: task velocity, shape (d,)

The rest lives in its modules: ``sim.setup`` (a run's setup), ``sim.step`` (the control step), ``sim.env``.
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
    "ArmJob": "sim.pipeline", "run_job": "sim.pipeline",
    "SCENARIOS": "sim.experiment", "Experiment": "sim.experiment", "RunSetup": "sim.setup",
    "Placement": "sim.placement", "make_environment": "sim.env",
    "GoalShift": "sim.perturbations", "JointVelocityNoise": "sim.perturbations", "Push": "sim.perturbations",
    "StartOffset": "sim.perturbations",
}

TYPE_CHECKING = False
if TYPE_CHECKING:
    from sim.env import make_environment
    from sim.experiment import SCENARIOS, Experiment
    from sim.perturbations import GoalShift, JointVelocityNoise, Push, StartOffset
    from sim.pipeline import ArmJob, run_job
    from sim.placement import Placement
    from sim.setup import RunSetup


# ``import sim; sim.loop`` worked when this file imported its modules eagerly
__getattr__ = lazy_getattr("sim", _LAZY)


__all__ = [
    "ArmJob", "Experiment", "GoalShift", "JointVelocityNoise", "Placement", "Push", "RunSetup", "SCENARIOS",
    "SimError", "StartOffset", "make_environment", "run_job",
]
