"""The control loop's step timed stage by stage, and against the dm_env step, for ``sim.speed.loop``
and ``sim.speed.ik``.

The one module of ``sim.speed`` that reaches into the loop's internals: the task's control step
(``sim.control.step.ControlStep``: ``begin``, ``field_point``, ``command``, ``end``, as ``sim.control.loop`` calls
it), the dm_env environment of an experiment (``Experiment.environment``) and the controller's IK
(``sim.control.controller.FieldController``). When the step changes, these change with it.

- ``breakdown``: per-stage wall times of the loop's step;
- ``env_steps``: the dm_env ``Environment.step`` of the same run, timed step by step;
- ``interleaved_steps``: that step against the loop's step (with the loop's recording), in short
  alternating blocks on two copies of the model;
- ``replay_ik``: one IK back-end's ``solve`` on the states of a recorded rollout.
"""

from __future__ import annotations

import time
from typing import Any

import mujoco
import numpy as np

import sim
from lfd.field import Field
from sim.control.controller import FieldController
from sim.control.task import ArmPhysics

__all__ = ["STAGES", "breakdown", "env_steps", "interleaved_steps", "replay_ik"]

STAGES = ("begin: mj_step1, q, tool pose", "field f(x)", "command: twist, IK, actuators", "end: mj_step2")
#: the MuJoCo warnings that mean the simulation diverged (those ``sim.control.loop`` checks)
DIVERGENCE = tuple(int(w) for w in (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
                                    mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADCTRL))


def breakdown(exp: sim.Experiment, field: Field, steps: int) -> dict[str, np.ndarray]:
    """Per-stage wall times of ``steps`` control steps of the loop (``sim.control.loop``'s calls of the task's
    ``ControlStep`` and the field's runner, timed one by one; "field f(x)" includes the task point
    x), shape (steps,) each, by stage name (``STAGES``)."""
    env = exp.environment()
    env.reset()
    task = env.task
    step, dt = task.step, task.control_dt
    runner = field.runner(task.start_task, dt)
    steps = min(steps, task.n_steps)
    t = {k: np.empty(steps) for k in STAGES}
    clock = time.perf_counter
    for k in range(steps):
        c0 = clock()
        step.begin()
        c1 = clock()
        v = runner(step.field_point(), k * dt)
        c2 = clock()
        step.command(v)
        c3 = clock()
        step.end()
        c4 = clock()
        for name, a, b in zip(STAGES, (c0, c1, c2, c3), (c1, c2, c3, c4)):
            t[name][k] = b - a
    return t


def env_steps(env: Any, field: Field, steps: int) -> tuple[np.ndarray, float]:
    """Wall time of dm_env ``Environment.step`` with the field as policy, shape (steps,), from a reset
    (untimed), at most one episode (a step past its end would time a reset), and the CPU time of
    all of them (``time.thread_time``, as ``RunTrace.cpu_s`` for the loop).

    The policy feeds the field's runner the observed ``task_position``, the point the loop feeds it
    (the environment computes it for the observation, as the loop does for the field); each timed
    call covers the field and the step, as the loop's step does.
    """
    ts = env.reset()
    dt = env.task.control_dt
    runner = field.runner(env.task.start_task, dt)
    out = np.empty(min(steps, env.task.n_steps))
    clock = time.perf_counter
    cpu0 = time.thread_time()
    for k in range(len(out)):
        t0 = clock()
        ts = env.step(runner(ts.observation["task_position"], k * dt))
        out[k] = clock() - t0
    return out, time.thread_time() - cpu0


def interleaved_steps(exp: sim.Experiment, field: Field, blocks: int,
                      block: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """Wall times of dm_env ``Environment.step`` (policy as ``env_steps``) and of the loop's step
    (the calls of ``sim.control.loop``'s loop, recording q, qdot, p and v as it does), in ``blocks`` pairs of
    ``block`` steps each, alternating, on two copies of the model: short blocks, so that load on the
    machine hits both alike, each warm in its block (alternating every step would leave both cold,
    which flatters the environment). Returns each one's per-block medians, shape (blocks,). Episodes
    restart as needed (untimed)."""
    env, twin = (sim.make_environment(exp.setup, physics=ArmPhysics.from_robot(exp.robot), **exp.options)
                 for _ in range(2))
    task, clock = twin.task, time.perf_counter
    step, dt, dadr, n = task.step, task.control_dt, exp.robot.mj_dof_adr, exp.robot.n
    K = task.n_steps
    Q, Qd, P, V = np.empty((K, n)), np.empty((K, n)), np.empty((K, 3)), np.empty((K, exp.placement.dim))
    t_env, t_loop, out = np.empty(blocks), np.empty(blocks), np.empty(block)
    w0, w1, w2, w3 = DIVERGENCE
    ts, k_env = env.reset(), 0
    r_env = field.runner(env.task.start_task, dt)
    k = K
    for b in range(blocks):
        if k_env + block >= K:   # a new episode (untimed)
            ts, k_env = env.reset(), 0
            r_env = field.runner(env.task.start_task, dt)
        for i in range(block):
            t0 = clock()
            ts = env.step(r_env(ts.observation["task_position"], (k_env + i) * dt))
            out[i] = clock() - t0
        k_env += block
        t_env[b] = np.median(out)
        if k + block >= K:
            twin.reset()
            r_loop, k = field.runner(task.start_task, dt), 0
            qvel, warn = twin.physics.data.ptr.qvel, twin.physics.data.ptr.warning.number
        for i in range(block):
            t0 = clock()
            P[k] = step.begin()
            Q[k], Qd[k] = step.q, qvel[dadr]
            v = V[k] = r_loop(step.field_point(), k * dt)
            step.command(v)
            step.end()
            if warn[w0] or warn[w1] or warn[w2] or warn[w3]:
                raise sim.SimError("the loop's step diverged")
            out[i] = clock() - t0
            k += 1
        t_loop[b] = np.median(out)
    return t_env, t_loop


def replay_ik(exp: sim.Experiment, field: Field, q_path: np.ndarray, backend: str) -> np.ndarray:
    """Wall time of ``solve`` (s), shape (K,), of the IK ``backend`` for the twists of the field along
    q_path, shape (K, n) (its runner from the run's start, one call per state)."""
    ctl = FieldController(exp.robot, exp.placement, 1.0 / exp.options["control_hz"], ik=backend,
                          rotation_ref=exp.setup.rotation_ref, mj_model=exp.physics.model.ptr)
    ctl.reset(q_path[0])
    dt = 1.0 / exp.options["control_hz"]
    runner = field.runner(exp.start, dt)
    out = np.empty(len(q_path))
    clock = time.perf_counter
    for k, q in enumerate(q_path):
        p = ctl.measure(q)
        tw = ctl.twist(runner(ctl.to_task(p), k * dt)).copy()
        t0 = clock()
        ctl.solve_ik(q, tw)
        out[k] = clock() - t0
    return out
