"""The controller a real arm runs, through libfranka against a simulated FR3 with the FCI's limits
enforced: the default spiral and a RoboTasks9 task, against our own simulation of the same job;
writes reports/franka.md. Run by ``scripts/franka_runs.py``.

For each job (tracking learner, 1 kHz): our simulation runs it on the torque-driven Panda in MuJoCo
through ``robots.controller.ArmController`` and its limiter (``--control-hz 1000 --limiter``), within
the limits ``STREAMED`` (the two arms' kinematics are the same). The
same controller, on the FR3's kinematics (franka-sim's own URDF in Pinocchio, with the Panda hand's
tool-centre point mounted on ``link7``: the two arms' tool kinematics then agree to round-off) and the
FR3's published limits with a third of its jerk (``STREAMED``), drives franka-sim's FR3 through pylibfranka's
joint-velocity interface (``robots.franka``), from the start configuration of our run, on the wall
clock (``stream_joint_velocities(wall_clock=True)``: franka-sim's physics keeps it). Reported: a
reflex (or none), the cycles and wall time, the FR3's tool path against our run's at the same times
and as paths (RMSE, m), the goal error, and the stream's peaks against the FR3's limits.
"""

from __future__ import annotations

import contextlib
import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
from scipy.spatial import cKDTree

import sim
from lfd.errors import LfdError
from lfd.io import atomic_write, check_writable
from robots import RobotError, load_robot
from robots.controller import ArmController
from robots.franka import (
    JOINT_NAMES,
    TOOL_FRAME,
    FrankaRecord,
    FrankaSimError,
    FrankaSimServer,
    franka_urdf,
    move_to,
    stream_joint_velocities,
)
from robots.kinematics import Kinematics
from robots.limits import FR3
from robots.pinocchio_arm import PinocchioArm, load_urdf_arm
from sim.errors import SimError
from sim.run.experiment import Experiment
from sim.run.parsing import OneLineParser, fail
from sim.run.plan import plan_job

__all__ = ["FrankaRun", "fr3_with_panda_hand", "main", "run_on_franka"]

PROG = "franka_runs"
PRELOAD = ("sim.run.pipeline",)
#: the jobs of the report: the default spiral and a recorded pour in full pose
JOBS: tuple[str, ...] = ("spiral", "robottasks:pouring")
#: the FR3's limits with a third of its jerk: where a command is lost, the FCI extrapolates it and the
#: next one's jerk by differences can reach three times the stream's own, which a host that misses
#: cycles (as this machine's franka-sim does) must leave room for
STREAMED = dataclasses.replace(FR3, name="fr3, a third of its jerk", dddq_max=FR3.dddq_max / 3.0)


@dataclass
class FrankaRun:
    """One job through franka-sim against our simulation (module docstring).

    Attributes
    ----------
    demos : str
    record : FrankaRecord
        The streamed motion (after the move to its start).
    tool_rmse_m : float
        The FR3's tool path against our run's at the same times, RMSE, m.
    path_rmse_m : float
        The FR3's tool path against our run's path, each point's distance to the nearest point of ours,
        RMSE, m (free of the time each took).
    goal_error_m, our_goal_error_m : float
        The FR3's and our run's final distance to the goal, m.
    command_limits : dict
        ``Limits.check`` of the whole stream sent, cycle after cycle, against the FR3's limits.
    """

    demos: str
    record: FrankaRecord
    tool_rmse_m: float
    path_rmse_m: float
    goal_error_m: float
    our_goal_error_m: float
    command_limits: dict[str, Any]


def fr3_with_panda_hand() -> PinocchioArm:
    """The FR3 of franka-sim's URDF with the Panda hand's tool-centre point on ``link7`` (module docstring)."""
    panda = load_robot("panda")
    model, data = panda.pin_model, panda.pin_model.createData()
    pin.framesForwardKinematics(model, data, panda.q_home)
    tool = data.oMf[model.getFrameId("panda_link7")].inverse() * data.oMf[model.getFrameId(panda.ee_frame)]
    return load_urdf_arm(franka_urdf(), TOOL_FRAME, joints=JOINT_NAMES, q_home=panda.q_home, name="fr3",
                         tool=tool.homogeneous)


