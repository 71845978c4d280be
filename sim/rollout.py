"""The closed loop, run fast on the Environment's own Physics and Task.

Every control step k (t_k = k dt):

1. read q, qdot of the arm joints from MuJoCo;
2. p = FK(q) with Pinocchio (``controller.measure``);
3. v = f(x - dg) with x = A^T (p - o) / s the MEASURED tool position in task space
   (dg: a goal shift, see ``sim.perturbations``);
4. qdot_ref = IK(q, twist(v)) and the actuator command (``FieldTrackingTask.apply``);
5. the step's perturbations (push, joint-velocity noise);
6. ``mujoco.mj_step`` on ``physics.model.ptr`` / ``physics.data.ptr`` (no dm_control wrapper);
   a NaN/unstable state or a bad control (MuJoCo warnings mjWARN_BADQPOS/QVEL/QACC/CTRL)
   raises ``SimulationError``.

States are recorded at every control step; full ``qpos`` at the video frame times only.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import mujoco
import numpy as np
from dm_control.rl import control
from tqdm import tqdm

from sim.errors import SimulationError
from sim.render import FPS, frame_times
from sim.task import FieldTrackingTask

_DIVERGENCE = (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
               mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADCTRL)


@dataclass
class Rollout:
    """One closed-loop run.

    t : (K+1,) s; ee : (K+1, 3) measured tool positions (world, m); q : (K+1, n) joint positions;
    frame_t : (F,) video frame times; frame_qpos : (F, nq) MuJoCo qpos at those times;
    step_time_s : (K,) wall time of each control step (controller + perturbations + physics);
    wall_s : the loop's wall time; start_task, goal_task : (d,) actual start and (shifted) goal,
    task units; goal_world : (3,); push_window_s : (t0, t1) or None; push_force : (3,) N or None;
    push_body : MuJoCo body id (-1: none); ik_limit_hits : IK solves that clamped to a limit;
    joint_limit_violations : control steps with an arm joint outside [q_min, q_max] in MuJoCo.
    """

    t: np.ndarray
    ee: np.ndarray
    q: np.ndarray
    frame_t: np.ndarray
    frame_qpos: np.ndarray
    step_time_s: np.ndarray
    wall_s: float
    start_task: np.ndarray
    goal_task: np.ndarray
    goal_world: np.ndarray
    push_window_s: tuple[float, float] | None
    push_force: np.ndarray | None
    push_body: int
    ik_limit_hits: int
    joint_limit_violations: int

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall-clock second of the loop."""
        return float(self.t[-1] - self.t[0]) / self.wall_s

    @property
    def control_step_us(self) -> float:
        """Median wall time of one control step, microseconds."""
        return float(np.median(self.step_time_s) * 1e6)


def execute(env: control.Environment, field_fn: Callable[[np.ndarray], np.ndarray],
            fps: float = FPS, progress: bool = False, desc: str = "rollout") -> Rollout:
    """Reset ``env`` and run one episode with the velocity field ``field_fn`` : x (d,) -> v (d,)
    (task units), evaluated at the measured tool position every control step."""
    task: FieldTrackingTask = env.task
    physics = env.physics
    env.reset()
    m, d = physics.model.ptr, physics.data.ptr
    n_sub = int(round(task.control_dt / m.opt.timestep))
    ctl = task.controller
    robot = task.robot
    qadr, dadr = robot.mj_qpos_adr, robot.mj_dof_adr
    K, dt = task.n_steps, task.control_dt
    shift = task.schedule.goal_offset_task
    shifted = bool(np.any(shift != 0))
    ftimes = frame_times(K * dt, fps)
    fsteps = np.minimum(np.round(ftimes / dt).astype(int), K)
    Q = np.empty((K + 1, robot.n))
    P = np.empty((K + 1, 3))
    FQ = np.empty((len(fsteps), m.nq))
    steps = np.empty(K)
    warn = d.warning.number
    bad = [int(w) for w in _DIVERGENCE]
    hits0 = getattr(ctl.ik, "limit_hits", 0)
    messages: list[str] = []
    prev_handler = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(messages.append)
    j, next_frame = 0, int(fsteps[0])
    bar = tqdm(total=K, desc=desc, disable=not progress, unit="step", leave=False, mininterval=0.5)
    clock = time.perf_counter
    try:
        start = clock()
        for k in range(K):
            t0 = clock()
            q = d.qpos[qadr]
            p = ctl.measure(q)
            Q[k] = q
            P[k] = p
            if k == next_frame:
                FQ[j] = d.qpos
                j += 1
                next_frame = int(fsteps[j]) if j < len(fsteps) else -1
            x = ctl.to_task(p)
            task.apply(d, q, d.qvel[dadr], field_fn(x - shift) if shifted else field_fn(x))
            mujoco.mj_step(m, d, n_sub)
            if warn[bad[0]] or warn[bad[1]] or warn[bad[2]] or warn[bad[3]]:
                raise SimulationError(_divergence_message(d, k, dt, bad))
            steps[k] = clock() - t0
            if k % 250 == 249:
                bar.update(250)
        wall = clock() - start
    finally:
        mujoco.set_mju_user_warning(prev_handler)
        bar.close()
    q = d.qpos[qadr]
    Q[K] = q
    P[K] = ctl.measure(q)
    if j < len(fsteps):
        FQ[j:] = d.qpos
    if not (np.isfinite(Q).all() and np.isfinite(P).all()):
        raise SimulationError("simulation diverged: NaN in the joint state; no output written")
    violations = int(np.count_nonzero(np.any((Q < robot.q_min) | (Q > robot.q_max), axis=1)))
    s = task.schedule
    return Rollout(
        t=np.arange(K + 1) * dt, ee=P, q=Q, frame_t=ftimes, frame_qpos=FQ, step_time_s=steps,
        wall_s=wall, start_task=task.start_task.copy(), goal_task=task.goal_task.copy(),
        goal_world=task.goal_world.copy(), push_window_s=s.push_window_s,
        push_force=None if s.push_force is None else s.push_force[:3].copy(), push_body=s.push_body,
        ik_limit_hits=int(getattr(ctl.ik, "limit_hits", 0) - hits0), joint_limit_violations=violations)


def _divergence_message(d: mujoco.MjData, k: int, dt: float, bad: list[int]) -> str:
    which = [i for i in bad if d.warning[i].number]
    text = "; ".join(mujoco.mju_warningText(i, int(d.warning[i].lastinfo)).strip().rstrip(".")
                     for i in which)
    return f"simulation diverged at t = {(k + 1) * dt:.3f} s ({text}); no output written"
