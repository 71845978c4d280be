"""sim: run a learned velocity field on a MuJoCo arm in closed loop, perturb it, score it, film it."""

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