def run_on_franka(demos: str, out: str, host: str | None = None) -> FrankaRun:
    """``demos``' job with the tracking learner in our simulation and through franka-sim (module
    docstring): on the server at ``host``, or on one started for it."""
    plan = plan_job(sim.ArmJob(demos=demos, learners=("tracking",), scenarios=("none",), control_hz=1000.0,
                               limiter=True, videos=False, plots=False, quiet=True, overwrite=True, out=out))
    field = plan.fields["tracking"]
    exp = Experiment(plan.exp.setup, control_hz=1000.0, limiter=True, limits=STREAMED)   # the same limits, ours too
    ours = exp.run(field, "none").trace
    arm = fr3_with_panda_hand()
    frame = exp.placement.task_frame(False, exp.setup.rotation_ref)
    dt = float(ours.t[1] - ours.t[0])
    ctl = ArmController(arm, frame, dt, limits=STREAMED)
    ctl.start(field.runner(ours.start_task, dt))
    with contextlib.ExitStack() as stack:
        if host is None:
            host = stack.enter_context(FrankaSimServer()).host
        start = move_to(host, ours.q[0])
        if start.error is not None:
            raise SimError(f"franka-sim refused the move to the start: {start.error}")
        record = stream_joint_velocities(host, ctl, exp.duration_s, wall_clock=True)
    kin = Kinematics(arm)
    steps = np.isfinite(record.t_control)   # the controller's cycles
    tool = np.array([kin.update_position(q).copy() for q in record.q[steps]])
    t = record.t_control[steps]
    ref = np.stack([np.interp(t, ours.t, ours.ee[:, i]) for i in range(3)], axis=1)
    goal = ours.goal_world
    nearest, _ = cKDTree(ours.ee).query(tool)
    return FrankaRun(demos, record, float(np.sqrt(np.mean(np.sum((tool - ref) ** 2, axis=1)))),
                     float(np.sqrt(np.mean(nearest ** 2))),
                     float(np.linalg.norm(kin.update_position(record.q[-1]) - goal)),
                     float(np.linalg.norm(ours.ee[-1] - goal)),
                     # the FCI judges every command, lead and stop included, one 1 ms cycle after the other
                     FR3.check(np.arange(record.cycles) * 1e-3, record.q, record.dq_cmd))


def _row(r: FrankaRun) -> str:
    rec, joint = r.record, r.command_limits["joint"]
    peaks = " / ".join(f"{joint[o]['peak']:.2f}" for o in ("velocity", "acceleration", "jerk"))
    over = r.command_limits["violations"]
    return (f"| {r.demos} | {rec.error or 'none'} | {rec.cycles} | {rec.wall_s:.2f} | {1e3 * r.tool_rmse_m:.2f} | "
            f"{1e3 * r.path_rmse_m:.2f} | "
            f"{1e3 * r.goal_error_m:.2f} | {1e3 * r.our_goal_error_m:.2f} | {peaks} | {over} |")


def main(argv: list[str] | None = None) -> int:
    """Run the jobs of ``JOBS`` (module docstring) and write the report; returns the exit code."""
    p = OneLineParser(prog=PROG, description=" ".join((__doc__ or "").split("\n\n")[0].split()))
    p.add_argument("--report", default="reports/franka.md", help="the report (default reports/franka.md)")
    args = p.parse_args(argv)
    report = Path(args.report)
    try:
        check_writable(report)
        rows = []
        for demos in JOBS:
            rows.append(_row(run_on_franka(demos, f"out/franka/{demos.replace(':', '_')}")))
            print(f"{demos}: done", flush=True)
    except (LfdError, SimError, RobotError, FrankaSimError, OSError) as e:
        return fail(PROG, str(e))
    text = "\n".join([
        "# Through libfranka: the controller on a simulated FR3 with the FCI's limits enforced", "",
        "Protocol: not a benchmark suite's; `python scripts/franka_runs.py` (sim.studies.franka), 2-core machine,",
        "franka-sim 1.1.7 with `--enforce-motion-limits` in `.venv-franka`, pylibfranka 0.21.3 in this process.",
        "Tracking learner, 1 kHz, `robots.controller.ArmController` with its limiter at 0.95 of the FR3's limits",
        "and a third of its jerk (a lost command, which franka-sim misses here, can triple the jerk the FCI sees);",
        "the FR3 carries the Panda hand's tool-centre point. Ours: the same job on the torque-driven Panda in",
        "MuJoCo (`--control-hz 1000 --limiter`). Tool RMSE: the FR3's tool path against ours at the same times.",
        "franka-sim's physics keeps wall-clock time while libfranka's clock counts its states, and this",
        "machine publishes fewer than 1000 a second (robots.franka.FrankaRecord): the cycles count states,",
        "and the controller runs on the wall clock (`stream_joint_velocities(wall_clock=True)`).", "",
        "| demos | reflex | cycles | wall s | tool RMSE to ours, same t, mm | path RMSE to ours mm | goal mm | "
        "our goal mm | command v / a / j peak (FR3) | command over |",
        "|---|---|---|---|---|---|---|---|---|---|", *rows, "",
        "The path RMSE is each FR3 tool point's distance to the nearest point of our run's path, free of",
        "the time each took; the same-time RMSE also carries the difference of the two clocks.", ""])
    atomic_write(report, lambda f: f.write(text.encode()))
    print(f"wrote {report}")
    return 0
