"""sim: run a learned velocity field on a MuJoCo arm in closed loop, perturb it, score it, film it.

The whole job in one call (``sim.run.pipeline``; ``lfd-demo-arm`` is its command line)::

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

Its groups, top to bottom (docs/developing.md): ``sim.speed``, ``studies``, ``run``, ``media``, ``control``, ``scene``.
"""

from __future__ import annotations

from sim.media.gl import select_backend

select_backend()  # MUJOCO_GL must be set before mujoco (or dm_control) is imported

from lfd.lazy import lazy_getattr  # noqa: E402
from sim.errors import SimError  # noqa: E402

# The names below are imported on first use (PEP 562): ``import sim.run.cli`` (``lfd-demo-arm``) does not pay
# for mujoco and torch before its main has taken over Ctrl-C and SIGTERM (lfd.interrupts).
# public name -> the module that defines it
_LAZY: dict[str, str] = {
    "ArmJob": "sim.run.pipeline", "run_job": "sim.run.pipeline",
    "SCENARIOS": "sim.run.experiment", "Experiment": "sim.run.experiment", "RunSetup": "sim.scene.setup",
    "Placement": "sim.scene.placement", "make_environment": "sim.control.env",
    "GoalShift": "sim.scene.perturbations", "JointVelocityNoise": "sim.scene.perturbations",
    "Push": "sim.scene.perturbations", "StartOffset": "sim.scene.perturbations",
}

TYPE_CHECKING = False
if TYPE_CHECKING:
    from sim.control.env import make_environment
    from sim.run.experiment import SCENARIOS, Experiment
    from sim.run.pipeline import ArmJob, run_job
    from sim.scene.perturbations import GoalShift, JointVelocityNoise, Push, StartOffset
    from sim.scene.placement import Placement
    from sim.scene.setup import RunSetup


# and any submodule on first use: ``import sim; sim.metrics``, ``sim.control`` (whose own modules load alike)
__getattr__ = lazy_getattr("sim", _LAZY)


__all__ = [
    "ArmJob", "Experiment", "GoalShift", "JointVelocityNoise", "Placement", "Push", "RunSetup", "SCENARIOS",
    "SimError", "StartOffset", "make_environment", "run_job",
]
