"""sim: run a learned velocity field on a MuJoCo arm in closed loop, perturb it, score it, film it.

    import lfd, sim
    from robots import load_robot

    demos = lfd.load_demos("spiral")
    field = lfd.train("contraction", demos)
    exp = sim.Experiment(load_robot("panda", actuation="torque"), demos)   # placement + reach check
    result = exp.run(field, "push")               # scenarios: sim.SCENARIOS
    print(result.metrics)                          # sim.metrics: tracking, imitation, recovery, ...
    exp.render(result, "push.mp4")

As a dm_env environment (for RL; gymnasium through ``shimmy.DmControlCompatibilityV0``, the
``gym`` extra), in one call:

    env = sim.make_environment("panda", demos="spiral", learner_field=None, seed=0)
    ts = env.reset()                               # observations: sim.OBSERVATION_KEYS
    ts = env.step(v)                               # v: task velocity, shape (d,)

The top level is what a user of the arm needs (12 names); the lower layer lives in its modules:
``sim.task`` (``ArmPhysics``, ``FieldTrackingTask``), ``sim.rollout`` (``execute``, the fast loop on
that Environment; ``Rollout``, ``Hold``), ``sim.controller`` (``FieldController``: twist -> IK ->
actuators; ``ACTUATIONS``, ``Gains``), ``sim.render`` (videos), ``sim.metrics`` (scores),
``sim.obstacles`` (obstacles as MuJoCo geoms, contacts), ``sim.errors`` (``SimError`` and its
subclasses ``PlacementError``, ``SimulationError``, ``RenderError``).
"""

from sim.gl import select_backend

select_backend()  # MUJOCO_GL must be set before mujoco (or dm_control) is imported

from sim.errors import SimError  # noqa: E402
from sim.experiment import SCENARIOS, Experiment, RunResult  # noqa: E402
from sim.perturbations import GoalShift, JointVelocityNoise, Push, StartOffset  # noqa: E402
from sim.placement import Placement  # noqa: E402
from sim.task import OBSERVATION_KEYS, make_environment  # noqa: E402

__all__ = [
    "Experiment", "GoalShift", "JointVelocityNoise", "OBSERVATION_KEYS", "Placement", "Push", "RunResult",
    "SCENARIOS", "SimError", "StartOffset", "make_environment",
]
