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

Lower level: ``Placement`` (task space -> robot), ``make_environment`` (the dm_control
Environment: Physics + ``FieldTrackingTask``), ``execute`` (the fast loop on that Environment),
``FieldController`` (twist -> IK -> actuators), the perturbations ``StartOffset``, ``Push``,
``GoalShift``, ``JointVelocityNoise``, and ``render_rollout``.
"""

from sim.gl import select_backend

select_backend()  # MUJOCO_GL must be set before mujoco (or dm_control) is imported

from sim.controller import ACTUATIONS, FieldController, Gains  # noqa: E402
from sim.errors import PlacementError, RenderError, SimError, SimulationError  # noqa: E402
from sim.experiment import SCENARIOS, Experiment, RunResult, scenario  # noqa: E402
from sim.metrics import recovery_time, run_metrics  # noqa: E402
from sim.perturbations import GoalShift, JointVelocityNoise, Perturbation, Push, StartOffset  # noqa: E402
from sim.placement import Placement  # noqa: E402
from sim.render import SceneRenderer, render_rollout, write_video  # noqa: E402
from sim.rollout import Rollout, execute  # noqa: E402
from sim.task import OBSERVATION_KEYS, ArmPhysics, FieldTrackingTask, make_environment  # noqa: E402

__all__ = [
    "ACTUATIONS", "ArmPhysics", "Experiment", "FieldController", "FieldTrackingTask", "Gains", "GoalShift",
    "JointVelocityNoise", "OBSERVATION_KEYS", "Perturbation", "Placement", "PlacementError", "Push",
    "RenderError", "Rollout", "RunResult", "SCENARIOS", "SceneRenderer", "SimError", "SimulationError",
    "StartOffset", "execute", "make_environment", "recovery_time", "render_rollout", "run_metrics",
    "scenario", "write_video",
]
