"""The closed loop, run fast on the Environment's own Physics and Task: the task's control step
(``sim.control.step.ControlStep``: measure, field, IK with its safety rows, command, physics) K times,
with the field's runner (``lfd.runner``: it carries a phase or the time itself), recording each step.

Each control step records q, qdot (as read before the command), the tool position p (and a pose
task's rotation), the command v and the force that ``xfrc_applied`` holds on the push body after
the step's perturbations (``RunTrace``); the full ``qpos`` only at the video frame times. A
NaN/unstable state or a bad control (mjWARN_BADQPOS/QVEL/QACC/CTRL) raises ``SimulationError``.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
from dm_control.rl import control
from tqdm import tqdm

from lfd.runner import Runner
from sim.control.step import contiguous
from sim.control.task import FieldTrackingTask
from sim.errors import SimulationError

FPS = 30.0  # default rate (frames per simulated second) at which a run keeps the full qpos for video


def frame_times(duration_s: float, fps: float = FPS) -> np.ndarray:
    """t_k = k / fps for k = 0 .. floor(duration fps), shape (K,)."""
    return np.arange(int(math.floor(duration_s * fps + 1e-9)) + 1) / fps


_DIVERGENCE = (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
               mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADCTRL)


@dataclass
class RunTrace:
    """One closed-loop run (K control steps, n arm joints, d task dimensions, F video frames).

    Attributes
    ----------
    t : ndarray, shape (K+1,)
        Time of each control step, s.
    ee : ndarray, shape (K+1, 3)
        Measured tool positions, world, m.
    q, qdot : ndarray, shape (K+1, n)
        Joint positions and velocities, read from MuJoCo by the loop at each step (qdot before
        any joint-velocity noise of that step).
    command : ndarray, shape (K+1, d)
        The field's command v = f(x - dg) the loop fed the controller at each step, task units per
        second (the last row: the field at the final state, which no step follows).
    applied_force : ndarray, shape (K+1, 3)
        The external force, world, N, that ``xfrc_applied`` held on the push body during step k
        (read back by the loop after the step's perturbations; zero without a push and in the
        last row).
    frame_t, frame_qpos : ndarray, shape (F,) and (F, nq)
        Video frame times and MuJoCo's full qpos at those times.
    step_time_s : ndarray, shape (K,)
        Wall time of each control step (controller + perturbations + physics), s.
    wall_s : float
        The loop's wall time, s.
    start_task, goal_task : ndarray, shape (d,)
        Actual start and (shifted) goal, task units.
    goal_world : ndarray, shape (3,)
    push_window_s : (t0, t1) or None
    push_force : ndarray, shape (3,), or None
        The push's force vector, N (``applied_force`` holds it step by step).
    push_body : int
        MuJoCo body id of the push (-1: none).
    ik_limit_hits : int
        IK solves that clamped to a limit.
    joint_limit_violations : int
        Control steps with an arm joint outside [q_min, q_max] in MuJoCo.
    phase : ndarray, shape (K+1,), or None
        The phase s of the field's runner at each step (a field with a phase, ``lfd.runner``).
    hold_window_s : (t0, t1) or None
    cpu_s : float or None
        The loop's CPU time (this thread; ``time.thread_time``), which machine load does not inflate.
    mocap_pos : ndarray, shape (K+1, nmocap, 3), or None
        Where the mocap bodies (moving obstacles, ``sim.scene.obstacles.mocap_path``) were at each step, m;
        ``frame_mocap`` gives them at the video frames.
    ee_rot : ndarray, shape (K+1, 3, 3), or None
        A pose task's measured tool rotations, world (None for a position task).
    arm_clearance_m : ndarray, shape (K+1,), or None
        With whole-arm clearance (``sim.scene.collision``): the smallest distance between an arm geom and
        the scene or the arm itself that the step's dampers saw, m (inf: nothing within their
        influence distance; the last row: inf). None without it.
    guard_active : ndarray of bool, shape (K+1,), or None
        Steps at which a damper held the IK at its bound.
    joint_command, ik_command : ndarray, shape (K+1, n), or None
        With an ``ArmController`` (``FieldTrackingTask.limiter``): the joint-velocity command stream
        the arm was sent and the IK's joint velocity the limiter took as its target, rad/s (the last
        row zero: no step follows). None otherwise.
    """

    @property
    def limiter_acted(self) -> np.ndarray | None:
        """Steps at which the limiter changed the IK's command (by more than 1e-9 rad/s), shape (K+1,)
        of bool, or None without a limiter."""
        if self.joint_command is None or self.ik_command is None:
            return None
        return np.abs(self.joint_command - self.ik_command).max(axis=1) > 1e-9

    t: np.ndarray
    ee: np.ndarray
    q: np.ndarray
    qdot: np.ndarray
    command: np.ndarray
    applied_force: np.ndarray
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
    phase: np.ndarray | None = None
    hold_window_s: tuple[float, float] | None = None
    cpu_s: float | None = None
    mocap_pos: np.ndarray | None = None
    ee_rot: np.ndarray | None = None
    arm_clearance_m: np.ndarray | None = None
    guard_active: np.ndarray | None = None
    joint_command: np.ndarray | None = None
    ik_command: np.ndarray | None = None

    def steps_at(self, times: np.ndarray) -> np.ndarray:
        """Index, shape (F,), of the control step nearest each of ``times`` (F,), s (the last step
        for times after the run)."""
        dt = float(self.t[1] - self.t[0])
        return np.minimum(np.round(np.asarray(times) / dt).astype(int), len(self.t) - 1)

    @property
    def frame_mocap(self) -> np.ndarray | None:
        """The mocap bodies' positions at the video frames, shape (F, nmocap, 3), or None."""
        return None if self.mocap_pos is None else self.mocap_pos[self.steps_at(self.frame_t)]

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall-clock second of the loop."""
        return float(self.t[-1] - self.t[0]) / self.wall_s

    @property
    def control_step_us(self) -> float:
        """Median wall time of one control step, microseconds."""
        return float(np.median(self.step_time_s) * 1e6)


def execute(env: control.Environment, runner: Runner, fps: float = FPS, progress: bool = False,
            desc: str = "run") -> RunTrace:
    """Reset ``env`` and run one episode (module docstring) with a field's runner.

    Parameters
    ----------
    env : dm_control Environment
        From ``sim.make_environment`` (its task a ``FieldTrackingTask``).
    runner : lfd.runner.Runner
        ``field.runner(start, dt)``: called at the measured task point (goal-shifted) and the time
        t_k = k dt every control step; a phase it carries is recorded (``RunTrace.phase``).
    fps : float
        Rate at which the full qpos is kept for video, frames per simulated second.
    progress, desc : a progress bar and its label.

    Returns
    -------
    RunTrace
        The recorded run; ``SimulationError`` if the simulation diverged.
    """
    task: FieldTrackingTask = env.task
    env.reset()
    m, d = env.physics.model.ptr, env.physics.data.ptr
    rec = _Record.allocate(task.n_steps, task.control_dt, task.robot.n, m.nq, task.placement.dim, fps,
                           task.placement.pose, task.controller.guard is not None, task.arm is not None)
    hits0 = getattr(task.controller.ik, "limit_hits", 0)
    messages: list[str] = []
    prev_handler = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(messages.append)
    bar = tqdm(total=task.n_steps, desc=desc, disable=not progress, unit="step", leave=False, mininterval=0.5)
    try:
        wall, cpu, j = _loop(task, m, d, runner, rec, bar)
    finally:
        mujoco.set_mju_user_warning(prev_handler)
        bar.close()
    if messages:  # MuJoCo's other warnings (e.g. too many contacts): said once, not swallowed
        warnings.warn(f"MuJoCo warned {len(messages)} time(s) during the run: {messages[0].strip()}",
                      RuntimeWarning, stacklevel=2)
    _record_final(task, d, runner, rec, j)
    return _to_trace(rec, task, runner, wall, cpu, int(getattr(task.controller.ik, "limit_hits", 0) - hits0))


def _loop(task: FieldTrackingTask, m: mujoco.MjModel, d: mujoco.MjData, runner: Runner, rec: _Record,
          bar: Any) -> tuple[float, float, int]:
    """The K control steps of ``execute``, written into ``rec``. Returns (wall s, CPU s, video frames written)."""
    step, ctl = task.step, task.controller
    begin, command, end = step.begin_at_point, step.command, step.end
    K, dt, dadr = task.n_steps, task.control_dt, task.robot.mj_dof_adr
    fsteps, Q, Qd, P, V, F, FQ, steps = rec.frame_steps, rec.q, rec.qdot, rec.ee, rec.command, rec.force, \
        rec.frame_qpos, rec.step_s
    ROT = rec.rot   # a pose task's tool rotations (None otherwise)
    guard, CLR, GA = ctl.guard, rec.clearance, rec.guarded   # whole-arm clearance (None without it)
    arm, CMD, IKC = task.arm, rec.joint_command, rec.ik_command   # the joint-velocity stream (None without it)
    warn, bad = d.warning.number, [int(w) for w in _DIVERGENCE]
    # the divergence counters as one view when they are consecutive (one bytes compare a step)
    b0 = min(bad)
    bad_view = warn[b0:b0 + len(bad)] if sorted(bad) == list(range(b0, b0 + len(bad))) else None
    no_warning = bytes(0 if bad_view is None else bad_view.nbytes)
    j, next_frame = 0, int(fsteps[0])
    clock = time.perf_counter
    qpos, qvel = d.qpos, d.qvel   # one view each for the whole loop (each attribute access builds a new one)
    qvel_arm = contiguous(qvel, dadr)   # the arm's qvel as one view when its dofs are contiguous
    push_body = task.schedule.push_body
    force = d.xfrc_applied[max(push_body, 0), :3]   # the push body's applied force (a view)
    cpu0 = time.thread_time()
    start = clock()
    for k in range(K):
        t0 = clock()
        x = begin()
        P[k] = step.p
        Q[k] = step.q
        Qd[k] = qvel[dadr] if qvel_arm is None else qvel_arm
        if k == next_frame:
            FQ[j] = qpos
            j += 1
            next_frame = int(fsteps[j]) if j < len(fsteps) else -1
        if ROT is not None:
            ROT[k] = step.measured_rotation()
        v = V[k] = runner(x, k * dt)
        command(v)
        if guard is not None and CLR is not None and GA is not None:
            CLR[k] = guard.min_distance
            GA[k] = ctl.guard_active if arm is None else arm.guarded
        if push_body >= 0:
            F[k] = force
        if arm is not None and CMD is not None and IKC is not None:
            CMD[k] = arm.dq_cmd
            IKC[k] = arm.dq_ik
        end()
        if (bad_view.tobytes() != no_warning if bad_view is not None else
                warn[bad[0]] or warn[bad[1]] or warn[bad[2]] or warn[bad[3]]):
            raise SimulationError(_divergence_message(d, k, dt, bad))
        steps[k] = clock() - t0
        if k % 250 == 249:
            bar.update(250)
    return clock() - start, time.thread_time() - cpu0, j


def _record_final(task: FieldTrackingTask, d: mujoco.MjData, runner: Runner, rec: _Record, j: int) -> None:
    """Row K of the record: the state after the last step, the field's command there (the runner
    not advanced), and the frames not reached."""
    ctl, K = task.controller, task.n_steps
    q = d.qpos[task.robot.mj_qpos_adr]
    rec.q[K] = q
    rec.qdot[K] = d.qvel[task.robot.mj_dof_adr]
    rec.ee[K] = ctl.measure(q)
    x = ctl.to_task(rec.ee[K]) - task.schedule.goal_offset_task
    if rec.rot is not None:
        rec.rot[K] = ctl.measured_rotation()
    if not np.isfinite(x).all():   # diverged: _to_trace raises SimulationError
        rec.command[K] = np.nan
    else:
        rec.command[K] = runner.peek(x, K * task.control_dt)
    if j < len(rec.frame_steps):
        rec.frame_qpos[j:] = d.qpos


@dataclass
class _Record:
    """What the loop writes: q, qdot (K+1, n), ee (K+1, 3), command (K+1, d), force (K+1, 3),
    step_s (K,), and the full qpos frame_qpos (F, nq) at the video frame times frame_t (F,), i.e. at
    control steps frame_steps (F,); a pose task's tool rotations rot (K+1, 3, 3); with an
    ``ArmController`` its commands joint_command and the IK's ik_command (K+1, n) (last row zero)."""

    q: np.ndarray
    qdot: np.ndarray
    ee: np.ndarray
    command: np.ndarray
    force: np.ndarray
    step_s: np.ndarray
    frame_t: np.ndarray
    frame_steps: np.ndarray
    frame_qpos: np.ndarray
    rot: np.ndarray | None = None
    clearance: np.ndarray | None = None
    guarded: np.ndarray | None = None
    joint_command: np.ndarray | None = None
    ik_command: np.ndarray | None = None

    @classmethod
    def allocate(cls, K: int, dt: float, n: int, nq: int, dim: int, fps: float, pose: bool = False,
                 guard: bool = False, stream: bool = False) -> _Record:
        ftimes = frame_times(K * dt, fps)
        fsteps = np.minimum(np.round(ftimes / dt).astype(int), K)
        return cls(np.empty((K + 1, n)), np.empty((K + 1, n)), np.empty((K + 1, 3)), np.empty((K + 1, dim)),
                   np.zeros((K + 1, 3)), np.empty(K), ftimes, fsteps, np.empty((len(fsteps), nq)),
                   np.empty((K + 1, 3, 3)) if pose else None,
                   np.full(K + 1, np.inf) if guard else None, np.zeros(K + 1, dtype=bool) if guard else None,
                   np.zeros((K + 1, n)) if stream else None, np.zeros((K + 1, n)) if stream else None)


def _to_trace(rec: _Record, task: FieldTrackingTask, runner: Runner, wall: float, cpu: float,
              ik_limit_hits: int) -> RunTrace:
    """The RunTrace of a finished loop (``SimulationError`` if its state went non-finite)."""
    robot, K, dt = task.robot, task.n_steps, task.control_dt
    if not (np.isfinite(rec.q).all() and np.isfinite(rec.qdot).all() and np.isfinite(rec.ee).all()):
        raise SimulationError("simulation diverged: NaN in the joint state; no output written")
    violations = int(np.count_nonzero(np.any((rec.q < robot.q_min) | (rec.q > robot.q_max), axis=1)))
    s = task.schedule
    phase = runner.phases()
    return RunTrace(
        t=np.arange(K + 1) * dt, ee=rec.ee, q=rec.q, qdot=rec.qdot, command=rec.command, applied_force=rec.force,
        frame_t=rec.frame_t, frame_qpos=rec.frame_qpos,
        step_time_s=rec.step_s, wall_s=wall, start_task=task.start_task.copy(), goal_task=task.goal_task.copy(),
        goal_world=task.goal_world.copy(), push_window_s=s.push_window_s,
        push_force=None if s.push_force is None else s.push_force[:3].copy(), push_body=s.push_body,
        ik_limit_hits=ik_limit_hits, joint_limit_violations=violations,
        phase=phase, hold_window_s=s.hold_window_s, cpu_s=cpu, mocap_pos=s.mocap_pos, ee_rot=rec.rot,
        arm_clearance_m=rec.clearance, guard_active=rec.guarded, joint_command=rec.joint_command,
        ik_command=rec.ik_command)


def _divergence_message(d: mujoco.MjData, k: int, dt: float, bad: list[int]) -> str:
    which = [i for i in bad if d.warning[i].number]
    text = "; ".join(mujoco.mju_warningText(i, int(d.warning[i].lastinfo)).strip().rstrip(".")
                     for i in which)
    return f"simulation diverged at t = {(k + 1) * dt:.3f} s ({text}); no output written"
